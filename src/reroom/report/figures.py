"""Pictures the report makes itself: input frames, HDR mesh views, label views.

The HDR mesh is drawn from input cameras by ray casting its per-vertex radiance
(:func:`reroom.hdr.pictures.render_vertex_colors`, no shading: the texture is the
radiance) times that frame's recovered exposure ``t_j``, so each view should look like
the photo beside it; the labels are drawn the same way with one colour per label.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from reroom.hdr.pictures import dollhouse_camera, render_vertex_colors
from reroom.io.mesh import read_ply
from reroom.rays import RayCaster
from reroom.scan import Scan

__all__ = ["LABEL_COLORS", "hdr_views", "label_views", "pick_frames"]

#: Display colours (linear RGB) of the layout labels.
LABEL_COLORS = {
    "wall": (0.55, 0.62, 0.80),
    "floor": (0.60, 0.35, 0.12),
    "ceiling": (0.85, 0.85, 0.75),
    "door": (0.70, 0.10, 0.10),
    "window": (0.10, 0.60, 0.85),
    "baseboard": (0.95, 0.65, 0.05),
    "other": (0.25, 0.25, 0.25),
}


def pick_frames(n_frames: int, count: int) -> list[int]:
    """``count`` frame indices evenly spread over ``n_frames`` (first and last included)."""
    if n_frames <= 0:
        return []
    k = max(1, min(count, n_frames))
    return sorted({int(round(x)) for x in np.linspace(0, n_frames - 1, k)})


def hdr_views(
    scan: Scan, hdr_dir: Path, count: int = 2
) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """HDR mesh views from ``count`` input cameras, each next to its photo.

    Returns
    -------
    list of (frame index, photo uint8, view uint8)
        Frames are evenly spread over those with an exposure. The view is the radiance
        times the frame's per-channel scale, clipped and sRGB-encoded (what a linear
        camera with that exposure records); unobserved surfaces are magenta.
    """
    doc = json.loads((hdr_dir / "exposures.json").read_text())
    mesh = read_ply(hdr_dir / "hdr_mesh.ply")
    rad = np.asarray(mesh.vertex_attributes["radiance"], np.float64)
    observed = np.asarray(mesh.vertex_attributes["observed"]).astype(bool)
    usable = [j for j, f in enumerate(doc["frames"]) if f.get("scale") is not None]
    usable = [j for j in usable if j < len(scan.frames)]
    caster = RayCaster(mesh)
    out = []
    for i in pick_frames(len(usable), count):
        j = usable[i]
        frame = scan.frames[j]
        scale = np.asarray(doc["frames"][j]["scale"], np.float64)
        colors = np.clip(rad * scale, 0.0, 1.0)
        view = render_vertex_colors(
            caster, colors, frame.c2w, frame.intrinsics, valid=observed, cull_backfaces=False
        )
        out.append((j, frame.load_image(), view))
    return out


def label_views(
    scan: Scan, labels_ply: Path, label_ids: dict[str, int], frame: int | None = None
) -> list[tuple[str, np.ndarray]]:
    """The per-vertex layout labels drawn from above the room and from an input camera.

    Parameters
    ----------
    labels_ply:
        ``layout_labels.ply`` (per-vertex ``label``).
    label_ids:
        Label name to id (``layout.json``'s ``labels``).
    frame:
        Input frame for the second view (default: the middle frame).
    """
    mesh = read_ply(labels_ply)
    lab = np.asarray(mesh.vertex_attributes["label"]).astype(int)
    colors = np.tile(np.asarray(LABEL_COLORS["other"]), (len(lab), 1))
    for name, i in label_ids.items():
        if name in LABEL_COLORS:
            colors[lab == int(i)] = LABEL_COLORS[name]
    caster = RayCaster(mesh)
    c2w, intr = dollhouse_camera(mesh.vertices, 480, 360)
    views = [
        (
            "from above (near walls and ceiling culled)",
            render_vertex_colors(caster, colors, c2w, intr),
        )
    ]
    j = len(scan.frames) // 2 if frame is None else frame
    f = scan.frames[j]
    views.append(
        (
            f"from input frame {j}",
            render_vertex_colors(caster, colors, f.c2w, f.intrinsics, cull_backfaces=False),
        )
    )
    return views
