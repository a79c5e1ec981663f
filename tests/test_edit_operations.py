"""Edit operations on a small exact room: each op changes the right part, by the right amount.

The room is a 4 x 3 x 2.5 m box (0.25 m grid) with a 0.6 x 0.6 x 0.8 m block on the
floor, albedo 0.4 everywhere, lit by one isotropic point light of intensity 1 (model
units). With ``max_depth=2`` (direct light only) the radiance of a floor point is the
closed form ``rho / pi * I * cos / d^2``, so every edit has an exact expected effect.
Radiance is probed per point with :func:`reroom.edit.bake_vertex_radiance` (same seed for
both sides of a comparison).
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import trimesh

from reroom.edit import (
    EditError,
    bake_vertex_radiance,
    composite_insertion,
    default_edit_sets,
    edited_scene,
    parse_edits,
    render_edit,
    swap_window_environment,
)
from reroom.hdr.synthetic import box_room
from reroom.io.images import read_exr, read_rgb8, write_rgb8
from reroom.io.mesh import read_ply, write_ply, write_triangle_ply
from reroom.render.mitsuba_env import mitsuba_info
from reroom.scan import Intrinsics, look_at, write_scan

pytestmark = pytest.mark.skipif(
    not mitsuba_info().vectorized, reason="Python emitters need a JIT Mitsuba variant"
)

SIZE = (4.0, 3.0, 2.5)
RHO = 0.4
LAMP = np.array([1.0, 1.5, 2.0])
BLOCK = (2.2, 1.5)  # centre of the 0.6 x 0.6 x 0.8 block box_room puts on the floor
W, H = 32, 24


def _labels(v: np.ndarray, n_room: int) -> np.ndarray:
    lab = np.full(len(v), 255, np.uint8)  # the block: "other" (furniture)
    room = np.arange(len(v)) < n_room
    lab[room] = 0
    lab[room & (v[:, 2] < 1e-6)] = 1
    lab[room & (v[:, 2] > SIZE[2] - 1e-6)] = 2
    return lab


@pytest.fixture(scope="module")
def scan(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("edit_ops") / "scan"
    v, f = box_room(SIZE, spacing=0.25, obstacle=True)
    n_room = len(box_room(SIZE, spacing=0.25, obstacle=False)[0])
    mesh = trimesh.Trimesh(v, f, process=False)
    intr = Intrinsics.from_fov(W, H, 70.0)
    poses = [
        look_at([0.4, 0.4, 1.6], [2.4, 1.6, 0.3]),
        look_at([3.6, 2.6, 1.8], [1.5, 1.0, 0.2]),
    ]
    grey = [np.full((H, W, 3), 128, np.uint8) for _ in poses]
    write_scan(root, mesh, intr, poses, grey)
    (root / "invert").mkdir()
    write_ply(
        root / "invert" / "albedo.ply",
        mesh,
        {"albedo": np.full((len(v), 3), RHO, np.float32)},
    )
    lamp = {
        "name": "lamp",
        "type": "point",
        "geometry": {"position": LAMP.tolist(), "axis": [0.0, 0.0, 1.0]},
        "color": [1.0, 1.0, 1.0],
        "distribution": {"basis": "inclination", "bins": 8, "profile": [1.0] * 8},
        "power": [4 * math.pi] * 3,
    }
    doc = {
        "format": "reroom-invert",
        "version": 1,
        "lights": [lamp],
        "materials": [
            {"name": n, "albedo": [RHO] * 3, "solved": True} for n in ("wall", "floor", "ceiling")
        ],
        "albedo_file": "albedo.ply",
    }
    (root / "invert" / "scene.json").write_text(json.dumps(doc))
    (root / "layout").mkdir()
    write_triangle_ply(root / "layout" / "layout_labels.ply", v, f, {"label": _labels(v, n_room)})
    walls = [
        {"index": i, "start": a, "end": b}
        for i, (a, b) in enumerate(
            [([0, 0], [4, 0]), ([4, 0], [4, 3]), ([4, 3], [0, 3]), ([0, 3], [0, 0])]
        )
    ]
    layout = {
        "format": "reroom-layout",
        "version": 1,
        "rotation": np.eye(3).tolist(),
        "rooms": [
            {
                "name": "room0",
                "polygon": [[0, 0], [4, 0], [4, 3], [0, 3]],
                "floor_z": 0.0,
                "ceiling_z": SIZE[2],
                "walls": walls,
                "openings": [],
                "baseboard": None,
            }
        ],
    }
    (root / "layout" / "layout.json").write_text(json.dumps(layout))
    (root / "hdr").mkdir()
    frames = [{"index": i, "scale": [2.0, 2.0, 2.0]} for i in range(len(poses))]
    (root / "hdr" / "exposures.json").write_text(
        json.dumps({"response": "gamma2.2", "frames": frames})
    )
    return root


def _probe(scene: dict, points: np.ndarray, normal=(0.0, 0.0, 1.0), spp: int = 4) -> np.ndarray:
    pts = np.atleast_2d(np.asarray(points, float))
    return bake_vertex_radiance(scene, pts, np.tile(normal, (len(pts), 1)), spp=spp).radiance


def _direct_on(p: np.ndarray, normal: np.ndarray, lamp: np.ndarray = LAMP, rho: float = RHO):
    """``rho / pi * I cos / d^2`` of the unit isotropic lamp at points facing ``normal``."""
    d = lamp - np.atleast_2d(p)
    r2 = (d**2).sum(1)
    return rho / math.pi * (d @ normal) / np.sqrt(r2) / r2


def _direct(p: np.ndarray, lamp: np.ndarray = LAMP, intensity: float = 1.0, rho: float = RHO):
    d = np.atleast_2d(p) - lamp
    r2 = (d**2).sum(1)
    return rho / math.pi * intensity * (-d[:, 2] / np.sqrt(r2)) / r2


FLOOR = np.array([[0.6, 0.8, 0.0], [1.2, 2.4, 0.0], [3.4, 0.6, 0.0], [3.5, 2.5, 0.0]])


# ---------------------------------------------------------------------- format
def test_parse_rejects_bad_edits_with_clear_messages(tmp_path: Path) -> None:
    with pytest.raises(EditError, match="unknown op 'paint'"):
        parse_edits([{"op": "paint"}])
    with pytest.raises(EditError, match=r"edit 1 \(repaint\): give exactly one"):
        parse_edits([{"op": "empty"}, {"op": "repaint", "target": "wall"}])
    with pytest.raises(EditError, match=r"'color' must lie in \[0.0, 1.0\]"):
        parse_edits({"op": "repaint", "target": "wall", "color": [2, 0, 0]})
    with pytest.raises(EditError, match="unknown keys \\['colour'\\]"):
        parse_edits({"op": "light", "name": "a", "colour": [1, 1, 1]})
    with pytest.raises(EditError, match="no shipped HDRI named 'mars'"):
        parse_edits({"op": "window", "name": "w", "hdri": "mars"})
    with pytest.raises(EditError, match="version 2 is not supported"):
        parse_edits({"format": "reroom-edits", "version": 2, "edits": []})
    bad = tmp_path / "broken.obj"
    bad.write_text("this is not a mesh\n")
    with pytest.raises(EditError, match=r"broken.obj: mesh file (does not load|holds no)"):
        parse_edits({"op": "insert", "object": str(bad), "position": [1, 1, 0]})
    with pytest.raises(EditError, match="no bundled object named 'piano'"):
        parse_edits({"op": "insert", "object": "piano", "position": [1, 1, 0]})
    # A mesh file: glTF is +Y up, so a box 3 m along its Y stands 3 m tall.
    from reroom.edit.furniture import placed_object

    glb = tmp_path / "tall.glb"
    glb.write_bytes(trimesh.creation.box(extents=[1.0, 3.0, 2.0]).export(file_type="glb"))
    placed = placed_object(str(glb), [1.0, 2.0, 0.5], rotation_deg=90.0)
    np.testing.assert_allclose(placed.bounds, [[0.0, 1.5, 0.5], [2.0, 2.5, 3.5]], atol=1e-9)
    ok = parse_edits(
        {
            "format": "reroom-edits",
            "version": 1,
            "edits": [{"op": "insert", "object": "chair", "position": [1, 1, 0]}],
        }
    )
    assert ok[0]["rotation_deg"] == 0.0 and ok[0]["scale"] == 1.0 and len(ok[0]["color"]) == 3


def test_names_and_placement_are_checked_against_the_room(scan: Path) -> None:
    with pytest.raises(EditError, match=r"no light named 'sun'; this room has \['lamp'\]"):
        edited_scene(scan, [{"op": "light", "name": "sun", "off": True}])
    with pytest.raises(EditError, match="no label or material cluster named 'sofa'.*'wall'"):
        edited_scene(scan, [{"op": "repaint", "target": "sofa", "color": [0.1, 0.1, 0.1]}])
    with pytest.raises(EditError, match="is a point light, not a window"):
        edited_scene(scan, [{"op": "window", "name": "lamp", "hdri": "sunset"}])
    with pytest.raises(EditError, match=r"insert 'cube0' \(cube\) at \[3.9, 1.0, 0.0\] is outside"):
        edited_scene(scan, [{"op": "insert", "object": "cube", "position": [3.9, 1.0, 0.0]}])


# ---------------------------------------------------------------------- lights
def test_light_off_scale_color_and_move(scan: Path) -> None:
    base = edited_scene(scan, [], max_depth=2)
    np.testing.assert_allclose(_probe(base, FLOOR)[:, 0], _direct(FLOOR), rtol=3e-3)
    off = edited_scene(scan, [{"op": "light", "name": "lamp", "off": True}], max_depth=2)
    assert "light_00" not in off and "light_00" in base
    edits = [
        {"op": "light", "name": "lamp", "scale": 3.0},
        {"op": "light", "name": "lamp", "color": [1.0, 0.5, 0.25]},
    ]
    scaled = edited_scene(scan, edits, max_depth=2)
    got = _probe(scaled, FLOOR)
    np.testing.assert_allclose(got, _direct(FLOOR)[:, None] * [3.0, 1.5, 0.75], rtol=3e-3)
    new = np.array([3.0, 1.0, 2.2])
    moved = edited_scene(
        scan, [{"op": "light", "name": "lamp", "move_to": new.tolist()}], max_depth=2
    )
    np.testing.assert_allclose(_probe(moved, FLOOR)[:, 0], _direct(FLOOR, new), rtol=3e-3)


def test_add_light_isotropic_and_ies(scan: Path) -> None:
    pos = [3.0, 1.0, 2.0]
    edits = [
        {"op": "light", "name": "lamp", "off": True},
        {"op": "add_light", "name": "new", "type": "point", "position": pos, "intensity": 1.0},
        {"op": "light", "name": "new", "scale": 2.0},  # later edits can name added lights
    ]
    scene = edited_scene(scan, edits, max_depth=2)
    np.testing.assert_allclose(
        _probe(scene, FLOOR)[:, 1], _direct(FLOOR, np.array(pos), 2.0), rtol=3e-3
    )
    ies = edited_scene(
        scan,
        [
            {
                "op": "add_light",
                "name": "spot",
                "position": pos,
                "intensity": 2.0,
                "ies": "ies_light_1",
            }
        ],
    )
    d = ies["added_spot"]
    # "intensity" is the profile's peak intensity.
    assert np.asarray(d["intensity"], float).max() * d["scale"] == pytest.approx(2.0, rel=1e-6)
    assert np.asarray(d["intensity"], float).min() * d["scale"] < 1.0  # a real distribution


# ---------------------------------------------------------------------- surfaces
def test_repaint_color_doubles_direct_light_on_that_label_only(scan: Path) -> None:
    base = edited_scene(scan, [], max_depth=2)
    painted = edited_scene(
        scan, [{"op": "repaint", "target": "floor", "color": [0.8, 0.8, 0.8]}], max_depth=2
    )
    wall = np.array([[3.999, 1.0, 1.0], [3.999, 2.0, 0.6]])
    ratio_floor = _probe(painted, FLOOR) / _probe(base, FLOOR)
    ratio_wall = _probe(painted, wall, (-1.0, 0.0, 0.0)) / _probe(base, wall, (-1.0, 0.0, 0.0))
    np.testing.assert_allclose(ratio_floor, 2.0, rtol=1e-3)
    np.testing.assert_allclose(ratio_wall, 1.0, rtol=1e-3)


def test_furnishings_render_with_one_albedo_per_object(scan: Path, tmp_path: Path) -> None:
    """The block (unlabelled: a furnishing) gets its seen vertices' median albedo where
    a vertex is far off it or unseen, not the room's median (reroom.edit.objects)."""
    copy = tmp_path / "scan"
    shutil.copytree(scan, copy)
    mesh = trimesh.load(copy / "invert" / "albedo.ply", process=False)
    v = np.asarray(mesh.vertices)
    n_room = len(box_room(SIZE, spacing=0.25, obstacle=False)[0])
    block = np.arange(len(v)) >= n_room
    albedo = np.full((len(v), 3), RHO, np.float32)
    albedo[block] = 0.2
    top = np.flatnonzero(block & (v[:, 2] > 0.8 - 1e-6))
    hot = top[np.argmin(np.linalg.norm(v[top, :2] - BLOCK, axis=1))]
    albedo[hot] = 0.9  # a crease vertex solved 4.5 times too bright
    side = block & (v[:, 0] < BLOCK[0] - 0.3 + 1e-6)  # the face toward the lamp, unseen
    albedo[side] = -1.0
    write_ply(copy / "invert" / "albedo.ply", mesh, {"albedo": albedo})
    scene = edited_scene(copy, [], max_depth=2, work_dir=tmp_path / "work")
    at_hot = v[hot][None, :] + [0.0, 0.0, 0.0]
    np.testing.assert_allclose(_probe(scene, at_hot)[:, 0], _direct(at_hot, rho=0.2), rtol=5e-3)
    face = np.array([[BLOCK[0] - 0.3, BLOCK[1] + 0.05, 0.5]])
    np.testing.assert_allclose(
        _probe(scene, face, (-1.0, 0.0, 0.0))[:, 0],
        _direct_on(face, np.array([-1.0, 0.0, 0.0]), rho=0.2),
        rtol=5e-3,
    )


def test_texture_repaint_follows_the_texture_mean(scan: Path, tmp_path: Path) -> None:
    tex = tmp_path / "checker.png"
    img = np.zeros((8, 8, 3), np.uint8)
    img[::2, ::2] = img[1::2, 1::2] = 255  # half white, half black: linear mean 0.5
    write_rgb8(tex, img)
    scene = edited_scene(
        scan,
        [{"op": "repaint", "target": "floor", "texture": str(tex), "metres_per_tile": 0.5}],
        max_depth=2,
    )
    assert "paint_floor" in scene
    rng = np.random.default_rng(1)
    pts = np.c_[rng.uniform(0.2, 1.8, (400, 2)), np.zeros(400)]
    got = _probe(scene, pts)[:, 0]
    want = _direct(pts, rho=1.0)
    # Each point sees black or white; on average half the light of a white floor.
    assert np.mean(got / want) == pytest.approx(0.5, abs=0.06)
    # ... and it varies across the floor with the checker (a colour would be constant).
    assert np.std(got / want) > 0.1  # bilinear texels: 0.18 here; a colour gives ~0


def test_empty_removes_the_furniture_and_keeps_the_lights(scan: Path) -> None:
    under_block = np.array([[BLOCK[0], BLOCK[1], 0.0]])
    full = edited_scene(scan, [], max_depth=2)
    empty = edited_scene(scan, [{"op": "empty"}], max_depth=2)
    assert "room" not in empty and {"room_wall", "room_floor", "room_ceiling"} <= set(empty)
    assert "light_00" in empty
    # Inside the block nothing arrives; in the empty room the floor there is lit directly.
    assert _probe(full, under_block).max() == 0.0
    np.testing.assert_allclose(_probe(empty, under_block)[:, 0], _direct(under_block), rtol=3e-3)
    # A floor point in the block's shadow (lamp -> block -> floor) gets light back.
    shadow = np.array([[2.75, 1.5, 0.0]])
    assert _probe(full, shadow).max() == 0.0
    assert _probe(empty, shadow)[0, 0] == pytest.approx(_direct(shadow)[0], rel=3e-3)


def test_the_backing_shell_shows_and_sends_light_back_through_a_hole(
    scan: Path, tmp_path: Path
) -> None:
    from reroom.edit.apply import BACKING_GAP

    # Cut a 1 x 1 m hole in the wall y = 0, where the lamp's light crosses it.
    holed = tmp_path / "holed"
    shutil.copytree(scan, holed)
    alb = read_ply(holed / "invert" / "albedo.ply")
    v, f = np.asarray(alb.vertices), np.asarray(alb.faces)
    c = v[f].mean(axis=1)
    hole = (c[:, 1] < 1e-6) & (np.abs(c[:, 0] - 3.0) < 0.5) & (np.abs(c[:, 2] - 1.25) < 0.5)
    write_triangle_ply(
        holed / "invert" / "albedo.ply", v, f[~hole], {"albedo": alb.vertex_attributes["albedo"]}
    )
    inward = np.array([0.0, 1.0, 0.0])
    in_hole = np.array([[3.0, 0.0, 1.25]])
    behind = in_hole - BACKING_GAP * inward
    on_wall = np.array([[1.0, 0.0, 1.25]])
    bare = edited_scene(holed, [], max_depth=2, backing=False)
    backed = edited_scene(holed, [], max_depth=2)
    assert not any(k.startswith("backing") for k in bare)
    assert {"backing_wall", "backing_floor", "backing_ceiling"} <= set(backed)
    # Without the backing there is nothing behind the hole; with it, a wall lit by the lamp.
    with pytest.warns(UserWarning, match="no surface within"):
        assert _probe(bare, behind, inward).max() == 0.0
    np.testing.assert_allclose(
        _probe(backed, behind, inward)[:, 0], _direct_on(behind, inward), rtol=3e-3
    )
    # Where the scan has its wall, the backing is hidden behind it.
    np.testing.assert_allclose(
        _probe(backed, on_wall, inward), _probe(bare, on_wall, inward), rtol=1e-5
    )
    # A repaint of the walls repaints the backing; the empty room has none.
    red = [0.8, 0.1, 0.1]
    painted = edited_scene(holed, [{"op": "repaint", "target": "wall", "color": red}], max_depth=2)
    np.testing.assert_allclose(
        _probe(painted, behind, inward)[0],
        _direct_on(behind, inward, rho=1.0)[0] * np.array(red),
        rtol=3e-3,
    )
    empty = edited_scene(holed, [{"op": "empty"}], max_depth=2)
    assert not any(k.startswith("backing") for k in empty)
    # A layout wall fitted 5 cm in front of the scanned one: the shell goes behind the
    # scan's wall (1 cm past it), not in front of it where it would block the lamp.
    layout = json.loads((holed / "layout" / "layout.json").read_text())
    layout["rooms"][0]["polygon"] = [[0, 0.05], [4, 0.05], [4, 3], [0, 3]]
    (holed / "layout" / "layout.json").write_text(json.dumps(layout))
    moved = edited_scene(holed, [], max_depth=2)
    np.testing.assert_allclose(
        _probe(moved, on_wall, inward), _probe(bare, on_wall, inward), rtol=1e-5
    )
    shell_y = read_ply(moved["backing_wall"]["filename"]).vertices[:, 1]
    assert shell_y.min() == pytest.approx(-0.01, abs=1e-6)
    # A hand-edited layout whose room is not a polygon: the scan renders without the shell.
    layout["rooms"][0]["polygon"] = "four corners"
    (holed / "layout" / "layout.json").write_text(json.dumps(layout))
    with pytest.warns(UserWarning, match=r"layout.json: room 'room0' does not make a shell"):
        broken = edited_scene(holed, [], max_depth=2)
    assert "room" in broken and not any(k.startswith("backing") for k in broken)
    layout["rooms"][0]["polygon"] = [[0, 0], [4, 0], [4, 3], [0, 3]]
    # A room whose ceiling was estimated (never seen) is a bound, not a surface: no backing.
    layout["rooms"][0]["ceiling"] = "estimated"
    (holed / "layout" / "layout.json").write_text(json.dumps(layout))
    assert not any(k.startswith("backing") for k in edited_scene(holed, [], max_depth=2))


def test_a_window_s_reveals_take_the_scanned_reveals_albedo_not_the_walls(
    scan: Path, tmp_path: Path
) -> None:
    # A 1 x 0.8 m window in the wall y = 0 (15 cm reveal), whose scanned reveal vertices
    # (here: the wall vertices inside the opening's span) were measured whiter than the
    # walls, as the true room's reveals are.
    room = tmp_path / "windowed"
    shutil.copytree(scan, room)
    layout = json.loads((room / "layout" / "layout.json").read_text())
    opening = {"kind": "window", "wall": 0, "s0": 1.5, "s1": 2.5, "z0": 1.0, "z1": 1.8}
    layout["rooms"][0]["openings"] = [{**opening, "depth": 0.15}]
    (room / "layout" / "layout.json").write_text(json.dumps(layout))
    labelled = read_ply(room / "layout" / "layout_labels.ply")
    v, f = np.asarray(labelled.vertices), np.asarray(labelled.faces)
    lab = np.asarray(labelled.vertex_attributes["label"]).copy()
    reveal = (lab == 0) & (v[:, 1] < 1e-6) & (np.abs(v[:, 0] - 2.0) <= 0.5)
    reveal &= (v[:, 2] >= 1.0) & (v[:, 2] <= 1.8)
    assert reveal.sum() >= 3
    lab[reveal] = 4
    write_triangle_ply(room / "layout" / "layout_labels.ply", v, f, {"label": lab})
    alb = read_ply(room / "invert" / "albedo.ply")
    albedo = np.asarray(alb.vertex_attributes["albedo"]).copy()
    albedo[reveal] = [0.8, 0.8, 0.78]
    write_triangle_ply(room / "invert" / "albedo.ply", v, f, {"albedo": albedo})

    def reveal_albedo(scene: dict, key: str) -> list[float]:
        return scene[key]["bsdf"]["bsdf"]["reflectance"]["value"]

    # The empty room's reveals and the shell's behind the scan: the scanned reveals'.
    empty = edited_scene(room, [{"op": "empty"}], max_depth=2)
    np.testing.assert_allclose(reveal_albedo(empty, "room_window"), [0.8, 0.8, 0.78], rtol=1e-6)
    backed = edited_scene(room, [], max_depth=2)
    np.testing.assert_allclose(reveal_albedo(backed, "backing_window"), [0.8, 0.8, 0.78], rtol=1e-6)
    # The scan's own reveal faces give way to the shell's; the rest of the scan stays.
    kept = np.asarray(read_ply(backed["room"]["filename"]).faces)
    on_reveal = reveal[f].all(axis=1)
    assert on_reveal.any() and not reveal[kept].all(axis=1).any()
    assert len(kept) == len(f) - on_reveal.sum()
    # Without the shell behind it the scan keeps them (no hole where nothing fills it).
    bare = edited_scene(room, [], max_depth=2, backing=False)
    assert len(read_ply(bare["room"]["filename"]).faces) == len(f)
    # A hand-edited opening that is no rectangle: a warning, no shell, the scan whole.
    layout["rooms"][0]["openings"] = [{**opening, "s1": "2.5 m", "depth": 0.15}]
    (room / "layout" / "layout.json").write_text(json.dumps(layout))
    with pytest.warns(UserWarning, match=r"layout.json: room .* does not make a shell"):
        broken = edited_scene(room, [], max_depth=2)
    assert len(read_ply(broken["room"]["filename"]).faces) == len(f)
    layout["rooms"][0]["openings"] = [{**opening, "depth": 0.15}]
    (room / "layout" / "layout.json").write_text(json.dumps(layout))
    # A repaint of the walls leaves them, as it leaves the scan's reveal vertices.
    red = [0.8, 0.1, 0.1]
    painted = edited_scene(room, [{"op": "repaint", "target": "wall", "color": red}], max_depth=2)
    assert reveal_albedo(painted, "backing_wall") == red
    np.testing.assert_allclose(
        reveal_albedo(painted, "backing_window"), [0.8, 0.8, 0.78], rtol=1e-6
    )
    # A scan that saw no reveal: they take the wall's solved albedo.
    lab[reveal] = 0
    write_triangle_ply(room / "layout" / "layout_labels.ply", v, f, {"label": lab})
    unseen = edited_scene(room, [{"op": "empty"}], max_depth=2)
    np.testing.assert_allclose(reveal_albedo(unseen, "room_window"), [RHO] * 3, rtol=1e-6)


def test_insert_casts_a_shadow(scan: Path) -> None:
    p = np.array([[1.7, 1.5, 0.0]])  # the lamp -> p segment is 0.43 m high at x = 1.55
    base = edited_scene(scan, [], max_depth=2)
    assert _probe(base, p)[0, 0] == pytest.approx(_direct(p)[0], rel=3e-3)
    with_cube = edited_scene(
        scan,
        [{"op": "insert", "object": "cube", "position": [1.3, 1.5, 0.0]}],  # 0.5 m cube
        max_depth=2,
    )
    assert any(k.startswith("insert_") for k in with_cube)
    assert _probe(with_cube, p).max() == 0.0
    # Far from the cube the floor is unchanged.
    far = np.array([[3.5, 2.5, 0.0]])
    assert _probe(with_cube, far)[0, 0] == pytest.approx(_probe(base, far)[0, 0], rel=1e-6)


def test_window_swap_scales_into_model_units() -> None:
    from reroom.edit.apply import environment_cells
    from reroom.invert.basis import CubemapBasis

    basis = CubemapBasis(4)
    courtyard = environment_cells("courtyard", basis)
    sunset = environment_cells("sunset", basis)
    # The "recovered" window: the courtyard in model units (per channel 0.3, 0.25, 0.2),
    # with the cells the window cannot see (entering the room, d . n > 0) left at 0.
    normal = np.array([0.0, 1.0, 0.0])
    outward = (basis.cell_directions() @ normal) < 0
    rec = courtyard * [0.3, 0.25, 0.2] * outward[:, None]
    light = {
        "name": "w",
        "type": "window",
        "geometry": {"normal": normal.tolist()},
        "distribution": {"basis": "cubemap", "n": 4, "cells": rec.tolist()},
    }
    cells, factor = swap_window_environment(light, "sunset", was="courtyard")
    # Cells straddling the window plane are partly seen: within a few per cent.
    np.testing.assert_allclose(factor, [0.3, 0.25, 0.2], rtol=0.05)
    np.testing.assert_allclose(cells, sunset * factor, rtol=1e-9)
    cells2, factor2 = swap_window_environment(light, "sunset", was="courtyard", scale=2.0)
    np.testing.assert_allclose(factor2, 2 * factor, rtol=1e-9)
    # Without `was`: one factor for all channels (the sunset keeps its colour).
    _, f3 = swap_window_environment(light, "sunset")
    assert f3[0] == f3[1] == f3[2] > 0
    with pytest.raises(Exception, match="no cube-map distribution"):
        swap_window_environment({**light, "distribution": {"basis": "sh"}}, "sunset")
    # A recovered sun (reroom.invert.sun) is part of the window's light: the swap counts
    # it, spread over its cell, as it would count the same sun left in the cells.
    from reroom.invert.sun import fold_sun_into_cells

    sun = {"direction": [0.3, -0.6, 0.74], "irradiance": [0.5, 0.4, 0.3]}
    folded = {**light, "distribution": {**light["distribution"]}}
    folded["distribution"]["cells"] = fold_sun_into_cells(
        rec, basis, sun["direction"], sun["irradiance"]
    ).tolist()
    _, f_sun = swap_window_environment({**light, "sun": sun}, "sunset")
    _, f_folded = swap_window_environment(folded, "sunset")
    np.testing.assert_allclose(f_sun, f_folded, rtol=1e-12)
    assert f_sun[0] > f3[0]
    # The level is the ratio of the light entering (the window's power), so one bright
    # cell solved at half its value moves it by that cell's share of the flux only; and
    # the solve's cells set it, not a render window's finer ones.
    leaving = -normal  # the way a ray leaves the room through the window
    d = basis.cell_directions()
    j = int(np.argmax(rec @ [0.2126, 0.7152, 0.0722]))
    off = rec.copy()
    off[j] *= 0.5
    _, f_off = swap_window_environment(
        {**light, "distribution": {**light["distribution"], "cells": off.tolist()}},
        "sunset",
        was="courtyard",
    )
    assert np.all(f_off < factor) and np.all(f_off > 0.8 * factor)
    refit = {
        **light,
        "render_distribution": {"basis": "cubemap", "n": 8, "cells": [[9.0] * 3] * 384},
    }
    _, f_refit = swap_window_environment(refit, "sunset", was="courtyard")
    np.testing.assert_allclose(f_refit, factor, rtol=1e-12)
    assert leaving @ d[j] > 0  # the bright cell is one the window shows


def test_window_swap_shows_the_new_sky_at_full_resolution(scan: Path, tmp_path: Path) -> None:
    """The swapped window shows the whole HDRI (a sharp sun), scaled into model units."""
    from reroom.data import hdri_path
    from reroom.render.emitters import load_hdri

    room = _scan_with_window(scan, tmp_path)
    window = json.loads((room / "invert" / "scene.json").read_text())["lights"][-1]
    base = edited_scene(room, [], max_depth=2)
    swapped = edited_scene(room, [{"op": "window", "name": "w", "hdri": "sunrise"}], max_depth=2)
    key = next(
        k
        for k, v in base.items()
        if isinstance(v, dict) and "emitter" in v and v["emitter"]["type"] == "reroom_portal"
    )
    before = np.array(base[key]["emitter"]["data"])
    after = np.array(swapped[key]["emitter"]["data"])
    assert before.shape == (8, 16, 3)
    _, factor = swap_window_environment(window, "sunrise")
    np.testing.assert_allclose(after, load_hdri(hdri_path("sunrise")) * factor, rtol=1e-5)
    # The opening goes with it, so the sun is found by the sky strategy.
    emitter = swapped[key]["emitter"]
    np.testing.assert_allclose(emitter["outward"], [0.0, -1.0, 0.0])
    np.testing.assert_allclose(emitter["opening_centre"], [2.0, 0.0, 1.4])


# ---------------------------------------------------------------------- renders
def test_render_edit_writes_exr_png_and_json(scan: Path, tmp_path: Path) -> None:
    from reroom.edit.render_edits import encode_response
    from reroom.hdr.linearize import response_lut

    cam = {
        "transform_matrix": look_at([2.0, 0.3, 1.2], [2.0, 2.5, 0.8]).tolist(),
        "name": "front",
        "w": 16,
        "h": 12,
        "fl_x": 14.0,
        "fl_y": 14.0,
        "cx": 8.0,
        "cy": 6.0,
    }
    edits = [{"op": "light", "name": "lamp", "scale": 2.0}]
    doc = render_edit(scan, edits, tmp_path / "r", frames=[1], cameras=[cam], spp=4, name="x")
    assert [v["view"] for v in doc["views"]] == ["f00001", "front"]
    assert json.loads((tmp_path / "r" / "x.json").read_text()) == doc
    exr = read_exr(tmp_path / "r" / "x_f00001.exr")
    png = read_rgb8(tmp_path / "r" / "x_f00001.png")
    assert exr.shape == (H, W, 3) and read_exr(tmp_path / "r" / "x_front.exr").shape == (12, 16, 3)
    lut = response_lut("gamma2.2")
    # PNG = the frame's exposure (2) x radiance through the response.
    np.testing.assert_array_equal(png, encode_response(exr * 2.0, lut))
    assert np.abs(lut[png] - np.clip(exr * 2.0, 0, 1)).max() < 0.01
    # Light scaled x2: the EXR doubles (same seed, same paths).
    base = render_edit(scan, [], tmp_path / "b", frames=[1], spp=4, name="x")
    assert base["views"][0]["exposure"] == [2.0, 2.0, 2.0]
    np.testing.assert_allclose(
        exr, 2 * read_exr(tmp_path / "b" / "x_f00001.exr"), rtol=1e-4, atol=1e-7
    )


def test_composite_keeps_the_photo_where_nothing_changes(scan: Path, tmp_path: Path) -> None:
    from reroom.edit.render_edits import encode_response, object_mask
    from reroom.hdr.linearize import response_lut
    from reroom.scan import load_scan

    # Direct light only: the cube changes exactly the pixels it covers or shades.
    edits = [
        {"op": "insert", "object": "cube", "position": [2.2, 0.6, 0.0], "color": [0.9, 0.1, 0.1]}
    ]
    doc = composite_insertion(scan, edits, 0, tmp_path, spp=4, max_depth=2)
    photo = read_rgb8(scan / "images" / "frame_00000.png")
    comp = read_rgb8(tmp_path / doc["png"])
    fr = load_scan(scan, check_images=False).frames[0]
    scene = edited_scene(scan, edits, max_depth=2)
    mask = object_mask(scene, fr.c2w, fr.intrinsics)
    assert 0 < doc["object_pixels"] < W * H and doc["changed_pixels"] < W * H
    untouched = mask == 0
    assert (comp[untouched] == photo[untouched]).mean() > 0.5
    # Where the photo is kept, it is kept exactly (grey 128) or darkened by the shadow.
    assert np.all(comp[untouched].astype(int) <= 128)
    # Object pixels come from the render: red.
    inside = mask == 1
    assert inside.any() and np.all(comp[inside][:, 0] > comp[inside][:, 1])
    lut = response_lut("gamma2.2")
    assert encode_response(lut[photo], lut).tolist() == photo.tolist()


def test_default_edit_sets_are_valid_for_the_room(scan: Path) -> None:
    sets = default_edit_sets(scan)
    assert set(sets) == {"empty", "repaint_walls", "light_off", "light_moved", "insert_chair"}
    assert sets["light_off"][0]["name"] == "lamp"
    moved = np.asarray(sets["light_moved"][0]["move_to"])
    assert np.linalg.norm(moved - LAMP) == pytest.approx(1.0)
    assert moved[0] - LAMP[0] == pytest.approx(1.0)  # the room's longer axis is x
    wall = np.asarray(sets["repaint_walls"][0]["color"])
    assert np.linalg.norm(wall - RHO) > 0.25
    chair = np.asarray(sets["insert_chair"][0]["position"])
    assert 0.3 < chair[0] < 3.7 and 0.3 < chair[1] < 2.7 and chair[2] == 0.0
    # Not on the block.
    assert max(abs(chair[0] - BLOCK[0]), abs(chair[1] - BLOCK[1])) > 0.3 + 0.22
    for ops in sets.values():
        edited_scene(scan, ops)  # every set applies without error


def test_cli_edit_renders_and_reports_errors(scan: Path, tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from reroom.cli import app

    runner = CliRunner()
    out = tmp_path / "cli"
    res = runner.invoke(
        app,
        [
            "edit",
            str(scan),
            "--op",
            "scale:lamp=0.5",
            "--frames",
            "0",
            "--spp",
            "4",
            "-o",
            str(out),
        ],
    )
    assert res.exit_code == 0, res.output
    assert (out / "edit_f00000.png").is_file() and (out / "edit.json").is_file()
    bad = runner.invoke(app, ["edit", str(scan), "--op", "off:sun", "--frames", "0"])
    assert bad.exit_code == 1 and "no light named 'sun'" in bad.output


def test_a_moved_light_takes_its_fitting_along(scan: Path, tmp_path: Path) -> None:
    # A second model of the same room whose bulb hangs 0.2 m above the block: the block
    # (unlabelled, small, next to the light) is then the bulb's fitting.
    inv = tmp_path / "invert"
    inv.mkdir()
    doc = json.loads((scan / "invert" / "scene.json").read_text())
    bulb = json.loads(json.dumps(doc["lights"][0]))
    bulb["name"], bulb["geometry"]["position"] = "bulb", [BLOCK[0], BLOCK[1], 1.0]
    doc["lights"].append(bulb)
    doc["albedo_file"] = str(scan / "invert" / "albedo.ply")
    (inv / "scene.json").write_text(json.dumps(doc))
    edits = [
        {"op": "light", "name": "bulb", "off": True, "move_to": [BLOCK[0] + 1.0, BLOCK[1], 1.0]}
    ]
    scene = edited_scene(scan, edits, invert_dir=inv, max_depth=2)
    assert "light_01_fixture" in scene and "light_01" not in scene
    old, new = np.array([[BLOCK[0], BLOCK[1], 0.0]]), np.array([[BLOCK[0] + 1.0, BLOCK[1], 0.0]])
    # The floor where the block stood is lit by the lamp; where it went, it is covered.
    assert _probe(scene, old)[0, 0] == pytest.approx(_direct(old)[0], rel=3e-3)
    assert _probe(scene, new).max() == 0.0


def test_glowing_fitting_does_not_block_its_line_light(tmp_path: Path) -> None:
    # A tube mesh (radius 2 cm) around a line light: flagged as the light's glowing
    # fitting (``light`` = 1 in albedo.ply) it is left out, otherwise it encloses the line.
    v, f = box_room(SIZE, spacing=0.25, obstacle=False)
    tube = trimesh.creation.cylinder(radius=0.02, segment=[[1.5, 1.5, 2.2], [2.5, 1.5, 2.2]])
    verts = np.vstack([v, tube.vertices])
    faces = np.vstack([f, tube.faces + len(v)])
    line = {
        "name": "tube",
        "type": "line",
        "geometry": {"p0": [1.5, 1.5, 2.2], "p1": [2.5, 1.5, 2.2], "d_perp": [0.0, 0.0, 1.0]},
        "color": [1.0, 1.0, 1.0],
        "distribution": {"basis": "inclination", "bins": 4, "profile": [1.0] * 4},
    }
    floor = np.array([[2.0, 1.0, 0.0], [1.2, 2.0, 0.0]])
    got = []
    for flag in (1, 0):
        scan = tmp_path / f"s{flag}"
        (scan / "invert").mkdir(parents=True)
        write_ply(
            scan / "invert" / "albedo.ply",
            trimesh.Trimesh(verts, faces, process=False),
            {
                "albedo": np.full((len(verts), 3), RHO, np.float32),
                "light": (np.arange(len(verts)) >= len(v)).astype(np.uint8) * flag,
            },
        )
        doc = {"format": "reroom-invert", "version": 1, "lights": [line]}
        (scan / "invert" / "scene.json").write_text(json.dumps(doc))
        got.append(_probe(edited_scene(scan, [], max_depth=2), floor)[:, 0])
    assert np.all(got[0] > 0)  # the line lights the floor
    assert np.all(got[1] == 0)  # an unflagged tube around it would block all of it


def _open_cylinder(centre, radius: float, height: float, inward: bool) -> trimesh.Trimesh:
    """The side of a cylinder about +z, its faces turned out (or in, for a lining)."""
    a = np.linspace(0.0, 2 * np.pi, 24, endpoint=False)
    ring = np.stack([radius * np.cos(a), radius * np.sin(a), np.zeros_like(a)], 1)
    v = np.vstack([ring, ring + [0.0, 0.0, height]]) + np.asarray(centre, float)
    i = np.arange(24)
    j = (i + 1) % 24
    faces = np.vstack([np.stack([i, j, j + 24], 1), np.stack([i, j + 24, i + 24], 1)])
    return trimesh.Trimesh(v, faces[:, ::-1] if inward else faces, process=False)


def test_a_shade_is_black_inside_and_keeps_its_albedo_outside(tmp_path: Path) -> None:
    # A lamp shade around a point light, its outside (normals out) and lining (normals
    # in) separate as in a scan: the lining faces the bulb, whose light on it is in the
    # solved profile already, so it renders black; the outside never sees the bulb and
    # keeps its albedo, lit by the room like any surface.
    v, f = box_room(SIZE, spacing=0.25, obstacle=False)
    bulb = np.array([2.0, 1.5, 1.5])
    outside = _open_cylinder(bulb - [0, 0, 0.12], 0.15, 0.24, inward=False)
    lining = _open_cylinder(bulb - [0, 0, 0.12], 0.145, 0.24, inward=True)
    mesh = trimesh.util.concatenate([trimesh.Trimesh(v, f, process=False), outside, lining])
    scan = tmp_path / "s"
    (scan / "invert").mkdir(parents=True)
    write_ply(
        scan / "invert" / "albedo.ply",
        mesh,
        {"albedo": np.full((len(mesh.vertices), 3), RHO, np.float32)},
    )
    lamp = {
        "name": "lamp",
        "type": "point",
        "geometry": {"position": bulb.tolist(), "axis": [0.0, 0.0, 1.0]},
        "color": [1.0, 1.0, 1.0],
        "distribution": {"basis": "inclination", "bins": 4, "profile": [1.0] * 4},
    }
    doc = {"format": "reroom-invert", "version": 1, "lights": [lamp]}
    (scan / "invert" / "scene.json").write_text(json.dumps(doc))
    edited_scene(scan, [], max_depth=2, work_dir=tmp_path / "work")
    (written,) = (tmp_path / "work").glob("*/albedo.ply")
    albedo = np.asarray(read_ply(written).vertex_attributes["albedo"])
    n_room, n_out = len(v), len(outside.vertices)
    np.testing.assert_allclose(albedo[:n_room], RHO, rtol=1e-6)  # the room
    np.testing.assert_allclose(albedo[n_room : n_room + n_out], RHO, rtol=1e-6)  # outside
    assert np.all(albedo[n_room + n_out :] == 0.0)  # the lining


def test_line_light_with_phi_bins_off_scale_color_and_move(scan: Path, tmp_path: Path) -> None:
    # A tube whose profile depends on phi (scene.json's (theta, phi) layout): dimming,
    # recolouring and moving it act on the whole emitter, off removes it.
    inv = tmp_path / "invert"
    inv.mkdir()
    doc = json.loads((scan / "invert" / "scene.json").read_text())
    grid = np.outer([0.0, 0.0, 1.0, 2.0, 3.0, 4.0], [1.0, 0.5, 0.2])
    doc["lights"] = [
        {
            "name": "tube",
            "type": "line",
            "geometry": {"p0": [0.8, 2.0, 2.2], "p1": [1.8, 2.0, 2.2], "d_perp": [0, 0, 1.0]},
            "color": [1.0, 1.0, 1.0],
            "distribution": {"basis": "line", "bins": 6, "phi_bins": 3, "profile": grid.tolist()},
            "power": [1.0] * 3,
        }
    ]
    doc["albedo_file"] = str(scan / "invert" / "albedo.ply")
    (inv / "scene.json").write_text(json.dumps(doc))
    pts = np.array([[1.5, 2.6, 0.0], [2.0, 2.8, 0.0], [3.0, 1.0, 0.0]])  # clear of the block

    def probe(edits):
        return _probe(edited_scene(scan, edits, invert_dir=inv, max_depth=2), pts, spp=16)

    base = probe([])
    assert np.all(base > 0)
    got = probe(
        [
            {"op": "light", "name": "tube", "scale": 3.0},
            {"op": "light", "name": "tube", "color": [1.0, 0.5, 0.25]},
        ]
    )
    np.testing.assert_allclose(got, base * [3.0, 1.5, 0.75], rtol=1e-5)
    assert probe([{"op": "light", "name": "tube", "off": True}]).max() == 0.0
    # Moved 1 m along +x (same direction): the floor 1 m further along sees what it saw.
    moved = probe([{"op": "light", "name": "tube", "move_to": [2.3, 2.0, 2.2]}])
    shifted = _probe(
        edited_scene(scan, [], invert_dir=inv, max_depth=2), pts - [1.0, 0.0, 0.0], spp=16
    )
    np.testing.assert_allclose(moved[:2], shifted[:2], rtol=0.02)


def test_photo_textures_render_on_the_scan_and_as_pattern_in_the_empty_room(
    scan: Path, tmp_path: Path
) -> None:
    import shutil

    from reroom.invert.textures import SurfaceTexture, write_textures

    room = tmp_path / "scan"
    shutil.copytree(scan, room)
    # The floor's texture: albedo 0.2 for x < 2, 0.8 beyond (10 cm texels); its detail
    # (the pattern the empty room shows) 0.5 for y < 1.5, 1.5 beyond.
    albedo = np.full((30, 40, 3), 0.2, np.float32)
    albedo[:, 20:] = 0.8
    detail = np.full((30, 40, 3), 0.5, np.float32)
    detail[15:] = 1.5
    tex = SurfaceTexture(
        label="floor",
        axis=2,
        offset=0.0,
        origin=(0.0, 0.0),
        texel=0.1,
        albedo=albedo,
        detail=detail,
        count=np.ones((30, 40), np.int64),
        rotation=np.eye(3),
        name="floor_0",
    )
    doc = json.loads((room / "invert" / "scene.json").read_text())
    doc["textures"] = write_textures([tex], room / "invert")
    (room / "invert" / "scene.json").write_text(json.dumps(doc))
    left = np.array([[0.6, 0.8, 0.0], [1.2, 2.4, 0.0]])
    right = np.array([[3.4, 0.6, 0.0], [3.5, 2.5, 0.0]])
    wall = np.array([[3.999, 1.0, 1.0]])

    scene = edited_scene(room, [], max_depth=2)
    assert "texture_floor_0" in scene
    np.testing.assert_allclose(_probe(scene, left)[:, 0], _direct(left, rho=0.2), rtol=3e-3)
    np.testing.assert_allclose(_probe(scene, right)[:, 0], _direct(right, rho=0.8), rtol=3e-3)
    wall_base = _probe(edited_scene(scan, [], max_depth=2), wall, (-1.0, 0.0, 0.0))
    np.testing.assert_allclose(_probe(scene, wall, (-1.0, 0.0, 0.0)), wall_base, rtol=1e-3)
    # The shell behind the scan shows the textured plane at its mean albedo, no image.
    below = np.array([[1.0, 1.0, -0.02], [3.0, 2.0, -0.02]])
    assert scene["backing_texture_floor_0"]["bsdf"]["bsdf"]["reflectance"]["value"] == [0.5] * 3
    np.testing.assert_array_equal(_probe(scene, below), 0.0)  # under the scan's floor: dark
    # The empty room: the detail at the plane's mean albedo (0.5).
    empty = edited_scene(room, [{"op": "empty"}], max_depth=2)
    assert "room_texture_floor_0" in empty and "room_floor" not in empty
    got = _probe(empty, np.r_[left, right])[:, 0]
    want = _direct(np.r_[left, right], rho=1.0) * 0.5 * np.r_[0.5, 1.5, 0.5, 1.5]
    np.testing.assert_allclose(got, want, rtol=3e-3)
    # A repainted floor drops its texture.
    painted = edited_scene(
        room, [{"op": "repaint", "target": "floor", "color": [0.5, 0.5, 0.5]}], max_depth=2
    )
    assert "texture_floor_0" not in painted
    np.testing.assert_allclose(_probe(painted, right)[:, 0], _direct(right, rho=0.5), rtol=3e-3)


def _scan_with_window(scan: Path, tmp_path: Path) -> Path:
    """A copy of ``scan`` whose model has a window ``w`` (cells and map at 0.2)."""
    import shutil

    from reroom.io.images import write_exr

    room = tmp_path / "scan"
    shutil.copytree(scan, room)
    doc = json.loads((room / "invert" / "scene.json").read_text())
    window = {
        "name": "w",
        "type": "window",
        "geometry": {
            "centre": [2.0, 0.0, 1.4],
            "half_u": [0.5, 0.0, 0.0],
            "half_v": [0.0, 0.0, 0.4],
            "normal": [0.0, 1.0, 0.0],
        },
        "distribution": {"basis": "cubemap", "n": 4, "cells": np.full((96, 3), 0.2).tolist()},
        "environment_exr": "window_w.exr",
    }
    write_exr(room / "invert" / "window_w.exr", np.full((8, 16, 3), 0.2, np.float32))
    doc["lights"].append(window)
    (room / "invert" / "scene.json").write_text(json.dumps(doc))
    return room


def test_a_window_shows_its_view_unless_its_sky_is_swapped(scan: Path, tmp_path: Path) -> None:
    """The recovered window's ``view_exr`` goes to the camera; a new sky replaces both;
    a dimmed window dims both."""
    from reroom.io.images import write_exr

    room = _scan_with_window(scan, tmp_path)
    write_exr(room / "invert" / "window_w_view.exr", np.full((16, 32, 3), 0.7, np.float32))
    doc = json.loads((room / "invert" / "scene.json").read_text())
    doc["lights"][-1]["view_exr"] = "window_w_view.exr"
    (room / "invert" / "scene.json").write_text(json.dumps(doc))

    def portal(scene: dict) -> dict:
        return next(
            v["emitter"]
            for v in scene.values()
            if isinstance(v, dict) and "emitter" in v and v["emitter"]["type"] == "reroom_portal"
        )

    base = portal(edited_scene(room, [], max_depth=2))
    np.testing.assert_allclose(np.array(base["view_data"]), 0.7)
    np.testing.assert_allclose(np.array(base["data"]), 0.2)
    dimmed = portal(edited_scene(room, [{"op": "light", "name": "w", "scale": 0.5}], max_depth=2))
    np.testing.assert_allclose(np.array(dimmed["view_data"]), 0.35, rtol=1e-6)
    swapped = portal(
        edited_scene(room, [{"op": "window", "name": "w", "hdri": "sunrise"}], max_depth=2)
    )
    assert "view_data" not in swapped
    # A view file named but missing: a warning naming it, and the light map alone.
    (room / "invert" / "window_w_view.exr").unlink()
    with pytest.warns(UserWarning, match="window_w_view.exr is missing"):
        plain = portal(edited_scene(room, [], max_depth=2))
    assert "view_data" not in plain
