"""The synthetic scanner's depth fusion against a box room whose planes are known."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import trimesh

from reroom.rays import RayCaster
from reroom.scan import Intrinsics, look_at
from reroom.scan.camera import Frame
from reroom.synth.scanner import fuse_depth_maps, kinect_noise, render_depth


def _box_room_depths(width: int = 200, height: int = 112, n: int = 40):
    """Noisy depth maps of a 6 x 4.5 x 2.7 m box room at round coordinates, from a loop."""
    box = trimesh.creation.box(extents=[6.0, 4.5, 2.7])
    box.apply_translation([3.0, 2.25, 1.35])
    box.invert()
    caster = RayCaster(np.asarray(box.vertices), np.asarray(box.faces))
    f = height / 2 / math.tan(math.radians(30.0))
    intr = Intrinsics(width=width, height=height, fx=f, fy=f, cx=width / 2, cy=height / 2)
    rng, noise = np.random.default_rng(0), np.random.default_rng(2)
    frames, depths = [], []
    for j in range(n):
        a = 2 * math.pi * j / n
        eye = np.array([3 + 0.5 * math.cos(a), 2.25 + 0.5 * math.sin(a), 1.5])
        ahead = np.array([math.cos(a + 1.0), math.sin(a + 1.0), rng.uniform(-0.6, 0.6)])
        frames.append(Frame(j, Path(), look_at(eye, eye + ahead), intr))
        depths.append(kinect_noise(render_depth(caster, frames[-1]), noise))
    return depths, frames, intr


def _planes(mesh: trimesh.Trimesh) -> dict[str, tuple[float, float]]:
    """Median offset (m) from the box's plane and median normal lean (deg) of each surface."""
    v, n = mesh.vertices, mesh.vertex_normals
    inner_xy = (v[:, 0] > 0.5) & (v[:, 0] < 5.5) & (v[:, 1] > 0.5) & (v[:, 1] < 4.0)
    mid_z = (v[:, 2] > 0.5) & (v[:, 2] < 2.2) & (v[:, 1] > 0.5) & (v[:, 1] < 4.0)
    out = {}
    for name, sel, axis, at in (
        ("floor", inner_xy & (v[:, 2] < 0.1), 2, 0.0),
        ("ceiling", inner_xy & (v[:, 2] > 2.6), 2, 2.7),
        ("wall", mid_z & (v[:, 0] < 0.1), 0, 0.0),
    ):
        lean = np.degrees(np.arccos(np.clip(np.abs(n[sel, axis]), 0.0, 1.0)))
        out[name] = (float(np.median(v[sel, axis]) - at), float(np.median(lean)))
    return out


def test_fused_planes_sit_on_the_truth_off_the_voxel_grid() -> None:
    """Fused at the default grid placement, every plane is where it is.

    With the grid unturned the walls (at multiples of the voxel) fall on layers of
    voxel centres: the fused wall flips between layers and its normals lean more.
    """
    depths, frames, intr = _box_room_depths()
    placed = _planes(fuse_depth_maps(depths, frames, intr))
    for name, (offset, _) in placed.items():
        assert abs(offset) < 0.002, (name, offset)
    # 6.0 against 8.7 deg here.
    unturned = _planes(fuse_depth_maps(depths, frames, intr, grid_yaw_deg=0.0))
    assert unturned["wall"][1] > placed["wall"][1] + 1.5
