"""Layout, feature half: wall evidence, baseboard, doors, windows, labels, empty room, evaluation."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from reroom.layout import features as ft
from reroom.layout.emptyroom import (
    PORTAL,
    backing_shell,
    depth_behind_planes,
    empty_room_mesh,
    reveal_points,
    room_shell,
)
from reroom.layout.evaluate import evaluate_layout, floorplan_iou
from reroom.layout.labels import (
    CEILING,
    DOOR,
    FLOOR,
    OTHER,
    WALL,
    WINDOW,
    clean_labels,
    shell_labels,
)
from reroom.layout.meshops import vertex_adjacency, vertex_normals
from reroom.layout.wallgrid import (
    WallGrids,
    accumulate_frames,
    oriented_edges,
    vanishing_points,
)
from reroom.rays import RayCaster
from reroom.scan import Frame, Intrinsics, look_at
from reroom.synth.geometry import Piece
from reroom.synth.presets import MATERIALS
from reroom.synth.room import Opening, RoomSpec, build_room, room_layout

WALL0 = {"start": [0.0, 0.0], "end": [5.0, 0.0], "inward_normal": [0.0, 1.0], "length": 5.0}


def grids_one_wall(cell: float = 0.05) -> WallGrids:
    return WallGrids.empty([WALL0], cell, 0.0, 2.5)


def rect_cells(g: WallGrids, s0: float, s1: float, z0: float, z1: float) -> tuple[slice, slice]:
    c = g.cell
    return slice(int(round(s0 / c)), int(round(s1 / c))), slice(
        int(round(z0 / c)), int(round(z1 / c))
    )


# ----------------------------------------------------------------------------- holes, doors


def test_window_and_passage_from_see_through_rays():
    g = grids_one_wall()
    g.surface[0][:] = 10
    win = rect_cells(g, 1.0, 2.2, 0.9, 2.0)
    g.surface[0][win] = 0
    g.through[0][win] = 8
    door = rect_cells(g, 3.5, 4.4, 0.0, 2.1)
    g.surface[0][door] = 1
    g.through[0][door] = 9
    found = sorted(ft.find_holes(g, 0), key=lambda o: o.s0)
    assert [o.kind for o in found] == ["window", "passage"]
    w, p = found
    assert (w.s0, w.s1, w.z0, w.z1) == pytest.approx((1.0, 2.2, 0.9, 2.0), abs=1e-9)
    assert (p.s0, p.s1, p.z1) == pytest.approx((3.5, 4.4, 2.1), abs=1e-9)


def test_a_window_crossed_by_sparse_rays_is_found_at_a_coarser_pooling():
    # 2 cm cells, each crossed by a ray with probability 0.3 (24 frames of 160x120 cross
    # a third of the cells near `furnished`'s window once each).
    g = grids_one_wall(cell=0.02)
    rng = np.random.default_rng(5)
    crossed = rng.random(g.surface[0].shape) < 0.3
    win = rect_cells(g, 1.0, 2.2, 0.9, 2.0)
    inside = np.zeros_like(crossed)
    inside[win] = True
    g.surface[0][crossed & ~inside] = 1
    g.through[0][crossed & inside] = 1
    assert ft.find_holes(g, 0, pools=(3,)) == []  # specks, removed by the opening
    (w,) = ft.find_holes(g, 0)
    assert w.kind == "window"
    assert (w.s0, w.s1, w.z0, w.z1) == pytest.approx((1.0, 2.2, 0.9, 2.0), abs=0.041)
    # Densely crossed, every pooling gives the same rectangle: the finest one stays.
    dense = grids_one_wall(cell=0.02)
    dense.surface[0][:] = 2
    dense.surface[0][win] = 0
    dense.through[0][win] = 2
    assert ft.find_holes(dense, 0) == ft.find_holes(dense, 0, pools=(3,))


def test_small_holes_and_floor_level_holes_are_not_windows():
    g = grids_one_wall()
    g.surface[0][:] = 10
    g.surface[0][rect_cells(g, 1.0, 1.15, 1.0, 1.15)] = 0
    g.through[0][rect_cells(g, 1.0, 1.15, 1.0, 1.15)] = 5  # 15 cm: a crack, not a window
    g.surface[0][rect_cells(g, 3.0, 4.0, 0.0, 0.8)] = 0
    g.through[0][rect_cells(g, 3.0, 4.0, 0.0, 0.8)] = 5  # behind a sofa, not door-high
    assert ft.find_holes(g, 0) == []


def test_bright_vertices_make_a_window_without_holes():
    g = grids_one_wall()
    g.surface[0][:] = 10
    g.bright[0][rect_cells(g, 2.0, 3.0, 1.0, 2.0)] = 3
    (w,) = ft.find_holes(g, 0)
    assert w.kind == "window" and w.source == "bright"
    assert (w.s0, w.s1, w.z0, w.z1) == pytest.approx((2.0, 3.0, 1.0, 2.0), abs=1e-9)


def _edge_wall(noise: float = 0.02, seed: int = 0) -> WallGrids:
    g = grids_one_wall(0.02)
    rng = np.random.default_rng(seed)
    g.n[0][:] = 4
    g.fv[0][:] = 4 * noise * rng.random(g.n[0].shape)
    g.fh[0][:] = 4 * noise * rng.random(g.n[0].shape)
    return g


def test_door_from_two_jambs_and_a_head():
    g = _edge_wall()
    c = g.cell
    for s in (1.0, 1.9):
        g.fv[0][int(s / c), : int(2.05 / c)] = 4 * 0.2
    g.fh[0][int(1.0 / c) : int(1.9 / c), int(2.05 / c)] = 4 * 0.2
    # A tall vertical edge elsewhere (a shadow) with no head does not make a door.
    g.fv[0][int(4.0 / c), : int(2.4 / c)] = 4 * 0.2
    (d,) = ft.find_doors(g, 0)
    assert (d.s0, d.s1, d.z1) == pytest.approx((1.01, 1.91, 2.05), abs=0.03)


def test_door_with_one_weak_jamb():
    g = _edge_wall()
    c = g.cell
    g.fv[0][int(1.0 / c), : int(2.05 / c)] = 4 * 0.2
    g.fv[0][int(1.9 / c), : int(2.05 / c)] = 4 * 0.045  # barely above the wall
    g.fh[0][int(1.0 / c) : int(1.9 / c), int(2.05 / c)] = 4 * 0.2
    (d,) = ft.find_doors(g, 0)
    assert (d.s0, d.s1) == pytest.approx((1.0, 1.9), abs=0.05)


def test_recessed_door_from_shallow_rays():
    g = grids_one_wall()
    g.surface[0][:] = 10
    r = rect_cells(g, 2.0, 2.9, 0.0, 2.05)
    g.surface[0][r] = 1
    g.shallow[0][r] = 9
    (d,) = ft.find_recessed_doors(g, 0)
    assert (d.s0, d.s1, d.z1) == pytest.approx((2.0, 2.9, 2.05), abs=0.051)
    merged = ft.merge_openings(ft.combine_doors([], [d]), [])
    assert merged == [d]


def test_baseboard_height_skips_the_floor_edge():
    g = _edge_wall(seed=1)
    c = g.cell
    g.fh[0][:, 0] = 4 * 0.3  # the wall-floor junction
    g.fh[0][:, int(0.08 / c)] = 4 * 0.15  # the baseboard's top (cell 4: 8-10 cm)
    h, b, heights = ft.find_baseboard_height(g)
    assert h == pytest.approx(0.09, abs=0.011)
    assert len(b) == len(heights)


def test_opening_iou():
    a = ft.Opening("door", 0, 0.0, 1.0, 0.0, 2.0)
    b = ft.Opening("door", 0, 0.5, 1.5, 0.0, 2.0)
    assert a.iou(b) == pytest.approx(1 / 3)
    assert a.iou(ft.Opening("door", 1, 0.0, 1.0, 0.0, 2.0)) == 0.0


# ----------------------------------------------------------------------------- image evidence


def test_oriented_edges_follow_the_vanishing_direction():
    # A horizontal step edge; the x axis's vanishing point at infinity along image x.
    img = np.zeros((40, 60))
    img[20:] = 1.0
    jj, ii = np.meshgrid(np.arange(60) + 0.5, np.arange(40) + 0.5)
    uv = np.stack([jj.ravel(), ii.ravel()], axis=1)
    along_x = oriented_edges(img, np.array([1.0, 0.0, 0.0]), uv).reshape(40, 60)
    along_y = oriented_edges(img, np.array([0.0, 1.0, 0.0]), uv).reshape(40, 60)
    assert along_x[19:21, 5:-5].min() > 0.2
    assert along_y.max() == 0.0


def test_vanishing_point_of_the_vertical_axis_for_a_level_camera():
    intr = Intrinsics.from_fov(64, 48, 60.0)
    fr = Frame(0, None, look_at([0, 0, 1.5], [1, 0, 1.5]), intr)
    vp = vanishing_points(fr, np.eye(3), 1.0)
    assert abs(vp[2, 2]) < 1e-9  # vertical lines stay parallel: vanishing point at infinity
    assert vp[0, 2] != 0 and vp[0, :2] / vp[0, 2] == pytest.approx([32, 24])  # looking along x


def _window_room(window: Opening, h: float) -> tuple[trimesh.Trimesh, list[dict]]:
    """A 5 x 4 m room with one window on wall 0: its mesh (spacing ``h``) and walls."""
    room = RoomSpec(np.array([[0, 0], [5, 0], [5, 4], [0, 4]], float), 0.0, 2.5, [window])
    parts, _ = build_room(room, h, MATERIALS, baseboard=None)
    pc = Piece.concat([p.piece for p in parts])
    walls = [
        {**w, "length": float(np.linalg.norm(np.subtract(w["end"], w["start"])))}
        for w in room_layout(room, None)["walls"]
    ]
    return trimesh.Trimesh(pc.vertices, pc.faces, process=False), walls


def test_rays_through_a_window_hole_mark_it_open():
    mesh, walls = _window_room(Opening("window", 0, 1.0, 2.2, 0.9, 2.0, 0.2), 0.1)
    intr = Intrinsics.from_fov(64, 48, 70.0)
    g = WallGrids.empty(walls, 0.1, 0.0, 2.5)
    frames = [
        Frame(i, None, look_at([1.6 + 0.3 * i, 2.5, 1.4], [1.6, 0.0, 1.4]), intr) for i in range(3)
    ]
    for fr in frames:  # grey images (the edges do not matter here)
        fr.load_image = lambda: np.full((48, 64, 3), 128, np.uint8)  # type: ignore[method-assign]
    face_wall = np.full(len(mesh.faces), -1)
    accumulate_frames(g, frames, RayCaster(mesh), np.eye(3), face_wall)
    (w,) = ft.find_holes(g, 0, min_size=0.2)
    assert w.kind == "window"
    assert (w.s0, w.s1, w.z0, w.z1) == pytest.approx((1.0, 2.2, 0.9, 2.0), abs=0.11)
    assert g.surface[0].sum() > 0

    # See-through only (no image read, no edges): the same opening evidence.
    g2 = WallGrids.empty(walls, 0.1, 0.0, 2.5)
    for fr in frames:
        fr.load_image = None  # type: ignore[assignment]  # must not be called
    accumulate_frames(g2, frames, RayCaster(mesh), np.eye(3), face_wall, edges=False)
    for name in ("surface", "shallow", "deep", "through"):
        np.testing.assert_array_equal(getattr(g2, name)[0], getattr(g, name)[0])
    assert g2.fh[0].sum() == 0 and g2.n[0].sum() == 0
    # These 64-pixel-wide frames cast a see-through ray from every pixel; from every
    # other one in each direction only when asked (the default for frames >= 240 px).
    g3 = WallGrids.empty(walls, 0.1, 0.0, 2.5)
    accumulate_frames(
        g3, frames, RayCaster(mesh), np.eye(3), face_wall, edges=False, through_stride=2
    )
    rays = [
        sum(getattr(gg, n)[0].sum() for n in ("surface", "shallow", "deep", "through"))
        for gg in (g2, g3)
    ]
    assert rays[0] == pytest.approx(4 * rays[1], rel=0.1)


def test_rays_that_meet_a_window_s_reveal_count_it_open():
    # Cameras to the left of a window in a 20 cm deep wall look at it obliquely: near its
    # right edge their rays cross the wall plane inside the opening and meet the reveal
    # a few centimetres behind it. Counted as shallow recesses (as before session 27)
    # those rays shrank the window by 10 cm; counted as open (``jamb``), it is whole.
    mesh, walls = _window_room(Opening("window", 0, 1.6, 2.8, 0.9, 2.0, 0.2), 0.05)
    intr = Intrinsics.from_fov(160, 120, 60.0)
    eyes = [[0.2 + 0.1 * i, 1.0 + 0.2 * (i % 3), 1.0 + 0.5 * (i % 2)] for i in range(8)]
    frames = [Frame(i, None, look_at(e, [2.2, 0.0, 1.45]), intr) for i, e in enumerate(eyes)]
    g = WallGrids.empty(walls, 0.02, 0.0, 2.5)
    accumulate_frames(
        g, frames, RayCaster(mesh), np.eye(3), np.full(len(mesh.faces), -1), edges=False
    )
    assert g.jamb[0].sum() > 0 and np.all(g.jamb[0] <= g.shallow[0])
    (w,) = ft.find_holes(g, 0)
    assert (w.s0, w.s1, w.z0, w.z1) == pytest.approx((1.6, 2.8, 0.9, 2.0), abs=0.025)
    g.jamb = []  # the reveal's rays as shallow recesses only
    (shrunk,) = ft.find_holes(g, 0)
    assert shrunk.s1 < 2.8 - 0.05


# ----------------------------------------------------------------------------- labels


def test_shell_labels_on_a_clean_room():
    room = RoomSpec(np.array([[0, 0], [4, 0], [4, 3], [0, 3]], float), 0.0, 2.5, [])
    parts, _ = build_room(room, 0.1, MATERIALS, baseboard=None)
    pc = Piece.concat([p.piece for p in parts])
    m = trimesh.Trimesh(pc.vertices, pc.faces, process=False)
    m.merge_vertices()
    v, f = np.asarray(m.vertices), np.asarray(m.faces)
    lay = room_layout(room, None)
    lab, wall = shell_labels(v, vertex_normals(v, f), 0.0, 2.5, lay["walls"], None, 0.05)
    lab = clean_labels(lab, vertex_adjacency(f, len(v)))
    inner = (v[:, 2] > 0.2) & (v[:, 2] < 2.3) & (v[:, 0] > 0.2) & (v[:, 0] < 3.8)
    assert np.all(lab[inner & (np.abs(v[:, 1]) < 1e-6)] == WALL)
    assert np.all(wall[inner & (np.abs(v[:, 1]) < 1e-6)] == 0)
    mid = (v[:, 0] > 0.2) & (v[:, 0] < 3.8) & (v[:, 1] > 0.2) & (v[:, 1] < 2.8)
    assert np.all(lab[mid & (v[:, 2] < 1e-6)] == FLOOR)
    assert np.all(lab[mid & (v[:, 2] > 2.5 - 1e-6)] == CEILING)
    assert np.mean(lab == OTHER) < 0.05


# ----------------------------------------------------------------------------- empty room


def test_room_shell_is_watertight_with_openings():
    poly = np.array([[0, 0], [6, 0], [6, 3], [3, 3], [3, 5.5], [0, 5.5]], float)
    ops = [
        {"kind": "window", "wall": 0, "s0": 2.0, "s1": 3.4, "z0": 0.9, "z1": 2.0, "depth": 0.2},
        {"kind": "door", "wall": 4, "s0": 1.0, "s1": 1.9, "z0": 0.0, "z1": 2.05, "depth": 0.03},
        {"kind": "passage", "wall": 1, "s0": 1.0, "s1": 2.0, "z0": 0.0, "z1": 2.1, "depth": 0.15},
    ]
    m, lab = room_shell(poly, 0.0, 2.6, ops)
    assert m.is_watertight and m.is_winding_consistent
    # Faces point into the room: the enclosed volume is negative.
    assert m.volume == pytest.approx(
        -(25.5 * 2.6 + 1.4 * 1.1 * 0.2 + 0.9 * 2.05 * 0.03 + 1.0 * 2.1 * 0.15), rel=1e-6
    )
    assert {int(x) for x in np.unique(lab)} >= {WALL, FLOOR, CEILING, PORTAL}


def test_empty_room_mesh_from_a_layout_document():
    room = RoomSpec(
        np.array([[0, 0], [4, 0], [4, 3], [0, 3]], float),
        0.0,
        2.5,
        [Opening("door", 1, 1.0, 1.9, 0.0, 2.0, 0.03)],
    )
    lay = room_layout(room, (0.08, 0.012))
    lay["baseboard"]["pieces"] = [
        {"wall": w, "s0": 0.0, "s1": 3.0 if w % 2 else 4.0} for w in (0, 2, 3)
    ] + [{"wall": 1, "s0": 0.0, "s1": 1.0}, {"wall": 1, "s0": 1.9, "s1": 3.0}]
    doc = {"rotation": np.eye(3).tolist(), "rooms": [lay]}
    mesh, lab = empty_room_mesh(doc)
    parts = mesh.split(only_watertight=False)
    assert len(parts) == 6  # the shell and five baseboard boxes
    assert all(p.is_watertight for p in parts)
    assert len(lab) == len(mesh.faces)


def test_backing_shell_lies_a_gap_behind_the_room_and_has_no_window_panes():
    # The L-shaped room of the shell test: five convex corners and one reflex one.
    poly = [[0, 0], [6, 0], [6, 3], [3, 3], [3, 5.5], [0, 5.5]]
    openings = [
        {"kind": "window", "wall": 0, "s0": 2.0, "s1": 3.4, "z0": 0.9, "z1": 2.0, "depth": 0.2},
        {"kind": "door", "wall": 4, "s0": 1.0, "s1": 1.9, "z0": 0.0, "z1": 2.05, "depth": 0.03},
        {"kind": "passage", "wall": 1, "s0": 1.0, "s1": 2.0, "z0": 0.0, "z1": 2.1, "depth": 0.15},
    ]
    room = {"polygon": poly, "floor_z": 0.0, "ceiling_z": 2.6, "openings": openings}
    doc = {"rotation": np.eye(3).tolist(), "rooms": [room]}
    gap, margin = 0.02, 0.05
    mesh, lab = backing_shell(doc, gap, margin)
    assert len(lab) == len(mesh.faces)
    assert not np.isin(lab, [PORTAL]).any()
    assert {WALL, FLOOR, CEILING, DOOR, WINDOW} <= {int(x) for x in np.unique(lab)}
    caster = RayCaster(np.asarray(mesh.vertices), np.asarray(mesh.faces))

    def hit(origin, direction):
        h = caster.intersect(np.array([origin], float), np.array([direction], float))
        return float(h.t[0]), int(lab[h.face[0]]) if h.hit[0] else None

    # Every wall (the reflex corner's two included), the floor and the ceiling: gap out.
    for origin, direction, distance in [
        ([1.0, 1.5, 1.2], [0, -1, 0], 1.5),  # wall 0, beside the window
        ([4.5, 0.5, 1.2], [1, 0, 0], 1.5),  # wall 1, beside the passage
        ([4.5, 1.5, 1.2], [0, 1, 0], 1.5),  # wall 2, towards the reflex corner
        ([1.5, 4.5, 1.2], [1, 0, 0], 1.5),  # wall 3, from the reflex corner
        ([0.5, 4.5, 1.2], [0, 1, 0], 1.0),  # wall 4, beside the door
        ([1.5, 4.5, 1.2], [-1, 0, 0], 1.5),  # wall 5
        ([1.5, 1.5, 1.2], [0, 0, -1], 1.2),  # floor
        ([1.5, 1.5, 1.2], [0, 0, 1], 1.4),  # ceiling
    ]:
        d, label = hit(origin, direction)
        assert d == pytest.approx(distance + gap, abs=1e-6), (origin, direction)
        assert label in (WALL, FLOOR, CEILING)
    # The window has no pane, and is open to its margin; beyond the margin the wall is
    # back. A ray at a slant past the opening meets the reveal (a jamb), not the outside.
    assert not np.isfinite(hit([2.7, 1.5, 1.45], [0, -1, 0])[0])
    d, label = hit([3.0, 0.3, 1.45], [-2, -1, 0])
    assert label == WINDOW and d == pytest.approx(np.hypot(1.05, 0.525), abs=1e-6)
    assert not np.isfinite(hit([2.0 - 0.6 * margin, 1.5, 1.45], [0, -1, 0])[0])
    assert hit([2.0 - 1.6 * margin, 1.5, 1.45], [0, -1, 0])[0] == pytest.approx(1.5 + gap)
    # The passage stays open (its pane is gone); the door's leaf is behind the scanned one.
    assert not np.isfinite(hit([4.5, 1.5, 1.0], [1, 0, 0])[0])
    d, label = hit([1.55, 4.5, 1.0], [0, 1, 0])
    assert label == DOOR and d == pytest.approx(1.0 + gap + 0.03 + gap + margin, abs=1e-6)

    # With the renderer's portal for that window (a little off the layout's opening, at
    # sub-micrometre coordinates as a solve gives them) the opening is the portal's
    # rectangle and its reveals end at the portal's plane.
    portal = tuple(
        np.array(x, float)
        for x in ([2.7200003, -0.19, 1.4600003], [0.69, 0, 0], [0, 0, 0.54], [0, 1, 0])
    )
    mesh, lab = backing_shell(doc, gap, margin, portals=[portal])
    caster = RayCaster(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    d, label = hit([3.0, 0.3, 1.45], [-2, -1, 0])  # meets the jamb at x = 2.03
    assert label == WINDOW and d == pytest.approx(np.hypot(0.97, 0.485), abs=1e-6)
    assert not np.isfinite(hit([2.7, 1.5, 1.45], [0, -1, 0])[0])  # no pane
    # The reveals run from the room's wall plane (in front of the shell's wall) to the
    # portal's plane.
    reveal_y = mesh.vertices[mesh.faces[lab == WINDOW]][..., 1]
    assert reveal_y.max() == pytest.approx(0.0, abs=1e-9)
    assert reveal_y.min() == pytest.approx(-0.19)


def _issue_room_layout() -> dict:
    """The issue's ``furnished`` room as its layout finds it: a window in wall 0 (y = 0,
    the room at y > 0), a door in wall 2."""
    poly = [[0, 0], [6, 0], [6, 4.5], [0, 4.5]]
    openings = [
        {"kind": "window", "wall": 0, "s0": 3.62, "s1": 5.2, "z0": 0.84, "z1": 2.16, "depth": 0.18},
        {"kind": "door", "wall": 2, "s0": 0.7, "s1": 1.6, "z0": 0.0, "z1": 2.05, "depth": 0.02},
    ]
    room = {"polygon": poly, "floor_z": 0.0, "ceiling_z": 2.7, "openings": openings}
    return {"rotation": np.eye(3).tolist(), "rooms": [room]}


def test_backing_shell_keeps_every_face_at_an_uneven_gap():
    """The gap is the scan's depth behind its planes plus a centimetre, to the float
    (0.020591... on the issue's scan, session 50): the grown corners are then off the
    micrometre the cut lines are rounded to. The shell must still have the window's head
    and sill and the door's leaf; they were lost, and a new camera saw out through the
    sill."""
    doc = _issue_room_layout()
    portal = tuple(
        np.array(x, float)
        for x in ([4.405144, -0.183196, 1.499751], [0.79, -0.0016, 0], [0, 0, 0.66], [0, 1, 0])
    )
    even, even_lab = backing_shell(doc, 0.02, 0.05, portals=[portal])
    for gap in (0.020591366540258185, 0.0213, 0.0317):
        mesh, lab = backing_shell(doc, gap, 0.05, portals=[portal])
        np.testing.assert_array_equal(np.bincount(lab), np.bincount(even_lab))
        # The sill (facing up) and the head (facing down) of the window's reveals.
        reveal = mesh.face_normals[lab == WINDOW]
        assert (reveal[:, 2] > 0.99).sum() >= 1 and (reveal[:, 2] < -0.99).sum() >= 1
        caster = RayCaster(np.asarray(mesh.vertices), np.asarray(mesh.faces))
        # Down past the window's inner edge onto its sill, from the room.
        down = np.array([[0.0, -1.0, -1.0]]) / np.sqrt(2.0)
        h = caster.intersect(np.array([[4.4, 0.1, 1.0]]), down)
        assert h.hit[0] and lab[h.face[0]] == WINDOW


def test_backing_shell_reveals_start_at_the_rooms_wall_plane():
    """A window's reveals in the shell reach from the room's wall plane to the portal.
    They started at the shell's wall, ``gap`` behind it; the scan's reveal faces give way
    to them, so a camera looking along the wall past the opening's edge met the shell's
    wall in that gap, dark, where the true jamb is lit by the sky (the issue's new
    camera ``new1``: 78 black pixels, session 51)."""
    doc = _issue_room_layout()
    portal = tuple(
        np.array(x, float)
        for x in ([4.405, -0.183, 1.5], [0.79, 0.0, 0.0], [0.0, 0.0, 0.66], [0, 1, 0])
    )
    gap = 0.0206
    mesh, lab = backing_shell(doc, gap, 0.05, portals=[portal])
    reveal = mesh.triangles[lab == WINDOW]
    assert reveal[..., 1].max() == pytest.approx(0.0, abs=1e-6)  # the room's wall plane
    assert reveal[..., 1].min() == pytest.approx(-0.183, abs=1e-6)  # the portal's
    walls = mesh.triangles[(lab == WALL) & (np.abs(mesh.face_normals[:, 1]) > 0.99)]
    window_wall = walls[walls[..., 1].max(axis=1) < 1.0]
    assert window_wall[..., 1].max() == pytest.approx(-gap, abs=1e-6)  # behind the room
    # From a camera beside the window, along the wall past the opening's near edge: the
    # jamb (x = 3.615), in front of the shell's wall.
    caster = RayCaster(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    eye = np.array([[5.3, 0.68, 2.1]])
    aim = np.array([[3.60, -0.01, 1.6]]) - eye
    h = caster.intersect(eye, aim / np.linalg.norm(aim))
    assert h.hit[0] and lab[h.face[0]] == WINDOW
    hit = eye[0] + h.t[0] * aim[0] / np.linalg.norm(aim)
    assert hit[0] == pytest.approx(3.615, abs=1e-6) and -gap < hit[1] < 0.0
    # A window with no portal keeps its margin-wide opening and its reveals behind.
    plain, plain_lab = backing_shell(doc, gap, 0.05)
    assert plain.triangles[plain_lab == WINDOW][..., 1].max() == pytest.approx(-gap, abs=1e-6)


def test_depth_behind_planes_counts_each_surface_out_of_its_own_plane():
    room = {
        "polygon": [[0, 0], [6, 0], [6, 3], [3, 3], [3, 5.5], [0, 5.5]],
        "floor_z": 0.0,
        "ceiling_z": 2.6,
    }
    rng = np.random.default_rng(4)
    n = 2000
    # Wall 0 (y = 0), 3 cm behind its line; wall 3 (x = 3, from the reflex corner up),
    # on its line: near the corner its points lie along wall 2's line, not out of it.
    w0 = np.column_stack([rng.uniform(0.1, 5.9, n), np.full(n, -0.03), rng.uniform(0, 2.6, n)])
    w3 = np.column_stack([np.full(n, 3.0), rng.uniform(3.0, 5.5, n), rng.uniform(0, 2.6, n)])
    floor = np.column_stack([rng.uniform(0.1, 2.9, n), rng.uniform(0.1, 5.4, n), np.full(n, -0.01)])
    pts = np.concatenate([w0, w3, floor])
    lab = np.repeat([WALL, WALL, FLOOR], n)
    assert depth_behind_planes(room, pts, lab) == pytest.approx(0.03, abs=1e-9)
    assert depth_behind_planes(room, pts[n:], lab[n:]) == pytest.approx(0.01, abs=1e-9)
    assert depth_behind_planes(room, pts[n : 2 * n], lab[n : 2 * n]) == 0.0
    assert depth_behind_planes(room, pts[:0], lab[:0]) == 0.0


def test_reveal_points_are_the_window_points_on_its_reveal_surfaces():
    # A window in wall 0 (y = 0, the room at y > 0): s 1-2 m, z 1-1.8 m, 0.2 m deep.
    room = {
        "polygon": [[0, 0], [4, 0], [4, 3], [0, 3]],
        "openings": [
            {"kind": "window", "wall": 0, "s0": 1.0, "s1": 2.0, "z0": 1.0, "z1": 1.8, "depth": 0.2},
            {"kind": "door", "wall": 0, "s0": 3.0, "s1": 3.8, "z0": 0.0, "z1": 2.0, "depth": 0.2},
        ],
    }
    pts = np.array(
        [
            [1.0, -0.1, 1.4],  # on the left jamb
            [2.01, -0.05, 1.4],  # the right jamb, 1 cm off its plane
            [1.5, -0.1, 1.0],  # the sill
            [1.5, -0.1, 1.8],  # the head
            [0.98, 0.0, 1.4],  # the wall's plane beside the jamb (a fused scan's bevel)
            [0.985, -0.015, 1.4],  # the bevel itself
            [1.5, -0.1, 1.3],  # a pot on the sill, 30 cm up: not the reveal
            [1.5, -0.2, 1.4],  # the pane at the far end
            [0.9, 0.0, 1.4],  # the wall 10 cm beside the opening
            [3.4, -0.1, 1.0],  # the door's reveal: no window
        ]
    )
    lab = np.full(len(pts), WINDOW)
    got = reveal_points(room, pts, lab)
    assert got.tolist() == [True] * 6 + [False] * 4
    # Only window-labelled points: the same jamb point as a wall point is not marked.
    assert not reveal_points(room, pts[:1], np.array([WALL]))[0]
    assert not reveal_points({"polygon": [], "openings": []}, pts, lab).any()


# ----------------------------------------------------------------------------- evaluation


def test_evaluation_of_the_truth_is_perfect():
    a = RoomSpec(
        np.array([[0, 0], [4, 0], [4, 4.5], [0, 4.5]], float),
        0.0,
        2.7,
        [
            Opening("window", 0, 1.2, 2.6, 0.9, 2.1, 0.2),
            Opening("passage", 1, 1.8, 2.7, 0.0, 2.1, 0.15),
        ],
    )
    truth = {"rooms": [room_layout(a, (0.08, 0.012))]}
    est = {"rotation": np.eye(3).tolist(), "rooms": [dict(truth["rooms"][0])]}
    est["rooms"][0]["baseboard"] = {
        "height": 0.08,
        "depth": 0.012,
        "pieces": [
            {"wall": 0, "s0": 0.0, "s1": 4.0},
            {"wall": 1, "s0": 0.0, "s1": 1.8},
            {"wall": 1, "s0": 2.7, "s1": 4.5},
            {"wall": 2, "s0": 0.0, "s1": 4.0},
            {"wall": 3, "s0": 0.0, "s1": 4.5},
        ],
    }
    ev = evaluate_layout(est, truth, np.zeros(10), np.zeros(10))
    assert ev["iou"] == pytest.approx(1.0)
    assert ev["wall_error_cm"]["max"] == pytest.approx(0.0, abs=1e-9)
    assert ev["floor_error_cm"] == 0.0 and ev["ceiling_error_cm"] == 0.0
    assert ev["label_accuracy"] == 1.0
    for kind in ("window", "passage", "baseboard"):
        assert ev["features"][kind]["precision"] == 1.0
        assert ev["features"][kind]["recall"] == 1.0
    # A shifted room: IoU drops as expected.
    iou, per = floorplan_iou(
        [np.array([[0.2, 0], [4.2, 0], [4.2, 4.5], [0.2, 4.5]])], [np.asarray(a.polygon)]
    )
    assert iou == pytest.approx(3.8 / 4.2, abs=0.01) and per == [pytest.approx(iou)]


def test_bright_hdr_vertices_are_binned_on_their_wall():
    from reroom.layout.wallgrid import accumulate_bright

    g = grids_one_wall()
    rng = np.random.default_rng(0)
    xyz = np.column_stack([rng.uniform(0, 5, 20000), np.zeros(20000), rng.uniform(0, 2.5, 20000)])
    lum = np.full(len(xyz), 0.2)
    inside = (xyz[:, 0] > 2.0) & (xyz[:, 0] < 3.0) & (xyz[:, 2] > 1.0) & (xyz[:, 2] < 2.0)
    lum[inside] = 50.0  # daylight through a (hole-filled) window
    thr = accumulate_bright(g, xyz, lum, np.zeros(len(xyz), int), factor=8.0)
    assert thr == pytest.approx(1.6)
    (w,) = ft.find_holes(g, 0)
    assert w.kind == "window" and w.source == "bright"
    assert (w.s0, w.s1, w.z0, w.z1) == pytest.approx((2.0, 3.0, 1.0, 2.0), abs=0.051)


def test_fast_ply_writer_matches_plyfile(tmp_path):
    from plyfile import PlyData, PlyElement

    from reroom.io.mesh import read_ply, write_triangle_ply

    m = trimesh.creation.icosphere(2)
    attrs = {
        "label": np.arange(len(m.vertices)).astype(np.uint8),
        "room": np.full(len(m.vertices), -1, np.int16),
        "radiance": np.random.default_rng(0).random((len(m.vertices), 3)),
    }
    # The same mesh written by plyfile (the reference PLY implementation) has the same bytes.
    names = [("x", "f4"), ("y", "f4"), ("z", "f4"), ("label", "u1"), ("room", "i2")]
    names += [(f"radiance_{c}", "f4") for c in "rgb"]
    vert = np.empty(len(m.vertices), dtype=names)
    for i, c in enumerate("xyz"):
        vert[c] = m.vertices[:, i]
    vert["label"], vert["room"] = attrs["label"], attrs["room"]
    for i, c in enumerate("rgb"):
        vert[f"radiance_{c}"] = attrs["radiance"][:, i]
    face = np.empty(len(m.faces), dtype=[("vertex_indices", "i4", (3,))])
    face["vertex_indices"] = m.faces
    PlyData([PlyElement.describe(vert, "vertex"), PlyElement.describe(face, "face")]).write(
        str(tmp_path / "a.ply")
    )
    write_triangle_ply(tmp_path / "b.ply", m.vertices, m.faces, attrs)
    assert (tmp_path / "a.ply").read_bytes() == (tmp_path / "b.ply").read_bytes()
    write_triangle_ply(
        tmp_path / "c.ply", m.vertices, m.faces, None, {"label": np.ones(len(m.faces), np.uint8)}
    )
    back = read_ply(tmp_path / "c.ply")
    assert np.array_equal(back.faces, m.faces)


def _two_rooms_walls() -> tuple[list[dict], np.ndarray]:
    """Two 4 x 4.5 m rooms side by side, a 0.15 m wall between them (x 4.0-4.15)."""

    def wall(index, start, end, n):
        a, b = np.array(start, float), np.array(end, float)
        return {"index": index, "start": a, "end": b, "inward_normal": np.array(n, float)}

    left = [
        wall(0, (0, 0), (4, 0), (0, 1)),
        wall(1, (4, 0), (4, 4.5), (-1, 0)),
        wall(2, (4, 4.5), (0, 4.5), (0, -1)),
        wall(3, (0, 4.5), (0, 0), (1, 0)),
    ]
    right = [
        wall(0, (4.15, 0), (8.15, 0), (0, 1)),
        wall(1, (8.15, 0), (8.15, 4.5), (-1, 0)),
        wall(2, (8.15, 4.5), (4.15, 4.5), (0, -1)),
        wall(3, (4.15, 4.5), (4.15, 0), (1, 0)),
    ]
    return left + right, np.array([0, 0, 0, 0, 1, 1, 1, 1])


def test_a_window_that_is_the_far_side_of_a_passage_becomes_that_passage():
    walls, wall_room = _two_rooms_walls()
    passage = ft.Opening("passage", 1, 1.8, 2.7, 0.0, 2.1)  # left room's wall at x = 4.0
    # Seen from the right room only from 0.94 m up: a hole that misses the floor. Its
    # wall runs the other way (y from 4.5 down), so y 2.02-2.68 is s 1.82-2.48.
    far_side = ft.Opening("window", 7, 1.82, 2.48, 0.94, 1.92)
    outside = ft.Opening("window", 4, 1.0, 2.4, 0.9, 2.1)  # the right room's y = 0 wall
    interior = ft.Opening("window", 1, 3.2, 3.9, 1.0, 1.8)  # nothing on the far side
    out = ft.join_shared_openings([passage, far_side, outside, interior], walls, wall_room)
    assert [o.kind for o in out] == ["passage", "passage", "window", "window"]
    assert [o.into for o in out] == [1, 0, -1, 1]
    assert (out[1].s0, out[1].s1, out[1].z0, out[1].z1) == (1.82, 2.48, 0.0, 2.1)
    assert far_side.kind == "window"  # the input is left as it was
    # A wall further than max_gap behind is another room, not the far side of this wall.
    assert ft.join_shared_openings([far_side], walls, wall_room, max_gap=0.1)[0].into == -1
