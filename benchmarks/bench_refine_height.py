"""The point-light refinement's objective along a light's vertical, against the truth.

Usage::

    python benchmarks/bench_refine_height.py SCAN --light localized0 \\
        [--heights 2.2,2.3,...] [--invert '{"refine_mounted_drop": -1}']

``SCAN`` is a synthetic scan with ``hdr/``, ``layout/``, ``lights/`` and
``ground_truth/`` (read here only, for the true light's x, y). ``reroom invert`` runs
once into a temporary folder; when its refinement (:mod:`reroom.invert.refine_points`)
comes to the named light, the objective (the weighted residual of the light's share,
its 32-bin profile refitted at each place) is printed at each height on the vertical
through the light's start and through the nearest true point light, then the refinement
goes on as usual and its result is printed. It shows where the objective has its
minima: a recessed downlight's cliff at the ceiling plane and a second minimum low in
the room (docs/invert.md, "Point-light refinement", session 23).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

import reroom.invert.refine_points as refine_points
from reroom.invert.direct import point_light_transfer
from reroom.invert.pipeline import InvertOptions, run_invert

HEIGHTS = "2.2,2.3,2.4,2.5,2.55,2.6,2.65,2.67,2.7,2.72"


def _true_points(scan: Path) -> list[np.ndarray]:
    scene = json.loads((scan / "ground_truth" / "scene" / "scene.json").read_text())
    return [np.asarray(x["position"], float) for x in scene["lights"] if "position" in x]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scan", type=Path)
    ap.add_argument("--light", required=True, help="the point light's name in lights.json")
    ap.add_argument("--heights", default=HEIGHTS, help="comma-separated heights, metres")
    ap.add_argument("--invert", default="{}", help="InvertOptions as JSON")
    args = ap.parse_args(argv)
    heights = [float(z) for z in args.heights.split(",")]
    lights = json.loads((args.scan / "lights" / "lights.json").read_text())["lights"]
    named = [x for x in lights if x["name"] == args.light]
    if not named or "position" not in named[0]:
        ap.error(f"no point light {args.light!r} in {args.scan / 'lights' / 'lights.json'}")
    start = np.asarray(named[0]["position"], float)
    truth = min(_true_points(args.scan), key=lambda t: float(np.linalg.norm(t - start)))
    original = refine_points.refine_point_position

    def scanned(caster, points, normals, target, weight, color, position, axis, basis, **kw):
        x0 = np.asarray(position, float)
        if np.linalg.norm(x0 - start) < 1e-6:
            keep = (weight > 0).any(axis=1) & np.isfinite(target).all(axis=1)
            p, n, t, w = points[keep], normals[keep], target[keep], weight[keep]
            print(f"{args.light} from {np.round(x0, 3).tolist()}, true {truth.tolist()}\n")
            print("| x, y | " + " | ".join(f"{z:.2f}" for z in heights) + " |")
            print("|---|" + "---|" * len(heights))
            for label, xy in (("start", x0[:2]), ("truth", truth[:2])):
                costs = []
                for z in heights:
                    f = point_light_transfer(
                        caster, p, n, np.array([xy[0], xy[1], z]), axis, basis,
                        clearance=kw["clearance"], fixture=kw["fixture"],
                    )  # fmt: skip
                    costs.append(refine_points._profile_fit(f, t, w, color, 1e-3)[1])
                print(f"| {label} | " + " | ".join(f"{c:.1f}" for c in costs) + " |")
        res = original(caster, points, normals, target, weight, color, position, axis, basis, **kw)
        if np.linalg.norm(x0 - start) < 1e-6:
            print(
                f"\nrefined to {np.round(res.position, 3).tolist()} ({res.shift:.3f} m, cost "
                f"{res.cost_start:.1f} -> {res.cost_end:.1f}); the bounds' lowest z "
                f"{float(kw['bounds'][0][2]):.3f} m"
            )
        return res

    refine_points.refine_point_position = scanned
    with tempfile.TemporaryDirectory() as tmp:
        opts = InvertOptions(pictures=False, **json.loads(args.invert))
        run_invert(args.scan, Path(tmp) / "invert", opts)
    return 0


if __name__ == "__main__":
    sys.exit(main())
