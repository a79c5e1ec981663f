"""A light's colour from the edge of its clipped image in the photos, against the truth.

Usage::

    python benchmarks/bench_emitter_color.py SCAN [SCAN ...]

``SCAN`` is a synthetic scan (or a ``reroom run`` folder of one) with ``hdr/``,
``lights/lights.json`` and ``ground_truth/``. For each line and area light it runs what
``reroom invert`` runs with ``InvertOptions.photo_color`` > 0
(:mod:`reroom.invert.emitter_color`, via the pipeline's ``_line_photo_color`` and
``_area_photo_color``), on the geometry the solve used (``invert/scene.json`` where the
scan has one: a fused scan's tube is then the photos' axis; else ``lights.json``), and
prints, next to the truth (read here, never by the pipeline):

* the colour in the HDR mesh's units, taken to the truth's by the HDR's per-channel
  scale ``k`` (the median over the frames of the true exposure over the HDR stage's;
  ``reroom.invert.evaluate``'s ``radiance_scale``, a ratio of sums over the clustered
  vertices, is within 2-3 % of it): what the solve gets;
* the same measured with the frames' *true* exposures (``ground_truth.json``): the
  method's own error, without the HDR stage's;
* the true colour (the emitter's radiance, mean 1), the errors per channel, the bootstrap
  spread, the edge pixels and frames used, whether the pipeline would use the colour
  (its spread gate, ``MAX_PHOTO_COLOR_SPREAD``), and the seconds it took.

``--per-frame`` also prints each frame's edge colour (HDR units over ``k``, mean 1) and
whether the frames' vote (:func:`reroom.invert.emitter_color.consistent_frames`) keeps it.

``--excess-over-background X`` and ``--edge-px P`` measure with other settings of
:func:`reroom.invert.emitter_color.emitter_color` than its defaults (1 and 1.5).
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import json
import sys
import time
from pathlib import Path
from unittest import mock

import numpy as np

import reroom.invert.emitter_color as emitter_module
import reroom.invert.photos as photos
from reroom.invert import pipeline
from reroom.rays import RayCaster
from reroom.scan import load_scan


def _radiance_scale(scan_dir: Path, true_scale: dict[int, np.ndarray]) -> np.ndarray:
    """``k``: the HDR stage's radiance over the truth's per channel, the median over the
    frames of the true exposure over the HDR's (its units are its exposures')."""
    from reroom.invert.photos import frame_scale, read_frame_scales

    _, scales = read_frame_scales(scan_dir)
    ratios = [true_scale[i] / s for i in true_scale if (s := frame_scale(scales, i)) is not None]
    return np.median(np.asarray(ratios), axis=0)


def _geometries(scan_dir: Path) -> list[tuple[str, str, dict]]:
    scene = scan_dir / "invert" / "scene.json"
    src = scene if scene.is_file() else scan_dir / "lights" / "lights.json"
    doc = json.loads(src.read_text())
    out = []
    for x in doc["lights"]:
        if x["type"] in ("line", "area"):
            g = x.get("geometry", x)
            out.append((x["name"], x["type"], g))
    return out


def _nearest_truth(kind: str, g: dict, truth: list[dict]) -> dict | None:
    here = np.asarray(g["centroid"] if kind == "area" else 0.5 * (np.add(g["p0"], g["p1"])), float)
    best, dist = None, np.inf
    for t in truth:
        if t["type"] != kind or "radiance" not in t:
            continue
        c = (
            np.mean([t["p0"], t["p1"]], axis=0)
            if kind == "line"
            else np.mean(np.asarray(t["corners"], float), axis=0)
        )
        d = float(np.linalg.norm(c - here))
        if d < dist:
            best, dist = t, d
    return best


def _pct(a: np.ndarray) -> str:
    return "/".join(f"{100 * v:+.1f}" for v in a) + " %"


def bench_scan(scan_dir: Path, measure: dict | None = None, per_frame: bool = False) -> None:
    gt = json.loads((scan_dir / "ground_truth" / "ground_truth.json").read_text())
    o = gt.get("options", {})
    scan = load_scan(scan_dir, check_images=False)
    mesh = scan.mesh
    caster = RayCaster(mesh.vertices, mesh.faces)
    true_scale = {f["index"]: np.asarray(f["scale"], float) for f in gt["frames"]}
    k = _radiance_scale(scan_dir, true_scale)
    print(f"\n### {scan_dir} ({o.get('mesh')} mesh, {len(scan.frames)} frames "
          f"{o.get('width')}x{o.get('height')}, {o.get('spp')} spp; k = "
          f"{np.round(k / k.mean(), 4).tolist()})\n")  # fmt: skip
    print(
        "| light | truth | photos (HDR, to the truth's units) | error | with true exposures "
        "| error | spread | edge pixels / frames (dropped) | used by the solve | s |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    frame_rows: list[str] = []
    for name, kind, g in _geometries(scan_dir):
        truth = _nearest_truth(kind, g, gt["lights"])
        if truth is None:
            continue
        rad = np.asarray(truth["radiance"], float)
        true = rad / rad.mean()
        rows = []
        edges: list[tuple[np.ndarray, int]] = []  # each frame's summed excess, HDR units
        t0 = time.perf_counter()
        for scales in (None, true_scale):
            notes: list[str] = []
            with contextlib.ExitStack() as stack:
                if per_frame and scales is None:
                    stack.enter_context(
                        mock.patch.object(emitter_module, "_frame_edge", _recording(edges))
                    )
                # every measurement, also one the pipeline's spread gate would not use
                stack.enter_context(
                    mock.patch.object(pipeline, "_checked_photo_color", lambda _n, f, _notes: f)
                )
                if measure:  # the measurement's settings, as given on the command line
                    stack.enter_context(
                        mock.patch.object(
                            emitter_module,
                            "emitter_color",
                            functools.partial(emitter_module.emitter_color, **measure),
                        )
                    )
                if scales is not None:  # the true exposures in place of the HDR stage's
                    stack.enter_context(
                        mock.patch.object(photos, "frame_scale", lambda _s, i: true_scale.get(i))
                    )
                if kind == "line":
                    found = pipeline._line_photo_color(scan_dir, mesh, name, g, notes)
                else:
                    found = pipeline._area_photo_color(scan_dir, caster, name, g, notes)
            rows.append((found, notes))
        seconds = (time.perf_counter() - t0) / 2
        (hdr, hdr_notes), (tr, _) = rows
        if hdr is None:
            why = "; ".join(hdr_notes) or "too few edge pixels or frames"
            print(f"| {name} | {truth['name']} | none ({why}) | | | | | | | |")
            continue
        used = pipeline._checked_photo_color(name, hdr, []) is not None
        c_hdr = hdr.color / k
        c_hdr = c_hdr / c_hdr.mean()
        c_tr = None if tr is None else tr.color
        print(
            f"| {name} | {np.round(true, 3).tolist()} | {np.round(c_hdr, 3).tolist()} | "
            f"{_pct(c_hdr / true - 1)} | "
            f"{'-' if c_tr is None else np.round(c_tr, 3).tolist()} | "
            f"{'-' if c_tr is None else _pct(c_tr / true - 1)} | "
            f"{np.round(hdr.spread, 3).tolist()} | {hdr.pixels} / {hdr.frames} ({hdr.dropped}) | "
            f"{'yes' if used else 'no (spread)'} | {seconds:.1f} |"
        )
        if per_frame and edges:
            sums = np.array([e for e, _ in edges])
            pixels = np.array([n for _, n in edges])
            keep = emitter_module.consistent_frames(sums, pixels)
            for (e, n), kept in zip(edges, keep, strict=True):
                c = e / k
                c = c / c.mean() if c.mean() > 0 else c
                frame_rows.append(
                    f"| {name} | {n} | {np.round(c, 3).tolist()} | {'yes' if kept else 'no'} |"
                )
    if frame_rows:
        print("\nEach frame's edge colour (the truth's units, mean 1), and whether the frames'")
        print("vote keeps it (before the two-thirds rule):\n")
        print("| light | edge pixels | colour | kept |")
        print("|---|---|---|---|")
        print("\n".join(frame_rows))


def _recording(edges: list):
    """``emitter_color``'s per-frame edge sum, recording what each frame gave."""
    original = emitter_module._frame_edge

    def wrapped(*args, **kwargs):
        total, count = original(*args, **kwargs)
        if count:
            edges.append((np.asarray(total, float), int(count)))
        return total, count

    return wrapped


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scans", nargs="+", type=Path)
    ap.add_argument("--excess-over-background", type=float, default=None)
    ap.add_argument("--edge-px", type=float, default=None)
    ap.add_argument(
        "--per-frame", action="store_true", help="each frame's edge colour and the frames' vote"
    )
    args = ap.parse_args(argv)
    measure = {
        k: v
        for k, v in (
            ("excess_over_background", args.excess_over_background),
            ("edge_px", args.edge_px),
        )
        if v is not None
    }
    for s in args.scans:
        bench_scan(s, measure, args.per_frame)
    return 0


if __name__ == "__main__":
    sys.exit(main())
