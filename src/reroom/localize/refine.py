"""The light refinement algorithm of thesis §6.5 (Algorithms 1-3) and its baselines.

Nothing here depends on the dimension of the scene. The scene enters through three
things the caller supplies:

* :class:`~reroom.localize.measurements.Measurements` (points, normals, albedo-free values);
* a *proposer*: ``propose(values, near=None, within=None) -> (M, d)`` candidate light
  positions from the voting function of the light ``values`` (strongest first), optionally
  only those within ``within`` of ``near`` (in 2D:
  :class:`~reroom.localize.fields.FieldProposer2D`);
* optionally a *visibility* function ``visibility(positions) -> (N, K) bool`` (or None when
  nothing occludes), held fixed during each nonlinear solve as in §6.5.3.

Algorithm 1 (``localize_lights``) keeps hypothesis lights ``X, I`` and the unexplained
light ``B' = B - render(X, I)``. Each iteration it proposes candidates from ``B'``,
associates them with the hypotheses (Algorithm 2); new ones join with intensity ``delta``
and trigger a linear intensity solve then a nonlinear position+intensity solve, which
ends the search when its mean squared error is below the tolerance. Matched hypotheses
gain ``delta`` of intensity, and every hypothesis moves to the candidate nearest it in the
voting function of ``B`` minus the other hypotheses (Algorithm 3). The search fails when
``B'`` turns negative (the hypotheses explain more light than there is).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from reroom.localize.measurements import LocalizeError, Measurements, shading_matrix
from reroom.localize.solve import (
    Visibility,
    fit_lights,
    fit_lights_lm,
    prune_lights,
    solve_intensities,
    split_lights,
)
from reroom.localize.solve import visible_at as _vis

__all__ = [
    "LocalizeResult",
    "RefineParams",
    "associate",
    "localize_lights",
    "random_restarts",
    "refine_positions",
    "single_round",
]

Proposer = Callable[..., np.ndarray]


@dataclass(frozen=True)
class RefineParams:
    """Settings of Algorithm 1.

    Attributes
    ----------
    increment:
        ``delta``, the intensity added to each matched hypothesis per iteration (thesis: 0.025).
    match_distance:
        ``d``, the light equality distance of Algorithms 2 and 3, in scene units.
    negative_tolerance:
        ``B'`` may dip this far below zero before the search gives up (thesis: 0; a tiny
        positive value absorbs rounding).
    max_iterations:
        Give up after this many iterations.
    max_lights:
        Give up when more hypotheses than this accumulate.
    time_limit:
        Give up after this many seconds (None: no limit).
    select:
        After success, revise the number of lights around the solution found: split
        lights that stand for a cluster
        (:func:`~reroom.localize.solve.split_lights`), then drop lights the measurements
        do not need (:func:`~reroom.localize.solve.prune_lights`). Not in the thesis's 2D
        algorithm (its real-scene runs drop weak lights, §6.6.3); without it a
        hypothesis left at zero intensity is reported as a light, and a low-error
        solution that merges a cluster of lights is returned as is.
    final_fit:
        When ``B'`` turns negative, run the intensity and nonlinear solves once more from
        the current (refined) hypotheses, and if that is not good enough, try splitting
        its lights (:func:`~reroom.localize.solve.split_lights`), before giving up. Not in
        the thesis, which only solves when new lights are discovered.
    """

    increment: float = 0.025
    match_distance: float = 0.07
    negative_tolerance: float = 1e-9
    max_iterations: int = 2000
    max_lights: int = 12
    time_limit: float | None = None
    select: bool = True
    final_fit: bool = True


@dataclass
class LocalizeResult:
    """What :func:`localize_lights` found.

    Attributes
    ----------
    success:
        Whether a solution with mean squared error below the tolerance was found.
    positions, intensities:
        The solution when successful; otherwise the last hypotheses.
    mse:
        Mean squared error of ``positions, intensities`` against the measurements.
    iterations:
        Iterations of Algorithm 1 run.
    optimizations:
        Nonlinear solves run (one per discovery of new lights).
    reason:
        Why the search stopped.
    seconds:
        Wall-clock time.
    """

    success: bool
    positions: np.ndarray
    intensities: np.ndarray
    mse: float
    iterations: int
    optimizations: int
    reason: str
    seconds: float
    discoveries: list[int] = field(default_factory=list)


def associate(
    hypotheses: np.ndarray, candidates: np.ndarray, distance: float
) -> tuple[np.ndarray, np.ndarray]:
    """Algorithm 2: which hypotheses have a candidate near them, and which candidates are new.

    Returns
    -------
    matched:
        Sorted indices of hypotheses within ``distance`` of some candidate.
    new:
        ``(M, d)`` candidates farther than ``distance`` from every hypothesis.
    """
    cand = np.asarray(candidates, dtype=np.float64)
    hyp = np.asarray(hypotheses, dtype=np.float64)
    if cand.shape[0] == 0:
        return np.zeros(0, dtype=np.int64), cand
    if hyp.shape[0] == 0:
        return np.zeros(0, dtype=np.int64), cand
    dist = np.linalg.norm(cand[:, None, :] - hyp[None, :, :], axis=-1)
    close = dist < distance
    matched = np.flatnonzero(close.any(axis=0))
    new = cand[~close.any(axis=1)]
    return matched, new


def refine_positions(
    meas: Measurements,
    positions: np.ndarray,
    intensities: np.ndarray,
    propose: Proposer,
    distance: float,
    visibility: Visibility | None = None,
) -> np.ndarray:
    """Algorithm 3: move each hypothesis to its peak in the votes of the light left for it.

    For hypothesis ``x``, the light ``B - render(X minus x)`` is what ``x`` alone should
    explain; the candidate of its voting function nearest ``x`` (within ``distance``)
    becomes the new position; with none, ``x`` stays. (The pseudocode's loop does not
    update its distance bound; taking the nearest is what "the one that corresponds to
    the current hypothesis light" means.)
    """
    k = positions.shape[0]
    if k == 0:
        return positions
    s = shading_matrix(meas.points, meas.normals, positions, _vis(visibility, positions))
    contrib = s * intensities[None, :]
    total = contrib.sum(axis=1)
    out = positions.copy()
    for i in range(k):
        own = meas.values - (total - contrib[:, i])
        cand = propose(own, near=positions[i], within=distance)
        if cand.shape[0]:
            dist = np.linalg.norm(cand - positions[i], axis=1)
            j = int(np.argmin(dist))
            if dist[j] < distance:
                out[i] = cand[j]
    return out


def localize_lights(
    meas: Measurements,
    propose: Proposer,
    bounds: tuple[ArrayLike, ArrayLike],
    tolerance: float,
    params: RefineParams | None = None,
    visibility: Visibility | None = None,
    on_iteration: Callable[[int, np.ndarray, np.ndarray, np.ndarray], None] | None = None,
) -> LocalizeResult:
    """Algorithm 1: find the number, positions and intensities of the point lights.

    Parameters
    ----------
    meas:
        Measurements ``B(q)`` of direct light.
    propose:
        Candidate positions from the voting function (see module docstring).
    bounds:
        ``(lo, hi)`` box that contains every light.
    tolerance:
        Success when the mean squared error of a solution is below this (thesis: 0.0025
        without noise; 105% of the ground truth's error with noise).
    params:
        :class:`RefineParams`.
    visibility:
        ``visibility(positions) -> (N, K)`` or None when nothing occludes.
    on_iteration:
        Called as ``on_iteration(iteration, positions, intensities, candidates)`` after
        each proposal, for progress reports and debugging.
    """
    prm = params or RefineParams()
    if prm.increment <= 0:
        raise LocalizeError(f"localize_lights: increment must be positive, got {prm.increment}")
    if tolerance <= 0:
        raise LocalizeError(f"localize_lights: tolerance must be positive, got {tolerance}")
    t0 = time.perf_counter()
    dim = meas.dim
    xs = np.zeros((0, dim))
    inten = np.zeros(0)
    n_opt = 0
    discoveries: list[int] = []
    last = (xs, inten, float(np.mean(meas.values**2)))
    neg_tol = prm.negative_tolerance * max(1.0, float(np.max(np.abs(meas.values))))

    def result(ok: bool, reason: str, it: int, sol=None) -> LocalizeResult:
        pos, ints, err = sol if sol is not None else last
        return LocalizeResult(
            ok, pos, ints, err, it, n_opt, reason, time.perf_counter() - t0, discoveries
        )

    stalled = False
    for it in range(prm.max_iterations):
        if prm.time_limit is not None and time.perf_counter() - t0 > prm.time_limit:
            return result(False, "time limit", it)
        vis = _vis(visibility, xs)
        unexplained = meas.values - (
            shading_matrix(meas.points, meas.normals, xs, vis) @ inten if xs.shape[0] else 0.0
        )
        if np.any(unexplained < -neg_tol):
            if prm.final_fit and xs.shape[0]:
                # Not in the thesis: one last solve from the refined hypotheses, which are
                # often better placed than at the last discovery.
                i_hat = solve_intensities(meas, xs, visibility)
                last = fit_lights(meas, xs, i_hat, bounds, visibility)
                n_opt += 1
                if last[2] >= tolerance:
                    # The usual reason to get here is a hypothesis standing for a cluster
                    # of lights that never voted apart (the thesis's Fig. 6.6b).
                    last = split_lights(
                        meas, *last[:2], bounds, prm.match_distance, visibility,
                        accept_below=tolerance,
                    )  # fmt: skip
                if last[2] < tolerance:
                    if prm.select:
                        last = _select(meas, last, bounds, tolerance, prm, visibility)
                    return result(True, "converged in the final solve", it, last)
            return result(False, "hypotheses explain more light than measured", it)
        cand = propose(unexplained)
        if on_iteration is not None:
            on_iteration(it, xs, inten, cand)
        matched, new = associate(xs, cand, prm.match_distance)
        if new.shape[0]:
            xs = np.concatenate([xs, new])
            inten = np.concatenate([inten, np.full(new.shape[0], prm.increment)])
            if xs.shape[0] > prm.max_lights:
                return result(False, "too many lights", it)
            discoveries.append(it)
            i_hat = solve_intensities(meas, xs, visibility)
            x_hat, i_hat, err = fit_lights(meas, xs, i_hat, bounds, visibility)
            n_opt += 1
            last = (x_hat, i_hat, err)
            if err < tolerance:
                if prm.select:
                    last = _select(meas, last, bounds, tolerance, prm, visibility)
                return result(True, "converged", it + 1, last)
        elif xs.shape[0] == 0:
            return result(False, "no candidate lights", it)
        if new.shape[0] == 0 and matched.size == 0 and it > 0 and stalled:
            return result(False, "stalled: no candidate near any hypothesis", it)
        inten = inten.copy()
        inten[matched] += prm.increment
        moved = refine_positions(meas, xs, inten, propose, prm.match_distance, visibility)
        # Nothing incremented and nothing moved twice in a row: the state is a fixed point.
        stalled = new.shape[0] == 0 and matched.size == 0 and np.array_equal(moved, xs)
        xs = moved
    return result(False, "iteration limit", prm.max_iterations)


def _select(
    meas: Measurements,
    sol: tuple[np.ndarray, np.ndarray, float],
    bounds: tuple[ArrayLike, ArrayLike],
    tolerance: float,
    prm: RefineParams,
    visibility: Visibility | None,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Prune, split clusters, prune again (see ``RefineParams.select``)."""
    pos, inten, err = prune_lights(meas, *sol[:2], bounds, tolerance, visibility)
    pos2, inten2, err2 = split_lights(meas, pos, inten, bounds, prm.match_distance, visibility)
    if pos2.shape[0] != pos.shape[0]:
        return prune_lights(meas, pos2, inten2, bounds, tolerance, visibility)
    return pos, inten, err


def single_round(
    meas: Measurements,
    propose: Proposer,
    bounds: tuple[ArrayLike, ArrayLike],
    tolerance: float,
    visibility: Visibility | None = None,
) -> LocalizeResult:
    """One round of voting, then the intensity and nonlinear solves (Table 6.1's ``V(p)`` column)."""
    t0 = time.perf_counter()
    cand = propose(meas.values)
    if cand.shape[0] == 0:
        return LocalizeResult(
            False, cand, np.zeros(0), float(np.mean(meas.values**2)), 1, 0, "no candidate lights",
            time.perf_counter() - t0,
        )  # fmt: skip
    i_hat = solve_intensities(meas, cand, visibility)
    x_hat, i_hat, err = fit_lights(meas, cand, i_hat, bounds, visibility)
    ok = err < tolerance
    return LocalizeResult(
        ok, x_hat, i_hat, err, 1, 1, "converged" if ok else "error above tolerance",
        time.perf_counter() - t0,
    )  # fmt: skip


def random_restarts(
    meas: Measurements,
    n_lights: int,
    bounds: tuple[ArrayLike, ArrayLike],
    tolerance: float,
    rng: np.random.Generator,
    n_starts: int = 100,
    intensity_range: tuple[float, float] = (1.0, 5.0),
    visibility: Visibility | None = None,
    init_bounds: tuple[ArrayLike, ArrayLike] | None = None,
    solver: str = "lm",
) -> np.ndarray:
    """The thesis's baseline: nonlinear solves from random starts, the light count known.

    Each start draws ``n_lights`` positions uniformly in ``init_bounds`` (default:
    ``bounds``) and intensities uniformly in ``intensity_range``, then runs
    a nonlinear solve within ``bounds``: the compiled Levenberg-Marquardt
    (``solver="lm"``, like the thesis's Ceres baseline, and fast enough for 100 starts per
    scene) or scipy's ``least_squares`` (``"trf"``, the solver of Algorithm 1).

    Returns
    -------
    ``(n_starts,)`` mean squared errors reached (success: below ``tolerance``).
    """
    if n_lights < 1:
        raise LocalizeError(f"random_restarts: need at least one light, got {n_lights}")
    if solver not in ("lm", "trf"):
        raise LocalizeError(f"random_restarts: unknown solver {solver!r}")
    lo, hi = (np.asarray(b, dtype=np.float64) for b in (init_bounds or bounds))
    errs = np.empty(n_starts)
    for s in range(n_starts):
        pos = lo + (hi - lo) * rng.random((n_lights, meas.dim))
        inten = rng.uniform(*intensity_range, size=n_lights)
        if solver == "lm":
            # Stopping at the tolerance is enough to count a success, and saves time.
            _, _, errs[s] = fit_lights_lm(meas, pos, inten, bounds, visibility, stop_mse=tolerance)
        else:
            _, _, errs[s] = fit_lights(meas, pos, inten, bounds, visibility)
    return errs
