"""The line lights' shape prior on a finished run: how its open fraction is sampled.

For the first line light of ``RUN/lights/lights.json`` (a ``reroom run`` folder with
``hdr/``; ``ground_truth/`` for the truth's rows)::

    python benchmarks/bench_line_fixture.py RUN [RUN ...]

prints

1. the open fraction of the scanned fixture (``reroom.invert.line_fixture``, as the
   pipeline computes it) in the end ``phi`` bin (60-90 deg) of the upward and sideways
   ``theta`` bins (0-120 deg), for 16, 48 (the default) and 96 ``phi`` strata, with the
   range over those bins and the seconds each took;
2. the same bins of the evaluation's true profile (``true_line_profile``, luminance of
   ``i / (2 r L)``, i.e. its open fraction) for 16, 64 (its default) and 96 strata;
3. ``inside_fraction`` of the scanned fixture with the pipeline's 4096 rays and with
   20,000, and what the pipeline decides from it (``MAX_INSIDE_FRACTION``).

Everything but (2) is what the estimate sees; (2) reads ``ground_truth/``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from reroom.hdr.linearize import LUMA
from reroom.invert.basis import LineBasis
from reroom.invert.line_fixture import (
    MAX_INSIDE_FRACTION,
    inside_fraction,
    line_open_fraction,
    scan_fixture_caster,
)
from reroom.invert.pipeline import InvertOptions
from reroom.io.mesh import read_ply

#: theta bins 0-120 deg of the 32 (upward and sideways), the end phi bin of 3.
END_BINS = (slice(0, 22), 2)


def _row(label: str, values: np.ndarray, seconds: float) -> str:
    v = values.reshape(32, 3)[END_BINS]
    return (
        f"| {label} | {v.min():.3f}-{v.max():.3f} | {np.abs(np.diff(v)).max():.3f} | "
        f"{seconds:.2f} s |"
    )


def bench(run: Path) -> None:
    mesh = read_ply(run / "hdr" / "hdr_mesh.ply")
    line = next(x for x in json.loads((run / "lights" / "lights.json").read_text())["lights"]
                if x["type"] == "line")  # fmt: skip
    opts = InvertOptions()
    p0, p1, up = (np.asarray(line[k], float) for k in ("p0", "p1", "d_perp"))
    r = float(line["radius"])
    basis = LineBasis(opts.bins, opts.line_phi_bins, opts.line_phi_fold)
    fixture = scan_fixture_caster(mesh.vertices, mesh.faces, p0, p1, r, opts.line_clearance)
    print(f"\n`{run}`, `{line['name']}` (radius {r:.4f} m, {fixture.n_faces} fixture faces)\n")
    print("| open fraction, end phi bin, theta 0-120 deg | range | largest step | time |")
    print("|---|---|---|---|")
    for pa in (16, 48, 96):
        t = time.perf_counter()
        o = line_open_fraction(
            fixture.occluded, p0, p1, up, r, basis, opts.line_clearance,
            samples=opts.line_fixture_samples, phi_angles=pa, seed=opts.seed,
        )  # fmt: skip
        print(_row(f"scan, {pa} phi strata", o, time.perf_counter() - t))
    truth_file = run / "ground_truth" / "ground_truth.json"
    if truth_file.is_file():
        from reroom.invert.evaluate import true_line_profile

        truth = next(x for x in json.loads(truth_file.read_text())["lights"]
                     if x["type"] == "line")  # fmt: skip
        bare = 2 * float(truth["radius"]) * np.asarray(truth["radiance"], float) @ LUMA
        for pa in (16, 64, 96):
            t = time.perf_counter()
            prof = true_line_profile(
                truth, run / "ground_truth" / "scene", up, bins=opts.bins,
                phi_bins=opts.line_phi_bins, fold=opts.line_phi_fold, phi_angles=pa,
            )  # fmt: skip
            print(_row(f"truth, {pa} phi strata", prof @ LUMA / bare, time.perf_counter() - t))
    print()
    for rays in (4096, 20000):
        f = inside_fraction(fixture, p0, p1, r, opts.line_clearance, rays=rays)
        verdict = "prior dropped" if f > MAX_INSIDE_FRACTION else "prior kept"
        print(f"inside_fraction, {rays} rays: {f:.3f} ({verdict} above {MAX_INSIDE_FRACTION})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("runs", nargs="+", type=Path)
    for run in ap.parse_args().runs:
        bench(run)


if __name__ == "__main__":
    main()
