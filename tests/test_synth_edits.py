"""Edits applied to the synthetic truth (reroom.synth.edits): each op, and tiny renders."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from reroom.edit.edits import EditError
from reroom.errors import ScanError
from reroom.scan import Intrinsics, look_at
from reroom.synth.edits import _read_piece, apply_edits, fixture_parts, light_centre, render_scene
from reroom.synth.presets import build_preset
from reroom.synth.scene import write_scene

LAYOUT = {"rooms": [{"polygon": [[0, 0], [6, 0], [6, 4.5], [0, 4.5]]}]}


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The furnished preset with coarse meshes and short paths (fast to write and render)."""
    d = tmp_path_factory.mktemp("truth") / "scene"
    write_scene(build_preset("furnished", mesh_spacing=0.5), d, max_depth=6, rr_depth=3)
    return d


def _digest(folder: Path) -> str:
    h = hashlib.sha1()
    for f in sorted(folder.rglob("*")):
        if f.is_file():
            h.update(f.relative_to(folder).as_posix().encode())
            h.update(f.read_bytes())
    return h.hexdigest()


def _edit(scene_dir: Path, tmp_path: Path, ops: list, **kw) -> tuple[dict, Path]:
    out = tmp_path / "edited"
    return apply_edits(scene_dir, ops, out, layout=LAYOUT, **kw), out


def _part(desc: dict, name: str) -> dict:
    return next(p for p in desc["parts"] if p["name"] == name)


def _light(desc: dict, name: str) -> dict:
    return next(light for light in desc["lights"] if light["name"] == name)


def test_empty_drops_furniture_keeps_fittings_and_the_original(
    scene_dir: Path, tmp_path: Path
) -> None:
    before = _digest(scene_dir)
    desc, out = _edit(scene_dir, tmp_path, [{"op": "empty"}])
    names = {p["name"] for p in desc["parts"]}
    assert not names & {"table", "sofa", "chair0", "chair1", "cabinet"}
    # The lamp's shade and the tube's baffles are labelled furniture but are fittings.
    assert {"floor_lamp_shade", "floor_lamp_pole", "tube_baffles", "ceiling_panel"} <= names
    assert {p["label"] for p in desc["parts"]} >= {"wall", "floor", "ceiling", "light"}
    assert all(light.get("on", True) for light in desc["lights"])
    assert (out / "scene.json").is_file() and json.loads((out / "scene.json").read_text())
    assert desc["edits"] == [{"op": "empty"}]
    desc2 = apply_edits(
        scene_dir, [{"op": "empty"}], tmp_path / "bare", layout=LAYOUT, keep_fixtures=False
    )
    assert not any(p["label"] == "furniture" for p in desc2["parts"])
    assert _digest(scene_dir) == before  # the scan's truth is never written


def test_repaint_by_label_color_and_texture(scene_dir: Path, tmp_path: Path) -> None:
    from PIL import Image

    from reroom.io.images import read_exr

    desc, _ = _edit(
        scene_dir, tmp_path, [{"op": "repaint", "target": "wall", "color": [0.1, 0.5, 0.2]}]
    )
    walls = [p for p in desc["parts"] if p["label"] == "wall"]
    assert len(walls) == 4
    assert all(p["material"] == {"type": "diffuse", "albedo": [0.1, 0.5, 0.2]} for p in walls)
    assert _part(desc, "room/ceiling")["material"]["albedo"] == [0.82, 0.82, 0.8]

    png = tmp_path / "paint.png"
    Image.fromarray(np.full((4, 4, 3), [128, 64, 255], np.uint8)).save(png)
    desc, out = _edit(
        scene_dir,
        tmp_path,
        [{"op": "repaint", "target": "floor", "texture": str(png), "metres_per_tile": 0.5}],
    )
    mat = _part(desc, "room/floor")["material"]
    tex = desc["textures"][mat["texture"]]
    assert tex["metres_per_tile"] == 0.5
    img = read_exr(out / tex["file"])[..., :3]
    # sRGB 128 / 64 / 255 decoded to linear albedo.
    np.testing.assert_allclose(img[0, 0], [0.2158605, 0.0512695, 1.0], atol=1e-5)
    np.testing.assert_allclose(mat["albedo"], img[0, 0], atol=1e-5)


def test_light_off_scale_and_color(scene_dir: Path, tmp_path: Path) -> None:
    from reroom.synth.lighting import normalized_color

    ops = [
        {"op": "light", "name": "ceiling_panel", "off": True},
        {"op": "light", "name": "tube", "scale": 0.5},
        {"op": "light", "name": "floor_lamp", "color": [1.0, 0.5, 0.25], "scale": 2.0},
        {"op": "light", "name": "window0", "scale": 3.0},
    ]
    desc, _ = _edit(scene_dir, tmp_path, ops)
    assert _light(desc, "ceiling_panel")["on"] is False
    assert _light(desc, "tube")["radiance"] == [6.0, 6.25, 6.5]
    assert _part(desc, "tube")["emission"] == [6.0, 6.25, 6.5]
    assert _light(desc, "window0")["scale"] == 3.0
    # A point light's rendered RGB intensity is power * color / mean(color): scaled by
    # 2 and multiplied channel-wise by the colour.
    old = _light(json.loads((scene_dir / "scene.json").read_text()), "floor_lamp")
    new = _light(desc, "floor_lamp")
    before = old["power"] * normalized_color(old["color"])
    after = new["power"] * normalized_color(new["color"])
    np.testing.assert_allclose(after, before * 2.0 * np.array([1.0, 0.5, 0.25]))


def test_window_color_tints_a_copy_of_the_hdri(scene_dir: Path, tmp_path: Path) -> None:
    from reroom.io.images import read_exr

    desc, out = _edit(
        scene_dir, tmp_path, [{"op": "light", "name": "window0", "color": [1.0, 0.5, 0.0]}]
    )
    w = _light(desc, "window0")
    src = read_exr(scene_dir / "hdri" / "courtyard.exr")[..., :3]
    tinted = read_exr(out / w["hdri_file"])[..., :3]
    np.testing.assert_allclose(tinted, src * np.array([1.0, 0.5, 0.0], np.float32), rtol=1e-3)


def test_move_point_and_area_lights_with_their_fittings(scene_dir: Path, tmp_path: Path) -> None:
    orig = json.loads((scene_dir / "scene.json").read_text())
    ops = [
        {"op": "light", "name": "floor_lamp", "move_to": [3.0, 1.0, 1.5]},
        {"op": "light", "name": "ceiling_panel", "move_to": [4.0, 1.2, 2.68]},
    ]
    desc, out = _edit(scene_dir, tmp_path, ops)
    lamp = _light(desc, "floor_lamp")
    assert lamp["position"] == [3.0, 1.0, 1.5]
    delta = np.array([3.0 - 0.55, 1.0 - 0.55, 0.0])
    for name in ("floor_lamp_shade", "floor_lamp_pole"):
        v0 = _read_piece(scene_dir / _part(orig, name)["file"]).vertices
        v1 = _read_piece(out / _part(desc, name)["file"]).vertices
        np.testing.assert_allclose(v1, v0 + delta, atol=1e-5)
    panel = _light(desc, "ceiling_panel")
    np.testing.assert_allclose(light_centre(panel), [4.0, 1.2, 2.68], atol=1e-9)
    moved = {p["name"] for p in fixture_parts(desc, panel)}
    assert moved == {"ceiling_panel", "ceiling_panel_rim"}
    face = _read_piece(out / _part(desc, "ceiling_panel")["file"]).vertices
    np.testing.assert_allclose(face.mean(axis=0)[:2], [4.0, 1.2], atol=1e-6)
    # The old recess is closed at the ceiling's height with the ceiling's material.
    patch = _part(desc, "ceiling_panel_recess_patch")
    assert patch["label"] == "ceiling"
    assert patch["material"] == _part(orig, "room/ceiling")["material"]
    pv = _read_piece(out / patch["file"])
    np.testing.assert_allclose(pv.vertices[:, 2], 2.7, atol=1e-6)
    np.testing.assert_allclose(pv.vertices.min(0)[:2], [2.2, 1.95], atol=1e-6)
    np.testing.assert_allclose(pv.normals, np.tile([0.0, 0.0, -1.0], (len(pv.normals), 1)))


def test_add_light_intensity(scene_dir: Path, tmp_path: Path) -> None:
    from reroom.render import mitsuba
    from reroom.synth.lighting import point_emitter

    ops = [
        {"op": "add_light", "name": "bulb", "position": [3, 2, 2], "intensity": 2.0},
        {
            "op": "add_light",
            "name": "spot",
            "position": [1, 1, 2.6],
            "intensity": 3.0,
            "color": [1.0, 0.5, 0.5],
            "ies": "ies_light_1",
        },
    ]
    desc, out = _edit(scene_dir, tmp_path, ops)
    bulb = _light(desc, "bulb")
    assert bulb["profile"] == "isotropic"
    assert bulb["power"] == pytest.approx(4 * np.pi * 2.0)
    spot = _light(desc, "spot")
    assert (out / spot["profile_file"]).is_file()
    # The emitter the renderer builds peaks at intensity * color.
    d = point_emitter(spot, out, mitsuba())
    peak = float(np.asarray(d["intensity"], float).max()) * d["scale"] * np.asarray(d["color"])
    np.testing.assert_allclose(peak, 3.0 * np.array([1.0, 0.5, 0.5]), rtol=1e-5)


def test_window_hdri_swap(scene_dir: Path, tmp_path: Path) -> None:
    desc, out = _edit(
        scene_dir, tmp_path, [{"op": "window", "name": "window0", "hdri": "sunset", "scale": 2}]
    )
    w = _light(desc, "window0")
    assert w["hdri"] == "sunset" and w["hdri_file"] == "hdri/sunset.exr"
    assert (out / "hdri" / "sunset.exr").is_file() and w["scale"] == 2.0
    assert w["rotation_deg"] == 0.0


def test_insert_places_the_object_on_the_floor(scene_dir: Path, tmp_path: Path) -> None:
    op = {
        "op": "insert",
        "object": "table",
        "position": [3.0, 1.0, 0.0],
        "rotation_deg": 90.0,
        "color": [0.2, 0.3, 0.4],
    }
    desc, out = _edit(scene_dir, tmp_path, [op])
    part = desc["parts"][-1]
    assert part["label"] == "furniture"
    assert part["material"] == {"type": "diffuse", "albedo": [0.2, 0.3, 0.4]}
    v = _read_piece(out / part["file"]).vertices
    lo, hi = v.min(axis=0), v.max(axis=0)
    np.testing.assert_allclose(
        [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]], [3, 1, 0], atol=1e-6
    )
    # Turned by 90 degrees: the 1.2 m long table now runs along y.
    assert hi[1] - lo[1] == pytest.approx(1.2, abs=1e-6)
    assert hi[0] - lo[0] == pytest.approx(0.8, abs=1e-6)


@pytest.mark.parametrize(
    ("op", "match"),
    [
        ({"op": "light", "name": "nope", "off": True}, "no light named 'nope'"),
        ({"op": "repaint", "target": "nope", "color": [1, 1, 1]}, "nope"),
        ({"op": "window", "name": "tube", "hdri": "sunset"}, "not a window"),
        (
            {"op": "insert", "object": "cube", "position": [9.0, 1.0, 0.0]},
            r"cube.*\[9\.0, 1\.0, 0\.0\] is outside the room",
        ),
        ({"op": "insert", "object": "missing_mesh.obj", "position": [1, 1, 0]}, "missing"),
    ],
)
def test_bad_edits_are_errors(scene_dir: Path, tmp_path: Path, op: dict, match: str) -> None:
    with pytest.raises(EditError, match=match):
        _edit(scene_dir, tmp_path, [op])


def test_never_edits_in_place(scene_dir: Path) -> None:
    with pytest.raises(ScanError, match="own ground-truth scene"):
        apply_edits(scene_dir, [{"op": "empty"}], scene_dir)


def test_render_shows_an_off_light_gone(scene_dir: Path, tmp_path: Path) -> None:
    """All lights minus (panel off) equals the panel alone: light transport is linear."""
    others = ["tube", "floor_lamp", "downlight", "window0"]
    all_on = scene_dir
    _, panel_off = _edit(
        scene_dir, tmp_path, [{"op": "light", "name": "ceiling_panel", "off": True}]
    )
    only = apply_edits(
        scene_dir,
        [{"op": "light", "name": n, "off": True} for n in others],
        tmp_path / "only_panel",
        layout=LAYOUT,
    )
    assert [light["on"] for light in only["lights"]] == [True, False, False, False, False]
    intr = Intrinsics.from_fov(24, 18, 70.0)
    # Looking up at the panel from below, so it fills part of the view.
    cam = [(look_at([2.5, 1.0, 1.2], [2.5, 2.25, 2.68]), intr)]
    a = render_scene(all_on, cam, 64, seed=1)[0]
    b = render_scene(panel_off, cam, 64, seed=2)[0]
    c = render_scene(tmp_path / "only_panel", cam, 64, seed=3)[0]
    panel_px = c.mean(axis=2) > 4.0  # the panel itself (radiance 5)
    assert panel_px.sum() >= 4
    assert np.all(b[panel_px].mean(axis=1) < 1.0)  # the panel no longer glows
    assert np.all(a[panel_px].mean(axis=1) > 4.0)
    rest = ~panel_px
    np.testing.assert_allclose((a - b)[rest].mean(), c[rest].mean(), rtol=0.1)
    # Different seeds, different noise; same seed, the same image.
    again = render_scene(tmp_path / "only_panel", cam, 64, seed=3)[0]
    np.testing.assert_array_equal(again, c)
