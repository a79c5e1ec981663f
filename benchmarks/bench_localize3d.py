"""Table 6.2 of the thesis: 3D light localization in cubical rooms, ours and the baseline.

Unit cubes with 2-5 isotropic point lights (``--configs`` random configurations each,
lights uniform in ``[0.1, 0.9]^3`` at least 0.1 apart, intensities in ``[1, 5]``), the
six faces sampled at ``--per-side``^2 sites each, no noise. For each room it runs our
Algorithm 1 with the 3D voting function (``FieldProposer3D`` on a ``1/--voxels`` grid)
and the random-restart baseline (``--random-starts`` compiled Levenberg-Marquardt solves
with the true light count; the thesis: 50 Ceres solves per room), and prints a markdown
table next to Table 6.2, then the time of one ``D``/``L`` field at the thesis's scale
(``|Q| = 60 000``; the thesis: about an hour per field at 512^3 on a Titan X).

    .venv/bin/python benchmarks/bench_localize3d.py                     # the full run
    .venv/bin/python benchmarks/bench_localize3d.py --configs 1 --timing-resolution 128
    .venv/bin/python benchmarks/bench_localize3d.py --configs 0 --timing-resolution 0 \
        --localization-timing 3                       # one localization at |Q| = 60 000

Success (both columns): mean squared error below ``1e-8 * mean(B^2)`` and every true light
matched one-to-one within 0.025 (and 10% in intensity). Seeded and deterministic.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from reroom.localize import (
    Measurements,
    RefineParams,
    localize_lights,
    matches_truth,
    render,
)
from reroom.localize.fields3d import VoxelGrid, intensity_distance_field_3d, limiter_count_3d
from reroom.localize.scene3d import (
    FieldProposer3D,
    box_light_bounds,
    box_measurements,
    box_valid_mask,
)
from reroom.localize.solve import fit_lights_lm

#: Table 6.2: lights -> (baseline success rate, median s, max s per optimization run).
THESIS_TABLE_6_2 = {2: (0.49, 95.0, 165.0), 3: (0.27, 283.0, 398.0), 4: (0.07, 499.0, 665.0), 5: (0.05, 1007.0, 1083.0)}  # fmt: skip
RADIUS = np.sqrt(3) / 2  # half the cube's diagonal


def random_cube_lights(k: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``k`` light positions in ``[0.1, 0.9]^3``, pairwise at least 0.1 apart, and intensities."""
    while True:
        pos = rng.uniform(0.1, 0.9, (k, 3))
        d = np.linalg.norm(pos[:, None] - pos[None], axis=-1) + np.eye(k)
        if d.min() >= 0.1:
            return pos, rng.uniform(1.0, 5.0, k)


def run_room(k: int, index: int, args: argparse.Namespace, proposer_parts) -> dict:
    """Ours and the baseline on room ``index`` of the ``k``-light row."""
    pts, nrm, grid, valid = proposer_parts
    rng = np.random.default_rng([args.seed, k, index])
    lights, inten = random_cube_lights(k, rng)
    meas = Measurements(pts, nrm, render(pts, nrm, lights, inten))
    tol = 1e-8 * float(np.mean(meas.values**2))
    bounds = box_light_bounds(1.0)
    prop = FieldProposer3D(pts, nrm, grid, valid, RADIUS)
    t0, c0 = time.perf_counter(), time.process_time()
    res = localize_lights(
        meas,
        prop,
        bounds,
        tol,
        RefineParams(match_distance=0.1 * RADIUS, time_limit=args.time_limit),
    )
    ours_s, ours_cpu = time.perf_counter() - t0, time.process_time() - c0
    ours_ok = bool(res.success) and matches_truth(
        res.positions, res.intensities, lights, inten, 0.025, 0.1
    )
    # Baseline: each start is one full solve, timed alone; success as for ours.
    ok, times = [], []
    for _ in range(args.random_starts):
        p0 = rng.uniform(*bounds, size=(k, 3))
        i0 = rng.uniform(1.0, 5.0, k)
        t = time.perf_counter()
        pos, it, err = fit_lights_lm(meas, p0, i0, bounds, None, 200)
        times.append(time.perf_counter() - t)
        ok.append(err < tol and matches_truth(pos, it, lights, inten, 0.025, 0.1))
    return {
        "k": k,
        "ours_ok": ours_ok,
        "ours_s": ours_s,
        "ours_cpu": ours_cpu,
        "ours_iterations": res.iterations,
        "ours_reason": res.reason,
        "base_rate": float(np.mean(ok)) if ok else float("nan"),
        "base_times": times,
    }


def field_timing(n_sites: int, resolution: int) -> dict[str, float]:
    """Wall and CPU seconds of one ``D``/``L`` field (and ``V``) of ``n_sites`` sites."""
    per_side = int(round(np.sqrt(n_sites / 6)))
    pts, nrm = box_measurements(1.0, per_side)
    rng = np.random.default_rng(0)
    lights, inten = random_cube_lights(3, rng)
    meas = Measurements(pts, nrm, render(pts, nrm, lights, inten))
    grid = VoxelGrid.for_box([0, 0, 0], [1, 1, 1], 1.0 / resolution)
    t, c = time.perf_counter(), time.process_time()
    _, lim = intensity_distance_field_3d(meas, grid)
    out = {"sites": len(pts), "voxels": int(np.prod(grid.shape)), "idf_s": time.perf_counter() - t}
    out["idf_cpu"] = time.process_time() - c
    t = time.perf_counter()
    limiter_count_3d(lim, 2)
    out["votes_s"] = time.perf_counter() - t
    return out


def localization_timing(n_sites: int, voxels: int, k: int, seed: int, time_limit: float) -> dict:
    """One full 3D localization (Algorithm 1) of a ``k``-light cube with ``n_sites`` sites."""
    per_side = int(round(np.sqrt(n_sites / 6)))
    pts, nrm = box_measurements(1.0, per_side)
    lights, inten = random_cube_lights(k, np.random.default_rng([seed, k, 999]))
    meas = Measurements(pts, nrm, render(pts, nrm, lights, inten))
    grid = VoxelGrid.for_box([0, 0, 0], [1, 1, 1], 1.0 / voxels)
    prop = FieldProposer3D(pts, nrm, grid, box_valid_mask(grid, 1.0, 0.04), RADIUS)
    t, c = time.perf_counter(), time.process_time()
    res = localize_lights(
        meas,
        prop,
        box_light_bounds(1.0),
        1e-8 * float(np.mean(meas.values**2)),
        RefineParams(match_distance=0.1 * RADIUS, time_limit=time_limit),
    )
    ok = bool(res.success) and matches_truth(
        res.positions, res.intensities, lights, inten, 0.025, 0.1
    )
    return {
        "sites": len(pts),
        "lights": k,
        "solved": ok,
        "reason": res.reason,
        "iterations": res.iterations,
        "wall_s": time.perf_counter() - t,
        "cpu_s": time.process_time() - c,
    }


def draw_figure(folder: Path, per_side: int, voxels: int, seed: int) -> Path:
    """Slices of ``D``, ``L``, ``V`` through the lights of room 0 of the 3-light row, with the
    lights found by Algorithm 1 (like the thesis's Fig. 6.2 / 6.8, in 3D)."""
    from reroom.localize.plot import plot_fields_3d

    pts, nrm = box_measurements(1.0, per_side)
    lights, inten = random_cube_lights(3, np.random.default_rng([seed, 3, 0]))
    meas = Measurements(pts, nrm, render(pts, nrm, lights, inten))
    grid = VoxelGrid.for_box([0, 0, 0], [1, 1, 1], 1.0 / voxels)
    prop = FieldProposer3D(pts, nrm, grid, box_valid_mask(grid, 1.0, 0.04), RADIUS)
    res = localize_lights(
        meas, prop, box_light_bounds(1.0), 1e-8 * float(np.mean(meas.values**2)),
        RefineParams(match_distance=0.1 * RADIUS, time_limit=600),
    )  # fmt: skip
    folder.mkdir(parents=True, exist_ok=True)
    return plot_fields_3d(
        prop, meas.values, folder / "localize_fields_3d.png", lights, res.positions,
        title=f"3-light cube, {len(pts)} sites, {voxels}^3 voxels: {res.reason}",
    )  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--configs", type=int, default=5, help="rooms per light count")
    ap.add_argument("--lights", default="2,3,4,5", help="light counts, comma-separated")
    ap.add_argument("--per-side", type=int, default=30, help="sites per face side (6 n^2 sites)")
    ap.add_argument("--voxels", type=int, default=64, help="voxels per cube side")
    ap.add_argument("--random-starts", type=int, default=50)
    ap.add_argument("--time-limit", type=float, default=1800.0, help="seconds per room (ours)")
    ap.add_argument("--timing-sites", type=int, default=60000)
    ap.add_argument("--timing-resolution", type=int, default=256, help="0: skip the timing")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--figures", type=Path, help="draw slices of D, L, V of a 3-light cube here")
    ap.add_argument(
        "--localization-timing",
        type=int,
        default=0,
        help="also time one full localization of this many lights at --timing-sites (0: skip)",
    )
    args = ap.parse_args()
    if args.figures is not None:
        print(f"wrote {draw_figure(args.figures, args.per_side, args.voxels, args.seed)}")
    pts, nrm = box_measurements(1.0, args.per_side)
    grid = VoxelGrid.for_box([0, 0, 0], [1, 1, 1], 1.0 / args.voxels)
    valid = box_valid_mask(grid, 1.0, 0.04)
    parts = (pts, nrm, grid, valid)
    rows = []
    for k in (int(x) for x in args.lights.split(",")) if args.configs > 0 else ():
        rooms = []
        for i in range(args.configs):
            r = run_room(k, i, args, parts)
            rooms.append(r)
            print(
                f"  {k} lights, room {i}: ours {'solved' if r['ours_ok'] else 'FAILED'} "
                f"({r['ours_reason']}, {r['ours_iterations']} iterations, {r['ours_s']:.0f} s, "
                f"{r['ours_cpu']:.0f} CPU s); baseline {r['base_rate']:.2f} of "
                f"{len(r['base_times'])} starts, load {os.getloadavg()[0]:.1f}",
                flush=True,
            )
        base_t = (
            np.concatenate([r["base_times"] for r in rooms]) if args.random_starts else [np.nan]
        )
        th = THESIS_TABLE_6_2[k]
        rows.append(
            f"| {k} | {len(rooms)} | {np.mean([r['ours_ok'] for r in rooms]):.2f} / 1.00 | "
            f"{np.median([r['ours_s'] for r in rooms]):.0f} / {max(r['ours_s'] for r in rooms):.0f} | "
            f"{np.median([r['ours_cpu'] for r in rooms]):.0f} | "
            f"{np.mean([r['base_rate'] for r in rooms]):.2f} / {th[0]:.2f} | "
            f"{np.median(base_t):.3f} / {th[1]:.0f} | {np.max(base_t):.3f} / {th[2]:.0f} |"
        )
        print(f"{k} lights done, load {os.getloadavg()[0]:.1f}", flush=True)
    print(
        f"\n## Table 6.2, ours / thesis ({args.configs} rooms per row, {6 * args.per_side**2} "
        f"sites, {args.voxels}^3 voxels, {args.random_starts} random starts, seed {args.seed})\n"
    )
    print(
        "| lights | rooms | ours: success | ours: median / max s | ours: median CPU s | "
        "baseline: success | baseline: median s per run | baseline: max s per run |"
    )
    print("|---|---|---|---|---|---|---|---|")
    print("\n".join(rows))
    print(f"\nLoad average {os.getloadavg()} (2 cores).")
    if args.timing_resolution > 0:
        t = field_timing(args.timing_sites, args.timing_resolution)
        print(
            f"\nOne field, |Q| = {t['sites']}, {t['voxels']} voxels ({args.timing_resolution}^3): "
            f"D+L {t['idf_s']:.1f} s wall ({t['idf_cpu']:.1f} CPU s), V (count, r = 2) "
            f"{t['votes_s']:.1f} s; thesis: about 1 hour at 512^3 on a Titan X. "
            f"Load {os.getloadavg()}."
        )
    if args.localization_timing > 0:
        t = localization_timing(
            args.timing_sites, args.voxels, args.localization_timing, args.seed, args.time_limit
        )
        print(
            f"\nOne localization, |Q| = {t['sites']}, {t['lights']} lights, {args.voxels}^3 "
            f"voxels: solved {t['solved']} ({t['reason']}, {t['iterations']} iterations), "
            f"{t['wall_s']:.0f} s wall, {t['cpu_s']:.0f} CPU s. Load {os.getloadavg()}."
        )


if __name__ == "__main__":
    main()
