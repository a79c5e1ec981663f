"""The render window (:mod:`reroom.invert.render_window`): a window refitted alone on a
finer cube map with the other lights held."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import scipy.sparse as sp

from reroom.invert.basis import CubemapBasis
from reroom.invert.render_window import (
    block_columns,
    refit_window,
    render_model,
    upsample_cells,
)
from reroom.invert.solve import (
    InverseProblem,
    LightBlock,
    SolveOptions,
    model_irradiance,
    solve_lighting,
)

COARSE, FINE = CubemapBasis(4), CubemapBasis(8)
RHO = np.array([[0.7, 0.65, 0.6], [0.4, 0.3, 0.2], [0.8, 0.8, 0.8]])
AREA = np.array([[3.0, 2.8, 2.5]])


def _problem(fine_cells: np.ndarray, n: int = 4000, seed: int = 3):
    """A room lit by an area light and a window whose true map is ``fine_cells`` on the
    8x8 cube map; returns the coarse (4x4) problem, its blocks and the fine transfer."""
    rng = np.random.default_rng(seed)
    # Each receiver sees a random patch of the sky through the window: a sparse,
    # nonnegative transfer per fine cell; a coarse cell's is the sum of its fine ones'.
    f_fine = rng.exponential(0.01, (n, FINE.size)) * (rng.random((n, FINE.size)) < 0.15)
    parent = COARSE.cell_of(FINE.cell_directions())
    f_coarse = np.zeros((n, COARSE.size))
    for j in range(FINE.size):
        f_coarse[:, parent[j]] += f_fine[:, j]
    f_area = rng.uniform(0.2, 1.0, (n, 1))
    cluster = rng.integers(0, 3, n)
    indirect = rng.uniform(0.1, 0.3, (n, 3))
    radiance = RHO[cluster] / np.pi * (indirect + f_area * AREA + f_fine @ fine_cells)
    blocks = [
        LightBlock("area", "area", 1),
        LightBlock("window", "window", COARSE.size, False, COARSE.adjacency()),
    ]
    problem = InverseProblem(
        radiance=radiance,
        indirect=indirect,
        cluster=cluster,
        cluster_names=["wall", "floor", "ceiling"],
        transfer=sp.csr_matrix(np.hstack([f_area, f_coarse])),
        lights=blocks,
    )
    return problem, blocks, f_fine


def _fine_sky(seed: int = 4) -> np.ndarray:
    """A window map with structure inside the coarse cells (a bright band that a 4x4
    cell cannot place)."""
    d = FINE.cell_directions()
    band = np.exp(-(((d[:, 2] - 0.2) / 0.12) ** 2))
    return np.stack([1.0 + 6.0 * band * c for c in (1.0, 0.9, 0.7)], axis=1)


def test_with_the_other_lights_at_their_truth_the_fine_window_is_recovered() -> None:
    truth = _fine_sky()
    problem, blocks, f_fine = _problem(truth)
    coarse = solve_lighting(problem, SolveOptions())
    # The coarse basis cannot represent the band: the coarse solve does not fit exactly.
    assert coarse.objective > 1e-6
    held = replace(
        coarse, intensities={"area": AREA.copy(), "window": coarse.intensities["window"]}
    )
    window = refit_window(problem, held, blocks, 1, f_fine, FINE, COARSE, 0.0, SolveOptions())
    assert window.n == 8 and window.cells.shape == (FINE.size, 3)
    np.testing.assert_allclose(window.cells, truth, rtol=2e-3, atol=2e-3)
    np.testing.assert_allclose(window.albedo, RHO, rtol=1e-3)
    assert window.objective_fine < 1e-6 * window.objective_coarse
    np.testing.assert_allclose(window.support, np.abs(f_fine).sum(axis=0))


def test_a_window_the_coarse_cells_represent_comes_back_as_its_coarse_cells() -> None:
    coarse_truth = 1.0 + np.random.default_rng(8).random((COARSE.size, 3))
    truth = upsample_cells(coarse_truth, COARSE, FINE)
    problem, blocks, f_fine = _problem(truth)
    coarse = solve_lighting(problem, SolveOptions())
    np.testing.assert_allclose(coarse.intensities["window"], coarse_truth, rtol=2e-3)
    window = refit_window(problem, coarse, blocks, 1, f_fine, FINE, COARSE, 1.0, SolveOptions())
    np.testing.assert_allclose(window.cells, truth, rtol=5e-3)
    assert window.objective_fine <= window.objective_coarse + 1e-12


def test_the_render_model_swaps_only_the_windows_columns() -> None:
    truth = _fine_sky()
    problem, blocks, f_fine = _problem(truth)
    coarse = solve_lighting(problem, SolveOptions())
    window = refit_window(problem, coarse, blocks, 1, f_fine, FINE, COARSE, 1.0, SolveOptions())
    transfer, lights, result = render_model(
        problem.transfer, blocks, coarse, {"window": (window, f_fine)}
    )
    assert [b.size for b in lights] == [1, FINE.size] and transfer.shape[1] == 1 + FINE.size
    assert lights[1].adjacency is None and blocks[1].size == COARSE.size  # input kept
    got = model_irradiance(problem.indirect, transfer, lights, result)
    area = np.asarray(problem.transfer[:, :1].todense()) * coarse.intensities["area"]
    np.testing.assert_allclose(got, problem.indirect + area + f_fine @ window.cells)
    # the coarse result itself is untouched
    assert coarse.intensities["window"].shape == (COARSE.size, 3)
    same = render_model(problem.transfer, blocks, coarse, {})
    assert same[0] is problem.transfer and same[1] is blocks and same[2] is coarse


def test_bad_inputs_are_refused() -> None:
    problem, blocks, f_fine = _problem(_fine_sky(), n=500)
    coarse = solve_lighting(problem, SolveOptions())
    assert block_columns(blocks, 1) == slice(1, 1 + COARSE.size)
    with pytest.raises(ValueError, match="not a window"):
        refit_window(problem, coarse, blocks, 0, f_fine, FINE, COARSE, 1.0, SolveOptions())
    with pytest.raises(ValueError, match="fine transfer has shape"):
        refit_window(problem, coarse, blocks, 1, f_fine[:, :10], FINE, COARSE, 1.0, SolveOptions())


def test_photo_bounds_hold_up_the_cells_the_room_cannot_see() -> None:
    truth = _fine_sky()
    problem, blocks, f_fine = _problem(truth)
    # Half the fine cells light no receiver: the room says nothing about them, and the
    # smoothness alone pulls them to their neighbours.
    unseen = np.arange(FINE.size) % 2 == 0
    f_fine[:, unseen] = 0.0
    irradiance = problem.indirect + problem.transfer[:, :1].toarray() * AREA + f_fine @ truth
    problem = replace(problem, radiance=RHO[problem.cluster] / np.pi * irradiance)
    coarse = solve_lighting(problem, SolveOptions())
    held = replace(
        coarse, intensities={"area": AREA.copy(), "window": coarse.intensities["window"]}
    )
    # The photos prove a few unseen cells brighter than their neighbours make them, and
    # bound a few seen ones below their truth.
    lower = np.zeros((FINE.size, 3))
    proven = np.flatnonzero(unseen)[:12]
    lower[proven] = 8.0
    loose = np.flatnonzero(~unseen)[:12]
    lower[loose] = 0.5 * truth[loose]
    free = refit_window(problem, held, blocks, 1, f_fine, FINE, COARSE, 1.0, SolveOptions())
    bounded = refit_window(
        problem, held, blocks, 1, f_fine, FINE, COARSE, 1.0, SolveOptions(), lower=lower
    )
    assert free.bounded_cells == 0 and bounded.bounded_cells == 24
    assert (free.cells[proven] < 8.0).all()
    assert (bounded.cells >= lower - 1e-9).all()
    np.testing.assert_allclose(bounded.cells[proven], 8.0, rtol=1e-6)
    # what the room sees is fitted as before: the bounds that the truth meets cost nothing
    seen = ~unseen & (np.abs(f_fine).sum(axis=0) > 0)
    np.testing.assert_allclose(bounded.cells[seen], truth[seen], rtol=2e-2, atol=2e-2)
    assert bounded.objective_fine < 1e-6 * bounded.objective_coarse
