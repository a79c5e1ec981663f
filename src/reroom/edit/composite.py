"""Differential rendering: insert virtual objects into real photos (Debevec 1998; thesis §7.3).

A render of the room model cannot match a photo pixel for pixel (the model is
approximate), but the *change* an edit makes can be rendered well. Differential
rendering therefore adds to the photo only the difference between two renders of
the model, with and without the edit: the shadows the new object casts and the
light it reflects land on the real surfaces, while everything the edit does not
touch stays exactly as photographed. Where the object itself is seen, the render
with the object replaces the photo.
"""

from __future__ import annotations

import numpy as np

__all__ = ["differential_composite"]


def differential_composite(
    photo: np.ndarray,
    render_with: np.ndarray,
    render_without: np.ndarray,
    object_mask: np.ndarray,
    mode: str = "ratio",
    eps: float = 1e-6,
) -> np.ndarray:
    """Composite an edit into a linear photo by differential rendering.

    Parameters
    ----------
    photo:
        ``(H, W, 3)`` linear radiance of the input frame, in the same units as the
        renders (divide an HDR-calibrated frame by its exposure scale ``t_j``).
    render_with, render_without:
        ``(H, W, 3)`` linear renders of the room model from the same camera, with and
        without the edit (the inserted object).
    object_mask:
        ``(H, W)`` coverage of the inserted object in ``[0, 1]`` (fractional at
        anti-aliased edges).
    mode:
        ``"ratio"`` (default): background pixels become
        ``photo * render_with / render_without``, so a shadow darkens the real
        texture by the factor the model predicts, whatever the model's error in
        absolute brightness (the photo's own texture and the model's albedo
        errors cancel). ``"additive"``: Debevec's
        ``photo + (render_with - render_without)``, exact when the model matches
        the photo, and the only choice where ``render_without`` is black.
        Where ``render_without`` is below ``eps`` the ratio falls back to the
        additive form.
    eps:
        Radiance below which a pixel of ``render_without`` counts as black.

    Returns
    -------
    ndarray
        ``(H, W, 3)`` linear composite, clamped at 0.

    Raises
    ------
    ValueError
        For mismatched shapes, a mask outside ``[0, 1]`` or an unknown mode.
    """
    photo = np.asarray(photo, np.float64)
    rw = np.asarray(render_with, np.float64)
    rwo = np.asarray(render_without, np.float64)
    mask = np.asarray(object_mask, np.float64)
    if photo.shape != rw.shape or photo.shape != rwo.shape or photo.ndim != 3:
        raise ValueError(
            f"photo and renders must have the same (H, W, 3) shape: {photo.shape}, "
            f"{rw.shape}, {rwo.shape}"
        )
    if mask.shape != photo.shape[:2]:
        raise ValueError(f"object_mask must be {photo.shape[:2]}, got {mask.shape}")
    if np.any(mask < 0) or np.any(mask > 1):
        raise ValueError("object_mask must lie in [0, 1]")
    additive = photo + (rw - rwo)
    if mode == "additive":
        background = additive
    elif mode == "ratio":
        dark = rwo < eps
        ratio = rw / np.where(dark, 1.0, rwo)
        background = np.where(dark, additive, photo * ratio)
    else:
        raise ValueError(f"mode must be 'ratio' or 'additive', not {mode!r}")
    m = mask[..., None]
    return np.maximum(m * rw + (1.0 - m) * background, 0.0)
