"""The 2D scene transforms of thesis §6.3-6.4: the Intensity-Distance Field and its relatives.

For a candidate light position ``p`` and a measurement ``q`` at surface point ``x``,

    I(q, p) = B(q) / S(q, p) = B(q) |p - x|^3 / (n . (p - x))          (eq. 6.3)

is the intensity a single light at ``p`` would need to explain ``B(q)``; with several
lights it is an upper bound on the light at ``p`` (eq. 6.5). On a regular grid of ``p``:

* ``D(p) = min_q I(q, p)``: the Intensity-Distance Field (eq. 6.6), the brightest a
  light at ``p`` may be;
* ``L(p) = argmin_q I(q, p)``: the Limiter field (eq. 6.7), stored as a measurement index;
* the medial axis: pixels where ``L`` jumps by more than a threshold between neighbours
  on a small circle around them (§6.4.2);
* ``V(p)``: the voting function (§6.4.3), the mean surface distance between the limiters
  of consecutive pixels on a circle of radius ``r`` around ``p``, counting only the
  steps that are neither zero (inside a region with one limiter) nor discontinuities.

Where ``S(q, p) = 0`` (``p`` behind the surface, or hidden from it) the measurement puts
no bound on ``p``: ``I`` is infinite there. Negative values of ``B`` (the unexplained light
once hypothesised lights overshoot) are clamped to zero: "no light can be here".

Speed: the ``256 x 256 x 400`` brute force of §6.4.1 runs as a numba kernel, rows in
parallel, with the pixels of a row in the inner loop so that it vectorises, and compares
``I^2 = B^2 r^6 / (n.l)^2`` (no square root per pair). The default kernel gets the same
fields several times faster by branch and bound over pixel blocks (``_idf_tiled``).
"""

from __future__ import annotations

import contextlib
import functools
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numba
import numpy as np
from numba import prange
from numpy.typing import ArrayLike

from reroom.localize.measurements import LocalizeError
from reroom.localize.scene2d import Room2D, WallSamples, check_samples, segment_blocked

__all__ = [
    "FieldGrid",
    "FieldProposer2D",
    "VoteParams",
    "find_candidates",
    "intensity_distance_field",
    "limiter_count_field",
    "medial_axis",
    "ring_offsets",
    "voting_field",
]


@dataclass(frozen=True)
class FieldGrid:
    """A regular grid of candidate light positions: pixel ``(i, j)`` has its centre at
    ``origin + ((j + 0.5) h, (i + 0.5) h)`` (row ``i`` along y, column ``j`` along x)."""

    origin: tuple[float, float]
    pixel: float
    shape: tuple[int, int]

    @staticmethod
    def for_room(room: Room2D, resolution: int = 256) -> FieldGrid:
        """Square pixels covering the room's bounding box, ``resolution`` along its longer side."""
        if resolution < 4:
            raise LocalizeError(f"field resolution must be at least 4, got {resolution}")
        lo, hi = room.bounds
        size = hi - lo
        h = float(size.max()) / resolution
        shape = (max(1, math.ceil(size[1] / h - 1e-9)), max(1, math.ceil(size[0] / h - 1e-9)))
        return FieldGrid((float(lo[0]), float(lo[1])), h, shape)

    def centres(self) -> np.ndarray:
        """``(ny, nx, 2)`` pixel centres."""
        ny, nx = self.shape
        xs = self.origin[0] + (np.arange(nx) + 0.5) * self.pixel
        ys = self.origin[1] + (np.arange(ny) + 0.5) * self.pixel
        gx, gy = np.meshgrid(xs, ys)
        return np.stack([gx, gy], axis=-1)

    def to_pixel(self, points: ArrayLike) -> np.ndarray:
        """``(..., 2)`` integer ``(i, j)`` of the pixel containing each point (may be off-grid)."""
        p = np.asarray(points, dtype=np.float64)
        j = np.floor((p[..., 0] - self.origin[0]) / self.pixel).astype(np.int64)
        i = np.floor((p[..., 1] - self.origin[1]) / self.pixel).astype(np.int64)
        return np.stack([i, j], axis=-1)

    def extent(self) -> tuple[float, float, float, float]:
        """``(left, right, bottom, top)`` for ``matplotlib.imshow(origin="lower")``."""
        ny, nx = self.shape
        return (
            self.origin[0],
            self.origin[0] + nx * self.pixel,
            self.origin[1],
            self.origin[1] + ny * self.pixel,
        )


# Below this many inner-loop steps a kernel runs on the calling thread alone: waking the
# other threads costs more than it saves, and on a busy machine a parallel region can wait
# a whole scheduler quantum (~10 ms) for a descheduled worker.
_PARALLEL_WORK = 2_000_000


@contextlib.contextmanager
def _threads_for(work: int) -> Iterator[None]:
    if work >= _PARALLEL_WORK:
        yield
        return
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(before)


# --------------------------------------------------------------------------------------
# D(p) and L(p)

_TILE = 8


@numba.njit(parallel=True, fastmath=True, cache=True)
def _idf_free(xs, ys, qx, qy, qnx, qny, b2, best_key, best_idx):  # pragma: no cover
    nq = qx.shape[0]
    nx = xs.shape[0]
    for i in prange(ys.shape[0]):
        y = ys[i]
        key_row = best_key[i]
        idx_row = best_idx[i]
        for q in range(nq):
            ax, ay, nx_, ny_, bb = qx[q], qy[q], qnx[q], qny[q], b2[q]
            dy = y - ay
            dyn = ny_ * dy
            dy2 = dy * dy
            # Pixels of a row innermost, branch-free: LLVM turns this into AVX selects.
            for j in range(nx):
                dx = xs[j] - ax
                dot = nx_ * dx + dyn
                r2 = dx * dx + dy2
                key = bb * r2 * r2 * r2 / (dot * dot)  # I(q, p)^2
                key = key if dot > 0.0 else np.inf
                better = key < key_row[j]
                key_row[j] = key if better else key_row[j]
                idx_row[j] = q if better else idx_row[j]


@numba.njit(cache=True, inline="always")
def _key(x, y, ax, ay, nx_, ny_, bb):  # pragma: no cover
    """``I(q, p)^2`` for a site at ``(ax, ay)`` with normal ``(nx_, ny_)``; inf behind it."""
    dx = x - ax
    dy = y - ay
    dot = nx_ * dx + ny_ * dy
    if dot <= 0.0:
        return np.inf
    r2 = dx * dx + dy * dy
    return bb * r2 * r2 * r2 / (dot * dot)


@numba.njit(parallel=True, cache=True)
def _idf_tiled(xs, ys, qx, qy, qnx, qny, b2, tile, best_key, best_idx):  # pragma: no cover
    """Exact ``argmin_q I(q, p)`` by branch and bound over ``tile x tile`` pixel blocks.

    For a block, a lower bound of ``I(q, .)`` over the block (nearest distance from the
    site to the block, largest ``n . l`` on it) rules out every site whose bound exceeds
    an upper bound of ``D`` on the block (the worst pixel of the site with the lowest
    bound). Usually a few dozen of the 400 sites survive; the survivors are evaluated
    exactly, in index order with the same tie-breaking as the brute force, so the
    result is identical to it.
    """
    ny, nx = ys.shape[0], xs.shape[0]
    tny = (ny + tile - 1) // tile
    tnx = (nx + tile - 1) // tile
    nq = qx.shape[0]
    for t in prange(tny * tnx):
        ti = t // tnx
        tj = t - ti * tnx
        i0 = ti * tile
        i1 = min(i0 + tile, ny)
        j0 = tj * tile
        j1 = min(j0 + tile, nx)
        xlo, xhi, ylo, yhi = xs[j0], xs[j1 - 1], ys[i0], ys[i1 - 1]
        cx, cy = 0.5 * (xlo + xhi), 0.5 * (ylo + yhi)
        hx, hy = 0.5 * (xhi - xlo), 0.5 * (yhi - ylo)
        lb = np.empty(nq)
        qs = -1
        lbs = np.inf
        for q in range(nq):
            dx = cx - qx[q]
            dy = cy - qy[q]
            dotmax = qnx[q] * dx + qny[q] * dy + abs(qnx[q]) * hx + abs(qny[q]) * hy
            if dotmax <= 0.0:
                lb[q] = np.inf
                continue
            ex = max(abs(dx) - hx, 0.0)
            ey = max(abs(dy) - hy, 0.0)
            r2 = ex * ex + ey * ey
            lb[q] = b2[q] * r2 * r2 * r2 / (dotmax * dotmax)
            if lb[q] < lbs:
                lbs = lb[q]
                qs = q
        if qs < 0:
            for i in range(i0, i1):
                for j in range(j0, j1):
                    best_key[i, j] = np.inf
                    best_idx[i, j] = -1
            continue
        upper = 0.0
        for i in range(i0, i1):
            for j in range(j0, j1):
                upper = max(upper, _key(xs[j], ys[i], qx[qs], qy[qs], qnx[qs], qny[qs], b2[qs]))
        # Relative slack: the bound and the exact value round differently.
        upper = upper * (1.0 + 1e-9)
        for i in range(i0, i1):
            for j in range(j0, j1):
                best_key[i, j] = np.inf
                best_idx[i, j] = -1
        # Survivors in index order with a strict comparison: ties go to the lowest index,
        # exactly as in the brute force. The pixel loop is branch-free so that it vectorises.
        for q in range(nq):
            if lb[q] > upper:
                continue
            ax, ay, nx_, ny_, bb = qx[q], qy[q], qnx[q], qny[q], b2[q]
            for i in range(i0, i1):
                dy = ys[i] - ay
                dyn = ny_ * dy
                dy2 = dy * dy
                key_row = best_key[i]
                idx_row = best_idx[i]
                for j in range(j0, j1):
                    dx = xs[j] - ax
                    dot = nx_ * dx + dyn
                    r2 = dx * dx + dy2
                    k = bb * r2 * r2 * r2 / (dot * dot)
                    k = k if dot > 0.0 else np.inf
                    better = k < key_row[j]
                    key_row[j] = k if better else key_row[j]
                    idx_row[j] = q if better else idx_row[j]


@numba.njit(parallel=True, cache=True)
def _idf_occluded(
    xs, ys, qx, qy, qnx, qny, b2, lx, ly, occ, best_key, best_idx
):  # pragma: no cover
    nq = qx.shape[0]
    for i in prange(ys.shape[0]):
        y = ys[i]
        for j in range(xs.shape[0]):
            x = xs[j]
            best = np.inf
            bi = -1
            for q in range(nq):
                dx = x - qx[q]
                dy = y - qy[q]
                dot = qnx[q] * dx + qny[q] * dy
                if dot <= 0.0:
                    continue
                r2 = dx * dx + dy * dy
                key = b2[q] * r2 * r2 * r2 / (dot * dot)
                # The crossing test is the expensive part: only run it for a would-be winner.
                if key < best and not segment_blocked(lx[q], ly[q], x, y, occ):
                    best = key
                    bi = q
            best_key[i, j] = best
            best_idx[i, j] = bi


def intensity_distance_field(
    room: Room2D,
    samples: WallSamples,
    values: ArrayLike,
    grid: FieldGrid,
    window: tuple[int, int, int, int] | None = None,
    method: str = "tiled",
) -> tuple[np.ndarray, np.ndarray]:
    """``D(p)`` and ``L(p)`` (eqs. 6.6, 6.7) on ``grid``, with exact occlusion.

    Parameters
    ----------
    room:
        The scene; its obstacles (and walls, when not convex) occlude.
    samples:
        Measurement sites (their points and normals are used).
    values:
        ``(N,)`` albedo-free direct light ``B`` at the sites (negatives count as zero).
    grid:
        Candidate light positions.
    window:
        Optional pixel window ``(i0, i1, j0, j1)`` (half-open); only it is computed and
        returned, which is what the per-light position refinement needs.
    method:
        ``"tiled"`` (branch and bound over pixel blocks, exact) or ``"brute"`` (every
        pixel against every measurement, as in the thesis); both give the same fields.
        Scenes with occluders always use the brute force.

    Returns
    -------
    D:
        ``(h, w)`` float64; ``inf`` where no measurement bounds ``p``, NaN outside free space.
    L:
        ``(h, w)`` int64 measurement index of the limiter; ``-1`` where ``D`` is not finite.
    """
    b = np.asarray(values, dtype=np.float64).reshape(-1)
    if len(samples) == 0:
        raise LocalizeError("intensity_distance_field: no measurements")
    if b.shape[0] != len(samples):
        raise LocalizeError(
            f"intensity_distance_field: {b.shape[0]} values for {len(samples)} measurements"
        )
    if not np.isfinite(b).all():
        raise LocalizeError("intensity_distance_field: measurement values must be finite")
    if method not in ("tiled", "brute"):
        raise LocalizeError(f"intensity_distance_field: unknown method {method!r}")
    ny, nx = grid.shape
    i0, i1, j0, j1 = window if window is not None else (0, ny, 0, nx)
    i0, j0 = max(0, i0), max(0, j0)
    i1, j1 = min(ny, i1), min(nx, j1)
    if i1 <= i0 or j1 <= j0:
        raise LocalizeError(f"intensity_distance_field: empty window {window}")
    b2 = np.maximum(b, 0.0) ** 2
    pts, nrm = samples.points, samples.normals
    qx, qy = np.ascontiguousarray(pts[:, 0]), np.ascontiguousarray(pts[:, 1])
    qnx, qny = np.ascontiguousarray(nrm[:, 0]), np.ascontiguousarray(nrm[:, 1])
    shape = (i1 - i0, j1 - j0)
    best_key = np.full(shape, np.inf)
    best_idx = np.full(shape, -1, dtype=np.int64)
    xs = grid.origin[0] + (np.arange(j0, j1) + 0.5) * grid.pixel
    ys = grid.origin[1] + (np.arange(i0, i1) + 0.5) * grid.pixel
    occ = room.occluder_segments
    with _threads_for(shape[0] * shape[1] * b.shape[0] * (1 + occ.shape[0])):
        if occ.shape[0]:
            # Lift sites off their own edge (see scene2d._lift) for the exact crossing test.
            lifted = pts + (1e-9 * room.radius) * nrm
            lx, ly = np.ascontiguousarray(lifted[:, 0]), np.ascontiguousarray(lifted[:, 1])
            occ = np.ascontiguousarray(occ)
            _idf_occluded(xs, ys, qx, qy, qnx, qny, b2, lx, ly, occ, best_key, best_idx)
        elif method == "brute":
            _idf_free(xs, ys, qx, qy, qnx, qny, b2, best_key, best_idx)
        else:
            _idf_tiled(xs, ys, qx, qy, qnx, qny, b2, _TILE, best_key, best_idx)
    d = np.sqrt(best_key)
    free = _free_mask(room, grid)[i0:i1, j0:j1]
    d[~free] = np.nan
    best_idx[~free] = -1
    return d, best_idx


_FREE_CACHE: dict[tuple, np.ndarray] = {}


def _free_mask(room: Room2D, grid: FieldGrid) -> np.ndarray:
    """Pixels whose centre lies in free space (cached: the same room is queried thousands of times)."""
    key = (room.walls.tobytes(), tuple(o.tobytes() for o in room.obstacles), grid)
    mask = _FREE_CACHE.get(key)
    if mask is None:
        if len(_FREE_CACHE) > 64:
            _FREE_CACHE.clear()
        mask = room.contains(grid.centres())
        _FREE_CACHE[key] = mask
    return mask


# --------------------------------------------------------------------------------------
# Circles of pixels, the medial axis and V(p)


@functools.lru_cache(maxsize=32)
def ring_offsets(radius: int) -> np.ndarray:
    """``(M, 2)`` pixel offsets ``(di, dj)`` at distance ``radius`` (rounded), in clockwise order.

    Consecutive offsets are 8-neighbours, so the ring is a closed chain of pixels; for
    ``radius = 1`` it is the 8 neighbours of the pixel.
    """
    if radius < 1:
        raise LocalizeError(f"voting radius must be at least one pixel, got {radius}")
    r = int(radius)
    di, dj = np.mgrid[-r - 1 : r + 2, -r - 1 : r + 2]
    dist = np.hypot(di, dj)
    keep = np.rint(dist) == r
    di, dj = di[keep], dj[keep]
    # Clockwise with rows pointing up (y): decreasing angle.
    order = np.argsort(-np.arctan2(di, dj), kind="stable")
    out = np.stack([di[order], dj[order]], axis=1).astype(np.int64)
    out.flags.writeable = False  # cached: shared between callers
    return out


@functools.lru_cache(maxsize=32)
def _disc_half_widths(radius: int) -> np.ndarray:
    """``half[di + r]``: the disc of :func:`disc_offsets` spans ``|dj| <= half`` in row ``di``."""
    r = max(1, int(radius))
    di = np.arange(-r, r + 1)
    out = np.floor(np.sqrt(np.maximum((r + 0.5) ** 2 - di**2, 0.0))).astype(np.int64)
    out.flags.writeable = False
    return out


@functools.lru_cache(maxsize=32)
def disc_offsets(radius: int) -> np.ndarray:
    """``(M, 2)`` offsets of the pixels within ``radius`` of the centre, the centre excluded."""
    r = max(1, int(radius))
    di, dj = np.mgrid[-r - 1 : r + 2, -r - 1 : r + 2]
    keep = (np.hypot(di, dj) <= r + 0.5) & ((di != 0) | (dj != 0))
    out = np.stack([di[keep], dj[keep]], axis=1).astype(np.int64)
    out.flags.writeable = False  # cached: shared between callers
    return out


@numba.njit(cache=True, inline="always")
def _surface_distance(a, b, arc, loop, loop_len):  # pragma: no cover
    if a == b:
        return 0.0
    la = loop[a]
    if la != loop[b]:
        return np.inf
    d = abs(arc[a] - arc[b])
    return min(d, loop_len[la] - d)


@numba.njit(parallel=True, cache=True)
def _vote_kernel(lim, ring, arc, loop, loop_len, threshold, medial, out):  # pragma: no cover
    ny, nx = lim.shape
    m = ring.shape[0]
    for i in prange(ny):
        for j in range(nx):
            if lim[i, j] < 0:
                out[i, j] = 0.0
                continue
            total = 0.0
            count = 0
            jump = False
            for k in range(m):
                ia, ja = i + ring[k, 0], j + ring[k, 1]
                kb = k + 1 if k + 1 < m else 0
                ib, jb = i + ring[kb, 0], j + ring[kb, 1]
                if ia < 0 or ia >= ny or ja < 0 or ja >= nx:
                    continue
                if ib < 0 or ib >= ny or jb < 0 or jb >= nx:
                    continue
                la, lb = lim[ia, ja], lim[ib, jb]
                if la < 0 or lb < 0:
                    continue
                d = _surface_distance(la, lb, arc, loop, loop_len)
                if d > threshold:
                    jump = True
                elif d > 0.0:
                    total += d
                    count += 1
            if medial:
                out[i, j] = 1.0 if jump else 0.0
            else:
                out[i, j] = total / count if count > 0 else 0.0


def _vote_inputs(samples: WallSamples, limiter: np.ndarray):
    lim = np.ascontiguousarray(limiter, dtype=np.int64)
    if lim.max(initial=-1) >= len(samples):
        raise LocalizeError("limiter field refers to measurements that do not exist")
    return lim, samples.arc, samples.loop, samples.loop_lengths


def voting_field(
    limiter: np.ndarray, samples: WallSamples, radius: int = 1, threshold: float = np.inf
) -> np.ndarray:
    """The voting function ``V(p)`` (§6.4.3, VOTINGFUNCTION).

    For the ring of pixels ``radius`` away from ``p``, ``V(p)`` is the mean surface distance
    ``d(L(p_i), L(p_i+1))`` over consecutive ring pixels with ``0 < d < threshold``; zero
    steps (one limiter on both) and discontinuities (``d >= threshold``, or limiters on
    different surface loops) do not count. Zero where no step counts.

    Parameters
    ----------
    limiter:
        ``L(p)`` as measurement indices (``-1`` outside free space).
    samples:
        The measurement sites, for their arc-length positions.
    radius:
        Ring radius in pixels (the thesis uses 1 without noise, 15 with).
    threshold:
        Discontinuity threshold ``T``, in surface length units.
    """
    lim, arc, loop, lens = _vote_inputs(samples, limiter)
    out = np.empty(lim.shape)
    ring = ring_offsets(radius)
    with _threads_for(lim.size * ring.shape[0]):
        _vote_kernel(lim, ring, arc, loop, lens, float(threshold), False, out)
    return out


def medial_axis(
    limiter: np.ndarray, samples: WallSamples, threshold: float, radius: int = 1
) -> np.ndarray:
    """Boolean medial axis of the IDF (§6.4.2, ISMEDIALAXIS).

    A pixel is on the medial axis when two consecutive pixels of the ring around it have
    limiters more than ``threshold`` apart along the surface (the thesis uses 5% of the
    scene radius).
    """
    lim, arc, loop, lens = _vote_inputs(samples, limiter)
    out = np.empty(lim.shape)
    ring = ring_offsets(radius)
    with _threads_for(lim.size * ring.shape[0]):
        _vote_kernel(lim, ring, arc, loop, lens, float(threshold), True, out)
    return out > 0.5


# --------------------------------------------------------------------------------------
# Candidates: local maxima of V


@numba.njit(parallel=True, cache=True)
def _count_kernel(lim, half, nq, out):  # pragma: no cover
    """Distinct limiters in the disc around each pixel, the disc sliding along each row.

    ``half[di + r]`` is the half-width of the disc's row ``di``; moving one pixel right
    drops the leftmost pixel of every disc row and adds one on the right, so each pixel
    costs ``2 (2 r + 1)`` counter updates instead of a whole disc.
    """
    ny, nx = lim.shape
    r = (half.shape[0] - 1) // 2
    for i in prange(ny):
        cnt = np.zeros(nq, dtype=np.int32)
        distinct = 0
        # Fill the disc of pixel (i, -1), then slide.
        for di in range(-r, r + 1):
            a = i + di
            if a < 0 or a >= ny:
                continue
            for b in range(-1 - half[di + r], -1 + half[di + r] + 1):
                if 0 <= b < nx and lim[a, b] >= 0:
                    cnt[lim[a, b]] += 1
                    if cnt[lim[a, b]] == 1:
                        distinct += 1
        for j in range(nx):
            for di in range(-r, r + 1):
                a = i + di
                if a < 0 or a >= ny:
                    continue
                w = half[di + r]
                b = j - 1 - w
                if 0 <= b < nx and lim[a, b] >= 0:
                    cnt[lim[a, b]] -= 1
                    if cnt[lim[a, b]] == 0:
                        distinct -= 1
                b = j + w
                if 0 <= b < nx and lim[a, b] >= 0:
                    cnt[lim[a, b]] += 1
                    if cnt[lim[a, b]] == 1:
                        distinct += 1
            out[i, j] = distinct if lim[i, j] >= 0 else 0.0


def limiter_count_field(limiter: np.ndarray, radius: int, n_measurements: int) -> np.ndarray:
    """``V(p)`` as eq. 6.8 defines it: how many distinct limiters the disc of ``radius`` pixels
    around ``p`` holds.

    The thesis approximates this count by the ring average of :func:`voting_field`
    because a one-pixel disc holds at most 9 values; with the 15-pixel radius it uses on
    noisy data the count itself is fine-grained, and it is what still peaks at the lights
    when noise breaks ``L(p)`` into streaks (see docs/localize.md).
    """
    lim = np.ascontiguousarray(limiter, dtype=np.int64)
    if lim.max(initial=-1) >= n_measurements:
        raise LocalizeError("limiter field refers to measurements that do not exist")
    r = max(1, int(radius))
    # Same disc as disc_offsets: pixels within r + 0.5 of the centre.
    half = _disc_half_widths(r)
    out = np.empty(lim.shape)
    with _threads_for(lim.size * (2 * r + 1) * 2):
        _count_kernel(lim, half, int(n_measurements), out)
    return out


@numba.njit(cache=True)
def _peaks(v, disc, half, valid, start, decay):  # pragma: no cover
    """Local maxima of ``v`` at or above the first level ``H = start * decay^k`` that has any.

    Only pixels at or above the final level are ever tested, level by level from the
    top, so a plateau-rich field costs little.
    """
    ny, nx = v.shape
    top = 0.0
    for i in range(ny):
        for j in range(nx):
            if valid[i, j] and v[i, j] > top:
                top = v[i, j]
    found = np.empty((ny * nx, 2), dtype=np.int64)
    n = 0
    if top <= 0.0:
        return found[:0], 0.0
    h = start
    while h > top:
        h *= decay
    hi = np.inf
    r = (half.shape[0] - 1) // 2
    while h > 1e-12 * top:
        for i in range(ny):
            left_max = False
            for j in range(nx):
                val = v[i, j]
                if not valid[i, j] or val < h or val >= hi:
                    left_max = False
                    continue
                if left_max and j > 0 and v[i, j - 1] == val and valid[i, j - 1]:
                    # The left neighbour, equal and a maximum, vouches for all of this
                    # disc but its right edge: only that edge needs checking (plateaus).
                    ok = True
                    for di in range(-r, r + 1):
                        a, b = i + di, j + half[di + r]
                        if a >= 0 and a < ny and b < nx and v[a, b] > val:
                            ok = False
                            break
                else:
                    ok = True
                    for k in range(disc.shape[0]):
                        a, b = i + disc[k, 0], j + disc[k, 1]
                        if a >= 0 and a < ny and b >= 0 and b < nx and v[a, b] > val:
                            ok = False
                            break
                left_max = ok
                if ok:
                    found[n, 0] = i
                    found[n, 1] = j
                    n += 1
        if n > 0:
            break
        hi = h
        h *= decay
    return found[:n], h


@numba.njit(cache=True)
def _greedy_merge(pos, dist):  # pragma: no cover
    """Indices of the points kept when each, in order, is dropped if near an earlier kept one."""
    keep = np.empty(pos.shape[0], dtype=np.int64)
    n = 0
    d2 = dist * dist
    for k in range(pos.shape[0]):
        ok = True
        for m in range(n):
            dx = pos[k, 0] - pos[keep[m], 0]
            dy = pos[k, 1] - pos[keep[m], 1]
            if dx * dx + dy * dy < d2:
                ok = False
                break
        if ok:
            keep[n] = k
            n += 1
    return keep[:n]


def find_candidates(
    votes: np.ndarray,
    centres: np.ndarray,
    valid: np.ndarray,
    peak_radius: int,
    start_height: float,
    merge_distance: float,
    decay: float = 0.5,
) -> tuple[np.ndarray, np.ndarray]:
    """Candidate light positions: local maxima of ``V`` (GETLIGHTCANDIDATES, §6.4.3).

    A pixel is a candidate when no pixel within ``peak_radius`` has more votes and its
    vote is at least ``H``. ``H`` starts at ``start_height`` (the thesis: ``|Q| / 10``
    measurement spacings) and is multiplied by ``decay`` until some candidate passes.
    Candidates closer than ``merge_distance`` are combined, the one with more votes
    standing for both.

    Parameters
    ----------
    votes:
        ``V(p)``.
    centres:
        ``(h, w, 2)`` positions of the pixels.
    valid:
        Pixels allowed to hold a light (free space, not too close to a surface: §6.3.6
        filters false peaks from occlusion by that distance).

    Returns
    -------
    positions:
        ``(M, 2)`` candidates, strongest first.
    heights:
        ``(M,)`` their votes.
    """
    if not 0.0 < decay < 1.0:
        raise LocalizeError(f"peak threshold decay must lie in (0, 1), got {decay}")
    v = np.ascontiguousarray(votes, dtype=np.float64)
    ok = np.ascontiguousarray(valid, dtype=np.bool_) & (v > 0)
    r = max(1, int(peak_radius))
    ij, _ = _peaks(v, disc_offsets(r), _disc_half_widths(r), ok, float(start_height), float(decay))
    if ij.shape[0] == 0:
        return np.zeros((0, 2)), np.zeros(0)
    pos = centres[ij[:, 0], ij[:, 1]]
    heights = v[ij[:, 0], ij[:, 1]]
    order = np.argsort(-heights, kind="stable")
    pos, heights = pos[order], heights[order]
    chosen = _greedy_merge(np.ascontiguousarray(pos), float(merge_distance))
    return pos[chosen], heights[chosen]


# --------------------------------------------------------------------------------------
# The candidate proposer used by the refinement algorithm


@dataclass(frozen=True)
class VoteParams:
    """Settings of the voting function and of candidate extraction, in scene-relative units.

    Attributes
    ----------
    method:
        ``"ring"``: the thesis's VOTINGFUNCTION (§6.4.3), mean surface distance between
        the limiters of consecutive pixels on a ring; ``"count"``: eq. 6.8 itself, the
        number of distinct limiters in the disc (see :func:`limiter_count_field`).
    radius:
        Ring (or disc) radius ``r`` in pixels (thesis: 1 noiseless, 15 noisy); also the
        radius of the local-maximum test.
    threshold:
        Discontinuity threshold ``T`` of the medial axis and the votes, as a fraction of
        the scene radius (thesis: 5%).
    start_height:
        First peak threshold ``H`` in units of ``|Q|`` (thesis: ``|Q| / 10``, i.e. 0.1):
        ``|Q| / 10`` distinct limiters for ``"count"``, ``|Q| / 10`` measurement spacings
        (10% of the wall length) for ``"ring"``.
    decay:
        Factor by which ``H`` is lowered until a peak is found.
    merge:
        Candidates closer than this fraction of the scene radius are combined (thesis: 0.1).
    surface_margin:
        Candidates closer than this fraction of the scene radius to a surface are
        discarded (false peaks near occluders and walls, §6.3.6); with ``"count"``, also
        those closer than the disc radius.
    """

    method: str = "ring"
    radius: int = 1
    threshold: float = 0.05
    start_height: float = 0.1
    decay: float = 0.5
    merge: float = 0.1
    surface_margin: float = 0.02


Proposer = Callable[..., np.ndarray]


class FieldProposer2D:
    """Candidate light positions from the voting function of a 2D room.

    Calling it with the unexplained light ``B'`` returns candidate positions (strongest
    first); ``near`` and ``within`` restrict the search to a disc, which is all that the
    per-light position refinement (Algorithm 3) looks at, and computes only the window
    of the fields that the disc needs.
    """

    def __init__(
        self,
        room: Room2D,
        samples: WallSamples,
        resolution: int = 256,
        params: VoteParams | None = None,
    ) -> None:
        check_samples(room, samples)
        self.room = room
        self.samples = samples
        self.params = params or VoteParams()
        self.grid = FieldGrid.for_room(room, resolution)
        self.centres = self.grid.centres()
        if self.params.method not in ("ring", "count"):
            raise LocalizeError(f"unknown voting method {self.params.method!r}")
        self.threshold = self.params.threshold * room.radius
        # |Q| / 10 in the units of V: distinct limiters, or surface length.
        unit = (
            1.0 if self.params.method == "count" else float(samples.loop_lengths[0]) / len(samples)
        )
        self.start_height = self.params.start_height * len(samples) * unit
        self.merge_distance = self.params.merge * room.radius
        margin = self.params.surface_margin * room.radius
        if self.params.method == "count":
            # A disc that reaches a surface counts that surface's own limiters, which
            # sweep along it pixel by pixel: false peaks all along the walls.
            margin = max(margin, self.params.radius * self.grid.pixel)
        free = _free_mask(room, self.grid)
        self.valid = free & (room.distance_to_surfaces(self.centres) >= margin)

    def votes(self, limiter: np.ndarray) -> np.ndarray:
        """``V(p)`` of a limiter field by the configured method."""
        if self.params.method == "count":
            return limiter_count_field(limiter, self.params.radius, len(self.samples))
        return voting_field(limiter, self.samples, self.params.radius, self.threshold)

    def fields(self, values: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Full-grid ``D``, ``L`` and ``V`` for ``values``."""
        d, lim = intensity_distance_field(self.room, self.samples, values, self.grid)
        return d, lim, self.votes(lim)

    def __call__(
        self, values: ArrayLike, near: ArrayLike | None = None, within: float | None = None
    ) -> np.ndarray:
        """``(M, 2)`` candidate light positions for the light ``values`` (strongest first)."""
        r = self.params.radius
        if near is None:
            _, lim = intensity_distance_field(self.room, self.samples, values, self.grid)
            v = self.votes(lim)
            valid, centres = self.valid, self.centres
        else:
            if within is None:
                raise LocalizeError("FieldProposer2D: 'near' needs 'within'")
            ci, cj = self.grid.to_pixel(np.asarray(near, dtype=np.float64))
            # The disc itself, plus the ring radius for V and the peak radius for the maxima.
            half = math.ceil(within / self.grid.pixel) + 2 * r + 1
            ny, nx = self.grid.shape
            i0, i1 = max(0, ci - half), min(ny, ci + half + 1)
            j0, j1 = max(0, cj - half), min(nx, cj + half + 1)
            if i1 <= i0 or j1 <= j0:
                return np.zeros((0, 2))
            _, lim = intensity_distance_field(
                self.room, self.samples, values, self.grid, (i0, i1, j0, j1)
            )
            v = self.votes(lim)
            centres = self.centres[i0:i1, j0:j1]
            dist = np.linalg.norm(centres - np.asarray(near, dtype=np.float64), axis=-1)
            valid = self.valid[i0:i1, j0:j1] & (dist < within)
        pos, _ = find_candidates(
            v, centres, valid, r, self.start_height, self.merge_distance, self.params.decay
        )
        return pos
