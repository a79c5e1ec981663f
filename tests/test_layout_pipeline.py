"""End to end: ``run_layout`` on a small generated scan, and on scans that are not rooms."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
import trimesh

from reroom.errors import ReroomError
from reroom.io.mesh import read_ply
from reroom.layout import OUTPUT_FILES, LayoutError, LayoutOptions, run_layout
from reroom.layout.evaluate import evaluate_scan
from reroom.scan import Intrinsics, look_at, write_scan
from reroom.synth.geometry import Piece, box, grid_rect

#: Generated scans are cached here between test runs (never in the repository).
CACHE = Path(os.environ.get("REROOM_TEST_CACHE", "/tmp/reroom_layout_cache"))


@pytest.fixture(scope="module")
def small_scan() -> Path:
    """A small, coarse (5 cm voxels) fused scan of the furnished room (generated once, about
    a minute, then cached)."""
    from reroom.synth.generate import SynthOptions, generate_scan

    out = CACHE / "test_furnished_24f_128x96_v05"
    if not (out / "transforms.json").exists():
        opts = SynthOptions(
            frames=24, width=128, height=96, spp=4, vertex_spp=1, mesh="fused", voxel_size=0.05
        )
        generate_scan("furnished", out, opts, overwrite=True)
    return out


def test_run_layout_end_to_end(small_scan: Path, tmp_path: Path):
    stages: set[str] = set()
    res = run_layout(small_scan, tmp_path, progress=lambda s, d, n: stages.add(s))
    assert {"load", "structure", "frames"} <= stages
    for key, name in OUTPUT_FILES.items():
        assert (tmp_path / name).is_file(), key
    doc = json.loads((tmp_path / "layout.json").read_text())
    assert doc["format"] == "reroom-layout"
    assert np.allclose(
        np.asarray(doc["rotation"]) @ np.asarray(doc["rotation"]).T, np.eye(3), atol=1e-6
    )
    (room,) = doc["rooms"]
    assert {"polygon", "walls", "openings", "floor_z", "ceiling_z", "baseboard"} <= set(room)
    ev = evaluate_scan(tmp_path / "layout.json", small_scan, tmp_path / "layout_labels.ply")
    assert ev["iou"] > 0.95
    assert ev["wall_error_cm"]["max"] < 3.0
    assert ev["floor_error_cm"] < 2.0 and ev["ceiling_error_cm"] < 2.0
    assert ev["label_accuracy"] > 0.93
    mesh = read_ply(tmp_path / "layout_labels.ply")
    assert {"label", "room", "wall"} <= set(mesh.vertex_attributes)
    assert np.array_equal(mesh.vertex_attributes["label"], res.labels)
    empty = trimesh.load(tmp_path / "empty_room.ply", process=False)
    assert all(p.is_watertight for p in empty.split(only_watertight=False))


def _write(root: Path, vertices: np.ndarray, faces: np.ndarray) -> Path:
    intr = Intrinsics.from_fov(32, 24, 60.0)
    poses = [look_at([0.5, 0.5, 1.2], [2.0, 1.0, 1.0])]
    img = np.full((24, 32, 3), 128, np.uint8)
    write_scan(root, trimesh.Trimesh(vertices, faces, process=False), intr, poses, [img])
    return root


def test_a_sphere_is_not_a_room(tmp_path: Path):
    s = trimesh.creation.icosphere(3, radius=2.0)
    scan = _write(tmp_path / "scan", np.asarray(s.vertices), np.asarray(s.faces))
    with pytest.raises(ReroomError, match="not a Manhattan-world room"):
        run_layout(scan, tmp_path / "out")


def test_floor_and_ceiling_without_walls_still_writes_labels(tmp_path: Path):
    pc = Piece.concat(
        [
            grid_rect([0, 0, 0], [1, 0, 0], [0, 1, 0], 4, 4, 0.1),
            grid_rect([0, 0, 2.5], [0, 1, 0], [1, 0, 0], 4, 4, 0.1),
            box([1.9, 1.9, 0.0], [2.1, 2.1, 0.3], 0.1, skip=("-z",)),
        ]
    )
    scan = _write(tmp_path / "scan", pc.vertices, pc.faces)
    with pytest.raises(LayoutError, match="wrote the labels that could be made") as err:
        run_layout(scan, tmp_path / "out", LayoutOptions(features=False))
    assert "no walls found" in str(err.value) or "no closed floorplan" in str(err.value)
    lab = read_ply(tmp_path / "out" / OUTPUT_FILES["labels"]).vertex_attributes["label"]
    assert np.sum(lab == 1) > 1000 and np.sum(lab == 2) > 1000  # floor and ceiling


def test_room_without_ceiling_writes_a_partial_layout(tmp_path: Path):
    from reroom.synth.presets import MATERIALS
    from reroom.synth.room import RoomSpec, build_room

    spec = RoomSpec(np.array([[0, 0], [5, 0], [5, 4], [0, 4]], float), 0.0, 2.7, [])
    pc = Piece.concat(
        [p.piece for p in build_room(spec, 0.1, MATERIALS)[0] if p.label != "ceiling"]
    )
    m = trimesh.Trimesh(pc.vertices, pc.faces, process=False)
    m.merge_vertices()
    scan = _write(tmp_path / "scan", np.asarray(m.vertices), np.asarray(m.faces))
    res = run_layout(scan, tmp_path / "out")
    doc = json.loads((tmp_path / "out" / OUTPUT_FILES["layout"]).read_text())
    assert doc["ceiling"] == "estimated"
    assert any("no ceiling seen" in w and "lower bound" in w for w in doc["warnings"])
    (room,) = doc["rooms"]
    assert room["ceiling"] == "estimated"
    assert 2.6 <= room["ceiling_z"] - room["floor_z"] <= 2.7 + 1e-6
    assert room["area"] == pytest.approx(20.0, rel=0.02)
    assert room["wall_support"] > 0.9 and all(w["seen"] > 0.8 for w in room["walls"])
    assert doc["label_counts"]["ceiling"] == 0 and doc["label_counts"]["wall"] > 1000
    assert res.structure.ceiling_estimated
    empty = trimesh.load(tmp_path / "out" / OUTPUT_FILES["empty_room"], process=False)
    assert all(p.is_watertight for p in empty.split(only_watertight=False))


SLAMBOOK = Path(
    os.environ.get(
        "REROOM_SLAMBOOK2_RGBD",
        Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "slambook2_rgbd",
    )
)


@pytest.mark.skipif(
    not (SLAMBOOK / "pose.txt").is_file(), reason=f"slambook2 frames not found at {SLAMBOOK}"
)
def test_slambook2_partial_room(tmp_path: Path):
    """The real scan whose cameras hardly look up: a partial room under an estimated ceiling."""
    from reroom.importers import import_rgbd_folder

    scan = import_rgbd_folder(SLAMBOOK, tmp_path / "scan").parent
    res = run_layout(scan, tmp_path / "out", LayoutOptions(figure=False))
    doc = res.layout
    assert doc["ceiling"] == "estimated" and doc["warnings"]
    assert doc["floor_z"] == pytest.approx(-1.36, abs=0.03)
    height = doc["ceiling_z"] - doc["floor_z"]
    assert 2.1 < height < 2.6  # walls seen up to ~2.3 m; no ceiling seen at all
    assert doc["rooms"], "a partial room"
    room = doc["rooms"][0]
    assert room["area"] > 8.0  # more than the floor seen (about 6 m² of floor faces)
    assert room["wall_support"] >= 0.1
    # Openings only on walls that were seen (not on the edge of the floor's coverage).
    for o in room["openings"]:
        assert room["walls"][o["wall"]]["seen"] >= 0.5
    # The scan was taken from inside the room: frames 0-3's cameras stood beyond the
    # floor the scan covered, and the outline is grown to contain every camera.
    from reroom.layout.floorplan import points_in_polygon
    from reroom.scan import load_scan

    cams = np.array([f.center for f in load_scan(scan).frames]) @ res.structure.rotation.T
    assert len(cams) == 5
    assert points_in_polygon(cams[:, :2], np.array(room["polygon"])).all()
    assert any("grown to contain" in w for w in doc["warnings"])
    assert (tmp_path / "out" / OUTPUT_FILES["empty_room"]).is_file()
