"""Per-vertex radiance as an EXR image, for tools that read images but not PLY.

Vertex ``i`` is pixel ``(i // width, i % width)`` of an RGBA float image: RGB the
linear radiance, A the observed flag (1 observed, 0 not). Pixels past the last
vertex are zero. Any EXR viewer or image library shows the dynamic range, and
``numpy`` code gets the vertex array back with :func:`read_vertex_exr`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from reroom.io.images import read_exr, write_exr

__all__ = ["write_vertex_exr", "read_vertex_exr", "VERTEX_EXR_WIDTH"]

#: Pixels per row of the vertex image.
VERTEX_EXR_WIDTH = 1024


def write_vertex_exr(
    path: str | Path,
    radiance: np.ndarray,
    observed: np.ndarray,
    width: int = VERTEX_EXR_WIDTH,
) -> Path:
    """Write ``(V, 3)`` radiance and a ``(V,)`` observed flag as an RGBA EXR (atomically)."""
    rad = np.asarray(radiance, np.float32)
    obs = np.asarray(observed, bool)
    if rad.ndim != 2 or rad.shape[1] != 3 or obs.shape != (len(rad),):
        raise ValueError(f"expected (V, 3) radiance and (V,) flags, got {rad.shape}, {obs.shape}")
    n = len(rad)
    rows = max(1, -(-n // width))
    img = np.zeros((rows * width, 4), np.float32)
    img[:n, :3] = rad
    img[:n, 3] = obs
    return write_exr(path, img.reshape(rows, width, 4))


def read_vertex_exr(path: str | Path, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`write_vertex_exr`: ``(radiance (V, 3), observed (V,))``."""
    img = read_exr(path)
    flat = img.reshape(-1, img.shape[-1])
    if img.shape[-1] != 4 or len(flat) < n_vertices:
        raise ValueError(f"{path}: not a vertex image of {n_vertices} vertices (shape {img.shape})")
    return flat[:n_vertices, :3].copy(), flat[:n_vertices, 3] > 0.5
