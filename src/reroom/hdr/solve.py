"""Global exposure calibration: eq. 3.1 of the thesis, solved like bundle adjustment.

The model is ``X_ij = t_j * b_i`` per channel: linear pixel value ``X_ij`` of vertex
``i`` in frame ``j``, per-frame per-channel scale (exposure x white balance)
``t_j``, per-vertex radiance ``b_i``; ``t_ref = 1`` fixes the scale ambiguity.

Solvers (``SolveOptions.method``; ``benchmarks/bench_hdr.py --solvers`` compares them):

``"log-schur"`` (default)
    In the log domain the model is *linear*: ``log X_ij = tau_j + beta_i``. Each
    vertex's ``beta_i`` is eliminated in closed form (the Schur complement, as in
    sparse bundle adjustment), leaving an ``F x F`` system -- the weighted
    Laplacian of the frames' co-visibility graph -- solved directly (Cholesky).
    Robustness (specular highlights, misregistered pixels) comes from iteratively
    reweighted least squares with Cauchy (or Huber) weights on residuals scaled
    by their MAD.
    One direct solve per IRLS round; no step sizes, no initialisation.
``"linear-schur"``
    Eq. 3.1 exactly as written (linear residuals ``t_j b_i - X_ij``), by
    Levenberg-Marquardt with the same Schur reduction per step (what Ceres does
    for the thesis), started from all ones unless given a start.
``"alternating"``
    Eq. 3.1 by alternating closed-form updates of ``b`` and ``t`` (block
    coordinate descent), started from all ones.
``"scipy"``
    Eq. 3.1 with :func:`scipy.optimize.least_squares` (trust-region reflective,
    sparse Jacobian, LSMR); small problems only.

Frames that share no vertex with the reference frame's component cannot be tied
to it; each such component is solved on its own, and its level is set so that
its mean log-exposure equals the main component's (auto-exposure aims every
frame at a similar brightness); their status says so.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from reroom.errors import ReroomError
from reroom.hdr import _kernels as K
from reroom.hdr.observe import CLIPPED, Observations
from reroom.threads import one_blas_thread

__all__ = [
    "ExposureSolution",
    "SolveOptions",
    "SolveProblem",
    "hat_confidence",
    "solve_exposures",
    "solve_problem",
]

METHODS = ("log-schur", "linear-schur", "alternating", "scipy")


@dataclass(frozen=True)
class SolveOptions:
    """Options of the exposure solve.

    Attributes
    ----------
    method:
        One of ``"log-schur"``, ``"linear-schur"``, ``"alternating"``, ``"scipy"``.
    min_level, max_level:
        Samples enter the solve only when every channel's 8-bit level lies in
        this range (dark pixels are quantisation and read noise; bright ones may
        be clipped).
    max_vertices:
        Solve on a random subset of at most this many vertices (thesis: "a random
        subset of the vertices"), topped up so that every frame keeps at least
        ``min_frame_samples`` samples where it has them.
    max_samples_per_vertex:
        Keep at most this many samples per vertex (random; samples of frames with
        few samples first). Bounds the Schur complement's cost, ``sum n_i^2``, and
        keeps vertices seen by very many frames (often at grazing angles, or not
        quite diffuse) from dominating: on the accuracy benchmark 16 gave a median
        exposure error of 0.33-0.35 % against 0.46 % with 64 (``docs/hdr.md``).
    min_frame_samples:
        See ``max_vertices``; frames with fewer usable samples are still solved.
    min_clean_samples:
        A frame with fewer clean usable samples (not near an image or depth edge)
        also uses its samples near edges (:func:`usable_samples`).
    weighting:
        ``"uniform"``: every sample counts the same, as in the thesis's solve
        ("for each associated pixel ... a data term"); ``"hat"``: each sample
        weighted by the hat confidence (eq. 3.3) of its least confident channel.
        Uniform measured better on all three benchmark scans (``docs/hdr.md``).
    robust, loss, robust_k:
        Iteratively reweighted least squares against outliers (specular
        highlights, misregistered pixels) with ``loss`` ``"cauchy"`` (default:
        redescending, so gross outliers end up with almost no weight) or
        ``"huber"``, on residuals in units of ``robust_k`` robust (MAD) standard
        deviations.
    irls_iterations, max_iterations, tol:
        IRLS rounds; iteration cap and tolerance (on ``max |d log t|``) of the
        iterative linear-domain solvers.
    reference:
        The frame with ``t = 1`` (the first usable frame if it has no samples).
    seed:
        Random subset seed.
    """

    method: str = "log-schur"
    min_level: int = 8
    max_level: int = 245
    max_vertices: int = 30000
    max_samples_per_vertex: int = 16
    min_frame_samples: int = 40
    min_clean_samples: int = 40
    weighting: str = "uniform"
    robust: bool = True
    loss: str = "cauchy"
    robust_k: float = 1.0
    irls_iterations: int = 8
    max_iterations: int = 200
    tol: float = 1e-10
    reference: int = 0
    seed: int = 0


@dataclass
class ExposureSolution:
    """Per-frame, per-channel scales and how they were obtained.

    Attributes
    ----------
    scales:
        ``(F, 3)`` float64 ``t_j`` per channel; NaN for frames without an exposure.
    status:
        Per frame: ``"reference"``, ``"ok"``, ``"no usable samples"``, or
        ``"disconnected: level guessed"``.
    reference:
        Index of the frame with ``t = 1``.
    samples:
        ``(F,)`` samples of each frame that entered the solve.
    info:
        Method, timings, iterations, residual spread, problem size.
    """

    scales: np.ndarray
    status: list[str]
    reference: int
    samples: np.ndarray
    info: dict = field(default_factory=dict)

    @property
    def solved(self) -> np.ndarray:
        """``(F,)`` bool: frames that have an exposure."""
        return np.all(np.isfinite(self.scales), axis=1)


@dataclass
class SolveProblem:
    """Samples grouped by vertex, ready for the solvers.

    ``x[k]`` (linear, ``(S, 3)``) is the value of vertex ``vertex_ids[v]`` in frame
    ``frames[k]`` for ``offsets[v] <= k < offsets[v + 1]``; ``weights`` are the base
    weights; ``local[k]`` is the compact vertex index ``v`` of sample ``k``.
    """

    n_frames: int
    vertex_ids: np.ndarray
    offsets: np.ndarray
    local: np.ndarray
    frames: np.ndarray
    x: np.ndarray
    weights: np.ndarray

    @staticmethod
    def build(
        vertex: np.ndarray,
        frame: np.ndarray,
        x: np.ndarray,
        n_frames: int,
        weights: np.ndarray | None = None,
    ) -> SolveProblem:
        """Group samples ``(vertex, frame, x)`` by vertex.

        Raises
        ------
        ReroomError
            On non-positive or non-finite values, frame indices out of range, or
            shapes that do not match.
        """
        vertex = np.asarray(vertex, np.int64).ravel()
        frame = np.asarray(frame, np.int64).ravel()
        x = np.asarray(x, np.float64)
        if x.ndim == 1:
            x = x[:, None]
        if len(vertex) != len(frame) or len(x) != len(vertex):
            raise ReroomError("vertex, frame and value arrays must have the same length")
        if len(frame) and (frame.min() < 0 or frame.max() >= n_frames):
            raise ReroomError(f"frame indices must lie in [0, {n_frames})")
        if not np.all(np.isfinite(x)) or np.any(x <= 0):
            raise ReroomError("values must be finite and positive (filter dark samples first)")
        w = np.ones(len(vertex)) if weights is None else np.asarray(weights, np.float64)
        order = np.lexsort((frame, vertex))
        vs = vertex[order]
        ids, local, counts = np.unique(vs, return_inverse=True, return_counts=True)
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        return SolveProblem(
            int(n_frames),
            ids,
            offsets,
            local.astype(np.int64),
            frame[order].astype(np.int64),
            x[order],
            w[order],
        )

    @property
    def n_vertices(self) -> int:
        return len(self.vertex_ids)

    def components(self) -> tuple[int, np.ndarray]:
        """Connected components of the frames through shared vertices; -1 = no samples."""
        nf, nv = self.n_frames, self.n_vertices
        rows = self.frames
        cols = nf + self.local
        adj = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(nf + nv, nf + nv)).tocsr()
        n, lab = connected_components(adj, directed=False)
        frame_lab = lab[:nf].copy()
        has = np.bincount(self.frames, minlength=nf) > 0
        frame_lab[~has] = -1
        return n, frame_lab


def hat_confidence(levels: np.ndarray) -> np.ndarray:
    """The thesis's eq. 3.3: ``X/127`` up to 127, ``(256 - X)/127`` above (float64)."""
    x = np.asarray(levels, dtype=np.float64)
    return np.where(x > 127, (256.0 - x) / 127.0, x / 127.0)


# --------------------------------------------------------------------------- solvers


def _robust_weights(r: np.ndarray, k: float, loss: str = "huber") -> tuple[np.ndarray, np.ndarray]:
    """IRLS weights of residual rows ``r`` (S, C), scaled per channel by the MAD.

    ``"huber"``: ``min(1, k / rho)``; ``"cauchy"``: ``1 / (1 + (rho / k)^2)``, which
    keeps discounting ever larger residuals (a redescending influence).
    """
    sigma = 1.4826 * np.median(np.abs(r), axis=0)
    sigma = np.maximum(sigma, 1e-9)
    rho = np.sqrt(np.mean((r / sigma) ** 2, axis=1))
    if loss == "cauchy":
        return 1.0 / (1.0 + (rho / k) ** 2), sigma
    return np.minimum(1.0, k / np.maximum(rho, 1e-300)), sigma


def _free_frames(prob: SolveProblem, refs: np.ndarray, labels: np.ndarray) -> np.ndarray:
    free = labels >= 0
    free[refs] = False
    return np.flatnonzero(free)


def _spd_solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve the (symmetric positive semi-definite) reduced system, robustly."""
    if a.shape[0] == 0:
        return np.zeros_like(b)
    try:
        # One BLAS thread: for F ~ 1000 a Cholesky takes ~20 ms, and OpenBLAS's
        # threads spin-waiting on a busy 2-core machine made it 40x slower.
        with one_blas_thread():
            factor = scipy.linalg.cho_factor(a, check_finite=False)
            return scipy.linalg.cho_solve(factor, b, check_finite=False)
    except (np.linalg.LinAlgError, scipy.linalg.LinAlgError):
        # Nearly disconnected frames make it singular: least squares still answers.
        return np.linalg.lstsq(a, b, rcond=None)[0]


def _log_schur(
    prob: SolveProblem, refs: np.ndarray, labels: np.ndarray, opt: SolveOptions
) -> tuple[np.ndarray, dict]:
    y = np.log(prob.x)
    nc = y.shape[1]
    nf, nv = prob.n_frames, prob.n_vertices
    free = _free_frames(prob, refs, labels)
    w = prob.weights.copy()
    tau = np.zeros((nf, nc))
    rounds = (opt.irls_iterations if opt.robust else 0) + 1
    sigma = np.zeros(nc)
    done = 0
    for it in range(rounds):
        s_i = np.bincount(prob.local, w, minlength=nv)
        d_j = np.bincount(prob.frames, w, minlength=nf)
        m = K.schur_outer(prob.offsets, prob.frames, w, s_i, nf)
        a = np.diag(d_j) - m
        rhs = np.empty((nf, nc))
        for c in range(nc):
            ybar = np.bincount(prob.local, w * y[:, c], minlength=nv) / np.maximum(s_i, 1e-300)
            rhs[:, c] = np.bincount(prob.frames, w * (y[:, c] - ybar[prob.local]), minlength=nf)
        new = np.zeros((nf, nc))
        new[free] = _spd_solve(a[np.ix_(free, free)], rhs[free])
        change = float(np.max(np.abs(new - tau))) if it else np.inf
        tau = new
        done = it + 1
        s_i = np.bincount(prob.local, w, minlength=nv)
        beta = np.stack(
            [
                np.bincount(prob.local, w * (y[:, c] - tau[prob.frames, c]), minlength=nv)
                / np.maximum(s_i, 1e-300)
                for c in range(nc)
            ],
            axis=1,
        )
        r = y - tau[prob.frames] - beta[prob.local]
        rw, sigma = _robust_weights(r, opt.robust_k, opt.loss)
        if not opt.robust or change < opt.tol:
            break
        w = prob.weights * rw
    return np.exp(tau), {"irls_rounds": done, "residual_sigma_log": sigma.tolist()}


def _vertex_values(prob: SolveProblem, t: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Closed-form radiances ``b_i = sum w t x / sum w t^2`` for fixed scales ``t``."""
    tf = t[prob.frames]
    nv = prob.n_vertices
    out = np.empty((nv, prob.x.shape[1]))
    for c in range(prob.x.shape[1]):
        num = np.bincount(prob.local, w * tf[:, c] * prob.x[:, c], nv)
        den = np.bincount(prob.local, w * tf[:, c] ** 2, nv)
        out[:, c] = num / np.maximum(den, 1e-300)
    return out


def _normalise(t: np.ndarray, refs: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Rescale each component so that its reference frame has ``t = 1``."""
    out = t.copy()
    for r in refs:
        members = labels == labels[r]
        out[members] = t[members] / t[r]
    return out


def _alternating(
    prob: SolveProblem,
    refs: np.ndarray,
    labels: np.ndarray,
    opt: SolveOptions,
    start: np.ndarray | None,
) -> tuple[np.ndarray, dict]:
    nc = prob.x.shape[1]
    nf = prob.n_frames
    t = np.ones((nf, nc)) if start is None else np.where(np.isfinite(start), start, 1.0)
    w = prob.weights.copy()
    iters = 0
    rounds = (opt.irls_iterations if opt.robust else 0) + 1
    for _ in range(rounds):
        for _ in range(opt.max_iterations):
            b = _vertex_values(prob, t, w)
            bl = b[prob.local]
            num = np.stack(
                [np.bincount(prob.frames, w * bl[:, c] * prob.x[:, c], nf) for c in range(nc)], 1
            )
            den = np.stack([np.bincount(prob.frames, w * bl[:, c] ** 2, nf) for c in range(nc)], 1)
            new = np.where(den > 0, num / np.maximum(den, 1e-300), 1.0)
            new = _normalise(new, refs, labels)
            iters += 1
            change = float(np.max(np.abs(np.log(new) - np.log(t))))
            t = new
            if change < opt.tol:
                break
        if not opt.robust:
            break
        b = _vertex_values(prob, t, w)
        r = np.log(prob.x) - np.log(t[prob.frames] * np.maximum(b[prob.local], 1e-300))
        w = prob.weights * _robust_weights(r, opt.robust_k, opt.loss)[0]
    return t, {"iterations": iters}


def _linear_schur(
    prob: SolveProblem,
    refs: np.ndarray,
    labels: np.ndarray,
    opt: SolveOptions,
    start: np.ndarray | None,
) -> tuple[np.ndarray, dict]:
    """Levenberg-Marquardt on eq. 3.1 with the Schur complement per step, per channel."""
    nc = prob.x.shape[1]
    nf, nv = prob.n_frames, prob.n_vertices
    free = _free_frames(prob, refs, labels)
    t_all = np.ones((nf, nc)) if start is None else np.where(np.isfinite(start), start, 1.0)
    t_all = _normalise(t_all, refs, labels)
    w0 = prob.weights.copy()
    iters = 0
    rounds = (opt.irls_iterations if opt.robust else 0) + 1
    w = w0
    for _ in range(rounds):
        for c in range(nc):
            x = prob.x[:, c]
            t = t_all[:, c].copy()
            b = _vertex_values(prob, t_all, w)[:, c]
            lam = 1e-4

            def cost(t_: np.ndarray, b_: np.ndarray, x=x, w=w) -> float:
                r_ = t_[prob.frames] * b_[prob.local] - x
                return float(np.sum(w * r_ * r_))

            f = cost(t, b)
            for _ in range(opt.max_iterations):
                tf, bl = t[prob.frames], b[prob.local]
                r = tf * bl - x
                u = np.bincount(prob.frames, w * bl * bl, nf)
                v = np.bincount(prob.local, w * tf * tf, nv)
                gt = np.bincount(prob.frames, w * r * bl, nf)
                gb = np.bincount(prob.local, w * r * tf, nv)
                a_k = w * tf * bl
                # J^T J of this residual has off-diagonal w (2 t b - x) terms in a full
                # Newton step; Gauss-Newton keeps w t b, which is what Ceres uses.
                while True:
                    ud, vd = u * (1 + lam), v * (1 + lam)
                    m = K.schur_outer(prob.offsets, prob.frames, a_k, vd, nf)
                    s = np.diag(ud) - m
                    rhs = -gt + np.bincount(
                        prob.frames, a_k * (gb / np.maximum(vd, 1e-300))[prob.local], nf
                    )
                    dt = np.zeros(nf)
                    dt[free] = _spd_solve(s[np.ix_(free, free)], rhs[free])
                    wdt = np.bincount(prob.local, a_k * dt[prob.frames], nv)
                    db = (-gb - wdt) / np.maximum(vd, 1e-300)
                    t_new, b_new = t + dt, b + db
                    f_new = cost(t_new, b_new) if np.all(t_new[free] > 0) else np.inf
                    iters += 1
                    if f_new <= f:
                        lam = max(lam / 10, 1e-12)
                        break
                    lam *= 10
                    if lam > 1e12:
                        break
                if lam > 1e12:
                    break
                step = float(np.max(np.abs(np.log(t_new[free] / t[free])))) if len(free) else 0.0
                t, b, f = t_new, b_new, f_new
                if step < opt.tol:
                    break
            t_all[:, c] = t
        if not opt.robust:
            break
        b3 = _vertex_values(prob, t_all, w)
        r3 = np.log(prob.x) - np.log(t_all[prob.frames] * np.maximum(b3[prob.local], 1e-300))
        w = w0 * _robust_weights(r3, opt.robust_k, opt.loss)[0]
    return t_all, {"iterations": iters}


def _scipy(
    prob: SolveProblem,
    refs: np.ndarray,
    labels: np.ndarray,
    opt: SolveOptions,
    start: np.ndarray | None,
) -> tuple[np.ndarray, dict]:
    from scipy.optimize import least_squares

    nc = prob.x.shape[1]
    nf, nv = prob.n_frames, prob.n_vertices
    free = _free_frames(prob, refs, labels)
    pos = -np.ones(nf, np.int64)
    pos[free] = np.arange(len(free))
    nfree = len(free)
    t0 = np.ones((nf, nc)) if start is None else np.where(np.isfinite(start), start, 1.0)
    t0 = _normalise(t0, refs, labels)
    sw = np.sqrt(prob.weights)
    rows = np.arange(len(prob.frames))
    fcol = pos[prob.frames]
    tcol_ok = fcol >= 0
    nfev = 0
    out = t0.copy()
    for c in range(nc):
        x = prob.x[:, c]

        def unpack(p: np.ndarray, c=c) -> tuple[np.ndarray, np.ndarray]:
            t = t0[:, c].copy()
            t[free] = p[:nfree]
            return t, p[nfree:]

        def fun(p: np.ndarray, x=x) -> np.ndarray:
            t, b = unpack(p)
            return sw * (t[prob.frames] * b[prob.local] - x)

        def jac(p: np.ndarray) -> sp.csr_matrix:
            t, b = unpack(p)
            data_t = (sw * b[prob.local])[tcol_ok]
            data_b = sw * t[prob.frames]
            jt = sp.csr_matrix((data_t, (rows[tcol_ok], fcol[tcol_ok])), shape=(len(rows), nfree))
            jb = sp.csr_matrix((data_b, (rows, prob.local)), shape=(len(rows), nv))
            return sp.hstack([jt, jb]).tocsr()

        b0 = _vertex_values(prob, t0, prob.weights)[:, c]
        p0 = np.concatenate([t0[free, c], b0])
        res = least_squares(
            fun,
            p0,
            jac=jac,
            method="trf",
            tr_solver="lsmr",
            loss="huber" if opt.robust else "linear",
            f_scale=float(np.median(x) * 0.05) if opt.robust else 1.0,
            xtol=1e-15,
            ftol=1e-15,
            gtol=1e-15,
            max_nfev=opt.max_iterations * 10,
            x_scale="jac",
        )
        nfev += int(res.nfev)
        out[:, c] = unpack(res.x)[0]
    return out, {"iterations": nfev}


def solve_problem(
    prob: SolveProblem,
    options: SolveOptions | None = None,
    start: np.ndarray | None = None,
) -> ExposureSolution:
    """Solve eq. 3.1 for the scales of every frame of ``prob``.

    Parameters
    ----------
    prob:
        Samples grouped by vertex (:meth:`SolveProblem.build`).
    options:
        :class:`SolveOptions` (``method``, robustness, reference frame).
    start:
        Optional ``(F, C)`` starting scales for the iterative linear-domain methods.

    Returns
    -------
    ExposureSolution
        With NaN scales for frames without samples.
    """
    opt = options or SolveOptions()
    if opt.method not in METHODS:
        raise ReroomError(f"unknown solver {opt.method!r}; choose one of {METHODS}")
    t0 = time.perf_counter()
    nf = prob.n_frames
    samples = np.bincount(prob.frames, minlength=nf)
    n_comp, labels = prob.components()
    status = ["no usable samples"] * nf
    nc = prob.x.shape[1]
    scales = np.full((nf, nc), np.nan)
    if not np.any(labels >= 0):
        return ExposureSolution(scales, status, -1, samples, {"method": opt.method})
    reference = int(opt.reference) if 0 <= opt.reference < nf else 0
    if labels[reference] < 0:
        reference = int(np.flatnonzero(labels >= 0)[0])
    # One reference per component: the global one, or each component's first frame.
    comp_ids = [c for c in np.unique(labels) if c >= 0]
    refs = np.array(
        [
            reference if labels[reference] == c else int(np.flatnonzero(labels == c)[0])
            for c in comp_ids
        ]
    )
    if opt.method == "log-schur":
        t, info = _log_schur(prob, refs, labels, opt)
    elif opt.method == "alternating":
        t, info = _alternating(prob, refs, labels, opt, start)
    elif opt.method == "linear-schur":
        t, info = _linear_schur(prob, refs, labels, opt, start)
    else:
        t, info = _scipy(prob, refs, labels, opt, start)
    t = _normalise(t, refs, labels)
    main = labels == labels[reference]
    scales[main] = t[main]
    for j in np.flatnonzero(main):
        status[j] = "ok"
    status[reference] = "reference"
    main_level = np.mean(np.log(t[main]), axis=0)
    for r in refs:
        if r == reference:
            continue
        members = labels == labels[r]
        # No shared vertex: nothing ties this group's level to the reference. Assume
        # the camera's auto-exposure kept a similar level on average.
        shift = main_level - np.mean(np.log(t[members]), axis=0)
        scales[members] = t[members] * np.exp(shift)
        for j in np.flatnonzero(members):
            status[j] = "disconnected: level guessed"
    if n_comp and len(refs) > 1:
        warnings.warn(
            f"{len(refs) - 1} group(s) of frames share no vertex with reference frame "
            f"{reference}; their exposure level is a guess",
            stacklevel=2,
        )
    bad = ~np.all(np.isfinite(scales) & (scales > 0), axis=1) & (labels >= 0)
    if bad.any():
        scales[bad] = np.nan
        for j in np.flatnonzero(bad):
            status[j] = "solver failed"
    info.update(
        method=opt.method,
        seconds=round(time.perf_counter() - t0, 4),
        frames=int(nf),
        vertices=int(prob.n_vertices),
        samples=int(len(prob.frames)),
        components=len(refs),
    )
    return ExposureSolution(scales, status, reference, samples, info)


def usable_samples(obs: Observations, opt: SolveOptions, fallback: bool = True) -> np.ndarray:
    """``(S,)`` bool: samples fit for the solve (and the baselines).

    Clean (not near an image or depth edge), no clipped pixel in their value,
    every channel's level in ``[min_level, max_level]`` and a positive linear value.
    With ``fallback``, a frame with fewer than ``min_clean_samples`` such samples
    also uses its samples near edges, rather than get a poor exposure or none.
    """
    v = obs.value
    # Per-channel comparisons: reductions along a length-3 axis are slow on 30M rows.
    levels_ok = (obs.flags & CLIPPED) == 0
    for c in range(v.shape[1]):
        levels_ok &= (v[:, c] >= opt.min_level) & (v[:, c] <= opt.max_level)
        levels_ok &= obs.linear[:, c] > 0
    ok = levels_ok & obs.clean
    if fallback and len(ok):
        # A frame with too few clean samples falls back on its samples near edges.
        off = obs.frame_offsets
        have = np.add.reduceat(ok, off[:-1])
        have[off[:-1] == off[1:]] = 0
        for j in np.flatnonzero(have < opt.min_clean_samples):
            ok[off[j] : off[j + 1]] = levels_ok[off[j] : off[j + 1]]
    return ok


def select_subset(obs: Observations, usable: np.ndarray, opt: SolveOptions) -> np.ndarray:
    """Indices of the samples that enter the solve (see :class:`SolveOptions`).

    Written to touch the full sample arrays (tens of millions) as few times as
    possible: vertices are chosen from per-vertex counts, and only the chosen
    vertices' samples are gathered.
    """
    rng = np.random.default_rng(opt.seed)
    if not np.any(usable):
        return np.zeros(0, np.int64)
    per_vertex = K.masked_bincount(obs.vertex, usable, obs.n_vertices)
    multi = per_vertex >= 2
    cand = np.flatnonzero(multi)
    if len(cand) > opt.max_vertices:
        chosen = np.zeros(obs.n_vertices, bool)
        chosen[rng.choice(cand, opt.max_vertices, replace=False)] = True
    else:
        chosen = multi
    in_sub = usable & chosen[obs.vertex]
    # Top up frames that the random subset leaves with too few samples (samples are
    # grouped by frame, so a frame's count is a sum over its slice).
    off = obs.frame_offsets
    have = np.add.reduceat(in_sub, off[:-1]) if len(in_sub) else np.zeros(obs.n_frames)
    have[off[:-1] == off[1:]] = 0
    added = False
    for j in np.flatnonzero(have < opt.min_frame_samples):
        s, e = off[j], off[j + 1]
        pool = np.flatnonzero(usable[s:e] & multi[obs.vertex[s:e]] & ~in_sub[s:e])
        if len(pool):
            pick = rng.permutation(pool)[: opt.min_frame_samples - int(have[j])]
            chosen[obs.vertex[s + pick]] = True
            added = True
    if added:
        in_sub = usable & chosen[obs.vertex]
    idx = np.flatnonzero(in_sub)
    vert = obs.vertex[idx]
    frm = obs.frame[idx]
    # Cap samples per vertex, keeping a random subset in which samples of sparsely
    # covered frames go first: shuffle, move those to the front (stable), then
    # group by vertex with a stable counting sort and keep each group's head.
    counts = np.bincount(frm, minlength=obs.n_frames)
    perm = rng.permutation(len(idx))
    sparse = counts[frm[perm]] < 2 * opt.min_frame_samples
    perm = perm[np.argsort(~sparse, kind="stable")]
    order, offsets = K.group_by(vert[perm], obs.n_vertices)
    grouped = perm[order]
    rank = np.arange(len(grouped)) - offsets[vert[grouped]]
    return np.sort(idx[grouped[rank < opt.max_samples_per_vertex]])


def _rank_in_group(groups: np.ndarray) -> np.ndarray:
    """Position of each element among the elements of its group, in array order."""
    order = np.argsort(groups, kind="stable")
    g = groups[order]
    starts = np.searchsorted(g, g, side="left")
    rank = np.empty(len(groups), np.int64)
    rank[order] = np.arange(len(groups)) - starts
    return rank


def solve_exposures(obs: Observations, options: SolveOptions | None = None) -> ExposureSolution:
    """Solve eq. 3.1 on a vertex subset of ``obs`` (their linear sample values).

    Returns an :class:`ExposureSolution`; frames without usable samples (black,
    saturated, seeing nothing) get NaN scales and a status saying so.
    """
    opt = options or SolveOptions()
    usable = usable_samples(obs, opt)
    sel = select_subset(obs, usable, opt)
    x = obs.linear_values(sel)
    if opt.weighting == "hat":
        w = hat_confidence(obs.value[sel]).min(axis=1)
    elif opt.weighting == "uniform":
        w = np.ones(len(sel))
    else:
        raise ReroomError(f"weighting must be 'hat' or 'uniform', not {opt.weighting!r}")
    prob = SolveProblem.build(obs.vertex[sel], obs.frame[sel], x, obs.n_frames, w)
    sol = solve_problem(prob, opt)
    sol.info["usable_samples"] = int(np.count_nonzero(usable))
    return sol
