"""2D rooms for light localization: walls, obstacles, wall samples and exact occlusion.

A :class:`Room2D` is a simple polygon (the walls, counter-clockwise, interior on the left)
with optional solid polygonal obstacles inside it. Surfaces are diffuse; measurements
carry albedo-free values (see :mod:`reroom.localize.measurements`), so albedo never
appears here.

Occlusion is exact in 2D (thesis §6.3.6): a light at ``p`` sees the wall point ``x`` unless
the open segment ``x p`` properly crosses a wall or obstacle edge. Only non-convex rooms
and rooms with obstacles can occlude at all, which :attr:`Room2D.occludes` tells callers,
so that the common convex case skips the tests.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np
from numpy.typing import ArrayLike

from reroom.localize.measurements import LocalizeError, Measurements, render

__all__ = [
    "Room2D",
    "WallSamples",
    "box_room",
    "check_samples",
    "light_bounds",
    "render_room",
    "sample_walls",
    "shot_noise",
    "visibility_2d",
]


def _signed_area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _as_polygon(poly: ArrayLike, what: str) -> np.ndarray:
    arr = np.asarray(poly, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] < 3:
        raise LocalizeError(f"{what}: expected an (M >= 3, 2) polygon, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise LocalizeError(f"{what}: vertices must be finite")
    if abs(_signed_area(arr)) < 1e-12:
        raise LocalizeError(f"{what}: polygon has zero area")
    return arr


def _edges(poly: np.ndarray) -> np.ndarray:
    """``(M, 4)`` edges ``(ax, ay, bx, by)`` of a closed polygon."""
    return np.concatenate([poly, np.roll(poly, -1, axis=0)], axis=1)


@dataclass(frozen=True)
class Room2D:
    """A 2D room: wall polygon plus solid obstacles.

    Parameters
    ----------
    walls:
        ``(M, 2)`` polygon of the walls; made counter-clockwise if given clockwise.
    obstacles:
        Solid polygons inside the room (pillars, furniture); each made clockwise, so that
        the left-hand normal of every edge, walls and obstacles alike, points into free space.
    """

    walls: np.ndarray
    obstacles: tuple[np.ndarray, ...] = field(default=())

    def __post_init__(self) -> None:
        walls = _as_polygon(self.walls, "room walls")
        if _signed_area(walls) < 0:
            walls = walls[::-1].copy()
        obs = []
        for i, o in enumerate(self.obstacles):
            arr = _as_polygon(o, f"obstacle {i}")
            if _signed_area(arr) > 0:
                arr = arr[::-1].copy()
            obs.append(arr)
        object.__setattr__(self, "walls", walls)
        object.__setattr__(self, "obstacles", tuple(obs))

    @property
    def loops(self) -> tuple[np.ndarray, ...]:
        """Every closed surface loop: the walls first, then each obstacle."""
        return (self.walls, *self.obstacles)

    @property
    def segments(self) -> np.ndarray:
        """``(M, 4)`` all surface edges ``(ax, ay, bx, by)``."""
        return np.concatenate([_edges(loop) for loop in self.loops], axis=0)

    @property
    def is_convex(self) -> bool:
        """Whether the wall polygon is convex (then walls never hide one interior point from another)."""
        e = np.roll(self.walls, -1, axis=0) - self.walls
        cross = e[:, 0] * np.roll(e[:, 1], -1) - e[:, 1] * np.roll(e[:, 0], -1)
        return bool(np.all(cross >= -1e-12))

    @property
    def occludes(self) -> bool:
        """Whether any surface can hide a point of the room from a wall point."""
        return bool(self.obstacles) or not self.is_convex

    @property
    def occluder_segments(self) -> np.ndarray:
        """The edges occlusion tests must check: none in a convex empty room."""
        if not self.occludes:
            return np.zeros((0, 4))
        if self.is_convex:
            return np.concatenate([_edges(o) for o in self.obstacles], axis=0)
        return self.segments

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounding box ``(lo, hi)`` of the walls."""
        return self.walls.min(axis=0), self.walls.max(axis=0)

    @property
    def radius(self) -> float:
        """The scene radius: half the diagonal of the bounding box (thresholds scale with it)."""
        lo, hi = self.bounds
        return 0.5 * float(np.linalg.norm(hi - lo))

    def contains(self, points: ArrayLike) -> np.ndarray:
        """Whether each ``(..., 2)`` point lies in free space (inside the walls, outside obstacles)."""
        pts = np.asarray(points, dtype=np.float64)
        inside = _inside_polygon(pts, self.walls)
        for o in self.obstacles:
            inside &= ~_inside_polygon(pts, o)
        return inside

    def distance_to_surfaces(self, points: ArrayLike) -> np.ndarray:
        """Euclidean distance from each ``(..., 2)`` point to the nearest wall or obstacle edge."""
        pts = np.asarray(points, dtype=np.float64)
        seg = self.segments
        a, b = seg[:, :2], seg[:, 2:]
        ab = b - a
        rel = pts[..., None, :] - a
        t = np.clip(np.sum(rel * ab, axis=-1) / np.sum(ab * ab, axis=-1), 0.0, 1.0)
        d = rel - t[..., None] * ab
        return np.sqrt(np.min(np.sum(d * d, axis=-1), axis=-1))


def _inside_polygon(pts: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Even-odd point-in-polygon test on ``(..., 2)`` points."""
    x, y = pts[..., 0][..., None], pts[..., 1][..., None]
    ax, ay = poly[:, 0], poly[:, 1]
    bx, by = np.roll(ax, -1), np.roll(ay, -1)
    crosses = (ay > y) != (by > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xint = ax + (y - ay) * (bx - ax) / (by - ay)
    return np.sum(crosses & (x < xint), axis=-1) % 2 == 1


def box_room(width: float = 1.0, height: float | None = None) -> Room2D:
    """An empty axis-aligned rectangular room ``[0, width] x [0, height]`` (square by default)."""
    h = width if height is None else height
    if not (width > 0 and h > 0):
        raise LocalizeError(f"box_room: sides must be positive, got {width} x {h}")
    return Room2D(np.array([[0.0, 0.0], [width, 0.0], [width, h], [0.0, h]]))


@dataclass(frozen=True)
class WallSamples:
    """Measurement sites on a 2D room's surfaces, with their position along each loop.

    ``arc`` (distance along the loop from its first vertex) and ``loop`` give the surface
    distance ``d(x, y)`` that the voting function needs (thesis §6.4.2): the shorter way
    round the loop between two sites of one loop, infinite between loops.
    """

    points: np.ndarray
    normals: np.ndarray
    arc: np.ndarray
    loop: np.ndarray
    loop_lengths: np.ndarray

    def measurements(self, values: ArrayLike) -> Measurements:
        """Measurements at these sites carrying ``values``."""
        return Measurements(self.points, self.normals, values)

    def __len__(self) -> int:
        return int(self.points.shape[0])


def sample_walls(room: Room2D, n: int, obstacles: bool = False) -> WallSamples:
    """``n`` measurement sites evenly spaced by arc length along the walls.

    Sites sit at the middles of ``n`` equal arcs, so none lands on a corner, where the
    normal is undefined. With ``obstacles``, the obstacle outlines are sampled too, at
    the same spacing (then more than ``n`` sites come back).
    """
    if n < 1:
        raise LocalizeError(f"sample_walls: need at least one measurement, got n={n}")
    loops = room.loops if obstacles else (room.walls,)
    wall_len = float(
        np.sum(np.linalg.norm(np.diff(room.walls, axis=0, append=room.walls[:1]), axis=1))
    )
    spacing = wall_len / n
    pts, nrm, arc, lid, lens = [], [], [], [], []
    for li, poly in enumerate(loops):
        seg = _edges(poly)
        e = seg[:, 2:] - seg[:, :2]
        elen = np.linalg.norm(e, axis=1)
        cum = np.concatenate([[0.0], np.cumsum(elen)])
        total = float(cum[-1])
        count = n if li == 0 else max(1, round(total / spacing))
        s = (np.arange(count) + 0.5) * (total / count)
        k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(elen) - 1)
        t = (s - cum[k]) / elen[k]
        pts.append(seg[k, :2] + t[:, None] * e[k])
        # Left-hand normal: into the room for the CCW walls, out of the CW obstacles.
        nrm.append(np.stack([-e[k, 1], e[k, 0]], axis=1) / elen[k, None])
        arc.append(s)
        lid.append(np.full(count, li, dtype=np.int64))
        lens.append(total)
    return WallSamples(
        np.concatenate(pts),
        np.concatenate(nrm),
        np.concatenate(arc),
        np.concatenate(lid),
        np.asarray(lens, dtype=np.float64),
    )


def check_samples(room: Room2D, samples: WallSamples) -> None:
    """Raise :class:`LocalizeError` unless every site lies on a surface of ``room`` and faces
    into free space, and the arc-length bookkeeping is consistent."""
    n = len(samples)
    if n == 0:
        raise LocalizeError("no measurements: at least one surface sample is needed")
    pts = np.asarray(samples.points, dtype=np.float64)
    if pts.shape != (n, 2) or np.asarray(samples.normals).shape != (n, 2):
        raise LocalizeError(f"measurement points and normals must be ({n}, 2) arrays")
    for name in ("arc", "loop"):
        if np.asarray(getattr(samples, name)).shape != (n,):
            raise LocalizeError(f"measurement {name} must have shape ({n},)")
    loop = np.asarray(samples.loop)
    if loop.min() < 0 or loop.max() >= len(samples.loop_lengths):
        raise LocalizeError("measurement loop ids do not match the loop lengths")
    tol = 1e-6 * room.radius
    dist = room.distance_to_surfaces(pts)
    bad = np.flatnonzero(~(dist <= tol))
    if bad.size:
        i = int(bad[0])
        raise LocalizeError(
            f"{bad.size} measurement(s) are not on a surface of the room, e.g. #{i} at "
            f"({pts[i, 0]:.4g}, {pts[i, 1]:.4g}), {dist[i]:.3g} from the nearest wall"
        )
    ahead = pts + (1e-4 * room.radius) * samples.normals
    bad = np.flatnonzero(~room.contains(ahead))
    if bad.size:
        i = int(bad[0])
        raise LocalizeError(
            f"{bad.size} measurement normal(s) point out of the room, e.g. #{i} at "
            f"({pts[i, 0]:.4g}, {pts[i, 1]:.4g})"
        )


@numba.njit(cache=True, inline="always")
def _orient(ax: float, ay: float, bx: float, by: float, cx: float, cy: float) -> float:
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


@numba.njit(cache=True)
def segment_blocked(
    x0: float, y0: float, x1: float, y1: float, occ: np.ndarray
) -> bool:  # pragma: no cover - compiled
    """Whether the open segment (x0,y0)-(x1,y1) properly crosses one of the ``occ`` edges."""
    for m in range(occ.shape[0]):
        ax, ay, bx, by = occ[m, 0], occ[m, 1], occ[m, 2], occ[m, 3]
        d1 = _orient(x0, y0, x1, y1, ax, ay)
        d2 = _orient(x0, y0, x1, y1, bx, by)
        if d1 * d2 >= 0.0:
            continue
        d3 = _orient(ax, ay, bx, by, x0, y0)
        d4 = _orient(ax, ay, bx, by, x1, y1)
        if d3 * d4 < 0.0:
            return True
    return False


@numba.njit(cache=True)
def _visibility(pts: np.ndarray, lights: np.ndarray, occ: np.ndarray) -> np.ndarray:
    out = np.ones((pts.shape[0], lights.shape[0]), dtype=np.bool_)
    for i in range(pts.shape[0]):
        for k in range(lights.shape[0]):
            out[i, k] = not segment_blocked(pts[i, 0], pts[i, 1], lights[k, 0], lights[k, 1], occ)
    return out


def _lift(samples: WallSamples | Measurements, room: Room2D) -> np.ndarray:
    # A site lies exactly on its own edge; a tiny step along the normal keeps the exact
    # crossing test from counting that edge (or a neighbour meeting it at a corner).
    return samples.points + (1e-9 * room.radius) * samples.normals


def visibility_2d(
    room: Room2D, samples: WallSamples | Measurements, lights: ArrayLike
) -> np.ndarray | None:
    """Exact ``(N, K)`` visibility between measurement sites and lights; None if nothing can occlude."""
    pos = np.asarray(lights, dtype=np.float64).reshape(-1, 2)
    if not room.occludes:
        return None
    return _visibility(_lift(samples, room), pos, np.ascontiguousarray(room.occluder_segments))


def light_bounds(
    room: Room2D, samples: WallSamples, spacings: float = 2.0
) -> tuple[np.ndarray, np.ndarray]:
    """The box lights are searched in: the room's bounding box less ``spacings`` measurement
    spacings on every side.

    Closer to a wall than about two spacings, a light lights only one or two measurements:
    the data cannot resolve it, and a fit would use such lights to chase noise.
    """
    lo, hi = room.bounds
    spacing = float(samples.loop_lengths[0]) / max(1, int(np.sum(samples.loop == 0)))
    m = spacings * spacing
    if np.any(hi - lo <= 2 * m):
        raise LocalizeError("light_bounds: the room is too small for its measurement spacing")
    return lo + m, hi - m


def render_room(
    room: Room2D, samples: WallSamples | Measurements, positions: ArrayLike, intensities: ArrayLike
) -> np.ndarray:
    """Albedo-free direct light at the sites from point lights, with exact occlusion."""
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
    if pos.shape[0] and not np.all(room.contains(pos)):
        raise LocalizeError("render_room: every light must lie inside the room, outside obstacles")
    vis = visibility_2d(room, samples, pos)
    return render(samples.points, samples.normals, pos, intensities, vis)


def shot_noise(values: ArrayLike, k: float, rng: np.random.Generator) -> np.ndarray:
    """``B + k sqrt(B) z`` with ``z ~ N(0, 1)``: the thesis's model of CCD shot noise (§6.6.1)."""
    b = np.asarray(values, dtype=np.float64)
    return b + k * np.sqrt(np.maximum(b, 0.0)) * rng.standard_normal(b.shape)
