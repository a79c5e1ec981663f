"""How long does the main job take? ``reroom demo`` from an empty folder, timed.

Runs ``reroom demo --out DIR`` (scan generation, then ``reroom run`` with every stage and
the report) in a fresh folder and prints wall and CPU time, the load average, and each
stage's seconds from ``run.json``, next to the issue's 3-minute target. Then runs it again
to time the resumed run (every stage skipped). With ``--scan SCAN`` it times ``reroom run
SCAN`` instead, against the issue's 5-minute target for a 300-frame 640x360 scan::

    python benchmarks/bench_run.py [--out /tmp/reroom_bench_run]
    python benchmarks/bench_run.py --scan SCAN [--out DIR]
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
    args = ap.parse_args()
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
    wall2, cpu2 = _timed([reroom, "run", str(scan), "--out", str(args.out)])
    print(f"resumed `reroom run` (nothing changed): {wall2:.1f} s wall, {cpu2:.1f} s CPU")


if __name__ == "__main__":
    main()
