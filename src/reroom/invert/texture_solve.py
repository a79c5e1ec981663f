"""A plane's texture as the least-squares answer to every photo pixel that saw it.

:func:`reroom.invert.textures.photo_textures` used to average the photo samples that
fall in each texel. That texture is the surface blurred three times over: by each
photo pixel's footprint (a pixel integrates the surface over its area), by the texel
the sample is binned into, and again by the renderer's bilinear lookup between texel
centres, before the render's own pixel integrates it once more. On the 160x120
`furnished` scans a plank floor kept a third of its pattern's contrast (the high-pass
regression of the renders on the truth's, 0.36).

Here every sample is a pixel: its value is the mean of the bilinear texture over its
footprint, the parallelogram its pixel square projects to on the plane (sampled at
2 x 2 points). The texture that best explains all samples, on a texel grid finer than
the photos' pixels, is solved by conjugate gradients on the normal equations, with a
penalty on differences between neighbouring texels, its weight set per plane (it decides
texels no footprint covers well and keeps the noise of a deconvolution down). The renderer then
blurs it once, as the camera does.

The operators are numba loops: a footprint touches up to 16 texels and a 300-frame
640x360 scan gives millions of samples, so neither a stored sparse matrix (hundreds of
millions of entries) nor numpy gathers (16 temporary arrays of that size per pass) do
well. No library solves this multi-view super-resolution problem for planar textures.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

__all__ = [
    "FootprintSamples",
    "back_projection",
    "median_footprint",
    "sample_range",
    "solve_texels",
]

#: Sub-sample offsets within a pixel (midpoint rule of a box over 2 x 2 cells).
_Q = (-0.25, 0.25)


@dataclass
class FootprintSamples:
    """Photo samples on texture planes, with their pixels' footprints.

    Attributes
    ----------
    plane:
        ``(N,)`` index of the plane each sample lies on.
    centre:
        ``(N, 2)`` the pixel centre's texture position, in texel-centre coordinates
        (texel ``(i, j)``'s centre at ``(j, i)``: column, row).
    jacobian:
        ``(N, 2, 2)`` how that position moves per pixel: ``[:, :, 0]`` along the
        image's x, ``[:, :, 1]`` along its y (texels per pixel).
    value:
        ``(N, 3)`` the sample (an albedo: the pixel's radiance over the irradiance).
    """

    plane: np.ndarray
    centre: np.ndarray
    jacobian: np.ndarray
    value: np.ndarray

    def __len__(self) -> int:
        return len(self.plane)


@nb.njit(cache=True, inline="always")
def _taps(u, v, w, h):
    """Bilinear taps at texel-centre position ``(u, v)`` on a ``h x w`` grid (clamped,
    as the renderer's ``wrap_mode: clamp``): the four flat offsets and weights."""
    u = min(max(u, 0.0), w - 1.0)
    v = min(max(v, 0.0), h - 1.0)
    c0 = min(int(u), w - 2) if w > 1 else 0
    r0 = min(int(v), h - 2) if h > 1 else 0
    fu = u - c0
    fv = v - r0
    c1 = c0 + 1 if w > 1 else c0
    r1 = r0 + 1 if h > 1 else r0
    return (
        r0 * w + c0,
        r0 * w + c1,
        r1 * w + c0,
        r1 * w + c1,
        (1.0 - fu) * (1.0 - fv),
        fu * (1.0 - fv),
        (1.0 - fu) * fv,
        fu * fv,
    )


@nb.njit(cache=True, parallel=True)
def _forward(tex, plane, centre, jac, starts, widths, heights, out):
    """``out[s] = mean over sample s's footprint of the bilinear texture``."""
    n = plane.shape[0]
    for s in nb.prange(n):
        p = plane[s]
        b = starts[p]
        w = widths[p]
        h = heights[p]
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        for qx in _Q:
            for qy in _Q:
                u = centre[s, 0] + jac[s, 0, 0] * qx + jac[s, 0, 1] * qy
                v = centre[s, 1] + jac[s, 1, 0] * qx + jac[s, 1, 1] * qy
                i00, i01, i10, i11, w00, w01, w10, w11 = _taps(u, v, w, h)
                a0 += (
                    w00 * tex[b + i00, 0]
                    + w01 * tex[b + i01, 0]
                    + w10 * tex[b + i10, 0]
                    + w11 * tex[b + i11, 0]
                )
                a1 += (
                    w00 * tex[b + i00, 1]
                    + w01 * tex[b + i01, 1]
                    + w10 * tex[b + i10, 1]
                    + w11 * tex[b + i11, 1]
                )
                a2 += (
                    w00 * tex[b + i00, 2]
                    + w01 * tex[b + i01, 2]
                    + w10 * tex[b + i10, 2]
                    + w11 * tex[b + i11, 2]
                )
        out[s, 0] = 0.25 * a0
        out[s, 1] = 0.25 * a1
        out[s, 2] = 0.25 * a2


@nb.njit(cache=True, parallel=True)
def _adjoint(res, plane, centre, jac, starts, widths, heights, n_tex, n_chunks, mode):
    """The transpose of :func:`_forward` applied to ``res`` (``(N, 3)``): each sample's
    value spread back over its footprint's taps (``mode`` 0). Any other ``mode``
    ignores ``res`` and sums the taps' weights (each texel's coverage, in samples) into
    column 0 and their squares into column 1: the normal matrix's diagonal, but for
    the cross terms of a sample's taps that land on the same texel (a little under
    it; it scales the penalty and the preconditioner, which need no more). Chunks of
    samples scatter into their own buffers (no races)."""
    n = plane.shape[0]
    buf = np.zeros((n_chunks, n_tex, 3))
    step = (n + n_chunks - 1) // n_chunks
    for k in nb.prange(n_chunks):
        for s in range(k * step, min(n, (k + 1) * step)):
            p = plane[s]
            b = starts[p]
            w = widths[p]
            h = heights[p]
            for qx in _Q:
                for qy in _Q:
                    u = centre[s, 0] + jac[s, 0, 0] * qx + jac[s, 0, 1] * qy
                    v = centre[s, 1] + jac[s, 1, 0] * qx + jac[s, 1, 1] * qy
                    i00, i01, i10, i11, w00, w01, w10, w11 = _taps(u, v, w, h)
                    idx = (i00, i01, i10, i11)
                    wt = (w00, w01, w10, w11)
                    for t in range(4):
                        if mode != 0:
                            buf[k, b + idx[t], 0] += 0.25 * wt[t]
                            buf[k, b + idx[t], 1] += (0.25 * wt[t]) ** 2
                        else:
                            for c in range(3):
                                buf[k, b + idx[t], c] += 0.25 * wt[t] * res[s, c]
    out = np.zeros((n_tex, 3))
    for k in range(n_chunks):
        out += buf[k]
    return out


@nb.njit(cache=True, parallel=True)
def _laplacian(x, starts, widths, heights, out):
    """``out = D^T D x``: each texel's sum of its differences from its 4-neighbours on
    its plane (the penalty's gradient, halved)."""
    for p in range(starts.shape[0] - 1):
        b = starts[p]
        w = widths[p]
        h = heights[p]
        for r in nb.prange(h):
            for c in range(w):
                i = b + r * w + c
                for ch in range(3):
                    acc = 0.0
                    if c > 0:
                        acc += x[i, ch] - x[i - 1, ch]
                    if c < w - 1:
                        acc += x[i, ch] - x[i + 1, ch]
                    if r > 0:
                        acc += x[i, ch] - x[i - w, ch]
                    if r < h - 1:
                        acc += x[i, ch] - x[i + w, ch]
                    out[i, ch] = acc


@nb.njit(cache=True, parallel=True)
def _dot(a, b):
    """Per channel ``sum(a * b)`` of two ``(n, 3)`` arrays."""
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    for i in nb.prange(a.shape[0]):
        s0 += a[i, 0] * b[i, 0]
        s1 += a[i, 1] * b[i, 1]
        s2 += a[i, 2] * b[i, 2]
    return np.array([s0, s1, s2])


@nb.njit(cache=True, parallel=True)
def _step(x, r, p, ap, alpha):
    """One conjugate-gradient update in place, ``x += alpha p``, ``r -= alpha ap``;
    returns the new ``sum(r * r)`` per channel."""
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    for i in nb.prange(x.shape[0]):
        for c in range(3):
            x[i, c] += alpha[c] * p[i, c]
            r[i, c] -= alpha[c] * ap[i, c]
        s0 += r[i, 0] * r[i, 0]
        s1 += r[i, 1] * r[i, 1]
        s2 += r[i, 2] * r[i, 2]
    return np.array([s0, s1, s2])


@nb.njit(cache=True, parallel=True)
def _direction(p, r, beta):
    """``p = r + beta p`` in place."""
    for i in nb.prange(p.shape[0]):
        for c in range(3):
            p[i, c] = r[i, c] + beta[c] * p[i, c]


@nb.njit(cache=True)
def _nearest_range(plane, centre, y, starts, widths, heights, lo, hi):
    """Per texel, the least and greatest sample (per channel) whose centre is nearest it."""
    for s in range(plane.shape[0]):
        p = plane[s]
        w = widths[p]
        h = heights[p]
        c = min(max(int(centre[s, 0] + 0.5), 0), w - 1)
        r = min(max(int(centre[s, 1] + 0.5), 0), h - 1)
        i = starts[p] + r * w + c
        for ch in range(3):
            v = y[s, ch]
            if v < lo[i, ch]:
                lo[i, ch] = v
            if v > hi[i, ch]:
                hi[i, ch] = v


def _grid(
    samples: FootprintSamples, shapes: list[tuple[int, int]]
) -> tuple[tuple[np.ndarray, ...], int]:
    """The operators' geometry arguments ``(plane, centre, jacobian, starts, widths,
    heights)`` as contiguous arrays (``starts``: each plane's first flat texel, plane
    after plane, and the total at the end), and the number of texels."""
    starts = np.concatenate([[0], np.cumsum([h * w for h, w in shapes])]).astype(np.int64)
    geo = (
        np.ascontiguousarray(samples.plane, np.int64),
        np.ascontiguousarray(samples.centre, np.float64),
        np.ascontiguousarray(samples.jacobian, np.float64),
        starts,
        np.array([w for _, w in shapes], np.int64),
        np.array([h for h, _ in shapes], np.int64),
    )
    return geo, int(starts[-1])


def sample_range(
    samples: FootprintSamples, shapes: list[tuple[int, int]], radius: int
) -> tuple[np.ndarray, np.ndarray]:
    """``(lo, hi)``, each ``(n_texels, 3)``: the least and greatest sample whose centre
    lies within ``radius`` texels (a square) of each texel; ``inf`` / ``-inf`` where
    none does."""
    from scipy import ndimage

    (plane, centre, _, starts, widths, heights), n_tex = _grid(samples, shapes)
    lo = np.full((n_tex, 3), np.inf)
    hi = np.full((n_tex, 3), -np.inf)
    y = np.ascontiguousarray(samples.value, np.float64)
    _nearest_range(plane, centre, y, starts, widths, heights, lo, hi)
    size = (2 * int(radius) + 1, 2 * int(radius) + 1, 1)
    for p, (h, w) in enumerate(shapes):
        sl = slice(starts[p], starts[p + 1])
        lo[sl] = ndimage.minimum_filter(lo[sl].reshape(h, w, 3), size, mode="nearest").reshape(
            -1, 3
        )
        hi[sl] = ndimage.maximum_filter(hi[sl].reshape(h, w, 3), size, mode="nearest").reshape(
            -1, 3
        )
    return lo, hi


def back_projection(samples: FootprintSamples, shapes: list[tuple[int, int]]) -> np.ndarray:
    """``(n_texels, 3)``: each texel's mean of the samples whose footprints reach it,
    weighted by their footprint weight on it; a texel none reaches takes the value of
    the nearest that one does on its plane (0 on a plane none reaches)."""
    geo, n_tex = _grid(samples, shapes)
    y = np.ascontiguousarray(samples.value, np.float64)
    chunks = max(1, nb.get_num_threads())
    num = _adjoint(y, *geo, n_tex, chunks, 0)
    weight = _adjoint(y, *geo, n_tex, chunks, 1)[:, 0]
    return _weighted_mean(num, weight, geo[3], shapes)


def _weighted_mean(
    num: np.ndarray, weight: np.ndarray, starts: np.ndarray, shapes: list[tuple[int, int]]
) -> np.ndarray:
    """:func:`back_projection` from the adjoint of the samples (``num``) and the
    texels' coverage (``weight``)."""
    from scipy import ndimage

    out = np.zeros((len(weight), 3))
    for p, (h, w) in enumerate(shapes):
        sl = slice(starts[p], starts[p + 1])
        wt = weight[sl].reshape(h, w)
        seen = wt > 1e-9
        if not seen.any():
            continue
        mean = np.where(
            seen[..., None], num[sl].reshape(h, w, 3) / np.maximum(wt, 1e-9)[..., None], 0
        )
        _, (ri, ci) = ndimage.distance_transform_edt(~seen, return_indices=True)
        out[sl] = mean[ri, ci].reshape(-1, 3)
    return out


def median_footprint(jacobian: np.ndarray) -> float:
    """The samples' median footprint in texels: the square root of the median area of
    the parallelograms ``jacobian`` (``(N, 2, 2)``, texels per pixel) spans; 0 for none."""
    jac = np.asarray(jacobian, np.float64)
    if len(jac) == 0:
        return 0.0
    area = np.abs(jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0])
    return float(np.sqrt(np.median(area)))


def _neighbour_count(shapes: list[tuple[int, int]]) -> np.ndarray:
    """``(n_texels,)`` each texel's number of 4-neighbours on its plane (the diagonal of
    :func:`_laplacian`)."""
    out = [np.zeros(0)]
    for h, w in shapes:
        c, r = np.arange(w), np.arange(h)
        cols = (c > 0).astype(float) + (c < w - 1)
        rows = (r > 0).astype(float) + (r < h - 1)
        out.append((rows[:, None] + cols[None, :]).reshape(-1))
    return np.concatenate(out)


def solve_texels(
    samples: FootprintSamples,
    shapes: list[tuple[int, int]],
    initial: np.ndarray | None = None,
    *,
    smooth: float | np.ndarray = 1.0,
    iterations: int = 15,
    tol: float = 1e-4,
    precondition: bool = True,
) -> tuple[np.ndarray, np.ndarray, dict[str, float]]:
    """The texels that best explain the samples (least squares, conjugate gradients).

    Minimises ``sum_s |F_s t - y_s|^2 + lam sum |t_i - t_j|^2`` over the texels ``t``
    of all planes (flat, plane after plane, each ``h x w`` row-major), where ``F_s t``
    is sample ``s``'s footprint mean of the bilinear texture and the second sum runs
    over neighbouring texels of a plane. The penalty spreads a texel's value over
    about ``sqrt(lam / d)`` texels, ``d`` a texel's data weight (the median of the
    normal matrix's diagonal over the texels the samples reach); ``lam = (smooth
    f)^2 d``, ``f`` the samples' median footprint in texels (the square root of the
    footprint's area), so ``smooth`` is that spread in footprints, whatever the texel
    size or the number of photos.

    Parameters
    ----------
    samples:
        The photo samples with their footprints.
    shapes:
        ``(h, w)`` of each plane's texel grid.
    initial:
        ``(n_texels, 3)`` the start, the answer being the least-squares correction of
        it; None: each texel's footprint-weighted mean of the samples that reach it
        (:func:`back_projection`), a blurred estimate whose weakly determined parts,
        those the steps correct last, are smooth rather than noisy.
    smooth:
        The neighbour penalty: how far it spreads a texel's value, in the photos'
        median footprints; one number for every plane or one per plane (``lam`` then
        differs by plane, each plane's penalty its own).
    iterations, tol:
        At most this many conjugate-gradient steps; stop when every channel's normal-equation
        residual fell below ``tol`` of its start.
    precondition:
        Scale the steps by the normal matrix's diagonal (Jacobi); False: plain
        conjugate gradients.

    Returns
    -------
    texels, coverage, stats
        ``(n_texels, 3)`` the solved texels; ``(n_texels,)`` each texel's share of the
        samples' footprints (in samples: a sample's weights sum to 1; 0 where none
        reaches); ``iterations`` run, ``lam`` (the planes' median), ``footprint``
        (the median, texels), the relative residual.
    """
    geo, n_tex = _grid(samples, shapes)
    plane, _, _, starts, widths, heights = geo
    if initial is not None:
        initial = np.asarray(initial, np.float64)
        if initial.shape != (n_tex, 3):
            raise ValueError(f"initial has shape {initial.shape}, expected ({n_tex}, 3)")
    y = np.ascontiguousarray(samples.value, np.float64)
    chunks = max(1, nb.get_num_threads())

    def fwd(x: np.ndarray) -> np.ndarray:
        out = np.empty((len(plane), 3))
        _forward(x, *geo, out)
        return out

    def adj(r: np.ndarray) -> np.ndarray:
        return _adjoint(r, *geo, n_tex, chunks, 0)

    weights = _adjoint(y, *geo, n_tex, chunks, 1)
    coverage, diag = weights[:, 0], weights[:, 1]
    reached = diag > 0
    if initial is None:
        initial = _weighted_mean(adj(y), coverage, starts, shapes)
    stats: dict[str, float] = {
        "iterations": 0,
        "lam": 0.0,
        "footprint": 0.0,
        "relative_residual": 0.0,
    }
    if len(plane) == 0 or not reached.any():
        return initial.copy(), coverage, stats
    footprint = median_footprint(samples.jacobian)
    per_plane = np.asarray(smooth, np.float64)
    if per_plane.ndim > 1 or per_plane.size not in (1, len(shapes)):
        raise ValueError(f"smooth must be one number or one per plane ({len(shapes)})")
    per_plane = np.broadcast_to(per_plane.reshape(-1), (len(shapes),))
    lam_plane = (per_plane * footprint) ** 2 * float(np.median(diag[reached]))
    lam = np.repeat(lam_plane, np.diff(starts))[:, None]  # (n_tex, 1)
    stats["footprint"] = footprint
    stats["lam"] = float(np.median(lam_plane))

    # Conjugate gradients on the normal equations (F^T F + lam L) x = F^T y, L = D^T D
    # the planes' 4-neighbour Laplacian; the three channels share the matrix.
    lap_out = np.empty((n_tex, 3))

    def normal(v: np.ndarray) -> np.ndarray:
        _laplacian(v, starts, widths, heights, lap_out)
        out = adj(fwd(v))
        out += lam * lap_out
        return out

    x = initial.copy()
    _laplacian(x, starts, widths, heights, lap_out)
    r = adj(y - fwd(x)) - lam * lap_out
    # Jacobi preconditioner: the normal matrix's diagonal. A texel's data weight varies
    # by orders of magnitude (one grazing frame against forty head-on ones), which
    # plain conjugate gradients pay for in steps.
    inv_m = 1.0 / np.maximum(diag + lam[:, 0] * _neighbour_count(shapes), 1e-12)
    if not precondition:
        inv_m[:] = 1.0
    inv_m = inv_m[:, None]
    z = r * inv_m
    p = z.copy()
    rz = _dot(r, z)
    rs0 = _dot(r, r)
    for it in range(int(iterations)):
        ap = normal(p)
        pap = _dot(p, ap)
        alpha = np.where(pap > 0, rz / np.maximum(pap, 1e-300), 0.0)
        rs_new = _step(x, r, p, ap, alpha)
        stats["iterations"] = it + 1
        rel = np.sqrt(rs_new / np.maximum(rs0, 1e-300))
        stats["relative_residual"] = float(rel.max())
        if np.all(rel < tol):
            break
        np.multiply(r, inv_m, out=z)
        rz_new = _dot(r, z)
        beta = np.where(rz > 0, rz_new / np.maximum(rz, 1e-300), 0.0)
        _direction(p, z, beta)
        rz = rz_new
    # A least-squares fit of a step rings beside it (a bilinear texture cannot put an
    # edge between texel centres): no texel leaves the range of the samples within a
    # footprint of it, the anti-ringing clamp of image resamplers.
    # (A texel with no sample centre that near, reached only by a wide footprint's
    # edge, is left as solved.)
    lo, hi = sample_range(samples, shapes, int(np.ceil(footprint)))
    np.clip(x, np.where(np.isfinite(lo), lo, -np.inf), np.where(np.isfinite(hi), hi, np.inf), out=x)
    return x, coverage, stats
