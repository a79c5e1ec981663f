"""Floorplans: closed rectilinear wall polygons from wall candidates.

Two methods:

``cycle`` (thesis §4.2.3, after Cabral & Furukawa 2014)
    The endpoints of the candidate segments are the nodes of a directed graph. Each
    segment joins its own endpoints with weight ``alpha`` (the model-complexity penalty);
    the end of a segment joins the start of any perpendicular segment that can follow it
    around the room counter-clockwise (and, our addition, of a collinear segment further
    along the same wall line, which bridges doorways), with the Manhattan distance
    between the two points as weight. The floorplan is the minimum-cost cycle through the
    longest segment, found by Dijkstra from its end back to its start.

``regions`` (ours, for several rooms and non-convex ones)
    Rooms are the connected regions of the floor grid under the ceiling: the ceiling is
    seen over every room, is not interrupted by furniture, and stops at every wall --
    including the thin wall between two rooms, above the doorway between them, which the
    floor does not. Each room's outline is then snapped to the wall lines that bound it:
    the lines cut the plane into rectangles, a rectangle belongs to the room when most of
    it lies under the room's ceiling, and the polygon is the boundary of those rectangles.
    Walls broken by doors or windows, furniture faces inside the room and missing short
    walls do not disturb it the way they can disturb a cycle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy import ndimage
from scipy.sparse.csgraph import dijkstra

from reroom.layout.walls import DIRECTIONS, FloorGrid, Segment

# --------------------------------------------------------------------------- polygons


def polygon_area(poly: np.ndarray) -> float:
    """Signed area of a polygon ``(K, 2)`` (positive for counter-clockwise)."""
    x, y = np.asarray(poly, float).T
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def points_in_polygon(xy: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Whether each point ``(N, 2)`` lies inside a polygon (even-odd rule)."""
    x, y = np.asarray(xy, float).reshape(-1, 2).T
    inside = np.zeros(len(x), bool)
    n = len(poly)
    for k in range(n):
        (x0, y0), (x1, y1) = poly[k], poly[(k + 1) % n]
        crosses = (y0 > y) != (y1 > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            xint = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
        inside ^= crosses & (x < xint)
    return inside


def simplify_rectilinear(poly: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """Drop repeated and collinear vertices of a closed polygon."""
    p = np.asarray(poly, float)
    changed = True
    while changed and len(p) > 3:
        changed = False
        keep = np.ones(len(p), bool)
        for i in range(len(p)):
            a, b, c = p[i - 1], p[i], p[(i + 1) % len(p)]
            if np.linalg.norm(b - a) < tol:
                keep[i] = False
                changed = True
                break
            cross = (b[0] - a[0]) * (c[1] - b[1]) - (b[1] - a[1]) * (c[0] - b[0])
            if abs(cross) < tol:
                keep[i] = False
                changed = True
                break
        p = p[keep]
    return p


def polygon_walls(poly: np.ndarray) -> list[dict]:
    """``start, end, inward_normal, length`` of each edge of a counter-clockwise polygon."""
    walls = []
    for i in range(len(poly)):
        a = np.asarray(poly[i], float)
        b = np.asarray(poly[(i + 1) % len(poly)], float)
        d = b - a
        length = float(np.linalg.norm(d))
        d = d / length
        walls.append(
            {
                "index": i,
                "start": a.tolist(),
                "end": b.tolist(),
                "inward_normal": [float(-d[1]), float(d[0])],
                "length": length,
            }
        )
    return walls


def rasterize_polygons(polys: list[np.ndarray], grid: FloorGrid) -> np.ndarray:
    """Boolean ``grid.shape`` mask of the cells whose centres lie inside any polygon."""
    from reroom.synth.room import point_in_polygon

    xc = grid.centres(0)[:, None]
    yc = grid.centres(1)[None, :]
    out = np.zeros(grid.shape, bool)
    for p in polys:
        out |= point_in_polygon(
            np.broadcast_to(xc, grid.shape), np.broadcast_to(yc, grid.shape), np.asarray(p)
        )
    return out


# --------------------------------------------------------------------------- thesis: cycle


@dataclass
class CycleResult:
    """A floorplan cycle: the segments in order, its polygon and its cost."""

    order: list[int]
    polygon: np.ndarray
    cost: float


def _corner(a: Segment, b: Segment) -> np.ndarray:
    p = np.empty(2)
    p[a.axis] = a.offset
    p[b.axis] = b.offset
    return p


def cycle_graph(
    segments: list[Segment],
    alpha: float = 1.0,
    tol: float = 0.15,
    collinear_tol: float = 0.1,
    bridge_collinear: bool = True,
) -> sp.csr_matrix:
    """The directed endpoint graph of the thesis (see the module notes).

    Node ``2k`` is the start of segment ``k`` and ``2k + 1`` its end (counter-clockwise
    order). An end connects to the start of a perpendicular segment when their lines
    meet at a corner ahead of the end and behind the start (within ``tol``).
    """
    n = len(segments)
    ends = [s.endpoints() for s in segments]
    tangents = [np.array([s.normal[1], -s.normal[0]]) for s in segments]
    rows, cols, w = [], [], []
    for k in range(n):
        rows.append(2 * k)
        cols.append(2 * k + 1)
        w.append(alpha)
    for a, sa in enumerate(segments):
        head, ta = ends[a][1], tangents[a]
        for b, sb in enumerate(segments):
            if a == b:
                continue
            tail, tb = ends[b][0], tangents[b]
            if sa.axis != sb.axis:
                c = _corner(sa, sb)
                if (c - head) @ ta < -tol or (tail - c) @ tb < -tol:
                    continue
            elif bridge_collinear and sa.direction == sb.direction:
                if abs(sa.offset - sb.offset) > collinear_tol or (tail - head) @ ta < -tol:
                    continue
            else:
                continue
            rows.append(2 * a + 1)
            cols.append(2 * b)
            # A tiny floor keeps zero-length joins as real edges in the sparse graph.
            w.append(max(float(np.abs(tail - head).sum()), 1e-6))
    return sp.csr_matrix((w, (rows, cols)), shape=(2 * n, 2 * n))


def cycle_polygon(segments: list[Segment], order: list[int]) -> np.ndarray:
    """Polygon of a cycle of segments: collinear runs merge, perpendicular ones meet at corners."""
    walls: list[tuple[int, float, float]] = []  # (axis, offset, weight)
    dirs: list[int] = []
    for k in order:
        s = segments[k]
        if walls and dirs[-1] == s.direction:
            ax, off, wt = walls[-1]
            walls[-1] = (ax, (off * wt + s.offset * s.length) / (wt + s.length), wt + s.length)
        else:
            walls.append((s.axis, s.offset, s.length))
            dirs.append(s.direction)
    if len(walls) > 1 and dirs[0] == dirs[-1]:
        ax, off, wt = walls.pop()
        dirs.pop()
        a0, o0, w0 = walls[0]
        walls[0] = (a0, (o0 * w0 + off * wt) / (w0 + wt), w0 + wt)
    pts = []
    for i in range(len(walls)):
        prev, cur = walls[i - 1], walls[i]
        if prev[0] == cur[0]:  # parallel neighbours (a U-turn): not a valid outline
            continue
        p = np.empty(2)
        p[prev[0]] = prev[1]
        p[cur[0]] = cur[1]
        pts.append(p)
    return simplify_rectilinear(np.array(pts)) if pts else np.zeros((0, 2))


def min_cost_cycle(
    segments: list[Segment],
    alpha: float = 1.0,
    start: int | None = None,
    tol: float = 0.15,
    bridge_collinear: bool = True,
) -> CycleResult | None:
    """The minimum-cost cycle through segment ``start`` (default: the longest).

    Returns ``None`` when no cycle closes (or it is not a polygon).
    """
    if len(segments) < 4:
        return None
    g = cycle_graph(segments, alpha, tol, bridge_collinear=bridge_collinear)
    if start is None:
        start = int(np.argmax([s.length for s in segments]))
    dist, pred = dijkstra(g, directed=True, indices=2 * start + 1, return_predecessors=True)
    target = 2 * start
    if not np.isfinite(dist[target]):
        return None
    nodes = [target]
    while nodes[-1] != 2 * start + 1:
        nodes.append(int(pred[nodes[-1]]))
    nodes.reverse()
    order = [start]
    for node in nodes[1:-1]:
        k = node // 2
        if order[-1] != k:
            order.append(k)
    poly = cycle_polygon(segments, order)
    if len(poly) < 4 or polygon_area(poly) <= 0:
        return None
    return CycleResult(order, poly, float(dist[target] + alpha))


# --------------------------------------------------------------------------- ours: regions


def room_regions(
    ceiling_mask: np.ndarray,
    cell: float,
    min_area: float = 1.0,
    close_cells: int = 1,
    walls: np.ndarray | None = None,
) -> tuple[np.ndarray, int]:
    """Label the rooms: connected regions of the floor grid under a seen ceiling.

    The mask is closed by ``close_cells`` (cracks of scan noise), its holes are filled
    (recessed light fittings, spots the scan missed), cells in ``walls`` (where wall
    surfaces stand) are taken out again so the closing never bridges a thin wall, and
    regions smaller than ``min_area`` m² are dropped. Returns ``(labels, count)`` with
    rooms numbered ``1..count`` by area.
    """
    m = np.asarray(ceiling_mask, bool)
    if close_cells > 0:
        st = ndimage.generate_binary_structure(2, 1)
        m = ndimage.binary_closing(m, st, iterations=close_cells, border_value=0)
    if walls is not None:
        m &= ~walls
    m = ndimage.binary_fill_holes(m)
    lab, n = ndimage.label(m)
    if n == 0:
        return lab, 0
    areas = np.bincount(lab.ravel())[1:] * cell * cell
    order = np.argsort(-areas)
    out = np.zeros_like(lab)
    count = 0
    for k in order:
        if areas[k] < min_area:
            break
        count += 1
        out[lab == k + 1] = count
    return out, count


def segments_bounding(
    segments: list[Segment],
    region: np.ndarray,
    grid: FloorGrid,
    depth: float = 0.15,
    min_len: float = 0.4,
) -> list[int]:
    """Indices of the segments that bound ``region``: along at least ``min_len`` metres
    (or half the segment) the region lies ``depth`` in front of the line and not behind.

    A wall line shared by two rooms (collinear walls on either side of a thin wall) thus
    bounds both.
    """
    out = []
    for k, s in enumerate(segments):
        ax = s.axis
        t = np.arange(s.lo + 0.5 * grid.cell, s.hi, grid.cell)
        if len(t) == 0:
            continue
        pts_in = np.empty((len(t), 2))
        pts_in[:, 1 - ax] = t
        pts_out = pts_in.copy()
        pts_in[:, ax] = s.offset + s.normal[ax] * depth
        pts_out[:, ax] = s.offset - s.normal[ax] * depth
        good = region[grid.index(pts_in)] & ~region[grid.index(pts_out)]
        if good.sum() * grid.cell >= min(min_len, 0.5 * s.length):
            out.append(k)
    return out


def _trace_cells(inside: np.ndarray) -> list[tuple[int, int]]:
    """Counter-clockwise boundary of a 4-connected, hole-free set of lattice cells.

    Cell ``(a, b)`` spans lattice points ``(a, b)``-``(a+1, b+1)``; returns lattice points.
    """
    na, nb = inside.shape
    pad = np.zeros((na + 2, nb + 2), bool)
    pad[1:-1, 1:-1] = inside
    nxt: dict[tuple[int, int], list[tuple[int, int]]] = {}

    def add(p: tuple[int, int], q: tuple[int, int]) -> None:
        nxt.setdefault(p, []).append(q)

    for a, b in zip(*np.nonzero(inside), strict=True):
        a, b = int(a), int(b)
        if not pad[a + 1, b]:  # below (-y) is outside
            add((a, b), (a + 1, b))
        if not pad[a + 2, b + 1]:  # +x side
            add((a + 1, b), (a + 1, b + 1))
        if not pad[a + 1, b + 2]:  # +y side
            add((a + 1, b + 1), (a, b + 1))
        if not pad[a, b + 1]:  # -x side
            add((a, b + 1), (a, b))
    if not nxt:
        return []
    start = min(nxt)
    path = [start]
    prev_dir = (1, 0)
    cur = start
    for _ in range(4 * (na + 1) * (nb + 1) + 4):
        options = nxt.get(cur, [])
        if not options:
            break
        if len(options) == 1:
            q = options.pop()
        else:
            # A pinch point: take the leftmost turn, keeping the region on the left.
            turns = [
                -(prev_dir[0] * (q[1] - cur[1]) - prev_dir[1] * (q[0] - cur[0])) for q in options
            ]
            q = options.pop(int(np.argmin(turns)))
        prev_dir = (q[0] - cur[0], q[1] - cur[1])
        cur = q
        if cur == start:
            break
        path.append(cur)
    return path


def snap_region(
    region: np.ndarray,
    grid: FloorGrid,
    xs: np.ndarray,
    ys: np.ndarray,
    min_fraction: float = 0.5,
) -> np.ndarray:
    """Rectilinear outline of a region with its edges on the given wall lines.

    The lines ``x = xs`` and ``y = ys`` cut the plane into rectangles; a rectangle is
    kept when at least ``min_fraction`` of it (sampled on a sub-grid) lies in
    ``region``; the outline of the largest 4-connected set of kept rectangles (holes
    filled) is returned counter-clockwise, collinear vertices removed.
    """
    xs = np.unique(np.asarray(xs, float))
    ys = np.unique(np.asarray(ys, float))
    if len(xs) < 2 or len(ys) < 2:
        return np.zeros((0, 2))
    keep = np.zeros((len(xs) - 1, len(ys) - 1), bool)
    step = 0.5 * grid.cell
    for a in range(len(xs) - 1):
        nx = max(1, int(np.ceil((xs[a + 1] - xs[a]) / step)))
        sx = xs[a] + (np.arange(nx) + 0.5) * (xs[a + 1] - xs[a]) / nx
        for b in range(len(ys) - 1):
            ny = max(1, int(np.ceil((ys[b + 1] - ys[b]) / step)))
            sy = ys[b] + (np.arange(ny) + 0.5) * (ys[b + 1] - ys[b]) / ny
            px, py = np.meshgrid(sx, sy, indexing="ij")
            i, j = grid.index(np.stack([px.ravel(), py.ravel()], axis=1))
            keep[a, b] = region[i, j].mean() >= min_fraction
    lab, n = ndimage.label(keep)
    if n == 0:
        return np.zeros((0, 2))
    # Largest by area, not by rectangle count.
    areas = np.zeros(n + 1)
    da = np.diff(xs)[:, None] * np.diff(ys)[None, :]
    np.add.at(areas, lab.ravel(), da.ravel())
    areas[0] = 0
    comp = ndimage.binary_fill_holes(lab == int(np.argmax(areas)))
    lattice = _trace_cells(comp)
    poly = np.array([[xs[a], ys[b]] for a, b in lattice])
    poly = simplify_rectilinear(poly)
    if polygon_area(poly) < 0:
        poly = poly[::-1]
    return poly


def region_lines(
    segments: list[Segment], indices: list[int], merge: float
) -> tuple[np.ndarray, np.ndarray]:
    """The x and y wall lines of a room's segments, merging lines closer than ``merge``.

    Merged lines take the score-weighted mean offset.
    """
    out = []
    for axis in (0, 1):
        items = sorted(
            (segments[k].offset, segments[k].score) for k in indices if segments[k].axis == axis
        )
        lines: list[list[float]] = []
        for off, sc in items:
            if lines and off - lines[-1][0] / lines[-1][1] < merge:
                lines[-1][0] += off * sc
                lines[-1][1] += sc
            else:
                lines.append([off * sc, sc])
        out.append(np.array([a / b for a, b in lines]))
    return out[0], out[1]


def boundary_lines(region: np.ndarray, grid: FloorGrid, min_len: float) -> tuple[list, list]:
    """Fallback wall lines from straight runs of a region's own boundary (cell precision).

    For a wall the segment search missed: any boundary run of at least ``min_len``
    metres along x or y gives a line at the boundary between the cells.
    """
    xs: list[float] = []
    ys: list[float] = []
    need = max(2, int(np.ceil(min_len / grid.cell)))
    r = region.astype(np.int8)
    # Edges between cells (i, j) and (i+1, j): x = x0 + (i+1) cell.
    dx = np.abs(np.diff(r, axis=0))
    for i in range(dx.shape[0]):
        if _longest_run(dx[i]) >= need:
            xs.append(grid.x0 + (i + 1) * grid.cell)
    dy = np.abs(np.diff(r, axis=1))
    for j in range(dy.shape[1]):
        if _longest_run(dy[:, j]) >= need:
            ys.append(grid.y0 + (j + 1) * grid.cell)
    return xs, ys


def _longest_run(v: np.ndarray) -> int:
    best = cur = 0
    for x in v:
        cur = cur + 1 if x else 0
        best = max(best, cur)
    return best


def direction_of(normal: np.ndarray) -> int:
    """Index into :data:`DIRECTIONS` of an axis-aligned 2D normal."""
    return int(np.argmax(DIRECTIONS @ np.asarray(normal, float)))


def extend_to_walls(
    region: np.ndarray,
    segments: list[Segment],
    grid: FloorGrid,
    reach: float,
    min_len: float = 0.5,
    close: float = 0.3,
) -> np.ndarray:
    """A partial room's floor coverage grown out to the wall candidates that face it.

    A partial scan sees walls beyond the floor it covers (the floor in front of them is
    hidden by furniture or lies outside the views). For each column of cells along a
    segment of at least ``min_len`` metres, the cells from the wall inwards up to the
    first covered cell are added when that cell lies within ``reach`` metres; a wall that
    faces no coverage adds nothing. The result is closed by ``close`` metres (the gaps
    between pieces of one wall) and its holes are filled.
    """
    out = region.copy()
    steps = max(1, int(np.ceil(reach / grid.cell)))
    for s in segments:
        if s.length < min_len:
            continue
        ax = s.axis
        sign = int(round(s.normal[ax]))
        t = np.arange(s.lo + 0.5 * grid.cell, s.hi, grid.cell)
        if len(t) == 0:
            continue
        pts = np.empty((len(t), 2))
        pts[:, 1 - ax] = t
        pts[:, ax] = s.offset + 0.5 * sign * grid.cell
        i, j = grid.index(pts)
        along = j if ax == 0 else i
        start = i if ax == 0 else j
        for a, k0 in zip(along, start, strict=True):
            ks = k0 + sign * np.arange(steps + 1)
            ks = ks[(ks >= 0) & (ks < grid.shape[ax])]
            line = region[ks, a] if ax == 0 else region[a, ks]
            hit = np.flatnonzero(line)
            if len(hit) == 0:
                continue
            fill = ks[: hit[0] + 1]
            if ax == 0:
                out[fill, a] = True
            else:
                out[a, fill] = True
    k = max(1, int(round(close / grid.cell)))
    st = np.ones((2 * (k // 2) + 1, 2 * (k // 2) + 1), bool)
    out = ndimage.binary_closing(out, st, border_value=0) | out
    return ndimage.binary_fill_holes(out)


def include_points(
    region: np.ndarray,
    points: np.ndarray,
    segments: list[Segment],
    grid: FloorGrid,
    margin: float,
    min_len: float = 0.5,
) -> tuple[np.ndarray, list[float], list[float], int]:
    """A region grown by axis-aligned rectangles until it contains the given points.

    For the camera positions of a partial scan (projected to the floor): a capture is
    taken from inside the room, but the floor right below and in front of the cameras is
    often out of view, so the floor's coverage can start metres ahead of them. Each point
    outside the region adds the rectangle spanning the point grown by ``margin`` metres
    and the nearest cell of the region (nearest points first, so later ones can join the
    earlier rectangles); a wall candidate of at least ``min_len`` metres that faces the point
    and lies across the rectangle's extent clips it (never past the point or that cell),
    so the room does not grow through a wall it saw. Returns the grown region, the x and
    y lines of the rectangles' sides (to snap the outline to) and how many points were
    outside.
    """
    out = np.asarray(region, bool).copy()
    pts = np.asarray(points, float).reshape(-1, 2)
    xs: list[float] = []
    ys: list[float] = []
    if not out.any() or len(pts) == 0:
        return out, xs, ys, 0
    centres = (grid.centres(0), grid.centres(1))
    walls = [s for s in segments if s.length >= min_len]

    def gap(p: np.ndarray) -> float:
        ci, cj = np.nonzero(out)
        return float(np.min(np.hypot(centres[0][ci] - p[0], centres[1][cj] - p[1])))

    pi, pj = grid.index(pts)
    away = pts[~out[pi, pj]]
    for p in sorted(away, key=gap):
        i, j = grid.index(p[None])
        ci, cj = np.nonzero(out)
        d = np.hypot(centres[0][ci] - p[0], centres[1][cj] - p[1])
        k = int(np.argmin(d))
        q = np.array([centres[0][ci[k]], centres[1][cj[k]]])
        lo = np.minimum(p - margin, q)
        hi = np.maximum(p + margin, q)
        for s in walls:
            ax = s.axis
            sign = s.normal[ax]
            if (p[ax] - s.offset) * sign <= 0:
                continue  # the point is behind this wall: it does not bound the point
            if s.hi <= lo[1 - ax] or s.lo >= hi[1 - ax]:
                continue
            if sign > 0:
                lo[ax] = max(lo[ax], min(s.offset, p[ax], q[ax]))
            else:
                hi[ax] = min(hi[ax], max(s.offset, p[ax], q[ax]))
        sel = [(c >= a) & (c <= b) for c, a, b in zip(centres, lo, hi, strict=True)]
        out[np.ix_(sel[0], sel[1])] = True
        out[i[0], j[0]] = True
        xs.extend([float(lo[0]), float(hi[0])])
        ys.extend([float(lo[1]), float(hi[1])])
    return out, xs, ys, len(away)
