"""Scene-scale inverse rendering: eq. 5.7 of the thesis, lights and cluster albedos at once.

For each observed diffuse vertex ``V`` of a material cluster ``k(V)`` and each channel::

    Lbar_V = rho_k / pi * (E_ind(V) + sum_l F_l(V) . I_l)          (eq. 5.6)

``Lbar`` is the HDR radiance, ``E_ind`` the indirect irradiance (rescaled for missing
data, eq. 5.9), ``F_l(V)`` the transfer row of light ``l`` (irradiance per unit basis
intensity) and ``I_l`` its basis intensities. The unknowns are ``rho`` (per cluster and
channel, ``0 <= rho < 1``) and every ``I_l`` (nonnegative). The solve minimises::

    sum_{V,c} huber_delta( sqrt(w_Vc) * r_Vc )  +  sum_l lambda_l sum_{(i,j) in A_l} a_ij (I_li - I_lj)^2

with ``r = (Lbar - model) / s`` (``s``: the median observed radiance, so ``delta`` is
relative), ``w`` the reweighting of eq. 5.8 (``R = Lbar / E_ind``, ``w = 1`` if
``R <= 1`` else ``exp(c (1 - R))``), ``A_l`` the adjacent basis cells of light ``l`` and
``a_ij`` their pair weights (``LightBlock.adjacency_weights``, default 1).
``lambda_l = lambda_smooth * mean_j ||F_lj||_w^2 * (0.5 / pi)^2``: the thesis's weak
smoothness made independent of units, relative to the data curvature of one basis
element. Cells no vertex sees are then the harmonic interpolation of their neighbours.
A light with a prior shape ``v`` (``LightBlock.shape``, e.g. the part of a tube its
scanned fixture leaves open) adds ``shape_weight * lambda_l * ||(1 - u u^T) I_l||^2``
with ``u = v / ||v||``: the part of ``I_l`` that is no multiple of ``v``, whatever the
scale, so the prior fixes the profile's shape and leaves its intensity to the data.
A chromatic light with measured values ``t`` of some elements (``LightBlock.prior``,
e.g. a window's cells where the photos see through it unsaturated) adds
``lambda_l sum_j prior_weight_j ||I_lj - t_j||^2``.

Monochromatic lights (points and lines) are parametrised *exactly* as
``I_l^c = col_lc * p_l`` with ``||col_l|| = 1`` (instead of the thesis's penalty
``lambda_mono = 1e8``): the alternating solver renormalises after every colour step, the
joint solver writes ``col`` in spherical angles restricted to the positive octant.
They couple the three channels; without them each channel is solved on its own.

Scale ambiguity (thesis 5.4.1): without ``E_ind``, ``(k I, rho / k)`` would fit as well;
``E_ind`` is a known quantity that fixes ``rho``, and eq. 5.8 down-weights the vertices
where direct light swamps it (there the ambiguity comes back).

Two solvers (``SolveOptions.method``), compared in ``benchmarks/bench_invert.py``:

``"alternating"`` (default)
    Block coordinate descent with Huber by iteratively reweighted least squares: for
    fixed ``rho`` the lights are a nonnegative linear least-squares problem, solved on its
    normal equations (a Cholesky factor, then Lawson-Hanson NNLS on a ``K x K`` system, so
    the cost per iteration is one sparse ``F^T W F`` product); for fixed lights ``rho`` is
    closed form per cluster and channel. Monochrome colours take a third, linear, step.
``"joint"``
    All unknowns at once by :func:`scipy.optimize.least_squares` (trust-region
    reflective with bounds, sparse Jacobian, LSMR), the Huber loss applied to the data
    residuals only, started from the alternating solver's first light step.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import scipy.linalg
import scipy.optimize
import scipy.sparse as sp

from reroom.errors import ReroomError
from reroom.layout.meshops import vertex_adjacency, vertex_areas
from reroom.threads import one_blas_thread

__all__ = [
    "LIGHT_KINDS",
    "InverseProblem",
    "LightBlock",
    "SolveOptions",
    "SolveResult",
    "bounded_quadratic",
    "footprint_operator",
    "indirect_weights",
    "model_irradiance",
    "per_vertex_albedo",
    "solve_lighting",
]

LIGHT_KINDS = ("area", "window", "point", "line", "sun")
METHODS = ("alternating", "joint")


class SolveError(ReroomError):
    """The inverse-rendering problem is malformed (shapes, values) or cannot be solved."""


@dataclass(frozen=True)
class LightBlock:
    """One light of the problem: a contiguous block of columns of the transfer matrix.

    Parameters
    ----------
    name : str
        The light's name (reports and warnings use it).
    kind : {"area", "window", "point", "line", "sun"}
        Its model (``"sun"``: a window's direct sun, one chromatic irradiance,
        :mod:`reroom.invert.sun`). Only ``monochrome`` and ``adjacency`` change the solve.
    size : int
        Number of basis elements (columns of the transfer matrix).
    monochrome : bool
        Whether its colour is shared by all its basis elements (``I^c = col_c * p``).
    adjacency : ndarray of int, shape (m, 2), optional
        Pairs of adjacent basis elements smoothed by ``lambda_smooth``.
    adjacency_weights : ndarray, shape (m,), optional
        Relative weight of each pair's smoothness term (default 1 each): a line light's
        :class:`~reroom.invert.basis.LineBasis` weighs its ``phi`` neighbours apart from
        its ``theta`` neighbours.
    shape : ndarray, shape (size,), optional
        A prior shape ``v >= 0`` of the light's intensities (of its profile, when
        monochrome), up to scale: the solve adds ``shape_weight * lambda_l * ||p - (v.p
        / v.v) v||^2``, which pulls the intensities toward ``i0 v`` and leaves ``i0``
        free. A line light in a fixture uses the fraction of its tube the scanned
        fixture leaves open (:mod:`reroom.invert.line_fixture`).
    shape_weight : float
        Weight of that prior, relative to the smoothness weight ``lambda_l``
        (0: no prior).
    prior : ndarray, shape (size, 3), optional
        Measured intensities of some basis elements (absolute units; rows without a
        measurement are ignored, NaN allowed there). Chromatic lights only: the solve
        adds ``lambda_l * prior_weight[j] * ||I_j - prior[j]||^2`` per element. A window
        uses the photos' unsaturated view through it (:mod:`reroom.invert.window_env`).
    prior_weight : ndarray, shape (size,), optional
        Weight of each element's measurement relative to ``lambda_l`` (0: none).
    lower : ndarray, shape (size, 3), optional
        Lower bounds on the intensities (absolute units, 0 or NaN: none), for chromatic
        lights and the joint solver: what a window's saturated photos prove about its
        cells (:func:`reroom.invert.window_env.cell_lower_bounds`).
    color_prior : ndarray, shape (3,), optional
        A measured colour of a monochrome light (any positive scale; the solve's
        radiance units), for the joint solver: it adds ``color_prior_weight * E *
        ||col - c||^2``, ``col`` the light's unit colour, ``c`` the prior's, ``E`` the
        weighted data term of a model that is off by 100 % everywhere (``sum w Lbar^2``),
        so a weight of 1 prices a colour 1 % off like a fit 1 % worse on every vertex.
        A tube's or panel's colour read from the unsaturated edge of its clipped image
        (:func:`reroom.invert.emitter_color.emitter_color`).
    color_prior_weight : float
        Weight of that prior (0: none).
    """

    name: str
    kind: str
    size: int
    monochrome: bool = False
    adjacency: np.ndarray | None = None
    adjacency_weights: np.ndarray | None = None
    shape: np.ndarray | None = None
    shape_weight: float = 0.0
    prior: np.ndarray | None = None
    prior_weight: np.ndarray | None = None
    lower: np.ndarray | None = None
    color_prior: np.ndarray | None = None
    color_prior_weight: float = 0.0


@dataclass
class InverseProblem:
    """The data of eq. 5.7 for the clustered vertices, independent of how it was computed.

    Parameters
    ----------
    radiance : ndarray, shape (n, 3)
        Observed outgoing radiance ``Lbar`` of each vertex.
    indirect : ndarray, shape (n, 3)
        Indirect irradiance ``E_ind`` (already rescaled for missing data, eq. 5.9).
    cluster : ndarray of int, shape (n,)
        Material cluster of each vertex, ``0 .. len(cluster_names) - 1``.
    cluster_names : list of str
        Names of the clusters (``wall``, ``floor``, ``ceiling``, ...).
    transfer : sparse or dense matrix, shape (n, K)
        Irradiance at each vertex per unit intensity of each basis light; the columns of
        ``lights[0]`` come first, then ``lights[1]``'s, and so on.
    lights : list of LightBlock
        The lights, in column order; ``sum(l.size) == K``.
    """

    radiance: np.ndarray
    indirect: np.ndarray
    cluster: np.ndarray
    cluster_names: list[str]
    transfer: sp.csr_matrix | np.ndarray
    lights: list[LightBlock]

    def validate(self) -> None:
        """Raise :class:`SolveError` naming the first inconsistent input."""
        n = len(self.radiance)
        if self.radiance.shape != (n, 3) or self.indirect.shape != (n, 3):
            raise SolveError(
                f"radiance {self.radiance.shape} and indirect {self.indirect.shape} must be (n, 3)"
            )
        if self.cluster.shape != (n,):
            raise SolveError(f"cluster has shape {self.cluster.shape}, expected ({n},)")
        k = sum(light.size for light in self.lights)
        if self.transfer.shape != (n, k):
            raise SolveError(
                f"transfer has shape {self.transfer.shape}, expected ({n}, {k}) for the lights"
            )
        for light in self.lights:
            if light.kind not in LIGHT_KINDS:
                raise SolveError(f"light {light.name!r} has unknown kind {light.kind!r}")
            if light.size < 1:
                raise SolveError(f"light {light.name!r} has no basis elements")
            if light.shape is not None:
                v = np.asarray(light.shape, float)
                if v.shape != (light.size,) or not np.all(np.isfinite(v)) or v.min() < 0:
                    raise SolveError(
                        f"light {light.name!r} needs a finite shape >= 0 of {light.size} values"
                    )
                if not np.isfinite(light.shape_weight) or light.shape_weight < 0:
                    raise SolveError(f"light {light.name!r} needs a shape_weight >= 0")
            if light.prior_weight is not None:
                _validate_prior(light)
            if light.color_prior_weight:
                _validate_color_prior(light)
            if light.lower is not None:
                lb = np.asarray(light.lower, float)
                if light.monochrome:
                    raise SolveError(f"light {light.name!r}: lower bounds need a chromatic light")
                if lb.shape != (light.size, 3) or np.nanmin(lb, initial=0.0) < 0:
                    raise SolveError(
                        f"light {light.name!r} needs lower bounds >= 0 of shape ({light.size}, 3)"
                    )
                if np.isinf(lb).any():
                    raise SolveError(f"light {light.name!r} has an infinite lower bound")
            if light.adjacency is not None and len(light.adjacency):
                adj = np.asarray(light.adjacency)
                if adj.ndim != 2 or adj.shape[1] != 2 or adj.min() < 0 or adj.max() >= light.size:
                    raise SolveError(f"light {light.name!r} has invalid adjacency pairs")
                if light.adjacency_weights is not None:
                    wts = np.asarray(light.adjacency_weights, float)
                    if wts.shape != (len(adj),) or not np.all(np.isfinite(wts)) or wts.min() < 0:
                        raise SolveError(
                            f"light {light.name!r} needs one finite weight >= 0 per adjacency pair"
                        )
        for name, a in (("radiance", self.radiance), ("indirect", self.indirect)):
            if not np.all(np.isfinite(a)):
                raise SolveError(f"{name} has non-finite values")
        if n and (self.cluster.min() < 0 or self.cluster.max() >= len(self.cluster_names)):
            raise SolveError("cluster ids out of range of cluster_names")


def _validate_color_prior(light: LightBlock) -> None:
    wt = light.color_prior_weight
    if not np.isfinite(wt) or wt < 0:
        raise SolveError(f"light {light.name!r} needs a color_prior_weight >= 0")
    if not light.monochrome:
        raise SolveError(f"light {light.name!r}: a colour prior needs a monochrome light")
    c = None if light.color_prior is None else np.asarray(light.color_prior, float)
    if c is None or c.shape != (3,) or not np.all(np.isfinite(c)) or c.min() < 0 or c.max() <= 0:
        raise SolveError(f"light {light.name!r} needs a colour prior of 3 finite values >= 0")


def _validate_prior(light: LightBlock) -> None:
    wt = np.asarray(light.prior_weight, float)
    if light.monochrome:
        raise SolveError(f"light {light.name!r}: a measured prior needs a chromatic light")
    if wt.shape != (light.size,) or not np.all(np.isfinite(wt)) or wt.min() < 0:
        raise SolveError(f"light {light.name!r} needs one finite prior weight >= 0 per element")
    if light.prior is None or np.shape(light.prior) != (light.size, 3):
        raise SolveError(f"light {light.name!r} needs a prior of shape ({light.size}, 3)")
    t = np.asarray(light.prior, float)[wt > 0]
    if not np.all(np.isfinite(t)) or (t.size and t.min() < 0):
        raise SolveError(f"light {light.name!r}: its weighted prior values must be finite, >= 0")


@dataclass
class SolveOptions:
    """Options of :func:`solve_lighting`.

    Parameters
    ----------
    method : {"alternating", "joint"}
        Solver (see the module docstring).
    huber_delta : float or None
        Huber threshold on ``sqrt(w) * r`` (relative to the median radiance); ``None``
        for plain least squares.
    reweight_c : float or None
        ``c`` of eq. 5.8 (thesis: 10); ``None`` disables the reweighting.
    min_weight : float
        Floor of the eq. 5.8 weights, so that a cluster lit only directly still counts.
    smooth_lambda : float
        Relative smoothness weight (see the module docstring).
    rho_max : float
        Upper bound of the cluster albedos (``rho < 1``).
    min_cluster_vertices : int
        Clusters with fewer vertices are left out of the solve (with a warning).
    max_vertices : int or None
        Solve on at most this many clustered vertices (a seeded random subset that keeps
        every vertex receiving light from a rarely seen basis element, each sampled
        vertex counted for the unsampled ones it stands for); ``None``: all.
        The lights have a few hundred unknowns, so a subset determines them as well as
        the whole mesh and keeps the solve time bounded (``benchmarks/bench_invert.py``).
    seed : int
        Seed of that subset.
    max_iterations : int
        Rounds of the alternating solver.
    max_evaluations : int
        Function evaluations of each ``least_squares`` call (joint solver).
    inner : {"lm", "trf"}
        Inner solver of the joint method: bounded Levenberg-Marquardt on the dense normal
        equations (``"lm"``), or ``scipy.optimize.least_squares`` (trust-region
        reflective, sparse Jacobian, LSMR).
    max_rounds : int
        Huber reweighting rounds of the joint solver.
    tolerance : float
        Relative decrease of the objective that stops the alternating solver, and the
        ``ftol``/``xtol``/``gtol`` of each ``least_squares`` call.
    irls_tolerance : float
        Relative decrease of the Huber objective that stops the joint solver's rounds.
    """

    method: Literal["alternating", "joint"] = "joint"
    huber_delta: float | None = 0.05
    reweight_c: float | None = 10.0
    min_weight: float = 1e-4
    smooth_lambda: float = 1e-5
    rho_max: float = 1.0 - 1e-6
    min_cluster_vertices: int = 30
    max_vertices: int | None = 20000
    seed: int = 0
    max_iterations: int = 300
    max_evaluations: int = 200
    inner: Literal["lm", "trf"] = "lm"
    max_rounds: int = 30
    tolerance: float = 1e-9
    irls_tolerance: float = 1e-6


@dataclass
class SolveResult:
    """Lights and cluster albedos solved by :func:`solve_lighting`.

    Attributes
    ----------
    albedo : ndarray, shape (C, 3)
        Albedo per cluster and channel; NaN for clusters left out of the solve.
    intensities : dict of str to ndarray (size, 3)
        Per light, per basis element, per channel intensity (radiance for area and window
        cells, radiant intensity per unit length or per steradian for lines and points).
    colors : dict of str to ndarray (3,)
        Unit-norm colour of each monochrome light.
    profiles : dict of str to ndarray (size,)
        Scalar profile of each monochrome light (``intensities = profile x colour``).
    cluster_used : ndarray of bool, shape (C,)
        Which clusters entered the solve.
    weights : ndarray, shape (n, 3)
        Final weight of each data term (eq. 5.8 times the Huber IRLS weight).
    residual : ndarray, shape (n, 3)
        ``Lbar - model`` (absolute radiance) at the solution; NaN for unused vertices.
    objective : float
        Final value of the objective (relative units).
    iterations : int
        Alternating rounds or ``least_squares`` evaluations.
    converged : bool
        Whether the tolerance was reached before ``max_iterations``.
    seconds : float
        Wall time of the solve.
    light_share : dict of str to float
        Each light's share of the modelled irradiance on the clustered vertices.
    warnings : list of str
        Problems found (unused clusters, lights that explain nothing, ...).
    history : list of float
        Objective after every round (alternating) or evaluation (joint).
    """

    albedo: np.ndarray
    intensities: dict[str, np.ndarray]
    colors: dict[str, np.ndarray]
    profiles: dict[str, np.ndarray]
    cluster_used: np.ndarray
    weights: np.ndarray
    residual: np.ndarray
    objective: float
    iterations: int
    converged: bool
    seconds: float
    light_share: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    history: list[float] = field(default_factory=list)
    method: str = "alternating"

    def intensity_vector(self, lights: list[LightBlock]) -> np.ndarray:
        """All lights' intensities stacked in column order, shape (K, 3)."""
        if not lights:
            return np.zeros((0, 3))
        return np.concatenate([self.intensities[light.name] for light in lights], axis=0)


def indirect_weights(
    radiance: np.ndarray, indirect: np.ndarray, c: float = 10.0, floor: float = 0.0
) -> np.ndarray:
    """The reweighting of eq. 5.8: favour vertices whose indirect light is not negligible.

    Parameters
    ----------
    radiance, indirect : ndarray, shape (n, 3)
        ``Lbar`` and ``E_ind``.
    c : float
        Steepness (thesis: 10).
    floor : float
        Smallest weight returned.

    Returns
    -------
    ndarray, shape (n, 3)
        ``1`` where ``R = Lbar / E_ind <= 1``, ``exp(c (1 - R))`` above.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(indirect > 0, radiance / indirect, np.inf)
    w = np.where(ratio <= 1.0, 1.0, np.exp(c * (1.0 - np.minimum(ratio, 1e6))))
    return np.maximum(w, floor)


# --------------------------------------------------------------------------------------
# internal structure: column layout and smoothness


@dataclass
class _Layout:
    """Where each light's columns are, split into chromatic and monochrome groups."""

    chrom_cols: np.ndarray  # transfer columns of chromatic lights
    mono_cols: np.ndarray  # transfer columns of monochrome lights
    mono_light_of_col: np.ndarray  # for each mono column, index into mono lights
    mono_lights: list[LightBlock]
    smooth_chrom: sp.csr_matrix  # rows sqrt(lambda) (e_i - e_j) over chrom columns
    smooth_mono: sp.csr_matrix  # same over mono columns
    # Right-hand side of smooth_chrom's rows per channel (relative units): 0 for the
    # smoothness and shape rows, sqrt(lambda w) t for a measured prior's; and its pull on
    # the normal equations, smooth_chrom^T chrom_rhs (n_chrom, 3), formed once.
    chrom_rhs: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    chrom_pull: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    # Lower bounds of the chromatic intensities (n_chrom, 3), relative units (0: none).
    chrom_lower: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    # Each monochrome light's colour prior (n_mono_lights, 3; unit rows) and the square
    # root of its weight in the objective (0: none), set once the data term is known.
    color_prior: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    color_sqrt_weight: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def n_chrom(self) -> int:
        return len(self.chrom_cols)

    @property
    def n_mono(self) -> int:
        return len(self.mono_cols)


def _regularisation_rows(
    lights: list[LightBlock],
    offsets: list[int],
    local: dict[int, int],
    n_cols: int,
    lam: dict,
    scale: float = 1.0,
) -> tuple[sp.csr_matrix, np.ndarray]:
    """The regularisation rows ``R x - b`` over some columns (smoothness, shape and
    measured priors), and ``b`` (rows, 3)."""
    rows, cols, vals = [], [], []
    rhs: list[np.ndarray] = []
    r = 0
    for li, light in enumerate(lights):
        if light.adjacency is None or len(light.adjacency) == 0 or lam.get(light.name, 0) <= 0:
            continue
        adj = np.asarray(light.adjacency)
        wts = (
            np.ones(len(adj))
            if light.adjacency_weights is None
            else np.asarray(light.adjacency_weights, float)
        )
        for (i, j), wt in zip(adj, wts, strict=True):
            if wt <= 0:
                continue
            s = np.sqrt(lam[light.name] * wt)
            rows += [r, r]
            cols += [local[offsets[li] + int(i)], local[offsets[li] + int(j)]]
            vals += [s, -s]
            r += 1
    for li, light in enumerate(lights):
        if light.shape is None or light.shape_weight <= 0 or lam.get(light.name, 0) <= 0:
            continue
        v = np.asarray(light.shape, float)
        if not np.any(v > 0):
            continue
        # The projection off the prior's direction: its rows penalise the part of the
        # intensities that is not a multiple of the shape, whatever the scale.
        u = v / np.linalg.norm(v)
        proj = np.sqrt(lam[light.name] * light.shape_weight) * (np.eye(light.size) - np.outer(u, u))
        local_cols = np.array([local[offsets[li] + j] for j in range(light.size)])
        for row in proj:
            nz = np.flatnonzero(row)
            rows += [r] * len(nz)
            cols += local_cols[nz].tolist()
            vals += row[nz].tolist()
            r += 1
    rhs.append(np.zeros((r, 3)))
    for li, light in enumerate(lights):
        if light.prior_weight is None or lam.get(light.name, 0) <= 0:
            continue
        wt = np.asarray(light.prior_weight, float)
        t = np.asarray(light.prior, float)
        for j in np.flatnonzero(wt > 0):
            a = np.sqrt(lam[light.name] * wt[j])
            rows.append(r)
            cols.append(local[offsets[li] + int(j)])
            vals.append(a)
            rhs.append(a * t[j][None, :] / scale)  # the solve's relative units
            r += 1
    return sp.csr_matrix((vals, (rows, cols)), shape=(r, n_cols)), np.concatenate(rhs)


def _layout(
    lights: list[LightBlock], col_norm2: np.ndarray, smooth_lambda: float, scale: float = 1.0
) -> _Layout:
    offsets = np.concatenate([[0], np.cumsum([light.size for light in lights])]).astype(int)
    chrom, mono, mono_of = [], [], []
    mono_lights: list[LightBlock] = []
    lam: dict[str, float] = {}
    ref = (0.5 / np.pi) ** 2
    for li, light in enumerate(lights):
        cols = np.arange(offsets[li], offsets[li + 1])
        seen = col_norm2[cols] > 0
        lam[light.name] = smooth_lambda * ref * (col_norm2[cols][seen].mean() if seen.any() else 0)
        if light.monochrome:
            mono.extend(cols)
            mono_of.extend([len(mono_lights)] * len(cols))
            mono_lights.append(light)
        else:
            chrom.extend(cols)
    chrom_local = {c: i for i, c in enumerate(chrom)}
    mono_local = {c: i for i, c in enumerate(mono)}
    chrom_lights = [light for light in lights if not light.monochrome]
    chrom_offsets = [int(offsets[i]) for i, lt in enumerate(lights) if not lt.monochrome]
    mono_offsets = [int(offsets[i]) for i, lt in enumerate(lights) if lt.monochrome]
    smooth_chrom, chrom_rhs = _regularisation_rows(
        chrom_lights, chrom_offsets, chrom_local, len(chrom), lam, scale
    )
    smooth_mono, _ = _regularisation_rows(mono_lights, mono_offsets, mono_local, len(mono), lam)
    lower = [
        np.zeros((light.size, 3))
        if light.lower is None
        else np.nan_to_num(np.asarray(light.lower, float)) / scale
        for light in chrom_lights
    ]
    return _Layout(
        chrom_cols=np.asarray(chrom, dtype=int),
        mono_cols=np.asarray(mono, dtype=int),
        mono_light_of_col=np.asarray(mono_of, dtype=int),
        mono_lights=mono_lights,
        smooth_chrom=smooth_chrom,
        smooth_mono=smooth_mono,
        chrom_rhs=chrom_rhs,
        chrom_pull=np.asarray(smooth_chrom.T @ chrom_rhs).reshape(len(chrom), 3),
        chrom_lower=np.concatenate(lower) if lower else np.zeros((0, 3)),
    )


def _nnls_normal(gram: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """``argmin_{x >= 0} x^T G x - 2 x^T g`` through a Cholesky factor and Lawson-Hanson."""
    n = len(rhs)
    if n == 0:
        return np.zeros(0)
    g = gram + np.eye(n) * (1e-12 * max(float(np.max(np.diag(gram))), 1e-300))
    try:
        r = scipy.linalg.cholesky(g, lower=False)
    except np.linalg.LinAlgError:
        g += np.eye(n) * 1e-9 * max(float(np.max(np.diag(gram))), 1e-300)
        r = scipy.linalg.cholesky(g, lower=False)
    d = scipy.linalg.solve_triangular(r, rhs, trans="T", lower=False)
    x, _ = scipy.optimize.nnls(r, d, maxiter=50 * n)
    return x


# --------------------------------------------------------------------------------------
# the state of a solve (relative units: radiance / s)


@dataclass
class _State:
    rho: np.ndarray  # (C, 3)
    chrom: np.ndarray  # (Kc, 3)
    profile: np.ndarray  # (Km,)
    color: np.ndarray  # (n_mono_lights, 3), unit rows

    def intensity_cols(self, lay: _Layout, k: int) -> np.ndarray:
        out = np.zeros((k, 3))
        out[lay.chrom_cols] = self.chrom
        if lay.n_mono:
            out[lay.mono_cols] = self.profile[:, None] * self.color[lay.mono_light_of_col]
        return out


class _Data:
    """The clustered data in relative units with the fixed weights of eq. 5.8."""

    def __init__(
        self,
        problem: InverseProblem,
        rows: np.ndarray,
        options: SolveOptions,
        scale: float | None = None,
        multiplicity: np.ndarray | None = None,
    ) -> None:
        self.rows = rows
        # How many clustered vertices each row stands for (a subset's sample weight,
        # outside the Huber loss: it counts a residual, it does not rescale it).
        self.m = (
            np.ones((len(rows), 1))
            if multiplicity is None
            else np.asarray(multiplicity, float).reshape(-1, 1)
        )
        lbar = problem.radiance[rows]
        positive = lbar[lbar > 0]
        if scale is None:
            scale = float(np.median(positive)) if positive.size else 1.0
        self.scale = scale
        self.L = lbar / self.scale
        self.E = problem.indirect[rows] / self.scale
        self.cluster = problem.cluster[rows]
        self.n_clusters = len(problem.cluster_names)
        f = problem.transfer
        self.F = (sp.csr_matrix(f) if not sp.issparse(f) else f.tocsr())[rows].astype(float)
        self.K = self.F.shape[1]
        if options.reweight_c is None:
            self.w = np.ones_like(self.L)
        else:
            self.w = indirect_weights(lbar, problem.indirect[rows], options.reweight_c)
            self.w = np.maximum(self.w, options.min_weight)
        self.delta = options.huber_delta

    def fit_weight(self, h: np.ndarray) -> np.ndarray:
        """Least-squares weight of each residual: eq. 5.8 x Huber IRLS x multiplicity."""
        return self.w * h * self.m

    def model(self, st: _State, lay: _Layout) -> np.ndarray:
        direct = self.F @ st.intensity_cols(lay, self.K)
        return st.rho[self.cluster] / np.pi * (self.E + direct)

    def objective(self, st: _State, lay: _Layout) -> tuple[float, np.ndarray]:
        """Objective and the Huber IRLS weights ``h`` (weighted residual scale)."""
        r = np.sqrt(self.w) * (self.L - self.model(st, lay))
        a = np.abs(r)
        if self.delta is None:
            data = float(np.sum(self.m * r * r))
            h = np.ones_like(r)
        else:
            d = self.delta
            data = float(np.sum(self.m * np.where(a <= d, r * r, 2 * d * a - d * d)))
            h = np.where(a <= d, 1.0, d / np.maximum(a, 1e-300))
        smooth = 0.0
        if lay.smooth_chrom.shape[0]:
            smooth += float(np.sum((lay.smooth_chrom @ st.chrom - lay.chrom_rhs) ** 2))
        if lay.smooth_mono.shape[0]:
            smooth += float(np.sum((lay.smooth_mono @ st.profile) ** 2))
        if lay.color_sqrt_weight.any():
            smooth += float(np.sum(_color_prior_rows(lay, st.color) ** 2))
        return data + smooth, h


def _color_prior_rows(lay: _Layout, color: np.ndarray) -> np.ndarray:
    """The colour priors' residuals ``sqrt(weight) (col - prior)``, (n_mono_lights * 3,)."""
    return (lay.color_sqrt_weight[:, None] * (color - lay.color_prior)).ravel()


# --------------------------------------------------------------------------------------
# alternating solver


def _target(data: _Data, st: _State) -> np.ndarray:
    """The irradiance each vertex needs from the lights: ``Lbar / (rho / pi) - E_ind``."""
    rv = st.rho[data.cluster] / np.pi
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(rv > 0, data.L / np.where(rv > 0, rv, 1.0) - data.E, 0.0)


def _light_step(data: _Data, lay: _Layout, st: _State, weight: np.ndarray) -> None:
    """For fixed ``rho`` and colours: the nonnegative least squares in the intensities."""
    f_chrom = data.F[:, lay.chrom_cols]
    f_mono = data.F[:, lay.mono_cols]
    scale = weight * (st.rho[data.cluster] / np.pi) ** 2  # (n, 3)
    target = _target(data, st)  # (n, 3)
    kc, km = lay.n_chrom, lay.n_mono
    s_c = (lay.smooth_chrom.T @ lay.smooth_chrom).toarray() if kc else np.zeros((0, 0))
    if km == 0:
        # uncoupled channels: one small NNLS per channel
        for c in range(3):
            g = (f_chrom.T @ f_chrom.multiply(scale[:, c : c + 1])).toarray() + s_c
            rhs = f_chrom.T @ (scale[:, c] * target[:, c]) + lay.chrom_pull[:, c]
            st.chrom[:, c] = _nnls_normal(g, rhs)
        return
    s_m = (lay.smooth_mono.T @ lay.smooth_mono).toarray()
    n_all = 3 * kc + km
    gram = np.zeros((n_all, n_all))
    rhs = np.zeros(n_all)
    col_of = st.color[lay.mono_light_of_col]  # (Km, 3)
    mono = slice(3 * kc, n_all)
    for c in range(3):
        fc_w = f_chrom.multiply(scale[:, c : c + 1]).tocsc()
        fm_w = f_mono.multiply(scale[:, c : c + 1]).tocsc()
        blk = slice(c * kc, (c + 1) * kc)
        gram[blk, blk] = (f_chrom.T @ fc_w).toarray() + s_c
        cm = (f_chrom.T @ fm_w).toarray() * col_of[:, c][None, :]
        gram[blk, mono] = cm
        gram[mono, blk] = cm.T
        mm = (f_mono.T @ fm_w).toarray()
        gram[mono, mono] += mm * np.outer(col_of[:, c], col_of[:, c])
        rhs[blk] = f_chrom.T @ (scale[:, c] * target[:, c]) + lay.chrom_pull[:, c]
        rhs[mono] += col_of[:, c] * (f_mono.T @ (scale[:, c] * target[:, c]))
    gram[mono, mono] += s_m
    x = _nnls_normal(gram, rhs)
    st.chrom[:] = x[: 3 * kc].reshape(3, kc).T
    st.profile[:] = x[3 * kc :]


def _color_step(data: _Data, lay: _Layout, st: _State, weight: np.ndarray) -> None:
    """For fixed ``rho`` and profiles: colours (and chromatic lights), one NNLS per channel."""
    n_ml = len(lay.mono_lights)
    f_chrom = data.F[:, lay.chrom_cols]
    # each monochrome light's irradiance for unit colour: F_l p_l
    per_light = sp.csr_matrix(
        (st.profile, (np.arange(lay.n_mono), lay.mono_light_of_col)), shape=(lay.n_mono, n_ml)
    )
    unit = np.asarray((data.F[:, lay.mono_cols] @ per_light).todense())  # (n, n_ml)
    design = sp.hstack([f_chrom, sp.csr_matrix(unit)]).tocsr()
    kc = lay.n_chrom
    scale = weight * (st.rho[data.cluster] / np.pi) ** 2
    target = _target(data, st)
    s_c = (lay.smooth_chrom.T @ lay.smooth_chrom).toarray() if kc else np.zeros((0, 0))
    new_color = np.zeros((n_ml, 3))
    for c in range(3):
        g = (design.T @ design.multiply(scale[:, c : c + 1])).toarray()
        g[:kc, :kc] += s_c
        rhs = design.T @ (scale[:, c] * target[:, c])
        rhs[:kc] += lay.chrom_pull[:, c]
        x = _nnls_normal(g, rhs)
        st.chrom[:, c] = x[:kc]
        new_color[:, c] = x[kc:]
    norm = np.linalg.norm(new_color, axis=1)
    for i in range(n_ml):
        if norm[i] > 0:
            st.color[i] = new_color[i] / norm[i]
            st.profile[lay.mono_light_of_col == i] *= norm[i]
        else:
            st.profile[lay.mono_light_of_col == i] = 0.0


def _rho_step(data: _Data, lay: _Layout, st: _State, weight: np.ndarray, rho_max: float) -> None:
    """For fixed lights: the closed-form weighted least squares albedo of each cluster."""
    irr = data.E + data.F @ st.intensity_cols(lay, data.K)  # (n, 3)
    num = np.zeros((data.n_clusters, 3))
    den = np.zeros((data.n_clusters, 3))
    np.add.at(num, data.cluster, weight * irr * data.L)
    np.add.at(den, data.cluster, weight * irr * irr)
    present = den > 0
    st.rho[present] = np.clip(np.pi * num[present] / den[present], 0.0, rho_max)


def _solve_alternating(
    data: _Data, lay: _Layout, st: _State, options: SolveOptions, progress
) -> tuple[int, bool, list[float]]:
    history: list[float] = []
    obj, h = data.objective(st, lay)
    converged = False
    it = 0
    for it in range(1, options.max_iterations + 1):
        weight = data.fit_weight(h)
        _light_step(data, lay, st, weight)
        if lay.n_mono:
            _color_step(data, lay, st, weight)
        _rho_step(data, lay, st, weight, options.rho_max)
        new, h = data.objective(st, lay)
        history.append(new)
        if progress is not None:
            progress("invert solve", it, options.max_iterations)
        if abs(obj - new) <= options.tolerance * max(abs(obj), 1e-300):
            converged = True
            break
        obj = new
    if progress is not None and converged:
        # Converged early: the bar says done, not "19 of 30".
        progress("invert solve", options.max_iterations, options.max_iterations)
    return it, converged, history


# --------------------------------------------------------------------------------------
# joint solver (scipy least_squares)


def _angles_of(color: np.ndarray) -> np.ndarray:
    c = np.clip(color / np.maximum(np.linalg.norm(color, axis=1, keepdims=True), 1e-300), 0, 1)
    theta = np.arccos(np.clip(c[:, 2], -1, 1))
    phi = np.arctan2(c[:, 1], c[:, 0])
    return np.stack([theta, phi], axis=1)


def _color_of(angles: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t, p = angles[:, 0], angles[:, 1]
    col = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=1)
    d_t = np.stack([np.cos(t) * np.cos(p), np.cos(t) * np.sin(p), -np.sin(t)], axis=1)
    d_p = np.stack([-np.sin(t) * np.sin(p), np.sin(t) * np.cos(p), np.zeros_like(t)], axis=1)
    return col, d_t, d_p


def bounded_quadratic(
    h: np.ndarray, g: np.ndarray, lo: np.ndarray, hi: np.ndarray
) -> np.ndarray | None:
    """``argmin 1/2 s^T h s + g^T s`` over ``lo <= s <= hi``: block principal pivoting
    (:func:`_box_qp`), and BVLS on the Cholesky factor of ``h`` where that does not
    converge. None when ``h`` is not positive definite."""
    step = _box_qp(h, g, lo, hi)
    if step is not None:
        return step
    try:
        rf = scipy.linalg.cholesky(h, lower=False)
    except np.linalg.LinAlgError:
        return None
    b = -scipy.linalg.solve_triangular(rf, g, trans="T", lower=False)
    return scipy.optimize.lsq_linear(rf, b, bounds=(lo, hi), method="bvls").x


def _box_qp(
    h: np.ndarray, g: np.ndarray, lo: np.ndarray, hi: np.ndarray, max_iter: int | None = None
) -> np.ndarray | None:
    """``argmin 1/2 s^T h s + g^T s`` over ``lo <= s <= hi`` (``h`` positive definite).

    Block principal pivoting (Judice & Pires 1994; Kim & Park 2011 for NNLS): guess
    which variables sit at a bound, solve the free block exactly (one Cholesky), and
    exchange *every* variable that breaks the optimality conditions at once (a free one
    outside its box goes to that bound, a bound one whose gradient pulls it inward is
    freed). If the number of such variables stops falling for three rounds, only the
    last one is exchanged (Murty's rule), which terminates for positive definite ``h``.
    The first guess fixes the variables whose bound is 0 and whose gradient pushes
    against it: in the LM steps of :func:`_bounded_lm` the intensities that are 0 stay
    there. Why not a primal active-set method (one variable in or out per Cholesky), as
    before session 31: with a 384-cell window a step took 200-400 factorizations of a
    1400-unknown block, 15 s, where this takes 5-6 (docs/invert.md). Returns None if it
    did not converge within ``max_iter`` rounds (default ``4 n + 20``); the caller then
    falls back to BVLS.
    """
    n = len(g)
    max_iter = 4 * n + 20 if max_iter is None else max_iter
    state = np.zeros(n, np.int8)  # -1: at lo, +1: at hi, 0: free
    state[(lo == 0) & (g > 0)] = -1
    state[(hi == 0) & (g < 0)] = 1
    scale = max(float(np.max(np.abs(g))), float(np.max(np.abs(np.diag(h)))), 1e-300)
    tol = 1e-13 * scale
    fewest, backup = n + 1, 3
    s = np.zeros(n)
    for _ in range(max_iter):
        free = state == 0
        fixed = ~free
        s[:] = 0.0
        s[state < 0] = lo[state < 0]
        s[state > 0] = hi[state > 0]
        if free.any():
            rhs = -(g[free] + h[np.ix_(free, fixed)] @ s[fixed])
            try:
                factor = scipy.linalg.cho_factor(h[np.ix_(free, free)], check_finite=False)
            except np.linalg.LinAlgError:
                return None
            s[free] = scipy.linalg.cho_solve(factor, rhs, check_finite=False)
        grad = h @ s + g
        size = max(1.0, float(np.max(np.abs(s[free])))) if free.any() else 1.0
        below = free & (s < lo - 1e-12 * size)
        above = free & (s > hi + 1e-12 * size)
        pulled = ((state < 0) & (grad < -tol)) | ((state > 0) & (grad > tol))
        wrong = below | above | pulled
        count = int(wrong.sum())
        if count == 0:
            return np.clip(s, lo, hi)
        if count < fewest:
            fewest, backup = count, 3
        elif backup > 0:
            backup -= 1
        else:  # Murty's rule: exchange only the last wrong variable
            last = np.zeros(n, bool)
            last[np.flatnonzero(wrong)[-1]] = True
            below &= last
            above &= last
            pulled &= last
        state[pulled] = 0
        state[below] = -1
        state[above] = 1
    return None


def _bounded_lm(
    fun: Callable, jac: Callable, x0: np.ndarray, lo: np.ndarray, hi: np.ndarray, options
) -> tuple[np.ndarray, int, bool]:
    """Levenberg-Marquardt with box bounds on the dense normal equations.

    There are only a few hundred unknowns, so ``J^T J`` is small and dense even for many
    residuals: each step is a bounded quadratic problem (Marquardt's diagonal scaling),
    solved exactly by block principal pivoting (:func:`_box_qp`; BVLS on its
    Cholesky factor if that does not converge).
    """
    x = x0.copy()
    r = fun(x)
    cost = float(r @ r)
    mu = 1e-4
    nfev = 1
    for _ in range(options.max_evaluations):
        jm = jac(x)
        a = (jm.T @ jm).toarray()
        g = jm.T @ r
        d = np.maximum(np.diag(a), 1e-12 * max(float(np.max(np.diag(a))), 1e-300))
        accepted = False
        while mu < 1e12:
            h = a + mu * np.diag(d)
            step = bounded_quadratic(h, g, lo - x, hi - x)
            if step is None:  # not positive definite
                mu *= 10
                continue
            xn = np.clip(x + step, lo, hi)
            rn = fun(xn)
            nfev += 1
            cn = float(rn @ rn)
            if cn <= cost:
                accepted = True
                break
            mu *= 10
        if not accepted:
            return x, nfev, True  # no descent left: a (constrained) minimum
        small_f = cost - cn <= options.tolerance * cost
        small_x = np.linalg.norm(xn - x) <= options.tolerance * (np.linalg.norm(x) + 1e-12)
        x, r, cost = xn, rn, cn
        mu = max(mu / 10, 1e-12)
        if small_f or small_x:
            return x, nfev, True
    return x, nfev, False


def _solve_joint(
    data: _Data, lay: _Layout, st: _State, options: SolveOptions, weight: np.ndarray
) -> tuple[int, bool]:
    """One weighted least-squares solve of all unknowns, warm-started from ``st``."""
    n, C = len(data.L), data.n_clusters
    kc, km, n_ml = lay.n_chrom, lay.n_mono, len(lay.mono_lights)
    used_c = np.unique(data.cluster)
    n_rho = 3 * len(used_c)
    rho_index = -np.ones(C, dtype=int)
    rho_index[used_c] = np.arange(len(used_c))
    n_par = n_rho + 3 * kc + km + 2 * n_ml
    sqw = np.sqrt(weight)
    f_chrom = data.F[:, lay.chrom_cols].tocsr()
    f_mono = data.F[:, lay.mono_cols].tocsr()
    sc, sm = lay.smooth_chrom, lay.smooth_mono
    priced = bool(n_ml and lay.color_sqrt_weight.any())

    def unpack(x: np.ndarray) -> tuple:
        rho = x[:n_rho].reshape(len(used_c), 3)
        chrom = x[n_rho : n_rho + 3 * kc].reshape(3, kc).T
        prof = x[n_rho + 3 * kc : n_rho + 3 * kc + km]
        ang = x[n_rho + 3 * kc + km :].reshape(n_ml, 2)
        return rho, chrom, prof, ang

    def parts(x: np.ndarray) -> tuple:
        rho, chrom, prof, ang = unpack(x)
        col, d_t, d_p = _color_of(ang)
        mono_i = prof[:, None] * col[lay.mono_light_of_col] if km else np.zeros((0, 3))
        direct = f_chrom @ chrom + (f_mono @ mono_i if km else 0.0)
        irr = data.E + direct
        rv = rho[rho_index[data.cluster]] / np.pi
        return rho, chrom, prof, col, d_t, d_p, irr, rv

    def fun(x: np.ndarray) -> np.ndarray:
        _, chrom, prof, col, _, _, irr, rv = parts(x)
        r = (sqw * (rv * irr - data.L)).T.ravel()
        smooth = [(sc @ chrom - lay.chrom_rhs).T.ravel(), sm @ prof]
        if priced:
            smooth.append(_color_prior_rows(lay, col))
        return np.concatenate([r, *smooth])

    vrows = np.arange(n)

    def jac(x: np.ndarray) -> sp.csr_matrix:
        _, _, prof, col, d_t, d_p, irr, rv = parts(x)
        blocks = []
        for c in range(3):
            a = sqw[:, c]
            rho_cols = rho_index[data.cluster] * 3 + c
            j_rho = sp.csr_matrix((a * irr[:, c] / np.pi, (vrows, rho_cols)), shape=(n, n_rho))
            j_ch = [sp.csr_matrix((n, kc))] * 3
            j_ch[c] = f_chrom.multiply((a * rv[:, c])[:, None]).tocsr()
            row = [j_rho, *j_ch]
            if km:
                wc = (a * rv[:, c])[:, None]
                j_p = f_mono.multiply(wc).multiply(col[lay.mono_light_of_col, c][None, :])
                per_light = sp.csr_matrix(
                    (prof, (np.arange(km), lay.mono_light_of_col)), shape=(km, n_ml)
                )
                unit = np.asarray((f_mono @ per_light).todense()) * wc  # (n, n_ml)
                j_ang = np.zeros((n, 2 * n_ml))
                j_ang[:, 0::2] = unit * d_t[:, c][None, :]
                j_ang[:, 1::2] = unit * d_p[:, c][None, :]
                row += [j_p, sp.csr_matrix(j_ang)]
            blocks.append(sp.hstack(row))
        j_data = sp.vstack(blocks)
        zr = sp.csr_matrix((sc.shape[0], n_rho))
        s_rows = []
        for c in range(3):
            ch = [sp.csr_matrix((sc.shape[0], kc))] * 3
            ch[c] = sc
            tail = [sp.csr_matrix((sc.shape[0], km + 2 * n_ml))]
            s_rows.append(sp.hstack([zr, *ch, *tail]))
        s_rows.append(
            sp.hstack(
                [
                    sp.csr_matrix((sm.shape[0], n_rho + 3 * kc)),
                    sm,
                    sp.csr_matrix((sm.shape[0], 2 * n_ml)),
                ]
            )
        )
        if priced:  # d (a_i col_i^c) / d angles_i, light-major rows as _color_prior_rows
            a = lay.color_sqrt_weight
            j_col = np.zeros((3 * n_ml, 2 * n_ml))
            for i in range(n_ml):
                j_col[3 * i : 3 * i + 3, 2 * i] = a[i] * d_t[i]
                j_col[3 * i : 3 * i + 3, 2 * i + 1] = a[i] * d_p[i]
            s_rows.append(
                sp.hstack([sp.csr_matrix((3 * n_ml, n_rho + 3 * kc + km)), sp.csr_matrix(j_col)])
            )
        return sp.vstack([j_data, *s_rows]).tocsr()

    x0 = np.concatenate(
        [
            st.rho[used_c].ravel(),
            st.chrom.T.ravel(),
            st.profile,
            _angles_of(st.color).ravel() if n_ml else np.zeros(0),
        ]
    )
    lo = np.zeros(n_par)
    lo[n_rho : n_rho + 3 * kc] = lay.chrom_lower.T.ravel()  # channel-major, as x
    hi = np.full(n_par, np.inf)
    hi[:n_rho] = options.rho_max
    hi[n_rho + 3 * kc + km :] = np.pi / 2
    x0 = np.clip(x0, lo, hi)
    if options.inner == "lm":
        x, nfev, ok = _bounded_lm(fun, jac, x0, lo, hi, options)
    else:
        res = scipy.optimize.least_squares(
            fun,
            x0,
            jac=jac,
            bounds=(lo, hi),
            method="trf",
            x_scale="jac",
            tr_solver="lsmr",
            ftol=options.tolerance,
            xtol=options.tolerance,
            gtol=options.tolerance,
            max_nfev=options.max_evaluations,
        )
        x, nfev, ok = res.x, int(res.nfev), bool(res.status > 0)
    rho, chrom, prof, ang = unpack(x)
    st.rho[used_c] = rho
    st.chrom[:] = chrom
    st.profile[:] = prof
    if n_ml:
        st.color[:] = _color_of(ang)[0]
    return nfev, ok


def _solve_joint_irls(
    data: _Data, lay: _Layout, st: _State, options: SolveOptions, progress
) -> tuple[int, bool, list[float]]:
    """Huber by iteratively reweighted joint least squares (warm-started inner solves)."""
    obj, h = data.objective(st, lay)
    history: list[float] = []
    evaluations, converged = 0, False
    rounds = 1 if data.delta is None else options.max_rounds
    for it in range(1, rounds + 1):
        nfev, ok = _solve_joint(data, lay, st, options, data.fit_weight(h))
        evaluations += nfev
        new, h = data.objective(st, lay)
        history.append(new)
        if progress is not None:
            progress("invert solve", it, rounds)
        if data.delta is None:
            converged = ok
            break
        if abs(obj - new) <= options.irls_tolerance * max(abs(obj), 1e-300):
            converged = True
            break
        obj = new
    if progress is not None:
        # Converged (or the last round): the bar says done, not "19 of 30".
        progress("invert solve", rounds, rounds)
    return evaluations, converged, history


# --------------------------------------------------------------------------------------


def _solve_rows(
    problem: InverseProblem, used: np.ndarray, options: SolveOptions
) -> tuple[np.ndarray, np.ndarray]:
    """The clustered vertices the solve uses, and how many vertices each one stands for.

    All of them, or a subset that keeps every vertex receiving light from a basis element
    few vertices see (multiplicity 1) plus a seeded uniform sample of the others, each
    standing for ``others / sampled`` of them, so that the subset's data term estimates
    the whole problem's. Unweighted, the data term was ``sampled / others`` of it while
    the smoothness scale (the mean data curvature of a light's elements, dominated by the
    few kept receivers next to a point light) was not: on the 300-frame `furnished` scan
    (20000 of 135k vertices, 39 kept as rare) the smoothness was 6.8x too strong, the floor
    albedo came out +11 % instead of +4 % (green) and the downlight -31 % instead of -15 %
    against solving on every vertex (docs/invert.md, "The solve's subset").
    """
    rows = np.flatnonzero(used[problem.cluster])
    cap = options.max_vertices
    if cap is None or len(rows) <= cap:
        return rows, np.ones(len(rows))
    rng = np.random.default_rng(options.seed)
    f = problem.transfer
    f = (sp.csr_matrix(f) if not sp.issparse(f) else f.tocsr())[rows]
    seen = (f != 0).astype(np.int32)
    counts = np.asarray(seen.sum(axis=0)).ravel()
    # vertices that receive light from a basis element few vertices see are all kept
    rare = (counts > 0) & (counts <= max(cap // max(f.shape[1], 1) // 4, 20))
    keep = np.zeros(len(rows), dtype=bool)
    if rare.any():
        keep |= np.asarray(seen[:, np.flatnonzero(rare)].sum(axis=1)).ravel() > 0
    multiplicity = np.ones(len(rows))
    rest = np.flatnonzero(~keep)
    need = min(max(cap - int(keep.sum()), 0), len(rest))
    if need:
        sampled = rng.choice(rest, size=need, replace=False)
        keep[sampled] = True
        multiplicity[sampled] = len(rest) / need
    return rows[keep], multiplicity[keep]


def solve_lighting(
    problem: InverseProblem,
    options: SolveOptions | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> SolveResult:
    """Solve eq. 5.7: every light's basis intensities and every cluster's albedo.

    Parameters
    ----------
    problem : InverseProblem
        The clustered vertices' radiance, indirect irradiance and light transfers.
    options : SolveOptions, optional
        Solver, loss and regularisation.
    progress : callable, optional
        ``progress(stage, done, total)``.

    Returns
    -------
    SolveResult
        The solution in the radiance units of ``problem``, with warnings for clusters
        left out, lights no vertex sees and lights that explain nothing.

    Raises
    ------
    SolveError
        Inconsistent shapes or non-finite data, an unknown method, or no cluster with
        enough vertices.
    """
    options = options or SolveOptions()
    if options.method not in METHODS:
        raise SolveError(f"unknown solve method {options.method!r}; choose from {METHODS}")
    problem.validate()
    if options.method == "alternating" and any(
        light.lower is not None and np.nan_to_num(np.asarray(light.lower, float)).max() > 0
        for light in problem.lights
    ):
        raise SolveError("lower bounds on intensities need the joint solver (method='joint')")
    if options.method == "alternating" and any(lt.color_prior_weight > 0 for lt in problem.lights):
        raise SolveError("a colour prior needs the joint solver (method='joint')")
    t0 = time.perf_counter()
    notes: list[str] = []
    n_clusters = len(problem.cluster_names)
    counts = np.bincount(problem.cluster, minlength=n_clusters)
    used = counts >= options.min_cluster_vertices
    for k in np.flatnonzero(~used):
        name = problem.cluster_names[k]
        if counts[k] == 0:
            notes.append(f"cluster {name!r} has no observed vertex: albedo unknown")
        else:
            notes.append(
                f"cluster {name!r} has only {counts[k]} observed vertices "
                f"(< {options.min_cluster_vertices}): left out of the lighting solve"
            )
    if not used.any():
        raise SolveError(
            f"no material cluster has {options.min_cluster_vertices} or more observed vertices "
            f"(counts {dict(zip(problem.cluster_names, counts.tolist(), strict=True))})"
        )
    rows, multiplicity = _solve_rows(problem, used, options)
    if len(rows) < int(np.sum(counts[used])):
        kept = int(np.sum(multiplicity == 1.0))
        notes.append(
            f"solved on {len(rows)} of {int(np.sum(counts[used]))} clustered vertices "
            f"({kept} that see rarely seen light bins, and a sample of the rest, each "
            f"counted {float(multiplicity.max()):.2f} times)"
        )
    data = _Data(problem, rows, options, multiplicity=multiplicity)
    col_norm2 = np.asarray(data.F.multiply(data.F).T @ (data.w * data.m).mean(axis=1)).ravel()
    lay = _layout(problem.lights, col_norm2, options.smooth_lambda, data.scale)
    for li, light in enumerate(problem.lights):
        start = sum(lt.size for lt in problem.lights[:li])
        seen = col_norm2[start : start + light.size] > 0
        if not seen.any():
            notes.append(f"light {light.name!r}: no clustered vertex receives its light")
    if not problem.lights:
        notes.append("no lights: albedos explain the radiance by indirect light alone")
    n_ml = len(lay.mono_lights)
    color0 = np.full((n_ml, 3), 1.0 / np.sqrt(3.0))
    lay.color_prior = color0.copy()
    lay.color_sqrt_weight = np.zeros(n_ml)
    # The scale of the colour priors' weights: the data term of a model off by 100 %.
    data_energy = float(np.sum(data.w * data.m * data.L**2))
    for i, light in enumerate(lay.mono_lights):
        if light.color_prior_weight > 0:
            c = np.asarray(light.color_prior, float)
            lay.color_prior[i] = color0[i] = c / np.linalg.norm(c)
            lay.color_sqrt_weight[i] = np.sqrt(light.color_prior_weight * data_energy)
    st = _State(
        rho=np.where(used[:, None], 0.5, np.nan) * np.ones((n_clusters, 3)),
        chrom=np.zeros((lay.n_chrom, 3)),
        profile=np.zeros(lay.n_mono),
        color=color0,
    )
    with one_blas_thread():  # threaded BLAS on small vectors is 10x slower under load
        if options.method == "alternating":
            iterations, converged, history = _solve_alternating(data, lay, st, options, progress)
        else:
            _, h = data.objective(st, lay)
            _light_step(data, lay, st, data.fit_weight(h))
            iterations, converged, history = _solve_joint_irls(data, lay, st, options, progress)
    objective, h = data.objective(st, lay)
    if not converged:
        notes.append(f"{options.method} solve stopped after {iterations} iterations")

    # back to absolute units
    s = data.scale
    icols = st.intensity_cols(lay, data.K) * s
    offsets = np.concatenate([[0], np.cumsum([lt.size for lt in problem.lights])]).astype(int)
    intensities, colors, profiles, share = {}, {}, {}, {}
    total_direct = 0.0
    contrib = {}
    for li, light in enumerate(problem.lights):
        block = icols[offsets[li] : offsets[li + 1]]
        intensities[light.name] = block
        contrib[light.name] = float(
            np.sum(data.F[:, offsets[li] : offsets[li + 1]] @ block) / max(len(data.L), 1)
        )
        total_direct += contrib[light.name]
    for i, light in enumerate(lay.mono_lights):
        colors[light.name] = st.color[i].copy()
        profiles[light.name] = st.profile[lay.mono_light_of_col == i] * s
    total = total_direct + float(np.sum(data.E) * s / max(len(data.L), 1))
    for light in problem.lights:
        share[light.name] = contrib[light.name] / total if total > 0 else 0.0
        if share[light.name] < 1e-3:
            notes.append(
                f"light {light.name!r} explains nothing (share {share[light.name]:.1e} of the "
                "irradiance): its intensity went to zero"
            )
    # residuals and weights of every clustered vertex, also those outside the subset
    full = _Data(problem, np.flatnonzero(used[problem.cluster]), options, scale=s)
    _, h_full = full.objective(st, lay)
    residual = np.full(problem.radiance.shape, np.nan)
    residual[full.rows] = (full.L - full.model(st, lay)) * s
    weights = np.zeros(problem.radiance.shape)
    weights[full.rows] = full.w * h_full
    rho = st.rho.copy()
    rho[~used] = np.nan
    return SolveResult(
        albedo=rho,
        intensities=intensities,
        colors=colors,
        profiles=profiles,
        cluster_used=used,
        weights=weights,
        residual=residual,
        objective=float(objective),
        iterations=int(iterations),
        converged=bool(converged),
        seconds=time.perf_counter() - t0,
        light_share=share,
        warnings=notes,
        history=history,
        method=options.method,
    )


def model_irradiance(
    indirect: np.ndarray,
    transfer: sp.csr_matrix | np.ndarray,
    lights: list[LightBlock],
    result: SolveResult,
) -> np.ndarray:
    """``(n, 3)`` the solved model's irradiance ``E_ind + F . I`` at the rows of ``transfer``."""
    intens = result.intensity_vector(lights)
    return np.asarray(indirect + (transfer @ intens if len(intens) else 0.0))


def footprint_operator(
    faces: np.ndarray,
    rows: np.ndarray,
    n_vertices: int,
    vertices: np.ndarray,
    rings: int = 1,
) -> sp.csr_matrix:
    """Averaging over each row vertex's neighbourhood, as a sparse ``(n, n)`` operator.

    Row ``i`` (mesh vertex ``rows[i]``) averages the row vertices within ``rings`` mesh
    edges of it, itself included, each weighted by its share of the area around it (a
    third of its faces' areas). Vertices that are not rows take no part.

    Parameters
    ----------
    faces : ndarray of int, shape (m, 3)
        Mesh triangles.
    rows : ndarray of int, shape (n,)
        The vertices that have a value (e.g. the receivers), in value order.
    n_vertices : int
        Vertices of the mesh.
    vertices : ndarray, shape (n_vertices, 3)
        Their positions (for the area weights).
    rings : int
        Neighbourhood size in mesh edges (0: the identity).

    Returns
    -------
    scipy.sparse.csr_matrix, shape (n, n)
        Rows sum to 1.

    Examples
    --------
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 0]], float)
    >>> op = footprint_operator(np.array([[0, 1, 2]]), np.array([0, 1, 3]), 4, v)
    >>> np.round(op.toarray(), 2).tolist()
    [[0.5, 0.5, 0.0], [0.5, 0.5, 0.0], [0.0, 0.0, 1.0]]
    """
    rows = np.asarray(rows, np.int64)
    n = len(rows)
    if rings <= 0:
        return sp.identity(n, format="csr")
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    area = vertex_areas(np.asarray(vertices, np.float64), faces)
    adj = (vertex_adjacency(faces, n_vertices) + sp.identity(n_vertices, format="csr")).astype(
        np.float64
    )
    reach = adj
    for _ in range(rings - 1):
        reach = ((reach @ adj) > 0).astype(np.float64).tocsr()
    # Vertices with no area (isolated) still count themselves.
    weight = np.where(area[rows] > 0, area[rows], 1e-12)
    op = reach[rows][:, rows] @ sp.diags(weight)
    return (sp.diags(1.0 / np.asarray(op.sum(axis=1)).ravel()) @ op).tocsr()


def per_vertex_albedo(
    radiance: np.ndarray,
    indirect: np.ndarray,
    transfer: sp.csr_matrix | np.ndarray,
    lights: list[LightBlock],
    result: SolveResult,
    min_irradiance: float = 1e-9,
    footprint: sp.csr_matrix | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Albedo of each vertex from the solved lighting (the last step of thesis 5.4).

    With the lights fixed, eq. 5.6 has one unknown per vertex and channel, so its least
    squares solution is ``rho_V = pi * Lbar_V / (E_ind(V) + F(V) . I)``. Values above 1
    are kept (not clipped) and flagged: they are non-physical and mark errors in the
    geometry, the radiance or the light model (thesis Fig. 5.10).

    Parameters
    ----------
    radiance, indirect : ndarray, shape (n, 3)
        ``Lbar`` and the rescaled ``E_ind`` of every vertex to solve.
    transfer : matrix, shape (n, K)
        The light transfer rows of these vertices.
    lights : list of LightBlock
        The lights, in column order.
    result : SolveResult
        The solved lighting.
    min_irradiance : float
        Irradiance below which the albedo is undetermined (NaN).
    footprint : sparse matrix, shape (n, n), optional
        Row-stochastic averaging of the irradiance over each vertex's surroundings
        (:func:`footprint_operator`), applied before the division: ``Lbar`` is a mean
        over the pixels around a vertex, so the irradiance it is divided by should be
        one too.

    Returns
    -------
    albedo : ndarray, shape (n, 3)
        Per-vertex albedo; NaN where the irradiance is below ``min_irradiance``.
    nonphysical : ndarray of bool, shape (n,)
        Vertices with some channel above 1.
    """
    irradiance = model_irradiance(indirect, transfer, lights, result)
    if footprint is not None:
        irradiance = np.asarray(footprint @ irradiance)
    with np.errstate(divide="ignore", invalid="ignore"):
        albedo = np.where(irradiance > min_irradiance, np.pi * radiance / irradiance, np.nan)
    nonphysical = np.any(albedo > 1.0, axis=1)
    return albedo, nonphysical
