"""Which way is up in a capture: the cameras' up axes refined by the mesh's horizontal and vertical surfaces."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

# --------------------------------------------------------------------------- up direction


@dataclass(frozen=True)
class UpEstimate:
    """The estimated up direction in the capture's world frame, and how it was found."""

    up: np.ndarray
    source: str
    camera_up: np.ndarray
    angle_to_camera_up_deg: float
    horizontal_area_fraction: float
    vertical_area_fraction: float

    def to_json(self) -> dict[str, Any]:
        return {
            "up_in_capture_world": [round(float(v), 6) for v in self.up],
            "camera_up_in_capture_world": [round(float(v), 6) for v in self.camera_up],
            "angle_to_camera_up_deg": round(self.angle_to_camera_up_deg, 3),
            "horizontal_area_fraction": round(self.horizontal_area_fraction, 4),
            "vertical_area_fraction": round(self.vertical_area_fraction, 4),
        }


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    c = float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


def estimate_up(
    poses_c2w_cv: np.ndarray,
    face_normals: np.ndarray | None = None,
    face_areas: np.ndarray | None = None,
    face_centers: np.ndarray | None = None,
    *,
    max_distance: float = 4.0,
    min_area_fraction: float = 0.02,
    max_correction_deg: float = 35.0,
) -> UpEstimate:
    """Estimate the world's up direction from camera poses and (optionally) mesh faces.

    1. Cameras are held roughly upright, so the mean of their "up" axes (-y in
       OpenCV axes) approximates up. Its roll error averages out, but a pitch
       shared by every frame (looking down at a table) does not: on slambook2
       it is 15 degrees off.
    2. Horizontal surfaces (floor, table tops, ceiling) are the largest family
       of parallel faces near that direction: a mean shift over the face
       normals (sign-folded towards the estimate, area-weighted) inside cones
       of 30, 20, 12, 8 and 5 degrees moves the estimate onto their mode.
    3. A final polish also asks vertical faces (walls, cupboard fronts) to be
       perpendicular: ``u`` maximises ``sum_h a (n.u)^2 - sum_v a (n.u)^2``.

    Only faces within ``max_distance`` metres of a camera centre take part
    when ``face_centers`` is given: far structured-light depth is quantised
    into fronto-parallel steps whose normals point back at the camera and
    would drag the estimate towards the cameras' own axes. The refinement is
    dropped (``source == "camera_up"``) when horizontal faces cover less than
    ``min_area_fraction`` of the face area in the widest cone, or when it
    would move the estimate more than ``max_correction_deg``.
    """
    poses = np.asarray(poses_c2w_cv, dtype=np.float64)
    cam_up = (-poses[:, :3, 1]).sum(axis=0)
    if np.linalg.norm(cam_up) < 1e-9:
        raise ValueError("camera up axes cancel out; cannot estimate the up direction")
    cam_up /= np.linalg.norm(cam_up)
    if face_normals is None or len(face_normals) == 0:
        return UpEstimate(cam_up, "camera_up", cam_up, 0.0, 0.0, 0.0)
    n = np.asarray(face_normals, dtype=np.float64)
    a = np.ones(len(n)) if face_areas is None else np.asarray(face_areas, dtype=np.float64)
    ok = np.isfinite(n).all(axis=1) & (np.linalg.norm(n, axis=1) > 0.5) & np.isfinite(a)
    if face_centers is not None:
        centers = np.asarray(face_centers, dtype=np.float64)
        from scipy.spatial import cKDTree

        dist, _ = cKDTree(poses[:, :3, 3]).query(centers)
        near = ok & (dist <= max_distance)
        # A capture of distant surfaces only: fall back to every face.
        if a[near].sum() >= 0.1 * a[ok].sum():
            ok = near
    n, a = n[ok], a[ok]
    total = float(a.sum())
    if total <= 0:
        return UpEstimate(cam_up, "camera_up", cam_up, 0.0, 0.0, 0.0)

    u = cam_up
    h_frac_wide = None
    for cone in (30.0, 20.0, 12.0, 8.0, 5.0):
        c = n @ u
        horiz = np.abs(c) > math.cos(math.radians(cone))
        frac = float(a[horiz].sum()) / total
        if h_frac_wide is None:
            h_frac_wide = frac
            if frac < min_area_fraction:
                return UpEstimate(cam_up, "camera_up", cam_up, 0.0, frac, 0.0)
        if not horiz.any():
            break
        folded = n[horiz] * np.sign(c[horiz])[:, None]
        new = (a[horiz, None] * folded).sum(axis=0)
        u = new / np.linalg.norm(new)

    v_frac = 0.0
    for cone in (8.0, 5.0):
        c = n @ u
        horiz = np.abs(c) > math.cos(math.radians(cone))
        vert = np.abs(c) < math.sin(math.radians(cone))
        v_frac = float(a[vert].sum()) / total
        nh = n[horiz] * np.sqrt(a[horiz])[:, None]
        nv = n[vert] * np.sqrt(a[vert])[:, None]
        _, evecs = np.linalg.eigh(nh.T @ nh - nv.T @ nv)
        new = evecs[:, -1]
        u = new * np.sign(np.dot(new, u)) / np.linalg.norm(new)

    h_frac = float(a[np.abs(n @ u) > math.cos(math.radians(5.0))].sum()) / total
    angle = _angle_deg(u, cam_up)
    if angle > max_correction_deg:
        return UpEstimate(cam_up, "camera_up", cam_up, 0.0, h_frac, v_frac)
    return UpEstimate(u, "camera_up+planes", cam_up, angle, h_frac, v_frac)


def world_alignment(up: np.ndarray, forward: np.ndarray | None = None) -> np.ndarray:
    """A 4x4 rotation taking ``up`` to +Z and, if given, ``forward``'s level part to +Y."""
    z = np.asarray(up, dtype=np.float64)
    z = z / np.linalg.norm(z)
    f = np.array([0.0, 1.0, 0.0]) if forward is None else np.asarray(forward, dtype=np.float64)
    y = f - np.dot(f, z) * z
    if np.linalg.norm(y) < 1e-6:  # forward parallel to up: any level direction will do
        y = np.cross(z, [1.0, 0.0, 0.0])
        if np.linalg.norm(y) < 1e-6:
            y = np.cross(z, [0.0, 1.0, 0.0])
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    out = np.eye(4)
    out[:3, :3] = np.stack([x, y, z])  # rows: the new axes in the old frame
    return out
