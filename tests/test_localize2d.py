"""Tests of 2D light localization (thesis ch. 6) on cases with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from reroom.errors import ReroomError
from reroom.localize import (
    FieldGrid,
    FieldProposer2D,
    LocalizeError,
    Measurements,
    RefineParams,
    Room2D,
    VoteParams,
    WallSamples,
    associate,
    box_room,
    find_candidates,
    fit_lights,
    fit_lights_lm,
    intensity_distance_field,
    limiter_count_field,
    localize_lights,
    make_scene,
    matches_truth,
    mean_squared_error,
    medial_axis,
    plot_fields,
    prune_lights,
    random_lights,
    render_room,
    sample_walls,
    settings_for,
    shading_jacobian,
    shading_matrix,
    single_round,
    solve_intensities,
    visibility_2d,
    voting_field,
)
from reroom.localize.fields import ring_offsets
from reroom.localize.scene2d import light_bounds

BOUNDS = (np.full(2, 1e-3), np.full(2, 1.0 - 1e-3))


@pytest.fixture(scope="module")
def room() -> Room2D:
    return box_room(1.0)


@pytest.fixture(scope="module")
def walls(room: Room2D) -> WallSamples:
    return sample_walls(room, 400)


def pixel_centre(grid: FieldGrid, i: int, j: int) -> np.ndarray:
    return grid.centres()[i, j]


# ---------------------------------------------------------------------------------------
# Shading model and scene


def test_shading_matches_hand_computation() -> None:
    # Wall point at the origin facing +y, light at (3, 4): cos = 4/5, r^2 = 25.
    s = shading_matrix([[0.0, 0.0]], [[0.0, 1.0]], [[3.0, 4.0]])
    assert s[0, 0] == pytest.approx(0.8 / 25.0)
    # Behind the surface: no light.
    assert shading_matrix([[0.0, 0.0]], [[0.0, 1.0]], [[3.0, -4.0]])[0, 0] == 0.0
    # The same formula in 3D.
    s3 = shading_matrix([[0.0, 0.0, 0.0]], [[0.0, 0.0, 1.0]], [[0.0, 3.0, 4.0]])
    assert s3[0, 0] == pytest.approx(0.8 / 25.0)


def test_shading_jacobian_matches_finite_differences() -> None:
    rng = np.random.default_rng(3)
    pts = rng.uniform(-1, 1, (20, 3))
    nrm = rng.normal(size=(20, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    pos = rng.uniform(-1, 1, (2, 3)) * 3
    s, ds = shading_jacobian(pts, nrm, pos)
    eps = 1e-6
    for k in range(2):
        for c in range(3):
            dp = pos.copy()
            dp[k, c] += eps
            num = (shading_matrix(pts, nrm, dp)[:, k] - s[:, k]) / eps
            np.testing.assert_allclose(ds[:, k, c], num, rtol=1e-4, atol=1e-6)


def test_sample_walls_evenly_spaced_with_inward_normals(room: Room2D, walls: WallSamples) -> None:
    assert len(walls) == 400
    assert walls.loop_lengths[0] == pytest.approx(4.0)
    np.testing.assert_allclose(np.diff(walls.arc), 0.01)
    inside = walls.points + 0.01 * walls.normals
    assert room.contains(inside).all()
    assert np.all(room.distance_to_surfaces(walls.points) < 1e-12)


def test_occlusion_against_hand_computed_case() -> None:
    # A 2 x 1 room with a pillar [0.9, 1.1] x [0.3, 0.7] in the middle.
    room = Room2D(
        np.array([[0, 0], [2, 0], [2, 1], [0, 1.0]]),
        (np.array([[0.9, 0.3], [1.1, 0.3], [1.1, 0.7], [0.9, 0.7]]),),
    )
    sites = Measurements(
        np.array([[0.0, 0.5], [2.0, 0.5], [1.0, 0.0]]),
        np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0]]),
        np.zeros(3),
    )
    light = np.array([[0.5, 0.5]])
    vis = visibility_2d(room, sites, light)
    # The left wall sees the light; the right wall is behind the pillar; the floor
    # point (1, 0) sees (0.5, 0.5) past the pillar's lower-left corner (0.9, 0.3)? The
    # segment from (1, 0) to (0.5, 0.5) passes x = 0.9 at y = 0.1 < 0.3: visible.
    np.testing.assert_array_equal(vis[:, 0], [True, False, True])
    b = render_room(room, sites, light, [2.0])
    assert b[0] == pytest.approx(2.0 * 1.0 / 0.25)  # cos 1, r = 0.5
    assert b[1] == 0.0
    assert b[2] == pytest.approx(2.0 * (0.5 / np.sqrt(0.5)) / 0.5)  # cos 1/sqrt2, r^2 = 0.5


def test_idf_with_occlusion_matches_explicit_loop() -> None:
    room = Room2D(
        np.array([[0, 0], [1, 0], [1, 1], [0, 1.0]]),
        (np.array([[0.4, 0.4], [0.6, 0.4], [0.6, 0.6], [0.4, 0.6]]),),
    )
    walls = sample_walls(room, 40)
    grid = FieldGrid.for_room(room, 16)
    # One light left of the pillar: the right wall behind the pillar is in shadow, B = 0.
    light = grid.centres()[8, 3]
    b = render_room(room, walls, [light], [1.0])
    assert np.any(b == 0)
    d, lim = intensity_distance_field(room, walls, b, grid)
    centres = grid.centres().reshape(-1, 2)
    vis = visibility_2d(room, walls, centres)
    s = shading_matrix(walls.points, walls.normals, centres, vis)
    with np.errstate(divide="ignore", invalid="ignore"):
        inten = np.where(s > 0, b[:, None] / s, np.inf)
    free = room.contains(grid.centres()).ravel()
    expect_d = np.where(free, inten.min(axis=0), np.nan).reshape(grid.shape)
    expect_l = np.where(free, inten.argmin(axis=0), -1).reshape(grid.shape)
    np.testing.assert_allclose(d, expect_d, rtol=1e-12)
    # At the light's own pixel every visible site ties (I = 1): rounding picks the limiter.
    tie = np.zeros(grid.shape, dtype=bool)
    tie[8, 3] = True
    np.testing.assert_array_equal(lim[~tie], expect_l[~tie])
    # The light's own pixel: the shadowed wall cannot see it, so it does not bound it,
    # and D there is exactly the light's intensity; ignoring occlusion would give 0.
    assert d[8, 3] == pytest.approx(1.0, rel=1e-12)
    s_free = shading_matrix(walls.points, walls.normals, [light])[:, 0]
    assert np.min(np.where(s_free > 0, b / np.maximum(s_free, 1e-300), np.inf)) == 0.0


# ---------------------------------------------------------------------------------------
# The fields


@pytest.mark.parametrize("ij", [(60, 100), (200, 30), (128, 128)])
def test_idf_peaks_at_a_single_light_with_its_intensity(room, walls, ij) -> None:
    """One light: ``I(q, p1) = I1`` for every q, so ``D(p1) = I1``; elsewhere ``D < I1``
    (the wall point where the ray from p1 through p exits is closer to p than to p1 at
    the same angle, so it bounds p below I1)."""
    grid = FieldGrid.for_room(room, 256)
    p1 = pixel_centre(grid, *ij)
    b = render_room(room, walls, [p1], [2.5])
    d, lim = intensity_distance_field(room, walls, b, grid)
    assert d[ij] == pytest.approx(2.5, rel=1e-12)
    others = d.copy()
    others[ij] = -np.inf
    assert np.nanmax(others) < 2.5
    assert lim.min() >= 0


def test_tiled_idf_equals_brute_force(room, walls) -> None:
    grid = FieldGrid.for_room(room, 96)
    rng = np.random.default_rng(7)
    for _ in range(3):
        pos, inten = random_lights(4, rng)
        b = render_room(room, walls, pos, inten)
        b = np.maximum(b - 0.8 * render_room(room, walls, pos[:2], inten[:2]), 0.0)
        d1, l1 = intensity_distance_field(room, walls, b, grid, method="brute")
        d2, l2 = intensity_distance_field(room, walls, b, grid, method="tiled")
        np.testing.assert_array_equal(l1, l2)
        np.testing.assert_allclose(d1, d2, rtol=1e-12)
    # A window is the same as the corresponding part of the whole field.
    dw, lw = intensity_distance_field(room, walls, b, grid, window=(10, 30, 40, 70))
    np.testing.assert_array_equal(lw, l2[10:30, 40:70])


def line_samples(n: int, spacing: float = 1.0) -> WallSamples:
    """n sites on one closed loop of length n * spacing (positions unused by the votes)."""
    return WallSamples(
        np.zeros((n, 2)),
        np.tile([0.0, 1.0], (n, 1)),
        np.arange(n) * spacing,
        np.zeros(n, dtype=np.int64),
        np.array([n * spacing]),
    )


def test_ring_offsets_are_the_eight_neighbours_clockwise() -> None:
    ring = ring_offsets(1)
    assert len(ring) == 8
    assert {tuple(o) for o in ring} == {
        (a, b) for a in (-1, 0, 1) for b in (-1, 0, 1) if (a, b) != (0, 0)
    }
    ang = np.arctan2(ring[:, 0], ring[:, 1])
    assert np.all(np.diff(np.unwrap(ang)) < 0)  # clockwise (rows point up)
    steps = np.abs(np.diff(np.vstack([ring, ring[:1]]), axis=0)).max(axis=1)
    assert np.all(steps == 1)  # a closed chain of 8-neighbours
    ring15 = ring_offsets(15)
    steps = np.abs(np.diff(np.vstack([ring15, ring15[:1]]), axis=0)).max(axis=1)
    assert np.all(steps == 1)


def test_voting_function_on_hand_built_limiters() -> None:
    samples = line_samples(100)
    lim = np.zeros((3, 3), dtype=np.int64)
    ring = ring_offsets(1)
    # Limiters around the centre pixel, in ring order: steps 2, 0 (same), 3, 40 (a jump
    # over the threshold), and the loop wraps: 99 -> 1 is 2 the short way round.
    values = [10, 12, 12, 15, 55, 57, 99, 1]
    for (di, dj), v in zip(ring, values, strict=True):
        lim[1 + di, 1 + dj] = v
    v = voting_field(lim, samples, radius=1, threshold=10.0)
    # Steps: 12-10=2, 0, 3, 40 (dropped), 2, 42 (dropped), 2 (wrap), 9 (1 -> 10).
    assert v[1, 1] == pytest.approx((2 + 3 + 2 + 2 + 9) / 5)
    # The medial axis at the same threshold: a jump above 10 exists around the centre.
    assert medial_axis(lim, samples, threshold=10.0)[1, 1]
    assert not medial_axis(lim, samples, threshold=50.0)[1, 1]
    # A constant field has no votes at all.
    assert np.all(voting_field(np.full((5, 5), 3), samples, 1, 10.0) == 0)


def test_limiter_count_is_the_number_of_distinct_limiters_in_the_disc() -> None:
    rng = np.random.default_rng(0)
    lim = rng.integers(-1, 30, size=(40, 50))
    for r in (1, 3, 7):
        got = limiter_count_field(lim, r, 30)
        for i, j in [(0, 0), (20, 25), (39, 49), (5, 44)]:
            if lim[i, j] < 0:
                assert got[i, j] == 0
                continue
            ii, jj = np.mgrid[:40, :50]
            disc = np.hypot(ii - i, jj - j) <= r + 0.5
            vals = lim[disc]
            assert got[i, j] == len(set(vals[vals >= 0].tolist()))


def test_candidates_are_local_maxima_above_a_decaying_threshold() -> None:
    v = np.zeros((40, 40))
    v[10, 10] = 5.0
    v[30, 30] = 3.0
    v[30, 32] = 2.9  # within the merge distance of (30, 30)
    v[10, 30] = 1.0
    centres = np.stack(np.meshgrid(np.arange(40.0), np.arange(40.0))[::-1], axis=-1)
    valid = np.ones(v.shape, dtype=bool)
    # H starts at 8 and halves: 4 lets only the strongest peak through.
    pos, h = find_candidates(v, centres, valid, 1, 8.0, 3.0, decay=0.5)
    np.testing.assert_array_equal(pos, [[10, 10]])
    # H = 6 lets nothing through, 3 lets 5 and 3 through; 2.9 is merged into 3.
    pos, h = find_candidates(v, centres, valid, 1, 6.0, 3.0, decay=0.5)
    np.testing.assert_array_equal(pos, [[10, 10], [30, 30]])
    np.testing.assert_array_equal(h, [5.0, 3.0])
    # Invalid pixels (near a surface) never become candidates.
    valid[10, 10] = False
    pos, _ = find_candidates(v, centres, valid, 1, 8.0, 3.0, decay=0.5)
    assert [10, 10] not in pos.tolist()


def test_voting_peaks_at_lights_in_a_two_light_scene(room, walls) -> None:
    scene = make_scene(2, 1)
    prop = FieldProposer2D(scene.room, scene.samples, 256, VoteParams())
    cand = prop(scene.values)
    dist = np.linalg.norm(cand[:, None, :] - scene.positions[None], axis=-1)
    # Every candidate is near a true light (no false peaks in this scene).
    assert np.all(dist.min(axis=1) < 0.05)


# ---------------------------------------------------------------------------------------
# Fitting and refinement


def test_linear_and_nonlinear_fits_recover_known_lights(room, walls) -> None:
    pos = np.array([[0.3, 0.4], [0.7, 0.65]])
    inten = np.array([2.0, 3.5])
    meas = walls.measurements(render_room(room, walls, pos, inten))
    np.testing.assert_allclose(solve_intensities(meas, pos), inten, rtol=1e-9)
    start = pos + np.array([[0.03, -0.02], [-0.02, 0.03]])
    for fit in (fit_lights, fit_lights_lm):
        p, i, err = fit(meas, start, [1.0, 1.0], BOUNDS)
        order = np.argsort(p[:, 0])
        np.testing.assert_allclose(p[order], pos, atol=1e-6)
        np.testing.assert_allclose(i[order], inten, rtol=1e-6)
        assert err < 1e-10


def test_associate_splits_matches_and_new_candidates() -> None:
    hyp = np.array([[0.2, 0.2], [0.8, 0.8]])
    cand = np.array([[0.21, 0.2], [0.5, 0.5]])
    matched, new = associate(hyp, cand, 0.05)
    np.testing.assert_array_equal(matched, [0])
    np.testing.assert_array_equal(new, [[0.5, 0.5]])
    matched, new = associate(np.zeros((0, 2)), cand, 0.05)
    assert matched.size == 0 and len(new) == 2


@pytest.mark.parametrize(("n_lights", "index"), [(2, 0), (2, 3), (3, 0), (3, 2)])
def test_refinement_recovers_noiseless_scenes_exactly(n_lights: int, index: int) -> None:
    scene = make_scene(n_lights, index)
    prop = FieldProposer2D(scene.room, scene.samples, 256, VoteParams())
    meas = scene.samples.measurements(scene.values)
    res = localize_lights(meas, prop, BOUNDS, scene.tolerance, RefineParams())
    assert res.success, res.reason
    assert matches_truth(
        res.positions, res.intensities, scene.positions, scene.intensities, 1e-4, 1e-4
    )
    assert res.mse < 1e-12


def test_prune_merges_a_light_split_into_coincident_halves(room, walls) -> None:
    # An exact solution with one light given as two coincident halves (Table 6.1, 4 lights,
    # room 3 ended so): both fits are exact to rounding, so the lone light must win.
    pos = np.array([[0.3, 0.4], [0.7, 0.65]])
    inten = np.array([2.0, 3.5])
    meas = walls.measurements(render_room(room, walls, pos, inten))
    doubled = np.concatenate([pos, pos[1:]])
    halves = np.array([2.0, 1.75, 1.75])
    assert mean_squared_error(meas, doubled, halves) < 1e-20
    p, i, err = prune_lights(meas, doubled, halves, BOUNDS, 0.0025)
    assert matches_truth(p, i, pos, inten, 1e-6, 1e-6)
    assert err < 1e-12


def test_refinement_reports_no_duplicate_light_in_table_room() -> None:
    scene = make_scene(4, 3)
    vote, refine = settings_for(0.0)
    prop = FieldProposer2D(scene.room, scene.samples, 256, vote)
    meas = scene.samples.measurements(scene.values)
    bounds = light_bounds(scene.room, scene.samples)
    res = localize_lights(meas, prop, bounds, scene.tolerance, refine)
    assert res.success, res.reason
    assert matches_truth(res.positions, res.intensities, scene.positions, scene.intensities)


def test_single_round_and_noise(room, walls) -> None:
    scene = make_scene(2, 1, noise=0.05)
    assert scene.truth_mse > 0
    assert scene.tolerance == pytest.approx(1.05 * scene.truth_mse)
    prop = FieldProposer2D(scene.room, scene.samples, 128, VoteParams(method="count", radius=8))
    res = single_round(scene.samples.measurements(scene.values), prop, BOUNDS, scene.tolerance)
    assert res.positions.shape[1] == 2 and np.isfinite(res.mse)


# ---------------------------------------------------------------------------------------
# Dataset and pictures


def test_dataset_is_deterministic_and_respects_spacing() -> None:
    a, b = make_scene(5, 17), make_scene(5, 17)
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.values, b.values)
    noisy = make_scene(5, 17, noise=0.05)
    np.testing.assert_array_equal(noisy.positions, a.positions)
    assert not np.array_equal(noisy.values, a.values)
    rng = np.random.default_rng(1)
    for _ in range(20):
        pos, inten = random_lights(5, rng)
        assert np.all((pos >= 0.05) & (pos <= 0.95))
        gaps = np.linalg.norm(pos[:, None] - pos[None], axis=-1) + np.eye(5)
        assert gaps.min() >= 0.05
        assert np.all((inten >= 1) & (inten <= 5))


def test_matches_truth() -> None:
    t = np.array([[0.2, 0.2], [0.6, 0.7]])
    assert matches_truth(t[::-1] + 0.01, [3.0, 2.0], t, [2.0, 3.0])
    assert not matches_truth(t[:1], [2.0], t, [2.0, 3.0])
    assert not matches_truth(t, [2.0, 3.5], t, [2.0, 3.0])
    assert not matches_truth(t + 0.03, [2.0, 3.0], t, [2.0, 3.0])


def test_plot_fields_writes_a_png(tmp_path, room, walls) -> None:
    b = render_room(room, walls, [[0.3, 0.3], [0.6, 0.7]], [2.0, 3.0])
    out = plot_fields(room, walls, b, tmp_path / "f.png", [[0.3, 0.3]], [[0.31, 0.3]], 64)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# ---------------------------------------------------------------------------------------
# Bad input


def test_bad_input_raises_clear_errors(room, walls) -> None:
    with pytest.raises(LocalizeError, match="non-empty"):
        Measurements(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))
    with pytest.raises(LocalizeError, match="unit length"):
        Measurements([[0.0, 0.0]], [[0.0, 2.0]], [1.0])
    with pytest.raises(LocalizeError, match="finite"):
        Measurements([[0.0, 0.0]], [[0.0, 1.0]], [np.nan])
    with pytest.raises(LocalizeError, match="values have shape"):
        Measurements([[0.0, 0.0]], [[0.0, 1.0]], [1.0, 2.0])
    with pytest.raises(LocalizeError, match="at least one measurement"):
        sample_walls(room, 0)
    with pytest.raises(LocalizeError, match="inside the room"):
        render_room(room, walls, [[1.5, 0.5]], [1.0])
    with pytest.raises(LocalizeError, match="values for"):
        intensity_distance_field(room, walls, np.ones(3), FieldGrid.for_room(room, 16))
    off = WallSamples(walls.points + 0.1, walls.normals, walls.arc, walls.loop, walls.loop_lengths)
    with pytest.raises(LocalizeError, match="not on a surface"):
        FieldProposer2D(room, off, 32)
    flipped = WallSamples(walls.points, -walls.normals, walls.arc, walls.loop, walls.loop_lengths)
    with pytest.raises(LocalizeError, match="point out of the room"):
        FieldProposer2D(room, flipped, 32)
    with pytest.raises(LocalizeError, match="voting method"):
        FieldProposer2D(room, walls, 32, VoteParams(method="vote"))
    meas = walls.measurements(np.ones(len(walls)))
    with pytest.raises(LocalizeError, match="tolerance"):
        localize_lights(meas, FieldProposer2D(room, walls, 32), BOUNDS, 0.0)
    with pytest.raises(LocalizeError, match="zero area"):
        Room2D(np.array([[0, 0], [1, 0], [2, 0.0]]))
    # Every error is a ReroomError, so the CLI reports it in one line.
    assert issubclass(LocalizeError, ReroomError)
