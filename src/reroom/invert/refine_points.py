"""Refine point-light positions against the solved lighting (after a first solve).

Point-light positions come from ``reroom localize`` or from the user, and a few
centimetres matter: on the synthetic ``furnished`` scan, the localized floor lamp 0.16 m
off costs 2-3 points of wall and floor albedo and 6 of the panel's power, and the
downlight 0.04 m off 6-8 points of its own power (docs/benchmarks.md, "Which detected light
costs what"). The localize stage fits isotropic lights to the walls alone; the solve of
eq. 5.7 knows more (the albedos, the other lights, the light's own profile), so each point
light is moved to where that model explains the photos best.

For point light ``p`` the first solve gives what the other terms leave for it, in
irradiance units, at every clustered receiver ``q`` and channel ``c``::

    T_qc = pi Lbar_qc / rho_qc - E_ind_qc - sum_{l != p} F_ql I_lc     (eq. 5.6)

and the light's share is modelled as ``col_c sum_b F_qb(x) i_b`` (eq. 5.10, shadow rays
cast at every trial position ``x``). For each ``x`` the profile ``i >= 0`` is the
weighted least-squares fit (the solve's final weights times ``(rho / pi)^2``, so the terms are
the solve's own radiance residuals; a weak smoothness between neighbouring bins), and
Nelder-Mead searches ``x`` within ``max_shift`` of the start. The pipeline then
recomputes the moved lights' transfer, solves again and keeps the new positions only if
the objective of eq. 5.7 went down by ``InvertOptions.refine_min_gain`` (2 %).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.optimize

from reroom.invert.basis import InclinationBasis
from reroom.invert.direct import point_light_transfer
from reroom.rays import RayCaster

__all__ = ["PointRefinement", "refine_point_position"]


@dataclass
class PointRefinement:
    """Result of :func:`refine_point_position`.

    Attributes
    ----------
    position:
        ``(3,)`` the refined position (the start if nothing better was found).
    shift:
        Metres moved.
    cost_start, cost_end:
        Weighted squared residual of the light's share at the start and at ``position``.
    evaluations:
        Positions tried.
    """

    position: np.ndarray
    shift: float
    cost_start: float
    cost_end: float
    evaluations: int


def _profile_fit(
    f: np.ndarray, target: np.ndarray, weight: np.ndarray, color: np.ndarray, smooth: float
) -> tuple[np.ndarray, float]:
    """Non-negative profile ``i`` minimising ``sum w (T - col F i)^2`` (+ smoothness); cost."""
    # Normal equations summed over the channels: G = sum_c col_c^2 F^T W_c F.
    gram = np.zeros((f.shape[1], f.shape[1]))
    rhs = np.zeros(f.shape[1])
    cost0 = 0.0
    for c in range(3):
        fw = f * (weight[:, c] * color[c])[:, None]
        gram += color[c] * (fw.T @ f)
        rhs += fw.T @ target[:, c]
        cost0 += float(weight[:, c] @ target[:, c] ** 2)
    n = f.shape[1]
    scale = max(float(np.max(np.diag(gram))), 1e-300)
    d = np.diff(np.eye(n), axis=0)
    g = gram + smooth * scale * (d.T @ d) + 1e-12 * scale * np.eye(n)
    r = scipy.linalg.cholesky(g, lower=False)
    b = scipy.linalg.solve_triangular(r, rhs, trans="T", lower=False)
    prof, _ = scipy.optimize.nnls(r, b, maxiter=50 * n)
    cost = cost0 - 2 * float(prof @ rhs) + float(prof @ gram @ prof)
    return prof, max(cost, 0.0)


def refine_point_position(
    caster: RayCaster,
    points: np.ndarray,
    normals: np.ndarray,
    target: np.ndarray,
    weight: np.ndarray,
    color: np.ndarray,
    position: np.ndarray,
    axis: np.ndarray,
    basis: InclinationBasis,
    *,
    clearance: float = 0.3,
    fixture: float = 0.0,
    max_shift: float = 0.3,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
    smooth: float = 1e-3,
    max_evaluations: int = 120,
    free: tuple[int, ...] = (0, 1, 2),
    extra_starts: tuple[np.ndarray, ...] = (),
) -> PointRefinement:
    """Move one point light to where its share of the solved lighting fits best.

    Parameters
    ----------
    caster:
        Ray caster of the scene mesh (shadow rays).
    points, normals:
        ``(n, 3)`` receivers (the solve's clustered ones).
    target:
        ``(n, 3)`` the irradiance the other terms leave for this light (module notes).
    weight:
        ``(n, 3)`` non-negative weight of each term (0: ignored).
    color:
        ``(3,)`` the light's solved colour.
    position, axis:
        The light's starting position and axis of symmetry.
    basis:
        The inclination bins of its profile.
    clearance:
        Shadow-ray clearance around the light (``InvertOptions.point_clearance``).
    fixture:
        Receivers this close to the trial position are its fitting, not lit by the
        point model (``InvertOptions.fixture_margin``): the fitting moves with the light.
    max_shift:
        Metres the light may move at most.
    bounds:
        ``(lo, hi)`` box the light must stay in (e.g. the room), or None.
    smooth:
        Weight of the profile's smoothness relative to its largest data curvature.
    max_evaluations:
        Positions tried at most.
    free:
        The coordinates that may change (``(0, 1)``: only across the room, the height
        kept).
    extra_starts:
        More places to start the search from (each still within ``max_shift`` of
        ``position``); the lowest cost found wins. The objective can have a cliff a
        local search does not cross (a ceiling light: below the ceiling plane or in its
        can above it).
    """
    x0 = np.asarray(position, dtype=np.float64).reshape(3)
    ax = np.asarray(axis, dtype=np.float64).reshape(3)
    col = np.asarray(color, dtype=np.float64).reshape(3)
    keep = (weight > 0).any(axis=1) & np.isfinite(target).all(axis=1)
    p, n, t, w = points[keep], normals[keep], target[keep], weight[keep]
    lo = hi = None
    if bounds is not None:
        lo, hi = (np.asarray(b, dtype=np.float64).reshape(3) for b in bounds)
    seen: dict[tuple, float] = {}

    axes = np.asarray(free, dtype=np.int64)

    def full(y: np.ndarray) -> np.ndarray:
        x = x0.copy()
        x[axes] = y
        return x

    def cost(x: np.ndarray) -> float:
        key = tuple(np.round(x, 6))
        if key in seen:
            return seen[key]
        shift = float(np.linalg.norm(x - x0))
        if shift > max_shift or (lo is not None and (np.any(x < lo) or np.any(x > hi))):
            value = np.inf
        else:
            f = point_light_transfer(
                caster, p, n, x, ax, basis, clearance=clearance, fixture=fixture
            )
            value = _profile_fit(f, t, w, col, smooth)[1]
        seen[key] = value
        return value

    start = cost(x0)
    if not np.isfinite(start) or len(p) < basis.size:
        return PointRefinement(x0, 0.0, start, start, len(seen))
    step = min(0.05, max_shift / 2)
    best, end = x0, start
    for s0 in (x0, *(np.asarray(e, dtype=np.float64).reshape(3) for e in extra_starts)):
        y0 = s0[axes]
        simplex = np.vstack([y0, y0 + step * np.eye(len(axes))])
        sol = scipy.optimize.minimize(
            lambda y: cost(full(y)),
            y0,
            method="Nelder-Mead",
            options={
                "initial_simplex": simplex,
                "xatol": 0.002,
                "fatol": 1e-6 * start,
                "maxfev": max_evaluations,
            },
        )
        x = full(np.asarray(sol.x, dtype=np.float64))
        c = cost(x)
        if c < end:
            best, end = x, c
    return PointRefinement(best, float(np.linalg.norm(best - x0)), start, end, len(seen))
