"""Building blocks of the synthetic generator: geometry, rooms, trajectory, camera model."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from reroom.synth.camera_sim import AutoCamera, CameraModel, apply_response, inverse_response
from reroom.synth.geometry import Piece, box, cylinder, frustum_shell, grid_rect
from reroom.synth.presets import PRESETS, build_preset
from reroom.synth.room import Opening, RoomSpec, build_room, point_in_polygon, polygon_area
from reroom.synth.trajectory import walk_and_look

MAT = {
    k: {"type": "diffuse", "albedo": [0.5] * 3}
    for k in "wall floor ceiling door baseboard window".split()
}


def _mesh(p: Piece) -> trimesh.Trimesh:
    return trimesh.Trimesh(p.vertices, p.faces, process=False)


def test_grid_rect_with_hole_has_exact_area_and_spacing() -> None:
    p = grid_rect([0, 0, 0], [1, 0, 0], [0, 0, 1], 4.0, 2.7, 0.1, holes=[(1.0, 2.2, 0.9, 2.1)])
    m = _mesh(p)
    assert m.area == pytest.approx(4 * 2.7 - 1.2 * 1.2)
    assert m.edges_unique_length.max() <= 0.1 * np.sqrt(2) + 1e-9
    np.testing.assert_allclose(m.face_normals, np.tile([0, -1, 0], (len(m.faces), 1)), atol=1e-12)


@pytest.mark.parametrize(
    "piece",
    [
        box([0, 0, 0], [1, 2, 0.5], 0.1),
        cylinder([0, 0, 0], [0, 0, 1], 0.1),
        frustum_shell([0, 0, 1], 0.2, 0.12, 0.25, 0.005),
    ],
)
def test_closed_primitives_are_watertight_with_outward_normals(piece: Piece) -> None:
    m = _mesh(piece)
    m.merge_vertices()
    assert m.is_watertight
    assert m.volume > 0  # positive volume: faces wound outward


def test_room_walls_face_inward_and_openings_are_cut() -> None:
    room = RoomSpec(
        np.array([[0, 0], [5, 0], [5, 4], [0, 4]], float),
        openings=[
            Opening("window", 0, 1.5, 3.0, 0.9, 2.1),
            Opening("door", 2, 1.0, 1.9, 0.0, 2.05, 0.03),
        ],
    )
    parts, portals = build_room(room, 0.1, MAT)
    by = {p.name.split("/")[1]: p for p in parts}
    assert _mesh(by["wall0"].piece).area == pytest.approx(5 * 2.7 - 1.5 * 1.2)
    centre = np.array([2.5, 2.0, 1.35])
    for name in ("wall0", "wall1", "wall2", "wall3", "floor", "ceiling"):
        m = _mesh(by[name].piece)
        to_centre = centre - m.triangles_center
        assert np.all(np.einsum("ij,ij->i", m.face_normals, to_centre) > 0), name
    assert len(portals) == 1
    np.testing.assert_allclose(portals[0]["normal"], [0, 1, 0], atol=1e-12)
    assert by["door"].label == "door"


def test_polygon_helpers() -> None:
    ell = np.array([[0, 0], [6, 0], [6, 3], [3, 3], [3, 5.5], [0, 5.5]], float)
    assert polygon_area(ell) == pytest.approx(6 * 3 + 3 * 2.5)
    inside = point_in_polygon(np.array([1.0, 5.0, 4.0]), np.array([5.0, 1.0, 4.0]), ell)
    assert inside.tolist() == [True, True, False]


@pytest.mark.parametrize("name", PRESETS)
def test_presets_build_with_labelled_parts_and_lights(name: str) -> None:
    spec = build_preset(name)
    labels = {p.label for p in spec.parts}
    assert {"wall", "floor", "ceiling", "light", "window", "baseboard"} <= labels
    kinds = {light["type"] for light in spec.lights}
    assert {"area", "window"} <= kinds
    names = [light["name"] for light in spec.lights]
    assert len(names) == len(set(names))
    for room in spec.rooms:
        assert polygon_area(room.polygon) > 0
        # every walk waypoint that lies in this room's bounding box is inside the polygon
        wp = spec.waypoints
        lo, hi = room.polygon.min(0), room.polygon.max(0)
        sel = np.all((wp >= lo) & (wp <= hi), axis=1)
        assert point_in_polygon(wp[sel, 0], wp[sel, 1], room.polygon).all()


def test_furnished_has_every_light_type() -> None:
    kinds = {light["type"] for light in build_preset("furnished").lights}
    assert kinds == {"area", "window", "point", "line"}


def test_trajectory_is_rigid_closed_and_varied() -> None:
    rng = np.random.default_rng(3)
    wps = np.array([[1, 1], [4, 1], [4, 3], [1, 3]], float)
    poses = walk_and_look(wps, 40, rng)
    for p in poses:
        r = p[:3, :3]
        np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-9)
        assert np.linalg.det(r) == pytest.approx(1.0)
    centres = np.array([p[:3, 3] for p in poses])
    assert np.linalg.norm(centres[0, :2] - centres[-1, :2]) < 0.6  # comes back: a loop closure
    pitch = np.degrees(np.arcsin(np.array([-p[2, 2] for p in poses])))
    assert pitch.min() < -20 and pitch.max() > 15  # looks at floor and ceiling


def test_response_curves_invert() -> None:
    x = np.linspace(0, 1, 101)
    for name in ("gamma2.2", "srgb", "linear"):
        np.testing.assert_allclose(inverse_response(apply_response(x, name), name), x, atol=1e-9)
    with pytest.raises(ValueError, match="unknown response"):
        apply_response(x, "log")


def test_auto_camera_exposes_to_mid_grey_and_smooths() -> None:
    cam = AutoCamera(CameraModel(noise=False), np.random.default_rng(0))
    dark = np.full((20, 20, 3), 0.01)
    bright = np.full((20, 20, 3), 1.0)
    img, scale, e0, wb = cam.capture(dark)
    assert e0 == pytest.approx(0.18 / 0.01, rel=1e-6)
    np.testing.assert_allclose(scale, e0 * wb)
    assert abs(int(img.mean()) - round(255 * 0.18 ** (1 / 2.2))) <= 1
    _, _, e1, _ = cam.capture(bright)
    assert 0.18 < e1 < e0  # moves toward the new target, but not all the way
    _, _, e2, _ = cam.capture(bright)
    assert e2 < e1


def test_auto_white_balance_neutralises_a_colour_cast() -> None:
    cam = AutoCamera(CameraModel(noise=False), np.random.default_rng(0))
    img, scale, _, wb = cam.capture(np.full((8, 8, 3), 0.2) * np.array([1.5, 1.0, 0.5]))
    assert wb[1] == pytest.approx(1.0)
    assert np.ptp(img.reshape(-1, 3).mean(0)) <= 1


def test_noise_is_signal_dependent_and_seeded() -> None:
    x = np.full((200, 200, 3), 0.3)
    a = AutoCamera(CameraModel(), np.random.default_rng(5)).capture(x)[0]
    b = AutoCamera(CameraModel(), np.random.default_rng(5)).capture(x)[0]
    np.testing.assert_array_equal(a, b)
    assert a.std() > 0.5


def test_opening_reveals_face_into_the_opening() -> None:
    room = RoomSpec(
        np.array([[0, 0], [5, 0], [5, 4], [0, 4]], float),
        openings=[
            Opening("window", 0, 1.5, 3.0, 0.9, 2.1, 0.2),
            Opening("passage", 1, 1.0, 2.0, 0.0, 2.1, 0.15),
        ],
    )
    parts, _ = build_room(room, 0.1, MAT)
    centres = {"window": np.array([2.25, -0.1, 1.5]), "passage": np.array([5.075, 1.5, 1.05])}
    for p in parts:
        for kind, c in centres.items():
            if p.name.endswith(f"{kind}_reveal") or p.name.endswith(f"{kind}_floor"):
                m = _mesh(p.piece)
                to_axis = c - m.triangles_center
                facing = np.einsum("ij,ij->i", m.face_normals, to_axis)
                assert np.all(facing > 0), p.name


def test_box_points_is_box_with_two_point_lights() -> None:
    box_spec, points = build_preset("box"), build_preset("box_points")
    np.testing.assert_array_equal(box_spec.rooms[0].polygon, points.rooms[0].polygon)
    old = {light["name"] for light in box_spec.lights}
    added = [light for light in points.lights if light["name"] not in old]
    assert {light["type"] for light in box_spec.lights} == {"area", "window"}
    assert sorted(light["name"] for light in added) == ["downlight", "floor_lamp"]
    poly = points.rooms[0].polygon
    for light in added:
        assert light["type"] == "point"
        x, y, z = light["position"]
        assert point_in_polygon(np.array([x]), np.array([y]), poly).all()
        assert points.rooms[0].floor_z < z < points.rooms[0].ceiling_z
    assert {light["profile"] for light in added} == {"isotropic", "ies_light_1"}
