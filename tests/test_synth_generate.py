"""End-to-end generation: scans load, ground truth is complete and consistent with the frames."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from reroom.io.mesh import read_ply
from reroom.scan import load_scan
from reroom.synth.camera_sim import CameraModel
from reroom.synth.generate import SynthOptions, generate_scan
from reroom.synth.labels import LABELS
from reroom.synth.validate import check_consistency


@pytest.fixture(scope="module")
def furnished(tmp_path_factory) -> Path:
    """A small furnished scan: few frames, enough samples that the truth is tight."""
    out = tmp_path_factory.mktemp("furnished") / "scan"
    opts = SynthOptions(
        frames=6, width=64, height=48, spp=256, vertex_spp=256, mesh_spacing=0.12, seed=1
    )
    return generate_scan("furnished", out, opts)


@pytest.fixture(scope="module")
def box_fused(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("box") / "scan"
    opts = SynthOptions(
        frames=8, width=64, height=48, spp=64, vertex_spp=64, mesh="fused", voxel_size=0.05, seed=2
    )
    return generate_scan("box", out, opts)


def test_scan_loads_and_carries_no_truth(furnished: Path) -> None:
    scan = load_scan(furnished)
    assert len(scan.frames) == 6
    assert scan.frames[0].load_image().shape == (48, 64, 3)
    assert scan.meta["reroom"]["response"] == "gamma2.2"
    # Estimation stages read the scan mesh; it must not leak labels, albedo or radiance.
    assert not {"label", "albedo", "radiance"} & set(scan.mesh.vertex_attributes)
    assert scan.has_ground_truth


def test_ground_truth_is_complete(furnished: Path) -> None:
    gt_dir = furnished / "ground_truth"
    truth = json.loads((gt_dir / "ground_truth.json").read_text())
    assert len(truth["frames"]) == 6
    for f in truth["frames"]:
        np.testing.assert_allclose(
            f["scale"], np.multiply(f["exposure"], f["white_balance"]), rtol=1e-9
        )
    kinds = {light["type"] for light in truth["lights"]}
    assert kinds == {"area", "line", "point", "window"}
    room = truth["layout"]["rooms"][0]
    assert room["floor_z"] == 0.0 and room["ceiling_z"] == 2.7
    assert {o["kind"] for o in room["openings"]} == {"window", "door"}
    gt = read_ply(gt_dir / "vertices.ply")
    scan = load_scan(furnished)
    assert len(gt.vertices) == len(scan.mesh.vertices)
    attrs = gt.vertex_attributes
    assert set(np.unique(attrs["label"])) >= {
        LABELS[k]
        for k in ("wall", "floor", "ceiling", "door", "window", "baseboard", "furniture", "light")
    }
    assert np.all(np.isfinite(attrs["radiance"])) and np.all(attrs["radiance"] >= 0)
    assert np.all((attrs["albedo"] >= 0) & (attrs["albedo"] <= 1))
    # Emitting panels are far brighter than the walls they light.
    light = attrs["label"] == LABELS["light"]
    wall = attrs["label"] == LABELS["wall"]
    assert np.median(attrs["radiance"][light].max(1)) > 20 * np.median(
        attrs["radiance"][wall].mean(1)
    )
    # the wood floor texture varies; painted walls are uniform
    assert np.ptp(attrs["albedo"][attrs["label"] == LABELS["floor"], 0]) > 0.05
    assert np.ptp(attrs["albedo"][wall, 0]) == 0
    scene = json.loads((gt_dir / "scene" / "scene.json").read_text())
    assert all((gt_dir / "scene" / p["file"]).is_file() for p in scene["parts"])


def test_frames_match_truth_on_diffuse_surfaces(furnished: Path) -> None:
    """Re-render the frames from the true radiance and exposures: no bias, spread = MC noise."""
    rep = check_consistency(furnished)
    assert rep.samples > 2000
    assert rep.ratio_of_means == pytest.approx(1.0, abs=0.05)
    assert rep.median_ratio == pytest.approx(1.0, abs=0.05)
    # The spread is Monte-Carlo noise of both sides at 256 samples (about 11 % per sample
    # each with this room's indirect light) plus sensor noise and quantisation.
    assert rep.median_abs_log_ratio < 0.2
    assert rep.median_abs_level_diff <= 10


def test_wrong_exposure_would_be_caught(furnished: Path, tmp_path: Path) -> None:
    """The consistency check can fail: doubling one frame's recorded exposure shows up."""
    import shutil

    copy = tmp_path / "scan"
    shutil.copytree(furnished, copy)
    p = copy / "ground_truth" / "ground_truth.json"
    truth = json.loads(p.read_text())
    for f in truth["frames"]:
        f["scale"] = [1.3 * s for s in f["scale"]]
    p.write_text(json.dumps(truth))
    assert check_consistency(copy).ratio_of_means < 0.85


def test_fused_mesh_is_scanner_like(box_fused: Path) -> None:
    scan = load_scan(box_fused)
    truth = json.loads((box_fused / "ground_truth" / "ground_truth.json").read_text())
    assert truth["mesh"]["kind"] == "fused"
    v = np.asarray(scan.mesh.vertices)
    lo, hi = np.percentile(v, 0.5, axis=0), np.percentile(v, 99.5, axis=0)
    # The room is 5 x 4 x 2.7 m; fusion with 5 cm voxels recovers it within a couple of voxels
    # (the window's 20 cm reveal pokes out of the east wall, x = 5).
    np.testing.assert_allclose(hi - lo, [5.0, 4.0, 2.7], atol=0.12)
    gt = read_ply(box_fused / "ground_truth" / "vertices.ply").vertex_attributes
    assert np.median(gt["surface_distance"]) < 0.03
    # Listed in the canonical order (Open3D's own order changes from run to run).
    assert np.all(np.diff(v[:, 0]) >= 0)
    assert check_consistency(box_fused).ratio_of_means == pytest.approx(1.0, abs=0.06)


def test_corrupted_mesh_has_holes_and_noise(tmp_path: Path) -> None:
    opts = SynthOptions(
        frames=2,
        width=32,
        height=24,
        spp=4,
        vertex_spp=4,
        mesh="corrupted",
        seed=3,
        camera=CameraModel(noise=False),
    )
    out = generate_scan("box", tmp_path / "scan", opts)
    scan = load_scan(out)
    gt = read_ply(out / "ground_truth" / "vertices.ply").vertex_attributes
    assert 0.0005 < np.median(gt["surface_distance"]) < 0.02
    assert not scan.mesh.is_watertight


def test_lights_can_be_switched_off(tmp_path: Path) -> None:
    opts = SynthOptions(
        frames=2, width=32, height=24, spp=8, vertex_spp=8, lights=["ceiling_panel"]
    )
    out = generate_scan("box", tmp_path / "scan", opts)
    scene = json.loads((out / "ground_truth" / "scene" / "scene.json").read_text())
    assert {light["name"]: light["on"] for light in scene["lights"]} == {
        "ceiling_panel": True,
        "window0": False,
    }


def test_bad_options_are_reported(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown preset 'castle'"):
        generate_scan("castle", tmp_path / "a")
    with pytest.raises(ValueError, match=r"no light\(s\) \['sun'\]"):
        generate_scan(
            "box",
            tmp_path / "b",
            SynthOptions(frames=1, width=16, height=16, spp=1, lights=["sun"]),
        )
    (tmp_path / "c").mkdir()
    (tmp_path / "c" / "x.txt").write_text("keep me")
    with pytest.raises(ValueError, match="not empty"):
        generate_scan("box", tmp_path / "c", SynthOptions(frames=1, width=16, height=16, spp=1))


def test_refuse_scan_fuses_the_same_depth_on_another_grid(box_fused: Path, tmp_path: Path) -> None:
    from reroom.synth.generate import refuse_scan

    doc = json.loads((box_fused / "ground_truth" / "ground_truth.json").read_text())
    assert doc["options"]["grid_yaw_deg"] == 17.0
    same = refuse_scan(box_fused, tmp_path / "same", 17.0)
    other = refuse_scan(box_fused, tmp_path / "other", 40.0)
    base = load_scan(box_fused).mesh
    # At the scan's own placement the fusion is the scan's (up to Open3D's
    # thread-dependent diagonals); turned, the mesh is another, of the same room.
    again = load_scan(same).mesh
    assert len(again.vertices) == len(base.vertices)
    np.testing.assert_allclose(again.bounds, base.bounds, atol=1e-6)
    turned = load_scan(other)
    assert len(turned.mesh.vertices) != len(base.vertices)
    np.testing.assert_allclose(turned.mesh.bounds, base.bounds, atol=0.06)
    truth = json.loads((other / "ground_truth" / "ground_truth.json").read_text())
    assert truth["options"]["grid_yaw_deg"] == 40.0
    gt = read_ply(other / "ground_truth" / "vertices.ply")
    assert len(gt.vertices) == truth["mesh"]["vertices"] == len(turned.mesh.vertices)
    assert np.all(np.isfinite(gt.vertex_attributes["radiance"]))
    # The photos are the scan's.
    assert (other / "images").is_dir() and len(turned.frames) == len(load_scan(box_fused).frames)
    with pytest.raises(ValueError, match="exists"):
        refuse_scan(box_fused, tmp_path / "other", 40.0)


def test_refuse_scan_needs_a_fused_synthetic_scan(furnished: Path, tmp_path: Path) -> None:
    from reroom.synth.generate import refuse_scan

    with pytest.raises(ValueError, match="not fused"):
        refuse_scan(furnished, tmp_path / "x", 30.0)
    with pytest.raises(ValueError, match="not a synthetic scan"):
        refuse_scan(tmp_path, tmp_path / "y", 30.0)


def test_refuse_scan_leaves_no_scan_behind_when_it_fails(
    box_fused: Path, tmp_path: Path, monkeypatch
) -> None:
    import reroom.synth.generate as generate

    def broken(*args, **kwargs):
        raise RuntimeError("fusion failed")

    monkeypatch.setattr(generate, "_fused_mesh", broken)
    with pytest.raises(RuntimeError, match="fusion failed"):
        generate.refuse_scan(box_fused, tmp_path / "out", 30.0)
    # Only the folder marked partial is left; the output folder does not exist.
    assert not (tmp_path / "out").exists()
    assert (tmp_path / "out.partial").is_dir()
