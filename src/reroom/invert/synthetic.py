"""Synthetic inverse-rendering problems with a known answer, for tests and benchmarks.

They exercise :func:`reroom.invert.solve.solve_lighting` without ray tracing: random
sparse transfer matrices shaped like real ones (an area light most vertices see, a window
seen through a few cube-map cells, a point light and a line light of which each vertex
sees exactly one inclination bin), known albedos and intensities, and radiance made by
eq. 5.6 -- optionally with noise and outlier vertices (posters, rugs).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from reroom.invert.basis import CubemapBasis
from reroom.invert.solve import InverseProblem, LightBlock

__all__ = ["SyntheticTruth", "chain_adjacency", "synthetic_problem"]


def chain_adjacency(size: int) -> np.ndarray:
    """``(size - 1, 2)`` pairs ``(i, i + 1)``: the neighbours of a 1D binned profile."""
    i = np.arange(size - 1)
    return np.stack([i, i + 1], axis=1)


@dataclass
class SyntheticTruth:
    """The answer of a synthetic problem.

    Attributes
    ----------
    albedo : ndarray, shape (C, 3)
    intensities : dict of str to ndarray (size, 3)
    seen : dict of str to ndarray of bool (size,)
        Basis elements that some vertex receives light from.
    outliers : ndarray of int
        Vertices whose radiance was replaced by an outlier.
    """

    albedo: np.ndarray
    intensities: dict[str, np.ndarray]
    seen: dict[str, np.ndarray]
    outliers: np.ndarray


def synthetic_problem(
    n: int = 3000,
    lights: tuple[str, ...] = ("area", "window", "point", "line"),
    noise: float = 0.0,
    outlier_fraction: float = 0.0,
    seed: int = 0,
    bins: int = 32,
    cubemap_n: int = 4,
) -> tuple[InverseProblem, SyntheticTruth]:
    """A random problem of eq. 5.7 with a known solution.

    Parameters
    ----------
    n : int
        Number of vertices (split over the clusters wall, floor, ceiling 3:1:1).
    lights : tuple of str
        Kinds of light to include (each at most once): ``area``, ``window``, ``point``,
        ``line``.
    noise : float
        Relative Gaussian noise on the radiance.
    outlier_fraction : float
        Fraction of vertices whose radiance is multiplied by 0.2-3 (other materials).
    seed : int
        Random seed.
    bins : int
        Inclination bins of the point and line lights.
    cubemap_n : int
        Cube-map resolution of the window (``6 n^2`` cells).

    Returns
    -------
    problem : InverseProblem
    truth : SyntheticTruth
    """
    rng = np.random.default_rng(seed)
    names = ["wall", "floor", "ceiling"]
    cluster = rng.choice(3, size=n, p=[0.6, 0.2, 0.2])
    albedo = np.array([[0.70, 0.65, 0.55], [0.35, 0.25, 0.15], [0.85, 0.85, 0.85]])
    indirect = rng.uniform(0.05, 0.3, size=(n, 1)) * np.array([1.0, 0.95, 0.85])
    blocks: list[LightBlock] = []
    mats: list[sp.csr_matrix] = []
    intens: dict[str, np.ndarray] = {}
    rows = np.arange(n)
    for kind in lights:
        if kind == "area":
            f = sp.csr_matrix(rng.uniform(0, 0.02, size=(n, 1)) * (rng.random((n, 1)) < 0.8))
            blocks.append(LightBlock("panel", "area", 1))
            intens["panel"] = np.array([[20.0, 19.0, 17.0]])
        elif kind == "window":
            basis = CubemapBasis(cubemap_n)
            k = basis.size
            # vertices see a patch of cells around the window's normal (+X), never the rest
            dirs = basis.cell_directions()
            visible = np.flatnonzero(dirs[:, 0] > 0.3)
            per = 6
            cols = rng.choice(visible, size=(n, per))
            vals = rng.uniform(0, 0.002, size=(n, per))
            f = sp.csr_matrix((vals.ravel(), (np.repeat(rows, per), cols.ravel())), shape=(n, k))
            f.sum_duplicates()
            blocks.append(LightBlock("window", "window", k, False, basis.adjacency()))
            sky = 3.0 + 2.0 * np.clip(dirs[:, 2], 0, None) + 1.5 * np.clip(dirs[:, 0], 0, None)
            intens["window"] = sky[:, None] * np.array([0.8, 0.9, 1.0])
        elif kind in ("point", "line"):
            reach = int(0.8 * bins)  # the upper bins face the ceiling close by, or nothing
            b = rng.integers(0, reach, size=n)
            vals = rng.uniform(0.05, 1.0, size=n) * (1.0 if kind == "point" else 0.5)
            f = sp.csr_matrix((vals, (rows, b)), shape=(n, bins))
            name = "lamp" if kind == "point" else "tube"
            blocks.append(LightBlock(name, kind, bins, True, chain_adjacency(bins)))
            theta = (np.arange(bins) + 0.5) / bins * np.pi
            profile = 1.0 + 0.8 * np.cos(theta) + 0.3 * np.cos(2 * theta)
            color = np.array([1.0, 0.85, 0.6]) if kind == "point" else np.array([0.9, 1.0, 1.0])
            intens[name] = profile[:, None] * (color / np.linalg.norm(color))
        else:
            raise ValueError(f"unknown light kind {kind!r}")
        mats.append(f)
    transfer = sp.hstack(mats).tocsr() if mats else sp.csr_matrix((n, 0))
    stacked = np.concatenate([intens[b.name] for b in blocks]) if blocks else np.zeros((0, 3))
    radiance = albedo[cluster] / np.pi * (indirect + transfer @ stacked)
    if noise > 0:
        radiance = radiance * (1.0 + noise * rng.standard_normal(radiance.shape))
    outliers = rng.choice(n, size=int(outlier_fraction * n), replace=False)
    if len(outliers):
        radiance[outliers] *= rng.uniform(0.2, 3.0, size=(len(outliers), 1))
    col_seen = np.asarray((transfer != 0).sum(axis=0)).ravel() > 0
    seen, start = {}, 0
    for b in blocks:
        seen[b.name] = col_seen[start : start + b.size]
        start += b.size
    problem = InverseProblem(
        radiance=np.maximum(radiance, 0.0),
        indirect=indirect,
        cluster=cluster,
        cluster_names=names,
        transfer=transfer,
        lights=blocks,
    )
    return problem, SyntheticTruth(albedo, intens, seen, np.sort(outliers))
