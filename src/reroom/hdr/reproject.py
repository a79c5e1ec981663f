"""Radiance reprojection (thesis §3.6): one robust HDR radiance per vertex.

Each sample of vertex ``i`` in frame ``j`` gives the radiance ``X_ij / t_j``
(linearised pixel over the frame's scale, per channel). Its weight is
``w_ij = c(X_ij) g_ij`` (eq. 3.4): the hat confidence of the 8-bit level
(eq. 3.3) times the projected area ``g_ij`` (eq. 3.2). The vertex radiance is
the per-channel weighted median of its samples.

The thesis's hat gives a black pixel (level 0) zero weight. A vertex seen only
black would then have no radiance at all; here every level keeps a small floor
weight (``CONFIDENCE_FLOOR``), so such a vertex gets radiance 0, and saturated
pixels keep their small positive weight as in the thesis.

Vertices with no sample in any frame that has an exposure are *unobserved*:
radiance 0 and ``observed = False``, never NaN.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from reroom.hdr import _kernels as K
from reroom.hdr.observe import Observations, decode_linear
from reroom.hdr.solve import hat_confidence

__all__ = [
    "CONFIDENCE_FLOOR",
    "BestFrame",
    "Radiance",
    "best_frame_texture",
    "reproject_radiance",
    "sample_tiers",
]

#: Smallest confidence of any 8-bit level (eq. 3.3 gives 0 for level 0).
CONFIDENCE_FLOOR = 1e-3


@dataclass
class Radiance:
    """Per-vertex HDR radiance.

    Attributes
    ----------
    radiance:
        ``(V, 3)`` float64 linear radiance in units of the reference frame's
        scale (``t_ref = 1``); 0 where unobserved.
    observed:
        ``(V,)`` bool.
    sample_count:
        ``(V,)`` int64 samples that entered the median (clean ones if the vertex
        has any, else all).
    """

    radiance: np.ndarray
    observed: np.ndarray
    sample_count: np.ndarray


@dataclass
class BestFrame:
    """Per vertex, its single best sample (largest weight ``w_ij``): naive texturing.

    ``frame`` is -1 for vertices without samples; ``value`` is the 8-bit pixel and
    ``linear`` the sample's linear value (``(V, 3)`` uint16 code, see
    :func:`~reroom.hdr.observe.decode_linear`), as the camera exposed it.
    """

    frame: np.ndarray
    value: np.ndarray
    linear: np.ndarray

    def linear_values(self) -> np.ndarray:
        """``(V, 3)`` float64 linear values (0 where there is no sample)."""
        return decode_linear(self.linear)


def _confidence_lut() -> np.ndarray:
    return np.maximum(hat_confidence(np.arange(256)), CONFIDENCE_FLOOR)


class VertexGroups:
    """Samples of ``obs`` grouped by vertex (a counting sort, computed once and reused)."""

    def __init__(self, obs: Observations) -> None:
        self.order, self.offsets = K.group_by(obs.vertex, obs.n_vertices)


def sample_tiers(flags: np.ndarray) -> np.ndarray:
    """How much each sample is trusted, from its flags: each vertex's radiance uses only
    its samples of the highest tier.

    2: clean; 1: near an image or depth edge (:data:`~reroom.hdr.observe.EDGE_FLAGS`;
    where the footprint test found some of its pixels on another surface, its value
    is already the mean of the others, :data:`~reroom.hdr.observe.MIXED_FOOTPRINT`);
    0: all its pixels see another surface than its vertex's
    (:data:`~reroom.hdr.observe.FOREIGN_FOOTPRINT`), never used.
    """
    # One rule for both: the reprojection kernel applies the same function per sample.
    return K.sample_tiers(np.ascontiguousarray(flags, np.uint8))


def reproject_radiance(
    obs: Observations,
    scales: np.ndarray,
    groups: VertexGroups | None = None,
    level_linear: np.ndarray | None = None,
) -> Radiance:
    """Weighted-median radiance of every vertex (eq. 3.2-3.4) given frame ``scales``.

    Parameters
    ----------
    obs:
        Samples from :func:`~reroom.hdr.observe.collect_observations`.
    scales:
        ``(F, 3)`` per-frame per-channel scales; frames with a non-finite or
        non-positive scale are left out.
    groups:
        Precomputed :class:`VertexGroups` of ``obs`` (saves a sort when called
        for several sets of scales).
    level_linear:
        ``(256,)`` linear value of each 8-bit level (the response LUT the samples
        were linearised with). When given, a second pass re-weights every sample by
        the hat confidence of the level the first pass's radiance *predicts* in its
        frame, and counts clipped samples as censored (+inf). The thesis's weights
        come from each sample's own level: with noisy pixels, that lets the noise
        pick the samples (a bright vertex keeps the frames where noise pulled it
        down from saturation, a dark one those where noise lifted it), which
        compresses the dynamic range -- measured in ``docs/hdr.md``.
    """
    groups = groups or VertexGroups(obs)
    s = np.asarray(scales, np.float64)
    good = np.all(np.isfinite(s) & (s > 0), axis=1)
    inv = np.full((obs.n_frames, 3), np.nan)
    inv[good] = 1.0 / s[good]
    out = np.zeros((obs.n_vertices, 3))
    count = np.zeros(obs.n_vertices, np.int64)
    decode = decode_linear(np.arange(65536))
    conf = _confidence_lut()
    no_prior = np.zeros((0, 3))

    def medians(prior: np.ndarray, lut: np.ndarray) -> None:
        K.reproject_medians(
            groups.offsets,
            groups.order,
            obs.frame,
            obs.value,
            obs.linear,
            obs.geometry,
            obs.flags,
            decode,
            conf,
            inv,
            prior,
            lut,
            out,
            count,
        )

    medians(no_prior, np.zeros(256))
    if level_linear is not None:
        lut = np.asarray(level_linear, np.float64)
        if lut.shape != (256,) or np.any(np.diff(lut) < 0):
            raise ValueError("level_linear must be 256 non-decreasing linear values")
        medians(out.copy(), lut)
    return Radiance(out, count > 0, count)


def best_frame_texture(obs: Observations, groups: VertexGroups | None = None) -> BestFrame:
    """Each vertex's best single sample: the frame where its weight ``c * g`` is largest.

    Samples of a higher tier (:func:`sample_tiers`: clean first) are preferred, and
    those whose pixels all show another surface are never chosen.
    """
    if len(obs) == 0:
        return BestFrame(
            np.full(obs.n_vertices, -1, np.int64),
            np.zeros((obs.n_vertices, 3), np.uint8),
            np.zeros((obs.n_vertices, 3), np.uint16),
        )
    groups = groups or VertexGroups(obs)
    conf = _confidence_lut()[obs.value].min(axis=1)
    # Higher tiers first: a flagged sample is chosen only when a vertex has nothing better.
    tier = sample_tiers(obs.flags)
    w = conf * obs.geometry
    score = np.where(tier > 0, tier + w / (1.0 + w), -np.inf)  # the weight breaks ties only
    best = K.best_samples(groups.offsets, groups.order, score)
    has = best >= 0
    frame = np.where(has, obs.frame[np.maximum(best, 0)], -1)
    value = np.where(has[:, None], obs.value[np.maximum(best, 0)], 0).astype(np.uint8)
    linear = np.where(has[:, None], obs.linear[np.maximum(best, 0)], 0).astype(np.uint16)
    return BestFrame(frame.astype(np.int64), value, linear)
