"""How long does the main job take? ``reroom demo`` from an empty folder, timed.

Runs ``reroom demo --out DIR`` (scan generation, then ``reroom run`` with every stage and
the report) in a fresh folder and prints wall and CPU time, the load average, and each
stage's seconds from ``run.json``, next to the issue's 3-minute target. Then runs it again
to time the resumed run (every stage skipped). With ``--scan SCAN`` it times ``reroom run
SCAN`` instead, against the issue's 5-minute target for a 300-frame 640x360 scan::

    python benchmarks/bench_run.py [--out /tmp/reroom_bench_run]
    python benchmarks/bench_run.py --scan SCAN [--out DIR]
    python benchmarks/bench_run.py --evaluate-only --out DIR [--scan SCAN]  # an earlier run

When the scan has a ground truth, the inverse rendering's errors against it follow
(``reroom.invert.evaluate.evaluate_invert``: cluster albedos, each light's power, power
leaving its fitting and distribution error).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

TARGET_S = 180.0
SCAN_TARGET_S = 300.0


def _timed(cmd: list[str]) -> tuple[float, float]:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", type=Path, default=Path("/tmp/reroom_bench_run"))
    ap.add_argument("--scan", type=Path, default=None, help="time `reroom run SCAN` instead")
    ap.add_argument(
        "--evaluate-only", action="store_true", help="only evaluate the run already in --out"
    )
    args = ap.parse_args()
    if args.evaluate_only:
        evaluate(args.scan or args.out, args.out / "invert")
        return
    if args.out.exists():
        shutil.rmtree(args.out)
    reroom = str(Path(sys.executable).with_name("reroom"))
    load = os.getloadavg()
    if args.scan is None:
        what, target = "reroom demo", TARGET_S
        scan = args.out / "scan"
        wall, cpu = _timed([reroom, "demo", "--out", str(args.out)])
    else:
        what, target = f"reroom run {args.scan}", SCAN_TARGET_S
        scan = args.scan
        wall, cpu = _timed([reroom, "run", str(scan), "--out", str(args.out)])
    print(f"load average before: {' '.join(f'{x:.1f}' for x in load)}")
    print(
        f"{what}: {wall:.1f} s wall, {cpu:.1f} s CPU; target {target:.0f} s "
        f"(ratio {wall / target:.2f})"
    )
    run = json.loads((args.out / "run.json").read_text())
    stages = run.get("stages", [])
    print("| stage | status | seconds |\n|---|---|---|")
    for st in stages:
        print(f"| {st.get('name')} | {st.get('status')} | {st.get('seconds', 0):.1f} |")
    report = args.out / "invert" / "report.json"
    if report.is_file():  # the inverse rendering's own steps (InvertResult.timings)
        doc = json.loads(report.read_text())
        steps = doc.get("timings_s", {})
        print("invert steps (s): " + ", ".join(f"{k} {v:.1f}" for k, v in steps.items()))
        tex = doc.get("textures") or {}
        if tex.get("deconvolution"):  # the photo textures' solve (texture_solve.py)
            print(f"textures: texel {tex.get('texel')} m, solve {tex['deconvolution']}")
    wall2, cpu2 = _timed([reroom, "run", str(scan), "--out", str(args.out)])
    print(f"resumed `reroom run` (nothing changed): {wall2:.1f} s wall, {cpu2:.1f} s CPU")
    evaluate(scan, args.out / "invert")


def _pct(values) -> str:
    return "/".join(f"{100 * v:+.1f}" for v in values) + " %"


def evaluate(scan: Path, invert_dir: Path) -> None:
    """Print the inverse rendering's errors against the scan's ground truth, if it has one."""
    if not (scan / "ground_truth").is_dir() or not invert_dir.is_dir():
        print(f"{scan}: no ground truth, or no {invert_dir}: nothing to evaluate")
        return
    from reroom.invert.evaluate import evaluate_invert

    rep = evaluate_invert(scan, invert_dir)
    print("\n| cluster | albedo error r/g/b |\n|---|---|")
    for name, c in rep["clusters"].items():
        print(f"| {name} | {_pct(c['relative_error'])} |")
    for which, st in rep["per_vertex"].items():
        if st is not None:
            print(
                f"per-vertex albedo error ({which}, {st['vertices']} vertices): median "
                f"{100 * st['median']:.2f} %, 90th percentile {100 * st['p90']:.1f} %"
            )
    print("\n| light | truth | off by | power error | leaving the fitting | distribution L2 |")
    print("|---|---|---|---|---|---|")
    for light in rep["lights"]:
        pe = light.get("power_relative_error")
        ee = light.get("effective_power_relative_error")
        l2 = light.get("distribution_relative_l2")
        l2_text = f"{100 * l2:.1f} %" if l2 is not None else "-"
        coarse = light.get("distribution_relative_l2_solved_bins")
        if coarse is not None:  # a point light split after the solve: at the solve's bins too
            dist = light["distribution"]
            l2_text = (
                f"{100 * coarse:.1f} % at {dist['solved_bins']} bins, {l2_text} at "
                f"{len(dist['true_profile'])}"
            )
        print(
            f"| {light['name']} | {light.get('truth')} | {light.get('distance_m', 0):.3f} m | "
            f"{_pct(pe) if pe else '-'} | {_pct(ee) if ee else '-'} | {l2_text} |"
        )
    _line_geometry(scan, invert_dir)


def _line_geometry(scan: Path, invert_dir: Path) -> None:
    """Each line light's radius, and how far its ends are from each true tube's axis."""
    from reroom.rays.geometry import segment_distance

    truth = json.loads((scan / "ground_truth" / "ground_truth.json").read_text())
    tubes = [t for t in truth.get("lights", []) if t.get("type") == "line"]
    ours = json.loads((invert_dir / "scene.json").read_text()).get("lights", [])
    for light in (x for x in ours if x.get("type") == "line"):
        g = light["geometry"]
        ends = np.array([g["p0"], g["p1"]], float)
        for t in tubes:
            off = segment_distance(ends, t["p0"], t["p1"])
            print(
                f"line light {light['name']} against {t['name']}: radius "
                f"{100 * float(g['radius']):.3f} cm (truth {100 * float(t['radius']):.3f}), "
                f"ends {1000 * off.max():.2f} mm from its axis"
            )


if __name__ == "__main__":
    main()
