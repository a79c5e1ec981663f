"""Denoising of path-traced renders with Intel Open Image Denoise (OIDN).

A path tracer's Monte-Carlo noise falls only as ``1 / sqrt(spp)``: in a closed room of
light walls the renders of a recovered model need hundreds of samples per pixel to look
clean, and 16 still look grainy. OIDN (through the ``pyoidn`` bindings; its trained
weights ship inside the library, nothing is downloaded) removes that noise guided by two
cheap auxiliary images, the first-hit albedo and shading normal, so a few samples per
pixel give a clean picture with sharp edges and texture.

Only renders of the *model* are denoised (``reroom edit``, ``reroom run``'s re-render and
edits): the synthetic generator's frames and truth renders never are, because a
denoiser's residual bias would then leak into what every stage is measured against.
"""

from __future__ import annotations

import warnings

import numpy as np

__all__ = ["AUX_AOVS", "denoise"]

#: Mitsuba ``aov`` integrator channels of the auxiliary pass: first-hit albedo, then
#: shading normal (world space), 6 channels in that order.
AUX_AOVS = "albedo:albedo,nn:sh_normal"


def _rgb(image: np.ndarray, name: str, shape: tuple[int, ...] | None) -> np.ndarray:
    a = np.asarray(image)
    if a.ndim != 3 or a.shape[2] != 3 or min(a.shape[:2]) == 0:
        raise ValueError(f"denoise: {name} must be an (H, W, 3) image, got shape {a.shape}")
    if shape is not None and a.shape != shape:
        raise ValueError(f"denoise: {name} has shape {a.shape}, the color image {shape}")
    return a.astype(np.float32, copy=False)


def denoise(
    color: np.ndarray,
    albedo: np.ndarray | None = None,
    normal: np.ndarray | None = None,
    *,
    quality: str = "high",
) -> np.ndarray:
    """A denoised copy of a linear HDR render.

    Parameters
    ----------
    color : ndarray, shape (H, W, 3)
        Linear radiance, any scale (OIDN's HDR mode measures the exposure itself).
        Non-finite pixels (a path tracer's rare NaN) are set to 0 first with a warning:
        the network would otherwise spread them over their neighbourhood.
    albedo, normal : ndarray, shape (H, W, 3), optional
        First-hit albedo (clipped to [0, 1]) and shading normal (unit, any frame), e.g.
        from Mitsuba's ``aov`` integrator (:data:`AUX_AOVS`). Both or neither: OIDN
        takes the normal only with the albedo. They may carry a little noise of their own
        (anti-aliased edges, few samples): OIDN prefilters them.
    quality : {"high", "balanced", "fast"}
        OIDN's filter quality.

    Returns
    -------
    ndarray, shape (H, W, 3), float32
        The denoised image; negative values (none in the input) clipped to 0.
    """
    import pyoidn

    col = _rgb(color, "color", None)
    bad = ~np.isfinite(col)
    if bad.any():
        warnings.warn(
            f"denoise: {int(bad.any(axis=2).sum())} pixel(s) not finite, set to 0",
            RuntimeWarning,
            stacklevel=2,
        )
        col = np.where(bad, 0.0, col).astype(np.float32)
    col = np.ascontiguousarray(np.maximum(col, 0.0))
    if (albedo is None) != (normal is None):
        raise ValueError("denoise: give both albedo and normal, or neither")
    aux: dict[str, np.ndarray] = {}
    if albedo is not None and normal is not None:
        alb = np.clip(np.nan_to_num(_rgb(albedo, "albedo", col.shape)), 0.0, 1.0)
        nrm = np.clip(np.nan_to_num(_rgb(normal, "normal", col.shape)), -1.0, 1.0)
        aux = {"albedo": np.ascontiguousarray(alb), "normal": np.ascontiguousarray(nrm)}
    out = pyoidn.denoise(col, **aux, hdr=True, quality=quality)
    return np.maximum(np.asarray(out, dtype=np.float32), 0.0)
