"""Per-vertex labels: wall, floor, ceiling or other (thesis §4.2.4), then features.

A vertex is floor (ceiling) when its normal is within ``max_angle_deg`` of up (down)
and it lies within ``tol`` of the plane; wall when its normal is within the same angle
of a wall's inward normal, it lies within ``tol`` of the wall plane and inside the
wall's extent. Everything else is ``other``. The labels are then closed along the mesh
(dilate, erode on the vertex adjacency graph) so the smooth corners of a fused mesh and
small noisy patches inside a surface join their surface.

Label ids are those of :data:`reroom.synth.labels.LABELS` (the ground truth's), plus
:data:`OTHER` for everything that is not part of the room's shell or its features.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from reroom.layout.meshops import close_labels, open_labels
from reroom.synth.labels import LABELS

WALL = LABELS["wall"]
FLOOR = LABELS["floor"]
CEILING = LABELS["ceiling"]
DOOR = LABELS["door"]
WINDOW = LABELS["window"]
BASEBOARD = LABELS["baseboard"]
#: Not part of the room's shell or features (furniture, lights, clutter).
OTHER = 255
#: Every label the layout stage writes, name -> id.
LAYOUT_LABELS: dict[str, int] = {
    "wall": WALL,
    "floor": FLOOR,
    "ceiling": CEILING,
    "door": DOOR,
    "window": WINDOW,
    "baseboard": BASEBOARD,
    "other": OTHER,
}


def assign_walls(
    xyz: np.ndarray,
    normals: np.ndarray | None,
    walls: list[dict],
    tol: float,
    cos_min: float,
    z_range: tuple[float, float],
    front: float | None = None,
    back: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The wall each vertex lies on (or ``-1``) and its signed depth behind that wall.

    Parameters
    ----------
    xyz, normals:
        Aligned vertices and unit normals; ``normals=None`` skips the normal test.
    walls:
        ``start``, ``end`` (xy), ``inward_normal`` per wall (all rooms together).
    tol:
        Largest distance from the plane (both sides) unless ``front``/``back`` are given.
    cos_min:
        Smallest cosine between a vertex normal and the wall's inward normal.
    z_range:
        Heights a wall spans.
    front, back:
        Distances in front of (into the room) and behind the plane to accept instead of
        ``tol``.

    Returns
    -------
    wall, depth
        ``(V,)`` int wall index (-1: none) and ``(V,)`` depth behind the wall plane
        (positive behind, i.e. away from the room; NaN where no wall).
    """
    front = tol if front is None else front
    back = tol if back is None else back
    n = len(xyz)
    best = np.full(n, np.inf)
    wall = np.full(n, -1, np.int64)
    depth = np.full(n, np.nan)
    zin = (xyz[:, 2] >= z_range[0] - tol) & (xyz[:, 2] <= z_range[1] + tol)
    for k, w in enumerate(walls):
        a = np.asarray(w["start"], float)
        b = np.asarray(w["end"], float)
        nin = np.asarray(w["inward_normal"], float)
        length = float(np.linalg.norm(b - a))
        t = (b - a) / length
        rel = xyz[:, :2] - a
        along = rel @ t
        dist = -(rel @ nin)  # positive behind the wall
        ok = zin & (dist > -front) & (dist < back) & (along > -tol) & (along < length + tol)
        if normals is not None:
            ok &= normals[:, :2] @ nin > cos_min
        closer = ok & (np.abs(dist) < best)
        best[closer] = np.abs(dist[closer])
        wall[closer] = k
        depth[closer] = dist[closer]
    return wall, depth


def shell_labels(
    xyz: np.ndarray,
    normals: np.ndarray,
    floor_z: float,
    ceiling_z: float,
    walls: list[dict],
    footprint: np.ndarray | None,
    tol: float,
    max_angle_deg: float = 35.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Raw wall / floor / ceiling / other labels (before clean-up) and the wall index.

    ``footprint`` (``(V,)`` bool, optional) limits floor and ceiling to vertices above or
    below a room's polygon.
    """
    c = np.cos(np.radians(max_angle_deg))
    labels = np.full(len(xyz), OTHER, np.uint8)
    inside = np.ones(len(xyz), bool) if footprint is None else footprint
    floor = inside & (normals[:, 2] > c) & (np.abs(xyz[:, 2] - floor_z) < tol)
    ceiling = inside & (normals[:, 2] < -c) & (np.abs(xyz[:, 2] - ceiling_z) < tol)
    wall, _ = assign_walls(xyz, normals, walls, tol, c, (floor_z, ceiling_z))
    labels[wall >= 0] = WALL
    labels[floor] = FLOOR
    labels[ceiling] = CEILING
    return labels, wall


def clean_labels(
    labels: np.ndarray, adjacency: sp.csr_matrix, close_steps: int = 2, open_steps: int = 1
) -> np.ndarray:
    """Close wall, floor and ceiling along the mesh, then open them (drop specks)."""
    shell = (WALL, FLOOR, CEILING)
    out = close_labels(labels, adjacency, shell, OTHER, close_steps)
    if open_steps > 0:
        out = open_labels(out, adjacency, shell, OTHER, open_steps)
    return out
