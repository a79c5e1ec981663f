"""Small meshes shared by the transfer tests."""

from __future__ import annotations

import numpy as np
import trimesh


def grid_plane(
    half: float, step: float, z: float = 0.0, up: bool = True, x0: float = 0.0
) -> trimesh.Trimesh:
    """A square grid mesh on the plane ``z`` centred at ``(x0, 0)``, facing +Z (or -Z)."""
    xs = np.arange(-half, half + step / 2, step)
    n = len(xs)
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    v = np.stack([gx.ravel() + x0, gy.ravel(), np.full(n * n, z)], axis=1)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    f = np.concatenate([np.stack([a, a + n, a + n + 1], 1), np.stack([a, a + n + 1, a + 1], 1)])
    mesh = trimesh.Trimesh(v, f, process=False)
    if not up:
        mesh.invert()
    return mesh
