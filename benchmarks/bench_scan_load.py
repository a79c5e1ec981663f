"""Loading a large scan is cheap: 1000 frames of 640x360 validate in seconds, in little memory.

Writes a scan with ``--frames`` frames (default 1000) of 640x360 PNGs and a
~200k-vertex mesh, then times ``load_scan`` (which reads every image header but
decodes no pixels) and reports the peak resident memory of the process, then
decodes every frame once, one at a time, as a stage would.
"""

from __future__ import annotations

import argparse
import resource
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

from reroom.scan import Intrinsics, load_scan, look_at, write_scan


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=1000)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "scan"
        mesh = trimesh.creation.icosphere(subdivisions=7, radius=3.0)  # 163842 vertices
        intr = Intrinsics.from_fov(640, 360, 60.0)
        poses = [
            look_at([0.5 * np.cos(a), 0.5 * np.sin(a), 1.5], [0, 0, 1.5 + np.sin(a)])
            for a in np.linspace(0, 6.28, args.frames)
        ]
        # Smooth frames keep PNG encoding quick; load_scan reads headers only either way.
        yy, xx = np.mgrid[0:360, 0:640]
        base = np.stack([xx * 255 // 639, yy * 255 // 359, (xx + yy) * 255 // 998], -1).astype(
            np.uint8
        )
        base = base + rng.integers(0, 2, base.shape, dtype=np.uint8)
        t = time.perf_counter()
        write_scan(root, mesh, intr, poses, (np.roll(base, i, axis=1) for i in range(args.frames)))
        print(
            f"wrote {args.frames} frames + {len(mesh.vertices)}-vertex mesh in {time.perf_counter() - t:.1f} s"
        )
        before = peak_rss_mb()
        t = time.perf_counter()
        scan = load_scan(root)
        print(
            f"load_scan: {time.perf_counter() - t:.2f} s, peak RSS {peak_rss_mb():.0f} MB (before: {before:.0f} MB)"
        )
        t = time.perf_counter()
        total = 0.0
        for f in scan.frames:
            total += float(f.load_image()[0, 0, 0])
        print(
            f"decoding all frames one by one: {time.perf_counter() - t:.1f} s, peak RSS {peak_rss_mb():.0f} MB"
        )


if __name__ == "__main__":
    main()
