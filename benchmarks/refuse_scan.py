"""A fused synthetic scan fused again with its voxel grid placed otherwise (its photos kept).

How much of an inverse-rendering figure is owed to where the fusion's voxels fell? This
re-fuses SCAN's mesh (``reroom.synth.generate.refuse_scan``: the same noisy depth maps,
the grid turned ``--yaw`` degrees about the vertical) with its per-vertex truth, into OUT,
in a few minutes instead of the frames' rendering; then run ``bench_run.py --scan OUT``
on it and compare::

    python benchmarks/refuse_scan.py SCAN --yaw 23 --out OUT

The default placement of ``reroom synth`` is 17 degrees (``synth.scanner.GRID_YAW_DEG``).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from reroom.synth.generate import refuse_scan


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scan", type=Path)
    ap.add_argument("--yaw", type=float, required=True, help="grid turn, degrees")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args()
    t = time.perf_counter()
    out = refuse_scan(a.scan, a.out, a.yaw)
    import json

    doc = json.loads((out / "ground_truth" / "ground_truth.json").read_text())
    print(
        f"{out}: fused again at grid yaw {a.yaw:g} deg, {doc['mesh']['vertices']} vertices, "
        f"{time.perf_counter() - t:.1f} s"
    )


if __name__ == "__main__":
    main()
