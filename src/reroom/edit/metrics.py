"""Image-fidelity figures for renders of edited rooms against a reference (issue #6, item 6).

Both images are linear RGB in the same units -- in the fidelity benchmark, *image units*:
radiance times the frame's exposure scale, so 1 is the sensor's white level and both are
what the camera would have recorded.

* :func:`relative_rmse` -- on the HDR images,
  ``||ours - truth||_2 / ||truth||_2`` with the norms over every pixel and channel (the
  root-mean-square error divided by the root-mean-square of the truth; no clipping, so
  visible light sources count with their full radiance).
* :func:`ssim_tonemapped` -- scikit-image's ``structural_similarity`` of the two images
  tone-mapped the way a photo is shown: clipped to the white level and sRGB-encoded
  (:func:`tone_map`), ``channel_axis=-1``, ``data_range=1``, default 7x7 window (so
  SSIM here also sees the clipping a camera would apply).
* :func:`comparison_strip` -- ``ours | truth | error`` side by side for people.
"""

from __future__ import annotations

import numpy as np

from reroom.errors import ReroomError

__all__ = ["comparison_strip", "compare_images", "relative_rmse", "ssim_tonemapped", "tone_map"]


def _pair(ours: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(ours, dtype=np.float64)
    b = np.asarray(truth, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 3 or a.shape[2] != 3:
        raise ReroomError(f"images to compare must both be (H, W, 3); got {a.shape} and {b.shape}")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise ReroomError("images to compare contain NaN or infinite values")
    return a, b


def tone_map(linear: np.ndarray) -> np.ndarray:
    """Display encoding of a linear image in image units: clip to [0, 1], sRGB curve."""
    from reroom.io.images import linear_to_srgb

    return linear_to_srgb(np.asarray(linear, dtype=np.float64))


def relative_rmse(ours: np.ndarray, truth: np.ndarray, mask: np.ndarray | None = None) -> float:
    """``||ours - truth||_2 / ||truth||_2`` over all pixels (``mask``: only those) and channels.

    Raises
    ------
    ReroomError
        When the shapes differ, values are not finite, or the truth is all zero.
    """
    a, b = _pair(ours, truth)
    if mask is not None:
        m = np.asarray(mask, bool)
        if m.shape != a.shape[:2]:
            raise ReroomError(f"mask has shape {m.shape}, images {a.shape[:2]}")
        a, b = a[m], b[m]
    denom = float(np.sqrt(np.sum(b * b)))
    if denom <= 0:
        raise ReroomError("the reference image is black: relative RMSE is undefined")
    return float(np.sqrt(np.sum((a - b) ** 2)) / denom)


def ssim_tonemapped(ours: np.ndarray, truth: np.ndarray) -> float:
    """Mean SSIM of the tone-mapped images (scikit-image, ``channel_axis=-1``, range 1)."""
    from skimage.metrics import structural_similarity

    a, b = _pair(ours, truth)
    return float(structural_similarity(tone_map(a), tone_map(b), channel_axis=-1, data_range=1.0))


def compare_images(ours: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Both figures and the ratio of means (a global brightness bias) as a dict."""
    a, b = _pair(ours, truth)
    mean_truth = float(b.mean())
    return {
        "relative_rmse": relative_rmse(a, b),
        "ssim": ssim_tonemapped(a, b),
        "ratio_of_means": float(a.mean() / mean_truth) if mean_truth > 0 else float("nan"),
    }


def comparison_strip(ours: np.ndarray, truth: np.ndarray, error_range: float = 0.5) -> np.ndarray:
    """``ours | truth | error`` as one uint8 image for people.

    The error panel shows ``(ours - truth) / truth`` per pixel on the luminance (mean of
    the channels), red where ours is brighter, blue where darker, full colour at
    ``error_range`` (default +-50 %); pixels darker than 1 % of the white level are grey,
    as a relative error means little there.
    """
    a, b = _pair(ours, truth)
    la, lb = a.mean(axis=2), b.mean(axis=2)
    rel = np.clip((la - lb) / np.maximum(lb, 1e-6) / error_range, -1.0, 1.0)
    err = np.ones(a.shape)
    err[..., 0] -= np.clip(-rel, 0, 1)  # darker: less red and green -> blue
    err[..., 1] -= np.abs(rel)
    err[..., 2] -= np.clip(rel, 0, 1)  # brighter: less blue and green -> red
    err[lb < 0.01] = 0.5
    strip = np.concatenate([tone_map(a), tone_map(b), err], axis=1)
    return (np.clip(strip, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
