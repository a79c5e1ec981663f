"""RGB-D import: readers, a synthetic box room with exact answers, the real slambook2 frames."""

from __future__ import annotations

import json
import math
import os
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from reroom.errors import ScanError
from reroom.importers import (
    estimate_up,
    import_rgbd,
    import_rgbd_folder,
    read_depth,
    read_intrinsics,
    read_pose_file,
    white_border_mask,
)
from reroom.importers.rgbd import read_depth_raw, world_alignment
from reroom.scan import Frame, Intrinsics, load_scan

SLAMBOOK = Path(
    os.environ.get(
        "REROOM_SLAMBOOK2_RGBD",
        Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "slambook2_rgbd",
    )
)
needs_slambook = pytest.mark.skipif(
    not (SLAMBOOK / "pose.txt").is_file(), reason=f"slambook2 frames not found at {SLAMBOOK}"
)
CV = np.diag([1.0, -1.0, -1.0, 1.0])


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    c = float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


def rot(axis: str, deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    m = np.eye(3)
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


def quat_xyzw(r: np.ndarray) -> np.ndarray:
    """Quaternion (x, y, z, w) of a rotation matrix."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(r).as_quat()


# --------------------------------------------------------------------------- synthetic room

ROOM = np.array([4.0, 3.0, 2.5])  # box [0, 4] x [0, 3] x [0, 2.5] in the true world, +Z up
SYN_INTR = Intrinsics(width=160, height=120, fx=100.0, fy=100.0, cx=80.0, cy=60.0)
# The capture's world frame: y down, z forward, origin somewhere in the room (like slambook2).
CAPTURE_FROM_TRUE = np.eye(4)
CAPTURE_FROM_TRUE[:3, :3] = rot("y", 25.0) @ np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
CAPTURE_FROM_TRUE[:3, 3] = [0.3, 1.2, -0.7]


def camera_true(eye, yaw_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
    """OpenCV camera-to-world in the true (Z-up) world: yaw 0 looks along +Y."""
    # Base: OpenCV axes with x right (+X), y down (-Z), z forward (+Y).
    base = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])
    r = rot("z", yaw_deg) @ base @ rot("x", -pitch_deg) @ rot("z", roll_deg)
    m = np.eye(4)
    m[:3, :3] = r
    m[:3, 3] = eye
    return m


TRUE_CAMS = [
    camera_true([2.0, 0.6, 1.5], 0.0, 15.0, 2.0),  # looks along +Y, pitched down 15 degrees
    camera_true([2.1, 0.8, 1.5], 25.0, 14.0, -2.0),
    camera_true([2.2, 1.1, 1.45], 55.0, 16.0, 1.0),
    camera_true([2.2, 1.4, 1.5], 95.0, 15.0, 0.0),
    camera_true([2.0, 1.6, 1.55], 140.0, 13.0, -1.0),
    camera_true([1.8, 1.7, 1.5], 185.0, 15.0, 2.0),
    camera_true([1.7, 1.5, 1.5], 230.0, 17.0, 0.0),
    camera_true([1.7, 1.1, 1.5], 280.0, 15.0, -2.0),
    camera_true([1.8, 0.8, 1.5], 325.0, 20.0, 1.0),
    camera_true([1.9, 0.9, 1.4], 10.0, -35.0, 0.0),  # two looking up, for the ceiling
    camera_true([2.0, 1.6, 1.4], 190.0, -35.0, 1.0),
]


def wall_colour(points: np.ndarray) -> np.ndarray:
    """A colour per box face, modulated by a 0.5 m checkerboard (uint8)."""
    base = np.array(
        [
            [200, 60, 60],
            [60, 200, 60],
            [60, 60, 200],
            [200, 200, 60],
            [160, 160, 160],
            [90, 60, 40],
        ],
        dtype=np.float64,
    )
    d = np.stack([points[:, 0], ROOM[0] - points[:, 0], points[:, 1], ROOM[1] - points[:, 1]], 1)
    d = np.concatenate([d, points[:, 2:3], ROOM[2] - points[:, 2:3]], axis=1)
    face = np.argmin(np.abs(d), axis=1)  # 0 x=0, 1 x=X, 2 y=0, 3 y=Y, 4 floor, 5 ceiling
    check = (np.floor(points / 0.5).astype(int).sum(axis=1) % 2).astype(np.float64)
    return np.clip(base[face] * (0.75 + 0.25 * check)[:, None], 0, 255).astype(np.uint8)


def render_box(c2w_cv_true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact depth (metres along the optical axis) and colour of the box room's inside."""
    k = SYN_INTR
    jj, ii = np.meshgrid(np.arange(k.width) + 0.5, np.arange(k.height) + 0.5)
    d_cam = np.stack([(jj - k.cx) / k.fx, (ii - k.cy) / k.fy, np.ones_like(jj)], -1).reshape(-1, 3)
    d = d_cam @ c2w_cv_true[:3, :3].T
    o = c2w_cv_true[:3, 3]
    with np.errstate(divide="ignore"):
        t_hi = np.where(d > 0, (ROOM - o) / d, np.inf)
        t_lo = np.where(d < 0, (0.0 - o) / d, np.inf)
    t = np.minimum(t_hi, t_lo).min(axis=1)  # z-depth, since d_cam has z = 1
    points = o + t[:, None] * d
    depth = t.reshape(k.height, k.width)
    colour = wall_colour(points).reshape(k.height, k.width, 3)
    return depth, colour


def write_pgm16(path: Path, mm: np.ndarray) -> None:
    h, w = mm.shape
    path.write_bytes(f"P5 {w} {h} 65535\n".encode() + mm.astype(">u2").tobytes())


def make_synthetic(folder: Path, *, border: int = 0, garbage_border_depth: float = 0.0) -> Path:
    """Write the box room as a slambook2-style folder (capture world: y down)."""
    (folder / "color").mkdir(parents=True)
    (folder / "depth").mkdir()
    lines = []
    for i, cam in enumerate(TRUE_CAMS, start=1):
        depth, colour = render_box(cam)
        if border:
            colour[:border], colour[-border:] = 255, 255
            colour[:, :border], colour[:, -border:] = 255, 255
            if garbage_border_depth:
                edge = np.zeros(depth.shape, bool)
                edge[:border], edge[-border:], edge[:, :border], edge[:, -border:] = 1, 1, 1, 1
                depth[edge] = garbage_border_depth
        Image.fromarray(colour).save(folder / "color" / f"{i}.png")
        write_pgm16(folder / "depth" / f"{i}.pgm", np.round(depth * 1000.0).astype(np.uint16))
        cap = CAPTURE_FROM_TRUE @ cam
        q = quat_xyzw(cap[:3, :3])
        lines.append(" ".join(f"{v:.9f}" for v in (*cap[:3, 3], *q)))
    (folder / "pose.txt").write_text("\n".join(lines))  # no trailing newline, like slambook2
    k = SYN_INTR
    (folder / "intrinsics.json").write_text(
        json.dumps(
            {
                "width": k.width,
                "height": k.height,
                "fx": k.fx,
                "fy": k.fy,
                "cx": k.cx - 0.5,  # OpenCV convention in the file
                "cy": k.cy - 0.5,
                "distortion": None,
                "depth_scale": 1000.0,
            }
        )
    )
    return folder


@pytest.fixture(scope="module")
def synthetic_scan(tmp_path_factory):
    src = make_synthetic(
        tmp_path_factory.mktemp("box") / "rgbd", border=4, garbage_border_depth=0.6
    )
    calls = []
    out = import_rgbd_folder(
        src,
        tmp_path_factory.mktemp("box_scan"),
        voxel_size=0.04,
        depth_trunc=8.0,
        progress=lambda done, total: calls.append((done, total)),
    )
    return src, load_scan(out), calls


def test_synthetic_room_box_and_up(synthetic_scan):
    _, scan, calls = synthetic_scan
    voxel = 0.04
    v = scan.mesh.vertices
    extent = v.max(axis=0) - v.min(axis=0)
    # First camera looks along the room's +Y, so the room comes out axis-aligned.
    assert np.all(np.abs(extent - ROOM) < 2 * voxel), extent
    # +Z is up: floor faces at the bottom face up, and every vertex lies on a wall of the box.
    lo = v.min(axis=0)
    local = v - lo
    dist = np.min(
        np.abs(np.concatenate([local, ROOM - local], axis=1)), axis=1
    )  # distance to the nearest face of the box
    assert np.percentile(dist, 99.5) < 2 * voxel  # the white border's fake depth was masked
    floor = scan.mesh.triangles_center[:, 2] < lo[2] + 0.05
    n_floor = (scan.mesh.face_normals[floor] * scan.mesh.area_faces[floor, None]).sum(axis=0)
    assert angle_deg(n_floor, [0, 0, 1]) < 1.0
    meta = scan.meta["reroom"]
    assert meta["source"] == "rgbd-import"
    assert meta["up_estimated_from"] == "camera_up+planes"
    # Cameras all around the room: their tilts cancel and camera-up alone is already close
    # (test_estimate_up_planes_fix_shared_pitch covers a capture where they do not).
    assert meta["up"]["angle_to_camera_up_deg"] < 5.0
    up_true_in_capture = CAPTURE_FROM_TRUE[:3, :3] @ [0.0, 0.0, 1.0]
    assert angle_deg(np.array(meta["up"]["up_in_capture_world"]), up_true_in_capture) < 0.5
    assert meta["tsdf"]["voxel_size"] == voxel
    assert calls[-1][0] == calls[-1][1] == len(TRUE_CAMS) + 3
    assert [c[0] for c in calls] == list(range(1, len(calls) + 1))
    # Exact poses survive ICP refinement.
    for rec in meta["pose_refinement"]["frames"]:
        assert rec["change_from_given_m"] < 0.01 and rec["change_from_given_deg"] < 0.3


def test_synthetic_poses_round_trip(synthetic_scan):
    _, scan, _ = synthetic_scan
    a = np.array(scan.meta["reroom"]["world_from_capture"])
    world_from_true = a @ CAPTURE_FROM_TRUE
    assert np.allclose(world_from_true[:3, :3].T @ world_from_true[:3, :3], np.eye(3), atol=1e-6)
    corners = np.array([[0.0, 0.0, 0.0], [4.0, 3.0, 0.0], [4.0, 3.0, 2.5], [0.0, 3.0, 2.5]])
    for frame, cam in zip(scan.frames, TRUE_CAMS, strict=True):
        # Pose conversion: OpenCV camera-to-world in the capture -> OpenGL in the reroom world.
        expect = world_from_true @ cam @ CV
        # ICP on voxel-thinned clouds leaves the exact poses within a few mm and 0.1 deg.
        assert np.allclose(frame.c2w, expect, atol=5e-3), frame.index
        # Project a room corner with Frame.project and with the true camera.
        pts = corners @ world_from_true[:3, :3].T + world_from_true[:3, 3]
        uv, z, inside = frame.project(pts)
        pc = (corners - cam[:3, 3]) @ cam[:3, :3]  # true camera, OpenCV axes
        k = SYN_INTR
        uv_true = np.stack(
            [k.fx * pc[:, 0] / pc[:, 2] + k.cx, k.fy * pc[:, 1] / pc[:, 2] + k.cy], 1
        )
        seen = (pc[:, 2] > 0.1) & (np.abs(uv_true - [k.cx, k.cy]) < [k.cx, k.cy]).all(axis=1)
        assert np.allclose(uv[seen], uv_true[seen], atol=0.5)
        assert np.array_equal(inside, seen)
        assert np.allclose(z, pc[:, 2], atol=5e-3)
    # Mesh vertices seen by frame 0 have the depth frame 0 measured at their pixel.
    frame = scan.frames[0]
    depth = frame.load_depth()
    uv, z, inside = frame.project(scan.mesh.vertices)
    ij = np.floor(uv[inside]).astype(int)
    measured = depth[ij[:, 1], ij[:, 0]]
    ok = measured > 0
    assert ok.mean() > 0.7  # the rest falls in the masked border
    assert np.median(np.abs(measured[ok] - z[inside][ok])) < 0.01


def test_synthetic_scan_keeps_depth_and_colour(synthetic_scan):
    src, scan, _ = synthetic_scan
    frame = scan.frames[2]
    depth = frame.load_depth()
    raw = read_depth(src / "depth" / "3.pgm")
    border = white_border_mask(np.asarray(Image.open(src / "color" / "3.png")))
    assert np.array_equal(depth[border], np.zeros(border.sum()))  # the border was masked
    assert np.allclose(depth[~border], raw[~border], atol=1e-5)
    image = frame.load_image()
    assert np.array_equal(image, np.asarray(Image.open(src / "color" / "3.png")))
    colour = scan.mesh.vertex_attributes["color"]
    assert colour.dtype == np.uint8 and colour.shape == (len(scan.mesh.vertices), 3)
    # Floor vertices carry the floor's grey, not the walls' saturated colours.
    floor = scan.mesh.vertices[:, 2] < scan.mesh.vertices[:, 2].min() + 0.02
    spread = colour[floor].astype(int).max(axis=1) - colour[floor].astype(int).min(axis=1)
    assert np.median(spread) < 25


def test_refinement_off_keeps_given_poses(tmp_path):
    src = make_synthetic(tmp_path / "rgbd")
    poses = read_pose_file(src / "pose.txt")[:3]
    k, _ = read_intrinsics(src / "intrinsics.json")
    out = import_rgbd(
        [src / "color" / f"{i}.png" for i in (1, 2, 3)],
        [src / "depth" / f"{i}.pgm" for i in (1, 2, 3)],
        k,
        poses,
        tmp_path / "scan",
        voxel_size=0.08,
        refine_poses=False,
        mask_white_border=False,
    )
    scan = load_scan(out)
    a = np.array(scan.meta["reroom"]["world_from_capture"])
    for frame, pose in zip(scan.frames, poses, strict=True):
        assert np.allclose(frame.c2w, a @ pose @ CV, atol=1e-6)
    assert scan.meta["reroom"]["pose_refinement"] is None


# --------------------------------------------------------------------------- readers


def test_read_pose_file_layouts(tmp_path):
    r = rot("z", 30.0) @ rot("x", 10.0)
    t = np.array([0.5, -1.0, 2.0])
    q = quat_xyzw(r)
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = r, t
    rows = [" ".join(f"{x:.12f}" for x in row) for row in m]
    files = {
        "q.txt": f"# tx ty tz qx qy qz qw\n{' '.join(f'{x:.12f}' for x in (*t, *q))}",
        "tum.txt": f"1305031102.175304 {' '.join(f'{x:.12f}' for x in (*t, *q))}\n",
        "kitti.txt": " ".join(f"{x:.12f}" for x in m[:3].ravel()),
        "m16.txt": " ".join(f"{x:.12f}" for x in m.ravel()) + "\n",
        "m4.txt": "\n".join(rows) + "\n\n" + "\n".join(rows),
    }
    for name, text in files.items():
        (tmp_path / name).write_text(text)
        poses = read_pose_file(tmp_path / name)
        assert poses.shape == ((2 if name == "m4.txt" else 1), 4, 4), name
        assert np.allclose(poses[0], m, atol=1e-9), name


def test_read_pose_file_errors(tmp_path):
    p = tmp_path / "pose.txt"
    p.write_text("0 0 0 0 0 0 1\n0 0 0 0 0 0 1\n0 nan 0 0 0 0 1")
    with pytest.raises(ScanError, match="line 3.*non-finite") as err:
        read_pose_file(p)
    assert err.value.path == p
    p.write_text("0 0 0 0 0 0 1\n0 0 0 0 0 1")
    with pytest.raises(ScanError, match="line 2: 6 numbers"):
        read_pose_file(p)
    p.write_text("0 0 0 0 0 0 2")
    with pytest.raises(ScanError, match="line 1.*length 2"):
        read_pose_file(p)
    p.write_text("0 0 0 0 0 0 1.01")
    with pytest.warns(RuntimeWarning, match="normalised"):
        poses = read_pose_file(p)
    assert np.allclose(poses[0], np.eye(4))
    p.write_text("0 0 0 0 0 0 1.0000001")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_pose_file(p)
    p.write_text(" ".join(["2"] + ["0"] * 15))  # a scale, not a rotation
    with pytest.raises(ScanError, match="line 1"):
        read_pose_file(p)
    p.write_text("\n".join(["1 0 0 0"] * 3))
    with pytest.raises(ScanError, match="multiple of 4"):
        read_pose_file(p)
    p.write_text("1 2 3 x 5 6 7")
    with pytest.raises(ScanError, match="line 1: not a list of numbers"):
        read_pose_file(p)
    with pytest.raises(ScanError, match="missing"):
        read_pose_file(tmp_path / "nope.txt")


def test_read_depth_png_and_pgm(tmp_path):
    mm = np.array([[0, 1, 256, 65535], [1234, 4321, 9823, 713]], dtype=np.uint16)
    write_pgm16(tmp_path / "d.pgm", mm)
    Image.fromarray(mm).save(tmp_path / "d.png")
    for name in ("d.pgm", "d.png"):
        assert np.array_equal(read_depth_raw(tmp_path / name), mm)
        assert np.allclose(read_depth(tmp_path / name), mm / 1000.0)
    assert np.allclose(read_depth(tmp_path / "d.png", 5000.0), mm / 5000.0)
    # Pillow reads 16-bit PGM big-endian as well (mode "I"): both readers agree.
    assert np.array_equal(np.asarray(Image.open(tmp_path / "d.pgm")), mm.astype(np.int32))
    Image.fromarray(np.zeros((4, 4), np.uint8)).save(tmp_path / "d8.png")
    with pytest.raises(ScanError, match="16-bit"):
        read_depth(tmp_path / "d8.png")
    (tmp_path / "t.pgm").write_bytes(b"P5 4 2 65535\n" + b"\0" * 7)
    with pytest.raises(ScanError, match="truncated"):
        read_depth(tmp_path / "t.pgm")


def test_white_border_mask():
    img = np.full((60, 80, 3), 120, np.uint8)
    img[:5], img[-6:], img[:, :4], img[:, -7:] = 255, 255, 255, 255
    img[20:30, 30:50] = 255  # a bright window inside: not a border
    mask = white_border_mask(img, pad=1)
    assert mask[:6].all() and mask[-7:].all() and mask[:, :5].all() and mask[:, -8:].all()
    assert not mask[7:-8, 6:-9].any()
    assert not white_border_mask(np.full((10, 10, 3), 100, np.uint8)).any()


def test_estimate_up_planes_fix_shared_pitch():
    up_true = np.array([0.0, 0.0, 1.0])
    cams = np.stack([camera_true([0, 0, 1.5], yaw, 15.0, 0.0) for yaw in (0, 20, 40)])
    rng = np.random.default_rng(1)
    floor = np.tile(up_true, (400, 1)) + rng.normal(0, 0.05, (400, 3))
    walls = np.concatenate([np.tile([[1.0, 0, 0]], (300, 1)), np.tile([[0, -1.0, 0]], (300, 1))])
    normals = np.concatenate([floor, walls + rng.normal(0, 0.05, walls.shape)])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    cam_only = estimate_up(cams)
    assert cam_only.source == "camera_up" and 10 < angle_deg(cam_only.up, up_true) < 20
    est = estimate_up(cams, normals, np.ones(len(normals)))
    assert est.source == "camera_up+planes"
    assert angle_deg(est.up, up_true) < 1.0
    align = world_alignment(est.up, cams[0][:3, 2])
    assert np.allclose(align[:3, :3] @ est.up, [0, 0, 1])
    assert np.linalg.det(align[:3, :3]) == pytest.approx(1.0)


# --------------------------------------------------------------------------- bad input


@pytest.fixture
def small_rgbd(tmp_path):
    src = make_synthetic(tmp_path / "rgbd")
    for i in range(4, len(TRUE_CAMS) + 1):  # three frames are enough to fail on
        (src / "color" / f"{i}.png").unlink()
        (src / "depth" / f"{i}.pgm").unlink()
    lines = (src / "pose.txt").read_text().splitlines()[:3]
    (src / "pose.txt").write_text("\n".join(lines))
    return src


def test_bad_input_missing_depth(small_rgbd, tmp_path):
    (small_rgbd / "depth" / "2.pgm").unlink()
    with pytest.raises(ScanError, match="depth file is missing") as err:
        import_rgbd_folder(small_rgbd, tmp_path / "out")
    assert err.value.path.name == "2.pgm"
    colors = [small_rgbd / "color" / f"{i}.png" for i in (1, 2, 3)]
    depths = [small_rgbd / "depth" / f"{i}.pgm" for i in (1, 2, 3)]
    with pytest.raises(ScanError, match="depth file is missing") as err:
        import_rgbd(
            colors, depths, small_rgbd / "intrinsics.json", small_rgbd / "pose.txt", tmp_path / "o"
        )
    assert err.value.path == depths[1]
    assert not (tmp_path / "o" / "transforms.json").exists()


def test_bad_input_nan_pose(small_rgbd, tmp_path):
    lines = (small_rgbd / "pose.txt").read_text().splitlines()
    lines[1] = "0.1 NaN 0.3 0 0 0 1"
    (small_rgbd / "pose.txt").write_text("\n".join(lines))
    with pytest.raises(ScanError, match="line 2") as err:
        import_rgbd_folder(small_rgbd, tmp_path / "out")
    assert err.value.path == small_rgbd / "pose.txt"


def test_bad_input_pose_count(small_rgbd, tmp_path):
    lines = (small_rgbd / "pose.txt").read_text().splitlines()
    (small_rgbd / "pose.txt").write_text("\n".join(lines[:2]))
    with pytest.raises(ScanError, match="2 poses for 3 frames") as err:
        import_rgbd_folder(small_rgbd, tmp_path / "out")
    assert err.value.path == small_rgbd / "pose.txt"


def test_bad_input_depth_size(small_rgbd, tmp_path):
    write_pgm16(small_rgbd / "depth" / "3.pgm", np.zeros((60, 80), np.uint16))
    with pytest.raises(ScanError, match="depth map is 80x60 but its colour image") as err:
        import_rgbd_folder(small_rgbd, tmp_path / "out")
    assert err.value.path == small_rgbd / "depth" / "3.pgm"


def test_bad_input_colour_size_and_intrinsics(small_rgbd, tmp_path):
    Image.fromarray(np.zeros((10, 10, 3), np.uint8)).save(small_rgbd / "color" / "1.png")
    with pytest.raises(ScanError, match="10x10 but the intrinsics say 160x120") as err:
        import_rgbd_folder(small_rgbd, tmp_path / "out")
    assert err.value.path.name == "1.png"
    (small_rgbd / "intrinsics.json").write_text(json.dumps({"width": 160, "height": 120}))
    with pytest.raises(ScanError, match="lacks 'fx'"):
        read_intrinsics(small_rgbd / "intrinsics.json")


def test_folder_sorts_frames_numerically(small_rgbd, tmp_path):
    from reroom.importers import find_rgbd_folder

    for name in ("color", "depth"):
        ext = ".png" if name == "color" else ".pgm"
        shutil.copy(small_rgbd / name / f"3{ext}", small_rgbd / name / f"10{ext}")
    colors, depths, _, _ = find_rgbd_folder(small_rgbd)
    assert [p.stem for p in colors] == ["1", "2", "3", "10"]
    assert [p.stem for p in depths] == ["1", "2", "3", "10"]


# --------------------------------------------------------------------------- real data


@pytest.fixture(scope="module")
def slambook_scan(tmp_path_factory):
    out = import_rgbd_folder(SLAMBOOK, tmp_path_factory.mktemp("slambook2"))
    return load_scan(out)


@needs_slambook
def test_slambook2_data_as_documented():
    intr, scale = read_intrinsics(SLAMBOOK / "intrinsics.json")
    assert (intr.width, intr.height, intr.fx, intr.fy) == (640, 480, 518.0, 519.0)
    assert (intr.cx, intr.cy) == (326.0, 254.0)  # 325.5, 253.5 with integer pixel centres
    assert scale == 1000.0
    lo, hi = np.inf, 0.0
    for i in range(1, 6):
        d = read_depth(SLAMBOOK / "depth" / f"{i}.pgm", scale)
        valid = d > 0
        assert 0.68 <= valid.mean() <= 0.73
        lo, hi = min(lo, d[valid].min()), max(hi, d.max())
    assert 0.70 <= lo <= 0.72 and 9.7 <= hi <= 9.9
    poses = read_pose_file(SLAMBOOK / "pose.txt")
    assert poses.shape == (5, 4, 4)


@needs_slambook
def test_slambook2_import(slambook_scan):
    scan = slambook_scan
    assert len(scan) == 5
    assert 20_000 < len(scan.mesh.vertices) < 600_000
    meta = scan.meta["reroom"]
    assert meta["up_estimated_from"] == "camera_up+planes"
    assert all(f["status"] in ("first", "refined") for f in meta["pose_refinement"]["frames"])
    assert all(f["change_from_given_m"] < 0.15 for f in meta["pose_refinement"]["frames"])
    # Horizontal surfaces (floor, table top) face +Z: their normals' mode is within a few degrees.
    n, a = scan.mesh.face_normals, scan.mesh.area_faces
    near = np.abs(n[:, 2]) > math.cos(math.radians(20))
    mode = (n[near] * np.sign(n[near, 2])[:, None] * a[near, None]).sum(axis=0)
    assert angle_deg(mode, [0, 0, 1]) < 5.0
    # The floor is below the cameras and faces up (seen from above).
    cam_z = np.mean([f.center[2] for f in scan.frames])
    floor = near & (scan.mesh.triangles_center[:, 2] < cam_z - 1.0)
    assert a[floor].sum() > 1.0  # square metres
    assert (a[floor] * (n[floor, 2] > 0)).sum() > 0.9 * a[floor].sum()
    # Cameras stand roughly upright in the new world.
    for f in scan.frames:
        assert angle_deg(f.c2w[:3, 1], [0, 0, 1]) < 30.0


@needs_slambook
def test_slambook2_frames_reproject_onto_mesh(slambook_scan):
    from scipy.spatial import cKDTree

    scan = slambook_scan
    tree = cKDTree(scan.mesh.vertices)
    for frame in scan.frames:
        depth = frame.load_depth()
        k = frame.intrinsics
        v, u = np.nonzero((depth > 0) & (depth < 4.0))
        v, u = v[::9], u[::9]
        z = depth[v, u]
        p_cv = np.stack([(u + 0.5 - k.cx) * z / k.fx, (v + 0.5 - k.cy) * z / k.fy, z], axis=1)
        p = (p_cv * [1.0, -1.0, -1.0]) @ frame.c2w[:3, :3].T + frame.c2w[:3, 3]
        dist, _ = tree.query(p)
        assert np.median(dist) < 0.03, frame.index
        assert (dist < 0.05).mean() > 0.85, frame.index
        # And the frame's image is the one imported (the white border included).
        img = frame.load_image()
        assert img.shape == (480, 640, 3) and (img[:3] == 255).all()


@needs_slambook
def test_slambook2_fused_mesh_meets_each_frames_depth(slambook_scan):
    """The fused mesh's depth, rendered from each frame's pose, against the frame's own.

    A half-pixel error in the fusion's projection shows as a bias that grows down
    the image (the floor: the depth changes fastest along the rows there). With the
    intrinsics shifted by -0.5 px the top, middle and bottom thirds read -2.1, +0.6
    and +3.7 mm; as given, 0.0, 0.0 and +1.0 mm.
    """
    from reroom.rays import RayCaster

    scan = slambook_scan
    caster = RayCaster(np.asarray(scan.mesh.vertices), np.asarray(scan.mesh.faces))
    thirds: list[list[np.ndarray]] = [[], [], []]
    for frame in scan.frames:
        depth = frame.load_depth()
        k = frame.intrinsics
        origins, dirs = frame.pixel_rays()
        hits = caster.intersect(origins, dirs)
        rendered = np.where(hits.hit, hits.t * (dirs @ frame.forward), 0.0)
        diff = (rendered.reshape(k.height, k.width) - depth).astype(float)
        ok = (depth > 0) & (depth < 4.0) & (rendered.reshape(depth.shape) > 0)
        ok &= np.abs(diff) < 0.1
        for j in range(3):
            rows = slice(j * k.height // 3, (j + 1) * k.height // 3)
            thirds[j].append(diff[rows][ok[rows]])
    for j, parts in enumerate(thirds):
        assert abs(np.median(np.concatenate(parts))) < 0.0015, j


def test_frame_project_matches_camera_model():
    """Frame.project with the converted pose equals the OpenCV pinhole projection."""
    cam = TRUE_CAMS[3]
    frame = Frame(0, Path("x.png"), cam @ CV, SYN_INTR)
    pts = np.array([[3.9, 2.0, 1.0], [2.5, 2.9, 0.3]])
    uv, z, _ = frame.project(pts)
    pc = (pts - cam[:3, 3]) @ cam[:3, :3]
    assert np.allclose(z, pc[:, 2])
    assert np.allclose(uv[:, 0], SYN_INTR.fx * pc[:, 0] / pc[:, 2] + SYN_INTR.cx)


def test_preview_renders_what_the_camera_saw(synthetic_scan, tmp_path):
    """The preview from frame 0's own pose matches frame 0's image (camera conventions)."""
    from reroom.importers.preview import overview_camera, render_mesh_preview

    src, scan, _ = synthetic_scan
    frame = scan.frames[0]
    path = render_mesh_preview(scan.mesh, frame.c2w, frame.intrinsics, tmp_path / "p.png", spp=4)
    img = np.asarray(Image.open(path)).astype(np.float64)
    ref = frame.load_image().astype(np.float64)
    assert img.shape == ref.shape
    inner = (slice(10, -10), slice(10, -10))  # away from the masked border
    chroma = img / np.maximum(img.sum(-1, keepdims=True), 1.0)
    chroma_ref = ref / np.maximum(ref.sum(-1, keepdims=True), 1.0)
    diff = np.abs(chroma - chroma_ref)[inner].max(axis=-1)
    assert np.median(diff) < 0.03
    assert (diff < 0.1).mean() > 0.9
    # A closed room seen from inside has no background showing (headlight shading).
    assert (img[inner].max(axis=-1) < 250).all()
    cam = overview_camera(frame.c2w, scan.mesh)
    assert np.allclose(cam[:3, :3].T @ cam[:3, :3], np.eye(3), atol=1e-9)


@pytest.mark.parametrize("offset", [(0.0, 0.0), (17.0, -11.0)])
def test_preview_camera_model(offset):
    """A small square lands where Frame.project puts it, off-centre principal point included."""
    import trimesh

    from reroom.importers.preview import render_mesh_image
    from reroom.scan import look_at

    k = Intrinsics(width=96, height=72, fx=80.0, fy=80.0, cx=48.0 + offset[0], cy=36.0 + offset[1])
    c2w = look_at(np.array([0.3, -0.2, 1.4]), np.array([1.0, 3.0, 1.0]))
    frame = Frame(0, Path("x.png"), c2w, k)
    centre = np.array([1.6, 2.8, 1.7])
    right, up = c2w[:3, 0], c2w[:3, 1]
    corners = np.array(
        [centre + 0.08 * (sx * right + sy * up) for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    )
    square = trimesh.Trimesh(corners, [[0, 1, 2], [0, 2, 3]], process=False)
    square.vertex_attributes["color"] = np.full((4, 3), 200, np.uint8)
    img = render_mesh_image(square, c2w, k, spp=16, background=(0.0, 0.0, 0.0))
    w = img.astype(np.float64).sum(axis=-1)
    ii, jj = np.mgrid[0 : k.height, 0 : k.width] + 0.5
    got = np.array([(w * jj).sum(), (w * ii).sum()]) / w.sum()
    (expect,), _, (inside,) = frame.project(centre[None])
    assert inside
    assert np.allclose(got, expect, atol=0.5), (got, expect)


def test_canonical_order_depends_only_on_the_geometry() -> None:
    """Open3D lists a fusion's vertices in a thread-dependent order; the canonical order
    is the same for any permutation of the vertices and faces, and keeps each face's
    winding (its vertices, in cyclic order)."""
    from reroom.importers.fusion import canonical_order

    rng = np.random.default_rng(31)
    verts = rng.normal(size=(200, 3))
    faces = np.array([rng.choice(200, 3, replace=False) for _ in range(300)])
    order, f0 = canonical_order(verts, faces)
    perm = rng.permutation(200)
    inv = np.empty(200, int)
    inv[perm] = np.arange(200)
    faces_p = inv[faces][rng.permutation(300)]
    # the same faces, listed from another of their three vertices (same winding)
    faces_p = np.roll(faces_p, 1, axis=1)
    order_p, f1 = canonical_order(verts[perm], faces_p)
    np.testing.assert_array_equal(verts[order], verts[perm][order_p])
    np.testing.assert_array_equal(f0, f1)
    # each new face is an old one, same cyclic order
    old = {tuple(np.roll(f, -int(np.argmin(f)))) for f in faces}
    new_as_old = order[f0]
    assert {tuple(np.roll(f, -int(np.argmin(f)))) for f in new_as_old} == old
    assert np.all(np.diff(verts[order][:, 0]) >= 0)


def test_fusion_puts_surfaces_where_the_depth_says() -> None:
    """A box room fused from exact depth maps: its floor, ceiling and walls on the box's planes.

    Cameras look around level with some pitch, so a half-pixel error in the
    projection moves the floor and ceiling up or down (8 mm at this size) while
    the walls, seen edge-on to the error, stay put.
    """
    import trimesh

    from reroom.importers.fusion import TsdfFusion
    from reroom.rays import RayCaster
    from reroom.scan.camera import look_at
    from reroom.synth.scanner import render_depth

    box = trimesh.creation.box(extents=[6.0, 5.0, 2.7])
    box.apply_translation([3.0, 2.5, 1.35])
    box.invert()
    caster = RayCaster(np.asarray(box.vertices), np.asarray(box.faces))
    w, h = 160, 120
    f = w / 2 / math.tan(math.radians(35.0))
    intr = Intrinsics(width=w, height=h, fx=f, fy=f, cx=w / 2, cy=h / 2)
    rng = np.random.default_rng(0)
    fusion = TsdfFusion(intr, 0.03, 0.12, 8.0)
    gl_to_cv = np.diag([1.0, -1.0, -1.0, 1.0])
    for j in range(24):
        a = 2 * math.pi * j / 24
        eye = np.array([3 + 0.5 * math.cos(a), 2.5 + 0.5 * math.sin(a), 1.5])
        ahead = np.array([math.cos(a + 1.0), math.sin(a + 1.0), rng.uniform(-0.6, 0.6)])
        frame = Frame(j, Path(), look_at(eye, eye + ahead), intr)
        depth_mm = np.round(render_depth(caster, frame) * 1000.0).astype(np.uint16)
        fusion.integrate(np.zeros((h, w, 3), np.uint8), depth_mm, frame.c2w @ gl_to_cv)
    v = np.asarray(fusion.extract_mesh().vertices)
    inner = (v[:, 0] > 0.5) & (v[:, 0] < 5.5) & (v[:, 1] > 0.5) & (v[:, 1] < 4.5)
    mid = (v[:, 2] > 0.5) & (v[:, 2] < 2.2)
    assert abs(np.median(v[inner & (v[:, 2] < 0.2), 2]) - 0.0) < 0.002
    assert abs(np.median(v[inner & (v[:, 2] > 2.5), 2]) - 2.7) < 0.002
    assert abs(np.median(v[mid & (v[:, 0] < 0.2), 0]) - 0.0) < 0.002
    assert abs(np.median(v[mid & (v[:, 1] > 4.8), 1]) - 5.0) < 0.002
