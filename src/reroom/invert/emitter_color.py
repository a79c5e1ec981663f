"""A light's colour from the unsaturated edge of its clipped image in the photos.

An auto-exposed room photo clips a tube or a panel (ten to a hundred times its white
level) to a saturated blob, so the light's colour is not in the blob. It is at the
blob's edge: a pixel the light covers by a few per cent (the lens's spread, the pixel's
footprint, the renderer's filter) holds ``f L + (1 - f) L_bg`` below the white level,
and its excess over the background beside it, ``f (L - L_bg)``, has the light's colour
whatever ``f`` is, up to ``L_bg / L`` (a few per cent of the difference between the two
colours for a light tens of times the white level). In the HDR stage's linear units
(its response and per-channel exposures), the excess summed over every such pixel of
every frame is the light's chromaticity in the HDR mesh's units, which is what the solve
needs: the room's receivers cannot tell a tube's colour from a window's where both light
the same walls (docs/invert.md, sessions 18 and 31); the photos can.

Per frame: the pixels clipped in every channel that hold the light's projected sample
points, grown to their connected blob; the edge, unsaturated pixels within
``edge_px`` of the blob; the background, unsaturated pixels ``edge_px + 1`` to
``edge_px + 4`` out, averaged within 4 pixels of each edge pixel (a normalised box
filter), so a blob between a dark fixture and a lit ceiling gets each side's own. Written by hand: no library reads an emitter's colour from the
fringe of its clipped image; the image operations are scipy.ndimage's, the occlusion
rays Embree's (:class:`reroom.rays.RayCaster`).

Across frames: a frame whose edge colour is more than ``MAX_FRAME_DEVIATION`` off the
frames' median colour in any channel is dropped (its background is not what lies
behind its edge: on a second trajectory of `furnished`, two of ten frames of the tube
read 0.74-0.76 / 1.02 / 1.23-1.24 against the others' 0.93-0.96 / 0.98-1.01 / 1.04-1.08,
and took the sum's red 5 % low and its blue 4.5 % high, the bootstrap's spread to 3.4 %).
When the frames that disagree hold more than a third of the edge pixels there is no
colour most frames agree on: none is dropped, and the bootstrap's spread over them all
says how far the colour can be trusted (the pipeline's gate).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy import ndimage

from reroom.invert.line_photos import points_in_view
from reroom.rays import RayCaster

__all__ = ["EmitterColor", "emitter_color", "rectangle_points", "segment_points"]

LUMA = np.array([0.2126, 0.7152, 0.0722])

#: A frame's edge colour further than this (relative, in any channel) from the
#: pixel-weighted median of the frames' colours is an outlier, and dropped.
MAX_FRAME_DEVIATION = 0.08

#: When the frames that disagree hold more than this share of the edge pixels, there is
#: no colour most frames agree on: none is dropped, and the spread over them all tells.
MAX_DROPPED_SHARE = 1.0 / 3.0


@dataclass(frozen=True)
class EmitterColor:
    """The photos' colour of a light.

    Attributes
    ----------
    color:
        Chromaticity (mean 1) in the linear units of the frame scales given.
    spread:
        Half the 90 % interval of each channel over a bootstrap on the frames (same
        units as ``color``): what the colour is good to.
    pixels, frames:
        Edge pixels used, and the frames they came from.
    dropped:
        Frames whose edge colour disagreed with the others' (``MAX_FRAME_DEVIATION``),
        left out.
    """

    color: np.ndarray
    spread: np.ndarray
    pixels: int
    frames: int
    dropped: int = 0

    def summary(self) -> dict[str, Any]:
        """JSON-ready figures (``scene.json``'s ``color_from_photos``)."""
        return {
            "color": np.round(self.color, 4).tolist(),
            "spread": np.round(self.spread, 4).tolist(),
            "edge_pixels": self.pixels,
            "frames": self.frames,
            "frames_dropped": self.dropped,
        }


def segment_points(p0: ArrayLike, p1: ArrayLike, n: int = 41) -> np.ndarray:
    """``n`` points on a tube's axis, 5-95 % of the way from ``p0`` to ``p1``."""
    a0, a1 = np.asarray(p0, float).reshape(3), np.asarray(p1, float).reshape(3)
    t = np.linspace(0.05, 0.95, n)
    return a0 + t[:, None] * (a1 - a0)


def rectangle_points(
    centroid: ArrayLike, axis_long: ArrayLike, axis_short: ArrayLike, size: ArrayLike, n: int = 7
) -> np.ndarray:
    """An ``n x n`` grid over the middle 80 % of a rectangular light."""
    c = np.asarray(centroid, float).reshape(3)
    a, b = np.asarray(axis_long, float).reshape(3), np.asarray(axis_short, float).reshape(3)
    sa, sb = (0.4 * float(s) for s in np.asarray(size, float).reshape(2))
    g = np.linspace(-1.0, 1.0, n)
    u, v = np.meshgrid(g * sa, g * sb)
    return c + u.reshape(-1, 1) * a + v.reshape(-1, 1) * b


def _frame_edge(
    img8: np.ndarray,
    lin: np.ndarray,
    uv: np.ndarray,
    saturation: int,
    edge_px: float,
    excess_over_background: float,
) -> tuple[np.ndarray, int]:
    """Summed excess (3,) of one photo's edge pixels around the blob holding ``uv``."""
    h, w = img8.shape[:2]
    clipped = (img8 >= saturation).all(axis=2)
    saturated = (img8 >= saturation).any(axis=2)
    seeds = np.zeros((h, w), bool)
    j = np.clip(uv[:, 0].astype(int), 0, w - 1)
    i = np.clip(uv[:, 1].astype(int), 0, h - 1)
    seeds[i, j] = True
    seeds = ndimage.binary_dilation(seeds, iterations=1) & clipped
    if not seeds.any():
        return np.zeros(3), 0  # the light is not clipped here: hidden, or not bright
    labels, _ = ndimage.label(clipped)
    blob = np.isin(labels, np.unique(labels[seeds]))
    dist = ndimage.distance_transform_edt(~blob)
    edge = (dist > 0) & (dist <= edge_px) & ~saturated
    ring = (dist >= edge_px + 1.0) & (dist <= edge_px + 4.0) & ~saturated
    if not edge.any() or not ring.any():
        return np.zeros(3), 0
    # The background under each edge pixel: the mean of the ring within 4 pixels of it.
    weight = ndimage.uniform_filter(ring.astype(float), size=9, mode="constant")
    bg = np.stack(
        [ndimage.uniform_filter(lin[..., c] * ring, size=9, mode="constant") for c in range(3)],
        axis=-1,
    )
    edge &= weight > 1e-6
    if not edge.any():
        return np.zeros(3), 0
    bg = bg[edge] / weight[edge][:, None]
    excess = lin[edge] - bg
    keep = excess @ LUMA >= excess_over_background * np.maximum(bg @ LUMA, 1e-12)
    return excess[keep].sum(axis=0), int(np.count_nonzero(keep))


def emitter_color(
    frames: Sequence[Any],
    load_image: Callable[[Any], np.ndarray | None],
    frame_scale: Callable[[int], np.ndarray | None],
    inverse_response: np.ndarray,
    caster: RayCaster,
    points: ArrayLike,
    *,
    facing: Callable[[np.ndarray], bool] | None = None,
    saturation: int = 250,
    edge_px: float = 1.5,
    excess_over_background: float = 1.0,
    min_pixels: int = 30,
    min_frames: int = 3,
    bootstrap: int = 200,
    seed: int = 0,
) -> EmitterColor | None:
    """A light's chromaticity from the edges of its clipped image (module notes).

    Parameters
    ----------
    frames:
        :class:`reroom.scan.Frame` objects (``project``, ``center``).
    load_image:
        ``load_image(frame) -> (H, W, 3)`` 8-bit image, or None to skip the frame.
    frame_scale:
        ``frame_scale(index) -> (3,)`` the frame's linear pixel per unit radiance (the
        HDR stage's exposures), or None to skip the frame.
    inverse_response:
        ``(256,)`` 8-bit level to linear value (the HDR stage's curve).
    caster:
        What may stand between a camera and the light (for a tube: the scan without
        its fixture, whose block a fused scan closes around it).
    points:
        ``(N, 3)`` points on the light (:func:`segment_points`, :func:`rectangle_points`).
    facing:
        ``facing(camera_centre) -> bool``: whether a camera can see the light's emitting
        side (default: every camera).
    saturation:
        8-bit level at or above which a channel counts as clipped. The blob is clipped
        in every channel; an edge pixel in none.
    edge_px:
        Pixels from the blob counted as its edge.
    excess_over_background:
        An edge pixel's excess luminance over its background's, at least. A noisy
        background (a path-traced ceiling's speckle) passes a low bar by its own
        noise and lends the edge its colour: at 0.3 a grey panel under a warm ceiling
        read 1.072/0.993/0.935, at 1 within 0.2 % (a 24-frame `furnished` scan, the true
        exposures; ``benchmarks/bench_emitter_color.py --excess-over-background``).
    min_pixels, min_frames:
        Fewer edge pixels or frames than this give None.
    bootstrap, seed:
        Bootstrap resamplings of the frames for ``spread``, and their seed.

    Returns
    -------
    EmitterColor or None
        None when the photos hold too few edge pixels (a light exposed below
        saturation, or one no frame sees).
    """
    pts = np.asarray(points, float).reshape(-1, 3)
    lut = np.asarray(inverse_response, float)
    sums, counts = [], []
    for fr in frames:
        c = np.asarray(fr.center, float)
        if facing is not None and not facing(c):
            continue
        uv, _, seen = points_in_view(fr, caster, pts)
        if not seen.any():
            continue
        scale = frame_scale(int(fr.index))
        if scale is None:
            continue
        img = load_image(fr)
        if img is None:
            continue
        img8 = np.asarray(img)
        lin = lut[img8] / np.asarray(scale, float)
        total, count = _frame_edge(img8, lin, uv[seen], saturation, edge_px, excess_over_background)
        if count:
            sums.append(total)
            counts.append(count)
    per_frame, pixels = np.asarray(sums).reshape(-1, 3), np.asarray(counts, int)
    keep = consistent_frames(per_frame, pixels)
    if pixels[~keep].sum() > MAX_DROPPED_SHARE * pixels.sum():
        # No colour most frames agree on: keep them all, and let the spread tell.
        keep = np.ones(len(per_frame), bool)
    dropped = int(len(keep) - np.count_nonzero(keep))
    per_frame, pixels = per_frame[keep], pixels[keep]
    if len(per_frame) < min_frames or pixels.sum() < min_pixels:
        return None
    whole = per_frame.sum(axis=0)
    if np.any(whole <= 0):
        return None
    rng = np.random.default_rng(seed)
    draws = []
    for _ in range(bootstrap):
        pick = per_frame[rng.integers(0, len(per_frame), len(per_frame))].sum(axis=0)
        if pick.mean() > 0:
            draws.append(pick / pick.mean())
    lo, hi = np.percentile(np.asarray(draws), [5, 95], axis=0)
    return EmitterColor(
        whole / whole.mean(), 0.5 * (hi - lo), int(pixels.sum()), len(per_frame), dropped
    )


def consistent_frames(
    per_frame: np.ndarray, pixels: np.ndarray, tolerance: float = MAX_FRAME_DEVIATION
) -> np.ndarray:
    """Which frames' summed edge excess ``(F, 3)`` agrees in colour with the rest.

    Each frame's colour (its excess over its mean) against the median of the frames'
    colours, each frame weighted by its edge ``pixels``, channel by channel: a frame
    more than ``tolerance`` off it (relative) in any channel, or without a positive
    colour, is an outlier. Returns a boolean mask.
    """
    per_frame = np.asarray(per_frame, float).reshape(-1, 3)
    w = np.asarray(pixels, float).reshape(-1)
    valid = np.all(per_frame > 0, axis=1)
    if not valid.any():
        return valid
    color = per_frame / np.maximum(per_frame.mean(axis=1, keepdims=True), 1e-300)
    median = np.array([_weighted_median(color[valid, c], w[valid]) for c in range(3)])
    return valid & (np.max(np.abs(color / median - 1.0), axis=1) <= tolerance)


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    # A handful of frames: numpy suffices (the HDR stage's numba kernel is per vertex,
    # and private to that stage); numpy's own median takes no weights.
    order = np.argsort(values)
    cum = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cum, 0.5 * cum[-1])])
