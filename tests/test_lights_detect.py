"""Light detection: candidates, decisions with reasons, the light file, user overrides, the CLI.

The end-to-end tests share one small projected scan (a box room with a ceiling panel
and a glossy table that reflects it, :mod:`reroom.lights.synthetic`), made once per
module with its HDR and layout outputs (a few seconds).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import trimesh
from typer.testing import CliRunner

from reroom.cli import app
from reroom.hdr.observe import Observations
from reroom.layout.meshops import vertex_adjacency
from reroom.lights import (
    LightsError,
    LightSet,
    LightsOptions,
    apply_edits,
    detect_lights,
    edits_from_options,
    load_lights,
    parse_point,
    write_lights,
)
from reroom.lights.candidates import bright_components, describe_component
from reroom.lights.consistency import view_consistency
from reroom.lights.evaluate import rectangle_iou
from reroom.lights.lightset import Light, Rejected
from reroom.lights.lines import fixture_from_pieces, merge_lines
from reroom.lights.room import RoomModel
from reroom.lights.synthetic import HIGHLIGHT_SCENE, highlight_scan

runner = CliRunner()


@pytest.fixture(scope="module")
def hl_scan(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The highlight scan with ``hdr/`` and ``layout/`` (built once per module)."""
    from reroom.hdr.pipeline import HdrOptions, run_hdr
    from reroom.layout.pipeline import LayoutOptions, run_layout

    out = tmp_path_factory.mktemp("lights") / "scan"
    highlight_scan(out, n_frames=24, width=96, height=72)
    run_hdr(out, out / "hdr", HdrOptions(baselines=False, report=False))
    run_layout(out, out / "layout", LayoutOptions(features=False, figure=False, empty_room=False))
    return out


@pytest.fixture(scope="module")
def hl_lights(hl_scan: Path) -> LightSet:
    return detect_lights(hl_scan)


# ----------------------------------------------------------------- end to end


def test_panel_is_an_area_light(hl_lights: LightSet) -> None:
    (area,) = hl_lights.of_type("area")
    p = HIGHLIGHT_SCENE["panel"]
    centre = [(p["lo"][0] + p["hi"][0]) / 2, (p["lo"][1] + p["hi"][1]) / 2, p["z"]]
    assert np.linalg.norm(np.asarray(area.geometry["centroid"]) - centre) < 0.05
    assert np.allclose(area.geometry["normal"], [0, 0, -1], atol=0.05)
    assert np.allclose(area.geometry["size"], [0.6, 0.6], atol=0.06)
    assert area.source == "detected"
    assert area.reason.startswith("kept: area light, 0.6")
    assert area.evidence["frames_bright"] == area.evidence["frames_seeing"] >= 5
    # Its vertices carry its index; nothing else does.
    ids = hl_lights.vertex_light_id
    assert (ids == hl_lights.lights.index(area)).sum() == area.evidence["vertices"]
    assert not hl_lights.of_type("line")


def test_specular_highlight_is_rejected_with_a_reason(hl_lights: LightSet) -> None:
    """The glossy table top looks bright in the HDR mesh; the frames show it is a highlight."""
    z = HIGHLIGHT_SCENE["table"]["z"]
    on_table = [
        r
        for r in hl_lights.rejected
        if r.evidence and abs(r.evidence.get("height_m", 9) - z) < 0.05
    ]
    assert on_table, "the highlight must be a candidate, or this test proves nothing"
    big = max(on_table, key=lambda r: r.evidence["vertices"])
    assert big.evidence["vertices"] >= 50
    assert "view-dependent" in big.reason and "specular highlight" in big.reason
    ev = big.evidence
    assert f"bright in {ev['frames_bright']} of {ev['frames_seeing']} frames" in big.reason
    assert ev["frames_bright"] < 0.8 * ev["frames_seeing"]
    # No light anywhere near the table.
    table = np.array([2.6, 1.5, z])
    for light in hl_lights.lights:
        anchor = light.geometry.get("centroid", light.geometry.get("position"))
        assert np.linalg.norm(np.asarray(anchor) - table) > 0.5


def test_without_view_test_the_location_rule_still_rejects_it(hl_scan: Path) -> None:
    ls = detect_lights(hl_scan, options=LightsOptions(view_consistency=False))
    reasons = [r.reason for r in ls.rejected if r.evidence.get("vertices", 0) >= 50]
    assert any("upward-facing surface at z = 0.75 m" in r for r in reasons)
    assert not any("view-dependent" in r for r in reasons)
    assert len(ls.of_type("area")) == 1


def test_no_light_found_writes_an_empty_set(hl_scan: Path, tmp_path: Path) -> None:
    opts = LightsOptions(threshold=1e9, clipped_fraction=2.0, propose_points=False)
    with pytest.warns(UserWarning, match="no light found"):
        ls = detect_lights(hl_scan, options=opts)
    assert ls.lights == []
    assert any("no vertex is above the threshold" in n for n in ls.notes)
    write_lights(ls, tmp_path)
    back = load_lights(tmp_path)
    assert back.lights == [] and back.notes == ls.notes
    assert np.all(back.vertex_light_id == -1)


def test_missing_stage_outputs_are_named(hl_scan: Path, tmp_path: Path) -> None:
    with pytest.raises(LightsError, match=r"hdr_mesh.ply: missing; run `reroom hdr"):
        detect_lights(hl_scan, hdr_dir=tmp_path / "nohdr")
    with pytest.raises(LightsError, match=r"layout.json: missing; run `reroom layout"):
        detect_lights(hl_scan, layout_dir=tmp_path / "nolayout")
    # Labels of another mesh.
    bad = tmp_path / "layout"
    shutil.copytree(hl_scan / "layout", bad)
    from reroom.io.mesh import write_ply

    write_ply(bad / "layout_labels.ply", trimesh.creation.box(), {"label": np.zeros(8, np.uint8)})
    with pytest.raises(LightsError, match="8 vertices, but the HDR mesh has"):
        detect_lights(hl_scan, layout_dir=bad)


def test_write_and_load_round_trip(hl_lights: LightSet, tmp_path: Path) -> None:
    path = write_lights(hl_lights, tmp_path)
    doc = json.loads(path.read_text())
    assert doc["format"] == "reroom-lights"
    assert {"lights", "rejected", "thresholds", "notes", "vertices_file"} <= set(doc)
    for light in doc["lights"]:
        assert {"name", "type", "source", "evidence", "reason"} <= set(light)
    back = load_lights(path)
    assert [x.name for x in back.lights] == [x.name for x in hl_lights.lights]
    assert np.array_equal(back.vertex_light_id, hl_lights.vertex_light_id)
    assert len(back.rejected) == len(hl_lights.rejected)
    area_idx = back.area_vertex_index()
    assert set(np.unique(area_idx)) == {-1, 0}


def test_cli_writes_lights_with_overrides(hl_scan: Path, tmp_path: Path) -> None:
    out = tmp_path / "lights"
    edit = tmp_path / "edit.json"
    edit.write_text(json.dumps({"retype": {"area0": "window"}}))
    args = ["lights", str(hl_scan), "--out", str(out), "--add-point", "2,1.5,2.3,lamp"]
    args += ["--move", "lamp=2.1,1.5,2.3", "--edit", str(edit)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    ls = load_lights(out)
    lamp = ls.by_name("lamp")
    assert lamp.type == "point" and lamp.source == "user"
    assert np.allclose(lamp.geometry["position"], [2.1, 1.5, 2.3])
    assert np.allclose(lamp.geometry["axis"], [0, 0, 1], atol=1e-3)
    win = ls.by_name("area0")
    assert win.type == "window" and "retyped by the user" in win.reason
    assert np.isclose(np.linalg.norm(win.geometry["half_u"]), 0.3, atol=0.04)
    # The per-vertex ids still point at it (a window surface now).
    assert (ls.vertex_light_id == ls.lights.index(win)).sum() == win.evidence["vertices"]

    bad = runner.invoke(app, ["lights", str(hl_scan), "--out", str(out), "--remove", "nope"])
    assert bad.exit_code == 1
    assert "no light named 'nope'" in bad.output
    with pytest.warns(UserWarning, match="outside the room"):
        far = runner.invoke(
            app, ["lights", str(hl_scan), "--out", str(out), "--add-point", "50,1,1"]
        )
    assert far.exit_code == 0, far.output
    assert any(
        "'point0' at [50.0, 1.0, 1.0] is outside the room" in n for n in load_lights(out).notes
    )
    missing = runner.invoke(app, ["lights", str(tmp_path / "none")])
    assert missing.exit_code == 1 and "run `reroom hdr" in missing.output


# ----------------------------------------------------------------- overrides


def _toy_set() -> LightSet:
    area = Light(
        "area0",
        "area",
        "detected",
        {
            "centroid": [1.0, 1.0, 2.5],
            "normal": [0, 0, -1],
            "area": 0.36,
            "size": [0.6, 0.6],
            "axis_long": [1, 0, 0],
            "axis_short": [0, 1, 0],
            "light_index": 0,
        },
        {"vertices": 2},
        "kept",
    )
    line = Light(
        "line0",
        "line",
        "detected",
        {"p0": [0, 0, 2.5], "p1": [1, 0, 2.5], "d_perp": [0, 0, 1], "radius": 0.02},
        {},
        "kept",
    )
    return LightSet([area, line], [], np.array([0, 0, -1, -1], np.int32))


def test_edits_add_move_remove_retype() -> None:
    ls = _toy_set()
    edits = edits_from_options(["1,2,2.4", "3,1,2,desk"], ["area0"], ["line0=2,2,2.4"], None)
    apply_edits(ls, edits)
    assert [x.name for x in ls.lights] == ["line0", "point0", "desk"]
    assert np.all(ls.vertex_light_id == -1)  # the removed area light's vertices
    assert ls.rejected[-1].reason == "removed by the user"
    assert np.allclose(
        np.add(ls.lights[0].geometry["p0"], ls.lights[0].geometry["p1"]) / 2, [2, 2, 2.4]
    )
    apply_edits(ls, {"retype": {"line0": "point"}})
    assert ls.by_name("line0").type == "point"
    assert np.allclose(ls.by_name("line0").geometry["position"], [2, 2, 2.4])


def test_edit_errors_are_clear() -> None:
    with pytest.raises(LightsError, match="expected x,y,z"):
        parse_point("1,2")
    with pytest.raises(LightsError, match="must be numbers"):
        parse_point("1,a,3")
    with pytest.raises(LightsError, match="expected NAME=value"):
        edits_from_options(move=["line0"])
    ls = _toy_set()
    with pytest.raises(LightsError, match="not one of"):
        apply_edits(ls, {"retype": {"line0": "spot"}})
    with pytest.raises(LightsError, match="has no 'position'"):
        apply_edits(ls, {"add": [{"type": "point"}]})
    with pytest.raises(LightsError, match="already exists"):
        apply_edits(ls, {"add": [{"type": "point", "name": "line0", "position": [0, 0, 1]}]})


def test_load_lights_rejects_bad_files(tmp_path: Path) -> None:
    with pytest.raises(LightsError, match="run `reroom lights SCAN` first"):
        load_lights(tmp_path)
    (tmp_path / "lights.json").write_text("{nope")
    with pytest.raises(LightsError, match="not valid JSON"):
        load_lights(tmp_path)
    (tmp_path / "lights.json").write_text(
        json.dumps({"format": "reroom-lights", "lights": [{"name": "a", "type": "line"}]})
    )
    with pytest.raises(LightsError, match="line light 'a' has no 'p0'"):
        load_lights(tmp_path)


# ----------------------------------------------------------------- parts


def _grid(nx: int, ny: int, h: float, z: float) -> trimesh.Trimesh:
    x, y = np.meshgrid(np.arange(nx) * h, np.arange(ny) * h, indexing="ij")
    v = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])
    i = np.arange(nx * ny).reshape(nx, ny)
    a, b, c, d = i[:-1, :-1].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel(), i[:-1, 1:].ravel()
    f = np.vstack([np.column_stack([a, c, b]), np.column_stack([a, d, c])])
    return trimesh.Trimesh(v, f, process=False)


def test_components_shape_and_edge_contrast() -> None:
    """A bright square with a hard edge, and a soft bright pool, on one grid."""
    from scipy.spatial import cKDTree

    mesh = _grid(40, 40, 0.05, 2.5)
    v = np.asarray(mesh.vertices)
    lum = np.full(len(v), 0.2)
    e = 1e-9  # grid coordinates are multiples of 0.05 up to rounding
    square = (
        (v[:, 0] >= 0.3 - e) & (v[:, 0] <= 0.9 + e) & (v[:, 1] >= 0.3 - e) & (v[:, 1] <= 0.6 + e)
    )
    lum[square] = 5.0
    r = np.linalg.norm(v[:, :2] - [1.5, 1.5], axis=1)
    lum += 2.0 * np.exp(-0.5 * (r / 0.2) ** 2)  # a soft pool
    adj = vertex_adjacency(mesh.faces, len(v))
    _, members = bright_components(adj, lum > 1.0)
    assert len(members) == 2
    normals = np.tile([0.0, 0.0, -1.0], (len(v), 1))
    areas = np.full(len(v), 0.0025)
    rad = np.repeat(lum[:, None], 3, 1)
    comps = [
        describe_component(m, v, normals, areas, rad, lum, np.ones(len(v), bool), cKDTree(v), 0.1)
        for m in members
    ]
    sq = next(c for c in comps if np.isclose(c.centroid[0], 0.6, atol=0.01))
    pool = next(c for c in comps if c is not sq)
    assert np.allclose(sq.size, [0.6, 0.3], atol=1e-9)
    assert abs(abs(sq.axes[0] @ [1, 0, 0]) - 1) < 1e-9
    assert sq.edge_contrast > 10 and pool.edge_contrast < 2


def test_min_area_rectangle_of_a_square_is_its_sides() -> None:
    """PCA axes of a square are arbitrary; the sides must come out, not the diagonal."""
    from scipy.spatial import cKDTree

    mesh = _grid(13, 13, 0.05, 0.0)
    rot = trimesh.transformations.rotation_matrix(np.deg2rad(30), [0, 0, 1])
    mesh.apply_transform(rot)
    v = np.asarray(mesh.vertices)
    m = np.arange(len(v))
    lum = np.ones(len(v))
    comp = describe_component(
        m,
        v,
        np.tile([0.0, 0.0, 1.0], (len(v), 1)),
        np.ones(len(v)),
        np.ones((len(v), 3)),
        lum,
        np.ones(len(v), bool),
        cKDTree(v),
        0.1,
    )
    assert np.allclose(comp.size, [0.6, 0.6], atol=0.01)


def test_a_tube_seen_from_below_gets_its_true_axis() -> None:
    """Only the lower half of a 1.6 cm tube is bright: the axis is the circle's centre."""
    from scipy.spatial import cKDTree

    from reroom.lights.decide import make_light

    r, z = 0.016, 2.6
    ang = np.linspace(np.pi, 2 * np.pi, 9)  # the lower half, seen from below
    x = np.linspace(1.0, 2.2, 61)
    xx, aa = np.meshgrid(x, ang, indexing="ij")
    v = np.stack([xx.ravel(), 3.0 + r * np.cos(aa.ravel()), z + r * np.sin(aa.ravel())], 1)
    n = len(v)
    normals = (v - [0.0, 3.0, z]) * [0.0, 1.0, 1.0] / r
    comp = describe_component(
        np.arange(n), v, normals, np.full(n, 1e-4), np.ones((n, 3)), np.ones(n),
        np.ones(n, bool), cKDTree(v), 0.05,
    )  # fmt: skip
    assert comp.center[2] < z - 0.007  # the box's middle: under the axis
    assert comp.section_radius == pytest.approx(r, rel=1e-6)
    light = make_light("line", comp, {}, np.array([0.0, 0.0, 1.0]), "")
    for end in ("p0", "p1"):
        np.testing.assert_allclose(np.asarray(light.geometry[end])[1:], [3.0, z], atol=1e-6)
    assert light.geometry["radius"] == pytest.approx(r, rel=1e-6)
    # A flat strip has no circle to speak of: the box's middle stays.
    flat = v * [1, 1, 0] + [0, 0, z]
    comp = describe_component(
        np.arange(n), flat, normals, np.full(n, 1e-4), np.ones((n, 3)), np.ones(n),
        np.ones(n, bool), cKDTree(flat), 0.05,
    )  # fmt: skip
    light = make_light("line", comp, {}, np.array([0.0, 0.0, 1.0]), "")
    np.testing.assert_allclose((np.asarray(light.geometry["p0"]))[1:], [3.0, z], atol=1e-6)


def test_a_tube_showing_another_side_at_each_end_keeps_its_axis_and_radius() -> None:
    """Cameras along a tube see its -y side at one end and its +y side at the other:
    the bright vertices' principal axis tilts (0.4 degree on a `furnished` walk, 8 mm of
    extra width over 1.2 m); the cross-sections' circles give the axis and radius back."""
    from scipy.spatial import cKDTree

    from reroom.lights.candidates import _axes_along, _tube_slices
    from reroom.lights.decide import make_light

    r, z = 0.016, 2.6
    x = np.linspace(1.0, 2.2, 61)
    t = (x - x[0]) / (x[-1] - x[0])
    rows = []
    for xi, ti in zip(x, t, strict=True):
        # A half-circle turning from the -y side (start) to the +y side (end).
        ang = np.linspace(np.pi * (0.75 + 0.5 * ti), np.pi * (1.75 + 0.5 * ti), 9)
        rows.append(np.stack([np.full(9, xi), 3.0 + r * np.cos(ang), z + r * np.sin(ang)], 1))
    v = np.concatenate(rows)
    n = len(v)
    normals = (v - [0.0, 3.0, z]) * [0.0, 1.0, 1.0] / r
    q = v - v.mean(0)
    tilt = np.linalg.eigh(q.T @ q)[1][:, -1]
    assert abs(tilt[1]) > 0.005  # the principal axis is off by over 0.3 degree
    comp = describe_component(
        np.arange(n), v, normals, np.full(n, 1e-4), np.ones((n, 3)), np.ones(n),
        np.ones(n, bool), cKDTree(v), 0.05,
    )  # fmt: skip
    assert np.abs(comp.axes[0][1:]).max() < 2e-4  # against 5e-3 and more
    assert comp.section_radius == pytest.approx(r, rel=1e-3)
    light = make_light("line", comp, {}, np.array([0.0, 0.0, 1.0]), "")
    for end in ("p0", "p1"):
        np.testing.assert_allclose(np.asarray(light.geometry[end])[1:], [3.0, z], atol=2e-4)
    assert light.geometry["radius"] == pytest.approx(r, rel=1e-3)
    # Cross-sections that do not agree on a line of centres (a fused scan's blob) leave
    # the axes as they were: centres that wander by more than a fifth of the radius.
    rng = np.random.default_rng(0)
    blob = v + rng.normal(0.0, 0.004, (n, 3)) * [0, 1, 1]
    blob[:, 1] += 0.02 * np.sin(6 * np.pi * (blob[:, 0] - 1.0) / 1.2)
    comp = describe_component(
        np.arange(n), blob, normals, np.full(n, 1e-4), np.ones((n, 3)), np.ones(n),
        np.ones(n, bool), cKDTree(blob), 0.05,
    )  # fmt: skip
    slices = _tube_slices((blob - blob.mean(0)) @ comp.axes.T)
    assert slices is not None and _axes_along(comp.axes, slices) is None


def test_view_consistency_tells_emitters_from_highlights() -> None:
    """Candidate 0 is bright in every frame, candidate 1 in 2 of 10."""
    n_f = 10
    vert = np.repeat([0, 1], n_f)
    frame = np.tile(np.arange(n_f), 2)
    level = np.full(2 * n_f, 200)
    level[n_f + 2 :] = 20  # candidate 1: bright only in frames 0 and 1
    value = np.repeat(level[:, None], 3, 1)
    obs = Observations.from_arrays(2, n_f, vert, frame, value)
    vc = view_consistency(obs, np.array([0, 1]), 2, np.ones((n_f, 3)), bright_level=0.5)
    assert list(vc.frames_seeing) == [n_f, n_f]
    assert list(vc.frames_bright) == [n_f, 2]
    assert vc.view_ratio[0] == pytest.approx(1.0)
    assert vc.view_ratio[1] > 5


def test_collinear_line_pieces_are_joined() -> None:
    def piece(x0: float, x1: float, y: float = 0.0) -> tuple[Light, np.ndarray]:
        g = {"p0": [x0, y, 2.5], "p1": [x1, y, 2.5], "d_perp": [0, 0, 1], "radius": 0.02}
        ev = {"vertices": 10, "mean_luminance": 1.0}
        return Light("", "line", "detected", g, ev, ""), np.arange(10)

    joined = merge_lines([piece(0.0, 0.5), piece(0.7, 1.2), piece(0.0, 1.0, y=1.0)])
    assert len(joined) == 2
    g = joined[0][0].geometry
    assert np.allclose(sorted([g["p0"][0], g["p1"][0]]), [0.0, 1.2])
    assert "2 collinear pieces joined" in joined[0][0].reason


def _strip(x0: float, x1: float, y: float, z: float, n: int, down: bool) -> tuple:
    """A small rejected piece near the ceiling: the lower half of a 1.6 cm tube along x
    (``down``) or a vertical lit face 3 cm high, with ``n`` vertices."""
    from scipy.spatial import cKDTree

    x = np.linspace(x0, x1, n)
    if down:  # rings of 5 vertices on the lower half
        x = np.repeat(np.linspace(x0, x1, n // 5), 5)
        a = np.tile(np.linspace(np.pi, 2 * np.pi, 5), n // 5)
        v = np.stack([x, y + 0.016 * np.cos(a), z + 0.016 * np.sin(a)], 1)
        normals = np.stack([0 * a, np.cos(a), np.sin(a)], 1)
    else:  # pairs of vertices, 3 cm apart in height
        x = np.repeat(np.linspace(x0, x1, n // 2), 2)
        v = np.stack([x, np.full(n, y), z + 0.015 * (-1.0) ** np.arange(n)], 1)
        normals = np.tile([0.0, -np.sign(y), 0.0], (n, 1))
    comp = describe_component(
        np.arange(n), v, normals, np.full(n, 1e-4), np.ones((n, 3)), np.ones(n),
        np.ones(n, bool), cKDTree(v), 0.05,
    )  # fmt: skip
    ev = {"vertices": n, "normal_up": float(comp.normal[2]), "mean_luminance": 1.0}
    return Rejected(f"piece{x0}{y}", "component", f"rejected: {n} vertices < 50", ev), comp, ev


def test_a_tube_seen_in_pieces_beside_its_lit_baffles_is_one_line() -> None:
    """`lshape`'s 24-frame tube: a 40-vertex piece of it and two lit baffle faces 7 cm
    to either side, each under 50 vertices, together one line light with the ends of
    the fixture and the axis of the tube."""
    up = np.array([0.0, 0.0, 1.0])
    tube = _strip(0.6, 1.0, 0.0, 2.5, 40, down=True)
    left = _strip(0.1, 1.1, 0.07, 2.5, 14, down=False)
    right = _strip(0.05, 0.35, -0.07, 2.5, 6, down=False)
    far = _strip(3.0, 3.5, 2.0, 2.5, 30, down=True)  # elsewhere, alone: too few vertices
    pieces = [tube, left, right, far]
    rejected = [p[0] for p in pieces]
    (found,) = fixture_from_pieces(pieces, [], up, rejected, 50, 0.3)
    light, members = found
    g = light.geometry
    assert sorted([g["p0"][0], g["p1"][0]]) == pytest.approx([0.05, 1.1], abs=2e-3)
    for end in ("p0", "p1"):
        assert np.asarray(g[end])[1:] == pytest.approx([0.0, 2.5], abs=2e-3)
    assert g["radius"] == pytest.approx(0.016, rel=0.2)
    assert len(members) == 60 and light.evidence["pieces"] == 3
    assert "3 pieces side by side" in light.reason
    assert rejected == [far[0]]
    # No downward-facing piece (lit faces alone), too few vertices, or a line light
    # already there: nothing new.
    assert fixture_from_pieces([left, right], [], up, [left[0], right[0]], 10, 0.3) == []
    assert fixture_from_pieces(pieces[:3], [], up, [p[0] for p in pieces[:3]], 61, 0.3) == []
    line = Light("line0", "line", "detected", {"p0": [0.0, 0, 2.5], "p1": [1.2, 0, 2.5]}, {}, "")
    assert fixture_from_pieces(pieces[:3], [(line, np.arange(3))], up, [], 50, 0.3) == []


def test_layout_window_rectangle() -> None:
    """A window opening becomes a rectangle on the wall's outside face, normal inward."""
    room = {
        "name": "r",
        "polygon": [[0, 0], [4, 0], [4, 3], [0, 3]],
        "walls": [{"index": 0, "start": [0, 0], "end": [4, 0], "inward_normal": [0, 1]}],
        "openings": [
            {"kind": "window", "wall": 0, "s0": 1.0, "s1": 2.0, "z0": 1.0, "z1": 2.0, "depth": 0.2},
            {"kind": "door", "wall": 0, "s0": 3.0, "s1": 3.8, "z0": 0.0, "z1": 2.0, "depth": 0.03},
        ],
    }
    model = RoomModel(np.eye(3), 0.0, 2.5, [room], np.zeros(1, np.int64))
    (w,) = model.windows()
    assert np.allclose(w["centre"], [1.5, -0.2, 1.5])
    assert np.allclose(np.abs(w["half_u"]), [0.5, 0, 0])
    assert np.allclose(w["half_v"], [0, 0, 0.5])
    assert np.allclose(w["normal"], [0, 1, 0])
    assert model.inside(np.array([[2.0, 1.0], [5.0, 1.0]]), 0.1).tolist() == [True, False]


def test_a_layout_window_into_another_room_lets_in_no_daylight(
    hl_scan: Path, tmp_path: Path
) -> None:
    """An opening of the layout that leads into another room is rejected, with its reason."""
    layout = tmp_path / "layout"
    shutil.copytree(hl_scan / "layout", layout)
    doc = json.loads((layout / "layout.json").read_text())
    room = doc["rooms"][0]
    opening = {"kind": "window", "wall": 0, "s0": 0.5, "s1": 1.0, "z0": 1.0, "z1": 1.6}
    room["openings"] = [
        {**opening, "depth": 0.1},
        {**opening, "s0": 1.5, "s1": 2.0, "into": "room1"},
    ]
    (layout / "layout.json").write_text(json.dumps(doc))
    ls = detect_lights(hl_scan, layout_dir=layout)
    (win,) = ls.of_type("window")
    assert "window opening 0 of the layout" in win.reason
    (rej,) = [r for r in ls.rejected if r.kind == "window"]
    assert "opens into room1, not outside" in rej.reason and rej.name == "layout_window1"


def test_rectangle_iou() -> None:
    sq = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    assert rectangle_iou(sq, sq) == pytest.approx(1.0)
    assert rectangle_iou(sq, sq + [0.5, 0, 0]) == pytest.approx(1 / 3)
    assert rectangle_iou(sq, sq + [2, 0, 0]) == 0.0


def test_without_a_layout_it_goes_on_when_asked(hl_scan: Path, tmp_path: Path) -> None:
    """`reroom layout` can fail on a partial scan; lights are still found, with a note."""
    opts = LightsOptions(require_layout=False)
    with pytest.warns(UserWarning, match="ran without a room layout"):
        ls = detect_lights(hl_scan, layout_dir=tmp_path / "nolayout", options=opts)
    assert any("ran without a room layout" in n for n in ls.notes)
    assert not ls.of_type("window")
    (area,) = ls.of_type("area")
    assert np.allclose(area.geometry["size"], [0.6, 0.6], atol=0.06)


def test_thin_candidates_are_not_judged_by_frames_that_cannot_resolve_them() -> None:
    from reroom.lights.consistency import resolved_frames
    from reroom.scan import Frame, Intrinsics, look_at

    intr = Intrinsics(160, 120, 100.0, 100.0, 80.0, 60.0)
    frames = [
        Frame(j, Path(), look_at([0, 0, 1.5], [d, 0, 1.5]), intr) for j, d in enumerate([2, 6])
    ]
    centroids = np.array([[2.0, 0, 1.5], [6.0, 0, 1.5]])
    # A 3 cm tube is 1.5 px wide at 2 m; a 0.6 m panel 10 px at 6 m.
    res = resolved_frames(frames, centroids, np.array([0.03, 0.6]), min_pixels=3.0)
    assert res.tolist() == [[False, False], [True, True]]
