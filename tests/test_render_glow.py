"""Glowing fittings (reroom.render.glow): the radiance a camera sees matches the solved light.

A Lambertian tube of radiance ``L`` and radius ``r`` has the line profile ``J = 2 r L``
per unit length; the glow rule ``L = J / w_vis`` must give ``L`` back, whatever hides it
nearby (a baffle within ``reach`` hides the tube *and* its light, so the radiance of what
stays visible does not change if the profile was fitted with the baffle) or far away.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

from reroom.io.mesh import write_ply
from reroom.render.emitters import goniometric_light
from reroom.render.frames import FrameRenderer
from reroom.render.glow import (
    GLOW,
    glow_entry,
    glow_sources,
    light_intensity,
    split_glow,
    visible_projected_area,
)
from reroom.render.line_emitter import line_light
from reroom.render.mitsuba_env import mitsuba_info
from reroom.scan import Intrinsics, look_at

pytestmark = pytest.mark.skipif(
    not mitsuba_info().vectorized, reason="Python emitters need a JIT Mitsuba variant"
)

R = 0.04  # tube radius (m)
J = 0.6  # line profile, W / (sr m)
Z = 2.5  # tube height
P0, P1 = np.array([-0.5, 0.0, Z]), np.array([0.5, 0.0, Z])
EYE = np.array([0.0, -0.3, 0.5])
W, H = 96, 72


def _tube(tmp: Path) -> Path:
    cyl = trimesh.creation.cylinder(radius=R, segment=[P0, P1], sections=24)
    return write_ply(tmp / "tube.ply", cyl, {})


def _scene(tmp: Path, *extra: tuple[str, trimesh.Trimesh]) -> dict:
    floor = trimesh.Trimesh(
        [[-3, -3, 0], [3, -3, 0], [3, 3, 0], [-3, 3, 0]], [[0, 1, 2], [0, 2, 3]], process=False
    )
    scene = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 2},
        "floor": {
            "type": "ply",
            "filename": str(write_ply(tmp / "floor.ply", floor, {})),
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.5}},
        },
        "light_00": line_light(P0, P1, np.full(8, J), color=[1.0, 0.5, 0.25]),
        "glow_00": glow_entry(str(_tube(tmp)), "light_00", (P0 + P1) / 2),
    }
    for k, (name, mesh) in enumerate(extra):
        scene[name] = {
            "type": "ply",
            "filename": str(write_ply(tmp / f"extra{k}.ply", mesh, {})),
            "face_normals": True,
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}},
        }
    return scene


def _render(scene: dict, c2w: np.ndarray) -> np.ndarray:
    intr = Intrinsics.from_fov(W, H, 60.0)
    return FrameRenderer(scene, intr, spp=4).render(c2w, seed=1)


def _plate(x0: float, x1: float, z: float) -> trimesh.Trimesh:
    return trimesh.Trimesh(
        [[x0, -0.3, z], [x1, -0.3, z], [x1, 0.3, z], [x0, 0.3, z]],
        [[0, 1, 2], [0, 2, 3]],
        process=False,
    )


def test_split_glow_leaves_a_loadable_scene(tmp_path: Path) -> None:
    scene = _scene(tmp_path)
    rest, glows = split_glow(scene)
    assert list(glows) == ["glow_00"] and glows["glow_00"]["type"] == GLOW
    assert "glow_00" not in rest and "glow_00" in scene  # input untouched
    srcs = glow_sources(rest, glows)
    assert len(srcs) == 1 and srcs[0].is_line
    del rest["light_00"]
    assert glow_sources(rest, glows) == []  # a light switched off takes its glow along


def test_line_intensity_is_the_profile_per_unit_length(tmp_path: Path) -> None:
    entry = line_light(P0, P1, np.linspace(1.0, 2.0, 16), color=[1.0, 0.5, 0.25], scale=2.0)
    down = light_intensity(entry, np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]]))
    # theta = pi (down) is the last node, theta = 0 (up) the first (linear, clamped).
    np.testing.assert_allclose(down[0], 2.0 * 2.0 * np.array([1.0, 0.5, 0.25]))
    np.testing.assert_allclose(down[1], 2.0 * 1.0 * np.array([1.0, 0.5, 0.25]))


def test_point_intensity_follows_the_table() -> None:
    table = np.stack([np.linspace(3.0, 1.0, 19)] * 2, axis=1)  # 3 at the nadir, 1 up
    entry = goniometric_light(table, [0.0, 0.0, 2.0], color=[1.0, 1.0, 1.0], scale=0.5)
    got = light_intensity(entry, np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]))
    np.testing.assert_allclose(got[:, 0], [1.5, 0.5, 1.0], rtol=1e-6)


def test_tube_glows_with_its_lambertian_radiance(tmp_path: Path) -> None:
    c2w = look_at(EYE, [0.0, 0.0, Z])
    img = _render(_scene(tmp_path), c2w)
    lum = img[..., 0]
    full = lum > 0.8 * lum.max()
    assert full.sum() > 20  # the tube spans many pixels
    expected = J / (2 * R)
    # Fully covered pixels show the tube's radiance (the background behind is black sky).
    np.testing.assert_allclose(np.median(lum[full]), expected, rtol=0.04)
    np.testing.assert_allclose(
        np.median(img[full], axis=0) / np.median(lum[full]), [1.0, 0.5, 0.25], rtol=1e-3
    )


def test_tube_seen_end_on_glows_uniformly_caps_included(tmp_path: Path) -> None:
    # 73 degrees off the tube's perpendicular its end cap is a sixth of what the camera
    # sees of it; the line model's J cos(phi) is the side's light only, so the cap must
    # not dilute it (0.83 of the radiance if it did): side and cap show J / (2 R). Far
    # enough (2 m from the axis) for the near field to move the radiance by ~1 %.
    eye = np.array([-6.5, 0.05, Z - 2.0])
    intr = Intrinsics.from_fov(W, H, 8.0)
    scene = _scene(tmp_path)
    img = FrameRenderer(scene, intr, spp=4).render(look_at(eye, (P0 + P1) / 2), seed=1)[..., 0]
    full = img > 0.8 * img.max()
    assert full.sum() > 40
    np.testing.assert_allclose(np.median(img[full]), J / (2 * R), rtol=0.03)


def test_baffle_near_the_tube_and_a_far_occluder(tmp_path: Path) -> None:
    c2w = look_at(EYE, [0.0, 0.0, Z])
    base = _render(_scene(tmp_path / "a"), c2w)[..., 0]
    # A baffle 0.1 m under the left half of the tube: part of the fitting. The profile
    # given is the bare tube's, so the visible half must carry all of it (2x radiance).
    near = _render(_scene(tmp_path / "b", ("baffle", _plate(-0.6, 0.0, Z - 0.1))), c2w)[..., 0]
    # The same plate 1.5 m under the tube (beyond reach): hides half of the picture only.
    far = _render(_scene(tmp_path / "c", ("shelf", _plate(-0.6, 0.0, Z - 1.5))), c2w)[..., 0]
    top = base.max()
    assert np.median(near[near > 0.8 * near.max()]) == pytest.approx(
        2 * np.median(base[base > 0.8 * top]), rel=0.06
    )
    assert np.median(far[far > 0.8 * far.max()]) == pytest.approx(
        np.median(base[base > 0.8 * top]), rel=0.04
    )
    # Energy: the far shelf halves the glow's pixels, the near baffle keeps their sum.
    glow_sum = (base[base > 1.0]).sum()
    assert (far[far > 1.0]).sum() == pytest.approx(glow_sum / 2, rel=0.15)
    assert (near[near > 1.0]).sum() == pytest.approx(glow_sum, rel=0.15)


def test_moved_light_takes_its_glow(tmp_path: Path) -> None:
    scene = _scene(tmp_path)
    c2w = look_at(EYE, [0.0, 0.0, Z])
    before = _render(scene, c2w)[..., 0]
    shift = np.array([0.3, 0.0, 0.0])
    scene["light_00"]["p0"] = (P0 + shift).tolist()
    scene["light_00"]["p1"] = (P1 + shift).tolist()
    after = _render(scene, c2w)[..., 0]
    cols_before = np.flatnonzero((before > 1.0).any(axis=0))
    cols_after = np.flatnonzero((after > 1.0).any(axis=0))
    assert cols_after.mean() > cols_before.mean() + 3  # moved right in the picture
    del scene["light_00"]
    off = _render(scene, c2w)
    assert off.max() < 1.0  # no glow (and no light) when switched off


def test_bulb_glow_is_intensity_over_projected_area(tmp_path: Path) -> None:
    radius = 0.1
    bulb = trimesh.creation.icosphere(subdivisions=3, radius=radius)
    bulb.apply_translation([0.0, 0.0, Z])
    scene = _scene(tmp_path)
    del scene["light_00"], scene["glow_00"]
    scene["light_01"] = goniometric_light(2.0, [0.0, 0.0, Z])
    scene["glow_01"] = glow_entry(
        str(write_ply(tmp_path / "bulb.ply", bulb, {})), "light_01", [0.0, 0.0, Z]
    )
    img = _render(scene, look_at(EYE, [0.0, 0.0, Z]))[..., 0]
    full = img > 0.8 * img.max()
    np.testing.assert_allclose(np.median(img[full]), 2.0 / (math.pi * radius**2), rtol=0.04)


def test_visible_area_of_an_unoccluded_tube(tmp_path: Path) -> None:
    rest, glows = split_glow(_scene(tmp_path))
    (src,) = glow_sources(rest, glows)

    def no_block(o: np.ndarray, d: np.ndarray, tmax: np.ndarray) -> np.ndarray:
        return np.zeros(len(o), bool)

    # Without shadow rays both halves of the tube count: twice the projected width.
    w = visible_projected_area(src, np.array([0.0, 0.0, 0.0]), no_block, samples=20000)
    assert w == pytest.approx(2 * 2 * R, rel=0.03)


def test_image_box_clips_at_the_camera_plane() -> None:
    from reroom.render.glow import _image_box

    intr = Intrinsics.from_fov(W, H, 60.0)
    c2w = look_at(np.zeros(3), [0.0, 0.0, 1.0])  # looking up +z
    small = np.array([[-0.05, -0.05, 2.0], [0.05, -0.05, 2.0], [0.0, 0.05, 2.0]])
    x0, x1, y0, y1 = _image_box(small, np.array([[0, 1, 2]]), c2w, intr)
    assert 0 < x0 < x1 < W and 0 < y0 < y1 < H and x1 - x0 < W // 4
    behind = small * [1, 1, -1]
    assert _image_box(behind, np.array([[0, 1, 2]]), c2w, intr) is None
    # A triangle reaching behind the camera: its visible part runs off the image.
    straddle = np.array([[0.0, 0.0, 2.0], [0.5, 0.0, -1.0], [0.0, 0.5, -1.0]])
    box = _image_box(straddle, np.array([[0, 1, 2]]), c2w, intr)
    assert box is not None and (box[0] == 0 or box[1] == W or box[2] == 0 or box[3] == H)
    # Two glows, one behind and one off to the side: nothing to cast.
    side = small + [10.0, 0.0, -1.9]
    both = np.vstack([behind, side])
    assert _image_box(both, np.array([[0, 1, 2], [3, 4, 5]]), c2w, intr) is None


def test_glow_bad_input(tmp_path: Path) -> None:
    from reroom.errors import ScanError

    scene = _scene(tmp_path)
    scene["glow_00"]["filename"] = str(tmp_path / "gone.ply")
    rest, glows = split_glow(scene)
    with pytest.raises(ScanError, match="gone.ply"):
        glow_sources(rest, glows)
    with pytest.raises(ValueError, match="point or line"):
        light_intensity({"type": "area"}, np.array([[0.0, 0.0, -1.0]]))
    # Degenerate (zero-area) glowing faces show nothing and break nothing.
    flat = trimesh.Trimesh([[0, 0, Z], [0.1, 0, Z], [0.2, 0, Z]], [[0, 1, 2]], process=False)
    scene = _scene(tmp_path / "flat")
    scene["glow_00"]["filename"] = str(write_ply(tmp_path / "flat.ply", flat, {}))
    img = _render(scene, look_at(EYE, [0.0, 0.0, Z]))
    assert np.isfinite(img).all() and img.max() < 1.0
