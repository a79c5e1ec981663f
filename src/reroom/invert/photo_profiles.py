"""A point light's fine profile fitted to the photos' pixels, not to the mesh's vertices.

After the solve, :mod:`reroom.invert.fine_profiles` splits each point light's 32 bins
to 128 (1.4 degrees) against the receivers, the scan mesh's vertices. Those lie 3-8 cm
apart, while a downlight's beam edge sweeps a wall 20 cm away by 2 cm per 1.4-degree
bin: several bins fall between two vertices, and the fitted profile misses the beam's
structure by 10-20 % per bin (`furnished`'s downlight, 13.8 % relative L2 at 128 bins).
The photo textures then hold the difference as arcs of wrong albedo (the scallops of the
model's beam against the true one), which stay on the wall when the light is moved or
switched off.

The photos resolve the beam: a 160x120 frame sees a wall 2 m away at under 2 cm per
pixel. :func:`photo_samples` turns every pixel on a clustered surface (wall, floor,
ceiling) into a sample of the radiance there (linearised with the HDR stage's response
and divided by the frame's exposure scale, the HDR mesh's units), away from
silhouettes and saturated pixels. :func:`refit_point_profile` then fits the light's
profile to the samples its light reaches, with everything else held, eq. 5.6 per pixel::

    pi L_s / rho_s - E_rest,s = col_c V_s cos_s / d_s^2 J(theta_s)

with ``rho`` the sample's cluster albedo (the solve's: a wall's paint is one colour),
``E_rest`` the solved model's irradiance without this light interpolated over the hit
triangle, and ``J`` read between bin centres as the renderer reads it (linear
interpolation, :func:`reroom.render.line_emitter.line_profile_value`), so the fitted
values are what the render shows. A weak pull toward the receivers' profile holds the
bins no sample sees, a weak smoothness the neighbouring ones, and Huber reweighting
leaves out the pixels the model cannot explain (a picture on the wall, a plank's
joint). By default every 32-bin group keeps the flux the solve gave it, so the light's
power and its 32-bin distribution stay the solve's: the photos only say where inside each
group the light goes.

Written by hand: no library fits a tabulated goniometric profile to image samples.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

from reroom.errors import ReroomError
from reroom.invert.solve import bounded_quadratic

__all__ = ["PhotoSamples", "ProfileRefit", "even_subset", "photo_samples", "refit_point_profile"]


@dataclass
class PhotoSamples:
    """Pixels of the photos on the clustered surfaces, in the HDR mesh's radiance units.

    Attributes
    ----------
    points : ndarray, shape (N, 3)
        Where each pixel's ray hits the scan mesh.
    normals : ndarray, shape (N, 3)
        The hit face's unit normal, turned toward the camera.
    face : ndarray of int, shape (N,)
        The hit face.
    barycentric : ndarray, shape (N, 3)
        The hit's barycentric coordinates in its face.
    radiance : ndarray, shape (N, 3)
        The pixel's radiance (``linear / scale``).
    """

    points: np.ndarray
    normals: np.ndarray
    face: np.ndarray
    barycentric: np.ndarray
    radiance: np.ndarray

    def __len__(self) -> int:
        return len(self.face)

    def interpolate(
        self, faces: np.ndarray, values: np.ndarray, rows: np.ndarray | None = None
    ) -> np.ndarray:
        """``values`` ``(V, ...)`` per mesh vertex read at each sample, or at the samples
        ``rows`` only (barycentric; NaN where a corner's value is NaN)."""
        face = self.face if rows is None else self.face[rows]
        bary = self.barycentric if rows is None else self.barycentric[rows]
        corners = np.asarray(faces, np.int64)[face]
        v = np.asarray(values, np.float64)[corners]
        w = bary.reshape(len(face), 3, *([1] * (v.ndim - 2)))
        return (v * w).sum(axis=1)


def _barycentric(tri: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Barycentric coordinates of points ``(N, 3)`` in triangles ``(N, 3, 3)``."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    v0, v1, v2 = b - a, c - a, p - a
    d00 = np.einsum("ij,ij->i", v0, v0)
    d01 = np.einsum("ij,ij->i", v0, v1)
    d11 = np.einsum("ij,ij->i", v1, v1)
    d20 = np.einsum("ij,ij->i", v2, v0)
    d21 = np.einsum("ij,ij->i", v2, v1)
    den = np.where(np.abs(d00 * d11 - d01**2) > 0, d00 * d11 - d01**2, 1.0)
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    return np.clip(np.stack([1.0 - v - w, v, w], axis=1), 0.0, 1.0)


def photo_samples(
    scan_dir: str | Path,
    mesh,
    face_ok: np.ndarray,
    *,
    caster=None,
    max_rays_per_frame: int = 30_000,
    min_cos: float = 0.2,
    saturation_level: int = 255,
) -> tuple[PhotoSamples, dict[str, Any]]:
    """The photos' pixels on the faces ``face_ok`` marks, as radiance samples.

    A pixel is kept when its ray hits a face in ``face_ok``, its four grid neighbours
    hit faces in ``face_ok`` whose normals agree with its own to within 18 degrees (a
    pixel across a silhouette or a crease mixes two surfaces), it sees its surface at a
    cosine of at least ``min_cos``, and no channel reaches ``saturation_level``.
    Frames without an exposure are skipped (counted); a frame whose image cannot be
    read is skipped with a note naming the file.
    """
    from reroom.hdr.linearize import linearize
    from reroom.invert.photos import frame_scale, open_photos, pixel_grid
    from reroom.rays import RayCaster

    notes: list[str] = []
    scan, scales, lut = open_photos(scan_dir, notes.append)
    caster = caster if caster is not None else RayCaster(mesh)
    vertices = np.asarray(mesh.vertices, np.float64)
    faces = np.asarray(mesh.faces, np.int64)
    face_ok = np.asarray(face_ok, bool)
    normals_f = np.asarray(mesh.face_normals, np.float64)
    parts: list[tuple[np.ndarray, ...]] = []
    stats: dict[str, Any] = {"frames_used": 0, "frames_no_exposure": 0, "notes": notes}
    for j, frame in enumerate(scan.frames):
        scale = frame_scale(scales, j)
        if scale is None:
            stats["frames_no_exposure"] += 1
            continue
        k = frame.intrinsics
        rows, cols = pixel_grid(k.width, k.height, max_rays_per_frame)
        jj, ii = np.meshgrid(cols, rows)
        o, d = frame.pixel_rays(np.stack([jj.ravel() + 0.5, ii.ravel() + 0.5], axis=1))
        hits = caster.intersect(o, d, tmin=caster.eps)
        face = np.where(hits.hit, hits.face, -1)
        ok = face >= 0
        ok[ok] = face_ok[face[ok]]
        if not ok.any():
            continue
        # Neighbours on the grid: same kind of surface, same orientation.
        grid_ok = ok.reshape(len(rows), len(cols))
        nrm = np.zeros((len(face), 3))
        nrm[ok] = normals_f[face[ok]]
        grid_n = nrm.reshape(len(rows), len(cols), 3)
        inner = np.zeros_like(grid_ok)
        core = grid_ok[1:-1, 1:-1].copy()
        for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1)):
            nb_ok = grid_ok[1 + dy : len(rows) - 1 + dy, 1 + dx : len(cols) - 1 + dx]
            nb_n = grid_n[1 + dy : len(rows) - 1 + dy, 1 + dx : len(cols) - 1 + dx]
            core &= nb_ok & (np.einsum("ijk,ijk->ij", nb_n, grid_n[1:-1, 1:-1]) > 0.95)
        inner[1:-1, 1:-1] = core
        keep = inner.ravel()
        n = nrm[keep]
        cos = -np.einsum("ij,ij->i", n, d[keep])
        n = np.where(cos[:, None] < 0, -n, n)
        keep_idx = np.flatnonzero(keep)[np.abs(cos) >= min_cos]
        if not len(keep_idx):
            continue
        try:
            img = frame.load_image()
        except (ReroomError, OSError, ValueError) as exc:
            notes.append(f"photo profiles: skipped frame {frame.image_path} ({exc})")
            continue
        codes = img[ii.ravel()[keep_idx], jj.ravel()[keep_idx]]
        unsat = ~(codes >= saturation_level).any(axis=1)
        keep_idx, codes = keep_idx[unsat], codes[unsat]
        radiance = linearize(codes, lut).astype(np.float64) / scale
        f = face[keep_idx]
        p = hits.points[keep_idx]
        nn = normals_f[f]
        nn = np.where((np.einsum("ij,ij->i", nn, d[keep_idx]) > 0)[:, None], -nn, nn)
        parts.append((p, nn, f, _barycentric(vertices[faces[f]], p), radiance))
        stats["frames_used"] += 1
    if parts:
        cat = [np.concatenate([x[i] for x in parts]) for i in range(5)]
    else:
        cat = [np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros((0, 3)),
               np.zeros((0, 3))]  # fmt: skip
    samples = PhotoSamples(*cat)
    stats["samples"] = len(samples)
    return samples, stats


@dataclass
class ProfileRefit:
    """Result of :func:`refit_point_profile`.

    Attributes
    ----------
    profile : ndarray, shape (bins,)
        The refitted scalar profile (the light's intensities are ``profile x colour``).
    samples : int
        Photo samples the light reaches that the fit used.
    supported_bins : int
        Bins whose interpolation weight over the samples is at least ``min_support``.
    residual_before, residual_after : float
        Relative RMS residual of the used samples (weighted, final Huber weights) with
        the starting profile and with the refitted one.
    groups : ndarray of bool, shape (bins // group,)
        The groups the photos reshaped (the others kept the starting values).
    """

    profile: np.ndarray
    samples: int
    supported_bins: int
    residual_before: float
    residual_after: float
    groups: np.ndarray


def even_subset(bins: np.ndarray, limit: int, seed: int = 0) -> np.ndarray:
    """Indices of at most about ``limit`` samples, spread evenly over their ``bins``.

    Every bin keeps up to the same number of its samples (a seeded random choice), the
    largest number that keeps the total within ``limit``: a bin few pixels see keeps
    all of them, the floor right under a downlight, seen by hundreds of thousands of a
    300-frame scan's pixels, keeps its share. Sorted indices; all of them when there
    are no more than ``limit``.
    """
    bins = np.asarray(bins, np.int64)
    n = len(bins)
    if n <= limit:
        return np.arange(n)
    rng = np.random.default_rng(seed)
    order = rng.permutation(n)
    b = bins[order]
    sort = np.argsort(b, kind="stable")
    counts = np.bincount(b)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    rank = np.empty(n, np.int64)
    rank[sort] = np.arange(n) - np.repeat(starts, counts)
    lo, hi = 1, int(counts.max())
    while lo < hi:  # the largest quota whose kept total is within the limit
        mid = (lo + hi + 1) // 2
        if np.minimum(counts, mid).sum() <= limit:
            lo = mid
        else:
            hi = mid - 1
    return np.sort(order[rank < lo])


def _hat_matrix(theta: np.ndarray, value: np.ndarray, bins: int) -> sp.csr_matrix:
    """``(N, bins)``: ``value`` times the linear-interpolation weights of ``theta``
    between bin centres, as :func:`reroom.render.line_emitter.line_profile_value`."""
    f = np.clip(theta, 0.0, np.pi) * (bins / np.pi)
    x = np.clip(f - 0.5, 0.0, bins - 1.0)
    i = np.minimum(x.astype(np.int64), bins - 2)
    w = x - i
    n = len(theta)
    r = np.repeat(np.arange(n), 2)
    c = np.stack([i, i + 1], axis=1).ravel()
    v = np.stack([(1.0 - w) * value, w * value], axis=1).ravel()
    return sp.csr_matrix((v, (r, c)), shape=(n, bins))


def refit_point_profile(
    profile: np.ndarray,
    color: np.ndarray,
    value: np.ndarray,
    theta: np.ndarray,
    target: np.ndarray,
    *,
    group: int = 4,
    keep_group_flux: bool = True,
    prior: float = 1e-3,
    smooth: float = 5e-4,
    min_support: float = 0.05,
    huber: float = 2.0,
    iterations: int = 3,
) -> ProfileRefit:
    """Fit a point light's profile to photo samples, everything else held.

    Parameters
    ----------
    profile : ndarray, shape (bins,)
        The starting profile (the receivers' fit); also the prior for unseen bins.
    color : ndarray, shape (3,)
        The light's colour (intensity per channel = ``profile x color``).
    value : ndarray, shape (N,)
        Each sample's ``V cos / d^2`` toward the light (0 in its shadow).
    theta : ndarray, shape (N,)
        Each sample's emission angle from the light's axis (radians).
    target : ndarray, shape (N, 3)
        What the light must explain there: ``pi L / rho - E_rest`` (irradiance).
    group : int
        Bins per group of the solve's resolution (4 for 128 bins split from 32).
    keep_group_flux : bool
        Rescale each group so that its flux is the starting profile's (the solve's
        power and coarse distribution kept); groups without supported bins keep the
        starting values.
    prior, smooth : float
        Weights (relative to the mean diagonal of the data's normal matrix per bin) of
        the pull toward ``profile`` and of the smoothness between neighbouring bins.
    min_support : float
        A bin is supported when its summed interpolation weight over the samples is at
        least this fraction of the mean over bins with any weight.
    huber : float
        Huber threshold, in robust standard deviations (MAD) of the relative residuals.
    iterations : int
        Reweighting rounds.
    """
    p0 = np.asarray(profile, np.float64).ravel()
    bins = len(p0)
    col = np.asarray(color, np.float64).ravel()
    t = np.asarray(target, np.float64)
    lit = np.asarray(value, np.float64) > 0
    hat = _hat_matrix(np.asarray(theta, np.float64)[lit], np.asarray(value)[lit], bins)
    t = t[lit]
    n = hat.shape[0]
    if n == 0:
        return ProfileRefit(
            p0.copy(), 0, 0, float("nan"), float("nan"), np.zeros(bins // group, bool)
        )
    model0 = hat @ p0
    # Relative residuals: each sample's error over what the light gives it there (floored
    # at a tenth of the median so that the beam's dark margin does not dominate).
    scale = np.maximum(model0 * col.mean(), 0.1 * np.median(model0 * col.mean()) + 1e-300)
    base_w = 1.0 / scale
    a_rows = sp.vstack([hat * c for c in col]).tocsr()
    b = np.concatenate([t[:, c] for c in range(3)])
    wrow = np.tile(base_w, 3)
    support = np.asarray(abs(hat).sum(axis=0)).ravel()
    seen = support > 0
    supported = seen & (support >= min_support * support[seen].mean()) if seen.any() else seen
    d = sp.diags([-np.ones(bins - 1), np.ones(bins - 1)], [0, 1], shape=(bins - 1, bins))
    huber_w = np.ones(3 * n)

    def solve(weights: np.ndarray) -> np.ndarray:
        aw = sp.diags(weights) @ a_rows
        diag = np.asarray(aw.multiply(aw).sum(axis=0)).ravel()
        level = float(diag[supported].mean()) if supported.any() else 1.0
        reg_p = np.sqrt(prior * level) * sp.identity(bins)
        reg_s = np.sqrt(smooth * level) * d
        big = sp.vstack([aw, reg_p, reg_s]).tocsr()
        rhs = np.concatenate([weights * b, np.sqrt(prior * level) * p0, np.zeros(bins - 1)])
        # A few hundred unknowns against up to 180k rows: solved on the normal equations
        # (the prior makes them positive definite) by the solve's block principal
        # pivoting, exactly, where lsq_linear's iterative LSMR took 4 s a round on the
        # 300-frame scan's 60k pixels.
        gram = (big.T @ big).toarray()
        grad = -np.asarray(big.T @ rhs).ravel()
        x = bounded_quadratic(gram, grad, np.zeros(bins), np.full(bins, np.inf))
        if x is None:  # pragma: no cover - the prior keeps the matrix positive definite
            raise ReroomError("photo profile fit: its normal matrix is not positive definite")
        return x

    def residual(p: np.ndarray, weights: np.ndarray) -> np.ndarray:
        return weights * (a_rows @ p - b)

    before = residual(p0, wrow)
    p = p0.copy()
    for _ in range(max(1, iterations)):
        p = solve(wrow * huber_w)
        r = residual(p, wrow)
        mad = 1.4826 * float(np.median(np.abs(r - np.median(r)))) + 1e-300
        a = np.abs(r) / (huber * mad)
        huber_w = np.where(a <= 1.0, 1.0, 1.0 / np.sqrt(np.maximum(a, 1e-300)))
    after = residual(p, wrow)
    groups = supported[: bins - bins % group].reshape(-1, group).any(axis=1)
    if keep_group_flux and bins % group == 0:
        from reroom.invert.basis import InclinationBasis
        from reroom.invert.fine_profiles import bin_solid_angles

        omega = bin_solid_angles(InclinationBasis(bins))
        for g in range(bins // group):
            s = slice(g * group, (g + 1) * group)
            if not groups[g]:
                p[s] = p0[s]
                continue
            want, got = float(omega[s] @ p0[s]), float(omega[s] @ p[s])
            p[s] = p[s] * (want / got) if got > 0 else p0[s]
    hw = huber_w

    def rms(r: np.ndarray) -> float:
        return float(np.sqrt(np.sum(hw * r**2) / max(float(np.sum(hw)), 1e-300)))

    return ProfileRefit(p, int(n), int(supported.sum()), rms(before), rms(after), groups)
