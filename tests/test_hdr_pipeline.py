"""run_hdr end to end: outputs, evaluation, and bad inputs (reroom.hdr.pipeline)."""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from reroom.errors import ReroomError, ScanError
from reroom.hdr import HdrOptions, SolveOptions, run_hdr
from reroom.hdr.evaluate import Truth, evaluate_hdr, radiance_errors
from reroom.hdr.synthetic import box_room, write_projected_scan
from reroom.hdr.vertex_exr import read_vertex_exr
from reroom.io.mesh import read_ply
from reroom.scan import Intrinsics, look_at
from reroom.synth.camera_sim import CameraModel

SIZE = (4.0, 3.0, 2.5)
N_FRAMES = 16


def loop_poses(n: int = N_FRAMES) -> list[np.ndarray]:
    """A loop around the room looking outwards at the walls, ending where it began."""
    poses = []
    for k in range(n):
        a = 2 * np.pi * k / n
        eye = np.array([2.0 + 0.7 * np.cos(a), 1.5 + 0.5 * np.sin(a), 1.4])
        target = eye + np.array([np.cos(a + 1.0), np.sin(a + 1.0), -0.25 + 0.3 * np.sin(2 * a)])
        poses.append(look_at(eye, target))
    return poses


def room_radiance(v: np.ndarray) -> np.ndarray:
    rad = (0.25 + 0.1 * np.sin(1.5 * v[:, 0]) + 0.08 * np.cos(2.0 * v[:, 1]))[:, None]
    rad = rad * np.array([1.0, 0.9, 0.75])
    rad[v[:, 2] > SIZE[2] - 1e-6] *= 2.5  # a bright ceiling
    return rad


def make(out: Path, **kwargs) -> Path:
    v, f = box_room(SIZE, spacing=0.15)
    kw = {"camera": CameraModel(noise=True)}
    kw.update(kwargs)
    return write_projected_scan(
        out, v, f, room_radiance(v), loop_poses(), Intrinsics.from_fov(48, 36, 75.0), **kw
    )


@pytest.fixture(scope="module")
def scan_dir(tmp_path_factory) -> Path:
    return make(tmp_path_factory.mktemp("hdr") / "scan")


@pytest.fixture(scope="module")
def result(scan_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("hdr") / "out"
    stages = []
    res = run_hdr(
        scan_dir,
        out,
        HdrOptions(render_size=(96, 72)),
        progress=lambda s, d, n: stages.append((s, d, n)),
    )
    return res, out, stages


def test_outputs_written(result):
    res, out, stages = result
    for name in ("hdr_mesh.ply", "hdr_radiance.exr", "exposures.json", "hdr_extras.npz"):
        assert (out / name).is_file()
    for name in ("hdr_exposures.png", "hdr_before_after.png", "report.md"):
        assert (out / "report" / name).stat().st_size > 0
    mesh = read_ply(out / "hdr_mesh.ply")
    attrs = mesh.vertex_attributes
    assert attrs["radiance"].shape == (len(mesh.vertices), 3)
    assert attrs["radiance"].dtype == np.float32
    assert np.all(np.isfinite(attrs["radiance"]))
    assert set(np.unique(attrs["observed"])) <= {0, 1}
    np.testing.assert_array_equal(attrs["observed"].astype(bool), res.observed)
    np.testing.assert_array_equal(attrs["sample_count"], res.sample_count)
    assert np.all(attrs["radiance"][~res.observed] == 0)
    rad_exr, obs_exr = read_vertex_exr(out / "hdr_radiance.exr", len(mesh.vertices))
    np.testing.assert_array_equal(rad_exr, attrs["radiance"])
    np.testing.assert_array_equal(obs_exr, res.observed)
    doc = json.loads((out / "exposures.json").read_text())
    assert len(doc["frames"]) == N_FRAMES
    assert doc["frames"][0]["scale"] == [1.0, 1.0, 1.0]
    assert doc["frames"][0]["status"] == "reference"
    assert all(len(f["frame_to_frame"]) == 3 for f in doc["frames"])
    assert doc["response"] == "gamma2.2"
    assert {s for s, _, _ in stages} >= {"reproject", "solve exposures", "baselines", "report"}
    assert ("reproject", N_FRAMES, N_FRAMES) in stages


def test_exposures_and_radiance_match_the_truth(scan_dir, result):
    res, out, _ = result
    truth = np.asarray(
        [
            f["scale"]
            for f in json.loads((scan_dir / "ground_truth/ground_truth.json").read_text())["frames"]
        ]
    )
    ratio = res.scales / (truth / truth[0])
    assert np.median(np.abs(ratio - 1)) < 0.01
    assert np.max(np.abs(ratio - 1)) < 0.04
    ev = evaluate_hdr(scan_dir, out)
    ours = ev["methods"]["ours"]
    assert ours["exposure_ratio_error"]["median"] < 0.01
    assert ours["radiance_error"]["median"] < 0.03
    assert ours["radiance_error"]["vertices"] > 100
    assert np.allclose(ours["radiance_error"]["ratio_of_sums"], 1.0, atol=0.03)
    assert set(ev["methods"]) == {"ours", "frame-to-frame", "frame-to-model"}
    assert (out / "evaluation.json").is_file()
    assert (out / "report" / "hdr_exposures_truth.png").is_file()


def test_ratio_of_sums_sees_a_bias_through_a_noisy_truth():
    # Truth with 15 % Monte-Carlo noise per vertex: no vertex is precise to 2 %, so the
    # per-vertex error is empty, but the ratio of sums still finds a 10 % bias in red.
    rng = np.random.default_rng(3)
    n = 20_000
    exact = rng.uniform(0.1, 1.0, (n, 3))
    noisy = exact * (1 + 0.15 * rng.standard_normal((n, 3)))
    noisy = np.abs(noisy)
    label = np.where(np.arange(n) < n // 2, 0, 1)
    truth = Truth(np.ones((1, 3)), noisy, 0.15 * noisy, label, {"wall": 0, "floor": 1})
    ours = exact * np.array([1.1, 1.0, 1.0])
    ours[label == 1] *= np.array([1.0, 1.0, 0.9]) / np.array([1.1, 1.0, 1.0])
    r = radiance_errors(ours, np.ones(n, bool), truth, np.ones(3), np.ones(n, bool))
    assert r["vertices"] == 0 and r["median"] is None
    assert r["ratio_of_sums_vertices"] == n
    np.testing.assert_allclose(r["ratio_of_sums_by_label"]["wall"], [1.1, 1.0, 1.0], atol=0.01)
    np.testing.assert_allclose(r["ratio_of_sums_by_label"]["floor"], [1.0, 1.0, 0.9], atol=0.01)


def test_estimation_never_reads_ground_truth(scan_dir, result, tmp_path):
    res, _, _ = result
    bare = tmp_path / "bare"
    shutil.copytree(scan_dir, bare, ignore=shutil.ignore_patterns("ground_truth"))
    again = run_hdr(bare, tmp_path / "out", HdrOptions(report=False))
    np.testing.assert_array_equal(again.scales, res.scales)
    np.testing.assert_array_equal(again.radiance, res.radiance)
    assert not (tmp_path / "out" / "report").exists()
    with pytest.raises(ScanError, match="ground_truth"):
        evaluate_hdr(bare, tmp_path / "out")


def test_bad_frames_are_reported_not_fatal(tmp_path):
    """Black, saturated, looking-at-nothing frames and a mesh with holes: warnings, no NaN."""
    v, f = box_room(SIZE, spacing=0.15)
    poses = loop_poses()
    # Frame 5 sits outside the room looking away from it: it sees nothing.
    poses[5] = look_at([10.0, 10.0, 1.0], [20.0, 20.0, 1.0])
    black = np.zeros((36, 48, 3), np.uint8)
    white = np.full((36, 48, 3), 255, np.uint8)
    # Holes: drop a patch of faces from the scanned mesh.
    centers = v[f].mean(axis=1)
    hole = (np.abs(centers[:, 0] - 2.0) < 0.5) & (centers[:, 1] < 1e-6)
    scan = write_projected_scan(
        tmp_path / "scan",
        v,
        f,
        room_radiance(v),
        poses,
        Intrinsics.from_fov(48, 36, 75.0),
        images_override={0: black, 9: white},
        mesh_faces=f[~hole],
    )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = run_hdr(scan, tmp_path / "out", HdrOptions(render_size=(64, 48)))
    text = " ".join(str(w.message) for w in caught)
    assert "sees no usable part of the mesh" in text
    assert "too dark" in text and "saturated" in text
    assert "frame 0 has no exposure" in text
    # Frame 5 sees nothing (all black), so the auto-exposure overshoots into frame 6.
    for j in (0, 5, 6, 9):
        assert np.all(np.isnan(res.scales[j]))
    assert res.reference == 1
    assert res.status[1] == "reference"
    assert np.all(np.isfinite(res.radiance))
    assert res.observed.any() and not res.observed.all()
    doc = json.loads((tmp_path / "out" / "exposures.json").read_text())
    assert doc["frames"][0]["scale"] is None and doc["frames"][9]["scale"] is None
    assert doc["warnings"]
    good = [j for j in range(N_FRAMES) if j not in (0, 5, 6, 9)]
    assert np.all(np.isfinite(res.scales[good]))
    truth = np.asarray(
        [
            fr["scale"]
            for fr in json.loads((scan / "ground_truth/ground_truth.json").read_text())["frames"]
        ]
    )
    ratio = res.scales[good] / (truth[good] / truth[1])
    assert np.median(np.abs(ratio - 1)) < 0.02
    ev = evaluate_hdr(scan, tmp_path / "out")
    assert ev["methods"]["ours"]["exposure_ratio_error"]["frames_without_exposure"] == 4


def test_scan_without_any_usable_frame(tmp_path):
    v, f = box_room(SIZE, spacing=0.3, obstacle=False)
    poses = loop_poses(3)
    black = np.zeros((36, 48, 3), np.uint8)
    scan = write_projected_scan(
        tmp_path / "scan",
        v,
        f,
        room_radiance(v),
        poses,
        Intrinsics.from_fov(48, 36, 75.0),
        images_override={0: black, 1: black, 2: black},
    )
    with pytest.warns(UserWarning):
        res = run_hdr(scan, tmp_path / "out", HdrOptions(render_size=(64, 48)))
    assert np.all(np.isnan(res.scales)) and not res.observed.any()
    assert np.all(res.radiance == 0)
    doc = json.loads((tmp_path / "out" / "exposures.json").read_text())
    assert all(fr["scale"] is None for fr in doc["frames"])


def test_bad_options_and_missing_scan(scan_dir, tmp_path):
    with pytest.raises(ScanError):
        run_hdr(tmp_path / "nope", tmp_path / "out")
    with pytest.raises(ReroomError, match="unknown response"):
        run_hdr(scan_dir, tmp_path / "out", HdrOptions(response="cubic"))
    with pytest.raises(ReroomError, match="unknown solver"):
        run_hdr(scan_dir, tmp_path / "out", HdrOptions(solve=SolveOptions(method="x")))


def test_vertex_exr_round_trip_and_bad_input(tmp_path):
    from reroom.hdr.vertex_exr import write_vertex_exr

    rng = np.random.default_rng(0)
    rad = (rng.random((2500, 3)) * 1e4).astype(np.float32)  # HDR: values far above 1
    obs = rng.random(2500) > 0.3
    write_vertex_exr(tmp_path / "v.exr", rad, obs)
    back, back_obs = read_vertex_exr(tmp_path / "v.exr", 2500)
    np.testing.assert_array_equal(back, rad)
    np.testing.assert_array_equal(back_obs, obs)
    with pytest.raises(ValueError, match="not a vertex image of 9000 vertices"):
        read_vertex_exr(tmp_path / "v.exr", 9000)
    with pytest.raises(ValueError, match=r"expected \(V, 3\)"):
        write_vertex_exr(tmp_path / "bad.exr", rad[:, :2], obs)
    assert not (tmp_path / "bad.exr").exists()
