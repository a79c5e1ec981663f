"""Wall candidates from the weighted floor-grid score of thesis eq. 4.1.

All vertices are projected onto the floor plane and binned into a grid of cell size
``r`` (the mesh resolution). For each cell ``G_p`` and each of the four axis directions
``n`` the score is

    s(G_p, n) = sum over V in G_p of log(1 + y_V) (n_V . n)

with ``y_V`` the vertex's height above the floor, and ``s = 0`` when the cell two steps
behind the would-be wall holds more than 0.023 |G_p| vertices (walls bound the scan:
what lies behind them is noise). Scanlines of the grid give runs of cells with
``s > N`` (candidate segments), non-maximum suppression keeps the best of nearby parallel
runs, and each survivor's plane offset is refined to sub-cell precision by the median
position of its wall vertices.

One change from the thesis, by measurement (see ``docs/layout.md``): the count behind a
wall ignores vertices that face away from it (``n_V . n < -0.5``). Those belong to the
far side of a thin wall -- the next room's wall -- and counting them zeroed the score of
every 15 cm wall whenever ``2r`` exceeded its thickness (the failure of thesis Fig. 4.5).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: The four inward wall normals, in the order of the score grid's first axis.
DIRECTIONS = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])


@dataclass
class FloorGrid:
    """A regular grid on the floor plane (aligned frame).

    ``cell (i, j)`` covers ``[x0 + i c, x0 + (i+1) c) x [y0 + j c, y0 + (j+1) c)``.
    """

    x0: float
    y0: float
    cell: float
    shape: tuple[int, int]

    @staticmethod
    def around(xy: np.ndarray, cell: float, margin: int = 4) -> FloorGrid:
        lo = xy.min(axis=0) - margin * cell
        hi = xy.max(axis=0) + margin * cell
        shape = tuple(int(v) for v in np.ceil((hi - lo) / cell).astype(int) + 1)
        return FloorGrid(float(lo[0]), float(lo[1]), float(cell), shape)  # type: ignore[arg-type]

    def index(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cell indices ``(i, j)`` of points (clipped to the grid)."""
        i = np.floor((xy[:, 0] - self.x0) / self.cell).astype(np.int64)
        j = np.floor((xy[:, 1] - self.y0) / self.cell).astype(np.int64)
        return np.clip(i, 0, self.shape[0] - 1), np.clip(j, 0, self.shape[1] - 1)

    def centres(self, axis: int) -> np.ndarray:
        """Cell-centre coordinates along ``axis`` (0: x, 1: y)."""
        start = self.x0 if axis == 0 else self.y0
        return start + (np.arange(self.shape[axis]) + 0.5) * self.cell

    def to_coord(self, axis: int, index: np.ndarray | float) -> np.ndarray | float:
        """Coordinate of the centre of cell ``index`` along ``axis``."""
        start = self.x0 if axis == 0 else self.y0
        return start + (np.asarray(index) + 0.5) * self.cell


@dataclass
class WallScores:
    """The eq. 4.1 score grids of a scan.

    Attributes
    ----------
    grid:
        The floor grid.
    score:
        ``(4, nx, ny)`` scores per direction of :data:`DIRECTIONS`, after the
        empty-behind test.
    raw:
        ``(4, nx, ny)`` scores before it.
    count:
        ``(nx, ny)`` number of vertices between floor and ceiling per cell.
    """

    grid: FloorGrid
    score: np.ndarray
    raw: np.ndarray
    count: np.ndarray


def expected_wall_weight(height: float, r: float) -> float:
    """``sum_{i=0}^{h/r} log(1 + i r)``: the score of one fully seen column of wall."""
    i = np.arange(int(np.floor(height / r)) + 1)
    return float(np.log1p(i * r).sum())


def wall_scores(
    xyz: np.ndarray,
    normals: np.ndarray,
    floor_z: float,
    ceiling_z: float,
    cell: float,
    grid: FloorGrid | None = None,
    behind_ratio: float = 0.023,
    thin_walls: bool = True,
) -> WallScores:
    """The weighted wall-likelihood grid of eq. 4.1 with the empty-behind test.

    Parameters
    ----------
    xyz, normals:
        ``(V, 3)`` vertices and unit normals in the Manhattan frame (z up).
    floor_z, ceiling_z:
        Plane heights; vertices outside ``(floor_z, ceiling_z)`` are ignored.
    cell:
        Grid cell size, the mesh resolution ``r``.
    grid:
        Grid to use (default: around the vertices).
    behind_ratio:
        The 0.023 of the thesis: ``1 - erf(sqrt(2)/2)) / 2`` for noise ``sigma = r/2``.
    thin_walls:
        Ignore vertices facing away from ``n`` when counting the cell behind (see the
        module notes); ``False`` is the thesis's test.
    """
    xyz = np.asarray(xyz, np.float64)
    keep = (xyz[:, 2] > floor_z) & (xyz[:, 2] < ceiling_z)
    p, nv = xyz[keep], np.asarray(normals)[keep]
    grid = grid or FloorGrid.around(p[:, :2] if len(p) else xyz[:, :2], cell)
    i, j = grid.index(p[:, :2])
    flat = i * grid.shape[1] + j
    size = grid.shape[0] * grid.shape[1]
    h = np.log1p(p[:, 2] - floor_z)
    # Floor and ceiling surfaces cover the whole interior; they say nothing about what is
    # behind a wall, so the counts use only the vertices clearly between them.
    band = (p[:, 2] > floor_z + 2 * cell) & (p[:, 2] < ceiling_z - 2 * cell)
    count = np.bincount(flat[band], minlength=size).reshape(grid.shape).astype(np.float64)
    raw = np.empty((4, *grid.shape))
    score = np.empty_like(raw)
    for d, n in enumerate(DIRECTIONS):
        dots = nv[:, :2] @ n
        raw[d] = np.bincount(flat, weights=h * dots, minlength=size).reshape(grid.shape)
        if thin_walls:
            behind_count = np.bincount(flat[band & (dots > -0.5)], minlength=size).reshape(
                grid.shape
            )
        else:
            behind_count = count
        # G_{p - 2n}: shift the count grid by two cells along n.
        sx, sy = int(n[0]) * 2, int(n[1]) * 2
        behind = np.zeros(grid.shape)
        src = behind_count[
            max(0, -sx) : grid.shape[0] - max(0, sx), max(0, -sy) : grid.shape[1] - max(0, sy)
        ]
        behind[max(0, sx) : max(0, sx) + src.shape[0], max(0, sy) : max(0, sy) + src.shape[1]] = src
        score[d] = np.where(behind > behind_ratio * count, 0.0, raw[d])
    return WallScores(grid, score, raw, count)


@dataclass
class Segment:
    """A candidate wall: a run of grid cells on one line of the floor grid.

    Attributes
    ----------
    direction:
        Index into :data:`DIRECTIONS` of its inward normal.
    offset:
        The wall plane's coordinate across the wall (x for normals along x), metres.
    lo, hi:
        Its extent along the wall, metres.
    score:
        The summed score of its cells.
    line:
        Grid line index (cell index across the wall) it was found on.
    """

    direction: int
    offset: float
    lo: float
    hi: float
    score: float
    line: int = -1

    @property
    def axis(self) -> int:
        """0 when the wall plane is ``x = offset`` (normal along x), 1 for ``y = offset``."""
        return 0 if self.direction < 2 else 1

    @property
    def normal(self) -> np.ndarray:
        return DIRECTIONS[self.direction]

    @property
    def length(self) -> float:
        return self.hi - self.lo

    def endpoints(self) -> tuple[np.ndarray, np.ndarray]:
        """``(start, end)`` in counter-clockwise room order (the room on the left)."""
        a = np.empty(2)
        b = np.empty(2)
        ax = self.axis
        a[ax] = b[ax] = self.offset
        a[1 - ax], b[1 - ax] = self.lo, self.hi
        tangent = np.array([self.normal[1], -self.normal[0]])  # inward normal = rot90(tangent)
        if (b - a) @ tangent < 0:
            a, b = b, a
        return a, b


def scanline_segments(
    scores: WallScores, threshold: float, max_gap: int = 1, min_cells: int = 3
) -> list[Segment]:
    """Runs of cells with ``score > threshold`` along each grid line, per direction.

    ``max_gap`` cells below the threshold may interrupt a run (noise); runs shorter
    than ``min_cells`` are dropped.
    """
    g = scores.grid
    out: list[Segment] = []
    for d in range(4):
        s = scores.score[d]
        axis = 0 if d < 2 else 1  # across-wall axis of the grid
        lines = s if axis == 0 else s.T  # lines[k] runs along the wall
        for k, row in enumerate(lines):
            above = row > threshold
            if not above.any():
                continue
            idx = np.flatnonzero(above)
            splits = np.flatnonzero(np.diff(idx) > max_gap + 1)
            for run in np.split(idx, splits + 1):
                if run[-1] - run[0] + 1 < min_cells:
                    continue
                lo = float(g.to_coord(1 - axis, run[0])) - 0.5 * g.cell
                hi = float(g.to_coord(1 - axis, run[-1])) + 0.5 * g.cell
                out.append(
                    Segment(
                        d,
                        float(g.to_coord(axis, k)),
                        lo,
                        hi,
                        float(row[run[0] : run[-1] + 1].clip(min=0).sum()),
                        k,
                    )
                )
    return out


def non_maximum_suppression(
    segments: list[Segment], radius: float, min_overlap: float = 0.5
) -> list[Segment]:
    """Keep the best-scoring of parallel same-facing segments within ``radius`` of each other.

    A segment is suppressed by a better one of the same direction whose line is within
    ``radius`` (metres) and which covers at least ``min_overlap`` of the shorter's extent.
    """
    kept: list[Segment] = []
    for s in sorted(segments, key=lambda s: -s.score):
        suppressed = False
        for k in kept:
            if k.direction != s.direction or abs(k.offset - s.offset) > radius:
                continue
            overlap = min(k.hi, s.hi) - max(k.lo, s.lo)
            if overlap >= min_overlap * min(k.length, s.length):
                suppressed = True
                break
        if not suppressed:
            kept.append(s)
    return kept


def refine_offsets(
    segments: list[Segment],
    xyz: np.ndarray,
    normals: np.ndarray,
    floor_z: float,
    ceiling_z: float,
    window: float,
    cos_max: float = np.cos(np.radians(30.0)),
) -> list[Segment]:
    """Move each segment's plane to the median across-wall position of its wall vertices.

    Wall vertices: normal within ``acos(cos_max)`` of the segment's normal, height between
    floor and ceiling, inside its extent, within ``window`` of its line. Heights near the
    floor are left out so baseboards do not pull the plane into the room.
    """
    xyz = np.asarray(xyz)
    z = xyz[:, 2]
    height = ceiling_z - floor_z
    band = (z > floor_z + 0.2 * height) & (z < ceiling_z - 0.05 * height)
    out = []
    for s in segments:
        ax = s.axis
        dots = normals[:, :2] @ s.normal
        sel = (
            band
            & (dots > cos_max)
            & (np.abs(xyz[:, ax] - s.offset) < window)
            & (xyz[:, 1 - ax] > s.lo)
            & (xyz[:, 1 - ax] < s.hi)
        )
        off = float(np.median(xyz[sel, ax])) if sel.sum() >= 5 else s.offset
        out.append(Segment(s.direction, off, s.lo, s.hi, s.score, s.line))
    return out


def find_wall_segments(
    xyz: np.ndarray,
    normals: np.ndarray,
    floor_z: float,
    ceiling_z: float,
    r: float,
    threshold_scale: float = 1.0,
    thin_walls: bool = True,
    grid: FloorGrid | None = None,
) -> tuple[list[Segment], WallScores, float]:
    """Candidate wall segments of a scan: score grid, scanlines at ``N``, NMS, refinement.

    ``N`` is the thesis's ``sum_{i=0}^{h/r} log(1 + i r) / 2`` times ``threshold_scale``.

    Returns
    -------
    segments, scores, N
    """
    scores = wall_scores(xyz, normals, floor_z, ceiling_z, r, grid=grid, thin_walls=thin_walls)
    n_thr = 0.5 * expected_wall_weight(ceiling_z - floor_z, r) * threshold_scale
    segs = scanline_segments(scores, n_thr, max_gap=1, min_cells=max(3, int(0.15 / r)))
    segs = non_maximum_suppression(segs, radius=max(3 * r, 0.08))
    segs = refine_offsets(segs, xyz, normals, floor_z, ceiling_z, window=2.5 * r)
    return segs, scores, n_thr
