"""A quick offscreen picture of an imported mesh (vertex colours, simple shading).

Rendered with Mitsuba (:func:`reroom.render.mitsuba`) on the CPU, headless, in
a few seconds for a few hundred thousand triangles. The mesh's sRGB vertex
colours are the albedo of a two-sided diffuse material. Two shadings:

* ``"headlight"`` (default): albedo times ``0.3 + 0.7 |n . v|``, a light at
  the eye. Works for closed rooms too (viewed from inside).
* ``"ambient"``: direct light from a uniform white sky, which darkens creases
  like ambient occlusion; nicer for open partial scans, but a closed room
  seen from inside gets no sky light and comes out black.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from reroom.io.images import linear_to_srgb, write_rgb8
from reroom.scan.camera import Intrinsics, look_at


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
    spp: int = 16,
    background: tuple[float, float, float] = (1.0, 1.0, 1.0),
    shading: str = "headlight",
    seed: int = 0,
) -> np.ndarray:
    """Render ``mesh`` seen by a pinhole camera; return ``(H, W, 3)`` uint8 sRGB.

    ``c2w`` is camera-to-world in OpenGL axes (the scan format's); the image has
    the intrinsics' size, field of view and principal point. ``shading`` is
    ``"headlight"`` or ``"ambient"`` (see the module notes).
    """
    from reroom.render import mitsuba
    from reroom.render.camera import perspective_sensor

    if shading not in ("headlight", "ambient"):
        raise ValueError(f"shading must be 'headlight' or 'ambient', got {shading!r}")

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
    scene = mi.load_dict(
        {
            "type": "scene",
            "integrator": {
                "type": "aov",
                "aovs": "albedo:albedo,normal:sh_normal",
                # Headlight shading needs only the AOVs and the coverage (alpha):
                # no light samples at all.
                "image": (
                    {"type": "direct", "emitter_samples": 1, "bsdf_samples": 1}
                    if shading == "ambient"
                    else {"type": "path", "max_depth": 1}
                )
                | {"hide_emitters": True},
            },
            "sensor": perspective_sensor(
                c2w, k, spp, seed, sampler="independent", rfilter="gaussian", pixel_format="rgba"
            ),
            "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}},
            "room": shape,
        }
    )
    img = np.asarray(mi.render(scene, seed=int(seed), spp=int(spp)), dtype=np.float64)
    alpha = np.clip(img[..., 3:4], 0.0, 1.0)
    if shading == "ambient":
        rgb = img[..., :3]
    else:
        # AOVs are averaged over the pixel's samples, misses counting as 0.
        cover = np.maximum(alpha, 1e-6)
        albedo = img[..., 4:7] / cover
        normal = img[..., 7:10]
        normal = normal / np.maximum(np.linalg.norm(normal, axis=-1, keepdims=True), 1e-9)
        jj, ii = np.meshgrid(np.arange(k.width) + 0.5, np.arange(k.height) + 0.5)
        d_cam = np.stack([(jj - k.cx) / k.fx, -(ii - k.cy) / k.fy, -np.ones_like(jj)], axis=-1)
        view = d_cam @ np.asarray(c2w, dtype=np.float64)[:3, :3].T
        view /= np.linalg.norm(view, axis=-1, keepdims=True)
        facing = np.abs((normal * view).sum(axis=-1, keepdims=True))
        rgb = albedo * (0.3 + 0.7 * facing) * alpha
    # Where no surface is hit, show the background.
    bg = _srgb_to_linear(np.asarray(background, dtype=np.float64))
    rgb = rgb + (1.0 - alpha) * bg
    return np.clip(np.round(linear_to_srgb(rgb) * 255.0), 0, 255).astype(np.uint8)


def render_mesh_preview(
    mesh: trimesh.Trimesh,
    c2w: np.ndarray,
    intrinsics: Intrinsics,
    path: str | Path,
    *,
    spp: int = 16,
    background: tuple[float, float, float] = (1.0, 1.0, 1.0),
    shading: str = "headlight",
    inset: np.ndarray | None = None,
    inset_fraction: float = 0.3,
) -> Path:
    """Render ``mesh`` (vertex colours) from ``c2w`` (OpenGL axes) and write a PNG to ``path``.

    ``inset``, an ``(H, W, 3)`` uint8 image (say, one input frame), is pasted
    into the top-left corner at ``inset_fraction`` of the picture's width,
    with a thin dark frame, for a side-by-side look at input and result.
    """
    image = render_mesh_image(
        mesh, c2w, intrinsics, spp=spp, background=background, shading=shading
    )
    if inset is not None:
        image = paste_inset(image, inset, inset_fraction)
    return write_rgb8(path, image)


def paste_inset(
    image: np.ndarray, inset: np.ndarray, fraction: float = 0.3, margin: int = 8
) -> np.ndarray:
    """Copy of ``image`` with ``inset`` resized to ``fraction`` of its width in the top-left."""
    from PIL import Image

    out = np.array(image, dtype=np.uint8, copy=True)
    h, w = out.shape[:2]
    ih, iw = inset.shape[:2]
    tw = max(8, round(w * fraction))
    th = max(8, round(ih * tw / iw))
    small = np.asarray(
        Image.fromarray(np.asarray(inset, dtype=np.uint8)).resize((tw, th), Image.LANCZOS)
    )
    y0, x0 = margin, margin
    if y0 + th + 2 > h or x0 + tw + 2 > w:
        return out
    out[y0 - 2 : y0 + th + 2, x0 - 2 : x0 + tw + 2] = 40
    out[y0 : y0 + th, x0 : x0 + tw] = small[..., :3]
    return out


def overview_camera(
    first_c2w: np.ndarray,
    mesh: trimesh.Trimesh,
    *,
    back: float = 0.6,
    up: float = 0.35,
) -> np.ndarray:
    """A camera ``back`` metres behind and ``up`` above ``first_c2w`` looking into the room.

    ``first_c2w`` is camera-to-world in OpenGL axes, in a +Z-up world. The new
    camera aims at the middle of what lies in front of the first camera (the
    centre of the 5th to 95th percentile box of the mesh vertices ahead of
    it), so the picture shows what the capture saw from a little further
    back. Stepping back far reveals the capture's occlusion shadows (floor
    behind chairs, table behind its centrepiece): nobody saw those.
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
    if len(ahead):
        lo, hi = np.percentile(ahead, [5.0, 95.0], axis=0)
        target = 0.5 * (lo + hi)
    else:
        target = eye0 + 3.0 * level
    eye = eye0 - back * level + np.array([0.0, 0.0, up])
    cam = look_at(eye, target)
    # Re-aim at the middle of the angular spread of what is ahead, so that a
    # near floor and a far, short wall both stay in the picture.
    if len(ahead):
        d = ahead - eye
        right, true_up, fwd_n = cam[:3, 0], cam[:3, 1], -cam[:3, 2]
        depth = d @ fwd_n
        d = d[depth > 0.1]
        depth = depth[depth > 0.1]
        if len(d):
            yaw = np.arctan2(d @ right, depth)
            pitch = np.arctan2(d @ true_up, depth)
            ylo, yhi = np.percentile(yaw, [2.0, 98.0])
            plo, phi = np.percentile(pitch, [2.0, 98.0])
            yc, pc = 0.5 * (ylo + yhi), 0.5 * (plo + phi)
            aim = np.cos(pc) * (np.cos(yc) * fwd_n + np.sin(yc) * right) + np.sin(pc) * true_up
            cam = look_at(eye, eye + aim)
    return cam


__all__ = [
    "mesh_vertex_colors",
    "overview_camera",
    "paste_inset",
    "render_mesh_image",
    "render_mesh_preview",
]
