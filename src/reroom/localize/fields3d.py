"""The scene transforms of thesis §6.3-6.4 in 3D: ``D``, ``L`` and ``V`` on a voxel grid.

* ``D(p) = min_q I(q, p)`` and ``L(p) = argmin_q I(q, p)`` with ``I(q, p) = B(q) / S(q, p)``
  (eqs. 6.3, 6.6, 6.7), exactly as in 2D, by branch and bound over ``8 x 8 x 8`` voxel
  blocks (:func:`intensity_distance_field_3d`): a lower bound of ``I(q, .)`` on a block
  rules out the sites that cannot be the limiter of any voxel in it; the survivors are
  evaluated exactly in index order, so the result equals the brute force's. Occlusion is
  not tested in the fields (the thesis ignores it for its real scenes too, §6.3.6); the
  refinement's solves use ray-cast visibility.
* ``V(p)``: the number of distinct limiters in the ball of radius ``r`` voxels around
  ``p`` (eq. 6.8, our noisy-2D choice; :func:`limiter_count_3d`). Around a light ``L``
  turns fast and every voxel has its own limiter; elsewhere neighbours share limiters,
  and a jump of ``L`` (the medial axis) only adds two small counts. We tried the
  thesis's 3D vote first, the areas of the limiter triangles of a sphere around ``p``
  (§6.4.4): its maxima lie on the medial axis between lights, because the long thin
  triangles straddling a jump of ``L`` have large areas; with signed solid angles (a
  winding number) those cancel, but so does the light's own sweep once other lights
  dim part of it (docs/localize.md).
* Candidates (GETLIGHTCANDIDATES): voxels that no voxel within the peak radius beats,
  at or above the peak level ``H`` (``|Q| / 10``, lowered by ``decay`` until one
  passes), merged within 10% of the scene radius, and only where ``valid`` (free space
  away from surfaces: the false-peak filter of §6.3.6) (:func:`find_peaks_3d`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from numba import prange
from numpy.typing import ArrayLike

from reroom.localize.measurements import LocalizeError, Measurements

__all__ = [
    "VoxelGrid",
    "find_peaks_3d",
    "intensity_distance_field_3d",
    "limiter_count_3d",
]

_TILE = 8
_N_UPPER = 16


@dataclass(frozen=True)
class VoxelGrid:
    """A regular grid of voxel centres ``origin + voxel * (i, j, k)``.

    Attributes
    ----------
    origin:
        ``(3,)`` centre of voxel ``(0, 0, 0)``.
    voxel:
        Edge length of a voxel.
    shape:
        ``(nx, ny, nz)``; arrays on the grid are indexed ``[i, j, k]`` along x, y, z.
    """

    origin: np.ndarray
    voxel: float
    shape: tuple[int, int, int]

    @staticmethod
    def for_box(lo: ArrayLike, hi: ArrayLike, voxel: float) -> VoxelGrid:
        """Voxels of edge ``voxel`` covering the box ``[lo, hi]`` (centres inside it)."""
        lo = np.asarray(lo, dtype=np.float64).reshape(3)
        hi = np.asarray(hi, dtype=np.float64).reshape(3)
        if voxel <= 0 or np.any(hi <= lo):
            raise LocalizeError(f"voxel grid: need voxel > 0 and lo < hi, got {voxel}, {lo}, {hi}")
        n = np.maximum(1, np.floor((hi - lo) / voxel).astype(int))
        # Centre the grid in the box.
        origin = lo + 0.5 * ((hi - lo) - (n - 1) * voxel)
        return VoxelGrid(origin, float(voxel), (int(n[0]), int(n[1]), int(n[2])))

    def axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Voxel-centre coordinates along x, y and z."""
        return tuple(self.origin[c] + self.voxel * np.arange(self.shape[c]) for c in range(3))

    def centres(self, window: tuple[slice, slice, slice] | None = None) -> np.ndarray:
        """``(nx, ny, nz, 3)`` voxel centres (of ``window`` when given)."""
        ax = self.axes()
        if window is not None:
            ax = tuple(a[w] for a, w in zip(ax, window, strict=True))
        return np.stack(np.meshgrid(*ax, indexing="ij"), axis=-1)

    def to_index(self, points: ArrayLike) -> np.ndarray:
        """Index of the voxel nearest each point, clipped to the grid."""
        p = np.asarray(points, dtype=np.float64)
        idx = np.rint((p - self.origin) / self.voxel).astype(np.int64)
        return np.clip(idx, 0, np.asarray(self.shape) - 1)

    def window(self, centre: ArrayLike, radius: float) -> tuple[slice, slice, slice]:
        """Index slices of the voxels within ``radius`` of ``centre`` along each axis."""
        c = self.to_index(centre)
        h = int(math.ceil(radius / self.voxel))
        return tuple(
            slice(max(0, int(c[a]) - h), min(self.shape[a], int(c[a]) + h + 1)) for a in range(3)
        )


# --------------------------------------------------------------------------------------
# D(p) and L(p)


@numba.njit(cache=True, inline="always")
def _key3(x, y, z, q, n, bb):  # pragma: no cover
    """``I(q, p)^2 = B^2 r^6 / (n . l)^2``; inf behind the surface."""
    dx = x - q[0]
    dy = y - q[1]
    dz = z - q[2]
    dot = n[0] * dx + n[1] * dy + n[2] * dz
    if dot <= 0.0:
        return np.inf
    r2 = dx * dx + dy * dy + dz * dz
    return bb * r2 * r2 * r2 / (dot * dot)


@numba.njit(parallel=True, cache=True)
def _idf3d(xs, ys, zs, q, n, b2, tile, n_upper, best_key, best_idx):  # pragma: no cover
    """Exact ``min_q I(q, p)^2`` and its argmin by branch and bound over voxel blocks.

    For each block: a lower bound of ``I(q, .)^2`` (nearest distance from the site to
    the block, largest ``n . l`` on it) for every site; the exact values of the site with
    the lowest bound give an upper bound of ``D^2`` on the block; only sites whose lower
    bound is below it are evaluated exactly, in index order with strict comparisons,
    which breaks ties as the brute force does.
    """
    nx, ny, nz = xs.shape[0], ys.shape[0], zs.shape[0]
    tx = (nx + tile - 1) // tile
    ty = (ny + tile - 1) // tile
    tz = (nz + tile - 1) // tile
    nq = q.shape[0]
    for t in prange(tx * ty * tz):
        bi = t // (ty * tz)
        bj = (t // tz) % ty
        bk = t % tz
        i0, j0, k0 = bi * tile, bj * tile, bk * tile
        i1, j1, k1 = min(i0 + tile, nx), min(j0 + tile, ny), min(k0 + tile, nz)
        cx, cy, cz = (
            0.5 * (xs[i0] + xs[i1 - 1]),
            0.5 * (ys[j0] + ys[j1 - 1]),
            0.5 * (zs[k0] + zs[k1 - 1]),
        )
        hx, hy, hz = (
            0.5 * (xs[i1 - 1] - xs[i0]),
            0.5 * (ys[j1 - 1] - ys[j0]),
            0.5 * (zs[k1 - 1] - zs[k0]),
        )
        lb = np.empty(nq)
        qs = -1
        lbs = np.inf
        for s in range(nq):
            dx = cx - q[s, 0]
            dy = cy - q[s, 1]
            dz = cz - q[s, 2]
            dotmax = (
                n[s, 0] * dx + n[s, 1] * dy + n[s, 2] * dz
                + abs(n[s, 0]) * hx + abs(n[s, 1]) * hy + abs(n[s, 2]) * hz
            )  # fmt: skip
            if dotmax <= 0.0:
                lb[s] = np.inf
                continue
            ex = max(abs(dx) - hx, 0.0)
            ey = max(abs(dy) - hy, 0.0)
            ez = max(abs(dz) - hz, 0.0)
            r2 = ex * ex + ey * ey + ez * ez
            lb[s] = b2[s] * r2 * r2 * r2 / (dotmax * dotmax)
            if lb[s] < lbs:
                lbs = lb[s]
                qs = s
        for i in range(i0, i1):
            for j in range(j0, j1):
                for k in range(k0, k1):
                    best_key[i, j, k] = np.inf
                    best_idx[i, j, k] = -1
        if qs < 0:
            continue
        # Upper bound of D^2 on the block: the worst voxel of the best of the few sites
        # with the lowest bounds (one site alone is a loose bound in 3D, where the
        # limiters of a block's voxels spread over more of the surfaces).
        few = np.argsort(lb)[:n_upper]
        upper = 0.0
        for i in range(i0, i1):
            for j in range(j0, j1):
                for k in range(k0, k1):
                    m = np.inf
                    for s in few:
                        m = min(m, _key3(xs[i], ys[j], zs[k], q[s], n[s], b2[s]))
                    upper = max(upper, m)
        # Relative slack: the bound and the exact value round differently.
        upper = upper * (1.0 + 1e-9)
        for s in range(nq):
            if lb[s] > upper:
                continue
            ax, ay, az = q[s, 0], q[s, 1], q[s, 2]
            nx_, ny_, nz_ = n[s, 0], n[s, 1], n[s, 2]
            bb = b2[s]
            for i in range(i0, i1):
                dx = xs[i] - ax
                for j in range(j0, j1):
                    dy = ys[j] - ay
                    dxy = nx_ * dx + ny_ * dy
                    r2xy = dx * dx + dy * dy
                    for k in range(k0, k1):
                        dz = zs[k] - az
                        dot = dxy + nz_ * dz
                        r2 = r2xy + dz * dz
                        key = bb * r2 * r2 * r2 / (dot * dot)
                        key = key if dot > 0.0 else np.inf
                        better = key < best_key[i, j, k]
                        best_key[i, j, k] = key if better else best_key[i, j, k]
                        best_idx[i, j, k] = s if better else best_idx[i, j, k]


@numba.njit(parallel=True, cache=True)
def _idf3d_brute(xs, ys, zs, q, n, b2, best_key, best_idx):  # pragma: no cover
    for i in prange(xs.shape[0]):
        for j in range(ys.shape[0]):
            for k in range(zs.shape[0]):
                best = np.inf
                arg = -1
                for s in range(q.shape[0]):
                    key = _key3(xs[i], ys[j], zs[k], q[s], n[s], b2[s])
                    if key < best:
                        best = key
                        arg = s
                best_key[i, j, k] = best
                best_idx[i, j, k] = arg


def intensity_distance_field_3d(
    meas: Measurements,
    grid: VoxelGrid,
    window: tuple[slice, slice, slice] | None = None,
    method: str = "tiled",
) -> tuple[np.ndarray, np.ndarray]:
    """``D(p)`` and ``L(p)`` on the voxels of ``grid`` (or of ``window``), occlusion ignored.

    Parameters
    ----------
    meas:
        ``(N, 3)`` measurements; negative values are clamped to zero.
    grid:
        The voxel grid.
    window:
        Optional index slices of a sub-box of the grid.
    method:
        ``"tiled"`` (branch and bound, the default) or ``"brute"`` (every voxel against
        every measurement); both give the same fields.

    Returns
    -------
    d:
        ``(nx, ny, nz)`` float64 ``D(p)``; inf where no measurement faces ``p``.
    limiter:
        ``(nx, ny, nz)`` int32 index of ``L(p)`` into the measurements, -1 where none.
    """
    if meas.dim != 3:
        raise LocalizeError(f"3D fields need (N, 3) measurements, got dimension {meas.dim}")
    if method not in ("tiled", "brute"):
        raise LocalizeError(f"unknown field method {method!r}")
    xs, ys, zs = grid.axes()
    if window is not None:
        xs, ys, zs = xs[window[0]], ys[window[1]], zs[window[2]]
    shape = (xs.shape[0], ys.shape[0], zs.shape[0])
    key = np.empty(shape)
    idx = np.empty(shape, dtype=np.int32)
    if min(shape) == 0:
        return key, idx
    b = np.maximum(meas.values, 0.0)
    q = np.ascontiguousarray(meas.points)
    n = np.ascontiguousarray(meas.normals)
    if method == "tiled":
        _idf3d(xs, ys, zs, q, n, b * b, _TILE, _N_UPPER, key, idx)
    else:
        _idf3d_brute(xs, ys, zs, q, n, b * b, key, idx)
    return np.sqrt(key), idx


# --------------------------------------------------------------------------------------
# V(p) and candidates


def _ball(radius: int) -> np.ndarray:
    """Voxel offsets within ``radius + 1/2`` of the centre, the centre excluded."""
    r = int(radius)
    g = np.arange(-r, r + 1)
    off = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    keep = (off**2).sum(axis=1) <= (r + 0.5) ** 2
    return np.ascontiguousarray(off[keep & np.any(off != 0, axis=1)])


@numba.njit(parallel=True, cache=True)
def _count3(lim, ball, out):  # pragma: no cover
    nx, ny, nz = lim.shape
    for i in prange(nx):
        buf = np.empty(ball.shape[0] + 1, dtype=np.int32)
        for j in range(ny):
            for k in range(nz):
                m = 0
                if lim[i, j, k] >= 0:
                    buf[0] = lim[i, j, k]
                    m = 1
                for t in range(ball.shape[0]):
                    a, b, c = i + ball[t, 0], j + ball[t, 1], k + ball[t, 2]
                    if a >= 0 and b >= 0 and c >= 0 and a < nx and b < ny and c < nz:
                        v = lim[a, b, c]
                        if v >= 0:
                            buf[m] = v
                            m += 1
                if m == 0:
                    out[i, j, k] = 0.0
                    continue
                s = np.sort(buf[:m])
                cnt = 1
                for t in range(1, m):
                    if s[t] != s[t - 1]:
                        cnt += 1
                out[i, j, k] = cnt


def limiter_count_3d(limiter: np.ndarray, radius: int) -> np.ndarray:
    """``V(p)`` as eq. 6.8 defines it: distinct limiters in the ball of ``radius`` voxels.

    Around a light ``L`` turns fast (every voxel of the ball has its own limiter); away
    from lights neighbouring voxels share limiters; a jump of ``L`` (the medial axis)
    adds the two sides' counts, which stay small.
    """
    lim = np.ascontiguousarray(limiter, dtype=np.int32)
    out = np.empty(lim.shape)
    _count3(lim, _ball(max(1, int(radius))), out)
    return out


@numba.njit(parallel=True, cache=True)
def _local_max3(v, valid, ball, out):  # pragma: no cover
    nx, ny, nz = v.shape
    for i in prange(nx):
        for j in range(ny):
            for k in range(nz):
                val = v[i, j, k]
                if not valid[i, j, k] or val <= 0.0:
                    out[i, j, k] = False
                    continue
                ok = True
                for m in range(ball.shape[0]):
                    a, b, c = i + ball[m, 0], j + ball[m, 1], k + ball[m, 2]
                    if a >= 0 and b >= 0 and c >= 0 and a < nx and b < ny and c < nz:
                        if v[a, b, c] > val:
                            ok = False
                            break
                out[i, j, k] = ok


def find_peaks_3d(
    votes: np.ndarray,
    centres: np.ndarray,
    valid: np.ndarray,
    peak_radius: int,
    start_height: float,
    merge_distance: float,
    decay: float = 0.9,
) -> tuple[np.ndarray, np.ndarray]:
    """Candidate light positions: local maxima of ``V`` at or above the peak level (§6.4.3).

    A voxel is a local maximum when no voxel within ``peak_radius`` has more votes. The
    level ``H`` starts at ``start_height`` and is multiplied by ``decay`` until a maximum
    reaches it; the maxima at or above it are merged greedily (strongest first) within
    ``merge_distance``.

    Returns
    -------
    positions:
        ``(M, 3)`` candidates, strongest first.
    heights:
        ``(M,)`` their votes.
    """
    if not 0.0 < decay < 1.0:
        raise LocalizeError(f"peak threshold decay must lie in (0, 1), got {decay}")
    v = np.ascontiguousarray(votes, dtype=np.float64)
    ok = np.ascontiguousarray(valid, dtype=np.bool_)
    is_max = np.empty(v.shape, dtype=np.bool_)
    _local_max3(v, ok, _ball(max(1, int(peak_radius))), is_max)
    heights = v[is_max]
    if heights.size == 0:
        return np.zeros((0, 3)), np.zeros(0)
    top = float(heights.max())
    h = float(start_height)
    while h > top:
        h *= decay
    keep = heights >= h
    pos = centres[is_max][keep]
    heights = heights[keep]
    order = np.argsort(-heights, kind="stable")
    pos, heights = pos[order], heights[order]
    chosen: list[int] = []
    for m in range(pos.shape[0]):
        if all(np.linalg.norm(pos[m] - pos[c]) >= merge_distance for c in chosen):
            chosen.append(m)
    return pos[chosen], heights[chosen]
