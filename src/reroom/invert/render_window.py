"""A finer window map for the renders, refitted with every other light held.

The thesis solves a window's distant light on a 4x4-per-face cube map (96 cells), and
reroom's evaluation of the window (its power, its cells) keeps that basis. A cell of
that map spans about 22 degrees, and on `furnished` the window's light into the far
corner of the room (cells 11-14 degrees up beside the window's axis) is solved at a
quarter of the truth, with the cells above it at 1.3-1.7 x: the basis cannot place the
light (docs/invert.md, "Session 34"). Solving every light at 8x8 cells fixed the
window's renders but let the tube go 10 % dim.

So the renders get a window of their own: after the solve, each window is solved again
alone on a finer cube map, with the other lights' solved irradiance folded into the
indirect light (held), and the textures and per-vertex albedos are computed with that
finer model, so that what the renderer shows and what the photos were divided by agree.
The coarse solve and every light's figures in ``scene.json`` stay as they were.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp

from reroom.invert.basis import CubemapBasis
from reroom.invert.solve import (
    InverseProblem,
    LightBlock,
    SolveOptions,
    SolveResult,
    solve_lighting,
)


@dataclass
class RenderWindow:
    """A window's finer map for rendering (:func:`refit_window`).

    Attributes
    ----------
    name : str
        The window.
    n : int
        Cells per cube face edge of the fine map.
    cells : ndarray, shape (6 n^2, 3)
        The solved fine cells (radiance; the cell of the direction a ray leaves in).
    support : ndarray, shape (6 n^2,)
        Summed transfer of each fine cell over the fitted receivers (green).
    albedo : ndarray, shape (C, 3)
        The cluster albedos the refit solved with them (reported, not used: the
        model's albedos stay the coarse solve's).
    objective_coarse, objective_fine : float
        The refit problem's weighted squared residual (radiance units, the refit's
        albedos and final weights) with the coarse window (its cells spread over the
        fine ones) and with the fine cells.
    bounded_cells : int
        How many fine cells had a lower bound above 0 (``lower``).
    """

    name: str
    n: int
    cells: np.ndarray
    support: np.ndarray
    albedo: np.ndarray
    objective_coarse: float
    objective_fine: float
    bounded_cells: int = 0


def block_columns(blocks: list[LightBlock], index: int) -> slice:
    """The columns of ``blocks[index]`` in the stacked transfer matrix."""
    start = int(sum(b.size for b in blocks[:index]))
    return slice(start, start + blocks[index].size)


def upsample_cells(cells: np.ndarray, coarse: CubemapBasis, fine: CubemapBasis) -> np.ndarray:
    """Coarse cube-map cells spread over a finer cube map (each fine cell takes the value
    of the coarse cell its centre falls in)."""
    return np.asarray(cells, float)[coarse.cell_of(fine.cell_directions())]


def refit_window(
    problem: InverseProblem,
    result: SolveResult,
    blocks: list[LightBlock],
    index: int,
    fine_transfer: np.ndarray,
    fine: CubemapBasis,
    coarse: CubemapBasis,
    smooth: float,
    options: SolveOptions,
    progress=None,
    lower: np.ndarray | None = None,
) -> RenderWindow:
    """Solve the window ``blocks[index]`` again on the finer basis ``fine``, alone.

    Parameters
    ----------
    problem : InverseProblem
        The problem the coarse solve fitted (its rows).
    result : SolveResult
        The coarse solve.
    blocks : list of LightBlock
        ``problem``'s lights (``problem.lights``).
    index : int
        Which of them is the window.
    fine_transfer : ndarray, shape (n, 6 m^2)
        The window's transfer on the fine basis at ``problem``'s rows.
    fine, coarse : CubemapBasis
        The fine basis and the one the window was solved on.
    smooth : float
        Weight of the smoothness between neighbouring fine cells (relative to the
        solve's, as ``InvertOptions.window_smooth``).
    options : SolveOptions
        The solve's options (its Huber loss and eq. 5.8 reweighting).
    lower : ndarray, shape (6 m^2, 3), optional
        Lower bounds on the fine cells (what the photos' clipped and unclipped pixels
        prove, :func:`reroom.invert.window_env.cell_lower_bounds`; joint solver only).

    Returns
    -------
    RenderWindow
    """
    block = blocks[index]
    if block.kind != "window":
        raise ValueError(f"{block.name!r} is a {block.kind} light, not a window")
    fine_transfer = np.asarray(fine_transfer, float)
    if fine_transfer.shape != (len(problem.radiance), fine.size):
        raise ValueError(
            f"fine transfer has shape {fine_transfer.shape}, expected "
            f"({len(problem.radiance)}, {fine.size})"
        )
    cols = block_columns(blocks, index)
    held = result.intensity_vector(blocks).copy()
    held[cols] = 0.0
    # Every other light (a window's sun too) at its solved intensities: light the refit
    # cannot change, like the indirect light.
    indirect = problem.indirect + np.asarray(sp.csr_matrix(problem.transfer) @ held)
    pairs = fine.adjacency()
    light = LightBlock(
        block.name,
        "window",
        fine.size,
        False,
        pairs,
        adjacency_weights=np.full(len(pairs), float(smooth)),
        lower=None if lower is None else np.asarray(lower, float),
    )
    refit = InverseProblem(
        radiance=problem.radiance,
        indirect=indirect,
        cluster=problem.cluster,
        cluster_names=problem.cluster_names,
        transfer=sp.csr_matrix(fine_transfer),
        lights=[light],
    )
    solved = solve_lighting(refit, options, progress)
    start = upsample_cells(result.intensities[block.name], coarse, fine)
    at_coarse = _objective(refit, solved, start)
    at_fine = _objective(refit, solved, np.asarray(solved.intensities[block.name], float))
    support = np.asarray(np.abs(fine_transfer).sum(axis=0)).ravel()
    return RenderWindow(
        name=block.name,
        n=fine.n,
        cells=np.asarray(solved.intensities[block.name], float),
        support=support,
        albedo=np.asarray(solved.albedo, float),
        objective_coarse=at_coarse,
        objective_fine=at_fine,
        bounded_cells=0 if lower is None else int(np.count_nonzero(np.max(lower, axis=1) > 0)),
    )


def _objective(problem: InverseProblem, solved: SolveResult, cells: np.ndarray) -> float:
    """The weighted squared residual of ``problem`` with its one light set to ``cells``
    and the refit's albedos and final weights (a like-for-like comparison of two maps)."""
    rho = np.nan_to_num(solved.albedo[problem.cluster], nan=0.0)
    model = rho / np.pi * (problem.indirect + np.asarray(problem.transfer @ cells))
    used = np.isfinite(solved.residual).all(axis=1)
    r = (problem.radiance - model)[used]
    return float(np.sum(solved.weights[used] * r * r))


def render_model(
    transfer: sp.csr_matrix,
    blocks: list[LightBlock],
    result: SolveResult,
    fine: dict[str, tuple[RenderWindow, np.ndarray]],
) -> tuple[sp.csr_matrix, list[LightBlock], SolveResult]:
    """The model the renders show: each refitted window's columns and intensities
    replaced by its fine ones.

    ``fine`` maps a window's name to its :class:`RenderWindow` and its fine transfer at
    ``transfer``'s rows. Returns the transfer, lights and solve result to compute the
    per-vertex albedos and textures with (:func:`reroom.invert.solve.model_irradiance`).
    """
    if not fine:
        return transfer, blocks, result
    parts, new_blocks = [], []
    intensities = dict(result.intensities)
    csc = sp.csc_matrix(transfer)
    for k, block in enumerate(blocks):
        cols = block_columns(blocks, k)
        if block.name in fine and block.kind == "window":
            window, columns = fine[block.name]
            parts.append(sp.csc_matrix(np.asarray(columns, float)))
            new_blocks.append(
                replace(
                    block,
                    size=window.cells.shape[0],
                    adjacency=None,
                    adjacency_weights=None,
                    prior=None,
                    prior_weight=None,
                    lower=None,
                )
            )
            intensities[block.name] = window.cells
        else:
            parts.append(csc[:, cols])
            new_blocks.append(block)
    stacked = sp.hstack(parts, format="csr") if parts else sp.csr_matrix(transfer)
    return stacked, new_blocks, replace(result, intensities=intensities)
