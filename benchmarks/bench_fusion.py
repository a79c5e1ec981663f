"""Where fused surfaces land: the fusion's pixel convention and its voxel grid's placement.

Two checks of ``reroom.importers.fusion.TsdfFusion`` (docs/benchmarks.md, session 49):

1. **slambook2** (real Kinect frames): the import fused with the intrinsics as given and
   with ``cx, cy`` shifted by -0.5 px (the code before session 49). For each frame the fused
   mesh's depth is ray-cast from the frame's pose and compared with the frame's measured
   depth (valid pixels under 4 m, differences under 10 cm): the median absolute difference
   and the signed median per third of the image (a half-pixel error shows as a bias that
   grows down the image, where the floor's depth changes fastest along the rows).
2. **A box room** (6 x 4.5 x 2.7 m at round coordinates, 60 Kinect-noisy frames at 320x180,
   3 cm voxels) fused with its grid placed several ways: vertices, and the floor's and
   a wall's normals' lean from their plane.

    python benchmarks/bench_fusion.py [--slambook DIR]
"""

from __future__ import annotations

import argparse
import math
import tempfile
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

import reroom.importers.fusion as fusion
from reroom.rays import RayCaster
from reroom.scan import Intrinsics, load_scan, look_at
from reroom.scan.camera import Frame
from reroom.synth.scanner import kinect_noise, render_depth

SLAMBOOK = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "slambook2_rgbd"


class _ShiftedFusion(fusion.TsdfFusion):
    """The fusion as before session 49: Open3D given ``cx - 0.5, cy - 0.5``."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        k = self._k.numpy().copy()
        k[:2, 2] -= 0.5
        self._k = self._o3c.Tensor(k, self._o3c.float64)


def slambook_depth_check(folder: Path) -> None:
    from reroom.importers import import_rgbd_folder, rgbd

    print(
        "| slambook2 fused | vertices | median abs difference | signed median top / middle / bottom |"
    )
    print("|---|---|---|---|")
    for name, cls in (
        ("intrinsics shifted -0.5 px (before)", _ShiftedFusion),
        ("as given (now)", fusion.TsdfFusion),
    ):
        rgbd.TsdfFusion = cls
        try:
            with tempfile.TemporaryDirectory() as tmp:
                scan = load_scan(import_rgbd_folder(folder, Path(tmp)))
                caster = RayCaster(np.asarray(scan.mesh.vertices), np.asarray(scan.mesh.faces))
                thirds: list[list[np.ndarray]] = [[], [], []]
                absolute = []
                for frame in scan.frames:
                    depth = frame.load_depth()
                    k = frame.intrinsics
                    origins, dirs = frame.pixel_rays()
                    hits = caster.intersect(origins, dirs)
                    rendered = np.where(hits.hit, hits.t * (dirs @ frame.forward), 0.0)
                    rendered = rendered.reshape(depth.shape)
                    diff = rendered - depth
                    ok = (depth > 0) & (depth < 4.0) & (rendered > 0) & (np.abs(diff) < 0.1)
                    absolute.append(np.abs(diff[ok]))
                    for j in range(3):
                        rows = slice(j * k.height // 3, (j + 1) * k.height // 3)
                        thirds[j].append(diff[rows][ok[rows]])
                signed = [1000 * np.median(np.concatenate(t)) for t in thirds]
                print(
                    f"| {name} | {len(scan.mesh.vertices)} | "
                    f"{1000 * np.median(np.concatenate(absolute)):.2f} mm | "
                    + " / ".join(f"{v:+.2f}" for v in signed)
                    + " mm |"
                )
        finally:
            rgbd.TsdfFusion = fusion.TsdfFusion


def _fuse_box(to_grid: np.ndarray, depths, frames, intr) -> trimesh.Trimesh:
    fus = fusion.TsdfFusion(intr, 0.03, 0.12, 8.0)
    grey = np.zeros((intr.height, intr.width, 3), np.uint8)
    for depth, frame in zip(depths, frames, strict=True):
        mm = np.round(depth * 1000.0).astype(np.uint16)
        fus.integrate(grey, mm, to_grid @ frame.c2w @ np.diag([1.0, -1.0, -1.0, 1.0]))
    om = fus.extract_mesh()
    om.remove_degenerate_triangles()
    om.remove_duplicated_vertices()
    v = (np.asarray(om.vertices) - to_grid[:3, 3]) @ to_grid[:3, :3]
    return trimesh.Trimesh(v, np.asarray(om.triangles), process=False)


def box_grid_table() -> None:
    box = trimesh.creation.box(extents=[6.0, 4.5, 2.7])
    box.apply_translation([3.0, 2.25, 1.35])
    box.invert()
    caster = RayCaster(np.asarray(box.vertices), np.asarray(box.faces))
    w, h = 320, 180
    f = h / 2 / math.tan(math.radians(30.0))
    intr = Intrinsics(width=w, height=h, fx=f, fy=f, cx=w / 2, cy=h / 2)
    rng, noise = np.random.default_rng(0), np.random.default_rng(2)
    frames, depths = [], []
    for j in range(60):
        a = 2 * math.pi * j / 60
        eye = np.array([3 + 0.5 * math.cos(a), 2.25 + 0.5 * math.sin(a), 1.5])
        ahead = np.array([math.cos(a + 1.0), math.sin(a + 1.0), rng.uniform(-0.6, 0.6)])
        frames.append(Frame(j, Path(), look_at(eye, eye + ahead), intr))
        depths.append(kinect_noise(render_depth(caster, frames[-1]), noise))
    print(
        "\n| box room grid placement | vertices | floor lean median / 90th pct | wall lean median | floor z |"
    )
    print("|---|---|---|---|---|")
    for name, euler, shift in (
        ("every plane on the grid", [0, 0, 0], [0, 0, 0]),
        ("shifted 2.5 mm", [0, 0, 0], [0.0025] * 3),
        ("shifted 5 mm", [0, 0, 0], [0.005] * 3),
        ("shifted 12.5 mm", [0, 0, 0], [0.0125] * 3),
        ("tilted 3 and 2 deg, turned 20 deg", [3, 2, 20], [0.011, 0.007, 0.013]),
        (
            "upright, turned 17 deg, raised half a voxel (the synthetic default)",
            [0, 0, 17],
            [0, 0, 0.015],
        ),
    ):
        to_grid = np.eye(4)
        to_grid[:3, :3] = Rotation.from_euler("xyz", euler, degrees=True).as_matrix()
        to_grid[:3, 3] = shift
        mesh = _fuse_box(to_grid, depths, frames, intr)
        v, n = mesh.vertices, mesh.vertex_normals
        inner = (v[:, 1] > 0.5) & (v[:, 1] < 4.0)
        floor = inner & (v[:, 2] < 0.1) & (v[:, 0] > 0.5) & (v[:, 0] < 5.5)
        wall = inner & (v[:, 0] < 0.1) & (v[:, 2] > 0.5) & (v[:, 2] < 2.2)
        lean_f = np.degrees(np.arccos(np.clip(np.abs(n[floor, 2]), 0, 1)))
        lean_w = np.degrees(np.arccos(np.clip(np.abs(n[wall, 0]), 0, 1)))
        print(
            f"| {name} | {len(v)} | {np.median(lean_f):.2f} / {np.percentile(lean_f, 90):.2f} deg | "
            f"{np.median(lean_w):.2f} deg | {1000 * np.median(v[floor, 2]):+.1f} mm |"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--slambook", type=Path, default=SLAMBOOK)
    a = ap.parse_args()
    if (a.slambook / "pose.txt").is_file():
        slambook_depth_check(a.slambook)
    else:
        print(f"slambook2 frames not found at {a.slambook}: its check skipped")
    box_grid_table()


if __name__ == "__main__":
    main()
