"""A lamp's ceiling pool and the bulb placed from its edge (``reroom lights``), per scan.

Usage::

    python benchmarks/bench_pool_edge.py SCAN [SCAN ...] [--factors 3,2] [--steps 0.03,0.04,0.05]

Each ``SCAN`` needs ``hdr/`` and ``layout/`` (a ``reroom run`` folder will do). For each
pool factor (``LightsOptions.pool_factor``) it runs :func:`reroom.lights.detect_lights`
and prints the lights found (name and type: does the factor change the set?) and every
point light placed under a ceiling pool: its position, whether the place was measured
from the pool's edge (``height_from``) or is a guess, and the edge's evidence (opening
radius ``R``, edge radius ``rho``, sectors that agree). For the pools the default factor
measured, :func:`reroom.lights.pools.bulb_from_pool_edge` is run again on the same
inputs with other radial steps, and the rim's two radii are printed (the fitted circle's
and the inner ring's, the 10th percentile of the rim's distances from the axis: the one
used on a thin rim).

Where the scan has ``ground_truth/`` (evaluation only; detection never reads it), each
true point light gets the ceiling's luminance within 0.4 m of its vertical over the
observed ceiling's median (the pool's contrast against the factor) and the distance of
the nearest detected point light from it. Session 25 (docs/benchmarks.md, docs/lights.md).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

import reroom.lights.pools as pools
from reroom.io.mesh import read_ply
from reroom.layout.labels import CEILING
from reroom.lights import LightsOptions, detect_lights
from reroom.lights.pools import fit_circle

LUMA = np.array([0.2126, 0.7152, 0.0722])


def _detect(scan: Path, factor: float) -> tuple[list, list[tuple]]:
    """The lights found with ``factor``, and the inputs of every pool-edge measurement."""
    calls: list[tuple] = []
    original = pools.bulb_from_pool_edge

    def spy(ceiling, luminance, body, top, ceiling_z, **kw):
        calls.append((ceiling, luminance, body, top, ceiling_z))
        return original(ceiling, luminance, body, top, ceiling_z, **kw)

    pools.bulb_from_pool_edge = spy
    try:
        found = detect_lights(scan, options=LightsOptions(pool_factor=factor)).lights
    finally:
        pools.bulb_from_pool_edge = original
    return found, calls


def _pool_contrast(scan: Path) -> list[tuple[str, float, np.ndarray]]:
    """Per true point light: the ceiling's luminance near its vertical over the median."""
    gt = scan / "ground_truth" / "ground_truth.json"
    if not gt.is_file():
        return []
    mesh = read_ply(scan / "hdr" / "hdr_mesh.ply")
    v = np.asarray(mesh.vertices)
    lum = np.asarray(mesh.vertex_attributes["radiance"]) @ LUMA
    observed = np.asarray(mesh.vertex_attributes["observed"]).astype(bool)
    labels = np.asarray(read_ply(scan / "layout" / "layout_labels.ply").vertex_attributes["label"])
    ceiling = observed & (labels == CEILING)
    median = float(np.median(lum[ceiling]))
    out = []
    for light in json.loads(gt.read_text())["lights"]:
        if "position" not in light:
            continue
        p = np.asarray(light["position"], float)
        near = ceiling & (np.linalg.norm(v[:, :2] - p[:2], axis=1) < 0.4)
        ratio = float(np.median(lum[near]) / median) if near.any() else float("nan")
        out.append((light["name"], ratio, p))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scans", type=Path, nargs="+")
    ap.add_argument("--factors", default="3,2", help="pool factors to compare")
    ap.add_argument("--steps", default="0.03,0.04,0.05", help="radial steps to re-measure with")
    args = ap.parse_args(argv)
    factors = [float(x) for x in args.factors.split(",")]
    steps = [float(x) for x in args.steps.split(",")]
    default = LightsOptions().pool_factor
    for scan in args.scans:
        print(f"\n## {scan}\n")
        truth = _pool_contrast(scan)
        for name, ratio, p in truth:
            print(f"true point light {name} at {np.round(p, 3).tolist()}: ceiling within 0.4 m "
                  f"of its vertical {ratio:.2f}x the ceiling's median")  # fmt: skip
        print(
            "\n| factor | lights | point light | position | placed from | R (m) | rho (m) | sectors | off the truth (m) |"
        )
        print("|---|---|---|---|---|---|---|---|---|")
        kept_calls: list[tuple] = []
        for factor in factors:
            found, calls = _detect(scan, factor)
            if factor == default:
                kept_calls = calls
            names = ", ".join(f"{x.name}:{x.type}" for x in found)
            points = [x for x in found if x.type == "point"]
            if not points:
                print(f"| {factor:g} | {names} | - | | | | | | |")
            for x in points:
                pos = np.asarray(x.geometry["position"], float)
                ev = x.evidence
                off = min((float(np.linalg.norm(pos - p)) for _, _, p in truth), default=np.nan)
                print(
                    f"| {factor:g} | {names} | {x.name} | {np.round(pos, 4).tolist()} | "
                    f"{ev.get('height_from', 'a guess under the top')} | "
                    f"{ev.get('opening_radius_m', float('nan')):.4f} | "
                    f"{ev.get('pool_edge_radius_m', float('nan')):.3f} | "
                    f"{ev.get('edge_sectors', '-')} | {off:.4f} |"
                )
        for ceiling, luminance, body, top, ceiling_z in kept_calls:
            rim = body[body[:, 2] > top - 0.04]
            axis, r_circle = fit_circle(rim[:, :2])
            d = np.linalg.norm(rim[:, :2] - axis, axis=1)
            p10, p90 = np.percentile(d, [10, 90])
            print(
                f"\npool under the object topping at {top:.3f} m: rim circle {r_circle:.4f} m, "
                f"inner ring {p10:.4f} m (10th-90th percentile spread {p90 - p10:.4f} m)"
            )
            for step in steps:
                out = pools.bulb_from_pool_edge(ceiling, luminance, body, top, ceiling_z, step=step)
                where = (
                    "no edge"
                    if out is None
                    else f"bulb at z {out['position'][2]:.4f} m, rho {out['pool_edge_radius_m']:.3f} m, "
                    f"{out['edge_sectors']} sectors"
                )
                print(f"  step {step:.3f} m: {where}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
