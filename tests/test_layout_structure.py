"""Layout, geometric half: Manhattan frame, floor/ceiling, wall scores, floorplans (small exact cases)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from reroom.layout import LayoutError, StructureOptions, estimate_structure
from reroom.layout.floorplan import min_cost_cycle, polygon_area, room_regions, snap_region
from reroom.layout.manhattan import manhattan_frame, rotation_angle_deg
from reroom.layout.meshops import (
    close_labels,
    mean_edge_length,
    vertex_adjacency,
    vertex_areas,
    vertex_normals,
)
from reroom.layout.planes import horizontal_planes
from reroom.layout.walls import FloorGrid, Segment, wall_scores
from reroom.synth.geometry import Piece, box, grid_rect
from reroom.synth.presets import MATERIALS
from reroom.synth.room import Opening, RoomSpec, build_room


def room_mesh(rooms: list[RoomSpec], h: float = 0.1, extra: list[Piece] = ()) -> trimesh.Trimesh:
    """A clean, welded mesh of rooms built by the generator's own room builder."""
    pieces = [p.piece for room in rooms for p in build_room(room, h, MATERIALS)[0]]
    pc = Piece.concat([*pieces, *extra])
    m = trimesh.Trimesh(pc.vertices, pc.faces, process=False)
    m.merge_vertices()
    return m


def box_room(w: float = 5.0, d: float = 4.0, height: float = 2.7, openings=()) -> RoomSpec:
    return RoomSpec(np.array([[0, 0], [w, 0], [w, d], [0, d]], float), 0.0, height, list(openings))


def yaw_equivalent_angle(rot: np.ndarray, truth: np.ndarray) -> float:
    """Smallest angle between ``rot`` and ``truth`` up to multiples of 90° about z."""
    best = 180.0
    for k in range(4):
        yaw = Rotation.from_euler("z", 90 * k, degrees=True).as_matrix()
        best = min(best, rotation_angle_deg(rot, yaw @ truth))
    return best


# ----------------------------------------------------------------------------- mesh helpers


def test_mesh_helpers_on_a_unit_square():
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    assert np.allclose(vertex_normals(v, f), [0, 0, 1])
    assert vertex_areas(v, f).sum() == pytest.approx(1.0)
    assert mean_edge_length(v, f) == pytest.approx((4 + 2 * np.sqrt(2)) / 6)
    a = vertex_adjacency(f, 4)
    assert a[0, 2] and a[0, 1] and not a[1, 3] and not a[0, 0]


def test_label_closing_fills_a_hole_but_keeps_other_classes():
    # A 7x7 grid of vertices: class 0 everywhere except one unlabelled vertex in the middle
    # and a column of class 1 at the right edge.
    n = 7
    idx = np.arange(n * n).reshape(n, n)
    faces = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = idx[i, j], idx[i + 1, j], idx[i + 1, j + 1], idx[i, j + 1]
            faces += [[a, b, c], [a, c, d]]
    adj = vertex_adjacency(np.array(faces), n * n)
    lab = np.zeros(n * n, np.uint8)
    lab[idx[3, 3]] = 255
    lab[idx[:, 6]] = 1
    out = close_labels(lab, adj, (0, 1), 255, steps=1)
    assert out[idx[3, 3]] == 0
    assert np.all(out[idx[:, 6]] == 1)


# ----------------------------------------------------------------------------- Manhattan frame


@pytest.mark.parametrize(
    "euler",
    [(0, 0, 0), (0, 0, 27), (35, 0, 0), (0, -38, 61), (30, 20, -140), (-40, 5, 200)],
)
def test_manhattan_frame_recovers_known_rotations(euler):
    m = room_mesh([box_room(openings=[Opening("window", 1, 1.0, 2.5, 0.9, 2.0, 0.2)])])
    q = Rotation.from_euler("xyz", euler, degrees=True).as_matrix()
    v = np.asarray(m.vertices) @ q.T
    f = np.asarray(m.faces)
    rot = manhattan_frame(vertex_normals(v, f), vertex_areas(v, f))
    # rot maps the rotated mesh back to an axis-aligned frame: rot @ q is a pure yaw.
    assert yaw_equivalent_angle(rot @ q, np.eye(3)) < 0.05
    assert rot[2] @ (q @ [0, 0, 1]) > 0.999  # up is up, not down
    assert np.linalg.det(rot) == pytest.approx(1.0)


def test_manhattan_frame_identity_for_aligned_mesh():
    m = room_mesh([box_room()])
    v, f = np.asarray(m.vertices), np.asarray(m.faces)
    rot = manhattan_frame(vertex_normals(v, f), vertex_areas(v, f))
    assert rotation_angle_deg(rot, np.eye(3)) < 0.01


def test_manhattan_frame_needs_horizontal_surfaces():
    sphere = trimesh.creation.icosphere(2)
    cyl = trimesh.creation.cylinder(radius=1.0, height=2.0, sections=64)
    walls_only = trimesh.Trimesh(cyl.vertices, cyl.faces[np.abs(cyl.face_normals[:, 2]) < 0.5])
    with pytest.raises(LayoutError, match="horizontal surfaces"):
        v, f = walls_only.vertices, walls_only.faces
        manhattan_frame(vertex_normals(v, f), vertex_areas(v, f))
    assert sphere.is_watertight  # (the sphere case is tested end to end below)


# ----------------------------------------------------------------------------- floor, ceiling


def test_floor_and_ceiling_from_height_histogram():
    rng = np.random.default_rng(0)
    floor = rng.uniform(0, 4, (4000, 2))
    table = rng.uniform(1, 2, (500, 2))
    z = np.concatenate(
        [
            0.013 + 0.003 * rng.standard_normal(4000),  # floor, noisy
            0.75 + 0.002 * rng.standard_normal(500),  # a table top (faces up too)
            2.61 + 0.003 * rng.standard_normal(4000),  # ceiling
            -0.4 + 0.01 * rng.standard_normal(20),  # a few specks below the floor
        ]
    )
    nz = np.concatenate([np.ones(4500), -np.ones(4000), np.ones(20)])
    w = np.ones(len(z))
    f, c = horizontal_planes(z, nz, w, 0.03)
    assert f.z == pytest.approx(0.013, abs=0.002)
    assert c.z == pytest.approx(2.61, abs=0.002)
    assert len(floor) and len(table)
    # Unknown orientation (the thesis's variant): any vertical normal votes for both.
    f2, c2 = horizontal_planes(z, np.abs(nz), w, 0.03, oriented=False)
    assert (f2.z, c2.z) == pytest.approx((0.013, 2.61), abs=0.002)


def test_no_ceiling_above_floor():
    z = np.zeros(100)
    f, c = horizontal_planes(z, np.ones(100), np.ones(100), 0.03)
    assert f is not None and c is None


# ----------------------------------------------------------------------------- walls


def _two_rooms(gap: float, x: float = 4.0) -> list[RoomSpec]:
    a = RoomSpec(np.array([[0, 0], [x, 0], [x, 3], [0, 3]], float), 0.0, 2.6, [], "a")
    b = RoomSpec(np.array([[x + gap, 0], [8, 0], [8, 3], [x + gap, 3]], float), 0.0, 2.6, [], "b")
    return [a, b]


def test_thin_wall_survives_the_empty_behind_test_only_with_the_fix():
    # A 20 cm wall on a 10 cm grid: two cells behind room a's face is room b's face.
    m = room_mesh(_two_rooms(0.2, x=3.95), h=0.1)
    v, f = np.asarray(m.vertices), np.asarray(m.faces)
    n = vertex_normals(v, f)
    grid = FloorGrid(-0.5, -0.5, 0.1, (90, 40))
    col_a = grid.index(np.array([[3.95, 1.5]]))[0][0]  # room a's face (facing -x) is in it

    def kept(thin: bool) -> float:
        ws = wall_scores(v, n, 0.0, 2.6, 0.1, grid=grid, thin_walls=thin)
        has = ws.raw[1][col_a] > 0
        return float(np.mean(ws.score[1][col_a][has] > 0))

    # The thesis's test zeroes the thin wall (its Fig. 4.5) wherever the far face's
    # vertices fall in the cell behind (the grid aliases with the mesh in a few rows).
    assert kept(False) < 0.2
    assert kept(True) == 1.0


def _seg(d, off, lo, hi):
    return Segment(d, off, lo, hi, hi - lo)


def test_min_cost_cycle_closes_a_box_and_bridges_a_doorway():
    segs = [
        _seg(2, 0.0, 0.1, 1.8),  # bottom, broken by a doorway
        _seg(2, 0.0, 2.7, 4.9),
        _seg(1, 5.0, 0.1, 3.9),  # right
        _seg(3, 4.0, 0.1, 4.9),  # top
        _seg(0, 0.0, 0.1, 3.9),  # left
        _seg(0, 2.0, 1.0, 1.6),  # a furniture face inside
    ]
    cyc = min_cost_cycle(segs, alpha=1.0)
    assert cyc is not None
    assert np.allclose(sorted(map(tuple, cyc.polygon)), [(0, 0), (0, 4), (5, 0), (5, 4)])
    assert polygon_area(cyc.polygon) == pytest.approx(20.0)
    assert 5 not in cyc.order


def test_regions_split_rooms_at_thin_wall_and_snap_to_lines():
    grid = FloorGrid(0.0, 0.0, 0.05, (170, 70))
    xc, yc = grid.centres(0)[:, None], grid.centres(1)[None, :]
    mask = ((xc > 0.05) & (xc < 3.95) | (xc > 4.2) & (xc < 8.0)) & (yc > 0.05) & (yc < 3.0)
    labels, n = room_regions(mask, grid.cell)
    assert n == 2
    poly = snap_region(labels == 1, grid, [0.02, 4.0, 4.15, 8.01], [0.03, 3.02])
    assert polygon_area(poly) > 0
    assert {tuple(p) for p in np.round(poly, 3)} in (
        {(0.02, 0.03), (4.0, 0.03), (4.0, 3.02), (0.02, 3.02)},
        {(4.15, 0.03), (8.01, 0.03), (8.01, 3.02), (4.15, 3.02)},
    )


# ----------------------------------------------------------------------------- whole structure


def test_structure_of_an_l_shaped_room_and_two_rooms_with_a_passage():
    lshape = RoomSpec(
        np.array([[0, 0], [6, 0], [6, 3], [3, 3], [3, 5.5], [0, 5.5]], float),
        0.0,
        2.6,
        [
            Opening("window", 0, 2.0, 3.4, 0.9, 2.0, 0.2),
            Opening("door", 4, 1.0, 1.9, 0.0, 2.05, 0.03),
        ],
    )
    st = estimate_structure(*_vf(room_mesh([lshape])))
    assert len(st.rooms) == 1
    assert np.allclose(st.rooms[0].polygon, lshape.polygon, atol=0.02)

    rooms = _two_rooms(0.15)
    rooms[0].openings.append(Opening("passage", 1, 1.0, 1.9, 0.0, 2.1, 0.15))
    rooms[1].openings.append(Opening("passage", 3, 1.1, 2.0, 0.0, 2.1, 0.15, build_tunnel=False))
    st = estimate_structure(*_vf(room_mesh(rooms)))
    assert len(st.rooms) == 2
    polys = sorted((r.polygon for r in st.rooms), key=lambda p: p[:, 0].min())
    assert np.allclose(sorted(map(tuple, polys[0])), [(0, 0), (0, 3), (4, 0), (4, 3)], atol=0.02)
    assert np.allclose(
        sorted(map(tuple, polys[1])), [(4.15, 0), (4.15, 3), (8, 0), (8, 3)], atol=0.02
    )
    # The thesis's single cycle sees one room around both.
    st = estimate_structure(*_vf(room_mesh(rooms)), StructureOptions(floorplan="cycle"))
    assert len(st.rooms) == 1 and st.rooms[0].area > 20


def test_closed_cabinet_against_a_wall_does_not_notch_the_room():
    # A closed box (front, sides, back, top) against the wall of a complete mesh: its
    # front scores as a wall and its footprint is walled off unless walls must reach
    # the ceiling (a notch and a false passage above the cabinet, seen on `furnished`).
    # Parts not welded, as in the generator's clean mesh (welding happened to hide it).
    cabinet = box([4.5, 1.4, 0.0], [4.95, 2.4, 1.2], 0.1, skip=("-z",))
    parts = [p.piece for p in build_room(box_room(), 0.1, MATERIALS)[0]]
    pc = Piece.concat([*parts, cabinet])
    st = estimate_structure(pc.vertices, pc.faces)
    assert len(st.rooms) == 1
    assert np.allclose(
        sorted(map(tuple, st.rooms[0].polygon)), [(0, 0), (0, 4), (5, 0), (5, 4)], atol=0.02
    )


def _vf(m: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(m.vertices), np.asarray(m.faces)


def test_structure_errors_say_what_was_missing():
    sphere = trimesh.creation.icosphere(3, radius=2.0)
    with pytest.raises(LayoutError, match="floor|walls|horizontal"):
        estimate_structure(*_vf(sphere))
    # Floor and ceiling but no walls: two planes and a small post (a few vertical normals).
    floor = grid_rect([0, 0, 0], [1, 0, 0], [0, 1, 0], 4, 4, 0.1)
    ceil = grid_rect([0, 0, 2.5], [0, 1, 0], [1, 0, 0], 4, 4, 0.1)
    post = box([1.9, 1.9, 0.0], [2.1, 2.1, 0.3], 0.1, skip=("-z",))
    pc = Piece.concat([floor, ceil, post])
    with pytest.raises(LayoutError, match="no (walls found|closed floorplan)") as err:
        estimate_structure(pc.vertices, pc.faces)
    assert err.value.partial["floor"].z == pytest.approx(0.0, abs=1e-6)
    assert err.value.partial["ceiling"].z == pytest.approx(2.5, abs=1e-6)
    # No floor: a room whose floor was not scanned.
    parts = [p for p in build_room(box_room(), 0.1, MATERIALS)[0] if p.label != "floor"]
    pc = Piece.concat([p.piece for p in parts])
    with pytest.raises(LayoutError, match="no floor found"):
        estimate_structure(pc.vertices, pc.faces)


def test_structure_of_a_tilted_and_turned_room():
    m = room_mesh([box_room(openings=[Opening("window", 1, 1.0, 2.5, 0.9, 2.0, 0.2)])])
    q = Rotation.from_euler("xyz", (33, -8, 50), degrees=True).as_matrix()
    st = estimate_structure(np.asarray(m.vertices) @ q.T, np.asarray(m.faces))
    assert yaw_equivalent_angle(st.rotation @ q, np.eye(3)) < 0.05
    assert st.ceiling.z - st.floor.z == pytest.approx(2.7, abs=0.005)
    (room,) = st.rooms
    assert room.area == pytest.approx(20.0, rel=0.01)
    assert sorted(w["length"] for w in room.walls) == pytest.approx([4, 4, 5, 5], abs=0.02)


# ----------------------------------------------------------------------------- no ceiling seen


def _no_ceiling(room: RoomSpec, cut: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A room mesh without its ceiling; ``cut``: also without anything above that height."""
    parts = [p for p in build_room(room, 0.1, MATERIALS)[0] if p.label != "ceiling"]
    pc = Piece.concat([p.piece for p in parts])
    v, f = pc.vertices, pc.faces
    if cut is not None:
        f = f[(v[f][:, :, 2] <= cut + 1e-9).all(axis=1)]
    m = trimesh.Trimesh(v, f, process=False)
    m.remove_unreferenced_vertices()
    m.merge_vertices()
    return _vf(m)


def test_room_without_a_seen_ceiling_gets_an_estimated_one():
    v, f = _no_ceiling(box_room())
    with pytest.raises(LayoutError, match="no ceiling found"):
        estimate_structure(v, f, StructureOptions(estimate_ceiling=False))
    st = estimate_structure(v, f)
    assert st.ceiling_estimated
    # The walls' tops are the highest wall points: 2.7 m (within a 10 cm mesh row).
    assert 2.6 <= st.ceiling.z - st.floor.z <= 2.7 + 1e-6
    assert st.ceiling.support == 0.0
    (room,) = st.rooms
    assert room.area == pytest.approx(20.0, rel=0.02)
    assert sorted(w["length"] for w in room.walls) == pytest.approx([4, 4, 5, 5], abs=0.05)
    assert room.support > 0.9 and np.all(room.seen > 0.8)
    assert any("no ceiling seen" in w and "lower bound" in w for w in st.warnings)
    # The same room with its ceiling keeps the seen one and no warning.
    st = estimate_structure(*_vf(room_mesh([box_room()])))
    assert not st.ceiling_estimated and st.warnings == []
    assert st.ceiling.z - st.floor.z == pytest.approx(2.7, abs=0.005)


def test_estimated_ceiling_is_at_least_the_smallest_room_height():
    # Walls scanned only up to 1.5 m: the ceiling goes to the floor + min_room_height.
    v, f = _no_ceiling(box_room(), cut=1.5)
    st = estimate_structure(v, f, StructureOptions(min_room_height=2.2))
    assert st.ceiling_estimated
    assert st.ceiling.z - st.floor.z == pytest.approx(2.2, abs=1e-9)
    assert any("smallest room height" in w for w in st.warnings)
    assert st.rooms and st.rooms[0].area == pytest.approx(20.0, rel=0.02)


def test_partial_floor_coverage_extends_to_the_walls_that_face_it():
    from reroom.layout.floorplan import extend_to_walls

    grid = FloorGrid(0.0, 0.0, 0.1, (50, 40))  # 5 x 4 m
    region = np.zeros(grid.shape, bool)
    region[5:25, 5:30] = True  # the floor seen: x 0.5-2.5, y 0.5-3.0
    # A wall at x = 4.0 facing -x along y 1.0-2.5 (1.5 m from the coverage), one at
    # x = 0.2 facing +x (0.3 m), and one facing away from the coverage at y = 3.8.
    segs = [_seg(1, 4.0, 1.0, 2.5), _seg(0, 0.2, 0.5, 3.0), _seg(3, 0.1, 0.5, 2.5)]
    out = extend_to_walls(region, segs, grid, reach=3.0)
    assert out[region].all()
    assert out[25:40, 10:25].all()  # up to the x = 4.0 wall, along its extent
    assert not out[25:40, 27:].any() and not out[40:, :].any()
    assert out[2:5, 5:30].all() and not out[:2].any()  # up to the x = 0.2 wall
    assert not out[:, :5].any()  # the wall facing away adds nothing
    # Beyond the reach nothing is added.
    assert not extend_to_walls(region, segs[:1], grid, reach=1.0)[25:].any()


def test_points_outside_a_region_are_included_by_rectangles():
    from reroom.layout.floorplan import include_points

    grid = FloorGrid(0.0, 0.0, 0.1, (60, 60))  # 6 x 6 m
    region = np.zeros(grid.shape, bool)
    region[10:40, 30:55] = True  # x 1.0-4.0, y 3.0-5.5
    # One point inside (nothing to add), one 2 m in front of the region.
    out, xs, ys, n = include_points(region, np.array([[2.0, 4.0], [2.5, 1.0]]), [], grid, 0.5)
    assert n == 1 and out[region].all()
    assert out[20:30, 5:30].all()  # x 2.0-3.0 (the point +- 0.5 m) from y 0.5 up to the region
    assert not out[:, :5].any() and not out[:20, :30].any() and not out[30:, :30].any()
    assert min(ys) == pytest.approx(0.5) and min(xs) == pytest.approx(2.0)
    assert max(xs) == pytest.approx(3.0)
    # A wall facing the point 20 cm behind it clips the rectangle there, not before it.
    out, _, ys, _ = include_points(
        region, np.array([[2.5, 1.0]]), [_seg(2, 0.8, 1.0, 4.0)], grid, 0.5
    )
    assert out[20:30, 8:30].all() and not out[:, :8].any()
    assert min(ys) == pytest.approx(0.8)
    # A wall the point stands behind (it faces away) does not.
    out, *_ = include_points(region, np.array([[2.5, 1.0]]), [_seg(3, 0.8, 1.0, 4.0)], grid, 0.5)
    assert out[20:30, 5:30].all()
    # Nothing outside: the region as it was.
    out, xs, ys, n = include_points(region, np.array([[2.0, 4.0]]), [], grid, 0.5)
    assert n == 0 and xs == [] and (out == region).all()


def _front_half_without_ceiling() -> tuple[np.ndarray, np.ndarray]:
    """A 5 x 8 m room without its ceiling, scanned only where y >= 4 m (as if every
    camera stood in the near half and looked away from it, never down at its floor)."""
    v, f = _no_ceiling(box_room(5.0, 8.0))
    f = f[(v[f][:, :, 1] >= 4.0 - 1e-9).all(axis=1)]
    m = trimesh.Trimesh(v, f, process=False)
    m.remove_unreferenced_vertices()
    return _vf(m)


def test_a_partial_room_is_grown_to_contain_the_cameras():
    from reroom.layout.floorplan import points_in_polygon

    v, f = _front_half_without_ceiling()
    cams = np.array([[2.5, 1.0, 1.4], [3.0, 2.0, 1.4]])
    alone = estimate_structure(v, f)
    assert alone.ceiling_estimated
    (room,) = alone.rooms
    assert room.area == pytest.approx(20.0, rel=0.05)  # the half that was seen
    assert not points_in_polygon(cams[:, :2], room.polygon).any()
    st = estimate_structure(v, f, cameras=cams)
    (grown,) = st.rooms
    assert grown.cameras_added == 2
    assert points_in_polygon(cams[:, :2], grown.polygon).all()
    # With room around each camera: 0.5 m (a nearby line may stand in, 24 cm at most).
    for dx, dy in ((0.25, 0), (-0.25, 0), (0, 0.25), (0, -0.25)):
        assert points_in_polygon(cams[:, :2] + [dx, dy], grown.polygon).all()
    # The seen part is unchanged; what was added are 1 m wide rectangles: from the
    # nearer camera (3, 2) to the coverage at y = 4, from the other one to that one.
    assert points_in_polygon(room.polygon.mean(axis=0)[None], grown.polygon)[0]
    assert grown.area - room.area == pytest.approx(1.0 * 2.5 + 1.0 * 1.0, rel=0.05)
    assert min(grown.polygon[:, 1]) == pytest.approx(0.5, abs=0.1)
    assert any("grown to contain 2 camera positions" in w for w in st.warnings)


def test_cameras_do_not_change_a_room_whose_ceiling_was_seen():
    m = room_mesh([box_room()])
    far = np.array([[9.0, 9.0, 1.4]])  # wherever they are, a seen ceiling outlines the room
    a, b = estimate_structure(*_vf(m)), estimate_structure(*_vf(m), cameras=far)
    assert not b.ceiling_estimated and b.grid == a.grid
    assert np.array_equal(a.rooms[0].polygon, b.rooms[0].polygon)
