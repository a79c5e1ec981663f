"""The exposure solvers of reroom.hdr.solve on small exact and contaminated problems."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from reroom.errors import ReroomError
from reroom.hdr.observe import Observations
from reroom.hdr.solve import SolveOptions, SolveProblem, solve_exposures, solve_problem


def chain_problem(
    n_frames: int = 30, n_vertices: int = 400, window: int = 50, step: int = 12, seed: int = 0
):
    """Frames sliding along a strip of vertices and wrapping round (a loop closure)."""
    rng = np.random.default_rng(seed)
    t = np.exp(rng.normal(0.0, 0.6, (n_frames, 3)))
    t /= t[0]
    b = np.exp(rng.normal(-1.0, 0.8, (n_vertices, 3)))
    vi, fj = [], []
    for j in range(n_frames):
        vs = (np.arange(window) + j * step) % n_vertices
        vi.append(vs)
        fj.append(np.full(window, j))
    vi, fj = np.concatenate(vi), np.concatenate(fj)
    return t, b, vi, fj


@pytest.mark.parametrize(
    "method, tol",
    [("log-schur", 1e-10), ("linear-schur", 1e-10), ("alternating", 1e-6), ("scipy", 1e-6)],
)
def test_exact_problem_recovers_exposures(method, tol):
    t, b, vi, fj = chain_problem(n_frames=12, n_vertices=150, window=30, step=12)
    prob = SolveProblem.build(vi, fj, t[fj] * b[vi], len(t))
    opt = SolveOptions(method=method, robust=False, max_iterations=20000, tol=1e-14)
    sol = solve_problem(prob, opt)
    assert sol.reference == 0
    assert sol.status[0] == "reference"
    np.testing.assert_allclose(sol.scales, t, rtol=tol)
    assert np.all(sol.solved)


def test_exact_problem_with_robust_weights_and_hat_still_exact():
    t, b, vi, fj = chain_problem()
    w = np.random.default_rng(3).uniform(0.2, 1.0, len(vi))
    prob = SolveProblem.build(vi, fj, t[fj] * b[vi], len(t), w)
    sol = solve_problem(prob, SolveOptions())
    np.testing.assert_allclose(sol.scales, t, rtol=1e-9)


@pytest.mark.parametrize("loss", ["cauchy", "huber"])
def test_outliers_are_rejected_by_irls(loss):
    t, b, vi, fj = chain_problem(seed=1)
    rng = np.random.default_rng(2)
    x = t[fj] * b[vi] * np.exp(rng.normal(0, 0.01, (len(vi), 3)))
    bad = rng.random(len(vi)) < 0.08
    x[bad] *= rng.uniform(2.0, 6.0, (int(bad.sum()), 1))  # highlights: much brighter
    prob = SolveProblem.build(vi, fj, x, len(t))
    robust = solve_problem(prob, SolveOptions(robust=True, loss=loss))
    plain = solve_problem(prob, SolveOptions(robust=False))
    err_r = np.median(np.abs(robust.scales / t - 1))
    err_p = np.median(np.abs(plain.scales / t - 1))
    assert err_r < 0.01
    assert err_r < 0.5 * err_p


def test_reference_frame_option_and_single_channel():
    t, b, vi, fj = chain_problem()
    prob = SolveProblem.build(vi, fj, (t[fj] * b[vi])[:, 1], len(t))
    sol = solve_problem(prob, SolveOptions(reference=5))
    assert sol.scales.shape == (len(t), 1)
    np.testing.assert_allclose(sol.scales[:, 0], t[:, 1] / t[5, 1], rtol=1e-9)


def test_frames_without_samples_and_disconnected_groups():
    t, b, vi, fj = chain_problem(n_frames=10, n_vertices=1000, window=40, step=30)
    # Frames 0-4 overlap each other, and so do 5-6 and 8-9; the groups share nothing.
    keep = fj != 7  # frame 7 sees nothing
    vi2 = np.where(fj >= 5, vi + 5000, vi)
    prob = SolveProblem.build(vi2[keep], fj[keep], (t[fj] * b[vi])[keep], 10)
    with pytest.warns(UserWarning, match="share no vertex"):
        sol = solve_problem(prob, SolveOptions())
    assert np.all(np.isnan(sol.scales[7]))
    assert sol.status[7] == "no usable samples"
    assert sol.status[6].startswith("disconnected")
    np.testing.assert_allclose(sol.scales[:5], t[:5], rtol=1e-9)
    # Within each disconnected group the ratios are still right.
    np.testing.assert_allclose(sol.scales[6] / sol.scales[5], t[6] / t[5], rtol=1e-9)
    np.testing.assert_allclose(sol.scales[9] / sol.scales[8], t[9] / t[8], rtol=1e-9)
    assert np.all(np.isfinite(sol.scales[[5, 6, 8, 9]]))


def test_reference_moves_when_frame0_has_no_samples():
    t, b, vi, fj = chain_problem()
    keep = fj != 0
    prob = SolveProblem.build(vi[keep], fj[keep], (t[fj] * b[vi])[keep], len(t))
    sol = solve_problem(prob, SolveOptions())
    assert sol.reference == 1
    np.testing.assert_allclose(sol.scales[1:], t[1:] / t[1], rtol=1e-9)
    assert np.all(np.isnan(sol.scales[0]))


def test_empty_problem_gives_no_exposures():
    prob = SolveProblem.build(np.zeros(0), np.zeros(0), np.zeros((0, 3)), 4)
    sol = solve_problem(prob, SolveOptions())
    assert np.all(np.isnan(sol.scales)) and sol.reference == -1


def test_bad_inputs_raise():
    with pytest.raises(ReroomError, match="positive"):
        SolveProblem.build([0, 1], [0, 1], np.array([[1.0] * 3, [0.0] * 3]), 2)
    with pytest.raises(ReroomError, match="frame indices"):
        SolveProblem.build([0], [5], np.ones((1, 3)), 2)
    prob = SolveProblem.build([0, 0], [0, 1], np.ones((2, 3)), 2)
    with pytest.raises(ReroomError, match="unknown solver"):
        solve_problem(prob, SolveOptions(method="magic"))


def test_solve_exposures_from_8bit_observations():
    """Through 8-bit levels and the level filter: saturated and black frames get no exposure."""
    t, b, vi, fj = chain_problem(n_frames=12, n_vertices=300, window=60, step=10, seed=4)
    x = t[fj] * b[vi]
    x = x / x.max() * 0.9
    levels = np.clip(np.round(x * 255), 0, 255).astype(np.uint8)
    levels[fj == 3] = 255  # saturated frame
    levels[fj == 4] = 0  # black frame
    obs = Observations.from_arrays(300, 12, vi, fj, levels)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sol = solve_exposures(obs, SolveOptions(min_level=3, max_level=250))
    assert np.all(np.isnan(sol.scales[[3, 4]]))
    good = [j for j in range(12) if j not in (3, 4)]
    ratio = sol.scales[good] / t[good]
    assert np.all(np.isfinite(ratio))
    assert np.median(np.abs(ratio / ratio[0] - 1)) < 0.02
