"""Differential-rendering composites and baked lighting on small exact scenes."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from reroom.edit import bake_vertex_radiance, differential_composite, export_baked
from reroom.render.mitsuba_env import mitsuba_info

LIGHT = [1.6, 0.2, 1.4]
INTENSITY = 6.0


@pytest.fixture(scope="module")
def mi():
    from reroom.render import mitsuba

    return mitsuba()


def _scene(mi, floor_bsdf: dict, with_box: bool, integrator: dict | None = None) -> dict:
    d = {
        "type": "scene",
        "integrator": integrator or {"type": "path", "max_depth": 2},
        "light": {
            "type": "point",
            "position": LIGHT,
            "intensity": {"type": "rgb", "value": INTENSITY},
        },
        "floor": {
            "type": "rectangle",
            "to_world": mi.ScalarTransform4f().scale([3.0, 3.0, 1.0]),
            "bsdf": floor_bsdf,
        },
        "sensor": {
            "type": "perspective",
            "fov": 60,
            "to_world": mi.ScalarTransform4f().look_at(
                origin=[0.0, -3.5, 3.0], target=[0.0, 0.0, 0.0], up=[0, 0, 1]
            ),
            "film": {"type": "hdrfilm", "width": 48, "height": 36, "rfilter": {"type": "box"}},
            "sampler": {"type": "independent", "sample_count": 4},
        },
    }
    if with_box:
        d["box"] = {
            "type": "cube",
            "to_world": mi.ScalarTransform4f().translate([0.0, 0.2, 0.3]).scale(0.3),
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.7}},
        }
    return d


def _render(mi, d: dict) -> np.ndarray:
    return np.array(mi.render(mi.load_dict(d), seed=1), dtype=np.float64)[..., :3]


def test_ratio_composite_reproduces_the_true_edit_despite_a_wrong_albedo(mi) -> None:
    # The real floor is a checkerboard; the model thinks it is uniform grey.
    checker = np.indices((8, 8)).sum(0) % 2 * 0.6 + 0.2
    tex = np.repeat(checker[..., None], 3, axis=2).astype(np.float32)
    true_floor = {
        "type": "diffuse",
        "reflectance": {"type": "bitmap", "bitmap": mi.Bitmap(tex), "filter_type": "nearest"},
    }
    model_floor = {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.5}}
    photo = _render(mi, _scene(mi, true_floor, False))
    truth = _render(mi, _scene(mi, true_floor, True))
    with_obj = _render(mi, _scene(mi, model_floor, True))
    without = _render(mi, _scene(mi, model_floor, False))
    depth = {"type": "aov", "aovs": "dd:depth"}
    d_with = _render(mi, _scene(mi, model_floor, True, depth))[..., 0]
    d_without = _render(mi, _scene(mi, model_floor, False, depth))[..., 0]
    mask = (d_with < d_without - 1e-4).astype(float)
    assert 0.02 < mask.mean() < 0.5
    shadow = (truth.sum(-1) < 0.5 * photo.sum(-1)) & (mask == 0)
    assert shadow.sum() > 10  # the box really casts a shadow on the floor

    ratio = differential_composite(photo, with_obj, without, mask, mode="ratio")
    additive = differential_composite(photo, with_obj, without, mask, mode="additive")
    # Errors on the floor pixels the edit changes (shadow), relative to their light.
    changed = (np.abs(with_obj - without).sum(-1) > 1e-6) & (mask == 0)
    assert changed.sum() > 10

    def err(img: np.ndarray) -> float:
        return float(np.abs(img - truth)[changed].sum() / truth[changed].sum())

    # Measured: ratio 6 %, additive 240 %. Not exact: pixels that the object covers
    # in part (the mask here is binary) and pixels where a shadow edge and a texture
    # edge meet (the mean of a product is not the product of the means).
    assert err(ratio) < 0.1, (err(ratio), err(additive))
    assert err(additive) > 10 * err(ratio)  # the additive form carries the albedo error
    # Away from the edit the photo is untouched.
    untouched = (np.abs(with_obj - without).sum(-1) == 0) & (mask == 0)
    np.testing.assert_array_equal(ratio[untouched], photo[untouched])


def test_composite_rejects_bad_input() -> None:
    a = np.zeros((4, 5, 3))
    with pytest.raises(ValueError, match="same"):
        differential_composite(a, a[:3], a, np.zeros((4, 5)))
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        differential_composite(a, a, a, np.full((4, 5), 2.0))
    with pytest.raises(ValueError, match="mode"):
        differential_composite(a, a, a, np.zeros((4, 5)), mode="max")


@pytest.mark.skipif(not mitsuba_info().vectorized, reason="needs a JIT Mitsuba variant")
def test_baked_floor_under_a_point_light_matches_closed_form(mi, tmp_path) -> None:
    albedo = 0.6
    scene = _scene(mi, {"type": "diffuse", "reflectance": {"type": "rgb", "value": albedo}}, False)
    del scene["sensor"]
    grid = np.stack(np.meshgrid(np.linspace(-1, 1, 9), np.linspace(-1, 1, 9)), -1).reshape(-1, 2)
    verts = np.c_[grid, np.zeros(len(grid))]
    baked = bake_vertex_radiance(scene, verts, np.tile([0.0, 0.0, 1.0], (len(verts), 1)), spp=4)
    d = np.asarray(LIGHT) - verts
    r2 = (d**2).sum(1)
    want = albedo / math.pi * INTENSITY * (d[:, 2] / np.sqrt(r2)) / r2
    np.testing.assert_allclose(baked.radiance[:, 0], want, rtol=1e-3)
    assert np.all(baked.stderr < 1e-3 * want.max())  # NEE of a point light is exact
    # A point 5 cm above the floor is not on a surface: it reads 0, and a warning says so.
    with pytest.warns(UserWarning, match="1 of 2 points have no surface"):
        off = bake_vertex_radiance(
            scene, np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.05]]), np.tile([0.0, 0.0, 1.0], (2, 1))
        )
    assert off.radiance[1].max() == 0.0 and off.radiance[0].max() > 0.0

    mesh = trimesh.Trimesh(verts, [[0, 1, 10], [0, 10, 9]], process=False)
    files = export_baked(mesh, baked, tmp_path, name="floor")
    from reroom.io.mesh import read_ply

    back = read_ply(files["ply"])
    np.testing.assert_allclose(back.vertex_attributes["radiance"], baked.radiance, rtol=1e-6)
    glb = trimesh.load(files["glb"], force="mesh")
    assert len(glb.vertices) > 0 and glb.visual.kind == "vertex"
    assert glb.visual.vertex_colors[:, :3].max() > 0


def test_bake_and_export_reject_mismatched_input(tmp_path) -> None:
    from reroom.edit.bake import BakedLighting

    with pytest.raises(ValueError, match=r"\(V, 3\)"):
        bake_vertex_radiance({"type": "scene"}, np.zeros((4, 3)), np.zeros((3, 3)))
    mesh = trimesh.creation.box()
    baked = BakedLighting(np.zeros((3, 3), np.float32), np.zeros((3, 3), np.float32), 4)
    with pytest.raises(ValueError, match="3 baked values for a mesh of 8 vertices"):
        export_baked(mesh, baked, tmp_path / "out")
    assert not any((tmp_path / "out").glob("*.ply"))
