"""Fitting point lights to measurements: linear intensities, nonlinear positions + intensities.

Dimension-free, like :mod:`reroom.localize.measurements`. The residual of lights
``(p_k, I_k)`` is ``r(q) = sum_k I_k S(q, p_k) - B(q)`` (eq. 6.4); the fits minimise
``sum_q r(q)^2`` and report the mean squared error, the quantity the thesis thresholds.

* :func:`solve_intensities`: positions fixed, ``B = S I`` is linear (§6.5.3, first step);
* :func:`fit_lights`: scipy's ``least_squares`` on positions and intensities (§6.5.3,
  second step; the thesis uses Ceres' Levenberg-Marquardt);
* :func:`fit_lights_lm`: a compiled projected Levenberg-Marquardt for the many short
  solves of the random-restart baseline, where scipy's per-iteration overhead dominates;
* :func:`prune_lights`, :func:`split_lights`: drop lights a solution does not need, split
  lights that stand for a cluster of lights.

Visibility, when given, is computed once at the starting positions and held fixed during
a solve, as in the thesis.
"""

from __future__ import annotations

from collections.abc import Callable

import numba
import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import least_squares, nnls

from reroom.localize.measurements import (
    LocalizeError,
    Measurements,
    shading_jacobian,
    shading_matrix,
)

__all__ = [
    "Visibility",
    "fit_lights",
    "fit_lights_lm",
    "mean_squared_error",
    "prune_lights",
    "solve_intensities",
    "split_lights",
]

Visibility = Callable[[np.ndarray], np.ndarray | None]


def visible_at(visibility: Visibility | None, positions: np.ndarray) -> np.ndarray | None:
    """``visibility(positions)``, or None when there is no visibility function or no light."""
    if visibility is None or positions.shape[0] == 0:
        return None
    return visibility(positions)


def _positions(meas: Measurements, positions: ArrayLike) -> np.ndarray:
    pos = np.asarray(positions, dtype=np.float64)
    if pos.size == 0:
        return pos.reshape(0, meas.dim)
    if pos.ndim != 2 or pos.shape[1] != meas.dim:
        raise LocalizeError(f"light positions must be (K, {meas.dim}), got shape {pos.shape}")
    return pos


def _bounds(
    meas: Measurements, bounds: tuple[ArrayLike, ArrayLike]
) -> tuple[np.ndarray, np.ndarray]:
    lo = np.asarray(bounds[0], dtype=np.float64).reshape(-1)
    hi = np.asarray(bounds[1], dtype=np.float64).reshape(-1)
    if lo.shape != (meas.dim,) or hi.shape != (meas.dim,) or np.any(hi <= lo):
        raise LocalizeError(f"bounds must be two {meas.dim}-vectors with lo < hi, got {lo}, {hi}")
    return lo, hi


def mean_squared_error(
    meas: Measurements,
    positions: ArrayLike,
    intensities: ArrayLike,
    visibility: Visibility | None = None,
) -> float:
    """Mean over measurements of ``(render(positions, intensities) - B)^2``."""
    pos = _positions(meas, positions)
    inten = np.asarray(intensities, dtype=np.float64).reshape(-1)
    if pos.shape[0] == 0:
        return float(np.mean(meas.values**2))
    s = shading_matrix(meas.points, meas.normals, pos, visible_at(visibility, pos))
    r = s @ inten - meas.values
    return float(np.mean(r * r))


def solve_intensities(
    meas: Measurements, positions: ArrayLike, visibility: Visibility | None = None
) -> np.ndarray:
    """Best non-negative intensities for lights fixed at ``positions`` (§6.5.3, first step).

    ``B = S I`` is linear in ``I``; the thesis solves it by least squares. Non-negative
    least squares is used because a negative light is not physical and would only mislead
    the nonlinear solve that follows.
    """
    pos = _positions(meas, positions)
    if pos.shape[0] == 0:
        return np.zeros(0)
    s = shading_matrix(meas.points, meas.normals, pos, visible_at(visibility, pos))
    # Lights near a wall have huge columns; equilibrate so they do not swamp the others.
    scale = np.linalg.norm(s, axis=0)
    scale[scale == 0] = 1.0
    x, _ = nnls(s / scale, meas.values, maxiter=50 * pos.shape[0] + 100)
    return x / scale


def _pack(pos: np.ndarray, inten: np.ndarray) -> np.ndarray:
    return np.concatenate([pos.ravel(), inten])


def fit_lights(
    meas: Measurements,
    positions: ArrayLike,
    intensities: ArrayLike,
    bounds: tuple[ArrayLike, ArrayLike],
    visibility: Visibility | None = None,
    max_nfev: int | None = None,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Nonlinear least squares on light positions and intensities (§6.5.3, second step).

    scipy's trust-region reflective solver with the analytic Jacobian; positions stay in
    the box ``bounds`` (a light on a wall makes ``S`` singular) and intensities
    non-negative.

    Returns
    -------
    positions, intensities, mse
    """
    pos = _positions(meas, positions)
    inten = np.asarray(intensities, dtype=np.float64).reshape(-1)
    k, dim = pos.shape
    if inten.shape[0] != k:
        raise LocalizeError(f"fit_lights: {k} positions but {inten.shape[0]} intensities")
    if k == 0:
        return pos, inten, float(np.mean(meas.values**2))
    lo, hi = _bounds(meas, bounds)
    vis = visible_at(visibility, pos)
    lb = _pack(np.tile(lo, (k, 1)), np.zeros(k))
    ub = _pack(np.tile(hi, (k, 1)), np.full(k, np.inf))
    x0 = _pack(pos, np.maximum(inten, 0.0))
    # least_squares wants a strictly feasible start.
    span = (hi - lo).min()
    x0[: k * dim] = np.clip(x0[: k * dim], lb[: k * dim] + 1e-6 * span, ub[: k * dim] - 1e-6 * span)
    x0[k * dim :] = np.maximum(x0[k * dim :], 1e-9)
    pts, nrm, b = meas.points, meas.normals, meas.values

    def residual(x: np.ndarray) -> np.ndarray:
        return shading_matrix(pts, nrm, x[: k * dim].reshape(k, dim), vis) @ x[k * dim :] - b

    def jacobian(x: np.ndarray) -> np.ndarray:
        s, ds = shading_jacobian(pts, nrm, x[: k * dim].reshape(k, dim), vis)
        jac_pos = (ds * x[k * dim :][None, :, None]).reshape(pts.shape[0], k * dim)
        return np.concatenate([jac_pos, s], axis=1)

    sol = least_squares(
        residual,
        x0,
        jac=jacobian,
        bounds=(lb, ub),
        method="trf",
        x_scale="jac",
        max_nfev=max_nfev or 100 * (k + 1),
    )
    return sol.x[: k * dim].reshape(k, dim), sol.x[k * dim :], float(np.mean(sol.fun**2))


@numba.njit(cache=True)
def _residual_jac(x, n, b, vis, has_vis, params, k, dim, jac, want_jac):  # pragma: no cover
    npts = x.shape[0]
    r = -b.copy()
    for kk in range(k):
        inten = params[k * dim + kk]
        for i in range(npts):
            if want_jac:
                for c in range(dim):
                    jac[i, kk * dim + c] = 0.0
                jac[i, k * dim + kk] = 0.0
            if has_vis and not vis[i, kk]:
                continue
            dot = 0.0
            r2 = 0.0
            for c in range(dim):
                lc = params[kk * dim + c] - x[i, c]
                dot += n[i, c] * lc
                r2 += lc * lc
            if dot <= 0.0:
                continue
            inv_r3 = 1.0 / (r2 * np.sqrt(r2))
            s = dot * inv_r3
            r[i] += inten * s
            if want_jac:
                f = 3.0 * dot * inv_r3 / r2
                for c in range(dim):
                    lc = params[kk * dim + c] - x[i, c]
                    jac[i, kk * dim + c] = inten * (n[i, c] * inv_r3 - f * lc)
                jac[i, k * dim + kk] = s
    return r


@numba.njit(cache=True)
def _lm(x, n, b, vis, has_vis, params, k, dim, lo, hi, max_iter, stop_cost):  # pragma: no cover
    npar = params.shape[0]
    jac = np.empty((x.shape[0], npar))
    # Trial residuals need no Jacobian; numba still wants an array for the argument.
    no_jac = np.empty((1, 1))
    r = _residual_jac(x, n, b, vis, has_vis, params, k, dim, jac, True)
    cost = np.dot(r, r)
    lam = 1e-3
    trial = np.empty(npar)
    for _ in range(max_iter):
        if cost <= stop_cost:
            break
        jtj = jac.T @ jac
        g = jac.T @ r
        diag = np.empty(npar)
        for c in range(npar):
            diag[c] = max(jtj[c, c], 1e-12)
        improved = False
        while lam < 1e12:
            a = jtj.copy()
            for c in range(npar):
                a[c, c] += lam * diag[c]
            step = np.linalg.solve(a, -g)
            # Project onto the box: positions inside the room, intensities non-negative.
            for c in range(npar):
                v = params[c] + step[c]
                if c < k * dim:
                    v = min(max(v, lo[c % dim]), hi[c % dim])
                else:
                    v = max(v, 0.0)
                trial[c] = v
            rt = _residual_jac(x, n, b, vis, has_vis, trial, k, dim, no_jac, False)
            ct = np.dot(rt, rt)
            if ct < cost:
                rel = (cost - ct) / cost
                params[:] = trial
                cost = ct
                r = _residual_jac(x, n, b, vis, has_vis, params, k, dim, jac, True)
                lam = max(lam / 3.0, 1e-12)
                improved = rel > 1e-10
                break
            lam *= 4.0
        if not improved:
            break
    return cost


def fit_lights_lm(
    meas: Measurements,
    positions: ArrayLike,
    intensities: ArrayLike,
    bounds: tuple[ArrayLike, ArrayLike],
    visibility: Visibility | None = None,
    max_iterations: int = 200,
    stop_mse: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Projected Levenberg-Marquardt on light positions and intensities (compiled).

    Marquardt's damping (``J^T J + lambda diag(J^T J)``), each step clipped to the box
    ``bounds`` and to non-negative intensities. It stops when a step no longer lowers the
    error, after ``max_iterations`` steps, or once the mean squared error is at most
    ``stop_mse`` (enough to decide success in the baseline).

    Returns
    -------
    positions, intensities, mse
    """
    pos = _positions(meas, positions)
    inten = np.asarray(intensities, dtype=np.float64).reshape(-1)
    k, dim = pos.shape
    if inten.shape[0] != k:
        raise LocalizeError(f"fit_lights_lm: {k} positions but {inten.shape[0]} intensities")
    if k == 0:
        return pos, inten, float(np.mean(meas.values**2))
    lo, hi = _bounds(meas, bounds)
    vis = visible_at(visibility, pos)
    has_vis = vis is not None
    vis_arr = np.ascontiguousarray(vis, dtype=np.bool_) if has_vis else np.ones((1, 1), np.bool_)
    params = _pack(np.clip(pos, lo, hi), np.maximum(inten, 0.0))
    npts = len(meas)
    cost = _lm(
        meas.points, meas.normals, meas.values, vis_arr, has_vis, params, k, dim, lo, hi,
        int(max_iterations), float(stop_mse) * npts,
    )  # fmt: skip
    return params[: k * dim].reshape(k, dim).copy(), params[k * dim :].copy(), float(cost / npts)


#: A change in the number of lights must change the error by at least this factor to count
#: as decisive: without noise a missing light of a cluster leaves an error orders of
#: magnitude above the exact solution's, while with noise an extra light only chases the
#: noise and gains tens of percent at most.
DECISIVE = 10.0

#: Errors below this fraction of ``mean(B^2)`` are rounding, not signal: a solution at
#: 1e-27 and one at 1e-20 are equally exact, and comparing them by ``DECISIVE`` would keep
#: a light split in two coincident halves (or split one to chase the last digits).
EXACT = 1e-14


def _error_floor(meas: Measurements) -> float:
    """The mean squared error below which two solutions count as equally exact."""
    return EXACT * max(float(np.mean(meas.values**2)), 1e-300)


def prune_lights(
    meas: Measurements,
    positions: np.ndarray,
    intensities: np.ndarray,
    bounds: tuple[ArrayLike, ArrayLike],
    tolerance: float,
    visibility: Visibility | None = None,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Drop lights, weakest first, while the re-fitted rest stays below ``tolerance`` and
    its error does not grow decisively (by ``DECISIVE`` or more).

    A hypothesis left at zero intensity, or a weak light chasing noise, goes; a light the
    measurements need stays. Returns ``positions, intensities, mse``.
    """
    pos, inten = positions, intensities
    err = mean_squared_error(meas, pos, inten, visibility)
    floor = _error_floor(meas)
    changed = True
    while changed and pos.shape[0] > 1:
        changed = False
        s = shading_matrix(meas.points, meas.normals, pos, visible_at(visibility, pos))
        # Weakest by the light it puts on the measured surfaces.
        for i in np.argsort(inten * s.sum(axis=0), kind="stable"):
            keep = np.arange(pos.shape[0]) != i
            p2, i2, e2 = fit_lights(meas, pos[keep], inten[keep], bounds, visibility)
            if e2 < tolerance and e2 < DECISIVE * max(err, floor):
                pos, inten, err, changed = p2, i2, e2, True
                break
    return pos, inten, err


def split_lights(
    meas: Measurements,
    positions: np.ndarray,
    intensities: np.ndarray,
    bounds: tuple[ArrayLike, ArrayLike],
    distance: float,
    visibility: Visibility | None = None,
    directions: int = 3,
    max_splits: int = 2,
    accept_below: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Try replacing each light by two, ``distance`` apart; keep splits the data demand.

    A tight cluster of lights can be explained, within a loose tolerance, by fewer
    lights between them (the thesis's Fig. 6.6a). Each light is split along a few
    directions into two of half its intensity and everything is re-fitted; the best split
    is kept when it lowers the error decisively (by ``DECISIVE`` or more), and the search
    repeats (at most ``max_splits`` times). Without noise a true split drops the error by
    orders of magnitude; with noise, a split that only chases the noise gains far less.
    A split that brings the error below ``accept_below`` is kept too (a solution that was
    not good enough becoming good enough is decisive whatever the factor).
    Returns ``positions, intensities, mse``.
    """
    pos, inten = positions, intensities
    err = mean_squared_error(meas, pos, inten, visibility)
    floor = _error_floor(meas)
    dim = meas.dim
    lo, hi = _bounds(meas, bounds)
    angles = np.pi * np.arange(directions) / directions
    for _ in range(max_splits):
        best = None
        for i in range(pos.shape[0]):
            for a in angles:
                u = np.zeros(dim)
                u[0], u[1] = np.cos(a), np.sin(a)
                pair = np.clip(pos[i] + 0.5 * distance * np.stack([u, -u]), lo, hi)
                p0 = np.concatenate([np.delete(pos, i, axis=0), pair])
                i0 = np.concatenate([np.delete(inten, i), [0.5 * inten[i]] * 2])
                # Trials with the compiled solver (most go nowhere); the winner is
                # polished with scipy's below.
                p2, i2, e2 = fit_lights_lm(meas, p0, i0, bounds, visibility, 100)
                good = max(e2, floor) * DECISIVE < err or (e2 < accept_below <= err)
                if good and (best is None or e2 < best[2]):
                    best = (p2, i2, e2)
        if best is None:
            break
        pos, inten, err = fit_lights(meas, best[0], best[1], bounds, visibility)
    return pos, inten, err
