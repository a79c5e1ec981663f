"""The light of what the scan does not hold: escaping share, its radiance, its emitter."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from reroom.edit.model import surroundings_emitter
from reroom.invert.surroundings import unseen_surroundings
from reroom.invert.transfer import HemisphereTransfer
from reroom.invert.windows import WindowOpening, rays_through_windows
from reroom.rays import RayCaster


def _room(open_top: bool) -> trimesh.Trimesh:
    """A 4 x 4 x 2.5 m box, faces pointing in; without its ceiling when ``open_top``."""
    box = trimesh.creation.box(extents=(4.0, 4.0, 2.5)).subdivide_to_size(0.25)
    box.invert()
    if open_top:
        top = box.triangles_center[:, 2] > 1.24
        box = trimesh.Trimesh(box.vertices, box.faces[~top], process=False)
        box.remove_unreferenced_vertices()
    return box


def _hemi(mesh: trimesh.Trimesh, seen_radiance: np.ndarray) -> HemisphereTransfer:
    """Every vertex a receiver that sees 60 % of its hemisphere at ``seen_radiance``."""
    n = len(mesh.vertices)
    p_obs = np.full(n, 0.6)
    return HemisphereTransfer(
        vertices=np.arange(n),
        indirect=np.pi * p_obs[:, None] * np.tile(seen_radiance, (n, 1)),
        p_observed=p_obs,
        p_unobserved=np.full(n, 0.4),
        p_light=np.zeros(n),
        area=np.zeros((n, 0)),
        distant=np.zeros((n, 0, 0)),
        rays_per_vertex=32,
    )


def test_an_open_top_room_escapes_by_reciprocity_and_a_closed_one_does_not() -> None:
    rgb = np.array([0.3, 0.2, 0.1])
    room = _room(open_top=True)
    info = unseen_surroundings(RayCaster(room), room, [], _hemi(room, rgb), seed=1)
    # Reciprocity: the area-weighted mean view factor of the inside toward the opening is
    # A_opening F_opening->inside / A_inside = 16 / (16 + 4 * 4 * 2.5).
    assert info["escape_fraction"] == pytest.approx(16 / 56, abs=0.01)
    np.testing.assert_allclose(info["radiance"], rgb, rtol=1e-9)
    assert info["points"] == 4000

    closed = _room(open_top=False)
    info = unseen_surroundings(RayCaster(closed), closed, [], _hemi(closed, rgb), seed=1)
    assert info["escape_fraction"] < 0.002
    assert info["radiance"] is None


def test_receivers_that_saw_nothing_give_no_surroundings() -> None:
    room = _room(open_top=True)
    hemi = _hemi(room, np.ones(3))
    hemi.p_observed[:] = 0.0  # no receiver saw anything: no radiance to give the holes
    info = unseen_surroundings(RayCaster(room), room, [], hemi)
    assert info["points"] == 0 and info["radiance"] is None


def test_rays_through_a_window_are_not_an_escape() -> None:
    room = _room(open_top=True)
    # The whole missing ceiling declared a window: nothing escapes any more.
    window = WindowOpening("sky", [0, 0, 1.25], [2.0, 0, 0], [0, 2.0, 0], [0, 0, -1.0])
    info = unseen_surroundings(
        RayCaster(room), room, [window], _hemi(room, np.ones(3)), seed=2
    )  # fmt: skip
    assert info["escape_fraction"] < 0.002
    assert info["radiance"] is None


def test_a_miss_crosses_a_window_within_its_grown_rectangle() -> None:
    """The rule the escape count takes from the hemisphere transfer, for rays that miss."""
    window = WindowOpening("w", [0, 0, 1], [0.5, 0, 0], [0, 0.25, 0], [0, 0, -1.0])
    o = np.zeros((4, 3))
    d = np.array([[0, 0, 1.0], [0.51, 0, 1.0], [0.6, 0, 1.0], [0, 0, -1.0]])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    crossed = rays_through_windows(o, d, np.full(4, np.inf), [window]) >= 0
    # inside; 1 cm outside the edge (within the 2 cm tolerance); 10 cm outside; away
    np.testing.assert_array_equal(crossed, [True, True, False, False])


def test_surroundings_emitter_is_a_constant_environment_only_with_a_radiance() -> None:
    assert surroundings_emitter(None) is None
    assert surroundings_emitter({"escape_fraction": 0.0, "radiance": None}) is None
    for bad in ([float("nan"), 0, 0], [0.1, -0.2, 0.3], [0.1, 0.2], "grey"):
        with pytest.warns(UserWarning, match=r"my/scene\.json: surroundings radiance"):
            assert surroundings_emitter({"radiance": bad}, "my/scene.json") is None
    assert surroundings_emitter({"radiance": [0.0, 0.0, 0.0]}) is None
    e = surroundings_emitter({"escape_fraction": 0.5, "radiance": [0.3, 0.2, 0.1]})
    assert e["type"] == "constant"
    assert e["radiance"]["value"] == [0.3, 0.2, 0.1]
    assert e["sampling_weight"] > 0


def test_a_floor_under_the_surroundings_renders_at_albedo_times_their_radiance() -> None:
    """A lone diffuse floor under the constant environment: L = rho L_env, exactly."""
    from reroom.render import mitsuba

    mi = mitsuba()
    env = surroundings_emitter({"escape_fraction": 1.0, "radiance": [0.5, 1.0, 2.0]})
    scene = mi.load_dict(
        {
            "type": "scene",
            "integrator": {"type": "path", "max_depth": 3},
            "surroundings": env,
            "floor": {
                "type": "rectangle",
                "to_world": mi.ScalarTransform4f().scale([50.0, 50.0, 1.0]),
                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.4}},
            },
            "sensor": {
                "type": "perspective",
                "fov": 30,
                "to_world": mi.ScalarTransform4f().look_at(
                    origin=[0, 0, 1.0], target=[0, 0, 0], up=[0, 1, 0]
                ),
                "film": {"type": "hdrfilm", "width": 16, "height": 16},
                "sampler": {"type": "independent", "sample_count": 64},
            },
        }
    )
    img = np.asarray(mi.render(scene, seed=3))[..., :3]
    np.testing.assert_allclose(img.mean(axis=(0, 1)), [0.2, 0.4, 0.8], rtol=0.02)
