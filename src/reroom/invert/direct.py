"""Transfer from point and line lights to surface points, with shadow rays (eq. 5.10-5.12).

Point lights are decomposed into :class:`~reroom.invert.basis.InclinationBasis` bins, a
receiver getting light from exactly one bin. Line lights are decomposed into
:class:`~reroom.invert.basis.LineBasis` bins of ``(theta, phi)``: a receiver sees the
line under one ``theta`` but, along the line, under a range of ``phi``, so its row has
up to ``phi_bins`` non-zero entries, all in its ``theta`` bin (one entry with the
separable ``phi_bins = 1`` model of the thesis, or an ``InclinationBasis``). Values are
irradiance per unit radiant intensity of the bin (``I cos / d^2`` for a point light).

Angle conventions (they differ from the thesis on purpose)
----------------------------------------------------------
* Point light: ``theta = acos(a_hat . axis)`` with ``a`` pointing **from the light
  to the receiver** (the emission direction), so with ``axis`` = up, bin 0 lights
  the ceiling above the light and the last bin the floor straight below. The
  thesis writes ``a = P - V`` (receiver to light); its ``theta`` is ``pi`` minus ours.
* Line light: ``theta = acos(e_perp_hat . d_perp)`` where ``e_perp`` is the part
  of the direction **from the line to the receiver** perpendicular to the line
  and ``d_perp`` is ``up`` made perpendicular to the line; again the emission
  angle (thesis: ``acos(a_perp_hat . d_perp)`` with ``a`` towards the light, ``pi``
  minus ours). It does not depend on the position along the line, and it is
  symmetric about ``d_perp`` (both sides of a ceiling tube share bins), as in
  the thesis. ``phi`` is the angle of the emission direction out of the plane
  perpendicular to the line, positive towards ``p1``; it does depend on the position
  along the line (``tan(phi) = (s_foot - x) / h`` for the line point ``x`` and a
  receiver at distance ``h`` whose foot point is ``s_foot``).

Visibility is a shadow ray from the receiver (offset along its normal) to the
light point, stopped where it enters a sphere (point light) or cylinder (line
light) of radius ``clearance`` around the light, so that the light's own bulb or
tube mesh does not shadow it. A scanned tube of radius ``r`` hides its axis from
every oblique ray: the clearance must exceed ``r`` (the default 3 cm covers T5
and T8 tubes, radius 0.8 and 1.3 cm, and the synthetic scans' 1.6 cm, with room
for scan noise); dark baffles beside the tube then still cast shadows. The pipeline
passes 0.3 m for both kinds (``InvertOptions.point_clearance``, ``line_clearance``): the
fixture (shade, baffles, housing) is then part of the solved distribution, the light as
seen from outside it (docs/invert.md, "Line lights in channels").
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from reroom.invert import _kernels
from reroom.invert.basis import InclinationBasis, LineBasis
from reroom.rays import RayCaster

__all__ = [
    "DEFAULT_LINE_SEGMENTS",
    "line_light_transfer",
    "point_light_irradiance",
    "point_light_transfer",
]

#: Shadow-ray segments per line light; chosen in ``benchmarks/bench_transfer.py``.
DEFAULT_LINE_SEGMENTS = 32
#: Rays per occlusion call.
_BATCH = 1 << 21


def receiver_arrays(points: ArrayLike, normals: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Receiving points and unit normals as ``(N, 3)`` float arrays, checked.

    Shared by every light model's transfer. Raises ValueError for other shapes,
    non-finite points or zero normals.
    """
    p = np.atleast_2d(np.asarray(points, dtype=np.float64))
    n = np.atleast_2d(np.asarray(normals, dtype=np.float64))
    if p.ndim != 2 or p.shape[1] != 3 or n.shape != p.shape:
        raise ValueError(f"points and normals must both be (N, 3), got {p.shape} and {n.shape}")
    length = np.linalg.norm(n, axis=1)
    if np.any(~(length > 0)) or not np.isfinite(p).all():
        raise ValueError("points must be finite and normals non-zero")
    return p, n / length[:, None]


def _points_normals(
    points: ArrayLike, normals: ArrayLike, offset: float | ArrayLike | None, caster: RayCaster
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    p, n = receiver_arrays(points, normals)
    off = np.broadcast_to(
        np.asarray(caster.eps if offset is None else offset, dtype=np.float64), (len(p),)
    )
    return p, n, p + off[:, None] * n


def _unoccluded(
    caster: RayCaster, starts: np.ndarray, targets: np.ndarray, clearance: float | np.ndarray
) -> np.ndarray:
    """Whether the segments ``starts -> targets`` (minus ``clearance`` at the end) are free.

    ``clearance`` is a scalar or one value per segment; segments shorter than it are free.
    """
    seg = targets - starts
    dist = np.linalg.norm(seg, axis=1)
    stop = dist - np.broadcast_to(np.asarray(clearance, dtype=np.float64), dist.shape)
    free = np.ones(len(seg), dtype=bool)
    cast = np.flatnonzero(stop > 0)
    for s in range(0, len(cast), _BATCH):
        idx = cast[s : s + _BATCH]
        free[idx] = ~caster.occluded(starts[idx], seg[idx], tmax=stop[idx])
    return free


def point_light_transfer(
    caster: RayCaster,
    points: ArrayLike,
    normals: ArrayLike,
    position: ArrayLike,
    axis: ArrayLike,
    basis: InclinationBasis,
    *,
    offset: float | ArrayLike | None = None,
    clearance: float = 0.02,
    fixture: float = 0.0,
) -> np.ndarray:
    """Eq. 5.10: irradiance at each point per unit intensity of each inclination bin.

    Parameters
    ----------
    caster:
        Ray caster of the scene mesh (for the shadow rays).
    points, normals:
        ``(N, 3)`` receiving points and their normals.
    position:
        ``(3,)`` light position, metres.
    axis:
        ``(3,)`` the light's axis of symmetry (usually up, +Z).
    basis:
        The inclination bins.
    offset:
        Metres the shadow rays start above the surface along the normal (scalar or
        ``(N,)``); default ``caster.eps``.
    clearance:
        Radius (metres) of a sphere around the light inside which nothing occludes
        (the bulb's own mesh): shadow rays stop this far short of the light.
    fixture:
        Metres: points this close to the light are its fitting (a downlight's trim, a
        bulb's socket), which the point model does not describe; they get no transfer.
        Without it a receiver a centimetre from the light gets 1e3-1e4 times the
        transfer of the room's surfaces, which dominates the solve's scale of the
        light's smoothness (docs/invert.md, "The solve's subset").

    Returns
    -------
    ``(N, bins)`` float64: ``F[i, bin] = V(i) max(0, n . (P - x)) / |P - x|^3`` in the
    bin of ``theta = acos(unit(x - P) . axis)``, zero elsewhere.
    """
    value, cos_theta = _point_geometry(
        caster, points, normals, position, axis, offset, clearance, fixture
    )
    out = np.zeros((len(value), basis.bins))
    rows = np.flatnonzero(value > 0)
    out[rows, basis.bin_of(cos_theta[rows])] = value[rows]
    return out


def point_light_irradiance(
    caster: RayCaster,
    points: ArrayLike,
    normals: ArrayLike,
    position: ArrayLike,
    axis: ArrayLike,
    intensities: ArrayLike,
    *,
    interpolation: str = "linear",
    offset: float | ArrayLike | None = None,
    clearance: float = 0.02,
    fixture: float = 0.0,
) -> np.ndarray:
    """A point light's direct irradiance at each point, as the edit renderer draws it.

    ``intensities`` is the light's ``(bins, 3)`` profile (bin ``k`` of ``theta`` from
    the axis, as :func:`point_light_transfer`), read between bin centres with
    ``interpolation`` as the goniometric emitter reads it
    (:func:`reroom.render.line_emitter.line_profile_value`). ``offset``, ``clearance``
    and ``fixture`` as in :func:`point_light_transfer`.

    Returns
    -------
    ``(N, 3)`` float64: ``V(i) max(0, n . (P - x)) / |P - x|^3 J(theta)``.
    """
    from reroom.render.line_emitter import line_profile_value

    prof = np.asarray(intensities, np.float64)
    if prof.ndim != 2 or prof.shape[1] != 3:
        raise ValueError(f"intensities must be (bins, 3), got {prof.shape}")
    value, cos_theta = _point_geometry(
        caster, points, normals, position, axis, offset, clearance, fixture
    )
    out = np.zeros((len(value), 3))
    rows = np.flatnonzero(value > 0)
    theta = np.arccos(np.clip(cos_theta[rows], -1.0, 1.0))
    for c in range(3):
        out[rows, c] = value[rows] * line_profile_value(prof[:, c], theta, interpolation)
    return out


def _point_geometry(
    caster: RayCaster,
    points: ArrayLike,
    normals: ArrayLike,
    position: ArrayLike,
    axis: ArrayLike,
    offset: float | ArrayLike | None,
    clearance: float,
    fixture: float,
    occlusion: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 5.10's geometry per point: ``V max(0, cos_r) / d^2`` (0 where occluded or
    within ``fixture`` of the light) and ``cos theta`` of the emission direction.
    ``occlusion=False``: ``V = 1`` everywhere (no shadow rays; an upper bound)."""
    p, n, starts = _points_normals(points, normals, offset, caster)
    pos = np.asarray(position, dtype=np.float64).reshape(3)
    ax = np.asarray(axis, dtype=np.float64).reshape(3)
    ax = ax / np.linalg.norm(ax)
    to_light = pos - p
    d2 = np.einsum("ij,ij->i", to_light, to_light)
    d = np.sqrt(d2)
    with np.errstate(divide="ignore", invalid="ignore"):
        cos_r = np.einsum("ij,ij->i", n, to_light) / d
        value = np.where(cos_r > 0, cos_r / d2, 0.0)
        cos_theta = -(to_light @ ax) / d  # emission direction: light -> receiver
    value[~np.isfinite(value)] = 0.0
    if fixture > 0:
        value[d <= fixture] = 0.0
    if not occlusion:
        return value, cos_theta
    lit = np.flatnonzero(value > 0)
    value[
        lit[~_unoccluded(caster, starts[lit], np.broadcast_to(pos, (len(lit), 3)), clearance)]
    ] = 0
    return value, cos_theta


def _line_integral(h: np.ndarray, c0: np.ndarray, c1: np.ndarray, sa: np.ndarray, sb: np.ndarray):
    """``integral_sa^sb h max(0, c0 + c1 s) / (h^2 + s^2)^2 ds`` in closed form.

    This is eq. 5.11's unoccluded integrand: with ``s`` the position along the line
    relative to the receiver's foot point, ``|a|^2 = h^2 + s^2``, ``n . a = c0 + c1 s``
    and the projected-length factor ``|a_perp| / |a| = h / |a|``.
    """
    # Clip [sa, sb] to where the receiver faces the line (c0 + c1 s > 0).
    with np.errstate(divide="ignore", invalid="ignore"):
        root = -c0 / c1
    lo = np.where(c1 > 0, np.maximum(sa, root), sa)
    hi = np.where(c1 < 0, np.minimum(sb, root), sb)
    facing = np.where(c1 == 0, c0 > 0, hi > lo)
    lo, hi = np.where(facing, lo, 0.0), np.where(facing, hi, 0.0)

    def prim(s: np.ndarray) -> np.ndarray:
        q = h * h + s * s
        i0 = s / (2 * h * h * q) + np.arctan2(s, h) / (2 * h**3)  # integral of 1/q^2
        i1 = -1.0 / (2 * q)  # integral of s/q^2
        return h * (c0 * i0 + c1 * i1)

    return np.where(facing, prim(hi) - prim(lo), 0.0)


def _tan_phi_edges(basis: LineBasis) -> np.ndarray:
    """``tan`` of the ``phi`` bin edges, exactly infinite at ``+-pi/2``."""
    e = basis.phi_edges()
    t = np.tan(e)
    t[np.isclose(e, np.pi / 2)] = np.inf
    t[np.isclose(e, -np.pi / 2)] = -np.inf
    t[e == 0.0] = 0.0
    return t


def line_light_transfer(
    caster: RayCaster,
    points: ArrayLike,
    normals: ArrayLike,
    p0: ArrayLike,
    p1: ArrayLike,
    up: ArrayLike,
    basis: LineBasis | InclinationBasis,
    segments: int = DEFAULT_LINE_SEGMENTS,
    *,
    quadrature: str = "exact",
    offset: float | ArrayLike | None = None,
    clearance: float = 0.03,
) -> np.ndarray:
    """Eq. 5.11-5.12: irradiance per unit intensity (per metre of line) of each angle bin.

    The line is cut into ``segments`` equal pieces with one shadow ray to each
    piece's centre (eq. 5.12). With ``quadrature="exact"`` each visible piece
    contributes its exact unoccluded integral of eq. 5.11 (closed form), so the
    result is exact without occluders for any ``segments`` and only the shadow
    edges are resolved to a piece; ``"midpoint"`` is eq. 5.12 literally.

    With a :class:`~reroom.invert.basis.LineBasis` of ``phi_bins > 1``, each visible
    piece is further cut where the emission angle ``phi`` crosses a bin edge (at
    ``s = s_foot - h tan(phi_edge)`` along the line, and its mirror image when the basis
    folds ``phi``), and each part goes to its own ``(theta, phi)`` bin, again in closed
    form, so the bins' sum is the separable transfer. (``"midpoint"`` gives each
    piece's whole value to the bin of its centre's ``phi``.)

    Parameters
    ----------
    caster:
        Ray caster of the scene mesh.
    points, normals:
        ``(N, 3)`` receiving points and normals.
    p0, p1:
        ``(3,)`` ends of the line, metres.
    up:
        ``(3,)`` reference direction for the angle (world up); made perpendicular
        to the line, it is the thesis's ``d_perp``.
    basis:
        The angle bins: a :class:`~reroom.invert.basis.LineBasis`, or an
        :class:`~reroom.invert.basis.InclinationBasis` for the separable model (the
        same as a ``LineBasis`` with ``phi_bins = 1``).
    segments:
        Shadow-ray pieces along the line.
    quadrature:
        ``"exact"`` or ``"midpoint"`` (see above).
    offset:
        As for :func:`point_light_transfer`.
    clearance:
        Radius (metres) of a cylinder around the line inside which nothing
        occludes: the tube's own mesh and its immediate housing. Shadow rays stop
        where they enter it. Make it at least the tube's radius.

    Returns
    -------
    ``(N, basis.size)`` float64; column ``theta_bin * phi_bins + phi_bin``.

    Raises
    ------
    ValueError
        If the line has zero length, ``up`` is parallel to it, or ``segments < 1``.
    """
    if segments < 1:
        raise ValueError(f"segments must be positive, got {segments}")
    if quadrature not in ("exact", "midpoint"):
        raise ValueError(f"quadrature must be 'exact' or 'midpoint', not {quadrature!r}")
    lb = LineBasis.from_basis(basis)
    n_phi = lb.phi_bins
    p, n, starts = _points_normals(points, normals, offset, caster)
    a0 = np.asarray(p0, dtype=np.float64).reshape(3)
    d = np.asarray(p1, dtype=np.float64).reshape(3) - a0
    length = float(np.linalg.norm(d))
    if length == 0:
        raise ValueError("line light has zero length")
    dh = d / length
    u = np.asarray(up, dtype=np.float64).reshape(3)
    d_perp = u - (u @ dh) * dh
    if np.linalg.norm(d_perp) < 1e-9 * np.linalg.norm(u):
        raise ValueError("up is parallel to the line light")
    d_perp /= np.linalg.norm(d_perp)

    # Receiver coordinates: foot point along the line and perpendicular offset.
    rel = p - a0
    s_foot = rel @ dh
    e_perp = rel - s_foot[:, None] * dh  # from the line to the receiver
    h = np.linalg.norm(e_perp, axis=1)
    ok = h > 1e-9
    cos_theta = np.divide(e_perp @ d_perp, h, out=np.zeros_like(h), where=ok)
    # n . a with a = line point - receiver = -e_perp + (s - s_foot) dh, s' = s - s_foot.
    c0 = -np.einsum("ij,ij->i", n, e_perp)
    c1 = n @ dh
    hh = np.where(ok, h, 1.0)

    edges = np.linspace(0.0, length, segments + 1)
    mids = (edges[:-1] + edges[1:]) / 2.0
    tan_edges = _tan_phi_edges(lb)
    total = np.zeros((len(p), n_phi))
    # Points in batches so that points x segments (x phi bins) values fit in memory.
    step = max(1, _BATCH // (segments * n_phi))
    for b0 in range(0, len(p), step):
        b = slice(b0, min(len(p), b0 + step))
        sf = s_foot[b, None]
        if quadrature == "exact" and n_phi == 1:
            w = _line_integral(
                hh[b, None], c0[b, None], c1[b, None], edges[None, :-1] - sf, edges[None, 1:] - sf
            )[:, :, None]
        elif quadrature == "exact":
            nb = len(hh[b])
            w = np.empty((nb, segments, n_phi))
            _kernels.line_phi_integrals(
                hh[b], c0[b], c1[b], s_foot[b], edges, tan_edges, lb.fold, w
            )
        else:
            s = mids[None, :] - sf
            q = hh[b, None] ** 2 + s * s
            wm = hh[b, None] * np.maximum(c0[b, None] + c1[b, None] * s, 0) / q**2
            wm = wm * (length / segments)
            # The whole piece goes to the bin of its centre's phi (tan phi = -s / h).
            j = lb.phi_bin_of(np.arctan2(-s, hh[b, None]))
            w = np.zeros(wm.shape + (n_phi,))
            np.put_along_axis(w, j[..., None], wm[..., None], axis=2)
        w = np.where(ok[b, None, None], w, 0.0)
        rows, segs = np.nonzero(w.sum(axis=2) > 0)
        targets = a0 + mids[segs, None] * dh
        # Stop where the ray enters the cylinder of radius `clearance` around the line:
        # clearance / sin(angle between the ray and the line) short of the target.
        ray = targets - starts[b][rows]
        sin = np.linalg.norm(np.cross(ray, dh), axis=1) / np.linalg.norm(ray, axis=1)
        free = _unoccluded(caster, starts[b][rows], targets, clearance / np.maximum(sin, 1e-6))
        nb = w.shape[0]
        for j in range(n_phi):
            total[b, j] = np.bincount(rows, w[rows, segs, j] * free, minlength=nb)
    out = np.zeros((len(p), lb.size))
    lit = np.flatnonzero(total.sum(axis=1) > 0)
    cols = lb.theta_bin_of(cos_theta[lit])[:, None] * n_phi + np.arange(n_phi)[None, :]
    out[lit[:, None], cols] = total[lit]
    return out
