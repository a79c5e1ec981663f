"""Line lights seen in pieces: join collinear pieces into one tube."""

from __future__ import annotations

import numpy as np

from reroom.lights.candidates import Component
from reroom.lights.decide import make_light, radiance_text
from reroom.lights.lightset import Light, Rejected

__all__ = ["absorb_pieces", "fixture_from_pieces", "merge_lines"]


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


def fixture_from_pieces(
    pieces: list[tuple[Rejected, Component, dict]],
    lines: list[tuple[Light, np.ndarray]],
    up: np.ndarray,
    rejected: list[Rejected],
    min_vertices: int,
    min_length: float,
    width: float = 0.15,
) -> list[tuple[Light, np.ndarray]]:
    """New line lights from small, thin pieces near the ceiling that lie side by side.

    On a scan of few, small frames a tube between baffles is under two pixels wide:
    only part of it comes out bright, and the baffles' inner faces, lit by it, come
    out as separate strips a few centimetres to either side (`lshape`'s 24-frame
    scan: a 40-vertex piece of the 1.2 m tube and two lit faces of 14 and 6 vertices,
    6-7 cm off its axis, each under ``min_vertices``). Pieces that are each line-shaped
    (the caller's test: every rule but the size), parallel (within ~14 degrees), within
    ``width`` of each other across their axes and at most half a metre apart along
    them form one fixture. A fixture becomes a line light when it has, together,
    ``min_vertices`` vertices and ``min_length`` of length, and one of its pieces faces
    down (the tube itself, seen from below: lit faces alone may be a slot lit from
    elsewhere). The tube's axis is that of its downward-facing pieces, its ends the
    fixture's (a baffle is lit where the tube is). Fixtures beside a line light found
    already are that light's fitting and are left rejected.
    """
    n = len(pieces)
    geo = [make_light("line", comp, ev, up, "").geometry for _, comp, ev in pieces]
    parent = list(range(n))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i in range(n):
        for j in range(i + 1, n):
            if _side_by_side(geo[i], geo[j], width):
                parent[find(i)] = find(j)
    groups: dict[int, list[int]] = {}
    for i in range(n):
        groups.setdefault(find(i), []).append(i)
    out: list[tuple[Light, np.ndarray]] = []
    for members in groups.values():
        down = [i for i in members if pieces[i][2]["normal_up"] < -0.5]
        n_vert = sum(pieces[i][2]["vertices"] for i in members)
        if not down or n_vert < min_vertices:
            continue
        if any(_side_by_side(x.geometry, geo[i], width) for x, _ in lines for i in members):
            continue
        light = _fixture_light([pieces[i] for i in members], [geo[i] for i in members], up)
        if light.evidence["size_m"][0] < min_length:
            continue
        for i in members:
            rejected.remove(pieces[i][0])
        out.append((light, np.concatenate([pieces[i][1].vertices for i in members])))
    return out


class _Pair:
    """How segment ``b`` lies against segment ``a``: the cosine of the angle between
    them, the distance of ``b``'s middle from ``a``'s axis, ``b``'s ends along that axis
    (``a`` spans ``0..length``) and the gap between the two along it (< 0: overlap)."""

    def __init__(self, ga: dict, gb: dict) -> None:
        self.a0 = np.asarray(ga["p0"], float)
        a1 = np.asarray(ga["p1"], float)
        b0, b1 = np.asarray(gb["p0"], float), np.asarray(gb["p1"], float)
        self.da = (a1 - self.a0) / max(np.linalg.norm(a1 - self.a0), 1e-12)
        db = (b1 - b0) / max(np.linalg.norm(b1 - b0), 1e-12)
        self.cos = abs(float(self.da @ db))
        off = (b0 + b1) / 2 - self.a0
        self.across = float(np.linalg.norm(off - (off @ self.da) * self.da))
        self.length = float((a1 - self.a0) @ self.da)
        self.tb = np.sort([(b0 - self.a0) @ self.da, (b1 - self.a0) @ self.da])
        self.gap = float(max(self.tb[0] - self.length, -self.tb[1]))


def _side_by_side(ga: dict, gb: dict, width: float) -> bool:
    """Two segments parallel within ~14 degrees, within ``width`` across and at most
    0.5 m apart along their axes."""
    pair = _Pair(ga, gb)
    return pair.cos >= 0.97 and pair.across <= width and pair.gap <= 0.5


def _fixture_light(
    pieces: list[tuple[Rejected, Component, dict]], geo: list[dict], up: np.ndarray
) -> Light:
    """The line light of one fixture's pieces: the axis through its downward-facing
    pieces (vertex-weighted) along the largest one's direction, the radius from them,
    the ends from all the pieces."""
    w = np.array([ev["vertices"] if ev["normal_up"] < -0.5 else 0 for _, _, ev in pieces], float)
    lead = int(np.argmax(w))
    # The direction of the tube itself (its largest downward-facing piece): the lit
    # faces are longer but a few centimetres tall, and on `lshape24` their direction
    # tilted the tube's ends 2 cm apart in height where the tube's own piece gives 0.3 mm.
    d = np.asarray(geo[lead]["p1"], float) - np.asarray(geo[lead]["p0"], float)
    d /= max(np.linalg.norm(d), 1e-12)
    mids = np.array([(np.asarray(g["p0"], float) + np.asarray(g["p1"], float)) / 2 for g in geo])
    middle = (w[:, None] * mids).sum(0) / w.sum()
    ends = np.array([[(np.asarray(g[k], float) - middle) @ d for k in ("p0", "p1")] for g in geo])
    lo, hi = float(ends.min()), float(ends.max())
    radius = float((w * [g["radius"] for g in geo]).sum() / w.sum())
    perp = up - (up @ d) * d
    perp /= max(np.linalg.norm(perp), 1e-12)
    evs = [ev for _, _, ev in pieces]
    evidence = _merged_evidence(
        [evs[lead], *evs[:lead], *evs[lead + 1 :]], len(pieces), [hi - lo, 2 * radius],
        middle + (lo + hi) / 2 * d,
    )  # fmt: skip
    geometry = {"p0": middle + lo * d, "p1": middle + hi * d, "d_perp": perp, "radius": radius}
    n_down = int((w > 0).sum())
    reason = (
        f"kept: line light, {hi - lo:.2f} m long, from {len(pieces)} pieces side by side, "
        f"each under the size limit ({n_down} facing down: the tube; the others lit faces "
        f"of its fitting), {radiance_text(evs[lead])}"
    )
    return Light("", "line", "detected", geometry, evidence, reason)


def _merged_evidence(evs: list[dict], pieces: int, size: list, centroid: np.ndarray) -> dict:
    """The evidence of a line joined from pieces: the first piece's, with the vertices
    summed, the luminance their weighted mean and the most frames any piece had."""
    n = int(sum(ev["vertices"] for ev in evs))
    return {
        **evs[0],
        "vertices": n,
        "mean_luminance": float(sum(ev["mean_luminance"] * ev["vertices"] for ev in evs) / n),
        "pieces": pieces,
        "size_m": size,
        "centroid": centroid,
        "frames_seeing": max(ev.get("frames_seeing", 0) for ev in evs),
        "frames_bright": max(ev.get("frames_bright", 0) for ev in evs),
    }


def _join(a: tuple[Light, np.ndarray], b: tuple[Light, np.ndarray]) -> tuple | None:
    ga, gb = a[0].geometry, b[0].geometry
    pair = _Pair(ga, gb)
    if pair.cos < 0.99 or pair.across > 0.05 or pair.gap > 0.5:
        return None
    a0, da, gap = pair.a0, pair.da, pair.gap
    lo, hi = min(0.0, pair.tb[0]), max(pair.length, pair.tb[1])
    ea, eb = a[0].evidence, b[0].evidence
    n = ea["vertices"] + eb["vertices"]
    radius = (ga["radius"] * ea["vertices"] + gb["radius"] * eb["vertices"]) / n
    geometry = {**ga, "p0": a0 + lo * da, "p1": a0 + hi * da, "radius": radius}
    pieces = ea.get("pieces", 1) + eb.get("pieces", 1)
    evidence = _merged_evidence([ea, eb], pieces, [hi - lo, 2 * radius], a0 + (lo + hi) / 2 * da)
    reason = (
        f"kept: line light, {hi - lo:.2f} m long ({pieces} collinear pieces joined, "
        f"gap {max(gap, 0.0):.2f} m), {radiance_text(evidence)}"
    )
    light = Light("", "line", "detected", geometry, evidence, reason)
    return light, np.concatenate([a[1], b[1]])
