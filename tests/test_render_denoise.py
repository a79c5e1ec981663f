"""Denoising of model renders (reroom.render.denoise, FrameRenderer(denoise=True))."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from reroom.io.mesh import write_ply
from reroom.render.denoise import denoise
from reroom.render.frames import FrameRenderer
from reroom.scan import Intrinsics, look_at


def _scene_image(h: int = 96, w: int = 128) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A clean HDR image of two flat regions and a smooth gradient, with albedo and normal."""
    y, x = np.mgrid[0:h, 0:w] / np.array([h, w])[:, None, None]
    left = x < 0.5
    albedo = np.where(left[..., None], [0.7, 0.6, 0.5], [0.2, 0.3, 0.6]).astype(np.float32)
    light = (2.0 + 3.0 * y)[..., None]  # smooth shading, HDR values above 1
    normal = np.where(left[..., None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]).astype(np.float32)
    return (albedo * light).astype(np.float32), albedo, normal


def _rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2)) / np.sqrt(np.mean(b**2)))


def test_denoise_removes_most_of_the_noise_and_keeps_the_edge():
    clean, albedo, normal = _scene_image()
    rng = np.random.default_rng(0)
    noisy = clean * rng.gamma(4.0, 0.25, clean.shape).astype(np.float32)  # mean 1, 50 % sd
    before = _rmse(noisy, clean)
    out = denoise(noisy, albedo, normal)
    assert out.shape == clean.shape and out.dtype == np.float32
    assert _rmse(out, clean) < before / 4
    # The albedo edge stays sharp: the columns beside it keep their own colours.
    mid = clean.shape[1] // 2
    np.testing.assert_allclose(out[:, mid - 2].mean(0), clean[:, mid - 2].mean(0), rtol=0.1)
    np.testing.assert_allclose(out[:, mid + 1].mean(0), clean[:, mid + 1].mean(0), rtol=0.1)
    # Colour alone (no guides) still denoises.
    assert _rmse(denoise(noisy), clean) < before / 2


def test_denoise_sets_non_finite_pixels_to_zero_with_a_warning():
    clean, albedo, normal = _scene_image(32, 32)
    img = clean.copy()
    img[5, 7] = np.nan
    img[9, 9, 1] = np.inf
    with pytest.warns(RuntimeWarning, match="2 pixel"):
        out = denoise(img, albedo, normal)
    assert np.isfinite(out).all()
    assert _rmse(out, clean) < 0.1


def test_denoise_rejects_bad_shapes():
    clean, albedo, normal = _scene_image(16, 16)
    with pytest.raises(ValueError, match="color must be an"):
        denoise(clean[..., :2])
    with pytest.raises(ValueError, match="albedo has shape"):
        denoise(clean, albedo[:8], normal)
    with pytest.raises(ValueError, match="both albedo and normal"):
        denoise(clean, albedo, None)


def _room(tmp: Path) -> dict:
    """A closed box room lit by a ceiling panel: a path tracer's noisy case."""
    box = trimesh.creation.box(extents=[4.0, 3.0, 2.5])
    box.apply_translation([0.0, 0.0, 1.25])
    box.invert()  # normals inward
    panel = trimesh.Trimesh(
        [[-0.3, -0.3, 2.49], [0.3, -0.3, 2.49], [0.3, 0.3, 2.49], [-0.3, 0.3, 2.49]],
        [[0, 2, 1], [0, 3, 2]],
        process=False,
    )
    return {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 8},
        "room": {
            "type": "ply",
            "filename": str(write_ply(tmp / "room.ply", box, {})),
            "face_normals": True,
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.7, 0.6, 0.5]}},
        },
        "panel": {
            "type": "ply",
            "filename": str(write_ply(tmp / "panel.ply", panel, {})),
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 20.0}},
        },
    }


def test_frame_renderer_denoises_a_room_render(tmp_path: Path):
    from scipy import ndimage

    scene = _room(tmp_path)
    intr = Intrinsics.from_fov(128, 96, 70.0)
    c2w = look_at(np.array([-1.5, -1.0, 1.4]), np.array([1.5, 1.0, 1.0]))
    reference = FrameRenderer(scene, intr, spp=1024).render(c2w, seed=7)
    noisy = FrameRenderer(scene, intr, spp=16).render(c2w, seed=1)
    clean = FrameRenderer(scene, intr, spp=16, denoise=True).render(c2w, seed=1)
    assert np.isfinite(clean).all() and clean.shape == noisy.shape
    panel = reference.max(axis=2) > 5.0
    assert panel.sum() > 10  # the panel is in view
    walls = ~ndimage.binary_dilation(panel, iterations=3)
    # Off the panel, much closer to the converged render than the same samples
    # undenoised; the panel itself is not fed to the denoiser, so its edge is as sharp
    # as the noisy render's; and no light is added or removed.
    assert _rmse(clean[walls], reference[walls]) < 0.6 * _rmse(noisy[walls], reference[walls])
    assert _rmse(clean, reference) < _rmse(noisy, reference)
    np.testing.assert_allclose(clean[panel], noisy[panel], rtol=0.05)
    assert abs(clean[walls].mean() / reference[walls].mean() - 1.0) < 0.02


def test_auto_spp_spends_about_a_million_samples_a_view():
    from reroom.render.frames import auto_spp

    assert auto_spp(160, 120) == 16  # 0.3 M samples: 64 would be 1.2 M
    assert auto_spp(640, 360) == 4
    assert auto_spp(64, 48) == 64  # capped
    assert auto_spp(4000, 3000) == 4  # never below the floor
    assert auto_spp(640, 360, budget=4_000_000) == 16
