"""Direct sun through a window: a directional light found in the HDR mesh.

A window's light is solved as a piecewise-constant cube map (96 cells of 0.05-0.2 sr,
:class:`~reroom.invert.basis.CubemapBasis`). A clear sky's sun is a disc of about
7e-5 sr that can carry a sixth of the sky's light (the bundled ``city.exr``: 17 % of the
map's power in three texels). Spread over its cell, that light would fall on a large,
blurred region of the room, while the photos show a sharp sunlit patch: the patch is
far brighter than any cell can make it, and its light is mistaken for albedo, or
down-weighted as an outlier and lost.

So a window may carry a **sun**: a delta directional light of irradiance ``E_sun``
(per channel, at normal incidence) arriving along ``-s``, where ``s`` is the direction
a ray *leaves* the room in (the cube cells' convention). A receiver at ``x`` with normal
``n`` gets ``E_sun max(0, n . s)`` if the ray from ``x`` along ``s`` leaves through the
opening (it crosses the rectangle before anything else; the window's own pane faces do
not block, as in :func:`reroom.invert.portal.window_portal_transfer`), else nothing:
:func:`sun_transfer`. That transfer is exact (one ray per receiver, or a few over a
disc the size of the receiver's footprint, as an HDR vertex averages the pixels around
it), so the solve meets the sunlit patch with a sharp model of it.

:func:`find_sun` finds ``s`` without ground truth, from the HDR radiance: the sunlit
patch is the set of receivers whose rays along ``s`` leave through the opening, and it
is brighter than its surroundings. For each candidate direction (a Fibonacci grid over
the directions that leave through the opening, then finer grids around the best) the
score is Welch's t statistic of the log luminance of the receivers it lights against
the unlit receivers within ``neighbourhood`` of them: a sunlit patch has a sharp edge,
so the right direction puts a bright set against a darker ring, where a wrong one
straddles the patch or lands on a region that is bright for other reasons (near a
lamp, the wall beside the window) and its ring is as bright. (A correlation with the
whole room's brightness, tried first, preferred such large bright regions: on the
sunny `furnished` scan it picked a direction 65 degrees off, t 1.4 against 37 for the
true one.) The frames clip the patch (auto-exposed for the room, they see it white),
so its radiance is a lower bound: the test needs only the contrast. A sun is kept
only if the best t reaches ``min_score`` and its lit receivers are at least
``min_contrast`` times as bright (median luminance) as the ring; otherwise the window
has no sun (an overcast sky, a sun behind the building) and nothing changes. Last,
the patch must be the opening's image: along each of its edges the data show, the lit
receivers beside the edge are brighter than the ring receivers just beyond it
(:func:`_edge_contrasts`). A lamp's pool on a wall can line up with one edge of some
projection of the opening and pass the ring test (the real slambook2 scan, t 23), but
not along the others. ``reroom invert`` searches the wall, floor and ceiling receivers,
the ones its solve fits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from reroom.invert.windows import WindowOpening
from reroom.rays import RayCaster

__all__ = [
    "SUN_MAP_HEIGHT",
    "SunEstimate",
    "add_sun_to_map",
    "find_sun",
    "fold_sun_into_cells",
    "sun_power",
    "sun_transfer",
]

#: Rec. 709 luminance weights.
_LUMA = np.array([0.2126, 0.7152, 0.0722])


@dataclass
class SunEstimate:
    """Result of :func:`find_sun`.

    Attributes
    ----------
    direction:
        ``(3,)`` unit direction a ray leaves the room in, towards the sun.
    score:
        Welch's t of the lit receivers' log luminance against their unlit ring's.
    lit:
        Receivers the sun reaches along ``direction``.
    contrast:
        Median luminance of the lit receivers over that of their ring (the unlit
        receivers within ``neighbourhood`` metres of them).
    evaluations:
        Directions tried.
    """

    direction: np.ndarray
    score: float
    lit: int
    contrast: float
    evaluations: int

    def as_dict(self) -> dict:
        return {
            "direction": [round(float(x), 6) for x in self.direction],
            "score": round(float(self.score), 4),
            "lit_receivers": int(self.lit),
            "contrast": round(float(self.contrast), 3),
            "evaluations": int(self.evaluations),
        }


def _opening_coords(
    window: WindowOpening, direction: np.ndarray, points: np.ndarray, offset: float,
    normals: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Where each point's ray along ``direction`` meets the opening's plane: the distance
    ``t`` and the rectangle's coordinates ``u, v`` (``|u|, |v| <= 1`` inside; NaN for
    rays that do not reach the plane)."""
    s = np.asarray(direction, np.float64)
    denom = float(s @ window.normal)
    if denom >= 0:  # a ray leaving the room goes against the inward normal
        nan = np.full(len(points), np.nan)
        return nan, nan.copy(), nan.copy()
    start = points + offset * normals
    t = ((window.centre - start) @ window.normal) / denom
    rel = start + t[:, None] * s - window.centre
    u = rel @ window.half_u / float(window.half_u @ window.half_u)
    v = rel @ window.half_v / float(window.half_v @ window.half_v)
    behind = t <= 0
    for a in (t, u, v):
        a[behind] = np.nan
    return t, u, v


def _edge_contrasts(
    u: np.ndarray, v: np.ndarray, lit: np.ndarray, ring: np.ndarray, y: np.ndarray,
    min_count: int = 5,
) -> list[float]:  # fmt: skip
    """Median luminance ratio across each edge of the opening's image the data show.

    A sun's patch is the opening projected along the sun: along each of its four edges
    the lit receivers next to that edge (within 0.4 of it in the rectangle's
    coordinates) are brighter than the ring receivers whose rays pass just beyond it.
    Edges with fewer than ``min_count`` receivers on either side (hidden, off the mesh)
    are skipped.
    """
    out = []
    for coord, other in ((u, v), (v, u)):
        for sign in (-1.0, 1.0):
            inner = lit & (sign * coord > 0.6)
            outer = ring & (sign * coord > 1.0) & (np.abs(other) <= 1.0)
            if inner.sum() >= min_count and outer.sum() >= min_count:
                out.append(float(np.exp(np.median(y[inner]) - np.median(y[outer]))))
    return out


def _through_opening(
    caster: RayCaster,
    window: WindowOpening,
    direction: np.ndarray,
    points: np.ndarray,
    normals: np.ndarray,
    offset: float,
    tolerance: float,
    pane: np.ndarray | None,
) -> np.ndarray:
    """``(N,)`` bool: the ray from each point (offset along its normal) along
    ``direction`` crosses the opening's rectangle before meeting the mesh."""
    s = np.asarray(direction, np.float64)
    out = np.zeros(len(points), dtype=bool)
    t, u, v = _opening_coords(window, s, points, offset, normals)
    with np.errstate(invalid="ignore"):
        cand = (t > tolerance) & (np.abs(u) <= 1.0) & (np.abs(v) <= 1.0) & (normals @ s > 0)
    rows = np.flatnonzero(cand)
    if len(rows) == 0:
        return out
    start = points + offset * normals
    stop = t[rows] - tolerance
    blocked = caster.occluded(start[rows], s, tmax=stop)
    if pane is not None and blocked.any():
        b = rows[blocked]
        face = caster.intersect(start[b], s, tmax=t[b] - tolerance).face
        blocked[blocked] = (face >= 0) & ~pane[np.maximum(face, 0)]
    out[rows] = ~blocked
    return out


def _pane_mask(pane_faces: ArrayLike | None) -> np.ndarray | None:
    """The window's pane faces as a mask, None when there are none."""
    pane = None if pane_faces is None else np.asarray(pane_faces, bool)
    return pane if pane is not None and pane.any() else None


def sun_transfer(
    caster: RayCaster,
    window: WindowOpening,
    direction: ArrayLike,
    points: ArrayLike,
    normals: ArrayLike,
    *,
    offset: float | None = None,
    tolerance: float = 0.02,
    pane_faces: ArrayLike | None = None,
    footprint: float = 0.0,
    footprint_samples: int = 16,
) -> np.ndarray:
    """Irradiance at each point per unit sun irradiance (at normal incidence).

    Parameters
    ----------
    caster:
        Ray caster of the scan mesh.
    window:
        The opening the sun shines through (``normal`` into the room).
    direction:
        ``(3,)`` direction a ray leaves the room in, towards the sun.
    points, normals:
        ``(N, 3)`` receivers and their unit normals.
    offset:
        Metres the rays start above the receiver along its normal (default
        ``caster.eps``).
    tolerance:
        Metres short of the opening where the rays stop (a pane in the opening's plane
        does not block its own light).
    pane_faces:
        ``(F,)`` bool: the window's own faces, which do not block (None: all block).
    footprint, footprint_samples:
        With ``footprint > 0``, the lit fraction of a disc of that radius (metres) on
        each receiver's tangent plane, from ``footprint_samples`` rays on a Vogel
        spiral: a vertex on the patch's edge then reads part lit, as its HDR radiance
        does. 0: the point alone.

    Returns
    -------
    ndarray, shape (N,)
        ``max(0, n . s)`` times the lit fraction (1 or 0 for a point): the ray along
        ``s`` leaves through the opening.

    Examples
    --------
    A floor point straight below a skylight-like opening, the sun overhead:

    >>> import numpy as np, trimesh
    >>> from reroom.rays import RayCaster
    >>> from reroom.invert.windows import WindowOpening
    >>> floor = trimesh.Trimesh([[-5, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0]],
    ...                         [[0, 1, 2], [0, 2, 3]])
    >>> sky = WindowOpening("skylight", [0.0, 0, 3], [0.5, 0, 0], [0, 0.5, 0], [0, 0, -1])
    >>> sun_transfer(RayCaster(floor), sky, [0, 0, 1], [[0, 0, 0], [2, 0, 0]],
    ...              [[0, 0, 1], [0, 0, 1]]).tolist()
    [1.0, 0.0]
    """
    s = np.asarray(direction, np.float64).reshape(3)
    length = float(np.linalg.norm(s))
    if not np.isfinite(length) or length == 0.0:
        raise ValueError(f"the sun's direction must be a finite non-zero vector, got {s.tolist()}")
    s = s / length
    p = np.asarray(points, np.float64).reshape(-1, 3)
    n = np.asarray(normals, np.float64).reshape(-1, 3)
    pane = _pane_mask(pane_faces)
    eps = caster.eps if offset is None else float(offset)
    if footprint <= 0 or footprint_samples < 2:
        lit = _through_opening(caster, window, s, p, n, eps, tolerance, pane)
        return np.where(lit, np.maximum(n @ s, 0.0), 0.0)
    # The lit fraction of a disc of radius `footprint` on each receiver's tangent plane
    # (Vogel spiral): an HDR vertex's radiance is a mean over the pixels around it, so
    # a vertex on the patch's edge reads half lit, not lit.
    from reroom.rays.sampling import orthonormal_basis

    e1, e2 = orthonormal_basis(n)
    k = np.arange(footprint_samples) + 0.5
    r = footprint * np.sqrt(k / footprint_samples)
    a = k * np.pi * (3.0 - 5**0.5)
    frac = np.zeros(len(p))
    for rk, ak in zip(r, a, strict=True):
        q = p + rk * (np.cos(ak) * e1 + np.sin(ak) * e2)
        frac += _through_opening(caster, window, s, q, n, eps, tolerance, pane)
    return frac / footprint_samples * np.maximum(n @ s, 0.0)


def _fibonacci_directions(count: int) -> np.ndarray:
    i = np.arange(count) + 0.5
    z = 1.0 - 2.0 * i / count
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    phi = np.pi * (1.0 + 5**0.5) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _local_grid(centre: np.ndarray, radius: float, steps: int) -> np.ndarray:
    """Directions on a ``(2 steps + 1)^2`` grid of angular half-width ``radius`` around
    ``centre`` (tangent-plane offsets, normalised)."""
    c = centre / np.linalg.norm(centre)
    a = np.array([1.0, 0, 0]) if abs(c[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = np.cross(c, a)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(c, e1)
    off = np.linspace(-radius, radius, 2 * steps + 1)
    du, dv = np.meshgrid(off, off, indexing="ij")
    d = c + np.tan(du.ravel())[:, None] * e1 + np.tan(dv.ravel())[:, None] * e2
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def find_sun(
    caster: RayCaster,
    window: WindowOpening,
    points: ArrayLike,
    normals: ArrayLike,
    radiance: ArrayLike,
    *,
    pane_faces: ArrayLike | None = None,
    coarse: int = 1200,
    max_receivers: int = 6000,
    min_lit: int = 20,
    min_score: float = 12.0,
    min_contrast: float = 2.0,
    neighbourhood: float = 0.12,
    min_edges: int = 2,
    min_edge_contrast: float = 1.5,
    seed: int = 0,
) -> SunEstimate | None:
    """The direction of a sun shining through ``window``, from the observed radiance.

    Parameters
    ----------
    caster, window, points, normals:
        As :func:`sun_transfer`; the points are the observed receivers.
    radiance:
        ``(N, 3)`` their observed (HDR) radiance.
    pane_faces:
        The window's own faces.
    coarse:
        Directions on the sphere for the first search (those leaving through the
        opening are tried: about a quarter).
    max_receivers:
        The search scores a seeded subset of the receivers in front of the window; the
        final direction is scored on all of them.
    min_lit, min_score, min_contrast:
        A sun is reported only if it lights at least ``min_lit`` receivers, its t
        statistic reaches ``min_score`` and its patch is ``min_contrast`` times as
        bright as its ring (the unlit receivers within ``neighbourhood`` metres, or 1.5
        receiver spacings on a coarser mesh).
    min_edges, min_edge_contrast:
        The patch must also be the opening's image: at least ``min_edges`` of its four
        edges seen, each with the lit receivers beside it ``min_edge_contrast`` times
        as bright as the ring receivers just beyond it.
    seed:
        Seed of the subset.

    Returns
    -------
    SunEstimate or None
        None when no direction passes the tests (no sun).
    """
    from scipy.spatial import cKDTree

    p = np.asarray(points, np.float64).reshape(-1, 3)
    n = np.asarray(normals, np.float64).reshape(-1, 3)
    lum = np.asarray(radiance, np.float64).reshape(-1, 3) @ _LUMA
    ok = np.isfinite(lum) & (lum > 0) & ((p - window.centre) @ window.normal > 0)
    rows = np.flatnonzero(ok)
    if len(rows) < 2 * min_lit:
        return None
    pane = _pane_mask(pane_faces)
    y = np.log(lum[rows])
    rng = np.random.default_rng(seed)
    sub = (
        np.sort(rng.choice(len(rows), max_receivers, replace=False))
        if len(rows) > max_receivers
        else np.arange(len(rows))
    )
    evaluations = 0

    front = p[rows]
    # The ring must hold the patch's unlit neighbours on a coarse mesh too.
    spacing = float(np.median(cKDTree(front).query(front, k=2)[0][:, 1]))
    neighbourhood = max(float(neighbourhood), 1.5 * spacing)

    def score(d: np.ndarray, idx: np.ndarray) -> tuple[float, float, int]:
        """Welch's t of the log luminance, lit receivers against the unlit ones within
        ``neighbourhood`` of them; the median ratio; the lit count."""
        nonlocal evaluations
        evaluations += 1
        r = rows[idx]
        lit = _through_opening(caster, window, d, p[r], n[r], caster.eps, 0.02, pane)
        if lit.sum() < 3:
            return -np.inf, 0.0, int(lit.sum())
        pts = front[idx]
        lp = pts[lit]
        # Only unlit receivers in the lit set's box (grown by the ring) can be in the
        # ring: the query stays small however large the room.
        near = ~lit & np.all(
            (pts >= lp.min(axis=0) - neighbourhood) & (pts <= lp.max(axis=0) + neighbourhood),
            axis=1,
        )
        dist = cKDTree(lp).query(pts[near], distance_upper_bound=neighbourhood)[0]
        a = y[idx][lit]
        b = y[idx][near][np.isfinite(dist)]
        if len(b) < 3:
            return -np.inf, 0.0, int(lit.sum())
        t = (a.mean() - b.mean()) / np.sqrt(a.var() / len(a) + b.var() / len(b) + 1e-12)
        return float(t), float(np.exp(np.median(a) - np.median(b))), int(lit.sum())

    cand = _fibonacci_directions(coarse)
    cand = cand[cand @ window.normal < 0]
    scores = np.array([score(d, sub)[0] for d in cand])
    best = cand[int(np.argmax(scores))]
    step = np.sqrt(4 * np.pi / coarse)  # radians between coarse directions
    for radius in (step, step / 4, step / 16):
        grid = _local_grid(best, radius, 4)
        grid = grid[grid @ window.normal < 0]
        sc = np.array([score(d, sub)[0] for d in grid])
        best = grid[int(np.argmax(sc))]
    final, contrast, n_lit = score(best, np.arange(len(rows)))
    if n_lit < min_lit or final < min_score or contrast < min_contrast:
        return None
    # The patch must be the opening's image: sharp along every edge the data show, not
    # a bright region (a lamp's cone on a wall) that shares one edge with it.
    lit = _through_opening(caster, window, best, p[rows], n[rows], caster.eps, 0.02, pane)
    dist = cKDTree(front[lit]).query(front, distance_upper_bound=neighbourhood)[0]
    ring = np.isfinite(dist) & ~lit
    _, u, v = _opening_coords(window, best, p[rows], caster.eps, n[rows])
    edges = _edge_contrasts(u, v, lit, ring, y)
    if len(edges) < min_edges or min(edges) < min_edge_contrast:
        return None
    return SunEstimate(best / np.linalg.norm(best), final, n_lit, contrast, evaluations)


#: Lat-long height of a window's rendering map that shows a sun: a texel there is about
#: 0.7 degrees across at the horizon (the sun's disc is 0.53), so its shadows stay sharp.
SUN_MAP_HEIGHT = 256


def add_sun_to_map(
    env: np.ndarray, direction: ArrayLike, irradiance: ArrayLike, height: int = SUN_MAP_HEIGHT
) -> np.ndarray:
    """A window's ``(H, 2H, 3)`` lat-long rendering map with its sun drawn in.

    The map is first enlarged (nearest texel) to at least ``height`` rows; then the texel
    containing ``direction`` (the direction a ray leaves the room in) gets
    ``irradiance / solid angle`` more radiance, so that the map sends the sun's
    irradiance along it.

    Examples
    --------
    >>> from reroom.invert.window_env import latlong_solid_angles
    >>> env = add_sun_to_map(np.zeros((4, 8, 3)), [0.3, -0.5, 0.8], [2.0, 1.0, 0.5], 16)
    >>> env.shape, np.round((env * latlong_solid_angles(16)[..., None]).sum((0, 1)), 9).tolist()
    ((16, 32, 3), [2.0, 1.0, 0.5])
    """
    from reroom.invert.window_env import _texel_index, latlong_solid_angles

    env = np.asarray(env, np.float64)
    h = env.shape[0]
    if h < height:
        f = -(-height // h)
        env = np.repeat(np.repeat(env, f, axis=0), f, axis=1)
        h = env.shape[0]
    out = env.copy().reshape(-1, 3)
    k = int(_texel_index(np.asarray(direction, np.float64).reshape(1, 3), h)[0])
    out[k] += np.asarray(irradiance, np.float64) / latlong_solid_angles(h).ravel()[k]
    return out.reshape(h, 2 * h, 3)


def fold_sun_into_cells(
    cells: ArrayLike, basis, direction: ArrayLike, irradiance: ArrayLike
) -> np.ndarray:
    """The ``(6 n^2, 3)`` cube cells with the sun's light spread over the cell it is in.

    What the piecewise-constant basis would hold for the same sky (the ground truth's
    cells average the HDRI, sun included): irradiance over the cell's solid angle.
    """
    out = np.array(cells, np.float64)
    j = int(basis.cell_of(np.asarray(direction, np.float64).reshape(1, 3))[0])
    out[j] += np.asarray(irradiance, np.float64) / float(basis.cell_solid_angles()[j])
    return out


def sun_power(
    irradiance: ArrayLike, direction: ArrayLike, normal: ArrayLike, area: float
) -> np.ndarray:
    """Flux (per channel) the sun sends through an opening of ``area`` with inward ``normal``."""
    cos = max(0.0, -float(np.dot(np.asarray(direction, float), np.asarray(normal, float))))
    return np.asarray(irradiance, np.float64) * area * cos
