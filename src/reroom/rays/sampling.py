"""Direction sampling on the hemisphere around surface normals.

Both the cosine-weighted and the uniform samplers go through Shirley and
Chiu's *concentric* map from the unit square to the unit disk, which is
area-preserving and has low distortion, so that a stratified (jittered) set of
points on the square stays well stratified on the hemisphere:

* cosine-weighted: Malley's method, lifting the disk point straight up,
  ``z = sqrt(1 - r^2)``; pdf ``cos(theta) / pi`` per steradian;
* uniform: the area-preserving disk-to-hemisphere map,
  ``z = 1 - r^2``, ``(x, y) *= sqrt(2 - r^2)``; pdf ``1 / (2 pi)``.

Local frames are built with the branchless orthonormal basis of Duff et al.,
"Building an Orthonormal Basis, Revisited" (JCGT 2017), which has no
singularity except exactly at ``n = (0, 0, -1)`` handled by its sign switch.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["concentric_disk", "orthonormal_basis", "sample_hemisphere", "unit_square_samples"]


def orthonormal_basis(normals: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents ``(t, b)`` such that ``(t, b, n)`` is a right-handed orthonormal frame.

    Parameters
    ----------
    normals:
        ``(..., 3)`` unit vectors.

    Returns
    -------
    t, b:
        ``(..., 3)`` float64 arrays.
    """
    n = np.asarray(normals, dtype=np.float64)
    nx, ny, nz = n[..., 0], n[..., 1], n[..., 2]
    # copysign rather than sign(): sign(0) is 0 and would divide by zero below.
    s = np.copysign(1.0, nz)
    a = -1.0 / (s + nz)
    b = nx * ny * a
    t = np.stack([1.0 + s * nx * nx * a, s * b, -s * nx], axis=-1)
    bt = np.stack([b, s + ny * ny * a, -ny], axis=-1)
    return t, bt


def concentric_disk(u: np.ndarray) -> np.ndarray:
    """Map points of the unit square ``(..., 2)`` to the unit disk (Shirley-Chiu concentric map)."""
    a = 2.0 * u[..., 0] - 1.0
    b = 2.0 * u[..., 1] - 1.0
    first = np.abs(a) > np.abs(b)
    r = np.where(first, a, b)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = np.where(first, (np.pi / 4.0) * (b / a), np.pi / 2.0 - (np.pi / 4.0) * (a / b))
    # a == b == 0 gives 0/0 above; that point is the disk centre whatever phi is.
    phi = np.where(r == 0.0, 0.0, phi)
    return np.stack([r * np.cos(phi), r * np.sin(phi)], axis=-1)


def _grid_shape(n: int) -> tuple[int, int] | None:
    """A near-square ``nx * ny == n`` grid, or None when ``n`` only factors into a thin strip."""
    nx = math.isqrt(n)
    while n % nx:
        nx -= 1
    ny = n // nx
    # A 1 x 7 "grid" stratifies only one axis; Latin hypercube sampling does better there.
    return (nx, ny) if ny <= 2 * nx else None


def unit_square_samples(
    n_points: int, n_per_point: int, rng: np.random.Generator, stratified: bool = True
) -> np.ndarray:
    """``(n_points, n_per_point, 2)`` samples in ``[0, 1)^2``, independent between points.

    With ``stratified``, each point's set is a jittered grid when ``n_per_point``
    factors into a near-square grid (``nx * ny`` with ``ny <= 2 nx``), and a
    Latin hypercube (``n`` strata on each axis, randomly paired) otherwise.
    """
    n = n_per_point
    jitter = rng.random((n_points, n, 2))
    if not stratified or n == 1:
        return jitter
    shape = _grid_shape(n)
    if shape is not None:
        nx, ny = shape
        k = np.arange(n)
        cells = np.stack([k % nx, k // nx], axis=-1).astype(np.float64)
        return (cells[None] + jitter) / np.array([nx, ny], dtype=np.float64)
    strata = np.broadcast_to(np.arange(n, dtype=np.float64), (n_points, n))
    u1 = (strata + jitter[..., 0]) / n
    u2 = (rng.permuted(strata, axis=1) + jitter[..., 1]) / n
    return np.stack([u1, u2], axis=-1)


def sample_hemisphere(
    normals: ArrayLike,
    n_per_point: int,
    rng: np.random.Generator | int | None = None,
    cosine: bool = True,
    stratified: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Sample directions on the hemisphere around each normal.

    Parameters
    ----------
    normals:
        ``(N, 3)`` or ``(3,)`` normals; they need not be unit length but must be
        finite and non-zero.
    n_per_point:
        Directions drawn per normal.
    rng:
        A :class:`numpy.random.Generator`, or a seed for one.
    cosine:
        Cosine-weighted (pdf ``cos(theta) / pi``) when True, uniform
        (pdf ``1 / (2 pi)``) when False.
    stratified:
        Jitter the samples of each point over a grid on the unit square (see
        :func:`unit_square_samples`) instead of drawing them independently.

    Returns
    -------
    directions:
        ``(N, n_per_point, 3)`` unit vectors with ``dot(direction, normal) >= 0``
        (``(n_per_point, 3)`` for a single ``(3,)`` normal), float64.
    pdf:
        ``(N, n_per_point)`` (or ``(n_per_point,)``) solid-angle densities.
        Monte Carlo estimates of ``integral f(w) dw`` are ``mean(f / pdf)``.

    Raises
    ------
    ValueError
        If ``normals`` has the wrong shape, non-finite or zero-length rows, or
        ``n_per_point < 1``.
    """
    n = np.asarray(normals, dtype=np.float64)
    single = n.ndim == 1
    n = np.atleast_2d(n)
    if n.ndim != 2 or n.shape[1] != 3:
        raise ValueError(f"normals must have shape (N, 3) or (3,), got {np.shape(normals)}")
    if n_per_point < 1:
        raise ValueError(f"n_per_point must be at least 1, got {n_per_point}")
    if not np.isfinite(n).all():
        raise ValueError("normals contain non-finite values")
    length = np.linalg.norm(n, axis=1)
    if np.any(length == 0.0):
        raise ValueError(f"normals contain {int(np.count_nonzero(length == 0.0))} zero vectors")
    n = n / length[:, None]
    rng = np.random.default_rng(rng)

    u = unit_square_samples(len(n), n_per_point, rng, stratified)
    d = concentric_disk(u)
    r2 = np.einsum("...i,...i->...", d, d)
    if cosine:
        z = np.sqrt(np.maximum(0.0, 1.0 - r2))
        x, y = d[..., 0], d[..., 1]
        pdf = z / np.pi
    else:
        z = 1.0 - r2
        scale = np.sqrt(np.maximum(0.0, 2.0 - r2))
        x, y = d[..., 0] * scale, d[..., 1] * scale
        pdf = np.full_like(z, 1.0 / (2.0 * np.pi))
    t, b = orthonormal_basis(n)
    dirs = x[..., None] * t[:, None] + y[..., None] * b[:, None] + z[..., None] * n[:, None]
    if single:
        return dirs[0], pdf[0]
    return dirs, pdf
