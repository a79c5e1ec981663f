"""Shared fixtures: a small valid scan written with reroom's own writer."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from reroom.scan import Intrinsics, look_at, write_scan


def make_scan(
    root: Path, n_frames: int = 3, width: int = 32, height: int = 24, depth: bool = False
) -> Path:
    """Write a tiny valid scan (a box mesh, gradient frames) and return its folder."""
    mesh = trimesh.creation.box(extents=[4.0, 3.0, 2.5])
    mesh.apply_translation([0, 0, 1.25])
    intr = Intrinsics.from_fov(width, height, 60.0)
    poses = [look_at([0.2 * i, 0.0, 1.5], [2.0, 0.5, 1.2]) for i in range(n_frames)]
    rng = np.random.default_rng(0)
    images = [rng.integers(0, 256, (height, width, 3), dtype=np.uint8) for _ in range(n_frames)]
    depths = [np.full((height, width), 2.0) for _ in range(n_frames)] if depth else None
    write_scan(root, mesh, intr, poses, images, depths=depths)
    return root


@pytest.fixture
def small_scan(tmp_path: Path) -> Path:
    return make_scan(tmp_path / "scan")
