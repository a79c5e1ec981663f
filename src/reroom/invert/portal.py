"""Transfer from a window's distant light by sampling the opening, with shadow rays.

The hemisphere transfer (:func:`reroom.invert.hemisphere_transfer`) counts, per cube-map
cell, the cosine-weighted rays that leave a receiver through a window. That is unbiased
but far too noisy for the solve: a 1.6 x 1.3 m window 3 m away covers ~2 % of the
cosine-weighted hemisphere, which the 96 cells split further, so at 512 rays a receiver
sees a cell with 0, 1 or 2 rays. Worse, the voxel receivers' transfer is spread to their
neighbours. The fit then meets a transfer whose noise is as large as its signal, and a
least-squares coefficient on a noisy regressor is biased towards zero (regression
dilution): on the synthetic ``furnished`` scan the cells seen only at grazing angles past
the reveal came out 0 where the sky was brightest, the window's power 5-16 % low.

:func:`window_portal_transfer` integrates over the opening instead, as
:func:`reroom.invert.area.area_light_transfer` does over an area light:

    F_j(x) = integral_window V(x, y) [cell(y - x) = j] cos_x cos_y / |x - y|^2 dA_y

with stratified (jittered-grid) samples on the rectangle and one shadow ray each. The
shadow ray stops ``tolerance`` short of the opening, as
:func:`reroom.invert.windows.rays_through_windows` counts a ray that meets a pane lying
in the rectangle's plane as leaving through the window. The guide's own advice for the
path tracer ("sample windows as portals: a point on the opening, then the HDRI") is the
same estimator seen from the receiver.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike

from reroom.invert._kernels import portal_samples
from reroom.invert.basis import CubemapBasis, SHBasis
from reroom.invert.direct import receiver_arrays
from reroom.invert.windows import WindowOpening
from reroom.rays import RayCaster

__all__ = ["DEFAULT_WINDOW_SAMPLES", "window_portal_transfer"]

#: Samples on the opening per receiver (an 8 x 8 jittered grid: 256 gave the same solve; docs/invert.md).
DEFAULT_WINDOW_SAMPLES = 64
#: Receivers per batch (samples x batch shadow rays at a time).
_RECEIVERS_PER_BATCH = 2048


def window_portal_transfer(
    caster: RayCaster,
    window: WindowOpening,
    basis: CubemapBasis | SHBasis,
    points: ArrayLike,
    normals: ArrayLike,
    samples: int = DEFAULT_WINDOW_SAMPLES,
    *,
    seed: int = 0,
    offset: float | None = None,
    tolerance: float = 0.02,
    pane_faces: ArrayLike | None = None,
    direction_weight: Callable[[np.ndarray], np.ndarray] | None = None,
) -> np.ndarray:
    """Irradiance at each point per unit radiance of each distant-light basis function.

    Parameters
    ----------
    caster:
        Ray caster of the scan mesh (for the shadow rays).
    window:
        The opening; its ``normal`` points into the room. Light arrives through the
        side of the rectangle that faces the receiver.
    basis:
        The distant-light basis; a direction is that of the ray *leaving* the room
        (from the receiver through the opening), as in
        :class:`~reroom.invert.transfer.HemisphereTransfer`'s ``distant``.
    points, normals:
        ``(N, 3)`` receiving points and their normals.
    samples:
        Points on the opening per receiver, on a jittered ``k x k`` grid with
        ``k = ceil(sqrt(samples))``.
    seed:
        Seed of the jitter (the result is deterministic for a seed).
    offset:
        Metres the shadow rays start above the receiver along its normal;
        default ``caster.eps``.
    tolerance:
        Metres short of the opening where the shadow rays stop (a pane in the
        opening's plane does not block its own light).
    pane_faces:
        ``(F,)`` bool over the caster's triangles: the window's own surface (a glazed
        pane or bright region the light detector labelled as the window), which the
        shadow rays pass as the hemisphere transfer counts a hit on it as the window's
        light. None: every triangle blocks.
    direction_weight:
        ``f(directions (M, 3)) -> (M,)``: a weight per direction leaving the room, e.g.
        the sky's pattern within each cube cell
        (:func:`reroom.invert.window_env.cell_shapes`), so that a receiver that sees part
        of a cell gets that part's share of the cell's value. None: 1 (each cell flat).

    Returns
    -------
    ndarray, shape (N, basis.size)
        ``integral basis_j(w) V cos dw`` over the directions through the opening:
        the same quantity as ``HemisphereTransfer.distant[:, w, :]``, without its
        sampling noise.

    Raises
    ------
    ValueError
        If the shapes do not match, ``samples < 1`` or a normal is zero.
    """
    if samples < 1:
        raise ValueError(f"samples must be positive, got {samples}")
    p, n = receiver_arrays(points, normals)
    out = np.zeros((len(p), basis.size))
    if len(p) == 0:
        return out

    k = int(np.ceil(np.sqrt(samples)))
    s = k * k
    eps = caster.eps if offset is None else float(offset)
    rng = np.random.default_rng(seed)
    n_in = window.normal
    # Only receivers in front of the opening see through it (behind the wall plane they
    # cannot, whatever their normal), and only those with some corner of the (convex)
    # opening above their tangent plane: the others would cast no ray at all.
    front = (p - window.centre) @ n_in > 0
    corners = window.corners()
    front &= (np.einsum("nkd,nd->nk", corners[None, :, :] - p[:, None, :], n) > 0).any(axis=1)
    cube = isinstance(basis, CubemapBasis)
    pane = None if pane_faces is None else np.asarray(pane_faces, dtype=bool)
    if pane is not None and not pane.any():
        pane = None

    for b0 in range(0, len(p), _RECEIVERS_PER_BATCH):
        b1 = min(len(p), b0 + _RECEIVERS_PER_BATCH)
        rows = b0 + np.flatnonzero(front[b0:b1])
        m = len(rows)
        if m == 0:
            continue
        # A jittered k x k grid over the rectangle, a fresh jitter per receiver; the
        # kernel keeps the samples with both cosines positive.
        owner, start, seg, stop, value, d, count = portal_samples(
            p[rows], n[rows], window.centre, window.half_u, window.half_v, n_in, k,
            rng.random((m, s, 2)), eps, tolerance,
        )  # fmt: skip
        owner, start, seg, stop = owner[:count], start[:count], seg[:count], stop[:count]
        value, d = value[:count], d[:count]
        blocked = np.zeros(count, dtype=bool)
        test = stop > 0
        if test.any():
            blocked[test] = caster.occluded(start[test], seg[test], tmax=stop[test])
        if pane is not None and blocked.any():
            # Occluded by the window's own surface only? The closest hit says (the
            # cheaper occlusion query first: most rays are not blocked at all).
            b = np.flatnonzero(blocked)
            face = caster.intersect(start[b], seg[b], tmax=stop[b]).face
            blocked[b] = (face >= 0) & ~pane[np.maximum(face, 0)]
        live = ~blocked
        # Each sample stands for area / s of the opening.
        weight = value[live] * (window.area / s)
        if direction_weight is not None:
            weight = weight * np.asarray(direction_weight(d[live]), np.float64)
        if cube:
            key = owner[live] * basis.size + basis.cell_of(d[live])
            out[rows] = np.bincount(key, weight, minlength=m * basis.size).reshape(m, basis.size)
        else:
            vals = basis.evaluate(d[live]) * weight[:, None]
            for j in range(basis.size):
                out[rows, j] = np.bincount(owner[live], vals[:, j], minlength=m)
    return out
