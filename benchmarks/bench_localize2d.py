"""Table 6.1 of the thesis: light localization on the synthetic 2D dataset, ours next to theirs.

400 diffuse square rooms (100 each with 2, 3, 4, 5 lights), 400 wall measurements,
256 x 256 fields, without noise and with shot noise ``0.05 sqrt(B)``. For every room it
runs the random-restart baseline, one round of voting, and the full algorithm, and
prints a markdown table of success rates and runtimes next to the thesis's numbers, then
the time of one 256 x 256 field. Column definitions: docs/localize.md.

    .venv/bin/python benchmarks/bench_localize2d.py                      # the full run
    .venv/bin/python benchmarks/bench_localize2d.py --rooms-per-row 5    # a quick look

Seeded and deterministic: room ``i`` of the ``K``-light row is the same in every run, so
a run with fewer rooms per row evaluates the first rooms of the full run. Runtimes are
wall-clock seconds of the full algorithm per room (CPU seconds are in the JSON log).
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from reroom.io import atomic_write_json
from reroom.localize import (
    THESIS_TABLE_6_1,
    FieldGrid,
    SceneResult,
    box_room,
    evaluate_scene,
    intensity_distance_field,
    limiter_count_field,
    make_scene,
    render_room,
    sample_walls,
    summarize,
    voting_field,
)
from reroom.localize.bench2d import SHOT_NOISE_K

NOISE = {"none": 0.0, "shot": SHOT_NOISE_K}


def field_timing(repeats: int = 30) -> dict[str, float]:
    """Median wall time (ms) of one 256 x 256 field from 400 measurements."""
    room = box_room()
    walls = sample_walls(room, 400)
    grid = FieldGrid.for_room(room, 256)
    b = render_room(room, walls, [[0.3, 0.4], [0.7, 0.6], [0.5, 0.2]], [2.0, 3.0, 1.5])
    radius = 0.05 * room.radius

    def idf(method: str) -> None:
        intensity_distance_field(room, walls, b, grid, method=method)

    def idf_ring() -> None:
        _, lim = intensity_distance_field(room, walls, b, grid)
        voting_field(lim, walls, 1, radius)

    def idf_count() -> None:
        _, lim = intensity_distance_field(room, walls, b, grid)
        limiter_count_field(lim, 15, len(walls))

    out = {}
    for name, fn in [
        ("D+L brute force", lambda: idf("brute")),
        ("D+L tiled (default)", lambda: idf("tiled")),
        ("D+L+V ring r=1", idf_ring),
        ("D+L+V count r=15", idf_count),
    ]:
        fn()
        times = []
        for _ in range(repeats):
            t = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t)
        out[name] = 1e3 * float(np.median(times))
    return out


def figures(folder: Path, seed: int) -> list[Path]:
    """Fields of room 0 of the 3-light row, without and with noise, with the lights found."""
    from reroom.localize import FieldProposer2D, localize_lights, plot_fields, settings_for

    out = []
    for noise in ("none", "shot"):
        scene = make_scene(3, 0, NOISE[noise], seed=seed)
        vp, rp = settings_for(scene.noise)
        meas = scene.samples.measurements(scene.values)
        lo, hi = scene.room.bounds
        prop = FieldProposer2D(scene.room, scene.samples, 256, vp)
        res = localize_lights(meas, prop, (lo + 1e-3, hi - 1e-3), scene.tolerance, rp)
        title = (
            f"3-light room 0, {'no noise' if noise == 'none' else 'shot noise 0.05 sqrt(B)'}: "
            f"{'found' if res.success else 'not found'} {len(res.positions)} lights "
            f"in {res.iterations} iterations"
        )
        out.append(
            plot_fields(
                scene.room,
                scene.samples,
                scene.values,
                folder / f"localize_fields_{'noiseless' if noise == 'none' else 'noisy'}.png",
                scene.positions,
                res.positions,
                256,
                vp,
                title,
            )  # fmt: skip
        )
    return out


def _run(job: tuple[int, int, str, int, int]) -> SceneResult:
    k, index, noise, random_starts, seed = job
    scene = make_scene(k, index, NOISE[noise], seed=seed)
    return evaluate_scene(scene, index, random_starts=random_starts, seed=seed)


def _init_worker() -> None:
    # One numba thread per worker process: the processes already fill the cores.
    import numba

    numba.set_num_threads(1)


def table(summary: dict, noises: list[str]) -> str:
    """Markdown table: ours / thesis for each column."""
    lines = [
        "| noise | lights | rooms | Random | V(p) | Solved | Full | median s | max s |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for noise in noises:
        for k in (2, 3, 4, 5):
            if (noise, k) not in summary:
                continue
            s = summary[(noise, k)]
            t = THESIS_TABLE_6_1[(noise, k)]

            def pair(ours: float, theirs: float, fmt: str = ".2f") -> str:
                o = "n/a" if not np.isfinite(ours) else format(ours, fmt)
                return f"{o} / {format(theirs, fmt)}"

            lines.append(
                f"| {noise} | {k} | {int(s['rooms'])} | {pair(s['random'], t[0])} | "
                f"{pair(s['vote'], t[1])} | {pair(s['solved'], t[2])} | "
                f"{pair(s['full'], t[3])} | {pair(s['median_s'], t[4], '.1f')} | "
                f"{pair(s['max_s'], t[5], '.1f')} |"
            )
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rooms-per-row", type=int, default=100, help="rooms per light count")
    ap.add_argument("--noise", choices=["none", "shot", "both"], default="both")
    ap.add_argument("--lights", default="2,3,4,5", help="light counts, comma-separated")
    ap.add_argument(
        "--random-starts", type=int, default=100, help="random restarts per room (0: skip)"
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=1, help="processes (1: numba threads)")
    ap.add_argument("--json", type=Path, default=None, help="write per-room results here")
    ap.add_argument(
        "--figures", type=Path, default=None, help="also write the field pictures to this folder"
    )
    args = ap.parse_args()
    if args.rooms_per_row < 1:
        ap.error("--rooms-per-row must be at least 1")
    noises = ["none", "shot"] if args.noise == "both" else [args.noise]
    lights = [int(k) for k in args.lights.split(",")]
    if any(k not in (2, 3, 4, 5) for k in lights):
        ap.error("--lights must be among 2, 3, 4, 5")

    jobs = [
        (k, i, noise, args.random_starts, args.seed)
        for noise in noises
        for k in lights
        for i in range(args.rooms_per_row)
    ]
    t0 = time.perf_counter()
    results: list[SceneResult] = []
    if args.workers > 1:
        with mp.get_context("spawn").Pool(args.workers, initializer=_init_worker) as pool:
            for n, r in enumerate(pool.imap(_run, jobs), 1):
                results.append(r)
                print(f"\r{n}/{len(jobs)} rooms", end="", file=sys.stderr, flush=True)
    else:
        for n, job in enumerate(jobs, 1):
            results.append(_run(job))
            print(f"\r{n}/{len(jobs)} rooms", end="", file=sys.stderr, flush=True)
    wall = time.perf_counter() - t0
    print(file=sys.stderr)

    summary = summarize(results)
    print(
        f"## Table 6.1, ours / thesis ({args.rooms_per_row} rooms per row, "
        f"{args.random_starts} random starts per room, seed {args.seed})\n"
    )
    print(table(summary, noises))
    cpu = sum(r.cpu_seconds for r in results)
    print(
        f"\nTotal wall time {wall:.0f} s with {args.workers} worker(s); full algorithm "
        f"{cpu:.0f} CPU s in all."
    )
    print("\n## One 256 x 256 field, 400 measurements (median wall ms; thesis: 45 ms on a GPU)\n")
    for name, ms in field_timing().items():
        print(f"- {name}: {ms:.1f} ms")
    if args.figures is not None:
        for path in figures(args.figures, args.seed):
            print(f"wrote {path}")
    if args.json is not None:
        atomic_write_json(
            args.json,
            {
                "args": {k: str(v) for k, v in vars(args).items()},
                "wall_seconds": wall,
                "summary": {f"{n}-{k}": v for (n, k), v in summary.items()},
                "rooms": [asdict(r) for r in results],
            },
        )


if __name__ == "__main__":
    main()
