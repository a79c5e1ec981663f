"""Weighted-median reprojection, the baselines and the seam metric."""

from __future__ import annotations

import numpy as np
import pytest

from reroom.hdr.baselines import frame_to_frame, frame_to_model
from reroom.hdr.metrics import (
    SeamSamples,
    boundary_pairs,
    boundary_seam,
    flat_vertices,
    seam_metric,
)
from reroom.hdr.observe import Observations, encode_linear
from reroom.hdr.reproject import (
    CONFIDENCE_FLOOR,
    BestFrame,
    best_frame_texture,
    reproject_radiance,
)
from reroom.hdr.solve import hat_confidence

LINEAR = np.arange(256) / 255.0


def brute_weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    order = np.argsort(values, kind="stable")
    cum = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cum, 0.5 * cum[-1])])


def test_weighted_median_matches_brute_force():
    rng = np.random.default_rng(0)
    nv, nf = 50, 20
    vi = np.concatenate([np.full(rng.integers(1, 12), v) for v in range(nv)])
    fj = rng.integers(0, nf, len(vi))
    # One sample per (vertex, frame): deduplicate.
    _, uniq = np.unique(vi * nf + fj, return_index=True)
    vi, fj = vi[uniq], fj[uniq]
    levels = rng.integers(0, 256, (len(vi), 3)).astype(np.uint8)
    g = rng.uniform(0.1, 2.0, len(vi)).astype(np.float32)
    scales = rng.uniform(0.5, 2.0, (nf, 3))
    scales[3] = np.nan  # a frame without exposure: its samples are left out
    obs = Observations.from_arrays(nv, nf, vi, fj, levels, g)
    rad = reproject_radiance(obs, scales)
    conf = np.maximum(hat_confidence(np.arange(256)), CONFIDENCE_FLOOR)
    for v in range(nv):
        sel = (obs.vertex == v) & (obs.frame != 3)
        assert rad.sample_count[v] == sel.sum()
        assert rad.observed[v] == (sel.sum() > 0)
        for c in range(3):
            if not sel.any():
                assert rad.radiance[v, c] == 0.0
                continue
            vals = obs.linear_values(sel)[:, c] / scales[obs.frame[sel], c]
            w = conf[obs.value[sel, c]] * obs.geometry[sel]
            expected = brute_weighted_median(vals, w.astype(np.float64))
            assert rad.radiance[v, c] == pytest.approx(expected, rel=1e-12)
    assert np.all(np.isfinite(rad.radiance))


def test_unobserved_black_and_saturated_vertices():
    # vertex 0: never seen; 1: seen black only; 2: saturated only; 3: seen once.
    vi = np.array([1, 1, 2, 3])
    fj = np.array([0, 1, 0, 1])
    levels = np.array([[0, 0, 0], [0, 0, 0], [255, 255, 255], [100, 100, 100]], np.uint8)
    obs = Observations.from_arrays(4, 2, vi, fj, levels)
    rad = reproject_radiance(obs, np.array([[1.0] * 3, [2.0] * 3]))
    assert rad.observed.tolist() == [False, True, True, True]
    assert rad.sample_count.tolist() == [0, 2, 1, 1]
    np.testing.assert_allclose(rad.radiance[0], 0.0)
    np.testing.assert_allclose(rad.radiance[1], 0.0)
    np.testing.assert_allclose(rad.radiance[2], 1.0)  # a lower bound, but not black
    np.testing.assert_allclose(rad.radiance[3], 100 / 255 / 2, rtol=1e-4)
    best = best_frame_texture(obs)
    assert best.frame.tolist() == [-1, 0, 0, 1]
    assert best.value[3].tolist() == [100, 100, 100]


def test_empty_observations():
    obs = Observations.from_arrays(3, 2, np.zeros(0), np.zeros(0), np.zeros((0, 3)))
    rad = reproject_radiance(obs, np.ones((2, 3)))
    assert not rad.observed.any() and np.all(rad.radiance == 0)
    assert np.all(best_frame_texture(obs).frame == -1)


def strip_observations(t: np.ndarray, b: np.ndarray, window: int = 40, step: int = 10):
    vi, fj = [], []
    for j in range(len(t)):
        vs = np.arange(window) + j * step
        vi.append(vs[vs < len(b)])
        fj.append(np.full(len(vi[-1]), j))
    vi, fj = np.concatenate(vi), np.concatenate(fj)
    return vi, fj


def test_baselines_exact_without_noise():
    rng = np.random.default_rng(1)
    nf, nv = 15, 200
    t = np.exp(rng.normal(0, 0.3, (nf, 3)))
    t /= t[0]
    b = rng.uniform(0.2, 0.5, (nv, 3))
    vi, fj = strip_observations(t, b)
    x = t[fj] * b[vi]
    levels = np.round(x / x.max() * 250).astype(np.uint8)
    obs = Observations.from_arrays(nv, nf, vi, fj, levels)
    for fn in (frame_to_frame, frame_to_model):
        s, info = fn(obs)
        assert s.shape == (nf, 3)
        np.testing.assert_allclose(s[0], 1.0)
        # Quantised to 8 bits: within a few per cent of the truth, no NaN.
        assert np.all(np.isfinite(s))
        assert np.median(np.abs(s / t - 1)) < 0.03, fn.__name__
        assert info["carried"] == 0


def test_baselines_carry_over_frames_without_overlap():
    nf, nv = 4, 120
    t = np.ones((nf, 3))
    b = np.full((nv, 3), 0.4)
    vi, fj = strip_observations(t, b, window=30, step=30)  # no overlap at all
    levels = np.full((len(vi), 3), 100, np.uint8)
    obs = Observations.from_arrays(nv, nf, vi, fj, levels)
    for fn in (frame_to_frame, frame_to_model):
        s, info = fn(obs)
        np.testing.assert_allclose(s, 1.0)
        assert info["carried"] == 3


def test_boundary_seam_sees_exposure_jumps():
    # A strip of vertices along x; frame 0 textures the left half, frame 1 the right.
    n = 40
    edges = np.stack([np.arange(n - 1), np.arange(1, n)], 1)
    frame = (np.arange(n) >= n // 2).astype(np.int64)
    true_scale = np.array([[1.0] * 3, [2.0] * 3])
    value = np.round(0.2 * true_scale[frame] * 255).astype(np.uint8)
    best = BestFrame(frame, value, encode_linear(value / 255.0))
    right = boundary_seam(edges, best, true_scale, LINEAR, min_edges=1)
    wrong = boundary_seam(edges, best, np.ones((2, 3)), LINEAR, min_edges=1)
    assert right["seam"] < 1e-4  # 8-bit levels, then 16-bit codes: not exact
    assert abs(wrong["seam"] - np.log(2)) < 0.02
    assert wrong["pairs"] == 1 and wrong["edges"] == 1
    assert boundary_seam(edges, best, true_scale, LINEAR, min_edges=5)["pairs"] == 0


def test_seam_metric_over_shared_vertices():
    """Frame 0 sees vertices 0-29, frame 1 sees 10-39; their territories meet at 20."""
    n = 40
    edges = np.stack([np.arange(n - 1), np.arange(1, n)], 1)
    rng = np.random.default_rng(0)
    b = rng.uniform(0.1, 0.3, (n, 3))
    t = np.array([[1.0, 1.0, 1.0], [1.5, 1.6, 1.4]])
    vi = np.r_[np.arange(0, 30), np.arange(10, 40)]
    fj = np.r_[np.zeros(30, int), np.ones(30, int)]
    samples = SeamSamples(vi, fj, encode_linear(t[fj] * b[vi]))
    best_frame = (np.arange(n) >= 20).astype(np.int64)
    pairs = boundary_pairs(edges, best_frame, np.ones(n, bool), 2)
    assert pairs.tolist() == [1]
    right = seam_metric(samples, pairs, t)
    assert right["pairs"] == 1 and right["vertices_pairs"] == 20
    assert right["seam"] < 1e-4
    wrong = seam_metric(samples, pairs, np.ones((2, 3)))
    assert abs(wrong["seam"] - np.log(1.5 * 0.2126 + 1.6 * 0.7152 + 1.4 * 0.0722)) < 0.02
    assert np.isnan(seam_metric(samples, pairs, t, min_gap=2)["seam"])
    assert np.isnan(seam_metric(samples, pairs, t, min_common=21)["seam"])


def test_flat_vertices():
    normals = np.array([[0, 0, 1.0], [0, 0, 1.0], [0, 1.0, 0], [0, 0, 1.0], [0, 0, 0]])
    edges = np.array([[0, 1], [1, 2], [3, 4]])
    assert flat_vertices(edges, normals).tolist() == [True, False, False, False, False]


def _noisy_bracket(radiance: float, seed: int, sigma: float = 0.25):
    """Samples of one vertex through 12 exposures with heavy multiplicative noise."""
    rng = np.random.default_rng(seed)
    scales = np.geomspace(0.2, 6.0, 12)
    vi, fj, levels = [], [], []
    for v in range(200):
        x = radiance * scales * rng.lognormal(-0.5 * sigma**2, sigma, len(scales))
        lv = np.clip(np.round(x * 255), 0, 255).astype(np.uint8)
        vi.append(np.full(len(scales), v))
        fj.append(np.arange(len(scales)))
        levels.append(np.repeat(lv[:, None], 3, axis=1))
    obs = Observations.from_arrays(
        200, len(scales), np.concatenate(vi), np.concatenate(fj), np.concatenate(levels)
    )
    return obs, np.repeat(scales[:, None], 3, axis=1)


@pytest.mark.parametrize("radiance", [0.03, 0.12])
def test_predicted_weights_remove_the_noise_selection_bias(radiance):
    # With the sample's own level in the hat weight, noise decides which samples
    # count: a vertex that saturates in the long exposures keeps the ones pulled
    # down by noise. Weights from the predicted level (and censored clips) do not.
    obs, scales = _noisy_bracket(radiance, seed=3)
    own = reproject_radiance(obs, scales).radiance[:, 1]
    predicted = reproject_radiance(obs, scales, level_linear=LINEAR).radiance[:, 1]
    # The lognormal noise has mean 1 and median exp(-sigma^2 / 2): the unbiased
    # weighted median of the samples sits at the latter.
    target = radiance * np.exp(-0.5 * 0.25**2)
    err_own = abs(np.median(own) / target - 1)
    err_pred = abs(np.median(predicted) / target - 1)
    assert err_pred < 0.02
    assert err_pred < err_own


def test_predicted_weights_reject_a_bad_lut():
    obs, scales = _noisy_bracket(0.1, seed=0)
    with pytest.raises(ValueError, match="256 non-decreasing"):
        reproject_radiance(obs, scales, level_linear=LINEAR[::-1])


def test_group_medians_match_a_sort_by_key_and_value():
    from reroom.hdr.metrics import _group_medians

    rng = np.random.default_rng(5)
    key = rng.integers(0, 300, 20_000) * 7  # sparse keys, some absent
    d = rng.normal(size=len(key))
    keys, counts, med = _group_medians(key, d)
    want = np.unique(key)
    np.testing.assert_array_equal(keys, want)
    np.testing.assert_array_equal(counts, [np.count_nonzero(key == k) for k in want])
    np.testing.assert_allclose(med, [np.median(d[key == k]) for k in want])
    # Even and odd group sizes; an empty input.
    keys, counts, med = _group_medians(np.array([4, 4, 1]), np.array([1.0, 2.0, 5.0]))
    assert keys.tolist() == [1, 4] and counts.tolist() == [1, 2] and med.tolist() == [5.0, 1.5]
    assert len(_group_medians(np.zeros(0, np.int64), np.zeros(0))[0]) == 0


def _clipped_hot_spot(box_mean: float = 0.8):
    """One bright vertex (radiance 3) clipped in all six frames, its 3x3 box reading
    ``box_mean`` (darker pixels beside a hot spot), and one (radiance 0.8) clipped in
    its two brightest frames only."""
    s = np.array([0.5, 0.6, 0.8, 1.0, 1.5, 2.0])
    vi = np.repeat([0, 1], 6)
    fj = np.tile(np.arange(6), 2)
    lv1 = np.clip(np.round(0.8 * s * 255), 0, 255)
    levels = np.repeat(np.concatenate([np.full(6, 255), lv1])[:, None], 3, axis=1)
    obs = Observations.from_arrays(2, 6, vi, fj, levels)
    clipped = obs.value[:, 0] == 255
    # A box around a hot spot: the sample's linear value is under white where it clips.
    obs.linear[clipped & (obs.vertex == 0)] = encode_linear(np.full(3, box_mean))
    return obs, np.repeat(s[:, None], 3, axis=1)


def test_a_vertex_clipped_everywhere_gets_the_median_its_bounds_allow():
    obs, scales = _clipped_hot_spot()
    first = reproject_radiance(obs, scales).radiance
    rad = reproject_radiance(obs, scales, level_linear=LINEAR).radiance
    # The first pass reads the clipped boxes (0.8 / t: 0.4-1.6); each clipped sample
    # only says "at least white / t", so the censored median is the weighted median of
    # those bounds, weighted by the levels the first pass predicts.
    conf = np.maximum(hat_confidence(np.arange(256)), CONFIDENCE_FLOOR)
    s = scales[:, 0]
    pred = np.clip(np.searchsorted(LINEAR, first[0, 0] * s), 0, 255)
    expected = brute_weighted_median(1.0 / s, conf[pred])
    assert rad[0, 0] == pytest.approx(expected, rel=1e-6)
    assert first[0, 0] < rad[0, 0] <= 2.0  # above the boxes, within the tightest bound
    # A vertex whose median is not censored keeps its estimate: the unclipped frames'.
    assert rad[1, 0] == pytest.approx(0.8, rel=0.01)


def test_a_censored_median_never_falls_below_the_first_pass():
    # Boxes at white: the bounds equal the samples, and the estimate is the first pass's
    # or above it.
    obs, scales = _clipped_hot_spot(box_mean=1.0)
    first = reproject_radiance(obs, scales).radiance
    rad = reproject_radiance(obs, scales, level_linear=LINEAR).radiance
    assert np.all(rad[0] >= first[0] - 1e-12)


def test_sample_tiers_pick_clean_then_edge_samples_and_never_foreign_ones():
    from reroom.hdr.observe import FOREIGN_FOOTPRINT, MIXED_FOOTPRINT, NEAR_IMAGE_EDGE
    from reroom.hdr.reproject import sample_tiers

    edge, mixed, foreign = NEAR_IMAGE_EDGE, NEAR_IMAGE_EDGE | MIXED_FOOTPRINT, FOREIGN_FOOTPRINT
    # vertex 0: a clean sample (level 50) and an edge one (200): the clean one alone;
    # 1: an edge (60) and a mixed edge sample (80): both (one tier); 2: foreign only
    # (unobserved); 3: a foreign sample (250) and an edge one (90): the edge one.
    vi = np.array([0, 0, 1, 1, 2, 3, 3])
    fj = np.array([0, 1, 0, 1, 0, 0, 1])
    levels = np.array([50, 200, 60, 80, 120, 250, 90], np.uint8)[:, None].repeat(3, 1)
    flags = np.array([0, edge, edge, mixed, foreign, foreign | edge, edge], np.uint8)
    assert sample_tiers(flags).tolist() == [2, 1, 1, 1, 0, 0, 1]
    obs = Observations.from_arrays(4, 2, vi, fj, levels, flags=flags)
    rad = reproject_radiance(obs, np.ones((2, 3)))
    assert rad.observed.tolist() == [True, True, False, True]
    assert rad.sample_count.tolist() == [1, 2, 0, 1]
    np.testing.assert_allclose(rad.radiance[0], 50 / 255, rtol=1e-4)
    np.testing.assert_allclose(rad.radiance[2], 0.0)
    np.testing.assert_allclose(rad.radiance[3], 90 / 255, rtol=1e-4)
    best = best_frame_texture(obs)
    assert best.frame.tolist() == [0, 1, -1, 1]  # vertex 1: one tier, level 80 more trusted
    # With the second (predicted-weight) pass too, the foreign sample stays out.
    rad2 = reproject_radiance(obs, np.ones((2, 3)), level_linear=LINEAR)
    np.testing.assert_allclose(rad2.radiance[3], 90 / 255, rtol=1e-4)
    assert not rad2.observed[2]
