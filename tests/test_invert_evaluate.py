"""The truth's effective light distributions in the solved bases (``reroom.invert.evaluate``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from reroom.invert.basis import InclinationBasis, LineBasis
from reroom.invert.evaluate import (
    distribution_relative_l2,
    hidden_as_unobserved,
    true_line_profile,
    true_point_profile,
    true_sun,
    true_window_cells,
    true_window_power,
)
from reroom.invert.export import inclination_power, line_light_power
from reroom.io.ies import IESProfile, read_ies, write_ies
from reroom.io.mesh import write_ply


def _scene(tmp_path: Path, parts: dict[str, trimesh.Trimesh]) -> Path:
    """A ground-truth scene folder with the given furniture parts (and nothing else)."""
    (tmp_path / "meshes").mkdir(exist_ok=True)
    entries = []
    for name, mesh in parts.items():
        write_ply(tmp_path / "meshes" / f"{name}.ply", mesh, {})
        entries.append({"name": name, "file": f"meshes/{name}.ply", "label": "furniture"})
    (tmp_path / "scene.json").write_text(json.dumps({"parts": entries, "lights": []}))
    return tmp_path


def _open_bottom_box(centre, half: float) -> trimesh.Trimesh:
    box = trimesh.creation.box(extents=[2 * half] * 3)
    box.apply_translation(centre)
    keep = ~(box.vertices[box.faces][:, :, 2] < centre[2] - half + 1e-9).all(axis=1)
    return trimesh.Trimesh(box.vertices, box.faces[keep], process=False)


def _point(power=10.0, color=(1.0, 1.0, 1.0), **extra) -> dict:
    return {
        "name": "p",
        "type": "point",
        "position": [1.0, 2.0, 1.5],
        "up": [0.0, 0.0, 1.0],
        "profile": "isotropic",
        "power": power,
        "color": list(color),
        **extra,
    }


def test_unoccluded_isotropic_point_is_flat(tmp_path):
    scene = _scene(tmp_path, {})
    light = _point(power=10.0, color=(1.0, 0.8, 0.6))
    prof = true_point_profile(light, scene, np.array([0.0, 0.0, 1.0]), samples=256)
    col = np.array([1.0, 0.8, 0.6]) / 0.8
    np.testing.assert_allclose(prof, np.broadcast_to(10.0 / (4 * np.pi) * col, prof.shape))
    np.testing.assert_allclose(inclination_power(prof), 10.0 * col)


def test_box_open_at_the_bottom_hides_the_upper_bins(tmp_path):
    light = _point(power=4 * np.pi)  # 1 W/sr
    scene = _scene(tmp_path, {"shade": _open_bottom_box(light["position"], 0.1)})
    prof = true_point_profile(light, scene, np.array([0.0, 0.0, 1.0]), samples=1024)[:, 1]
    centres = InclinationBasis(32).bin_centres()
    # Open square of half-width 0.1 at 0.1 below: all of the cone within 45 deg of the
    # nadir leaves, nothing above the box's lower edge (54.7 deg from the nadir) does.
    assert np.all(prof[centres < np.radians(180 - 55)] == 0)
    np.testing.assert_allclose(prof[centres > np.radians(180 - 45 + 3)], 1.0)
    # Beyond the fixture radius the box no longer counts.
    far = true_point_profile(light, scene, np.array([0.0, 0.0, 1.0]), fixture_radius=0.05)
    np.testing.assert_allclose(far[:, 1], 1.0)


def test_ies_profile_round_trips(tmp_path):
    scene = _scene(tmp_path, {})
    (scene / "ies").mkdir()
    vertical = np.arange(0.0, 181.0, 1.0)  # from the nadir
    cd = np.where(vertical <= 60, 100 * np.cos(np.radians(vertical) * 1.5) + 5, 0.0)
    write_ies(
        scene / "ies" / "t.ies",
        IESProfile(
            vertical_angles=vertical,
            horizontal_angles=np.array([0.0, 360.0]),
            candela=np.stack([cd, cd]),
            keywords={"TEST": "t", "MANUFAC": "t"},
            symmetry="axial",
        ),
    )
    light = _point(power=8.0, color=(0.9, 1.0, 1.1), profile="t", profile_file="ies/t.ies")
    prof = true_point_profile(light, scene, np.array([0.0, 0.0, 1.0]), samples=4096)
    col = np.array([0.9, 1.0, 1.1])
    # Units: the whole sphere integrates to the light's power, per channel.
    np.testing.assert_allclose(inclination_power(prof), 8.0 * col, rtol=2e-3)
    # Orientation and shape: bin k (theta from up) holds the file's table at 180 - theta,
    # scaled to the power; reference by fine quadrature of the file's own interpolant.
    ies = read_ies(scene / "ies" / "t.ies")
    scale = 8.0 / ies.total_flux()
    edges = InclinationBasis(32).bin_edges()
    ref = []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        theta = np.linspace(a, b, 2001)
        w = np.sin(theta)
        ref.append(scale * np.sum(ies.intensity(180 - np.degrees(theta), 0.0) * w) / np.sum(w))
    np.testing.assert_allclose(prof[:, 1], ref, rtol=5e-3, atol=1e-3 * max(ref))


def test_relative_l2_exact_and_scaled():
    rng = np.random.default_rng(0)
    truth = rng.random((32, 3))
    k = np.array([2.0, 3.0, 4.0])
    assert distribution_relative_l2(truth * k, truth, k) == pytest.approx(0.0, abs=1e-12)
    assert distribution_relative_l2(1.1 * truth * k, truth, k) == pytest.approx(0.1)
    mask = np.zeros(32, bool)
    mask[:5] = True
    est = truth * k
    est[10:] = 0  # wrong outside the mask only
    assert distribution_relative_l2(est, truth, k, mask) == pytest.approx(0.0, abs=1e-12)
    assert distribution_relative_l2(est, truth, k) > 0.5


def _tube(radius=0.016, radiance=(12.0, 12.5, 13.0)) -> dict:
    return {
        "name": "tube",
        "type": "line",
        "part": "tube",
        "p0": [0.0, 0.0, 2.5],
        "p1": [1.2, 0.0, 2.5],
        "radius": radius,
        "radiance": list(radiance),
    }


def test_bare_tube_is_2rL_in_every_bin(tmp_path):
    tube = _tube()
    mesh = trimesh.creation.cylinder(radius=0.016, segment=[tube["p0"], tube["p1"]])
    scene = _scene(tmp_path, {"tube": mesh})  # its own part never occludes it
    prof = true_line_profile(tube, scene, np.array([0.0, 0.0, 1.0]), samples=64)
    expected = 2 * 0.016 * np.array([12.0, 12.5, 13.0])
    np.testing.assert_allclose(prof, np.broadcast_to(expected, prof.shape))


def test_bare_tube_power_in_every_basis(tmp_path):
    tube = _tube()
    scene = _scene(tmp_path, {})
    for phi_bins, fold in ((1, True), (4, True), (5, False)):
        prof = true_line_profile(
            tube, scene, np.array([0.0, 0.0, 1.0]), 8, samples=16, phi_bins=phi_bins, fold=fold
        )
        assert prof.shape == (8 * phi_bins, 3)
        np.testing.assert_allclose(prof[:, 1], 2 * 0.016 * 12.5)
        power = line_light_power(prof, 1.2, phi_bins, fold)
        np.testing.assert_allclose(power, np.pi**2 * 1.2 * 2 * 0.016 * np.array([12, 12.5, 13]))


def test_tube_under_a_plate_sends_nothing_up(tmp_path):
    # A plate 5 cm above the tube, reaching 0.4 m past its ends. Within 22.5 deg of the
    # plane perpendicular to the tube nothing leaves upwards; further along the tube,
    # light from near its ends passes the plate's ends.
    tube = _tube()
    plate = trimesh.creation.box(extents=[2.0, 1.0, 0.01])
    plate.apply_translation([0.6, 0.0, 2.55])
    scene = _scene(tmp_path, {"housing": plate})
    up = np.array([0.0, 0.0, 1.0])
    prof = true_line_profile(tube, scene, up, samples=256, phi_bins=4)[:, 1].reshape(32, 4)
    centres = LineBasis(32, 4).theta_centres()
    assert np.all(prof[centres < np.radians(75), 0] == 0)
    np.testing.assert_allclose(prof[centres > np.radians(95)], 2 * 0.016 * 12.5)
    assert prof[(centres > np.radians(55)) & (centres < np.radians(75)), 3].min() > 0
    # The separable basis's single phi bin: the same light, averaged over phi.
    one = true_line_profile(tube, scene, up, samples=256)
    assert line_light_power(one, 1.2)[1] == pytest.approx(
        line_light_power(prof.reshape(-1), 1.2, 4), rel=0.01
    )


def test_open_ended_channel_matches_its_closed_form(tmp_path):
    # Two tall baffles 7 cm either side of a thin tube, exactly as long as it, open at
    # both ends: a ray leaving from x along (theta, phi) reaches a baffle after
    # g tan|phi| / sin(theta) along the tube, so it escapes past the baffle's end from the
    # last such stretch of the tube: the fraction min(1, g tan|phi| / (L sin theta)).
    g, length, r = 0.07, 1.2, 0.001
    tube = _tube(radius=r)
    baffles = []
    for y in (-g, g):
        b = trimesh.creation.box(extents=[length, 0.002, 1.0])
        b.apply_translation([length / 2, y + np.sign(y) * 0.001, 2.5])
        baffles.append(b)
    scene = _scene(tmp_path, {"baffles": trimesh.util.concatenate(baffles)})
    basis = LineBasis(8, 4)
    prof = true_line_profile(
        tube,
        scene,
        np.array([0.0, 0.0, 1.0]),
        8,
        samples=256,
        angles=4,
        fixture_radius=3.0,
        phi_bins=4,
        phi_angles=64,
    )[:, 0].reshape(8, 4) / (2 * r * 12.0)
    # The closed form averaged over each bin (theta uniform, phi weighted by cos^2).
    t_e, p_e = basis.theta_edges(), basis.phi_edges()
    for k in (3, 4):  # sideways: the baffles (1 m tall) stop every ray not escaping
        for j in range(4):
            th = np.linspace(t_e[k], t_e[k + 1], 201)[:, None]
            ph = np.linspace(p_e[j], p_e[j + 1], 2001)[None, :-1]
            ph = ph + (p_e[j + 1] - p_e[j]) / 4000  # midpoints
            frac = np.minimum(1.0, g * np.tan(ph) / (length * np.sin(th)))
            want = np.average(frac.mean(axis=0), weights=np.cos(ph[0]) ** 2)
            assert prof[k, j] == pytest.approx(want, rel=0.05, abs=0.003), (k, j, want)
    assert prof[3:5, 0].max() < 0.02 and prof[3:5, 3].min() > 0.15


def test_window_cells_of_a_constant_sky(tmp_path):
    from reroom.io.images import write_exr

    (tmp_path / "hdri").mkdir()
    write_exr(tmp_path / "hdri" / "c.exr", np.full((16, 32, 3), [1.0, 2.0, 3.0], np.float32))
    light = {"normal": [0.0, 1.0, 0.0], "hdri_file": "hdri/c.exr", "scale": 0.5}
    cells, shown = true_window_cells(light, tmp_path)
    assert shown.sum() == 48  # the half of the cube map beyond the wall
    np.testing.assert_allclose(cells[shown], np.broadcast_to([0.5, 1.0, 1.5], (48, 3)), 1e-6)
    assert np.all(cells[~shown] == 0)
    assert true_sun(light, tmp_path) is None  # an even sky has no sun


def test_a_one_texel_sun_is_integrated_exactly(tmp_path):
    # 400k random directions (the quadrature before session 21) hit a sun this small a
    # handful of times; the texel sum carries it whole.
    from reroom.invert.window_env import latlong_directions, latlong_solid_angles
    from reroom.io.images import write_exr

    h = 64
    img = np.full((h, 2 * h, 3), 0.1, np.float32)
    d = latlong_directions(h).reshape(-1, 3)
    k = int(np.argmax(d @ np.array([0.3, -0.6, 0.74])))  # a texel beyond the wall y = 0
    omega = latlong_solid_angles(h).ravel()
    img.reshape(-1, 3)[k] = np.array([2.0, 1.0, 0.5]) / omega[k]  # irradiance (2, 1, 0.5)
    (tmp_path / "hdri").mkdir()
    write_exr(tmp_path / "hdri" / "s.exr", img)
    corners = [[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1]]
    light = {"normal": [0.0, 1.0, 0.0], "hdri_file": "hdri/s.exr", "corners": corners}
    sun = true_sun(light, tmp_path)
    np.testing.assert_allclose(sun["irradiance"], [2.0, 1.0, 0.5], rtol=1e-5)
    np.testing.assert_allclose(sun["direction"], d[k], atol=1e-9)
    cos = -d[:, 1].clip(max=0.0)
    sky = 0.1 * float((omega * cos).sum() - omega[k] * cos[k])  # the sun's texel replaced
    want = sky + np.array([2.0, 1.0, 0.5]) * cos[k]  # area 1 m^2
    np.testing.assert_allclose(true_window_power(light, tmp_path), want, rtol=1e-5)


def test_hidden_vertices_are_unobserved_in_true_radiance_runs():
    # A vertex no probe could see reads exactly 0 in every channel; a dark channel alone
    # (a saturated red surface's blue) is real radiance and stays.
    rad = np.array([[0.2, 0.3, 0.1], [0.0, 0.0, 0.0], [0.4, 0.0, 0.0]])
    out = hidden_as_unobserved(rad)
    assert np.isnan(out[1]).all()
    np.testing.assert_array_equal(out[[0, 2]], rad[[0, 2]])
    assert not np.isnan(rad).any()  # the input is not changed
