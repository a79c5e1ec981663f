"""Procedural textures for synthetic rooms (no downloads): a wooden plank floor."""

from __future__ import annotations

import numpy as np


def wood_floor(
    size: int = 512,
    extent_m: float = 2.0,
    plank_width_m: float = 0.16,
    mean_albedo: tuple[float, float, float] = (0.42, 0.28, 0.16),
    seed: int = 7,
) -> np.ndarray:
    """A tileable linear-RGB albedo image of wooden planks running along +u.

    ``size`` pixels cover ``extent_m`` metres; planks have random lengths,
    per-plank tone variation, dark seams and a wavy grain. Values stay within
    [0.02, 0.95] so the texture is a physically plausible albedo.
    """
    rng = np.random.default_rng(seed)
    px = extent_m / size
    u = (np.arange(size) + 0.5) * px
    uu, vv = np.meshgrid(u, u, indexing="xy")  # uu along columns (u), vv along rows (v)
    n_rows = int(round(extent_m / plank_width_m))
    row = np.minimum((vv / (extent_m / n_rows)).astype(int), n_rows - 1)
    offsets = rng.uniform(0, extent_m, n_rows)
    lengths = rng.uniform(0.6, 1.2, n_rows)
    along = (uu + offsets[row]) % extent_m
    plank_id = row * 100 + (along // lengths[row]).astype(int)
    tone = 1.0 + 0.18 * np.sin(plank_id * 12.9898) * np.cos(plank_id * 4.1414)
    grain = 1.0 + 0.07 * np.sin(2 * np.pi * (vv * 38.0 + 0.25 * np.sin(2 * np.pi * uu * 1.7 + row)))
    seam_v = (
        np.abs(((vv / (extent_m / n_rows)) % 1.0) - 0.5) > 0.5 - 0.004 / (extent_m / n_rows) * 2
    )
    seam_u = (along % lengths[row]) < 0.004
    shade = tone * grain * np.where(seam_v | seam_u, 0.45, 1.0)
    img = np.asarray(mean_albedo, float)[None, None, :] * shade[..., None]
    # Rescale so the texture's mean equals the requested albedo exactly.
    img *= np.asarray(mean_albedo) / img.reshape(-1, 3).mean(0)
    return np.clip(img, 0.02, 0.95).astype(np.float32)
