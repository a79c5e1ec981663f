"""``reroom invert``: the pipeline's wiring, outputs and bad-input messages."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from reroom.errors import ScanError
from reroom.invert.pipeline import InvertOptions, run_invert
from reroom.io.mesh import read_ply, write_ply


def _box_scan(root: Path, radiance: float = 0.3) -> Path:
    """A closed 3 x 2.5 x 2.4 m room, seen from inside, glowing uniformly."""
    box = trimesh.creation.box(extents=(3.0, 2.5, 2.4))
    box.apply_translation((1.5, 1.25, 1.2))
    for _ in range(4):
        box = box.subdivide()
    box.invert()  # normals into the room
    nv = len(box.vertices)
    scan = root / "scan"
    (scan / "hdr").mkdir(parents=True)
    (scan / "layout").mkdir()
    write_ply(
        scan / "hdr" / "hdr_mesh.ply",
        box,
        {
            "radiance": np.full((nv, 3), radiance, np.float32),
            "observed": np.ones(nv, np.uint8),
        },
    )
    z = box.vertices[:, 2]
    label = np.zeros(nv, np.uint8)
    label[z < 1e-6] = 1
    label[z > 2.4 - 1e-6] = 2
    write_ply(scan / "layout" / "layout_labels.ply", box, {"label": label})
    return scan


FAST = InvertOptions(rays_per_receiver=64, receiver_voxel=0.25, pictures=False)


def test_closed_uniform_room_without_lights_has_white_walls(tmp_path: Path) -> None:
    # with no emitter, uniform radiance in a closed room means E_ind = pi L: albedo 1
    scan = _box_scan(tmp_path)
    result = run_invert(scan, options=FAST)
    assert any("lights.json is missing" in w for w in result.warnings)
    np.testing.assert_allclose(result.solve.albedo, 1.0, atol=0.03)
    out = scan / "invert"
    scene = json.loads((out / "scene.json").read_text())
    assert scene["format"] == "reroom-invert" and scene["lights"] == []
    assert [m["name"] for m in scene["materials"]] == ["wall", "floor", "ceiling"]
    mesh = read_ply(out / scene["albedo_file"])
    attrs = mesh.vertex_attributes
    keys = ("albedo", "in_cluster", "solved_per_vertex", "nonphysical", "unobserved")
    for key in (*keys, "near_geometry"):
        assert key in attrs
    # every vertex is solved, except those on the room's edges (a seam: the neighbouring
    # surface blocks their hemisphere at distance 0), which are left out and flagged
    near = np.asarray(attrs["near_geometry"]).astype(bool)
    p = np.asarray(mesh.vertices)
    on_bounds = (np.isclose(p, 0) | np.isclose(p, (3.0, 2.5, 2.4))).sum(axis=1)
    assert near.any() and np.all(on_bounds[near] >= 2)
    assert np.all(near | (on_bounds >= 2) | np.asarray(attrs["in_cluster"]).astype(bool))
    assert not np.any(near & np.asarray(attrs["in_cluster"]).astype(bool))
    report = json.loads((out / "report.json").read_text())
    assert report["vertices"]["in_cluster"] + report["vertices"]["near_geometry"] == len(p)


def test_missing_inputs_name_the_file(tmp_path: Path) -> None:
    scan = _box_scan(tmp_path)
    (scan / "layout" / "layout_labels.ply").unlink()
    with pytest.raises(ScanError, match="layout_labels.ply: is missing"):
        run_invert(scan, options=FAST)
    with pytest.raises(ScanError, match="hdr_mesh.ply: is missing"):
        run_invert(tmp_path / "nowhere", options=FAST)


def test_unobserved_cluster_is_reported_and_marked_partial(tmp_path: Path) -> None:
    scan = _box_scan(tmp_path)
    mesh = read_ply(scan / "hdr" / "hdr_mesh.ply")
    observed = np.ones(len(mesh.vertices), np.uint8)
    observed[mesh.vertices[:, 2] > 2.4 - 1e-6] = 0  # nobody looked up
    write_ply(
        scan / "hdr" / "hdr_mesh.ply",
        mesh,
        {"radiance": mesh.vertex_attributes["radiance"], "observed": observed},
    )
    result = run_invert(scan, options=FAST)
    assert np.isnan(result.solve.albedo[2]).all()
    assert any("'ceiling' has no observed vertex" in w for w in result.warnings)
    scene = json.loads((scan / "invert" / "scene.json").read_text())
    assert scene["complete"] is False
    assert scene["materials"][2] == {"name": "ceiling", "albedo": None, "solved": False}


def test_fill_poorly_seen_bins():
    from reroom.invert.export import fill_poorly_seen

    profile = np.array([1.0, 2.0, 50.0, 4.0, 7.0, 9.0])
    support = np.array([10.0, 10.0, 0.01, 10.0, 0.0, 10.0])
    out = fill_poorly_seen(profile, support, 0.01)
    # bin 2: seen by almost nothing -> between its well-seen neighbours; bin 4: unseen -> 0
    np.testing.assert_allclose(out, [1.0, 2.0, 3.0, 4.0, 0.0, 9.0])
    np.testing.assert_allclose(fill_poorly_seen(profile, np.full(6, 1.0), 0.01), profile)
    np.testing.assert_allclose(fill_poorly_seen(profile, np.zeros(6), 0.01), profile)
    with pytest.raises(ValueError, match="differ"):
        fill_poorly_seen(profile, support[:3], 0.01)
