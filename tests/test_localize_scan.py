"""Room-scale light localization (``reroom.localize.scan``) on a small synthetic room.

The room is a 4 x 3 x 2.5 m box lit by two isotropic point lights; its radiance is a
radiosity solution (direct light plus bounces gathered by the same hemisphere rays the
estimator uses, with other seeds), so the answer is known: the lights' positions and
the three albedos.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from reroom.errors import ReroomError
from reroom.invert.transfer import hemisphere_transfer
from reroom.io.mesh import write_ply
from reroom.lights.lightset import Light, LightSet, load_lights, write_lights
from reroom.localize.measurements import shading_matrix
from reroom.localize.scan import (
    LOCALIZED_REASON,
    ScanLocalizeOptions,
    ScanLocalizeResult,
    _discovery_gain,
    _enclosed,
    _fitting_axis,
    _floating,
    _mount_test,
    _one_fixture,
    _Problem,
    _unheld,
    localize_into_lights,
    localize_scan,
    merge_localized_lights,
)
from reroom.rays import RayCaster

SIZE = np.array([4.0, 3.0, 2.5])
LIGHTS = np.array([[1.1, 0.9, 1.9], [2.9, 2.0, 1.2]])
POWER = np.array([2.0, 1.5])
ALBEDO = {0: 0.6, 1: 0.3, 2: 0.8}  # wall, floor, ceiling


def _face_grid(axis: int, side: float, step: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Grid vertices and triangles of one inner face of the box, wound to face inwards."""
    others = [c for c in range(3) if c != axis]
    na, nb = (int(round(SIZE[c] / step)) + 1 for c in others)
    a, b = np.meshgrid(
        np.linspace(0, SIZE[others[0]], na), np.linspace(0, SIZE[others[1]], nb), indexing="ij"
    )
    v = np.zeros((na * nb, 3))
    v[:, axis] = side
    v[:, others[0]], v[:, others[1]] = a.ravel(), b.ravel()
    idx = np.arange(na * nb).reshape(na, nb)
    q = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 4)
    f = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
    inward = np.zeros(3)
    inward[axis] = 1.0 if side == 0 else -1.0
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    if float(n[0] @ inward) < 0:
        f = f[:, ::-1]
    label = 0 if axis < 2 else (1 if side == 0 else 2)
    return v, f, label


def make_room_scan(root: Path, step: float = 0.25, bounces: int = 5) -> Path:
    """Write ``hdr/hdr_mesh.ply``, ``layout/layout_labels.ply`` and ``layout/layout.json``."""
    verts, faces, labels = [], [], []
    off = 0
    for axis in range(3):
        for side in (0.0, SIZE[axis]):
            v, f, lab = _face_grid(axis, side, step)
            verts.append(v)
            faces.append(f + off)
            labels.append(np.full(len(v), lab))
            off += len(v)
    v, f, lab = np.concatenate(verts), np.concatenate(faces), np.concatenate(labels)
    mesh = trimesh.Trimesh(v, f, process=False)
    normals = np.zeros_like(v)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    for k in range(3):
        np.add.at(normals, f[:, k], fn)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    rho = np.array([ALBEDO[int(c)] for c in lab])
    caster = RayCaster(mesh)
    vis = caster.visibility_matrix(v, normals, LIGHTS)
    direct = shading_matrix(v, normals, LIGHTS, vis) @ POWER
    radiance = rho / np.pi * direct
    everything, no_light = np.ones(len(v), bool), np.full(len(v), -1)
    for b in range(bounces):
        rad3 = np.repeat(radiance[:, None], 3, axis=1)
        hemi = hemisphere_transfer(
            caster, mesh, np.arange(len(v)), normals, rad3, everything, no_light, [], None,
            rays_per_vertex=256, seed=1000 + b,
        )  # fmt: skip
        radiance = rho / np.pi * (hemi.indirect[:, 0] + direct)
    (root / "hdr").mkdir(parents=True)
    (root / "layout").mkdir()
    write_ply(root / "hdr" / "hdr_mesh.ply", mesh,
              {"radiance": np.repeat(radiance[:, None], 3, axis=1), "observed": everything.astype(np.uint8)})  # fmt: skip
    write_ply(root / "layout" / "layout_labels.ply", mesh, {"label": lab.astype(np.uint8)})
    layout = {
        "rotation": np.eye(3).tolist(),
        "rooms": [{"name": "room0", "polygon": [[0, 0], [4, 0], [4, 3], [0, 3]],
                   "floor_z": 0.0, "ceiling_z": 2.5}],
    }  # fmt: skip
    (root / "layout" / "layout.json").write_text(json.dumps(layout))
    return root


@pytest.fixture(scope="module")
def room_scan(tmp_path_factory) -> Path:
    return make_room_scan(tmp_path_factory.mktemp("localize_scan") / "scan")


@pytest.fixture(scope="module")
def localized(room_scan: Path) -> tuple[ScanLocalizeResult, dict]:
    # Bare bulbs in an empty box: nothing holds them, so they are kept explicitly.
    opts = ScanLocalizeOptions(rays_per_vertex=128, time_limit=120, drop_floating=False)
    return localize_scan(room_scan, opts)


def test_finds_both_lights_within_five_percent(localized):
    res, info = localized
    size = float(np.linalg.norm(SIZE))
    assert len(res.positions) == 2, info
    d = np.linalg.norm(LIGHTS[:, None] - res.positions[None], axis=-1)
    assert d.min(axis=1).max() < 0.05 * size, res.positions
    # Intensities come out in pi * radiance / albedo units: here the true ones.
    order = d.argmin(axis=1)
    np.testing.assert_allclose(res.intensities[order], POWER, rtol=0.2)


def test_albedos_recovered(localized):
    res, _ = localized
    for c, name in ((0, "wall"), (2, "ceiling"), (1, "floor")):
        assert abs(res.albedo[name] - ALBEDO[c]) < 0.1 * ALBEDO[c], res.albedo


def test_isotropic_lights_stay_isotropic(localized):
    res, _ = localized
    assert all(g is None for g in res.goniometric), res.goniometric


def test_missing_stage_output_is_named(tmp_path: Path):
    with pytest.raises(ReroomError, match="hdr_mesh.ply"):
        localize_scan(tmp_path)


def _point(name: str, pos, source: str) -> Light:
    return Light(name, "point", source, {"position": list(pos), "axis": [0, 0, 1]}, {}, "test")


def test_merge_replaces_detected_and_keeps_user_lights(localized, room_scan: Path, tmp_path: Path):
    res, info = localized
    near = res.positions[0] + [0.1, 0.0, -0.1]
    far = [0.3, 2.7, 0.4]
    lights = LightSet(
        lights=[_point("point0", near, "detected"), _point("mine", far, "user")],
        vertex_light_id=np.full(3, -1, np.int32),
    )
    write_lights(lights, tmp_path / "lights")
    path, done = localize_into_lights(room_scan, res, info, tmp_path / "lights")
    back = load_lights(path)
    names = [x.name for x in back.lights]
    assert names[:2] == ["point0", "mine"] and len(names) == 3, names
    assert back.lights[0].source == "localize" and back.lights[0].reason == LOCALIZED_REASON
    np.testing.assert_allclose(back.lights[0].anchor(), res.positions[0], atol=1e-5)
    assert back.lights[1].source == "user" and back.lights[1].anchor().tolist() == far
    assert back.lights[2].type == "point" and back.lights[2].reason == LOCALIZED_REASON
    assert len(done) == 2
    # Merging again replaces the localized lights in place instead of adding more.
    merge_localized_lights(back, res, info)
    assert [x.name for x in back.lights] == names


def test_merge_keeps_a_place_measured_from_the_pool_edge(localized):
    res, info = localized
    measured = res.positions[0] + [0.02, 0.0, -0.12]  # e.g. inside a shade, under the rim
    lamp = _point("point0", measured, "detected")
    lamp.evidence.update(height_from="pool edge", pool_edge_radius_m=1.15, edge_sectors=5)
    lights = LightSet(lights=[lamp], vertex_light_id=np.full(3, -1, np.int32))
    done = merge_localized_lights(lights, res, info)
    kept = lights.lights[0]
    assert kept.source == "localize" and kept.name == "point0"
    np.testing.assert_allclose(kept.anchor(), measured, atol=1e-9)
    np.testing.assert_allclose(kept.evidence["localized_position"], res.positions[0])
    assert kept.evidence["height_from"] == "pool edge" and "kept at" in done[0]
    # Merging again (a second `reroom localize`) keeps it there too.
    merge_localized_lights(lights, res, info)
    np.testing.assert_allclose(lights.lights[0].anchor(), measured, atol=1e-9)


def test_merge_records_the_mount(localized):
    """A light the mount test held by the surface above says so in its evidence."""
    res, info = localized
    info = {**info, "goniometric": [
        {"mount": {"mounted": True, "surface_above_z": 2.5, "reason": "no fitting"}},
        {"mount": {"mounted": False, "surface_above_z": 2.5}},
    ]}  # fmt: skip
    lights = LightSet(lights=[], vertex_light_id=np.full(3, -1, np.int32))
    merge_localized_lights(lights, res, info)
    assert lights.lights[0].evidence["mounted_on"] == {"surface_z": 2.5, "reason": "no fitting"}
    assert "mounted_on" not in lights.lights[1].evidence


def _mount_case(
    profile_up: bool = False,
    pendant: bool = False,
    side: bool = False,
    top_ratio: float = 1.02,
    labelled: bool = False,
    stand: bool = False,
):
    """A 4 x 3 x 2.5 m room, a light tested along the vertical x = 2, y = 1.5 whose costs
    are lowest at 1.8 m and ``top_ratio`` times that just under the ceiling."""
    room = trimesh.creation.box(extents=SIZE)
    room.apply_translation(SIZE / 2)
    if pendant:  # a 0.2 m shade above the light
        shade = trimesh.creation.box(extents=[0.2, 0.2, 0.2])
        shade.apply_translation([2.0, 1.5, 1.95])
        room = trimesh.util.concatenate([room, shade])
    if side:  # a body beside the light, not straight above it (an arm, a side shade)
        arm = trimesh.creation.box(extents=[0.1, 0.1, 0.3])
        arm.apply_translation([2.2, 1.5, 2.0])
        room = trimesh.util.concatenate([room, arm])
    n_room = len(room.vertices)
    if stand:  # a lamp's stand below the light (a floor lamp): what holds it
        body = trimesh.creation.box(extents=[0.1, 0.1, 1.2])
        body.apply_translation([2.1, 1.5, 0.6])
        room = trimesh.util.concatenate([room, body])
    # Layout labels: the room's corners are floor (z = 0) and ceiling, the rest "other".
    labels = np.full(len(room.vertices), 255)
    corners = np.asarray(room.vertices[:8])
    labels[:8] = np.where(corners[:, 2] < 1.0, 1, 2)
    labels[8:n_room] = 255
    heights = np.arange(0.5, 2.48, 0.05)
    cands = np.column_stack([np.full_like(heights, 2.0), np.full_like(heights, 1.5), heights])
    costs = 100.0 * (1.0 + (top_ratio - 1.0) * ((heights - 1.8) / (heights[-1] - 1.8)) ** 2)
    bins = 64
    edges = np.linspace(0.0, np.pi, bins + 1)
    solid = 2.0 * np.pi * (np.cos(edges[:-1]) - np.cos(edges[1:]))
    profile = np.ones(bins) if profile_up else np.r_[np.zeros(bins // 2), np.ones(bins // 2)]
    best = int(np.argmin(costs))
    return _mount_test(
        RayCaster(room), np.asarray(room.vertices), cands, costs, profile, best, solid,
        ScanLocalizeOptions(), labels if labelled else None,
    ), cands  # fmt: skip


def test_mount_test_moves_unshaded_downlight_to_the_ceiling():
    res, cands = _mount_case()
    assert res["mounted"], res
    assert res["upward_flux"] == 0.0
    assert res["surface_above_z"] == pytest.approx(2.5)
    assert 2.4 <= cands[res["index"], 2] < 2.5
    assert res["cost_ratio"] <= 1.1


def test_mount_test_keeps_lights_that_light_upwards_or_have_a_fitting():
    up, _ = _mount_case(profile_up=True)
    assert not up["mounted"] and up["upward_flux"] == pytest.approx(0.5)
    # A pendant's shade is the body above: the light stays under it, not at the ceiling.
    shade, cands = _mount_case(pendant=True)
    assert shade["surface_above_z"] == pytest.approx(1.85), shade
    assert not shade["mounted"] or cands[shade["index"], 2] < 1.85, shade
    beside, _ = _mount_case(side=True)
    assert not beside["mounted"] and beside["fitting_vertices"] > 0, beside
    assert beside["surface_above_z"] == pytest.approx(2.5)
    rejected, _ = _mount_case(top_ratio=1.5)
    assert not rejected["mounted"] and rejected["cost_ratio"] > 1.1, rejected


def test_mount_test_lifts_a_light_nothing_holds():
    # It lights upwards (no body needs to shade it), but nothing in the scan holds it
    # (only floor and ceiling around its vertical): it is in the ceiling, if the data allow.
    free, cands = _mount_case(profile_up=True, labelled=True)
    assert free["mounted"] and free["fitting_vertices"] == 0, free
    assert 2.4 <= cands[free["index"], 2] < 2.5
    # A stand below it (a floor lamp) holds it; a pendant's shade is the surface above.
    held, _ = _mount_case(profile_up=True, labelled=True, stand=True)
    assert not held["mounted"] and held["fitting_vertices"] > 0, held
    shade, cands = _mount_case(profile_up=True, labelled=True, pendant=True)
    assert shade["surface_above_z"] == pytest.approx(1.85), shade
    assert not shade["mounted"] or cands[shade["index"], 2] < 1.85, shade
    # The data must still allow the ceiling.
    rejected, _ = _mount_case(profile_up=True, labelled=True, top_ratio=1.5)
    assert not rejected["mounted"] and rejected["cost_ratio"] > 1.1, rejected
    # Switched off: the earlier rule (a light lighting upwards stays).
    off = _mount_test(
        RayCaster(trimesh.creation.box(extents=SIZE).apply_translation(SIZE / 2)),
        np.zeros((0, 3)), cands, np.full(len(cands), 100.0), np.ones(64),
        0, np.full(64, 4.0 * np.pi / 64), ScanLocalizeOptions(mount_unsupported=False),
        np.zeros(0, int),
    )  # fmt: skip
    assert not off["mounted"], off


def test_enclosed_by_a_shade_not_by_a_pole_beside():
    # A lamp: a shade (a ring of radius 0.2 m from 1.3 to 1.7 m) on a pole to the floor.
    t = np.linspace(0.0, 2.0 * np.pi, 24, endpoint=False)
    ring = np.column_stack([0.2 * np.cos(t), 0.2 * np.sin(t)])
    shade = np.vstack([np.column_stack([ring, np.full(24, z)]) for z in (1.3, 1.5, 1.7)])
    pole = np.column_stack([np.zeros(14), np.zeros(14), np.linspace(0.0, 1.3, 14)])
    floor = np.array([[0.1, 0.0, 0.0], [-0.1, 0.1, 0.0]])
    verts = np.vstack([shade, pole, floor]) + [2.0, 1.5, 0.0]
    labels = np.r_[np.full(len(shade) + len(pole), 255), np.ones(len(floor), int)]
    assert _enclosed(verts, labels, np.array([2.05, 1.5, 1.5]), 0.3)
    # Below the shade, beside the pole; above it; the same shade labelled as wall.
    assert not _enclosed(verts, labels, np.array([2.15, 1.5, 0.8]), 0.3)
    assert not _enclosed(verts, labels, np.array([2.0, 1.5, 2.2]), 0.3)
    assert not _enclosed(verts, np.zeros(len(verts), int), np.array([2.05, 1.5, 1.5]), 0.3)


def test_fitting_axis_is_the_shade_centre_seen_from_one_side():
    # A frustum shade (radius 0.22 m at 1.36 m to 0.14 m at 1.64 m) in a corner: the scan
    # shows 3/4 of it, so the mean of its vertices is off its axis; a pole under it.
    rng = np.random.default_rng(3)
    t = rng.uniform(0.0, 1.5 * np.pi, 600)
    z = rng.uniform(1.36, 1.64, 600)
    r = 0.22 - 0.08 * (z - 1.36) / 0.28 + rng.normal(0.0, 0.003, 600)
    shade = np.column_stack([r * np.cos(t), r * np.sin(t), z])
    pole = np.column_stack([np.zeros(14), np.zeros(14), np.linspace(0.0, 1.36, 14)])
    centre = np.array([0.55, 0.55])
    verts = np.vstack([shade, pole]) + [*centre, 0.0]
    labels = np.full(len(verts), 255)
    p = np.array([0.59, 0.52, 1.50])  # 5 cm off the axis, inside the shade
    axis = _fitting_axis(verts, labels, p, 0.3)
    near = (np.abs(verts[:, 2] - 1.5) < 0.1) & (np.linalg.norm(verts[:, :2] - p[:2], axis=1) < 0.3)
    assert np.linalg.norm(verts[near, :2].mean(axis=0) - centre) > 0.03  # the mean is off
    assert axis is not None and np.linalg.norm(axis - centre) < 0.005, axis
    # Not inside a fitting: beside the pole, far above the shade, or the shade is a wall.
    assert _fitting_axis(verts, labels, np.array([0.65, 0.55, 0.8]), 0.3) is None
    assert _fitting_axis(verts, labels, np.array([0.55, 0.55, 2.3]), 0.3) is None
    assert _fitting_axis(verts, np.zeros(len(verts), int), p, 0.3) is None


def _shade_problem():
    """A 4 x 3 x 2.5 m room, a lamp shade open at both ends (as ``furnished``'s) around
    an isotropic bulb at (2, 1.5, 1.5); receivers on the ceiling and floor see only
    the bulb's direct light, through the shade's openings."""
    from reroom.synth.geometry import frustum_shell

    room = trimesh.creation.box(extents=SIZE)
    room.apply_translation(SIZE / 2)
    shade = frustum_shell([2.0, 1.5, 1.36], 0.22, 0.14, 0.28, 0.006, sections=40, rings=5)
    mesh = trimesh.util.concatenate(
        [room, trimesh.Trimesh(shade.vertices, shade.faces, process=False)]
    )
    xs, ys = np.meshgrid(np.arange(0.05, 4.0, 0.1), np.arange(0.05, 3.0, 0.1), indexing="ij")
    xy = np.column_stack([xs.ravel(), ys.ravel()])
    pts = np.vstack([np.column_stack([xy, np.full(len(xy), 2.5)]),
                     np.column_stack([xy, np.zeros(len(xy))])])  # fmt: skip
    nrm = np.vstack(
        [np.tile([0.0, 0.0, -1.0], (len(xy), 1)), np.tile([0.0, 0.0, 1.0], (len(xy), 1))]
    )
    caster = RayCaster(mesh)
    bulb = np.array([[2.0, 1.5, 1.5]])
    vis = caster.visibility_matrix(pts, nrm, bulb)
    n = len(pts)
    pil = 2.0 * shading_matrix(pts, nrm, bulb, vis)[:, 0]
    prob = _Problem(
        pts, nrm, pil, np.zeros(n), np.zeros(n, int), [0], np.zeros((n, 0)), [], caster, 1.0
    )
    labels = np.r_[
        np.where(np.asarray(room.vertices)[:, 2] < 1.0, 1, 2), np.full(len(shade.vertices), 255)
    ]
    layout = {
        "rooms": [{"polygon": [[0, 0], [4, 0], [4, 3], [0, 3]], "floor_z": 0.0, "ceiling_z": 2.5}]
    }
    return prob, np.asarray(mesh.vertices), labels, layout


def test_goniometric_height_inside_a_shade_is_found_on_its_axis():
    from reroom.localize.scan import _goniometric_test

    prob, verts, labels, layout = _shade_problem()
    start = np.array([[2.04, 1.53, 0.9]])  # the search's isotropic fit: under the shade, off axis
    box = (np.zeros(3), SIZE.astype(float))
    found = {}
    for axis in (True, False):
        opt = ScanLocalizeOptions(enclosed_axis=axis, profile_gain=0.0)
        out = _goniometric_test(
            prob, start, np.array([1.0]), np.array([1.0]), box, layout, opt, verts, labels
        )
        assert out[0] is not None
        found[axis] = np.asarray(out[0]["position"])
    # On the shade's axis, at the bulb's height (tested every 0.05 m).
    assert np.linalg.norm(found[True][:2] - [2.0, 1.5]) < 0.005, found
    assert abs(found[True][2] - 1.5) < 0.03, found
    # Without it the vertical stays 5 cm off the axis, and the height is not the bulb's.
    assert np.linalg.norm(found[False][:2] - [2.0, 1.5]) > 0.04, found
    assert abs(found[False][2] - 1.5) > 0.03, found


def test_downward_light_lights_only_what_is_below_it():
    room = trimesh.creation.box(extents=SIZE)
    room.apply_translation(SIZE / 2)
    pts = np.array([[2.0, 1.5, 0.0], [2.0, 1.5, 2.5], [0.0, 1.5, 0.5], [0.0, 1.5, 2.2]])
    nrm = np.array([[0, 0, 1.0], [0, 0, -1.0], [1.0, 0, 0], [1.0, 0, 0]])
    n = len(pts)
    prob = _Problem(
        pts, nrm, np.ones(n), np.zeros(n), np.zeros(n, int), [0], np.zeros((n, 0)), [],
        RayCaster(room), 1.0,
    )  # fmt: skip
    light = np.array([[2.0, 1.5, 2.0]])
    assert prob.visibility(light).all()
    assert prob.visibility(light, np.array([False])).all()
    np.testing.assert_array_equal(
        prob.visibility(light, np.array([True]))[:, 0], [True, False, True, False]
    )


def test_unknown_albedo_update_mode_is_rejected(tmp_path: Path):
    with pytest.raises(ValueError, match="search_albedo_update"):
        localize_scan(tmp_path, ScanLocalizeOptions(search_albedo_update="sometimes"))
    for bad in (-0.1, float("nan")):
        with pytest.raises(ValueError, match="normal_radius"):
            localize_scan(tmp_path, ScanLocalizeOptions(normal_radius=bad))


def test_discovery_gain_refits_the_known_lights():
    # A window-like known column overlaps the point light's: fitted alone first, it
    # absorbs part of the light's signal. With the known column refitted, the light
    # explains all that is left, at its true intensity; against the fixed residual, less.
    rng = np.random.default_rng(3)
    s = rng.random((300, 4))
    known = (0.6 * s[:, 0] + 0.4 * rng.random(300))[:, None]
    b = 2.0 * s[:, 0] + 1.5 * known[:, 0]
    r = b - known[:, 0] * float(known[:, 0] @ b) / float(known[:, 0] @ known[:, 0])
    gain, start = _discovery_gain(s, r, known, scale=1e6)  # huge scale: plain least squares
    assert int(np.argmax(gain)) == 0
    assert gain[0] == pytest.approx(1.0)
    assert start[0] == pytest.approx(2.0)
    fixed = float(s[:, 0] @ r) ** 2 / float(s[:, 0] @ s[:, 0]) / float(r @ r)
    assert fixed < 0.9
    # Nothing known: the plain share; a candidate anti-correlated with r gains nothing.
    g0, _ = _discovery_gain(s, r, np.zeros((300, 0)), scale=1e6)
    assert g0[0] == pytest.approx(fixed)
    g1, st1 = _discovery_gain(-s, r, np.zeros((300, 0)), scale=1e6)
    assert g1[0] == 0.0 and st1[0] == 0.0


def test_discovery_gain_weighs_outliers_down():
    # A few huge residuals (a fixture's bleeding) that a candidate would explain do not
    # make it win against the light that explains the rest (soft-L1 weights).
    rng = np.random.default_rng(4)
    s = rng.random((400, 2))
    spot = np.zeros(400)
    spot[:5] = 1.0
    s[:, 1] = spot
    r = 0.5 * s[:, 0] + 10.0 * spot
    gain, _ = _discovery_gain(s, r, np.zeros((400, 0)), scale=0.1)
    assert int(np.argmax(gain)) == 0, gain
    plain, _ = _discovery_gain(s, r, np.zeros((400, 0)), scale=1e9)
    assert int(np.argmax(plain)) == 1, plain


def _grid_room() -> tuple[trimesh.Trimesh, np.ndarray]:
    """The 4 x 3 x 2.5 m box as 0.25 m vertex grids, labelled wall / floor / ceiling."""
    verts, faces, labels, off = [], [], [], 0
    for axis in range(3):
        for side in (0.0, SIZE[axis]):
            v, f, lab = _face_grid(axis, side, 0.25)
            verts.append(v)
            faces.append(f + off)
            labels.append(np.full(len(v), lab))
            off += len(v)
    mesh = trimesh.Trimesh(np.concatenate(verts), np.concatenate(faces), process=False)
    return mesh, np.concatenate(labels)


def test_floating_light_is_one_nothing_can_hold():
    mesh, labels = _grid_room()
    opt = ScanLocalizeOptions()
    caster = RayCaster(mesh)
    verts = np.asarray(mesh.vertices)
    # In mid-air, 1.3 m below the ceiling, nothing but floor and ceiling around its vertical.
    why = _floating(caster, verts, labels, np.array([2.0, 1.5, 1.2]), opt)
    assert why is not None and why.startswith("floating: 1.30 m below the surface above"), why
    # Just under the ceiling (a ceiling fitting), or beside a wall (a sconce): held.
    assert _floating(caster, verts, labels, np.array([2.0, 1.5, 2.45]), opt) is None
    assert _floating(caster, verts, labels, np.array([0.2, 1.5, 1.2]), opt) is None
    # A lamp's stand under it holds it; the same stand 0.5 m away or a stool far below
    # it does not.
    for x, height, held in ((2.05, 1.0, True), (2.5, 1.0, False), (2.05, 0.4, False)):
        stand = trimesh.creation.box(extents=[0.1, 0.1, height])
        stand.apply_translation([x, 1.5, height / 2])
        both = trimesh.util.concatenate([mesh, stand])
        lab = np.r_[labels, np.full(len(stand.vertices), 255)]
        got = _floating(
            RayCaster(both), np.asarray(both.vertices), lab, np.array([2.0, 1.5, 1.2]), opt
        )
        assert (got is None) == held, (x, height, got)


def test_a_mounted_light_is_held_by_the_surface_it_is_mounted_on():
    # The mount test put a light mount_depth below the ceiling at the x, y it searched
    # from; refitted sideways, the ceiling above it (a fused scan's is bumpy) is a little
    # higher, so the floating test alone reads it as floating. Mounted, it is held.
    mesh, labels = _grid_room()
    opt = ScanLocalizeOptions()
    caster = RayCaster(mesh)
    verts = np.asarray(mesh.vertices)
    low = SIZE[2] - opt.mount_depth - 1e-3
    placed = np.array([[2.0, 1.5, low], [2.0, 1.5, 1.2], [1.0, 1.5, low]])
    assert _floating(caster, verts, labels, placed[0], opt) is not None
    mounted = {"mount": {"mounted": True}}
    profiles = [mounted, None, {"mount": {"mounted": False}}]
    got = _unheld(caster, verts, labels, placed, profiles, opt)
    assert [k for k, _ in got] == [1, 2], got
    assert all(why.startswith("floating:") for _, why in got)


def test_floating_lights_dropped_by_default(room_scan: Path, localized):
    # The fixture's bare bulbs float in an empty box: the default drops them and says why.
    res, info = localize_scan(room_scan, ScanLocalizeOptions(rays_per_vertex=128, time_limit=120))
    assert len(res.positions) == 0, res.positions
    kept, _ = localized
    assert len(info["floating"]) >= len(kept.positions)
    assert all(f["reason"].startswith("floating:") for f in info["floating"])


def test_lights_placed_at_one_fixture_are_one_light():
    # Two lights the goniometric test put 10 cm apart at a lamp (the discovery's
    # isotropic lights above and below its shade) and one far away: the weaker of the
    # two goes, by the profile's mean intensity where there is one.
    placed = np.array([[0.5, 0.5, 1.40], [0.5, 0.5, 1.50], [5.3, 3.9, 2.64]])
    profiles = [{"mean_intensity": 0.4}, {"mean_intensity": 0.6}, None]
    inten = np.array([9.0, 0.1, 1.4])
    assert _one_fixture(placed, profiles, inten, 0.25) == [(0, 1)]
    assert _one_fixture(placed, profiles, inten, 0.05) == []
    # A chain of three, each 0.2 m from the next: the strongest (the middle) keeps both.
    chain = np.array([[0.0, 0.0, 1.0], [0.2, 0.0, 1.0], [0.4, 0.0, 1.0]])
    got = _one_fixture(chain, [None, None, None], np.array([1.0, 3.0, 2.0]), 0.25)
    assert got == [(2, 1), (0, 1)]


def test_shared_nnls_matches_plain_nnls():
    from reroom.localize.scan import _nonneg_fit, _SharedNNLS

    rng = np.random.default_rng(3)
    n, m0, m1 = 600, 40, 12
    base = np.abs(rng.normal(size=(n, m0))) * rng.uniform(0.01, 10.0, m0)
    base[:, 5] = 0.0  # an unobserved light: a zero column
    f = np.abs(rng.normal(size=(n, m1)))
    b = base[:, :6] @ rng.uniform(0, 1, 6) + f[:, :4] @ rng.uniform(0, 1, 4)
    b += 0.05 * rng.normal(size=n)
    a = np.hstack([base, f])
    coef, resid = _SharedNNLS(base, b).fit(f)
    np.testing.assert_allclose(coef, _nonneg_fit(a, b), atol=1e-9)
    np.testing.assert_allclose(resid, b - a @ coef, atol=1e-9)
    assert (coef >= 0).all()


def test_joint_fit_keeps_each_light_within_its_own_bounds():
    # A light found inside a fitting is held on the fitting's axis (hold_in_fitting) by
    # per-light bounds; let loose, the fit is free in the room.
    from reroom.localize.scan import _joint_fit

    prob, _, _, _ = _shade_problem()
    start = np.array([[2.1, 1.55, 1.45]])
    room = (np.full(3, 0.05), SIZE - 0.05)
    free, i_free, _, _ = _joint_fit(
        prob, start, np.array([1.0]), np.array([1.0]), np.zeros(0), room, 0.05
    )
    assert np.linalg.norm(free[0] - [2.0, 1.5, 1.5]) < 0.02, free
    # Bounds that leave out the bulb's place: the fit stops on their edge, nearest to it.
    lo, hi = np.array([[2.08, 1.45, 1.4]]), np.array([[2.2, 1.6, 1.6]])
    held, _, _, _ = _joint_fit(
        prob, start, np.array([1.0]), np.array([1.0]), np.zeros(0), (lo, hi), 0.05
    )
    assert np.all(held >= lo - 1e-9) and np.all(held <= hi + 1e-9), held
    assert abs(held[0, 0] - 2.08) < 1e-3, held


@pytest.mark.parametrize("slack, height", [(0.0, 0.15), (0.05, -0.1)])
def test_fitting_bounds_must_be_positive(tmp_path: Path, slack: float, height: float):
    opt = ScanLocalizeOptions(fitting_slack=slack, fitting_height=height)
    with pytest.raises(ValueError, match="fitting_slack .* must be positive"):
        localize_scan(tmp_path, opt)
