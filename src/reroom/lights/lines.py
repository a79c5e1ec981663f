"""Line lights seen in pieces: join collinear pieces into one tube."""

from __future__ import annotations

import numpy as np

from reroom.lights.candidates import Component
from reroom.lights.decide import make_light, radiance_text
from reroom.lights.lightset import Light, Rejected

__all__ = ["absorb_pieces", "merge_lines"]


def merge_lines(lines: list[tuple[Light, np.ndarray]]) -> list[tuple[Light, np.ndarray]]:
    """Join collinear line-light pieces (a tube seen in parts) into one light.

    Two pieces join when their axes are parallel (within ~8 degrees), each one's
    middle lies within 5 cm of the other's axis, and the gap between them is under
    half a metre.
    """
    out = list(lines)
    merged = True
    while merged:
        merged = False
        for i in range(len(out)):
            for j in range(i + 1, len(out)):
                joined = _join(out[i], out[j])
                if joined is not None:
                    out[i] = joined
                    out.pop(j)
                    merged = True
                    break
            if merged:
                break
    return out


def absorb_pieces(
    lines: list[tuple[Light, np.ndarray]],
    small: list[tuple[Rejected, Component, dict]],
    up: np.ndarray,
    rejected: list[Rejected],
) -> list[tuple[Light, np.ndarray]]:
    """Join small components near the ceiling that continue a line light (a tube seen in
    parts, some under ``min_vertices``); their rejection becomes "joined to the line"."""
    out = list(lines)
    for rej, comp, ev in small:
        piece = (make_light("line", comp, ev, up, ""), comp.vertices)
        for i, line in enumerate(out):
            joined = _join(line, piece)
            if joined is not None:
                out[i] = joined
                rejected.remove(rej)
                break
    return out


def _join(a: tuple[Light, np.ndarray], b: tuple[Light, np.ndarray]) -> tuple | None:
    ga, gb = a[0].geometry, b[0].geometry
    a0, a1 = np.asarray(ga["p0"], float), np.asarray(ga["p1"], float)
    b0, b1 = np.asarray(gb["p0"], float), np.asarray(gb["p1"], float)
    da = (a1 - a0) / max(np.linalg.norm(a1 - a0), 1e-12)
    db = (b1 - b0) / max(np.linalg.norm(b1 - b0), 1e-12)
    if abs(da @ db) < 0.99:
        return None
    mid_b = (b0 + b1) / 2
    off = mid_b - a0
    if np.linalg.norm(off - (off @ da) * da) > 0.05:
        return None
    ta = np.array([0.0, (a1 - a0) @ da])
    tb = np.sort([(b0 - a0) @ da, (b1 - a0) @ da])
    gap = max(tb[0] - ta[1], ta[0] - tb[1])
    if gap > 0.5:
        return None
    lo, hi = min(ta[0], tb[0]), max(ta[1], tb[1])
    ea, eb = a[0].evidence, b[0].evidence
    n = ea["vertices"] + eb["vertices"]
    lum = (ea["mean_luminance"] * ea["vertices"] + eb["mean_luminance"] * eb["vertices"]) / n
    radius = (ga["radius"] * ea["vertices"] + gb["radius"] * eb["vertices"]) / n
    geometry = {**ga, "p0": a0 + lo * da, "p1": a0 + hi * da, "radius": radius}
    pieces = ea.get("pieces", 1) + eb.get("pieces", 1)
    evidence = {**ea, "vertices": n, "mean_luminance": lum, "pieces": pieces}
    evidence["frames_seeing"] = max(ea.get("frames_seeing", 0), eb.get("frames_seeing", 0))
    evidence["frames_bright"] = max(ea.get("frames_bright", 0), eb.get("frames_bright", 0))
    evidence["size_m"] = [hi - lo, 2 * radius]
    evidence["centroid"] = a0 + (lo + hi) / 2 * da
    reason = (
        f"kept: line light, {hi - lo:.2f} m long ({pieces} collinear pieces joined, "
        f"gap {max(gap, 0.0):.2f} m), {radiance_text(evidence)}"
    )
    light = Light("", "line", "detected", geometry, evidence, reason)
    return light, np.concatenate([a[1], b[1]])
