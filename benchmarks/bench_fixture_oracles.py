"""What the fixtures behind the line and point shape priors cost, against the truth.

Usage::

    python benchmarks/bench_fixture_oracles.py trough-variants SCAN
    python benchmarks/bench_fixture_oracles.py true-fixture SCAN --work DIR
    python benchmarks/bench_fixture_oracles.py true-depth SCAN --work DIR
    python benchmarks/bench_fixture_oracles.py shade-open SCAN [--light point0]
    python benchmarks/bench_fixture_oracles.py shade-frustum SCAN --work DIR --bottom Z,R
    python benchmarks/bench_fixture_oracles.py shade-forced SCAN --work DIR --light NAME \
        [--invert '{"window_view_hdri": "/tmp/view.exr"}']

``SCAN`` is a synthetic scan with ``hdr/``, ``layout/``, ``lights/`` and
``ground_truth/``; the truth is read here (evaluation), never by the pipeline.

* ``trough-variants``: the photos' trough (:mod:`reroom.invert.line_photos`) of the
  scan's line light, its open fraction's relative L2 against the true fixture's, as
  built (the scanned block's underside and top, the photos' radius) and with the true
  baffle depth, a top level with the bottom, the true radius, all three, and the true
  trough.
* ``true-fixture``: ``reroom invert`` with the true fixture's parts in place of the
  photos' trough (the photos' axis and radius kept), evaluated: what a perfect trough
  would give the tube.
* ``true-depth``: ``reroom invert`` with the photos' trough at the true baffles' depth
  and half gap (its axis, radius and top the photos'), evaluated: what the two numbers
  :func:`reroom.invert.line_photos.trough_edges` fits would give if they were exact.
* ``shade-open``: the scanned shade's open fraction (:mod:`reroom.invert.point_fixture`)
  of a point light against the true fixture's, bin by bin.
* ``shade-frustum``: ``reroom invert`` with the shaded bulb's prior taken from a
  frustum, its top at the localize evidence's object top and opening radius, its
  bottom at ``Z`` metres with radius ``R`` (e.g. read off a fused shell), evaluated.
* ``shade-forced``: ``reroom invert`` with the shaded bulb's prior given to the point
  light ``NAME`` as if the lights stage had placed it in a shade (its evidence's
  ``height_from`` read as ``"pool edge"``), evaluated: does the prior help a bulb
  ``reroom localize`` found on its own (session 23, `box_points`'s floor lamp)?
  ``--invert JSON`` sets other ``InvertOptions`` for that run (e.g. a captured window
  view, to see the prior without the window's cell error).

The two ``reroom invert`` variants replace one private step of
:mod:`reroom.invert.pipeline` for the run (``_photo_trough``, ``_point_open_shape``) and
write to ``DIR/invert`` through a linked copy of the scan.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

import reroom.invert.pipeline as pipeline
from reroom.invert.basis import InclinationBasis, LineBasis
from reroom.invert.evaluate import (
    _fixture_caster,
    evaluate_invert,
    true_line_profile,
    true_point_profile,
)
from reroom.invert.line_fixture import line_open_fraction, scan_fixture_caster
from reroom.invert.line_photos import (
    caster_without_fixture,
    fixture_extent,
    observe_tube,
    trough_edges,
    trough_fixture,
)
from reroom.invert.point_fixture import point_open_fraction
from reroom.rays import RayCaster
from reroom.scan import load_scan


def _lights(scan: Path) -> list[dict]:
    return json.loads((scan / "lights" / "lights.json").read_text())["lights"]


def _geometry(light: dict) -> dict:
    return light.get("geometry", light)


def _true(scan: Path, kind: str) -> dict:
    gt = json.loads((scan / "ground_truth" / "ground_truth.json").read_text())
    return [x for x in gt["lights"] if x["type"] == kind][0]


def _linked_copy(scan: Path, work: Path) -> Path:
    """``work`` holding links to everything of ``scan`` that comes before ``invert/``."""
    from reroom.invert.incomplete import DERIVED_OUTPUTS

    work.mkdir(parents=True, exist_ok=True)
    for child in scan.iterdir():
        dst = work / child.name
        if child.name not in DERIVED_OUTPUTS and not dst.exists():
            dst.symlink_to(child.resolve())
    return work


def _report(scan: Path, invert_dir: Path) -> None:
    rep = evaluate_invert(scan, invert_dir)

    def pct(v) -> str:
        return "/".join(f"{100 * x:+.1f}" for x in v) + " %"

    for name, c in rep["clusters"].items():
        print(f"| {name} | {pct(c['relative_error'])} |")
    for light in rep["lights"]:
        eff = light.get("effective_power_relative_error")
        l2 = light.get("distribution_relative_l2")
        print(
            f"| {light['name']} | power {pct(light['power_relative_error'])} | leaving its "
            f"fitting {pct(eff) if eff else '-'} | L2 {'-' if l2 is None else f'{100 * l2:.1f} %'} |"
        )


def trough_variants(scan: Path) -> None:
    sc = load_scan(scan, check_images=False)
    mesh = sc.mesh
    light = _geometry([x for x in _lights(scan) if x["type"] == "line"][0])
    p0, p1 = np.asarray(light["p0"], float), np.asarray(light["p1"], float)
    up = np.asarray(light["d_perp"], float)
    others = caster_without_fixture(mesh.vertices, mesh.faces, p0, p1)
    tube = observe_tube(sc.frames, lambda f: f.load_image(), others, p0, p1, up)
    truth = _true(scan, "line")
    opts = pipeline.InvertOptions()
    basis = LineBasis(opts.bins, opts.line_phi_bins, opts.line_phi_fold)
    prof = true_line_profile(
        truth, scan / "ground_truth" / "scene", up, bins=opts.bins,
        phi_bins=opts.line_phi_bins, fold=opts.line_phi_fold,
    )  # fmt: skip
    true_open = prof[:, 1] / (2 * truth["radius"] * truth["radiance"][1])
    bottom, top = fixture_extent(mesh.vertices, tube.p0, tube.p1, up, tube.radius)
    baffles = truth["baffles"]
    ceiling = max(r["ceiling_z"] for r in json.loads(
        (scan / "ground_truth" / "ground_truth.json").read_text())["layout"]["rooms"])  # fmt: skip
    axis_z = 0.5 * (truth["p0"][2] + truth["p1"][2])
    true_bottom = baffles["bottom_below_ceiling"] - (ceiling - axis_z)
    print(f"photos: radius {1000 * tube.radius:.1f} mm, scanned underside {1000 * bottom:.0f} mm, "
          f"top {1000 * top:.0f} mm; truth: radius {1000 * truth['radius']:.1f} mm, baffles' "
          f"bottom {1000 * true_bottom:.0f} mm, half gap {1000 * baffles['half_gap']:.0f} mm\n")  # fmt: skip
    print("| trough | edges (mm) | bottom (mm) | open fraction L2 |\n|---|---|---|---|")

    def row(name: str, radius: float, b: float, t: float, edges=None, **fit) -> None:
        if edges is None:
            # held=True: the depth given is kept (the pipeline before session 27).
            held = fit.pop("held", True)
            trough = trough_edges(tube, b, radius, **({"bottom_sigma": 1e-9} if held else fit))
            edges, b = trough.edges, trough.bottom
        c = trough_fixture(tube.p0, tube.p1, up, edges, b, t)
        o = line_open_fraction(c.occluded, tube.p0, tube.p1, up, radius, basis, opts.line_clearance)
        l2 = np.linalg.norm(o - true_open) / np.linalg.norm(true_open)
        print(
            f"| {name} | {1000 * edges[0]:.0f}, {1000 * edges[1]:.0f} | {1000 * b:.0f} "
            f"| {100 * l2:.1f} % |"
        )

    r_true = float(truth["radius"])
    # The true housing's underside: the generator puts it 5 cm above the axis.
    housing = 0.05
    row("as built: depth fitted to the part-hidden views", tube.radius, bottom, top, held=False)
    for px in (0.25, 1.0):
        row(f"the same, widths good to {px} px", tube.radius, bottom, top, held=False,
            width_sigma_px=px)  # fmt: skip
    row("scanned depth held (before session 27)", tube.radius, bottom, top)
    row("true baffle depth", tube.radius, true_bottom, top)
    row("top level with the bottom", tube.radius, bottom, bottom)
    row("true radius", r_true, bottom, top)
    row("true depth, housing and radius", r_true, true_bottom, housing)
    half = float(baffles["half_gap"])
    row("the true trough", r_true, true_bottom, housing, (half, half))


def true_fixture(scan: Path, work: Path) -> None:
    truth = _true(scan, "line")
    own = pipeline._photo_trough

    def with_true_parts(scan_dir, mesh, name, geometry, options, notes, caster=None):
        found = own(scan_dir, mesh, name, geometry, options, notes, caster)
        if found is None:
            return None
        _, g, info = found
        p0, p1, r = np.asarray(truth["p0"]), np.asarray(truth["p1"]), float(truth["radius"])
        caster = _fixture_caster(
            scan / "ground_truth" / "scene", np.minimum(p0, p1) - r, np.maximum(p0, p1) + r,
            {truth["part"]}, options.line_clearance,
        )  # fmt: skip
        return caster, g, info

    pipeline._photo_trough = with_true_parts
    run = _linked_copy(scan, work)
    pipeline.run_invert(run, run / "invert")
    _report(run, run / "invert")


def true_depth(scan: Path, work: Path) -> None:
    """``reroom invert`` with the photos' trough set to the true baffles' depth and half
    gap (its axis, radius and top the photos'): what the trough's two fitted numbers
    would give if they were exact."""
    import reroom.invert.line_photos as line_photos
    from reroom.invert.line_photos import Trough

    truth = _true(scan, "line")
    ceiling = max(r["ceiling_z"] for r in json.loads(
        (scan / "ground_truth" / "ground_truth.json").read_text())["layout"]["rooms"])  # fmt: skip
    axis_z = 0.5 * (truth["p0"][2] + truth["p1"][2])
    depth = truth["baffles"]["bottom_below_ceiling"] - (ceiling - axis_z)
    half = float(truth["baffles"]["half_gap"])
    print(f"true trough: half gap {1000 * half:.0f} mm, depth {1000 * depth:.0f} mm\n")
    line_photos.trough_edges = lambda *a, **k: Trough((half, half), depth, ["truth"], "truth")
    run = _linked_copy(scan, work)
    pipeline.run_invert(run, run / "invert")
    _report(run, run / "invert")


def shade_open(scan: Path, name: str) -> None:
    light = [x for x in _lights(scan) if x["name"] == name][0]
    g = _geometry(light)
    mesh = load_scan(scan, check_images=False).mesh
    pos, axis = np.asarray(g["position"], float), np.asarray(g["axis"], float)
    opts = pipeline.InvertOptions()
    caster = scan_fixture_caster(mesh.vertices, mesh.faces, pos, pos, 0.01, 0.3)
    basis = InclinationBasis(opts.bins)
    ours = point_open_fraction(caster.occluded, pos, axis, basis, opts.point_clearance)
    scene = scan / "ground_truth" / "scene"
    points = [x for x in json.loads((scene / "scene.json").read_text())["lights"]
              if "position" in x]  # fmt: skip
    lamp = min(points, key=lambda x: float(np.linalg.norm(np.asarray(x["position"]) - pos)))
    shaded = true_point_profile(lamp, scene, axis).mean(axis=1)
    bare = true_point_profile(lamp, scene, axis, fixture_radius=0).mean(axis=1)
    true_open = shaded / np.maximum(bare, 1e-12)
    print(f"{name} at {np.round(pos, 4).tolist()}, true {lamp['position']}\n")
    print("| theta | scanned shade | truth |\n|---|---|---|")
    for i, (a, b) in enumerate(zip(ours, true_open, strict=True)):
        if a not in (0.0, 1.0) or b not in (0.0, 1.0):
            print(f"| {(i + 0.5) * 180 / basis.bins:.1f} | {a:.2f} | {b:.2f} |")
    print(
        f"\nrelative L2 {100 * np.linalg.norm(ours - true_open) / np.linalg.norm(true_open):.1f} %"
    )


def shade_frustum(scan: Path, work: Path, z_bottom: float, r_bottom: float) -> None:
    def frustum(mesh, light, basis, options, notes):
        if light.evidence.get("height_from") != "pool edge":
            return None, {}
        p = np.asarray(light.geometry["position"], float)
        z_top = float(light.evidence["object_top_m"])
        r_top = float(light.evidence["opening_radius_m"])
        ang = np.linspace(0, 2 * np.pi, 97)[:-1]

        def ring(z: float, r: float) -> np.ndarray:
            return np.stack(
                [p[0] + r * np.cos(ang), p[1] + r * np.sin(ang), np.full_like(ang, z)], 1
            )

        n = len(ang)
        i = np.arange(n)
        f = np.concatenate([np.stack([i, (i + 1) % n, n + i], 1),
                            np.stack([(i + 1) % n, n + (i + 1) % n, n + i], 1)])  # fmt: skip
        f = np.concatenate([f, f[:, ::-1]])  # two-sided
        c = RayCaster(np.concatenate([ring(z_bottom, r_bottom), ring(z_top, r_top)]), f, eps=1e-6)
        o = point_open_fraction(
            c.occluded, p, light.geometry["axis"], basis, options.point_clearance, seed=options.seed
        )
        print("frustum open fraction:", np.round(o, 2).tolist())
        return o, {"open_fraction": np.round(o, 4).tolist()}

    pipeline._point_open_shape = frustum
    run = _linked_copy(scan, work)
    pipeline.run_invert(run, run / "invert")
    _report(run, run / "invert")


def shade_forced(scan: Path, work: Path, name: str, options: dict | None = None) -> None:
    original = pipeline._point_open_shape

    def forced(mesh, light, basis, options, notes):
        if light.name == name:
            light = dataclasses.replace(
                light, evidence={**light.evidence, "height_from": "pool edge"}
            )
        return original(mesh, light, basis, options, notes)

    pipeline._point_open_shape = forced
    run = _linked_copy(scan, work)
    pipeline.run_invert(run, run / "invert", pipeline.InvertOptions(**(options or {})))
    _report(run, run / "invert")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "what",
        choices=[
            "trough-variants",
            "true-fixture",
            "true-depth",
            "shade-open",
            "shade-frustum",
            "shade-forced",
        ],
    )
    ap.add_argument("scan", type=Path)
    ap.add_argument("--work", type=Path, help="folder of the linked copy (invert variants)")
    ap.add_argument("--light", default="point0")
    ap.add_argument("--bottom", default="", help="Z,R of the frustum's bottom rim (metres)")
    ap.add_argument(
        "--invert",
        default="{}",
        help="shade-forced: InvertOptions overrides as JSON, e.g. "
        '{"window_view_hdri": "/tmp/view.exr"}',
    )
    args = ap.parse_args(argv)
    if (
        args.what in ("true-fixture", "true-depth", "shade-frustum", "shade-forced")
        and args.work is None
    ):
        ap.error(f"{args.what} needs --work DIR")
    if args.what == "trough-variants":
        trough_variants(args.scan)
    elif args.what == "true-fixture":
        true_fixture(args.scan, args.work)
    elif args.what == "true-depth":
        true_depth(args.scan, args.work)
    elif args.what == "shade-open":
        shade_open(args.scan, args.light)
    elif args.what == "shade-forced":
        shade_forced(args.scan, args.work, args.light, json.loads(args.invert))
    else:
        try:
            z, r = (float(x) for x in args.bottom.split(","))
        except ValueError:
            ap.error("--bottom takes Z,R, e.g. 1.34,0.20")
        shade_frustum(args.scan, args.work, z, r)
    return 0


if __name__ == "__main__":
    sys.exit(main())
