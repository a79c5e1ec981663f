"""The scan format: round trip, lazy loading, and one clear error per kind of bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import make_scan

from reroom.errors import ScanError
from reroom.scan import Intrinsics, load_scan, look_at


def _edit(scan_dir: Path, fn) -> None:
    p = scan_dir / "transforms.json"
    doc = json.loads(p.read_text())
    fn(doc)
    p.write_text(json.dumps(doc))


def test_round_trip(small_scan: Path) -> None:
    scan = load_scan(small_scan)
    assert len(scan) == 3
    assert len(scan.mesh.faces) == 12
    img = scan.frames[1].load_image()
    assert img.shape == (24, 32, 3) and img.dtype == np.uint8
    np.testing.assert_allclose(scan.frames[0].c2w, look_at([0, 0, 1.5], [2.0, 0.5, 1.2]))
    assert not scan.has_ground_truth


def test_depth_round_trip(tmp_path: Path) -> None:
    scan = load_scan(make_scan(tmp_path / "s", depth=True))
    d = scan.frames[0].load_depth()
    np.testing.assert_allclose(d, 2.0)


def test_projection_matches_pixel_rays() -> None:
    from reroom.scan import Frame

    intr = Intrinsics(
        64, 48, 50.0, 52.0, 30.0, 25.0, "OPENCV", k1=-0.1, k2=0.02, p1=0.001, p2=-0.002
    )
    frame = Frame(0, Path("x.png"), look_at([1, 2, 1.5], [3, 3, 1]), intr)
    uv = np.array([[0.5, 0.5], [10.2, 40.7], [63.5, 47.5], [30, 25]])
    o, d = frame.pixel_rays(uv)
    pts = o + 2.7 * d
    uv2, z, inside = frame.project(pts)
    np.testing.assert_allclose(uv2, uv, atol=1e-6)
    assert inside.all() and np.all(z > 0)


def test_behind_camera_is_not_inside() -> None:
    from reroom.scan import Frame

    frame = Frame(0, Path("x.png"), look_at([0, 0, 0], [1, 0, 0]), Intrinsics.from_fov(32, 24, 60))
    _, z, inside = frame.project(np.array([[-1.0, 0, 0], [1.0, 0, 0]]))
    assert z[0] < 0 and not inside[0] and inside[1]


def test_camera_axes_are_opengl() -> None:
    c2w = look_at([0, 0, 0], [1, 0, 0])
    assert np.allclose(-c2w[:3, 2], [1, 0, 0])  # looks down -z
    assert np.allclose(c2w[:3, 1], [0, 0, 1])  # y up
    assert np.allclose(c2w[:3, 0], [0, -1, 0])  # x right (looking along +x with z up)


def test_lazy_loading_reads_no_pixels(small_scan: Path, monkeypatch) -> None:
    import reroom.scan.camera as cam

    calls = []
    monkeypatch.setattr(cam, "read_rgb8", lambda p: calls.append(p))
    load_scan(small_scan)
    assert calls == []


# --- bad input ---------------------------------------------------------------------------


def test_missing_folder(tmp_path: Path) -> None:
    with pytest.raises(ScanError, match="does not exist"):
        load_scan(tmp_path / "nope")


def test_missing_transforms(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    with pytest.raises(ScanError, match="transforms.json"):
        load_scan(tmp_path / "empty")


def test_invalid_json(small_scan: Path) -> None:
    (small_scan / "transforms.json").write_text("{ not json")
    with pytest.raises(ScanError, match="not valid JSON"):
        load_scan(small_scan)


def test_no_frames(small_scan: Path) -> None:
    _edit(small_scan, lambda d: d.update(frames=[]))
    with pytest.raises(ScanError, match="frames"):
        load_scan(small_scan)


def test_missing_image(small_scan: Path) -> None:
    (small_scan / "images" / "frame_00001.png").unlink()
    with pytest.raises(ScanError, match=r"frame_00001.png: image file is missing"):
        load_scan(small_scan)


def test_corrupt_image(small_scan: Path) -> None:
    (small_scan / "images" / "frame_00002.png").write_bytes(b"\x89PNG garbage")
    with pytest.raises(ScanError, match=r"frame_00002.png.*not a readable image"):
        load_scan(small_scan)


def test_truncated_image_fails_on_decode(small_scan: Path) -> None:
    p = small_scan / "images" / "frame_00000.png"
    p.write_bytes(p.read_bytes()[:80])  # header intact, pixels cut off
    scan = load_scan(small_scan)
    with pytest.raises(ScanError, match="frame_00000.png"):
        scan.frames[0].load_image()


def test_image_size_mismatch(small_scan: Path) -> None:
    from PIL import Image

    Image.new("RGB", (40, 24)).save(small_scan / "images" / "frame_00001.png")
    with pytest.raises(
        ScanError, match=r"frame_00001.png: image is 40x24 but the intrinsics say 32x24"
    ):
        load_scan(small_scan)


def test_depth_size_mismatch(tmp_path: Path) -> None:
    from PIL import Image

    scan_dir = make_scan(tmp_path / "s", depth=True)
    Image.fromarray(np.zeros((10, 10), np.uint16)).save(scan_dir / "depth" / "frame_00000.png")
    with pytest.raises(ScanError, match=r"frame_00000.png: depth map is 10x10"):
        load_scan(scan_dir)


@pytest.mark.parametrize(
    ("matrix", "message"),
    [
        ([[float("nan")] * 4] * 4, "non-finite"),
        ([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]], "must be 4x4"),
        ([[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "not rigid"),
        ([[-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "not rigid"),
        ([[1, 0.3, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "not rigid"),
        ([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]], "last row"),
        ("identity", "not numeric"),
    ],
)
def test_bad_pose(small_scan: Path, matrix, message: str) -> None:
    def set_pose(d):
        d["frames"][1]["transform_matrix"] = matrix

    _edit(small_scan, set_pose)
    with pytest.raises(ScanError, match=rf"transforms.json: frame 1: .*{message}"):
        load_scan(small_scan)


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("fl_x", -5, "must be positive"),
        ("w", 31.5, "whole pixels"),
        ("camera_model", "FISHEYE", "camera_model"),
        ("cx", "a", "must be a number"),
    ],
)
def test_bad_intrinsics(small_scan: Path, key: str, value, message: str) -> None:
    _edit(small_scan, lambda d: d.update({key: value}))
    with pytest.raises(ScanError, match=message):
        load_scan(small_scan)


def test_missing_intrinsics(small_scan: Path) -> None:
    def drop(d):
        for k in ("fl_x", "fl_y", "cx", "cy", "w", "h"):
            d.pop(k)

    _edit(small_scan, drop)
    with pytest.raises(ScanError, match="no intrinsics"):
        load_scan(small_scan)


def test_per_frame_intrinsics_override(small_scan: Path) -> None:
    def per_frame(d):
        d["frames"][0]["fl_x"] = 99.0

    _edit(small_scan, per_frame)
    scan = load_scan(small_scan)
    assert scan.frames[0].intrinsics.fx == 99.0
    assert scan.frames[1].intrinsics.fx != 99.0


def test_missing_mesh_reference(small_scan: Path) -> None:
    _edit(small_scan, lambda d: d.pop("ply_file_path"))
    with pytest.raises(ScanError, match="ply_file_path"):
        load_scan(small_scan)


def test_missing_mesh_file(small_scan: Path) -> None:
    (small_scan / "mesh.ply").unlink()
    with pytest.raises(ScanError, match=r"mesh.ply: mesh file is missing"):
        load_scan(small_scan)


def test_corrupt_mesh(small_scan: Path) -> None:
    (small_scan / "mesh.ply").write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement vertex 10\n"
    )
    with pytest.raises(ScanError, match=r"mesh.ply: is not a readable PLY"):
        load_scan(small_scan)


def _write_ascii_ply(path: Path, verts, faces) -> None:
    lines = [
        "ply",
        "format ascii 1.0",
        f"element vertex {len(verts)}",
        "property float x",
        "property float y",
        "property float z",
    ]
    lines += [f"element face {len(faces)}", "property list uchar int vertex_indices", "end_header"]
    lines += [" ".join(map(str, v)) for v in verts]
    lines += [" ".join(map(str, [len(f), *f])) for f in faces]
    path.write_text("\n".join(lines) + "\n")


def test_mesh_without_faces(small_scan: Path) -> None:
    _write_ascii_ply(small_scan / "mesh.ply", [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [])
    with pytest.raises(ScanError, match="no faces"):
        load_scan(small_scan)


def test_non_triangle_faces(small_scan: Path) -> None:
    _write_ascii_ply(
        small_scan / "mesh.ply", [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2, 3]]
    )
    with pytest.raises(ScanError, match=r"1 faces are not triangles \(faces with \[4\] vertices\)"):
        load_scan(small_scan)


def test_face_index_out_of_range(small_scan: Path) -> None:
    _write_ascii_ply(small_scan / "mesh.ply", [[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 1, 7]])
    with pytest.raises(ScanError, match="out of range"):
        load_scan(small_scan)


def test_non_finite_vertices(small_scan: Path) -> None:
    _write_ascii_ply(
        small_scan / "mesh.ply", [[0, 0, 0], [1, float("nan"), 0], [1, 1, 0]], [[0, 1, 2]]
    )
    with pytest.raises(ScanError, match="non-finite coordinates"):
        load_scan(small_scan)


def test_write_is_atomic_on_failure(tmp_path: Path) -> None:
    from reroom.io.atomic import atomic_path

    target = tmp_path / "result.json"
    target.write_text("old")
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("crash while writing")
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["result.json"]


def test_an_evaluation_with_a_nan_figure_is_written_with_null(tmp_path: Path) -> None:
    from reroom.io.atomic import atomic_write_json, nan_to_null

    # A loop seam with no loop pair is NaN (reroom.hdr.metrics.seam_metric); the report's
    # evaluation.json failed on a 12-frame scan with it.
    ev = {"loop_seam": {"seam": float("nan"), "pairs": 0}, "v": np.array([1.0, np.inf])}
    with pytest.raises(ValueError, match="not JSON compliant"):
        atomic_write_json(tmp_path / "bad.json", ev)
    atomic_write_json(tmp_path / "ev.json", nan_to_null(ev))
    back = json.loads((tmp_path / "ev.json").read_text())
    assert back == {"loop_seam": {"seam": None, "pairs": 0}, "v": [1.0, None]}


def test_ply_attributes_round_trip(tmp_path: Path) -> None:
    import trimesh

    from reroom.io.mesh import read_ply, write_ply

    mesh = trimesh.creation.icosphere(subdivisions=1)
    n = len(mesh.vertices)
    rad = np.random.default_rng(0).random((n, 3)) * 1000.0
    write_ply(
        tmp_path / "m.ply",
        mesh,
        {"radiance": rad, "observed": np.arange(n) % 2 == 0, "label": np.arange(n, dtype=np.uint8)},
    )
    back = read_ply(tmp_path / "m.ply")
    np.testing.assert_allclose(back.vertex_attributes["radiance"], rad, rtol=1e-6)
    assert back.vertex_attributes["observed"].dtype == np.uint8
    np.testing.assert_array_equal(back.vertex_attributes["label"], np.arange(n))


def test_binary_ply_fast_and_general_readers_agree(tmp_path: Path) -> None:
    import plyfile
    import trimesh

    from reroom.io.mesh import read_ply, write_ply

    mesh = trimesh.creation.icosphere(subdivisions=2)
    write_ply(tmp_path / "tri.ply", mesh, {"label": np.arange(len(mesh.vertices)) % 7})
    back = read_ply(tmp_path / "tri.ply")  # fixed-size fast path
    np.testing.assert_array_equal(back.faces, mesh.faces)
    assert back.faces.dtype == np.int64
    np.testing.assert_allclose(back.vertices, mesh.vertices, rtol=1e-6)
    np.testing.assert_array_equal(
        back.vertex_attributes["label"], np.arange(len(mesh.vertices)) % 7
    )
    # A binary file with one quad among triangles: the fast read fails, the general one
    # reports the quad.
    verts = np.array([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0)], dtype="f4,f4,f4")
    verts.dtype.names = ("x", "y", "z")
    faces = np.empty(2, dtype=[("vertex_indices", "O")])
    faces[0] = (np.array([1, 4, 2], "i4"),)
    faces[1] = (np.array([0, 1, 2, 3], "i4"),)
    plyfile.PlyData(
        [plyfile.PlyElement.describe(verts, "vertex"), plyfile.PlyElement.describe(faces, "face")]
    ).write(str(tmp_path / "mixed.ply"))
    with pytest.raises(ScanError, match=r"1 faces are not triangles \(faces with \[4\] vertices\)"):
        read_ply(tmp_path / "mixed.ply")


def test_sampler_choice() -> None:
    from reroom.render.camera import is_perfect_square, is_power_of_four, perspective_sensor

    assert [n for n in range(1, 300) if is_power_of_four(n)] == [1, 4, 16, 64, 256]
    assert [n for n in range(1, 50) if is_perfect_square(n)] == [1, 4, 9, 16, 25, 36, 49]
    intr = Intrinsics.from_fov(32, 24, 60)
    assert perspective_sensor(np.eye(4), intr, 64)["sampler"]["type"] == "multijitter"
    assert perspective_sensor(np.eye(4), intr, 1024)["sampler"]["type"] == "multijitter"
    assert perspective_sensor(np.eye(4), intr, 32)["sampler"]["type"] == "independent"
