"""Surface measurements and the point-light shading model, in any dimension.

This module is the part of light localization that does not care whether the scene is a
2D floor plan or a 3D scan: a measurement is a surface point ``x`` with its unit normal
``n`` and an *albedo-free* direct-light value ``B`` (radiance times ``pi / rho`` for a
diffuse surface of albedo ``rho``), and a point light of intensity ``I`` at ``p`` adds

    B(q) += I * S(q, p),   S(q, p) = V(x, p) * (n . (p - x))_+ / |p - x|^3     (thesis eq. 6.2)

to it, with ``V`` the visibility between ``x`` and ``p``. The same formula holds in 2D and
3D (the thesis keeps the inverse-square falloff in its 2D experiments: "due to quadratic
distance falloff"), so every function here takes ``(N, d)`` points for any ``d``.
Visibility is the only thing that needs the scene; callers pass it in as a boolean
``(N, K)`` matrix computed by the scene (exact segment tests in 2D, ray casts in 3D).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import ArrayLike

from reroom.errors import ReroomError

__all__ = [
    "LocalizeError",
    "Measurements",
    "render",
    "shading_jacobian",
    "shading_matrix",
]


class LocalizeError(ReroomError, ValueError):
    """Bad input to light localization (empty or inconsistent measurements, lights off-scene)."""


@dataclass(frozen=True)
class Measurements:
    """Direct-light measurements on surfaces.

    Parameters
    ----------
    points:
        ``(N, d)`` surface points ``x`` (metres, or any unit shared with the lights).
    normals:
        ``(N, d)`` unit normals ``n(x)`` pointing into the room.
    values:
        ``(N,)`` albedo-free direct light ``B(q)`` (radiance * pi / albedo for diffuse
        surfaces); non-negative for real data.
    """

    points: np.ndarray
    normals: np.ndarray
    values: np.ndarray

    def __post_init__(self) -> None:
        pts = np.asarray(self.points, dtype=np.float64)
        nrm = np.asarray(self.normals, dtype=np.float64)
        val = np.asarray(self.values, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[0] == 0 or pts.shape[1] not in (2, 3):
            raise LocalizeError(
                f"measurements: points must be a non-empty (N, 2) or (N, 3) array, got shape {pts.shape}"
            )
        if nrm.shape != pts.shape:
            raise LocalizeError(
                f"measurements: normals have shape {nrm.shape}, points have {pts.shape}"
            )
        if val.shape != (pts.shape[0],):
            raise LocalizeError(
                f"measurements: values have shape {val.shape}, expected ({pts.shape[0]},)"
            )
        if not (np.isfinite(pts).all() and np.isfinite(nrm).all() and np.isfinite(val).all()):
            raise LocalizeError("measurements: points, normals and values must all be finite")
        lens = np.linalg.norm(nrm, axis=1)
        if np.any(np.abs(lens - 1.0) > 1e-6):
            raise LocalizeError("measurements: normals must have unit length")
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "normals", nrm)
        object.__setattr__(self, "values", val)

    @property
    def dim(self) -> int:
        """Dimension of the scene (2 or 3)."""
        return int(self.points.shape[1])

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def with_values(self, values: ArrayLike) -> Measurements:
        """The same surface points carrying other values (e.g. the unexplained light)."""
        return Measurements(self.points, self.normals, np.asarray(values, dtype=np.float64))


def _check_lights(positions: ArrayLike, dim: int) -> np.ndarray:
    pos = np.asarray(positions, dtype=np.float64)
    if pos.ndim == 1 and pos.size == 0:
        pos = pos.reshape(0, dim)
    if pos.ndim != 2 or pos.shape[1] != dim:
        raise LocalizeError(f"light positions must be a (K, {dim}) array, got shape {pos.shape}")
    return pos


@numba.njit(cache=True)
def _shade(x, n, p, vis, has_vis, grad, s, ds):  # pragma: no cover
    npts, dim = x.shape
    for i in range(npts):
        for k in range(p.shape[0]):
            s[i, k] = 0.0
            if grad:
                for c in range(dim):
                    ds[i, k, c] = 0.0
            if has_vis and not vis[i, k]:
                continue
            dot = 0.0
            r2 = 0.0
            for c in range(dim):
                lc = p[k, c] - x[i, c]
                dot += n[i, c] * lc
                r2 += lc * lc
            if dot <= 0.0:
                continue
            inv_r3 = 1.0 / (r2 * np.sqrt(r2))
            s[i, k] = dot * inv_r3
            if grad:
                f = 3.0 * dot * inv_r3 / r2
                for c in range(dim):
                    ds[i, k, c] = n[i, c] * inv_r3 - f * (p[k, c] - x[i, c])


def _shade_call(points, normals, positions, visible, grad):
    x = np.ascontiguousarray(points, dtype=np.float64)
    n = np.ascontiguousarray(normals, dtype=np.float64)
    p = np.ascontiguousarray(_check_lights(positions, x.shape[1]))
    npts, k = x.shape[0], p.shape[0]
    has_vis = visible is not None
    vis = np.ascontiguousarray(visible, dtype=np.bool_) if has_vis else np.ones((1, 1), np.bool_)
    if has_vis and vis.shape != (npts, k):
        raise LocalizeError(f"visibility has shape {vis.shape}, expected ({npts}, {k})")
    s = np.empty((npts, k))
    ds = np.empty((npts, k, x.shape[1]) if grad else (1, 1, 1))
    _shade(x, n, p, vis, has_vis, grad, s, ds)
    return s, ds


def shading_matrix(
    points: ArrayLike,
    normals: ArrayLike,
    positions: ArrayLike,
    visible: np.ndarray | None = None,
) -> np.ndarray:
    """``S[q, k]``: direct light at measurement ``q`` from a unit-intensity light ``k`` (eq. 6.2).

    Parameters
    ----------
    points, normals:
        ``(N, d)`` surface points and unit normals.
    positions:
        ``(K, d)`` light positions.
    visible:
        Optional ``(N, K)`` boolean visibility; None means everything is visible.

    Returns
    -------
    ``(N, K)`` float64 array, zero where the light is behind the surface or hidden.
    """
    return _shade_call(points, normals, positions, visible, False)[0]


def shading_jacobian(
    points: ArrayLike,
    normals: ArrayLike,
    positions: ArrayLike,
    visible: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``S`` and its gradient with respect to the light positions.

    With ``l = p - x`` and ``r = |l|``, ``dS/dp = n / r^3 - 3 (n . l) l / r^5`` where
    ``n . l > 0`` (zero elsewhere: the clamp is flat there). Visibility is held fixed,
    as the thesis's optimizer does (§6.5.3: no closed form exists for its derivative).

    Returns
    -------
    s:
        ``(N, K)`` shading matrix.
    ds:
        ``(N, K, d)`` derivatives of ``s`` with respect to each light's coordinates.
    """
    return _shade_call(points, normals, positions, visible, True)


def render(
    points: ArrayLike,
    normals: ArrayLike,
    positions: ArrayLike,
    intensities: ArrayLike,
    visible: np.ndarray | None = None,
) -> np.ndarray:
    """Predicted direct light ``B(q) = sum_k I_k S(q, p_k)`` at every measurement (eq. 6.4)."""
    x = np.asarray(points, dtype=np.float64)
    p = _check_lights(positions, x.shape[1])
    inten = np.asarray(intensities, dtype=np.float64).reshape(-1)
    if inten.shape[0] != p.shape[0]:
        raise LocalizeError(f"{p.shape[0]} light positions but {inten.shape[0]} intensities")
    if p.shape[0] == 0:
        return np.zeros(x.shape[0])
    return shading_matrix(x, normals, p, visible) @ inten
