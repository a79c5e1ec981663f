"""Ground-truth-free quality measures of a calibration: the seam metrics.

A naive texture colours each vertex from its single best frame (the sample of
largest weight ``c(X) g``, :func:`~reroom.hdr.reproject.best_frame_texture`).
The mesh is then cut into *territories*, one per frame, and wherever the
territories of frames ``j`` and ``k`` meet, an error in ``t_j / t_k`` shows as a
jump in brightness: the seams of thesis Fig. 3.1 and the loop-closure
discontinuities of Fig. 3.3. Both metrics below use luminance
``Y(X / t)`` of linear values ``X`` divided by the frame's scale ``t``, in log
units (0.01 = a 1 % jump). The evaluation restricts both to flat walls; the
report of :func:`~reroom.hdr.pipeline.run_hdr` uses every surface for the seam
metric (it compares each vertex with itself, so texture cancels) and flat
surfaces for the boundary seam (which compares neighbours).

Seam metric (:func:`seam_metric`)
    For every pair of frames ``(j, k)`` whose territories share a mesh edge,
    the jump a seam between them has is estimated over *all* the vertices both
    frames see (not just the few on the boundary)::

        D_jk = median_i [ log Y(X_ij / t_j) - log Y(X_ik / t_k) ]

    and the metric is the count-weighted mean of ``|D_jk|`` over pairs with at
    least ``min_common`` shared vertices::

        seam = sum_jk n_jk |D_jk| / sum_jk n_jk

    With hundreds of shared vertices per pair, the noise of the samples averages
    out: with the true scales it is close to 0 (what remains is view-dependent
    shading and misregistration), and it is directly the size of the visible
    seams. Uses clean, unclipped samples within the solve's level range.
    The *loop seam* is the same over pairs at least ``min_gap`` frames apart in
    the sequence (``k - j >= min_gap``): places the camera came back to, where
    sequential methods have drifted (thesis Fig. 3.3's loop-closure seams).
Boundary seam (:func:`boundary_seam`)
    Measured on the naive texture's actual boundary edges only: per frame pair,
    the median over boundary edges of the jump of ``log Y`` across the edge;
    count-weighted mean of the absolute medians. Closer to what one sees, but
    noisier (few edges per pair), so its floor with the true scales is higher.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from reroom.hdr import _kernels as K
from reroom.hdr.linearize import LUMA
from reroom.hdr.observe import Observations, decode_linear
from reroom.hdr.reproject import BestFrame
from reroom.hdr.solve import SolveOptions, usable_samples

__all__ = [
    "LUMA",
    "loop_gap",
    "SeamSamples",
    "boundary_pairs",
    "boundary_seam",
    "flat_vertices",
    "luminance",
    "seam_metric",
    "seam_samples",
]


def luminance(rgb: np.ndarray) -> np.ndarray:
    """Linear luminance of ``(..., 3)`` linear RGB."""
    return np.asarray(rgb, np.float64) @ LUMA


def flat_vertices(
    edges: np.ndarray, normals: np.ndarray, max_angle_deg: float = 10.0
) -> np.ndarray:
    """``(V,)`` bool: vertices whose normal is within ``max_angle_deg`` of every neighbour's."""
    n = np.asarray(normals, np.float64)
    ok = np.linalg.norm(n, axis=1) > 0.5
    e = np.asarray(edges, np.int64)
    cos = np.einsum("ij,ij->i", n[e[:, 0]], n[e[:, 1]])
    bad = cos < np.cos(np.radians(max_angle_deg))
    ok[e[bad, 0]] = False
    ok[e[bad, 1]] = False
    return ok


@dataclass
class SeamSamples:
    """Samples kept for the seam metric: ``vertex``, ``frame`` (int32), ``linear`` codes."""

    vertex: np.ndarray
    frame: np.ndarray
    linear: np.ndarray

    def to_npz(self, prefix: str = "seam_") -> dict[str, np.ndarray]:
        return {
            f"{prefix}vertex": self.vertex,
            f"{prefix}frame": self.frame,
            f"{prefix}linear": self.linear,
        }

    @staticmethod
    def from_npz(data, prefix: str = "seam_") -> SeamSamples:
        return SeamSamples(data[f"{prefix}vertex"], data[f"{prefix}frame"], data[f"{prefix}linear"])


def seam_samples(
    obs: Observations,
    mask: np.ndarray,
    max_vertices: int = 30000,
    max_per_vertex: int = 32,
    seed: int = 0,
) -> SeamSamples:
    """Pick the samples the seam metric needs (usable samples of ``mask`` vertices, capped)."""
    rng = np.random.default_rng(seed)
    ok = usable_samples(obs, SolveOptions(), fallback=False)
    verts = np.flatnonzero(np.asarray(mask, bool))
    if len(verts) > max_vertices:
        verts = rng.choice(verts, max_vertices, replace=False)
    chosen = np.zeros(obs.n_vertices, bool)
    chosen[verts] = True
    idx = np.flatnonzero(ok & chosen[obs.vertex])
    idx = idx[rng.permutation(len(idx))]
    order, offsets = K.group_by(obs.vertex[idx], obs.n_vertices)
    grouped = idx[order]
    rank = np.arange(len(grouped)) - offsets[obs.vertex[grouped]]
    keep = np.sort(grouped[rank < max_per_vertex])
    return SeamSamples(obs.vertex[keep], obs.frame[keep], obs.linear[keep])


def boundary_pairs(edges: np.ndarray, best_frame: np.ndarray, mask: np.ndarray, n_frames: int):
    """Sorted keys ``j * n_frames + k`` (``j < k``) of frames whose territories share an edge."""
    e = np.asarray(edges, np.int64)
    f = np.asarray(best_frame, np.int64)
    ok = np.asarray(mask, bool) & (f >= 0)
    e = e[ok[e[:, 0]] & ok[e[:, 1]]]
    fa, fb = f[e[:, 0]], f[e[:, 1]]
    diff = fa != fb
    lo, hi = np.minimum(fa, fb)[diff], np.maximum(fa, fb)[diff]
    return np.unique(lo * n_frames + hi)


def loop_gap(n_frames: int) -> int:
    """The frame gap that makes a pair a revisit for the loop seam: a quarter of the scan."""
    return max(10, n_frames // 4)


def _group_medians(key: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unique keys, their counts and the medians of ``d`` per key."""
    if len(key) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    key = np.asarray(key, np.int64)
    if key.min() < 0 or key.max() > 50_000_000:
        raise ValueError("group keys must be integers in [0, 5e7]")
    # A counting sort by key (in numba): a lexsort by key and value took 1.7 s per call
    # on 300 frames, and this is a report's metric, computed 12 times.
    return K.group_medians_by_key(key, np.ascontiguousarray(d, np.float64), int(key.max()) + 1)


def seam_metric(
    samples: SeamSamples,
    pair_keys: np.ndarray,
    scales: np.ndarray,
    min_common: int = 20,
    min_gap: int = 1,
) -> dict:
    """The seam metric (module notes) of ``scales``; the loop seam with ``min_gap > 1``.

    ``pair_keys`` come from :func:`boundary_pairs`; only pairs with ``k - j >=
    min_gap`` count. Returns ``{"seam", "pairs", "vertices_pairs", "p90"}``: the
    metric, how many frame pairs entered it, the total shared-vertex count, and
    the 90th percentile of ``|D_jk|`` over pairs.
    """
    s = np.asarray(scales, np.float64)
    nf = len(s)
    pair_keys = np.asarray(pair_keys, np.int64)
    pair_keys = pair_keys[(pair_keys % nf) - (pair_keys // nf) >= min_gap]
    good = np.all(np.isfinite(s) & (s > 0), axis=1)
    f = samples.frame.astype(np.int64)
    ok = good[f]
    x = decode_linear(samples.linear[ok]) / s[f[ok]]
    lum = luminance(x)
    pos = lum > 0
    v = samples.vertex[ok][pos].astype(np.int64)
    fr = f[ok][pos]
    logy = np.log(lum[pos])
    nan = {"seam": float("nan"), "pairs": 0, "vertices_pairs": 0, "p90": float("nan")}
    if len(v) == 0 or len(pair_keys) == 0:
        return nan
    order = np.lexsort((fr, v))
    v, fr, logy = v[order], fr[order], logy[order]
    offsets = np.r_[np.flatnonzero(np.r_[True, v[1:] != v[:-1]]), len(v)].astype(np.int64)
    keys, d = K.pair_differences(offsets, fr, logy, np.ascontiguousarray(pair_keys, np.int64), nf)
    uk, counts, med = _group_medians(keys, d)
    big = counts >= min_common
    if not np.any(big):
        return nan
    w = counts[big]
    a = np.abs(med[big])
    return {
        "seam": float(np.sum(w * a) / np.sum(w)),
        "pairs": int(np.count_nonzero(big)),
        "vertices_pairs": int(np.sum(w)),
        "p90": float(np.percentile(a, 90)),
    }


def boundary_seam(
    edges: np.ndarray,
    best: BestFrame,
    scales: np.ndarray,
    lut: np.ndarray,
    mask: np.ndarray | None = None,
    min_edges: int = 5,
    levels: tuple[int, int] = (8, 245),
) -> dict:
    """The boundary seam (module notes) of a naive best-frame texture under ``scales``.

    Returns ``{"seam", "pairs", "edges", "same_frame_jump"}``: the metric, how many
    frame pairs and boundary edges entered it, and for scale the median absolute
    jump across edges *within* one frame's territory (noise + shading).
    """
    lut = np.asarray(lut, np.float64)
    s = np.asarray(scales, np.float64)
    f = best.frame
    nf = len(s)
    good_frame = np.zeros(nf + 1, bool)
    good_frame[:nf] = np.all(np.isfinite(s) & (s > 0), axis=1)
    valid = (f >= 0) & good_frame[f]
    valid &= (best.value.min(axis=1) >= levels[0]) & (best.value.max(axis=1) <= levels[1])
    if mask is not None:
        valid &= np.asarray(mask, bool)
    safe_f = np.where(valid, f, 0)
    t = np.where(good_frame[:nf, None], s, 1.0)
    lum = luminance(best.linear_values() / t[safe_f])
    valid &= lum > 0
    logt = np.log(np.where(valid, lum, 1.0))
    e = np.asarray(edges, np.int64)
    e = e[valid[e[:, 0]] & valid[e[:, 1]]]
    fa, fb = f[e[:, 0]], f[e[:, 1]]
    d = logt[e[:, 0]] - logt[e[:, 1]]
    same = fa == fb
    same_jump = float(np.median(np.abs(d[same]))) if np.any(same) else float("nan")
    cross = ~same
    d, fa, fb = d[cross], fa[cross], fb[cross]
    flip = fa > fb
    d[flip] = -d[flip]
    key = np.minimum(fa, fb).astype(np.int64) * nf + np.maximum(fa, fb)
    _, counts, med = _group_medians(key, d)
    big = counts >= min_edges
    if not np.any(big):
        return {"seam": float("nan"), "pairs": 0, "edges": 0, "same_frame_jump": same_jump}
    w = counts[big]
    seam = float(np.sum(w * np.abs(med[big])) / np.sum(w))
    return {
        "seam": seam,
        "pairs": int(np.count_nonzero(big)),
        "edges": int(np.sum(w)),
        "same_frame_jump": same_jump,
    }
