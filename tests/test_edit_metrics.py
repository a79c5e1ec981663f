"""Image-fidelity figures of the edit benchmark (reroom.edit.metrics)."""

from __future__ import annotations

import numpy as np
import pytest

from reroom.edit.metrics import (
    compare_images,
    comparison_strip,
    relative_rmse,
    ssim_tonemapped,
    tone_map,
)
from reroom.errors import ReroomError


def _image(seed: int = 0, shape: tuple[int, int] = (24, 32)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0 : shape[0], 0 : shape[1]]
    base = 0.2 + 0.3 * np.sin(x / 5.0)[..., None] * np.cos(y / 7.0)[..., None] ** 2
    return np.clip(base + 0.02 * rng.standard_normal((*shape, 3)), 0.01, None)


def test_relative_rmse_is_the_norm_ratio() -> None:
    truth = _image()
    assert relative_rmse(truth, truth) == 0.0
    # A uniform 10 % gain is a relative RMSE of exactly 0.1.
    assert relative_rmse(1.1 * truth, truth) == pytest.approx(0.1, rel=1e-12)
    ours = truth.copy()
    ours[0, 0, 0] += 1.0
    expected = 1.0 / np.sqrt(np.sum(truth**2))
    assert relative_rmse(ours, truth) == pytest.approx(expected, rel=1e-12)


def test_relative_rmse_mask_selects_pixels() -> None:
    truth = _image()
    ours = truth.copy()
    ours[:, :16] *= 2.0  # left half doubled
    mask = np.zeros(truth.shape[:2], bool)
    mask[:, 16:] = True
    assert relative_rmse(ours, truth, mask) == 0.0
    assert relative_rmse(ours, truth, ~mask) == pytest.approx(1.0)


def test_bad_images_are_errors() -> None:
    truth = _image()
    with pytest.raises(ReroomError, match="must both be"):
        relative_rmse(truth[:, :10], truth)
    with pytest.raises(ReroomError, match="black"):
        relative_rmse(truth, np.zeros_like(truth))
    bad = truth.copy()
    bad[1, 1, 1] = np.nan
    with pytest.raises(ReroomError, match="NaN"):
        ssim_tonemapped(bad, truth)
    with pytest.raises(ReroomError, match="mask"):
        relative_rmse(truth, truth, np.ones((3, 3), bool))


def test_ssim_is_one_for_equal_images_and_drops_with_noise() -> None:
    truth = _image()
    assert ssim_tonemapped(truth, truth) == pytest.approx(1.0)
    rng = np.random.default_rng(3)
    noisy = truth * (1.0 + 0.3 * rng.standard_normal(truth.shape))
    s = ssim_tonemapped(noisy, truth)
    assert 0.0 < s < 0.9
    # Tone mapping clips at the white level: values above 1 all look the same.
    assert ssim_tonemapped(truth + 5.0, truth + 9.0) == pytest.approx(1.0)


def test_tone_map_is_srgb_of_clipped_values() -> None:
    x = np.array([[[-1.0, 0.0, 0.0031308]], [[0.18, 1.0, 7.0]]])
    y = tone_map(x)
    assert y[0, 0, 0] == 0.0
    assert y[1, 0, 2] == pytest.approx(1.0) and y[1, 0, 1] == pytest.approx(1.0)
    assert y[1, 0, 0] == pytest.approx(1.055 * 0.18 ** (1 / 2.4) - 0.055)


def test_compare_images_and_strip() -> None:
    truth = _image()
    ours = 1.25 * truth
    fig = compare_images(ours, truth)
    assert fig["relative_rmse"] == pytest.approx(0.25)
    assert fig["ratio_of_means"] == pytest.approx(1.25)
    assert 0.0 < fig["ssim"] < 1.0
    strip = comparison_strip(ours, truth)
    h, w = truth.shape[:2]
    assert strip.shape == (h, 3 * w, 3) and strip.dtype == np.uint8
    err = strip[:, 2 * w :].astype(int)
    lit = truth.mean(axis=2) >= 0.01
    # Ours brighter everywhere: the error panel is red (red channel above blue).
    assert np.all(err[lit][:, 0] > err[lit][:, 2])
    darker = comparison_strip(0.8 * truth, truth)[:, 2 * w :].astype(int)
    assert np.all(darker[lit][:, 2] > darker[lit][:, 0])
