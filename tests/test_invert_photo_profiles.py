"""A point light's profile fitted to photo pixels (reroom.invert.photo_profiles)."""

from __future__ import annotations

import numpy as np
import pytest

from reroom.invert.basis import InclinationBasis
from reroom.invert.fine_profiles import bin_solid_angles
from reroom.invert.photo_profiles import PhotoSamples, _hat_matrix, refit_point_profile
from reroom.render.line_emitter import line_profile_value

BINS = 128


def _beam() -> np.ndarray:
    """A downlight's scalloped beam: peaks, a dip and a cut-off within 40 degrees of nadir."""
    theta = np.degrees(InclinationBasis(BINS).bin_centres())
    off = 180.0 - theta
    j = 8.0 + 6.0 * np.cos(np.radians(off) * 12.0)
    return np.where(off < 30.0, j, np.where(off < 40.0, j * (40.0 - off) / 10.0, 0.0))


def test_hat_matrix_reads_a_profile_as_the_renderer_does():
    rng = np.random.default_rng(0)
    prof = rng.uniform(0.0, 5.0, BINS)
    theta = rng.uniform(0.0, np.pi, 500)
    value = rng.uniform(0.1, 2.0, 500)
    np.testing.assert_allclose(
        _hat_matrix(theta, value, BINS) @ prof, value * line_profile_value(prof, theta)
    )


def _samples(truth: np.ndarray, color: np.ndarray, n: int = 40_000, noise: float = 0.0):
    rng = np.random.default_rng(1)
    theta = np.radians(180.0 - rng.uniform(0.0, 45.0, n))
    value = rng.uniform(0.2, 1.5, n)
    light = value * line_profile_value(truth, theta)
    target = light[:, None] * color[None, :]
    target *= 1.0 + noise * rng.standard_normal(target.shape)
    return value, theta, target


def test_refit_recovers_the_beam_from_exact_samples():
    truth = _beam()
    color = np.array([1.1, 1.0, 0.8])
    start = np.repeat(truth.reshape(-1, 4).mean(axis=1), 4)  # a 32-bin blur of it
    value, theta, target = _samples(truth, color)
    fit = refit_point_profile(start, color, value, theta, target, keep_group_flux=False)
    seen = np.degrees(InclinationBasis(BINS).bin_centres()) > 136.0
    err = np.linalg.norm(fit.profile[seen] - truth[seen]) / np.linalg.norm(truth[seen])
    before = np.linalg.norm(start[seen] - truth[seen]) / np.linalg.norm(truth[seen])
    assert err < 0.02 < before
    assert fit.residual_after < 0.1 * fit.residual_before
    # Bins no sample sees keep the start.
    np.testing.assert_allclose(fit.profile[:80], start[:80], atol=1e-3 * start.max())


def test_refit_keeps_each_groups_flux_and_ignores_outliers():
    truth = _beam()
    color = np.ones(3)
    start = np.repeat(truth.reshape(-1, 4).mean(axis=1), 4) * 0.9  # the solve's level
    value, theta, target = _samples(truth, color, noise=0.02)
    target[::50] *= 3.0  # a picture on the wall
    fit = refit_point_profile(start, color, value, theta, target)
    omega = bin_solid_angles(InclinationBasis(BINS))
    flux = lambda p: (p * omega).reshape(-1, 4).sum(axis=1)  # noqa: E731
    np.testing.assert_allclose(flux(fit.profile), flux(start), rtol=1e-9)
    assert fit.groups.sum() >= 8 and not fit.groups[:20].any()
    seen = np.degrees(InclinationBasis(BINS).bin_centres()) > 136.0
    shape = fit.profile[seen] / 0.9
    assert np.linalg.norm(shape - truth[seen]) / np.linalg.norm(truth[seen]) < 0.05


def test_refit_without_lit_samples_keeps_the_profile():
    start = _beam()
    fit = refit_point_profile(start, np.ones(3), np.zeros(10), np.zeros(10), np.zeros((10, 3)))
    assert fit.samples == 0 and not fit.groups.any()
    np.testing.assert_array_equal(fit.profile, start)


def test_photo_samples_interpolate_per_vertex_values():
    faces = np.array([[0, 1, 2]])
    s = PhotoSamples(
        np.zeros((2, 3)), np.zeros((2, 3)), np.array([0, 0]),
        np.array([[1.0, 0.0, 0.0], [0.2, 0.3, 0.5]]), np.zeros((2, 3)),
    )  # fmt: skip
    values = np.array([[1.0], [2.0], [4.0]])
    np.testing.assert_allclose(s.interpolate(faces, values)[:, 0], [1.0, 0.2 + 0.6 + 2.0])
    with_nan = values.copy()
    with_nan[2] = np.nan
    assert np.isnan(s.interpolate(faces, with_nan)[1, 0])
    assert len(s) == 2
    pytest.importorskip("scipy")


def test_even_subset_keeps_sparse_bins_whole_and_caps_the_crowded():
    from reroom.invert.photo_profiles import even_subset

    bins = np.concatenate([np.zeros(10_000, int), np.full(50, 1), np.full(3_000, 2)])
    keep = even_subset(bins, 2_000, seed=3)
    assert len(keep) <= 2_000 and np.all(np.diff(keep) > 0)
    counts = np.bincount(bins[keep], minlength=3)
    assert counts[1] == 50  # the sparse bin whole
    assert abs(counts[0] - counts[2]) <= 1 and counts[0] >= 900  # the crowded ones alike
    np.testing.assert_array_equal(even_subset(bins, 2_000, seed=3), keep)  # seeded
    np.testing.assert_array_equal(even_subset(bins[:40], 100), np.arange(40))


def test_photo_samples_skip_an_unreadable_frame_with_a_note(tmp_path):
    """A frame whose image is corrupt is left out, named in the notes; the others count."""
    import trimesh

    from reroom.invert.photo_profiles import photo_samples
    from reroom.scan import Intrinsics, look_at, write_scan

    room = trimesh.creation.box(extents=[4.0, 3.0, 2.5])
    room.apply_translation([0.0, 0.0, 1.25])
    intr = Intrinsics.from_fov(48, 36, 70.0)
    poses = [look_at([0.0, 0.0, 1.3], [1.5, 0.5, 1.0]), look_at([0.5, 0.2, 1.4], [-1.5, 0.4, 1.0])]
    images = [np.full((36, 48, 3), 120, np.uint8)] * 2
    write_scan(tmp_path, room, intr, poses, images, meta={"reroom": {"response": "gamma2.2"}})
    (tmp_path / "hdr").mkdir()
    doc = {"response": "gamma2.2", "frames": [{"index": j, "scale": [1.0] * 3} for j in range(2)]}
    (tmp_path / "hdr" / "exposures.json").write_text(__import__("json").dumps(doc))
    broken = sorted((tmp_path / "images").iterdir())[1]
    broken.write_bytes(b"not a png")
    samples, stats = photo_samples(tmp_path, room, np.ones(len(room.faces), bool))
    assert stats["frames_used"] == 1 and len(samples) > 500
    assert any(broken.name in n for n in stats["notes"])
    # linearised (gamma 2.2) and divided by the scale
    np.testing.assert_allclose(samples.radiance, (120 / 255) ** 2.2, rtol=0.02)
