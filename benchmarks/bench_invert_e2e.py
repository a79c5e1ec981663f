"""End to end without the truth: layout -> lights -> invert -> re-render, then evaluate.

Usage::

    python benchmarks/bench_invert_e2e.py SCAN [--add-point x,y,z,name ...] [--localize]
    python benchmarks/bench_invert_e2e.py SCAN --rerender-only INVERT_DIR --lights LIGHTS_DIR \
        --unit-scale-from-truth

``SCAN`` must already hold ``hdr/`` (``reroom hdr``). The first form runs the stages as
the command line does (the estimate never reads ``ground_truth/``), then compares with the
truth: cluster albedo, light power and distribution errors (``reroom.invert.evaluate``) and the
re-render of input frames next to the photos (brightness ratio and relative L1). The
second form only re-renders an existing model; ``--unit-scale-from-truth`` multiplies the
render by the reference frame's true scale, for a model solved on the truth's radiance
(an evaluation-only shortcut, e.g. ``bench_invert.py --true-radiance``).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np


def _pct(v) -> str:
    if v is None or isinstance(v, str):
        return str(v)
    return "/".join(f"{100 * x:+.0f}" for x in np.atleast_1d(v)) + " %"


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("scan", type=Path)
    ap.add_argument("--add-point", action="append", default=[], help="x,y,z[,name] (user light)")
    ap.add_argument(
        "--localize",
        action="store_true",
        help="point lights from `reroom localize --into-lights` (no light placed by a person)",
    )
    ap.add_argument("--rerender-only", type=Path, default=None, help="an invert folder")
    ap.add_argument("--lights", type=Path, default=None, help="lights folder (--rerender-only)")
    ap.add_argument("--unit-scale-from-truth", action="store_true")
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--spp", type=int, default=16)
    args = ap.parse_args()

    from reroom.edit.rerender import rerender_inputs

    scan: Path = args.scan
    timings: dict[str, float] = {}
    if args.rerender_only is None:
        from reroom.invert.evaluate import evaluate_invert
        from reroom.invert.pipeline import run_invert
        from reroom.layout import run_layout
        from reroom.layout.pipeline import LayoutOptions
        from reroom.lights import LightsOptions, detect_lights
        from reroom.lights.detect import check_user_lights
        from reroom.lights.lightset import apply_edits, edits_from_options, write_lights

        t = time.perf_counter()
        run_layout(scan, scan / "layout", LayoutOptions(radiance=scan / "hdr" / "hdr_mesh.ply"))
        timings["layout"] = time.perf_counter() - t
        t = time.perf_counter()
        lights = detect_lights(scan, scan / "hdr", scan / "layout", LightsOptions())
        up = np.asarray(lights.meta.get("up", [0, 0, 1]))
        apply_edits(lights, edits_from_options(args.add_point), up=up)
        check_user_lights(lights)
        write_lights(lights, scan / "lights")
        timings["lights"] = time.perf_counter() - t
        if args.localize:
            from reroom.localize.scan import (
                ScanLocalizeOptions,
                localize_into_lights,
                localize_scan,
            )

            t = time.perf_counter()
            res, info = localize_scan(scan, ScanLocalizeOptions())
            for line in localize_into_lights(scan, res, info)[1]:
                print("localize:", line)
            timings["localize"] = time.perf_counter() - t
        t = time.perf_counter()
        run_invert(scan, scan / "invert")
        timings["invert"] = time.perf_counter() - t
        invert_dir, lights_dir, unit = scan / "invert", scan / "lights", 1.0
    else:
        invert_dir, lights_dir, unit = args.rerender_only, args.lights, 1.0
    if args.unit_scale_from_truth:
        truth = json.loads((scan / "ground_truth" / "ground_truth.json").read_text())
        unit = np.asarray(truth["frames"][0]["scale"], float)
    t = time.perf_counter()
    doc = rerender_inputs(
        scan, invert_dir, lights_dir, frames=args.frames, spp=args.spp, unit_scale=unit
    )
    timings["rerender"] = time.perf_counter() - t
    print(f"\n### {scan.name} (load {' '.join(f'{x:.1f}' for x in os.getloadavg())})\n")
    print("timings s:", {k: round(v, 1) for k, v in timings.items()})
    print(
        f"re-render: brightness {doc['median_ratio_of_means']:.3f} of the photos "
        f"(per frame {[round(f['ratio_of_means'], 3) for f in doc['frames']]}), relative L1 "
        f"{doc['median_relative_l1']:.2f} ({args.spp} spp)"
    )
    if args.rerender_only is None:
        ev = evaluate_invert(scan, invert_dir)
        print("\n| cluster | albedo error (r/g/b) |\n|---|---|")
        for name, c in ev["clusters"].items():
            print(f"| {name} | {_pct(c['relative_error'])} |")
        print(
            "\n| light | truth | power error (r/g/b) | distribution rel. L2 all / seen / well-seen |"
            "\n|---|---|---|---|"
        )
        for light in ev["lights"]:
            err = light.get("power_relative_error", light.get("note"))
            d = light.get("distribution") or {}
            l2 = "-" if d.get("relative_l2") is None else f"{d['relative_l2']:.0%}"
            for key in ("relative_l2_seen", "relative_l2_well_seen"):
                if d.get(key) is not None:
                    l2 += f" / {d[key]:.0%}"
            print(f"| {light['name']} | {light.get('truth')} | {_pct(err)} | {l2} |")


if __name__ == "__main__":
    main()
