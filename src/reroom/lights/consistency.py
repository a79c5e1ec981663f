"""Is a bright candidate bright from every direction? (view consistency)

An emitter -- a panel, a tube, a window's glass -- has about the same radiance in
every frame that sees it. A specular highlight (a glossy desk reflecting a lamp or
the window) is bright only in frames near the mirror direction; the HDR stage's
per-vertex weighted median can still land above the light threshold when the lobe
is broad or the camera path lingers near it. So every candidate's vertices are
observed again in every frame (:func:`~reroom.hdr.observe.collect_observations`,
the HDR stage's own projection and visibility test), each sample is brought to
radiance with that frame's exposure from ``exposures.json``, and per frame the
median radiance over the candidate's visible vertices says whether the frame sees
it bright. Saturated samples count as bright (the camera's white level is a lower
bound).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from reroom.hdr.linearize import LUMA
from reroom.hdr.observe import Observations, ObserveOptions, collect_observations
from reroom.rays import RayCaster
from reroom.scan import Frame

__all__ = [
    "SATURATED",
    "ViewConsistency",
    "clipped_fraction",
    "observe_vertices",
    "view_consistency",
]

#: 8-bit level from which a pixel counts as clipped (noise keeps some clipped pixels below 255).
SATURATED = 250


@dataclass
class ViewConsistency:
    """Per-candidate view statistics.

    Attributes
    ----------
    frames_seeing:
        ``(C,)`` frames that see at least ``min_samples`` of the candidate's vertices.
    frames_bright:
        ``(C,)`` of those, frames where the median radiance of its visible vertices
        is at least ``bright_level`` (or saturated).
    view_ratio:
        ``(C,)`` 90th over 10th percentile of the per-frame median luminances
        (1 = the same from everywhere; NaN when fewer than 3 frames see it).
    """

    frames_seeing: np.ndarray
    frames_bright: np.ndarray
    view_ratio: np.ndarray

    def fraction(self) -> np.ndarray:
        """``(C,)`` bright frames over seeing frames (NaN when none sees it)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.frames_seeing > 0, self.frames_bright / self.frames_seeing, np.nan)


def observe_vertices(
    frames: list[Frame],
    caster: RayCaster,
    points: np.ndarray,
    normals: np.ndarray,
    lut: np.ndarray,
    progress: Callable[[str, int, int], None] | None = None,
) -> Observations:
    """Every (vertex, frame) sample of ``points`` (the HDR stage's projection and visibility).

    ``caster`` is the whole scan mesh's; ``points`` may be all its vertices or a subset.
    No sample is dropped near image edges: an emitter's outline is an edge.
    """
    return collect_observations(
        frames,
        SimpleNamespace(vertices=np.ascontiguousarray(points, np.float64)),
        lut,
        # Not the footprint test: the points need not be a mesh, and the nearest pixel is
        # what the clipped fraction counts.
        ObserveOptions(gradient_threshold=float("inf"), footprint_test=False),
        caster=caster,
        progress=(lambda s, d, t: progress("observe", d, t)) if progress else None,
        normals=np.ascontiguousarray(normals, np.float64),
    )


def clipped_fraction(obs: Observations, level: int = SATURATED) -> tuple[np.ndarray, np.ndarray]:
    """Per vertex: samples, and the fraction of them whose pixel is at the white level.

    A surface that is clipped in most frames, whatever each frame's exposure, is
    brighter than anything the auto-exposure was set for: an emitter (or the sun).
    Its HDR radiance is only a lower bound (about ``1 / t_j``).
    """
    n = np.bincount(obs.vertex, minlength=obs.n_vertices)
    sat = obs.value.max(axis=1) >= level
    k = np.bincount(obs.vertex, weights=sat, minlength=obs.n_vertices)
    with np.errstate(invalid="ignore", divide="ignore"):
        return n, np.where(n > 0, k / np.maximum(n, 1), 0.0)


def resolved_frames(
    frames: list[Frame], centroids: np.ndarray, widths: np.ndarray, min_pixels: float = 3.0
) -> np.ndarray:
    """``(C, F)`` whether each frame sees each candidate at least ``min_pixels`` wide.

    A thin emitter (a 3 cm tube seen from 2 m in a 160-pixel frame is under 2 pixels
    wide) is blurred with its dark surroundings by the 3x3 sample, so it looks dim in
    frames that do not resolve it: those frames cannot tell an emitter from a highlight.
    """
    c = np.asarray(centroids, float).reshape(-1, 3)
    w = np.asarray(widths, float).reshape(-1)
    centres = np.array([f.center for f in frames]).reshape(-1, 3)
    focal = np.array([min(f.intrinsics.fx, f.intrinsics.fy) for f in frames])
    dist = np.linalg.norm(c[:, None, :] - centres[None, :, :], axis=2)
    return focal[None, :] * w[:, None] / np.maximum(dist, 1e-6) >= min_pixels


def view_consistency(
    obs: Observations,
    group: np.ndarray,
    n_groups: int,
    scales: np.ndarray,
    bright_level: float,
    min_samples: int = 3,
    resolved: np.ndarray | None = None,
) -> ViewConsistency:
    """Measure how view-dependent each candidate's brightness is.

    Parameters
    ----------
    obs:
        Samples of the mesh vertices (:func:`observe_vertices`).
    group:
        ``(V,)`` candidate index of every vertex of ``obs`` (-1 = none).
    n_groups:
        Number of candidates.
    scales:
        ``(F, 3)`` per-frame per-channel exposure (``exposures.json``; NaN rows =
        frames without an exposure, skipped).
    bright_level:
        Luminance above which a frame sees a candidate bright.
    min_samples:
        A frame must see this many of a candidate's vertices (or all of them, if
        fewer) to count.
    resolved:
        ``(C, F)`` bool, whether frame ``j`` resolves candidate ``c`` (see
        :func:`resolved_frames`); unresolved frames do not count. Default: all.
    """
    n_f = obs.n_frames
    seeing = np.zeros(n_groups, np.int64)
    bright = np.zeros(n_groups, np.int64)
    ratio = np.full(n_groups, np.nan)
    if n_groups == 0 or len(obs) == 0:
        return ViewConsistency(seeing, bright, ratio)
    s = np.asarray(scales, np.float64).reshape(n_f, 3)
    g_all = np.asarray(group)[obs.vertex]
    ok = (g_all >= 0) & np.all(np.isfinite(s[obs.frame]) & (s[obs.frame] > 0), axis=1)
    frm = obs.frame[ok]
    lum = (obs.linear_values(ok) / s[frm]) @ LUMA
    saturated = obs.value[ok].max(axis=1) >= SATURATED
    g = g_all[ok]
    counts = np.bincount(group[group >= 0], minlength=n_groups)
    need = np.minimum(min_samples, counts)
    # Median luminance per (candidate, frame): sort samples by key, then take the
    # middle of each run. Saturated samples sort as +inf so they are "bright".
    key = g.astype(np.int64) * n_f + frm
    val = np.where(saturated, np.inf, lum)
    order = np.lexsort((val, key))
    key, val = key[order], val[order]
    if len(key) == 0:
        return ViewConsistency(seeing, bright, ratio)
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    ends = np.r_[starts[1:], len(key)]
    med = val[(starts + ends - 1) // 2]
    cg = key[starts] // n_f
    enough = (ends - starts) >= need[cg]
    if resolved is not None:
        enough &= np.asarray(resolved, bool)[cg, key[starts] % n_f]
    cg, med = cg[enough], med[enough]
    seeing[:] = np.bincount(cg, minlength=n_groups)
    bright[:] = np.bincount(cg, weights=(med >= bright_level), minlength=n_groups).astype(np.int64)
    for c in np.flatnonzero(seeing >= 3):
        m = np.minimum(med[cg == c], np.finfo(float).max)
        lo, hi = np.percentile(m, [10, 90])
        with np.errstate(over="ignore"):
            ratio[c] = hi / lo if lo > 0 else np.inf
    return ViewConsistency(seeing, bright, ratio)
