"""A line light's tube and trough from the photos, against the synthetic truth.

Usage::

    python benchmarks/bench_line_photos.py SCAN [SCAN ...]

``SCAN`` is a synthetic scan with ``lights/lights.json`` (a detected line light) and
``ground_truth/``. For each line light this runs what ``reroom invert`` runs when the
scan does not resolve the tube's fixture (:mod:`reroom.invert.line_photos`, via
``reroom.invert.pipeline._photo_trough``) and prints, next to the truth (read here,
never by the pipeline):

* the scanned fixture's inside fraction (above 0.05 the pipeline uses the photos);
* the axis: the detected one's and the photos' distance from the true axis, across
  (along ``d_perp x (p1 - p0)``) and up, at each end; the stripe samples and frames;
* the radius: detected, photos', true;
* the cut-off angles per side, the trough's edges, bottom and top against the true
  baffles' half gap and depth below the true axis;
* the open fraction of the photos' trough against the true fixture's (relative L2 over
  the bins, in the pipeline's ``LineBasis``), and of the scanned fixture where the scan
  resolves it (what the pipeline uses there), and the seconds the photos took.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from reroom.invert.basis import LineBasis
from reroom.invert.evaluate import true_line_profile
from reroom.invert.line_fixture import inside_fraction, line_open_fraction, scan_fixture_caster
from reroom.invert.pipeline import InvertOptions, _photo_trough
from reroom.scan import load_scan


def _offsets(points: np.ndarray, p0: np.ndarray, p1: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Each point's offset from the line ``p0 -> p1``: across (``dh x up``) and up, metres."""
    dh = (p1 - p0) / np.linalg.norm(p1 - p0)
    u = up - (up @ dh) * dh
    u /= np.linalg.norm(u)
    side = np.cross(dh, u)
    rel = points - p0
    return np.stack([rel @ side, rel @ u], axis=1)


def bench_scan(scan_dir: Path) -> None:
    opts = InvertOptions()
    doc = json.loads((scan_dir / "lights" / "lights.json").read_text())
    gt = json.loads((scan_dir / "ground_truth" / "ground_truth.json").read_text())
    true_lines = [x for x in gt["lights"] if x["type"] == "line"]
    scan = load_scan(scan_dir, check_images=False)
    mesh = scan.mesh
    o = gt.get("options", {})
    print(f"\n### {scan_dir} ({o.get('mesh')} mesh, {len(scan.frames)} frames "
          f"{o.get('width')}x{o.get('height')}, {o.get('spp')} spp)\n")  # fmt: skip
    print(
        "| line | inside | axis across / up at p0, p1 (mm): detected -> photos "
        "| stripes (frames) | radius mm: detected / photos / true | cut-off deg "
        "| trough edges / bottom / top mm (true half gap / depth) "
        "| open fraction L2: trough / scanned fixture | s |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for light in [x for x in doc["lights"] if x["type"] == "line"]:
        p0, p1 = np.asarray(light["p0"], float), np.asarray(light["p1"], float)
        up = np.asarray(light["d_perp"], float)
        mid = 0.5 * (p0 + p1)
        truth = min(
            true_lines, key=lambda t: np.linalg.norm(0.5 * (np.add(t["p0"], t["p1"])) - mid)
        )
        t0, t1 = np.asarray(truth["p0"], float), np.asarray(truth["p1"], float)
        if (p1 - p0) @ (t1 - t0) < 0:
            t0, t1 = t1, t0
        radius = float(light.get("radius", 0.013))
        fixture = scan_fixture_caster(mesh.vertices, mesh.faces, p0, p1, radius, 0.3)
        inside = 0.0 if fixture is None else inside_fraction(fixture, p0, p1, radius, 0.3)
        start = time.perf_counter()
        notes: list[str] = []
        found = _photo_trough(scan_dir, mesh, light["name"], light, opts, notes)
        secs = time.perf_counter() - start
        det = _offsets(np.stack([p0, p1]), t0, t1, up) * 1000
        if found is None:
            print(f"| {light['name']} | {inside:.2f} | {det.round(1).tolist()} -> none "
                  f"| | | | {'; '.join(notes)} | | {secs:.1f} |")  # fmt: skip
            continue
        caster, g, info = found
        ph = _offsets(np.asarray([g["p0"], g["p1"]], float), t0, t1, up) * 1000
        basis = LineBasis(opts.bins, opts.line_phi_bins, opts.line_phi_fold)
        ours = line_open_fraction(
            caster.occluded, np.asarray(g["p0"]), np.asarray(g["p1"]), up, float(g["radius"]),
            basis, opts.line_clearance, samples=opts.line_fixture_samples, seed=opts.seed,
        )  # fmt: skip
        prof = true_line_profile(
            truth, scan_dir / "ground_truth" / "scene", up, bins=opts.bins,
            phi_bins=opts.line_phi_bins, fold=opts.line_phi_fold,
        )  # fmt: skip
        true_open = prof[:, 1] / (2 * truth["radius"] * truth["radiance"][1])
        l2 = np.linalg.norm(ours - true_open) / np.linalg.norm(true_open)
        scanned = "-"  # the scanned fixture's open fraction, where the scan resolves it
        if fixture is not None and inside <= 0.05:
            theirs = line_open_fraction(
                fixture.occluded, p0, p1, up, radius, basis, opts.line_clearance,
                samples=opts.line_fixture_samples, seed=opts.seed,
            )  # fmt: skip
            scanned = (
                f"{100 * np.linalg.norm(theirs - true_open) / np.linalg.norm(true_open):.1f} %"
            )
        baff = truth.get("baffles", {})
        ceiling = max(r["ceiling_z"] for r in gt["layout"]["rooms"])
        # The baffles' bottom below the true axis (the generator hangs them from the ceiling).
        depth = baff.get("bottom_below_ceiling", np.nan) - (ceiling - 0.5 * (t0[2] + t1[2]))
        edges = info["trough_edges_m"]
        print(
            f"| {light['name']} | {inside:.2f} | {det.round(1).tolist()} -> {ph.round(1).tolist()} "
            f"| {info['stripe_samples']} ({info['stripe_frames']}) "
            f"| {1000 * radius:.1f} / {1000 * g['radius']:.1f} / {1000 * truth['radius']:.1f} "
            f"| {info['cutoff_deg']} "
            f"| {1000 * edges[0]:.0f}, {1000 * edges[1]:.0f} / {1000 * info['trough_bottom_m']:.0f}"
            f" / {1000 * info['trough_top_m']:.0f} ({1000 * baff.get('half_gap', np.nan):.0f} / "
            f"{1000 * depth:.0f}) | {100 * l2:.1f} % / {scanned} | {secs:.1f} |"
        )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scans", nargs="+", type=Path)
    args = ap.parse_args(argv)
    for scan in args.scans:
        bench_scan(scan)
    return 0


if __name__ == "__main__":
    sys.exit(main())
