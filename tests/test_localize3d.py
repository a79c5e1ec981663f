"""3D light localization: fields on known one-light scenes, voting, refinement in boxes."""

from __future__ import annotations

import numpy as np
import pytest

from reroom.localize import LocalizeError, Measurements, RefineParams, localize_lights, render
from reroom.localize.fields3d import (
    VoxelGrid,
    find_peaks_3d,
    intensity_distance_field_3d,
    limiter_count_3d,
)
from reroom.localize.scene3d import (
    FieldProposer3D,
    box_light_bounds,
    box_measurements,
    box_valid_mask,
)

UNIT = VoxelGrid.for_box([0, 0, 0], [1, 1, 1], 1 / 32)


def _box_scene(lights, intensities, per_side=16):
    pts, nrm = box_measurements(1.0, per_side)
    return Measurements(pts, nrm, render(pts, nrm, lights, intensities))


def test_box_measurements_face_inwards():
    pts, nrm = box_measurements([2.0, 3.0, 1.0], 4)
    assert pts.shape == (96, 3)
    centre = np.array([1.0, 1.5, 0.5])
    assert np.all(np.einsum("ij,ij->i", centre - pts, nrm) > 0)
    assert np.allclose(np.linalg.norm(nrm, axis=1), 1.0)


def test_voxel_grid_round_trip():
    c = UNIT.centres()
    assert c.shape == (32, 32, 32, 3)
    idx = UNIT.to_index(c[3, 5, 7])
    assert tuple(idx) == (3, 5, 7)
    w = UNIT.window(c[0, 0, 0], 2 / 32)
    assert [s.start for s in w] == [0, 0, 0] and [s.stop for s in w] == [3, 3, 3]


def test_one_light_idf_peaks_at_the_light_with_its_intensity():
    # A light on a voxel centre: D there is exactly its intensity (every site bounds it
    # by I), and lower everywhere else in the convex box (eq. 6.5 and docs/localize.md).
    light = UNIT.centres()[10, 14, 20]
    meas = _box_scene([light], [3.0])
    d, lim = intensity_distance_field_3d(meas, UNIT)
    assert d[10, 14, 20] == pytest.approx(3.0, rel=1e-12)
    others = np.delete(d.ravel(), np.ravel_multi_index((10, 14, 20), d.shape))
    assert np.all(others < 3.0 * (1 - 1e-9))
    assert lim.min() >= 0


def test_tiled_field_equals_brute_force():
    rng = np.random.default_rng(3)
    meas = _box_scene(rng.uniform(0.2, 0.8, (3, 3)), [1.0, 2.0, 4.0], per_side=10)
    grid = VoxelGrid.for_box([0, 0, 0], [1, 1, 1], 1 / 20)
    window = (slice(2, 17), slice(0, 20), slice(5, 13))
    for w in (None, window):
        d1, l1 = intensity_distance_field_3d(meas, grid, w)
        d2, l2 = intensity_distance_field_3d(meas, grid, w, method="brute")
        assert np.array_equal(l1, l2)
        assert np.array_equal(d1, d2)


def test_idf_rejects_2d_measurements():
    meas = Measurements(np.zeros((2, 2)), np.array([[1.0, 0.0], [0.0, 1.0]]), np.ones(2))
    with pytest.raises(LocalizeError, match="3D fields"):
        intensity_distance_field_3d(meas, UNIT)


def test_limiter_count_exact_cases():
    same = np.zeros((6, 6, 6), dtype=np.int32)
    assert np.all(limiter_count_3d(same, 1) == 1)
    distinct = np.arange(216, dtype=np.int32).reshape(6, 6, 6)
    counts = limiter_count_3d(distinct, 1)
    # Radius 1 and the +1/2 rule (|offset|^2 <= 2.25): the centre, 6 face and 12 edge
    # neighbours; a corner voxel keeps 3 face and 3 edge neighbours.
    assert counts[3, 3, 3] == 19
    assert counts[0, 0, 0] == 7
    none = np.full((4, 4, 4), -1, dtype=np.int32)
    assert np.all(limiter_count_3d(none, 2) == 0)


def test_find_peaks_levels_and_merging():
    c = UNIT.centres()
    v = np.zeros(UNIT.shape)
    v[8, 8, 8] = 10.0
    v[9, 8, 8] = 9.5  # beaten by its neighbour: not a maximum
    v[24, 24, 24] = 9.9  # at or above the level (100 * 0.9^22 = 9.85): proposed too
    v[24, 8, 8] = 2.0  # far below the level: not proposed
    valid = np.ones(UNIT.shape, dtype=bool)
    pos, h = find_peaks_3d(v, c, valid, 1, 100.0, 0.05, 0.9)
    assert np.allclose(h, [10.0, 9.9])
    assert np.allclose(pos[0], c[8, 8, 8]) and np.allclose(pos[1], c[24, 24, 24])
    # Merging: a peak within the merge distance of a stronger one goes.
    pos, _ = find_peaks_3d(v, c, valid, 1, 100.0, 1.0, 0.9)
    assert len(pos) == 1
    # Invalid voxels (near surfaces) hold no candidate.
    valid[8, 8, 8] = False
    pos, _ = find_peaks_3d(v, c, valid, 1, 100.0, 0.05, 0.9)
    assert np.allclose(pos[0], c[24, 24, 24])


def test_count_votes_peak_near_a_lone_light():
    light = np.array([0.3, 0.55, 0.62])
    meas = _box_scene([light], [2.0], per_side=20)
    valid = box_valid_mask(UNIT, 1.0, 0.04)
    prop = FieldProposer3D(meas.points, meas.normals, UNIT, valid, np.sqrt(3) / 2)
    cand = prop(meas.values)
    assert np.linalg.norm(cand[0] - light) < 2.5 / 32
    near = prop(meas.values, near=light + 0.05, within=0.1)
    assert np.linalg.norm(near[0] - light) < 2.5 / 32


@pytest.mark.slow  # 50-300 s on a loaded 2-core machine (the nonlinear solves on 1536 sites)
@pytest.mark.parametrize(
    "lights, intensities",
    [
        ([[0.3, 0.35, 0.6], [0.7, 0.65, 0.3]], [2.0, 3.5]),
        ([[0.25, 0.3, 0.3], [0.7, 0.3, 0.7], [0.5, 0.75, 0.45]], [1.5, 3.0, 2.0]),
    ],
)
def test_refinement_finds_two_and_three_lights(lights, intensities):
    lights = np.asarray(lights)
    meas = _box_scene(lights, intensities)
    valid = box_valid_mask(UNIT, 1.0, 0.04)
    prop = FieldProposer3D(meas.points, meas.normals, UNIT, valid, np.sqrt(3) / 2)
    res = localize_lights(
        meas,
        prop,
        box_light_bounds(1.0),
        1e-8 * float(np.mean(meas.values**2)),
        RefineParams(match_distance=0.087, max_iterations=50),
    )
    assert res.success, res.reason
    assert len(res.positions) == len(lights)
    dist = np.linalg.norm(res.positions[:, None] - lights[None], axis=-1)
    assert np.all(dist.min(axis=0) < 1e-3)
    order = dist.argmin(axis=0)
    assert np.allclose(res.intensities[order], intensities, rtol=1e-3)


def test_refinement_finds_two_lights_on_a_coarse_box():
    # The fast companion of the slow test above: 864 sites, 32^3 voxels (about 10 s).
    lights = np.array([[0.3, 0.35, 0.6], [0.7, 0.65, 0.3]])
    meas = _box_scene(lights, [2.0, 3.5], per_side=12)
    prop = FieldProposer3D(meas.points, meas.normals, UNIT, box_valid_mask(UNIT, 1.0, 0.04), 0.866)
    res = localize_lights(
        meas,
        prop,
        box_light_bounds(1.0),
        1e-8 * float(np.mean(meas.values**2)),
        RefineParams(match_distance=0.087, max_iterations=50),
    )
    assert res.success and len(res.positions) == 2, res.reason
    dist = np.linalg.norm(res.positions[:, None] - lights[None], axis=-1)
    assert np.all(dist.min(axis=0) < 1e-3)


def test_localize_scan_names_the_missing_stage(tmp_path):
    from reroom.errors import ReroomError
    from reroom.localize.scan import localize_scan

    with pytest.raises(ReroomError, match=r"hdr_mesh\.ply: missing \(run `reroom hdr"):
        localize_scan(tmp_path)


def test_localized_lights_are_written_in_the_light_schema(tmp_path):
    from reroom.lights.lightset import load_lights
    from reroom.localize.scan import LOCALIZED_REASON, ScanLocalizeResult, write_localized_lights

    res = ScanLocalizeResult(
        np.array([[1.0, 2.0, 2.5]]), np.array([3.0]), {"wall": 0.6}, {}, 0.1, 0.1
    )
    path = write_localized_lights(res, {"albedo": {"wall": 0.6}}, tmp_path)
    lights = load_lights(path)
    (light,) = lights.lights
    assert light.type == "point" and light.source == "localize"
    assert light.reason == LOCALIZED_REASON
    assert light.geometry["position"] == [1.0, 2.0, 2.5]
    assert light.evidence["intensity"] == 3.0
    assert (tmp_path / "localize.json").is_file()


def test_plot_fields_3d_draws_one_row_per_light(tmp_path):
    from PIL import Image

    from reroom.localize import plot_fields_3d

    lights = np.array([[0.3, 0.35, 0.6], [0.7, 0.65, 0.3]])
    meas = _box_scene(lights, [2.0, 3.5], per_side=8)
    grid = VoxelGrid.for_box([0, 0, 0], [1, 1, 1], 1 / 16)
    prop = FieldProposer3D(meas.points, meas.normals, grid, box_valid_mask(grid, 1.0, 0.04), 0.866)
    path = plot_fields_3d(prop, meas.values, tmp_path / "f.png", lights, lights + 0.01)
    with Image.open(path) as im:
        w, h = im.size
    assert h > 1.5 * w / 3  # two rows of three panels
