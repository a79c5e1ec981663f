"""Baked global illumination: per-vertex radiance of a (possibly edited) room model.

The thesis showed its relit rooms in a headset as "a static mesh with baked global
illumination computed using PBRT" (§5.7). Here the path tracer is Mitsuba's: each
vertex's outgoing radiance is estimated by :func:`reroom.render.frames.probe_radiance`
(rays from just in front of the surface looking back at it, full light transport), and
:func:`export_baked` writes it as a float PLY (for further processing) and as a binary
glTF (``.glb``) with tone-mapped sRGB vertex colours that any viewer displays.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from reroom.io.atomic import atomic_path
from reroom.io.images import linear_to_srgb
from reroom.io.mesh import write_ply

__all__ = ["BakedLighting", "bake_vertex_radiance", "export_baked", "tonemap_srgb8"]


@dataclass
class BakedLighting:
    """Per-vertex radiance (linear RGB), its Monte-Carlo standard error, and the spp."""

    radiance: np.ndarray
    stderr: np.ndarray
    spp: int


def bake_vertex_radiance(
    scene: Any,
    vertices: np.ndarray,
    normals: np.ndarray,
    spp: int = 64,
    seed: int = 0,
    progress: Callable[[int, int], None] | None = None,
) -> BakedLighting:
    """Path-trace the outgoing radiance of every vertex towards its normal.

    Parameters
    ----------
    scene:
        A loaded Mitsuba scene, or a scene dict (loaded with ``optimize=False``).
    vertices, normals:
        ``(V, 3)`` positions and normals (normals point to the side that is seen).
    spp:
        Samples per vertex; the returned ``stderr`` says how noisy the result is.
    """
    from reroom.render import mitsuba
    from reroom.render.frames import probe_radiance

    if isinstance(scene, dict):
        from reroom.render.glow import split_glow

        scene = mitsuba().load_dict(split_glow(scene)[0], optimize=False)
    v = np.asarray(vertices, np.float64)
    n = np.asarray(normals, np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or n.shape != v.shape:
        raise ValueError(f"vertices and normals must both be (V, 3): {v.shape}, {n.shape}")
    mean, stderr = probe_radiance(scene, v, n, spp, seed=seed, progress=progress)
    return BakedLighting(mean.astype(np.float32), stderr.astype(np.float32), int(spp))


def tonemap_srgb8(radiance: np.ndarray, exposure: float | None = None) -> tuple[np.ndarray, float]:
    """Linear RGB to 8-bit sRGB: ``exposure`` times radiance, clipped, sRGB-encoded.

    With ``exposure=None`` the median luminance of the lit vertices maps to 0.18
    (mid-grey), like a camera's auto-exposure. Returns ``(rgb8, exposure)``.
    """
    rad = np.maximum(np.asarray(radiance, np.float64), 0.0)
    if exposure is None:
        lum = rad @ np.array([0.2126, 0.7152, 0.0722])
        lit = lum[lum > 0]
        exposure = 0.18 / float(np.median(lit)) if len(lit) else 1.0
    return np.round(linear_to_srgb(rad * exposure) * 255.0).astype(np.uint8), float(exposure)


def export_baked(
    mesh: trimesh.Trimesh,
    baked: BakedLighting,
    out_dir: str | Path,
    name: str = "baked",
    exposure: float | None = None,
) -> dict[str, Path]:
    """Write ``<name>.ply`` (float radiance + stderr) and ``<name>.glb`` (sRGB colours).

    Both are written atomically. Returns the paths by kind (``"ply"``, ``"glb"``).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if len(baked.radiance) != len(mesh.vertices):
        raise ValueError(
            f"{len(baked.radiance)} baked values for a mesh of {len(mesh.vertices)} vertices"
        )
    files = {
        "ply": write_ply(
            out / f"{name}.ply",
            mesh,
            {"radiance": baked.radiance, "radiance_stderr": baked.stderr},
        )
    }
    rgb8, _ = tonemap_srgb8(baked.radiance, exposure)
    rgba = np.concatenate([rgb8, np.full((len(rgb8), 1), 255, np.uint8)], axis=1)
    coloured = trimesh.Trimesh(mesh.vertices, mesh.faces, vertex_colors=rgba, process=False)
    data = coloured.export(file_type="glb")
    with atomic_path(out / f"{name}.glb") as tmp:
        Path(tmp).write_bytes(data)
    files["glb"] = out / f"{name}.glb"
    return files
