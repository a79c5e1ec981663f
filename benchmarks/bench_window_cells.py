"""Where does a window's light go? Its solved cube cells against the truth's, cell by cell.

Usage::

    python benchmarks/bench_window_cells.py RUN [OTHER_RUN ...] [--window window0] [--top 12]
        [--render]

``RUN`` is a finished ``reroom run`` of a synthetic scan (``invert/`` and
``ground_truth/``); the other runs are runs of the same scan (e.g. the folders of
``bench_invert_sweep.py``). The truth's cells come from the first run's evaluation
(:func:`reroom.invert.evaluate.evaluate_invert`: the true HDRI averaged over each cell,
in the true scene's units); each run's cells (``scene.json``'s ``distribution.cells``,
divided by that run's radiance scale ``k``) are printed as a ratio to them, Rec. 709
luminance, for the brightest true cells, with each cell's direction (the way a ray from
the room leaves) and its elevation. ``--render`` compares the window refitted for the
renders instead (``render_distribution``, e.g. 8x8 cells) with the truth on its cells.
This is evaluation: it reads ``ground_truth/``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def solved_cells(run: Path, window: str, render: bool = False) -> tuple[np.ndarray, dict]:
    """``window``'s cells in ``run``'s ``invert/scene.json`` over the run's radiance scale
    ``k``, and the run's evaluation (:func:`reroom.invert.evaluate.evaluate_invert`).
    ``render``: the cells of the window's refit for the renders (``render_distribution``)."""
    from reroom.invert.evaluate import evaluate_invert

    path = run / "invert" / "scene.json"
    if not path.is_file():
        raise SystemExit(f"{path} is missing: run `reroom run` (or `reroom invert`) first")
    doc = json.loads(path.read_text())
    light = next((x for x in doc.get("lights", []) if x.get("name") == window), None)
    if light is None or light.get("type") != "window":
        raise SystemExit(f"{path} has no window named {window!r}")
    key = "render_distribution" if render else "distribution"
    if key not in light:
        raise SystemExit(f"{path}: {window!r} has no {key} (no render window in this run)")
    report = evaluate_invert(run)
    k = np.asarray(report["radiance_scale"], float)
    return np.asarray(light[key]["cells"], float) / k, report


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("runs", type=Path, nargs="+")
    ap.add_argument("--window", default="window0")
    ap.add_argument("--top", type=int, default=12, help="how many of the brightest true cells")
    ap.add_argument(
        "--render",
        action="store_true",
        help="the render window's finer cells (render_distribution) against the truth's",
    )
    args = ap.parse_args()

    from reroom.invert.basis import CubemapBasis
    from reroom.invert.evaluate import true_window_cells

    first, report = solved_cells(args.runs[0], args.window, args.render)
    entry = next(e for e in report["lights"] if e["name"] == args.window)
    truth = np.asarray(entry["distribution"]["true_cells"], float)
    if args.render:
        scene_dir = args.runs[0] / "ground_truth" / "scene"
        desc = json.loads((scene_dir / "scene.json").read_text())
        true_w = next(x for x in desc["lights"] if x["name"] == entry["truth"])
        n_fine = int(round(np.sqrt(len(first) / 6)))
        truth = true_window_cells(true_w, scene_dir, n=n_fine)[0]
    n = int(round(np.sqrt(len(truth) / 6)))
    basis = CubemapBasis(n)
    if basis.size != len(truth):
        raise SystemExit(f"the truth has {len(truth)} cells, not a cube map's 6 n^2")
    t_lum = truth @ LUMINANCE
    runs = [first] + [solved_cells(r, args.window, args.render)[0] for r in args.runs[1:]]
    for r, cells in zip(args.runs, runs, strict=True):
        if len(cells) != basis.size:
            raise SystemExit(f"{r}: {len(cells)} cells, the truth {basis.size}; compare like bases")
    dirs = basis.cell_directions()
    order = np.argsort(-t_lum)[: args.top]
    names = " | ".join(f"ours / truth: {r.name}" for r in args.runs)
    print(f"`{args.window}`, the {len(order)} brightest true cells (luminance / k):\n")
    print(f"| cell | leaves along | elevation | truth | {names} |")
    print("|---|---|---|---|" + "---|" * len(runs))
    for i in order:
        ratios = " | ".join(f"{(c[i] @ LUMINANCE) / t_lum[i]:.2f}" for c in runs)
        d = np.round(dirs[i], 2)
        el = np.degrees(np.arcsin(dirs[i][2]))
        print(
            f"| {i} | {d[0]:+.2f} {d[1]:+.2f} {d[2]:+.2f} | {el:.1f}° | {t_lum[i]:.2f} | {ratios} |"
        )


if __name__ == "__main__":
    main()
