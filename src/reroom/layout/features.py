"""Architectural features on the walls: baseboards, doors, windows, passages (thesis §4.3).

Everything here works on :class:`~reroom.layout.wallgrid.WallGrids`: per wall, a grid of
cells ``(s, z)`` holding how often the frames saw the cell, its horizontal and vertical
edge responses, and where rays crossing the wall plane there ended.

* **Baseboard** (§4.3.2): ``B(y) = sum_x F(x, y) / N(x, y) / sum_x nonzero(N(x, y))``
  over all walls; its first clear local maximum above the floor edge is the baseboard's
  top. (The thesis takes the first local maximum; in every scan we measured, the first
  one is the wall-floor junction itself, 0-3 cm up, so maxima that low are skipped.)
* **Doors** (§4.3.3): vertical edge segments (scanlines of ``F_v / N`` allowed to run
  through unobserved cells) that start at the floor and end at the same height above
  1.5 m, joined by a horizontal edge segment at that height; overlapping candidates keep
  the widest.
* **Windows and passages** (§4.3.4): rectangles where the rays crossing the wall went
  far beyond it (a hole in the mesh, or a recess deeper than a reveal), plus, when an
  HDR radiance is given, where the wall's vertices are far brighter than the walls.
  Openings that reach the floor and are door-high are passages (open doorways).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy import ndimage

from reroom.layout.wallgrid import WallGrids


@dataclass
class Opening:
    """A door, window or passage on one wall.

    Attributes
    ----------
    kind:
        ``"door"``, ``"window"`` or ``"passage"``.
    wall:
        Index of the wall (over all rooms, in layout order).
    s0, s1:
        Extent along the wall, metres of arc length from the wall's start.
    z0, z1:
        Bottom and top heights (aligned frame, like the floor height).
    depth:
        How far the opening's surface lies behind the wall plane (metres, positive
        for a recess: a door set into its frame, a window reveal, the thickness of the
        wall at a passage; negative for a door that protrudes).
    score:
        Detection strength (method-specific, for ranking).
    source:
        Which evidence found it: ``"edges"``, ``"holes"``, ``"bright"``.
    into:
        Index of the room of the layout it opens into, or ``-1`` where it opens to the
        outside (or nothing of the layout lies behind it); set by
        :func:`join_shared_openings`.
    """

    kind: str
    wall: int
    s0: float
    s1: float
    z0: float
    z1: float
    depth: float = 0.0
    score: float = 0.0
    source: str = ""
    into: int = -1

    @property
    def width(self) -> float:
        return self.s1 - self.s0

    @property
    def height(self) -> float:
        return self.z1 - self.z0

    def iou(self, other: Opening) -> float:
        """Intersection over union of the two rectangles on the wall plane (0 on other walls)."""
        if other.wall != self.wall:
            return 0.0
        return rect_iou(
            (self.s0, self.s1, self.z0, self.z1), (other.s0, other.s1, other.z0, other.z1)
        )


def rect_iou(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    """IoU of two rectangles ``(u0, u1, v0, v1)``."""
    iu = max(0.0, min(a[1], b[1]) - max(a[0], b[0]))
    iv = max(0.0, min(a[3], b[3]) - max(a[2], b[2]))
    inter = iu * iv
    union = (a[1] - a[0]) * (a[3] - a[2]) + (b[1] - b[0]) * (b[3] - b[2]) - inter
    return inter / union if union > 0 else 0.0


# --------------------------------------------------------------------------- baseboard


@dataclass
class Baseboard:
    """The baseboard: its height above the floor, depth, and the walls it runs along.

    Attributes
    ----------
    height:
        Top of the baseboard above the floor, metres.
    depth:
        How far it stands out of the wall, metres (median over its vertices).
    profile:
        ``B(y)`` per grid row (for plots), and ``heights``: the rows' heights above floor.
    walls:
        Indices of the walls on which it was seen.
    """

    height: float
    depth: float
    profile: np.ndarray
    heights: np.ndarray
    walls: list[int]


def baseboard_profile(grids: WallGrids, walls: list[int] | None = None) -> np.ndarray:
    """``B(y)`` of the thesis, summed over ``walls`` (default all)."""
    ks = range(len(grids.walls)) if walls is None else walls
    num = None
    den = None
    for k in ks:
        n = grids.n[k]
        e = np.divide(grids.fh[k], n, out=np.zeros_like(n), where=n > 0)
        num = e.sum(axis=0) if num is None else num + e.sum(axis=0)
        d = (n > 0).sum(axis=0)
        den = d if den is None else den + d
    if num is None:
        return np.zeros(0)
    return np.divide(num, den, out=np.zeros_like(num), where=den > 0)


def find_baseboard_height(
    grids: WallGrids,
    min_height: float = 0.03,
    max_height: float = 0.4,
    min_ratio: float = 1.3,
) -> tuple[float | None, np.ndarray, np.ndarray]:
    """The baseboard's top: the first local maximum of ``B`` above ``min_height``.

    A maximum must stand ``min_ratio`` times above the median of ``B`` between
    ``max_height`` and 1.2 m (plain wall). Measured peaks: 1.6-2.4 times that median on
    the four synthetic rooms, while rows of plain wall vary by about 7 %. Returns ``(height or None, B, row heights)``;
    the height is refined to sub-cell precision by a parabola through the peak.
    """
    b = baseboard_profile(grids)
    c = grids.cell
    heights = (np.arange(len(b)) + 0.5) * c
    if len(b) < 5:
        return None, b, heights
    ref_rows = (heights > max_height) & (heights < 1.2)
    ref = float(np.median(b[ref_rows])) if ref_rows.any() else float(np.median(b))
    for j in range(1, len(b) - 1):
        h = heights[j]
        if h < min_height:
            continue
        if h > max_height:
            break
        if b[j] >= b[j - 1] and b[j] > b[j + 1] and b[j] > min_ratio * ref:
            y0, y1, y2 = b[j - 1], b[j], b[j + 1]
            den = y0 - 2 * y1 + y2
            off = 0.5 * (y0 - y2) / den if den < 0 else 0.0
            return float(h + np.clip(off, -0.5, 0.5) * c), b, heights
    return None, b, heights


# --------------------------------------------------------------------------- edge segments


@dataclass
class EdgeSegment:
    """A run of strong edge cells along one grid column (vertical) or row (horizontal)."""

    line: float  # s (vertical) or z (horizontal), metres, cell centre
    lo: float  # start along the run, metres
    hi: float
    strength: float  # mean response over the observed cells of the run


def _runs(strong: np.ndarray, unknown: np.ndarray, max_gap: int) -> list[tuple[int, int]]:
    """Runs of ``strong`` cells, bridging unobserved cells and gaps of <= ``max_gap``."""
    ok = strong | unknown
    idx = np.flatnonzero(ok)
    if len(idx) == 0:
        return []
    out = []
    for run in np.split(idx, np.flatnonzero(np.diff(idx) > max_gap + 1) + 1):
        # Trim unobserved cells at the ends: a run is anchored by evidence.
        sel = run[strong[run]]
        if len(sel):
            out.append((int(sel[0]), int(sel[-1])))
    return out


def edge_segments(
    response: np.ndarray,
    observed: np.ndarray,
    threshold: float,
    cell: float,
    vertical: bool,
    min_len: float,
    max_gap: int = 2,
    min_support: float = 0.5,
) -> list[EdgeSegment]:
    """Scanline segments of an edge image with non-maximum suppression across lines.

    Parameters
    ----------
    response:
        ``(ns, nz)`` mean edge response per cell.
    observed:
        ``(ns, nz)`` cells seen by at least one pixel; unobserved cells may continue a
        run (occlusion) but do not count as support.
    vertical:
        Trace columns (fixed ``s``) if True, rows (fixed ``z``) if False.
    min_support:
        Fraction of a run's cells that must be observed and strong.
    """
    # Non-maximum suppression across lines: a cell counts only where its response is a
    # local maximum over its two neighbours across the run direction.
    r = response if vertical else response.T
    o = observed if vertical else observed.T
    left = np.vstack([np.full((1, r.shape[1]), -np.inf), r[:-1]])
    right = np.vstack([r[1:], np.full((1, r.shape[1]), -np.inf)])
    peak = (r >= left) & (r >= right)
    strong = (r > threshold) & o & peak
    # Allow a one-line wobble: strong on this line or on a neighbour (edges are not
    # always centred on one cell across their whole run).
    near = strong.copy()
    near[1:] |= strong[:-1] & ~(r[1:] < 0.5 * threshold)
    near[:-1] |= strong[1:] & ~(r[:-1] < 0.5 * threshold)
    out = []
    for k in range(r.shape[0]):
        for a, b in _runs(near[k], ~o[k], max_gap):
            n_cells = b - a + 1
            if n_cells * cell < min_len:
                continue
            support = near[k, a : b + 1].mean()
            if support < min_support:
                continue
            vals = r[k, a : b + 1][o[k, a : b + 1]]
            out.append(
                EdgeSegment(
                    (k + 0.5) * cell,
                    a * cell,
                    (b + 1) * cell,
                    float(vals.mean()) if len(vals) else 0.0,
                )
            )
    # Merge duplicates on adjacent lines that overlap (keep the strongest).
    out.sort(key=lambda e: -e.strength)
    kept: list[EdgeSegment] = []
    for e in out:
        if any(
            abs(k.line - e.line) <= 2.5 * cell
            and min(k.hi, e.hi) - max(k.lo, e.lo) > 0.5 * min(k.hi - k.lo, e.hi - e.lo)
            for k in kept
        ):
            continue
        kept.append(e)
    return kept


def edge_threshold(response: np.ndarray, observed: np.ndarray, factor: float) -> float:
    """``factor`` times the median response of the observed cells (plain wall)."""
    v = response[observed]
    return factor * float(np.median(v)) if len(v) else np.inf


def find_doors(
    grids: WallGrids,
    k: int,
    min_top: float = 1.5,
    width_range: tuple[float, float] = (0.55, 1.8),
    floor_tol: float = 0.15,
    height_tol: float = 0.12,
    cover: float = 0.8,
    factor: float = 2.5,
    weak_factor: float = 1.5,
) -> list[Opening]:
    """Doors on wall ``k`` from its edge grids (thesis §4.3.3, made more tolerant).

    The thesis's door is a pair of vertical edge segments that both start within
    ``floor_tol`` of the floor and end within ``height_tol`` of the same height above
    ``min_top``, ``width_range`` apart, with a horizontal edge segment at that height
    covering ``cover`` of the span between them. One jamb is often lit like the wall and
    shows a much weaker edge (measured: on the furnished scan the right jamb's segment
    broke off at 1.1 m), so a door is also accepted from one full vertical segment and a
    horizontal segment that starts or ends at it, when the column at the horizontal
    segment's other end has a mean vertical response of ``weak_factor`` times the plain
    wall's from the floor to the top. Overlapping candidates keep the widest.
    """
    n = grids.n[k]
    obs = n > 0
    ev = np.divide(grids.fv[k], n, out=np.zeros_like(n), where=obs)
    eh = np.divide(grids.fh[k], n, out=np.zeros_like(n), where=obs)
    c = grids.cell
    zf = grids.floor_z
    room_h = grids.ceiling_z - zf
    base_v = edge_threshold(ev, obs, 1.0)
    vs = edge_segments(ev, obs, factor * base_v, c, True, min_len=1.0)
    hs = edge_segments(eh, obs, edge_threshold(eh, obs, factor), c, False, min_len=0.3)
    full = [v for v in vs if v.lo <= floor_tol and min_top <= v.hi <= room_h - 0.1]

    def column_mean(s: float, top: float) -> float:
        i = int(np.clip(s / c, 0, ev.shape[0] - 1))
        cols = ev[max(0, i - 1) : i + 2, : max(1, int(top / c))]
        o = obs[max(0, i - 1) : i + 2, : max(1, int(top / c))]
        # The best of three neighbouring columns (the edge may sit between two cells).
        means = [cols[m][o[m]].mean() if o[m].any() else 0.0 for m in range(len(cols))]
        return float(max(means)) if means else 0.0

    def door(left: float, right: float, top: float, score: float) -> Opening:
        return Opening("door", k, left, right, zf, zf + top, score=score, source="edges")

    cands: list[Opening] = []
    for i, a in enumerate(full):
        for b in full[i + 1 :]:
            left, right = (a, b) if a.line < b.line else (b, a)
            width = right.line - left.line
            top = 0.5 * (left.hi + right.hi)
            if not width_range[0] <= width <= width_range[1]:
                continue
            if abs(left.hi - right.hi) > height_tol:
                continue
            for h in hs:
                span = min(h.hi, right.line) - max(h.lo, left.line)
                if abs(h.line - top) <= height_tol and span >= cover * width:
                    cands.append(
                        door(
                            left.line,
                            right.line,
                            h.line,
                            left.strength + right.strength + h.strength,
                        )
                    )
                    break
    # One strong jamb, the head, and a weak other jamb where the head ends.
    for v in full:
        for h in hs:
            if abs(h.line - v.hi) > height_tol or h.line < min_top:
                continue
            if abs(h.lo - v.line) <= 3 * c:
                other = h.hi
            elif abs(h.hi - v.line) <= 3 * c:
                other = h.lo
            else:
                continue
            left, right = sorted((v.line, other))
            if not width_range[0] <= right - left <= width_range[1]:
                continue
            if column_mean(other, h.line) >= weak_factor * base_v:
                cands.append(door(left, right, h.line, v.strength + h.strength))
    cands.sort(key=lambda o: -o.width)
    kept: list[Opening] = []
    for o in cands:
        if all(min(o.s1, q.s1) - max(o.s0, q.s0) <= 0 for q in kept):
            kept.append(o)
    return kept


def find_recessed_doors(
    grids: WallGrids,
    k: int,
    min_fraction: float = 0.5,
    min_top: float = 1.5,
    width_range: tuple[float, float] = (0.55, 1.8),
    floor_tol: float = 0.15,
    min_fill: float = 0.7,
) -> list[Opening]:
    """Doors set into the wall: door-shaped regions where most rays crossing the wall
    plane ended a little behind it (``shallow``: 1.5 to 6 cm)."""
    total = _pooled(grids.surface[k] + grids.shallow[k] + grids.deep[k] + grids.through[k])
    frac = np.divide(_pooled(grids.shallow[k]), total, out=np.zeros_like(total), where=total > 0)
    mask = (total >= 3) & (frac >= min_fraction)
    mask = ndimage.binary_opening(mask, iterations=1)
    mask = ndimage.binary_closing(mask, iterations=2)
    lab, _ = ndimage.label(mask)
    c = grids.cell
    zf = grids.floor_z
    out = []
    for sl_id, sl in enumerate(ndimage.find_objects(lab), start=1):
        if sl is None:
            continue
        comp = lab[sl] == sl_id
        s0, s1 = sl[0].start * c, sl[0].stop * c
        z0, z1 = sl[1].start * c, sl[1].stop * c
        if z0 > floor_tol or z1 < min_top or not width_range[0] <= s1 - s0 <= width_range[1]:
            continue
        if comp.mean() < min_fill:
            continue
        out.append(
            Opening(
                "door", k, s0, s1, zf, zf + z1, score=float(frac[sl][comp].mean()), source="recess"
            )
        )
    return out


def combine_doors(edge_doors: list[Opening], recess_doors: list[Opening]) -> list[Opening]:
    """Edge doors and recess doors together; where they overlap the edge door (sharper
    outline) is kept, and of overlapping edge doors the widest."""
    out = list(edge_doors)
    for d in recess_doors:
        if not any(_overlap_s(d, e) > 0 for e in out):
            out.append(d)
    return out


# --------------------------------------------------------------------------- holes


def _pooled(a: np.ndarray, size: int = 3) -> np.ndarray:
    """Sum over each cell's ``size x size`` neighbourhood (rays are sparse per 2 cm cell)."""
    return ndimage.uniform_filter(a.astype(np.float64), size, mode="constant") * size * size


def opening_fraction(
    grids: WallGrids, k: int, min_rays: int = 3, size: int = 3
) -> tuple[np.ndarray, np.ndarray]:
    """Per cell of wall ``k``: the fraction of crossing rays that went through or deep
    behind the plane, or ended on a reveal across it (``jamb``: near an opening's edge an
    oblique ray meets the reveal a few centimetres in), pooled over the ``size x size``
    neighbourhood, and a mask of cells whose neighbourhood was crossed by at least
    ``min_rays`` rays."""
    total = _pooled(grids.surface[k] + grids.shallow[k] + grids.deep[k] + grids.through[k], size)
    jamb = grids.jamb[k] if grids.jamb else 0.0
    far = _pooled(grids.through[k] + grids.deep[k] + jamb, size)
    frac = np.divide(far, total, out=np.zeros_like(total), where=total > 0)
    return frac, total >= min_rays


def find_holes(
    grids: WallGrids,
    k: int,
    min_fraction: float = 0.5,
    min_size: float = 0.25,
    min_fill: float = 0.6,
    passage_top: float = 1.5,
    floor_tol: float = 0.25,
    bright_min: int = 1,
    pools: tuple[int, ...] = (3, 5, 7, 9),
    min_gain: float = 1.5,
) -> list[Opening]:
    """Windows and passages on wall ``k``: rectangles the rays went through.

    Cells where at least ``min_fraction`` of the crossing rays went deep behind the
    plane or through it (or holding bright vertices) are grouped into 4-connected
    components; a component at least ``min_size`` wide and tall that fills ``min_fill``
    of its bounding box is an opening: a passage if it starts within ``floor_tol`` of the
    floor and rises above ``passage_top``, else a window (if it does not). The tolerance
    is generous because seen from the far room a passage's own floor stops the rays just
    behind the wall plane (measured: the bottom 11 cm of the tworooms passage), while
    window sills stand 0.85-0.9 m up.

    The rays are pooled over each cell's neighbourhood, at each size of ``pools`` in
    turn (cells of 2 cm: 6 to 18 cm). Few or low-resolution frames cross a wall sparsely
    (24 frames of 160x120 cross a third of the cells near `furnished`'s window, once
    each), and at the finest pooling the opening breaks into specks that the
    morphological opening removes, or into a part of it; so an opening found at a
    coarser pooling is kept where no finer one was found, and replaces the finer ones
    it overlaps when it is ``min_gain`` times their area or more (otherwise the finer,
    sharper rectangle stays). Where the frames cross the wall densely every pooling
    gives the same rectangle.
    """
    found: list[Opening] = []
    for size in pools:
        for o in _holes_at(
            grids, k, size, min_fraction, min_size, min_fill, passage_top, floor_tol, bright_min
        ):
            under = [f for f in found if o.iou(f) > 0]
            if not under:
                found.append(o)
            elif o.width * o.height >= min_gain * sum(f.width * f.height for f in under):
                found = [f for f in found if f not in under] + [o]
    return sorted(found, key=lambda o: (o.s0, o.z0))


def _holes_at(
    grids: WallGrids,
    k: int,
    size: int,
    min_fraction: float,
    min_size: float,
    min_fill: float,
    passage_top: float,
    floor_tol: float,
    bright_min: int,
) -> list[Opening]:
    """:func:`find_holes` at one pooling size."""
    frac, seen = opening_fraction(grids, k, size=size)
    mask = seen & (frac >= min_fraction)
    source = np.where(mask, 1, 0)
    if grids.bright and grids.bright[k].any():
        bright = grids.bright[k] >= bright_min
        bright = ndimage.binary_closing(bright, iterations=2)
        source = np.where(bright & ~mask, 2, source)
        mask |= bright
    mask = ndimage.binary_opening(mask, iterations=1)
    mask = ndimage.binary_closing(mask, iterations=2)
    lab, n = ndimage.label(mask)
    c = grids.cell
    zf = grids.floor_z
    out = []
    for sl_id, sl in enumerate(ndimage.find_objects(lab), start=1):
        if sl is None:
            continue
        comp = lab[sl] == sl_id
        w = (sl[0].stop - sl[0].start) * c
        h = (sl[1].stop - sl[1].start) * c
        if w < min_size or h < min_size or comp.mean() < min_fill:
            continue
        s0, s1 = sl[0].start * c, sl[0].stop * c
        z0, z1 = zf + sl[1].start * c, zf + sl[1].stop * c
        bright_share = float((source[sl][comp] == 2).mean())
        src = "bright" if bright_share > 0.5 else "holes"
        score = float(frac[sl][comp].mean())
        if z0 - zf <= floor_tol:
            if z1 - zf >= passage_top:
                out.append(Opening("passage", k, s0, s1, zf, z1, score=score, source=src))
            continue
        out.append(Opening("window", k, s0, s1, z0, z1, score=score, source=src))
    return out


def merge_openings(
    doors: list[Opening], holes: list[Opening], min_iou: float = 0.3
) -> list[Opening]:
    """Combine edge doors with hole openings: a door over a passage-sized hole is that
    passage (its frame shows edges too); everything else is kept."""
    out = list(holes)
    for d in doors:
        if any(
            d.iou(h) >= min_iou or _overlap_s(d, h) > 0.5 * min(d.width, h.width) for h in holes
        ):
            continue
        out.append(d)
    return out


def join_shared_openings(
    openings: list[Opening],
    walls: list[dict],
    wall_room: np.ndarray,
    max_gap: float = 0.5,
    min_overlap: float = 0.5,
) -> list[Opening]:
    """Openings in a wall two rooms share: say which room each opens into, and let a
    window that is the far side of a passage or door become that passage or door.

    Seen from the far room, the bottom of a passage is often hidden (furniture, or too
    few frames low enough: the 24-frame ``tworooms`` scan shows its passage from the
    second room only from 0.94 m up), and a hole that does not reach the floor is
    called a window. A window leads outside; one whose far side is another room of the
    layout is not a source of daylight. So every opening gets ``into``: the room
    behind its wall (a parallel wall of another room, facing back, at most ``max_gap``
    behind it, over the opening's middle). A window with a passage or door on that wall
    overlapping at least ``min_overlap`` of the narrower of the two takes that
    opening's kind and heights (the same opening seen from both sides); a window with
    nothing there keeps its kind, with ``into`` set (an interior window, or a passage
    whose far side went unseen).

    Returns new :class:`Opening` objects; the input is not modified.
    """
    geo = []
    for w in walls:
        a = np.asarray(w["start"], float)
        b = np.asarray(w["end"], float)
        length = float(np.linalg.norm(b - a))
        geo.append((a, (b - a) / max(length, 1e-12), np.asarray(w["inward_normal"], float), length))
    out = []
    for o in openings:
        a, t, nin, _ = geo[o.wall]
        mid = a + t * (o.s0 + o.s1) / 2
        into, partner = -1, None
        for v, (av, tv, ninv, lv) in enumerate(geo):
            if wall_room[v] == wall_room[o.wall] or nin @ ninv > -0.9:
                continue
            gap = float((av - mid) @ -nin)  # how far behind o's wall the other lies
            sv = float((mid - av) @ tv)
            if not (-1e-3 <= gap <= max_gap and 0.0 <= sv <= lv):
                continue
            into = int(wall_room[v])
            # o's extent in v's arc length (the walls run opposite ways)
            e = sorted(float((a + t * s - av) @ tv) for s in (o.s0, o.s1))
            for q in openings:
                if q.wall != v or q.kind not in ("passage", "door"):
                    continue
                shared = min(e[1], q.s1) - max(e[0], q.s0)
                if shared >= min_overlap * min(o.width, q.width):
                    partner = q
            break
        if o.kind == "window" and partner is not None:
            o = replace(o, kind=partner.kind, z0=partner.z0, z1=max(o.z1, partner.z1))
        out.append(replace(o, into=into))
    return out


def _overlap_s(a: Opening, b: Opening) -> float:
    if a.wall != b.wall:
        return 0.0
    return max(0.0, min(a.s1, b.s1) - max(a.s0, b.s0)) if min(a.z1, b.z1) > max(a.z0, b.z0) else 0.0


# --------------------------------------------------------------------------- measurements


def _wall_coords(xyz: np.ndarray, wall: dict) -> tuple[np.ndarray, np.ndarray]:
    """Arc length along a wall and depth behind its plane (positive away from the room)."""
    a = np.asarray(wall["start"], float)
    b = np.asarray(wall["end"], float)
    t = (b - a) / np.linalg.norm(b - a)
    nin = np.asarray(wall["inward_normal"], float)
    rel = xyz[:, :2] - a
    return rel @ t, -(rel @ nin)


def measure_depths(
    openings: list[Opening],
    xyz: np.ndarray,
    normals: np.ndarray,
    walls: list[dict],
    grids: WallGrids,
) -> None:
    """Set each opening's ``depth`` from the mesh (in place).

    A door's depth is the median depth of the vertices of its leaf (the rectangle shrunk
    by 5 cm, facing the room); a window's or passage's, the 90th percentile depth of its
    reveal (vertices inside the rectangle whose normals lie in the wall plane: jambs,
    sill, head). Without such vertices, the mean depth of the rays that ended in a recess
    there is used.
    """
    for o in openings:
        s, d = _wall_coords(xyz, walls[o.wall])
        nin = np.asarray(walls[o.wall]["inward_normal"], float)
        facing = normals[:, :2] @ nin
        z = xyz[:, 2]
        if o.kind == "door":
            m = 0.05
            sel = (
                (s > o.s0 + m)
                & (s < o.s1 - m)
                & (z > o.z0 + m)
                & (z < o.z1 - m)
                & (d > -0.15)
                & (d < 0.3)
                & (facing > 0.7)
            )
            if sel.sum() >= 5:
                o.depth = float(np.median(d[sel]))
                continue
        else:
            m = 0.03
            sel = (
                (s > o.s0 - m)
                & (s < o.s1 + m)
                & (z > o.z0 + m)
                & (z < o.z1 + m)
                & (d > 0.01)
                & (d < 0.6)
                & (np.abs(facing) < 0.5)
            )
            if sel.sum() >= 5:
                o.depth = float(np.quantile(d[sel], 0.9))
                continue
        # Fallback: mean recess depth of the rays over the rectangle.
        c = grids.cell
        i0, i1 = int(o.s0 / c), int(np.ceil(o.s1 / c))
        j0, j1 = int((o.z0 - grids.floor_z) / c), int(np.ceil((o.z1 - grids.floor_z) / c))
        cnt = grids.shallow[o.wall][i0:i1, j0:j1] + grids.deep[o.wall][i0:i1, j0:j1]
        tot = grids.recess_sum[o.wall][i0:i1, j0:j1].sum()
        o.depth = float(tot / cnt.sum()) if cnt.sum() > 0 else 0.0


def measure_baseboard(
    height: float,
    grids: WallGrids,
    xyz: np.ndarray,
    normals: np.ndarray,
    floor_z: float,
    profile: np.ndarray,
    heights: np.ndarray,
    min_ratio: float = 1.05,
) -> Baseboard:
    """Depth, refined height and walls of a baseboard found at ``height`` by its edges.

    Per 1 cm of height, the median distance in front of the wall planes of the
    wall-facing vertices near the floor gives the baseboard's profile in the mesh: its
    depth (thesis §4.3.2: median distance to the wall plane) is the step between the
    baseboard's band and the plain wall above, and where the mesh shows that step its
    top is the height at which the profile crosses half of it (fusion smooths a step
    symmetrically). The edge estimate sits 1.8-2.7 cm too high on our scans -- a thin
    bright band's edge response spreads outwards under the derivative filter -- while
    the half-step crossing lands within a few millimetres; it is used when found within
    5 cm below to 2 cm above the edge estimate.

    As in the thesis the baseboard is assumed to run along every wall; a wall is left
    out only when it was seen near the floor and its own ``B`` shows no rise at that
    height (below ``min_ratio`` of its plain wall). A stricter per-wall test dropped real
    baseboards on noisy walls (measured on the lshape scan: ratios 1.13 and 1.21 on two
    walls that have one, 1.9-6.9 on the others).
    """
    c = grids.cell
    j = int(np.clip(round(height / c - 0.5), 0, len(heights) - 1))
    has = []
    zs, ps = [], []
    for k, w in enumerate(grids.walls):
        b = baseboard_profile(grids, [k])
        seen_low = (grids.n[k][:, : max(1, j + 2)] > 0).any(axis=1).mean()
        ref_rows = (heights > 0.4) & (heights < 1.2)
        ref = float(np.median(b[ref_rows])) if ref_rows.any() else 0.0
        peak = float(b[max(0, j - 1) : j + 2].max()) if len(b) else 0.0
        if seen_low < 0.2 or peak > min_ratio * ref:
            has.append(k)
        s, d = _wall_coords(xyz, w)
        nin = np.asarray(w["inward_normal"], float)
        sel = (
            (xyz[:, 2] < floor_z + height + 0.2)
            & (s > 0.1)
            & (s < w["length"] - 0.1)
            & (d > -0.08)
            & (d < 0.03)
            & (normals[:, :2] @ nin > 0.7)
        )
        zs.append(xyz[sel, 2] - floor_z)
        ps.append(-d[sel])
    z = np.concatenate(zs) if zs else np.zeros(0)
    p = np.concatenate(ps) if ps else np.zeros(0)
    new_height, depth = _step_profile(z, p, height)
    return Baseboard(new_height, depth, profile, heights, has)


def _step_profile(z: np.ndarray, p: np.ndarray, height: float) -> tuple[float, float]:
    """``(height, depth)`` of the step in the protrusion profile ``p(z)`` near ``height``."""
    if len(z) < 50:
        return height, 0.0
    base = (z > 0.02) & (z < height - 0.03)
    plain = (z > height + 0.04) & (z < height + 0.2)
    if base.sum() < 10 or plain.sum() < 10:
        return height, float(max(0.0, np.median(p[base]))) if base.sum() else 0.0
    p_base = float(np.median(p[base]))
    p_plain = float(np.median(p[plain]))
    depth = max(0.0, p_base - p_plain)
    if depth < 0.004:  # no step the mesh can show: keep the edge estimate
        return height, depth
    half = 0.5 * (p_base + p_plain)
    centres = np.arange(max(0.02, height - 0.06), height + 0.03, 0.01) + 0.005
    med = np.array(
        [
            np.median(p[np.abs(z - c) < 0.005]) if np.any(np.abs(z - c) < 0.005) else np.nan
            for c in centres
        ]
    )
    for i in range(len(centres) - 1):
        a, b2 = med[i], med[i + 1]
        if np.isfinite(a) and np.isfinite(b2) and a >= half > b2:
            zc = centres[i] + (a - half) / (a - b2) * 0.01
            if height - 0.05 <= zc <= height + 0.02:
                return float(zc), depth
    return height, depth


def label_features(
    labels: np.ndarray,
    xyz: np.ndarray,
    walls: list[dict],
    openings: list[Opening],
    baseboard: Baseboard | None,
    floor_z: float,
    tol: float,
    spans: list[tuple[int, float, float]] | None = None,
) -> np.ndarray:
    """Per-feature labels: door leaves and frames, window reveals, passage reveals (as
    wall, like the walls they cut through) and baseboards, on top of the shell labels.

    Only ``wall`` and ``other`` vertices are relabelled (floor and ceiling stay).
    """
    from reroom.layout.labels import BASEBOARD, DOOR, OTHER, WALL, WINDOW

    out = labels.copy()
    free = np.isin(out, (WALL, OTHER))
    m = 0.03
    for o in openings:
        s, d = _wall_coords(xyz, walls[o.wall])
        z = xyz[:, 2]
        sel = (
            free
            & (s > o.s0 - m)
            & (s < o.s1 + m)
            & (z > o.z0 - m)
            & (z < o.z1 + m)
            & (d > -tol)
            & (d < max(o.depth, 0.0) + tol)
        )
        out[sel] = {"door": DOOR, "window": WINDOW}.get(o.kind, WALL)
    if baseboard is not None and spans:
        free = np.isin(out, (WALL, OTHER))
        for k, s0, s1 in spans:
            s, d = _wall_coords(xyz, walls[k])
            sel = (
                free
                & (s > s0 - m)
                & (s < s1 + m)
                & (xyz[:, 2] < floor_z + baseboard.height + 0.3 * tol)
                & (xyz[:, 2] > floor_z - tol)
                & (d > -(baseboard.depth + tol))
                & (d < tol)
            )
            out[sel] = BASEBOARD
    return out
