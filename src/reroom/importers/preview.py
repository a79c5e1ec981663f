"""A quick offscreen picture of an imported mesh (vertex colours, soft ambient light).

Rendered with Mitsuba (:func:`reroom.render.mitsuba`): the mesh's sRGB vertex
colours become the albedo of a two-sided diffuse material lit by a uniform
white environment, traced with direct lighting only. Surfaces open to the sky
show their colour as captured; creases and corners darken like ambient
occlusion, which is what makes the geometry readable. It runs headless, on
the CPU, in a few seconds for a few hundred thousand triangles.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from reroom.io.images import write_rgb8
from reroom.scan.camera import Intrinsics, look_at

#: Mitsuba's camera looks down +z with +y up (x to the left); reroom's (OpenGL) down -z.
_GL_TO_MITSUBA = np.diag([-1.0, 1.0, -1.0, 1.0])


def _srgb_to_linear(c: np.ndarray) -> np.ndarray:
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def mesh_vertex_colors(mesh: trimesh.Trimesh, default: float = 0.7) -> np.ndarray:
    """The mesh's vertex colours as sRGB floats in [0, 1], ``(N, 3)`` (grey if it has none)."""
    attrs = getattr(mesh, "vertex_attributes", {}) or {}
    col = attrs.get("color")
    if col is None:
        visual = getattr(mesh, "visual", None)
        if visual is not None and getattr(visual, "kind", None) == "vertex":
            col = np.asarray(visual.vertex_colors)[:, :3]
    if col is None:
        return np.full((len(mesh.vertices), 3), default)
    col = np.asarray(col)
    if col.dtype == np.uint8 or col.max() > 1.0:
        return col[:, :3].astype(np.float64) / 255.0
    return col[:, :3].astype(np.float64)


def render_mesh_image(
    mesh: trimesh.Trimesh,
    c2w: np.ndarray,
    intrinsics: Intrinsics,
    *,
    spp: int = 32,
    background: tuple[float, float, float] = (1.0, 1.0, 1.0),
    seed: int = 0,
) -> np.ndarray:
    """Render ``mesh`` seen by a pinhole camera; return ``(H, W, 3)`` uint8 sRGB.

    ``c2w`` is camera-to-world in OpenGL axes (the scan format's); the image has
    the intrinsics' size, field of view and principal point.
    """
    from reroom.render import mitsuba

    mi = mitsuba()
    verts = np.ascontiguousarray(np.asarray(mesh.vertices, dtype=np.float32))
    faces = np.ascontiguousarray(np.asarray(mesh.faces, dtype=np.uint32))
    colors = _srgb_to_linear(np.clip(mesh_vertex_colors(mesh), 0.0, 1.0)).astype(np.float32)

    props = mi.Properties()
    props["bsdf"] = mi.load_dict(
        {
            "type": "twosided",
            "material": {
                "type": "diffuse",
                "reflectance": {"type": "mesh_attribute", "name": "vertex_color"},
            },
        }
    )
    shape = mi.Mesh(
        "preview",
        vertex_count=len(verts),
        face_count=len(faces),
        props=props,
        has_vertex_normals=False,
        has_vertex_texcoords=False,
    )
    params = mi.traverse(shape)
    params["vertex_positions"] = mi.Float(verts.ravel())
    params["faces"] = mi.UInt32(faces.ravel())
    params.update()
    shape.add_attribute("vertex_color", 3, mi.Float(colors.ravel()))

    k = intrinsics
    to_world = np.asarray(c2w, dtype=np.float64) @ _GL_TO_MITSUBA
    scene = mi.load_dict(
        {
            "type": "scene",
            "integrator": {
                "type": "direct",
                "emitter_samples": 1,
                "bsdf_samples": 1,
                "hide_emitters": True,
            },
            "sensor": {
                "type": "perspective",
                "fov_axis": "y",
                "fov": float(k.fov_y_deg),
                # Offsets of the principal point from the film centre, in film
                # fractions (x to the right, y down, as pixel coordinates).
                "principal_point_offset_x": float((k.cx - k.width / 2.0) / k.width),
                "principal_point_offset_y": float((k.cy - k.height / 2.0) / k.height),
                "near_clip": 0.01,
                "far_clip": 1000.0,
                "to_world": mi.ScalarTransform4f(to_world.tolist()),
                "sampler": {"type": "stratified", "sample_count": int(spp), "seed": int(seed)},
                "film": {
                    "type": "hdrfilm",
                    "width": int(k.width),
                    "height": int(k.height),
                    "rfilter": {"type": "gaussian"},
                    "pixel_format": "rgba",
                },
            },
            "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}},
            "room": shape,
        }
    )
    img = np.asarray(mi.render(scene, seed=int(seed), spp=int(spp)), dtype=np.float32)
    rgb, alpha = img[..., :3], np.clip(img[..., 3:4], 0.0, 1.0)
    # The sky shows through where no surface is hit: paint it the background instead.
    bg = _srgb_to_linear(np.asarray(background, dtype=np.float64)).astype(np.float32)
    rgb = rgb + (1.0 - alpha) * bg
    srgb = np.where(rgb <= 0.0031308, rgb * 12.92, 1.055 * np.power(np.maximum(rgb, 0), 1 / 2.4) - 0.055)
    return np.clip(np.round(srgb * 255.0), 0, 255).astype(np.uint8)


def render_mesh_preview(
    mesh: trimesh.Trimesh,
    c2w: np.ndarray,
    intrinsics: Intrinsics,
    path: str | Path,
    *,
    spp: int = 32,
    background: tuple[float, float, float] = (1.0, 1.0, 1.0),
) -> Path:
    """Render ``mesh`` (vertex colours) from ``c2w`` (OpenGL axes) and write a PNG to ``path``."""
    image = render_mesh_image(mesh, c2w, intrinsics, spp=spp, background=background)
    return write_rgb8(path, image)


def overview_camera(
    first_c2w: np.ndarray,
    mesh: trimesh.Trimesh,
    *,
    back: float = 1.5,
    up: float = 1.0,
) -> np.ndarray:
    """A camera behind and above ``first_c2w`` (OpenGL axes, +Z up) looking into the room.

    It looks at the median of the mesh vertices in front of the first camera,
    so the picture shows what the capture saw, with the capture's own
    position in the foreground.
    """
    c2w = np.asarray(first_c2w, dtype=np.float64)
    eye0 = c2w[:3, 3]
    fwd = -c2w[:3, 2]
    level = np.array([fwd[0], fwd[1], 0.0])
    if np.linalg.norm(level) < 1e-6:
        level = np.array([0.0, 1.0, 0.0])
    level /= np.linalg.norm(level)
    v = np.asarray(mesh.vertices, dtype=np.float64)
    ahead = v[(v - eye0) @ fwd > 0.5]
    target = np.median(ahead, axis=0) if len(ahead) else eye0 + 3.0 * level
    eye = eye0 - back * level + np.array([0.0, 0.0, up])
    return look_at(eye, target)


__all__ = ["mesh_vertex_colors", "overview_camera", "render_mesh_image", "render_mesh_preview"]
