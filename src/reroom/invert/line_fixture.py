"""How much of a line light's tube its fixture leaves open, in each direction bin.

A fluorescent tube is a diffuse cylinder: bare, it sends ``2 r L cos(phi)`` per metre
in every direction (projected width ``2 r`` times radiance ``L``), i.e. a *flat*
``i(theta, phi) = 2 r L`` in the line model ``i(theta, phi) cos(phi)`` of
:class:`~reroom.invert.basis.LineBasis`. In a fixture (housing, baffles, louvres) each
direction keeps the fraction of the tube's projected area whose rays leave the fixture:
``i(theta, phi) = 2 r L * open(theta, phi)``. :func:`line_open_fraction` integrates that
fraction per bin; it serves twice:

* the inverse rendering's shape prior for line lights
  (:class:`reroom.invert.pipeline.InvertOptions` ``line_shape_prior``), with the fixture
  taken from the *scanned* mesh (:func:`scan_fixture_caster`): the solved profile is
  pulled toward ``i0 * open`` with a free ``i0``;
* the evaluation's true profile (:func:`reroom.invert.evaluate.true_line_profile`), with
  the fixture taken from the synthetic scene's true parts.

Written by hand: no library integrates a cylinder's visible projected area through
arbitrary occluders; the rays themselves go to Embree (:class:`reroom.rays.RayCaster`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike

from reroom.invert.basis import LineBasis
from reroom.rays import RayCaster
from reroom.rays.geometry import segment_distance

__all__ = [
    "MAX_INSIDE_FRACTION",
    "back_face_fraction",
    "cos2_quantiles",
    "inside_fraction",
    "line_open_fraction",
    "scan_fixture_caster",
]

#: Above this fraction of rays from the tube that first meet a back face, the scanned
#: fixture is not resolved around the tube (the pipeline then drops the shape prior).
MAX_INSIDE_FRACTION = 0.05


def cos2_quantiles(lo: float, hi: float, u: np.ndarray) -> np.ndarray:
    """``phi`` in ``[lo, hi]`` at quantiles ``u`` of the density ``cos^2(phi)`` there.

    ``cos^2`` is the measure of a line light's power (``i cos(phi)`` per metre times
    ``d omega = cos(phi) dphi dtheta``), so the mean of ``i`` over such samples is the
    bin value that carries the bin's power.
    """

    def prim(p: np.ndarray) -> np.ndarray:
        return p / 2.0 + np.sin(2.0 * p) / 4.0

    grid = np.linspace(lo, hi, 2049)
    cdf = prim(grid) - prim(np.asarray(lo))
    return np.interp(u * cdf[-1], cdf, grid)


def _axis(p0: ArrayLike, p1: ArrayLike) -> tuple[np.ndarray, np.ndarray, float]:
    """``p0``, the unit direction to ``p1`` and the length; ValueError if zero."""
    a = np.asarray(p0, float).reshape(3)
    length = float(np.linalg.norm(np.asarray(p1, float).reshape(3) - a))
    if length == 0:
        raise ValueError("line light has zero length")
    return a, (np.asarray(p1, float).reshape(3) - a) / length, length


def line_open_fraction(
    occluded: Callable[..., np.ndarray],
    p0: ArrayLike,
    p1: ArrayLike,
    up: ArrayLike,
    radius: float,
    basis: LineBasis,
    reach: float,
    *,
    samples: int = 64,
    angles: int = 4,
    phi_angles: int = 48,
    seed: int = 0,
) -> np.ndarray:
    """Fraction of a tube's projected area that its fixture leaves open, per bin.

    For each direction, ``samples`` stratified points on the tube's surface facing it
    (along the length and across the projected width) cast a ray; the fraction that
    hits nothing within ``reach`` is that direction's open fraction. A bin's value is
    the mean over ``angles`` jittered ``theta`` strata times ``phi_angles / phi_bins``
    (at least 1) jittered ``phi`` strata equal in ``cos^2`` measure (the weight of a
    line's power), on both sides of ``up`` (the basis folds them) and, when the basis
    folds ``phi``, at ``+phi`` and ``-phi``.

    Parameters
    ----------
    occluded : callable
        ``occluded(points, directions, tmax=reach) -> (N,) bool``, e.g. a
        :meth:`reroom.rays.RayCaster.occluded` of the fixture without the tube itself.
    p0, p1 : array_like, shape (3,)
        Ends of the tube's axis.
    up : array_like, shape (3,)
        The line's ``d_perp`` (made perpendicular to the line here).
    radius : float
        Tube radius, metres; the rays start on its surface.
    basis : LineBasis
        The ``(theta, phi)`` bins.
    reach : float
        Metres: hits farther than this are not the fixture.
    samples, angles, phi_angles, seed
        Sampling (see above). Light leaving a channel through its open ends changes
        fast with ``phi``: on `furnished`'s tube the largest step between neighbouring
        large-``|phi|`` bins is 0.19 with 16 ``phi`` strata over 3 bins, 0.085 with 48
        (the default), 0.07 with 96 (``benchmarks/bench_line_fixture.py``).

    Returns
    -------
    ndarray, shape (basis.size,)
        Open fraction in ``[0, 1]`` per bin, in ``LineBasis`` order.

    Raises
    ------
    ValueError
        If the line has zero length, ``up`` is parallel to it, or ``radius <= 0``.
    """
    p0, dh, length = _axis(p0, p1)
    if not radius > 0:
        raise ValueError(f"tube radius must be positive, got {radius}")
    u_vec = np.asarray(up, float).reshape(3)
    u_vec = u_vec - (u_vec @ dh) * dh
    if np.linalg.norm(u_vec) < 1e-9:
        raise ValueError("up is parallel to the line light")
    u_vec /= np.linalg.norm(u_vec)
    side = np.cross(dh, u_vec)
    r = float(radius)
    rng = np.random.default_rng(seed)
    n_s = max(1, int(np.sqrt(samples / 8)))  # across the width
    n_l = max(1, samples // n_s)  # along the length
    il, is_ = np.meshgrid(np.arange(n_l), np.arange(n_s), indexing="ij")
    t_edges, p_edges = basis.theta_edges(), basis.phi_edges()
    n_p = max(1, phi_angles // basis.phi_bins)
    phi_signs = (1.0, -1.0) if basis.fold else (1.0,)
    frac = np.ones(basis.size)
    for k in range(basis.theta_bins):
        for j in range(basis.phi_bins):
            strata = (np.arange(angles) + rng.random(angles)) / angles  # jittered
            theta = t_edges[k] + (t_edges[k + 1] - t_edges[k]) * strata
            u = (np.arange(n_p) + rng.random(n_p)) / n_p
            phis = cos2_quantiles(p_edges[j], p_edges[j + 1], u)
            tt, pp, sg, ps = np.meshgrid(theta, phis, (1.0, -1.0), phi_signs, indexing="ij")
            tt, pp, sg, ps = tt.ravel(), pp.ravel(), sg.ravel(), ps.ravel()
            w_perp = np.cos(tt)[:, None] * u_vec + (sg * np.sin(tt))[:, None] * side
            w = np.cos(pp)[:, None] * w_perp + (ps * np.sin(pp))[:, None] * dh
            q = np.cross(dh, w_perp)
            m = len(w)
            along = length * (il.ravel() + rng.random((m, il.size))) / n_l
            across = r * (2 * (is_.ravel() + rng.random((m, is_.size))) / n_s - 1)
            pts = (
                p0
                + along[..., None] * dh
                + across[..., None] * q[:, None, :]
                + np.sqrt(np.maximum(r * r - across**2, 0.0))[..., None] * w_perp[:, None, :]
            ).reshape(-1, 3)
            ray_dirs = np.repeat(w, il.size, axis=0)
            hits = int(np.count_nonzero(occluded(pts, ray_dirs, tmax=reach)))
            frac[basis.index(k, j)] = 1.0 - hits / len(pts)
    return frac


def scan_fixture_caster(
    vertices: ArrayLike,
    faces: ArrayLike,
    p0: ArrayLike,
    p1: ArrayLike,
    radius: float,
    reach: float,
) -> RayCaster | None:
    """A ray caster of the scanned faces that can be a line light's fixture (or ``None``).

    Keeps the faces with a vertex within ``reach`` of the tube's axis (a capsule), minus
    the tube's own surface (faces whose vertices all lie within ``max(2 r, r + 1 cm)`` of
    the axis). A ceiling or wall within ``reach`` counts as fixture: the layout's labels
    cannot tell them apart there (on `furnished` they call the tube's housing and the
    baffles' lower edges "ceiling"), and light that meets a ceiling a few centimetres
    from the tube is the fixture's glow, not light into the room.

    Parameters
    ----------
    vertices : array_like, shape (V, 3)
    faces : array_like of int, shape (F, 3)
    p0, p1 : array_like, shape (3,)
        Ends of the tube's axis.
    radius : float
        Tube radius (metres).
    reach : float
        Metres around the axis that the fixture can occupy.
    """
    v = np.asarray(vertices, float)
    f = np.asarray(faces, np.int64)
    if len(v) == 0 or len(f) == 0:
        return None
    dist = segment_distance(v, p0, p1)
    tube = dist < max(2.0 * radius, radius + 0.01)
    near = dist <= reach
    keep = near[f].any(axis=1) & ~tube[f].all(axis=1)
    if not keep.any():
        return None
    used, inverse = np.unique(f[keep], return_inverse=True)
    # A tiny offset: rays start on the tube's surface, never on a fixture face.
    return RayCaster(v[used], inverse.reshape(-1, 3), eps=1e-6)


def inside_fraction(
    caster: RayCaster,
    p0: ArrayLike,
    p1: ArrayLike,
    radius: float,
    reach: float,
    rays: int = 4096,
    seed: int = 0,
) -> float:
    """Fraction of rays from the tube's surface whose first hit within ``reach`` is a back face.

    Random points on the tube's surface, each casting a ray in a random direction on
    the side it faces. On a scan that resolves the fixture every first hit is a front
    face (the housing's underside, a baffle's inner side): 0 on `furnished`'s 60-frame
    mesh. A fused (TSDF) scan can close a fixture's channel into a solid block with the
    tube half inside it; rays from inside then leave through back faces (0.31 of them on
    the 300-frame fused `furnished`), and :func:`line_open_fraction` would call the
    block's inside open. Needs consistently wound faces (outward normals), as a
    fused mesh's are.
    """
    a, dh, length = _axis(p0, p1)
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(rays, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    w_perp = d - (d @ dh)[:, None] * dh
    norm = np.linalg.norm(w_perp, axis=1, keepdims=True)
    ok = norm[:, 0] > 1e-6  # directions along the axis have no facing side
    d, w_perp = d[ok], w_perp[ok] / norm[ok]
    origins = a + (length * rng.random(len(d)))[:, None] * dh + float(radius) * w_perp
    return back_face_fraction(caster, origins, d, reach)


def back_face_fraction(
    caster: RayCaster, origins: np.ndarray, directions: np.ndarray, reach: float
) -> float:
    """Fraction of the rays whose first hit within ``reach`` is a back face (0 for none).

    What :func:`inside_fraction` and :func:`reroom.invert.point_fixture.point_inside_fraction`
    count: a light inside closed geometry sees the inside of its surfaces.
    """
    if len(directions) == 0:
        return 0.0
    hits = caster.intersect(origins, directions, tmax=reach)
    back = hits.hit & (np.einsum("ij,ij->i", hits.normals, directions) > 0)
    return float(back.mean())
