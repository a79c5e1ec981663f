"""Where a detected area light's surface ends: the convex outline of its vertices.

A light's vertices (:mod:`reroom.lights`) are those the photos saw bright. On a clean
mesh they are the panel's own piece, and the emitter is their faces. On a depth-fused
mesh the panel is part of one surface with the ceiling around it, and the bright set
reaches one row of vertices past the panel's edge (a vertex whose footprint the panel
covers in part is clipped too). The barycentric rule of the transfers (a point of a
triangle is light by the share of its light corners, so the light ends half-way into
its rim triangles) then adds another half row: on the 300-frame 320x180 fused
`furnished` scan the 0.60 x 0.60 m panel emitted from 0.40 m^2, 11 % too much, and the
solve gave the panel +4 % and the tube beside it +6 % of power (docs/invert.md,
"An area light's outline").

Here the emitter is the part of the mesh around the light whose projection onto the
light's plane lies inside the convex hull of its vertices' projections: on the fused
scan 0.362 m^2 (0.6014 x 0.6014 extent), on a clean mesh the panel's faces exactly.
Convex: a panel, a disc, a skylight; a light of another shape keeps its hull, which a
user can correct by hand. scipy's ``ConvexHull`` (Qhull) and matplotlib's ``Path``
containment test do the geometry.

A recessed panel adds a second way past its edge. The fusion rounds the recess's step
into a slope, and where the cameras look across that slope at the face below it, the
slope's vertices take the face's radiance: on the same scan fused on a voxel grid turned
17 degrees (session 49), bright vertices up to 4.1 cm past two of the panel's edges, 0.8-1.6
cm off its face's plane, made the hull 0.628 x 0.643 m (0.395 m^2, 10 % too much), and the panel
rendered 13 % too dim where a camera sees it directly. The emitting face is flat, so
:func:`on_emitting_plane` keeps the light's vertices on its plane (within the plane's
own scatter, at least 5 mm) for the outline; a light whose vertices do not mostly lie on
one plane (a dome, a curved strip) keeps them all.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import ConvexHull, QhullError

__all__ = [
    "CORE_SHARE",
    "FACE_TOLERANCE",
    "MIN_PLANE_SHARE",
    "AreaRegion",
    "area_region",
    "clip_to_region",
    "emitting_face_plane",
    "on_emitting_plane",
    "onto_plane",
]

#: Metres off its plane within which a light's vertex is on its emitting face, or the
#: plane's own scatter (three robust standard deviations) where that is larger. A
#: fused plane scatters by 1-5 mm (marching cubes' steps on a 3 cm grid); the rim of a
#: recessed panel, 2 cm deep, fuses 7 mm and more off the face.
FACE_TOLERANCE = 0.005

#: :func:`on_emitting_plane` keeps every vertex when fewer than this share lie on the
#: plane: the light is not flat.
MIN_PLANE_SHARE = 0.6


#: Share of a light's vertices inside its outline, those furthest from its edge, through
#: which :func:`emitting_face_plane` fits the emitting face's plane.
CORE_SHARE = 0.5


@dataclass(frozen=True)
class AreaRegion:
    """A planar convex outline: ``origin + a u + b v`` for ``(a, b)`` inside ``polygon``."""

    origin: np.ndarray
    u: np.ndarray
    v: np.ndarray
    normal: np.ndarray
    polygon: np.ndarray  # (K, 2), counter-clockwise

    @property
    def area(self) -> float:
        """The outline's area (m²): the light's area projected on its plane."""
        x, y = self.polygon[:, 0], self.polygon[:, 1]
        return float(0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))

    def plane_coordinates(self, points: ArrayLike) -> np.ndarray:
        """``(N, 2)`` coordinates of ``points`` projected on the plane."""
        q = np.asarray(points, float).reshape(-1, 3) - self.origin
        return np.stack([q @ self.u, q @ self.v], axis=1)

    def edge_distance(self, points: ArrayLike) -> np.ndarray:
        """``(N,)`` in-plane distance (m) of each point's projection from the outline's
        edge (from the nearest of its sides, inside or out)."""
        ab = self.plane_coordinates(points)
        a = self.polygon
        e = np.roll(a, -1, axis=0) - a
        rel = ab[:, None, :] - a[None]
        t = np.clip((rel * e).sum(-1) / np.maximum((e * e).sum(-1), 1e-30), 0.0, 1.0)
        return np.linalg.norm(rel - t[..., None] * e, axis=-1).min(axis=1)

    def contains(self, points: ArrayLike) -> np.ndarray:
        """``(N,)`` bool: whether each point projects inside the outline (edges count)."""
        ab = self.plane_coordinates(points)
        inside = np.ones(len(ab), bool)
        p = self.polygon
        for k in range(len(p)):
            e = p[(k + 1) % len(p)] - p[k]
            rel = ab - p[k]
            # Counter-clockwise: inside is to the left of every edge (a small tolerance
            # keeps points on an edge, which the hull's own vertices are).
            inside &= e[0] * rel[:, 1] - e[1] * rel[:, 0] >= -1e-9 * (1.0 + np.dot(e, e))
        return inside


def area_region(points: ArrayLike, normal: ArrayLike) -> AreaRegion | None:
    """The convex outline of a light's vertices ``points`` on the plane of ``normal``.

    None when there are fewer than three points, they are collinear on the plane, or
    ``points`` / ``normal`` are not finite coordinates.
    """
    try:
        p = np.asarray(points, float).reshape(-1, 3)
        n = np.asarray(normal, float).reshape(3)
    except (TypeError, ValueError):  # not coordinates (a hand-edited scene.json)
        return None
    if len(p) < 3 or not np.all(np.isfinite(p)) or not np.linalg.norm(n) > 0:
        return None
    n = n / np.linalg.norm(n)
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(n, helper)
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    origin = p.mean(axis=0)
    ab = np.stack([(p - origin) @ u, (p - origin) @ v], axis=1)
    try:
        hull = ConvexHull(ab)
    except (QhullError, ValueError):
        return None
    poly = ab[hull.vertices]  # counter-clockwise for 2-D hulls
    region = AreaRegion(origin, u, v, n, poly)
    return region if region.area > 0 else None


def _plane_deviation(p: np.ndarray, n: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Distances of ``p`` from the plane through ``p[keep]`` (at least three points; the
    normal refit by SVD where the fit stays near ``n``)."""
    q = p[keep]
    c = q.mean(axis=0)
    fit = np.linalg.svd(q - c, full_matrices=False)[2][-1]
    return np.abs((p - c) @ (fit if abs(fit @ n) > 0.9 else n))


def on_emitting_plane(
    points: ArrayLike, normal: ArrayLike, tolerance: float = FACE_TOLERANCE
) -> np.ndarray:
    """``(N,)`` bool: which of a light's vertices lie on the plane of its emitting face.

    The plane starts with the light's ``normal`` through the vertices' median offset and
    is refit (SVD) to the vertices on it, three times. A vertex is on it within
    ``tolerance`` (the first time) and then within ``tolerance`` or three robust standard
    deviations (``1.4826 x`` the median distance) of the vertices kept, whichever is
    larger. Everything is kept when fewer than ``MIN_PLANE_SHARE`` of the vertices (or
    fewer than three) are on it, or the input is not finite: a light that is not flat
    has no such plane.
    """
    p = np.asarray(points, float).reshape(-1, 3)
    n = np.asarray(normal, float).reshape(3)
    everything = np.ones(len(p), bool)
    if len(p) < 3 or not np.all(np.isfinite(p)) or not np.linalg.norm(n) > 0:
        return everything
    n = n / np.linalg.norm(n)
    d = p @ n
    keep = np.abs(d - np.median(d)) <= tolerance
    for _ in range(3):
        if keep.sum() < 3:
            break
        # The scatter is the kept vertices' own: the rim's must not widen it.
        dev = _plane_deviation(p, n, keep)
        scatter = 3.0 * 1.4826 * float(np.median(dev[keep]))
        keep = dev <= max(float(tolerance), scatter)
    if keep.sum() < max(3, MIN_PLANE_SHARE * len(p)):
        return everything
    return keep


def emitting_face_plane(
    points: ArrayLike, region: AreaRegion, tolerance: float = FACE_TOLERANCE
) -> tuple[np.ndarray, np.ndarray] | None:
    """The plane of an area light's flat emitting face, ``(point on it, unit normal)``, or
    None when the light's vertices do not show one.

    Fitted (SVD) to the core of the light's vertices ``points``: of those inside
    ``region``, the ``CORE_SHARE`` furthest from its edge (never those on it). A
    depth-fused scan pulls the ring of vertices at a panel's edge towards the surface
    around it: on the issue's 300-frame fused `furnished` the panel's face lies at 2.680
    m (the truth's) more than 3 cm inside its edge and at 2.6845 m within 3 cm of it,
    towards the ceiling at 2.70, and the plane through all of them is tilted by half a
    degree. Drawn on the scan's faces, the emitter's edges sat up to 6 mm too high, and
    a camera that sees the panel at a grazing angle put them half a pixel off: most of
    that view's error (docs/invert.md, "Session 52").

    None (draw the light on the scan's faces) when there are fewer than three core
    points, when the fit's normal is more than 25 degrees from ``region.normal``, or
    when the core scatters about the fitted plane by more than ``tolerance`` (1.4826 x
    its median distance): a dome or a curved strip is not flattened. The normal is on
    ``region.normal``'s side.
    """
    n = region.normal
    p = np.asarray(points, float).reshape(-1, 3)
    p = p[np.all(np.isfinite(p), axis=1)]
    inside = p[region.contains(p)] if len(p) else p
    if len(inside) < 3:
        return None
    depth = region.edge_distance(inside)
    cut = float(np.quantile(depth, 1.0 - CORE_SHARE))
    # The outline's own corners lie on its edge: never its core, even when they are half
    # of the points (a small light on a coarse mesh).
    core = inside[depth >= cut] if cut > 0 else inside[depth > 0]
    if len(core) < 3:
        return None
    c = core.mean(axis=0)
    fit = np.linalg.svd(core - c, full_matrices=False)[2][-1]
    if fit @ n < 0:
        fit = -fit
    if fit @ n < np.cos(np.radians(25.0)):
        return None
    if 1.4826 * float(np.median(np.abs((core - c) @ fit))) > tolerance:
        return None
    return c, fit / np.linalg.norm(fit)


def onto_plane(
    points: ArrayLike, origin: ArrayLike, normal: ArrayLike, along: ArrayLike
) -> np.ndarray:
    """``points`` moved along the direction ``along`` onto the plane through ``origin``
    with ``normal`` (an outline's pieces put on its face: moved along the outline's own
    normal, their in-plane shape is kept). Points are returned unchanged where ``along``
    lies in the plane."""
    p = np.asarray(points, float).reshape(-1, 3)
    o, m, d = (np.asarray(x, float).reshape(3) for x in (origin, normal, along))
    denom = float(d @ m)
    if abs(denom) < 1e-9:
        return p.copy()
    t = ((o - p) @ m) / denom
    return p + t[:, None] * d


def clip_to_region(
    vertices: ArrayLike, faces: ArrayLike, region: AreaRegion
) -> tuple[np.ndarray, np.ndarray]:
    """The parts of triangles ``faces`` of ``vertices`` that project inside ``region``.

    Each triangle is clipped against the outline in the plane's coordinates
    (Sutherland-Hodgman: the intersection of a triangle and a convex polygon is convex)
    and the pieces are put back on the triangle's own plane, along the region's normal,
    in the triangle's winding (its front side stays its front side). Written by hand:
    trimesh slices by planes, not by a polygon's prism. Returns ``(vertices (M, 3),
    faces (K, 3))`` of the pieces, fan-triangulated; empty arrays when nothing is inside.
    """
    v = np.asarray(vertices, float)
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    poly = region.polygon
    out_v: list[np.ndarray] = []
    out_f: list[np.ndarray] = []
    count = 0
    for tri in v[f]:
        piece = [tuple(x) for x in region.plane_coordinates(tri)]
        for k in range(len(poly)):
            a, b = poly[k], poly[(k + 1) % len(poly)]
            piece = _clip_half_plane(piece, a, b)
            if not piece:
                break
        if len(piece) < 3:
            continue
        ab = np.asarray(piece, float)
        n_t = np.cross(tri[1] - tri[0], tri[2] - tri[0])
        denom = float(region.normal @ n_t)
        if abs(denom) < 1e-12 * max(float(np.linalg.norm(n_t)), 1e-30):
            continue  # edge-on to the plane: nothing of it shows from the room
        flat = region.origin + ab[:, :1] * region.u + ab[:, 1:] * region.v
        t = ((tri[0] - flat) @ n_t) / denom
        out_v.append(flat + t[:, None] * region.normal)
        m = len(ab)
        out_f.append(
            np.stack([np.zeros(m - 2, np.int64), np.arange(1, m - 1), np.arange(2, m)], 1) + count
        )
        count += m
    if not out_v:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    pv, pf = np.concatenate(out_v), np.concatenate(out_f)
    # Slivers where a face only touches the outline (a corner or an edge on it).
    t = pv[pf]
    double_area = np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
    pf = pf[double_area > 1e-12]
    if len(pf) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    used, local = np.unique(pf, return_inverse=True)
    return pv[used], local.reshape(-1, 3)


def _clip_half_plane(
    piece: list[tuple[float, float]], a: np.ndarray, b: np.ndarray
) -> list[tuple[float, float]]:
    """The part of the polygon ``piece`` left of the directed edge ``a -> b``."""
    ex, ey = b[0] - a[0], b[1] - a[1]
    tol = 1e-12 * (1.0 + ex * ex + ey * ey)

    def side(p: tuple[float, float]) -> float:
        return ex * (p[1] - a[1]) - ey * (p[0] - a[0])

    out: list[tuple[float, float]] = []
    n = len(piece)
    for k in range(n):
        p, q = piece[k], piece[(k + 1) % n]
        sp, sq = side(p), side(q)
        if sp >= -tol:
            out.append(p)
        if (sp >= -tol) != (sq >= -tol):
            s = sp / (sp - sq)
            out.append((p[0] + s * (q[0] - p[0]), p[1] + s * (q[1] - p[1])))
    return out
