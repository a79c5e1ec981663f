"""``reroom invert``: the pipeline's wiring, outputs and bad-input messages."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from reroom.errors import ScanError
from reroom.invert.pipeline import InvertOptions, run_invert
from reroom.invert.solve import SolveOptions
from reroom.io.mesh import read_ply, write_ply


def _box_scan(root: Path, radiance: float = 0.3) -> Path:
    """A closed 3 x 2.5 x 2.4 m room, seen from inside, glowing uniformly."""
    box = trimesh.creation.box(extents=(3.0, 2.5, 2.4))
    box.apply_translation((1.5, 1.25, 1.2))
    for _ in range(4):
        box = box.subdivide()
    box.invert()  # normals into the room
    nv = len(box.vertices)
    scan = root / "scan"
    (scan / "hdr").mkdir(parents=True)
    (scan / "layout").mkdir()
    write_ply(
        scan / "hdr" / "hdr_mesh.ply",
        box,
        {
            "radiance": np.full((nv, 3), radiance, np.float32),
            "observed": np.ones(nv, np.uint8),
        },
    )
    z = box.vertices[:, 2]
    label = np.zeros(nv, np.uint8)
    label[z < 1e-6] = 1
    label[z > 2.4 - 1e-6] = 2
    write_ply(scan / "layout" / "layout_labels.ply", box, {"label": label})
    return scan


FAST = InvertOptions(rays_per_receiver=64, receiver_voxel=0.25, pictures=False)


def _spy_on_solve_blocks(monkeypatch: pytest.MonkeyPatch) -> dict:
    """The light blocks of every solve the pipeline runs, by name (the latest kept)."""
    import reroom.invert.pipeline as pipeline

    seen: dict = {}
    solve = pipeline.solve_lighting

    def spy(problem, *args, **kwargs):
        seen.update({b.name: b for b in problem.lights})
        return solve(problem, *args, **kwargs)

    monkeypatch.setattr(pipeline, "solve_lighting", spy)
    return seen


def test_closed_uniform_room_without_lights_has_white_walls(tmp_path: Path) -> None:
    # with no emitter, uniform radiance in a closed room means E_ind = pi L: albedo 1
    scan = _box_scan(tmp_path)
    result = run_invert(scan, options=FAST)
    assert any("lights.json is missing" in w for w in result.warnings)
    np.testing.assert_allclose(result.solve.albedo, 1.0, atol=0.03)
    out = scan / "invert"
    scene = json.loads((out / "scene.json").read_text())
    assert scene["format"] == "reroom-invert" and scene["lights"] == []
    assert [m["name"] for m in scene["materials"]] == ["wall", "floor", "ceiling"]
    mesh = read_ply(out / scene["albedo_file"])
    attrs = mesh.vertex_attributes
    keys = ("albedo", "in_cluster", "solved_per_vertex", "nonphysical", "unobserved")
    for key in (*keys, "near_geometry"):
        assert key in attrs
    # every vertex is solved, except those on the room's edges (a seam: the neighbouring
    # surface blocks their hemisphere at distance 0), which are left out and flagged
    near = np.asarray(attrs["near_geometry"]).astype(bool)
    p = np.asarray(mesh.vertices)
    on_bounds = (np.isclose(p, 0) | np.isclose(p, (3.0, 2.5, 2.4))).sum(axis=1)
    assert near.any() and np.all(on_bounds[near] >= 2)
    assert np.all(near | (on_bounds >= 2) | np.asarray(attrs["in_cluster"]).astype(bool))
    assert not np.any(near & np.asarray(attrs["in_cluster"]).astype(bool))
    report = json.loads((out / "report.json").read_text())
    assert report["vertices"]["in_cluster"] + report["vertices"]["near_geometry"] == len(p)


def test_missing_inputs_name_the_file(tmp_path: Path) -> None:
    scan = _box_scan(tmp_path)
    (scan / "layout" / "layout_labels.ply").unlink()
    with pytest.raises(ScanError, match="layout_labels.ply: is missing"):
        run_invert(scan, options=FAST)
    with pytest.raises(ScanError, match="hdr_mesh.ply: is missing"):
        run_invert(tmp_path / "nowhere", options=FAST)


def test_unobserved_cluster_is_reported_and_marked_partial(tmp_path: Path) -> None:
    scan = _box_scan(tmp_path)
    mesh = read_ply(scan / "hdr" / "hdr_mesh.ply")
    observed = np.ones(len(mesh.vertices), np.uint8)
    observed[mesh.vertices[:, 2] > 2.4 - 1e-6] = 0  # nobody looked up
    write_ply(
        scan / "hdr" / "hdr_mesh.ply",
        mesh,
        {"radiance": mesh.vertex_attributes["radiance"], "observed": observed},
    )
    result = run_invert(scan, options=FAST)
    assert np.isnan(result.solve.albedo[2]).all()
    assert any("'ceiling' has no observed vertex" in w for w in result.warnings)
    scene = json.loads((scan / "invert" / "scene.json").read_text())
    assert scene["complete"] is False
    assert scene["materials"][2] == {"name": "ceiling", "albedo": None, "solved": False}


def test_fill_poorly_seen_bins():
    from reroom.invert.export import fill_poorly_seen

    profile = np.array([1.0, 2.0, 50.0, 4.0, 7.0, 9.0])
    support = np.array([10.0, 10.0, 0.01, 10.0, 0.0, 10.0])
    out = fill_poorly_seen(profile, support, 0.01)
    # bin 2: seen by almost nothing -> between its well-seen neighbours; bin 4: unseen -> 0
    np.testing.assert_allclose(out, [1.0, 2.0, 3.0, 4.0, 0.0, 9.0])
    np.testing.assert_allclose(fill_poorly_seen(profile, np.full(6, 1.0), 0.01), profile)
    np.testing.assert_allclose(fill_poorly_seen(profile, np.zeros(6), 0.01), profile)
    with pytest.raises(ValueError, match="differ"):
        fill_poorly_seen(profile, support[:3], 0.01)


def test_window_cells_fill_poorly_seen_and_unseen_cells():
    from types import SimpleNamespace

    from reroom.invert.basis import CubemapBasis
    from reroom.invert.export import fill_poorly_seen, window_cells

    basis = CubemapBasis(2)
    cells = np.tile([[1.0, 2.0, 3.0]], (basis.size, 1))
    support = np.full(basis.size, 5.0)
    cells[7] = 600.0  # a cell barely seen (one grazing receiver) solved far too bright
    support[7] = 0.01
    support[11] = 0.0  # and one no receiver sees
    cells[11] = 0.0
    result = SimpleNamespace(solve=SimpleNamespace(intensities={"w": cells}), cubemap_n=2)
    got = window_cells(result, "w", support, 0.01)
    # Both get the harmonic fill of their well-seen neighbours (here all equal): a window's
    # unseen cell is still sky, unlike a light's hidden bin, which stays 0.
    np.testing.assert_allclose(got, np.tile([[1.0, 2.0, 3.0]], (basis.size, 1)))
    np.testing.assert_allclose(window_cells(result, "w", None, 0.01), cells)
    pairs = basis.adjacency()
    assert fill_poorly_seen(cells[:, 0], support, 0.01, pairs)[11] == 0.0
    with pytest.raises(ValueError, match="unseen"):
        fill_poorly_seen(cells[:, 0], support, 0.01, pairs, "nearest")


def test_fill_poorly_seen_on_a_graph():
    from reroom.invert.basis import LineBasis
    from reroom.invert.export import fill_poorly_seen

    # On a chain the harmonic fill is the linear interpolation of the 1D rule.
    profile = np.array([1.0, 2.0, 50.0, 4.0, 7.0, 9.0, 30.0])
    support = np.array([10.0, 10.0, 0.01, 10.0, 0.0, 10.0, 0.02])
    chain = np.stack([np.arange(6), np.arange(1, 7)], axis=1)
    np.testing.assert_allclose(
        fill_poorly_seen(profile, support, 0.01, chain), fill_poorly_seen(profile, support, 0.01)
    )
    # A (theta, phi) grid: a poorly seen bin takes the mean of its well-seen neighbours.
    basis = LineBasis(3, 3)
    grid = np.arange(9.0).reshape(3, 3) ** 2
    sup = np.full((3, 3), 5.0)
    sup[1, 1] = 0.001  # poorly seen
    sup[0, 0] = 0.0  # unseen: 0
    out = fill_poorly_seen(grid.ravel(), sup.ravel(), 0.01, basis.adjacency()[0]).reshape(3, 3)
    assert out[1, 1] == pytest.approx((grid[0, 1] + grid[2, 1] + grid[1, 0] + grid[1, 2]) / 4)
    assert out[0, 0] == 0.0
    keep = sup > 0.01
    np.testing.assert_array_equal(out[keep], grid[keep])


def test_line_light_power_with_phi_bins():
    from reroom.invert.basis import LineBasis
    from reroom.invert.export import line_light_power, line_profile_grid

    # A bare tube (i = 2 r L everywhere): pi^2 * length * i, whatever the bins.
    assert line_light_power(np.full(32, 0.4), 1.2) == pytest.approx(np.pi**2 * 1.2 * 0.4)
    for fold in (True, False):
        p = line_light_power(np.full((32 * 4, 3), 0.4), 1.2, 4, fold)
        np.testing.assert_allclose(p, np.pi**2 * 1.2 * 0.4)
    # A profile constant in phi has the separable model's power.
    theta_prof = np.linspace(0.0, 2.0, 16)
    two = np.repeat(theta_prof, 5)
    assert line_light_power(two, 2.0, 5) == pytest.approx(line_light_power(theta_prof, 2.0))
    # Power weights: the phi bin nearest the axis carries the least.
    w = LineBasis(4, 4).power_weights().reshape(4, 4)
    assert np.all(np.diff(w, axis=1) < 0)
    with pytest.raises(ValueError, match="multiple"):
        line_light_power(np.ones(10), 1.0, 4)
    # scene.json readers: the 2D layout and the 1D profile of older files.
    grid, fold = line_profile_grid({"profile": [[1, 2], [3, 4]], "phi_bins": 2, "phi_fold": False})
    assert grid.shape == (2, 2) and fold is False
    grid, fold = line_profile_grid({"basis": "inclination", "bins": 3, "profile": [1, 2, 3]})
    assert grid.shape == (3, 1) and fold is True
    with pytest.raises(ValueError, match="expected"):
        line_profile_grid({"profile": [[1, 2, 3]], "phi_bins": 2})


@pytest.mark.parametrize("phi_bins", [1, 3])
def test_line_light_outputs(tmp_path: Path, phi_bins: int) -> None:
    from reroom.invert.export import line_light_power, line_profile_grid
    from reroom.io.ies import read_ies
    from reroom.lights.lightset import Light, LightSet, write_lights

    scan = _box_scan(tmp_path)
    nv = len(read_ply(scan / "hdr" / "hdr_mesh.ply").vertices)
    geom = {"p0": [1.0, 1.25, 2.2], "p1": [2.0, 1.25, 2.2], "d_perp": [0, 0, 1.0], "radius": 0.02}
    tube = Light("tube", "line", "user", geom, {}, "test")
    write_lights(LightSet([tube], [], np.full(nv, -1, np.int32)), scan / "lights")
    opts = InvertOptions(rays_per_receiver=64, receiver_voxel=0.25, bins=8, line_phi_bins=phi_bins)
    result = run_invert(scan, None, opts)
    block = result.lights[0]
    assert block.size == 8 * phi_bins and len(block.adjacency) == len(block.adjacency_weights)
    doc = json.loads((scan / "invert" / "scene.json").read_text())
    dist = doc["lights"][0]["distribution"]
    assert dist["basis"] == "line" and dist["bins"] == 8 and dist["phi_bins"] == phi_bins
    grid, fold = line_profile_grid(dist)
    assert grid.shape == (8, phi_bins) and fold is True
    assert np.asarray(dist["support"]).shape == (8, phi_bins)
    assert np.asarray(dist["profile_solved"]).shape == (8, phi_bins)
    # The renderer needs the clearance the profile was solved with (reroom.edit.model).
    assert dist["shadow_clearance"] == opts.line_clearance
    # The shape prior's open fraction: a bare tube in an empty box is open everywhere
    # but steeply towards the ceiling 0.2 m above it, within the fixture's reach.
    open_frac = np.asarray(dist["open_fraction"])
    assert open_frac.shape == (8, phi_bins) and dist["tube_radius"] == 0.02
    assert np.all(open_frac[4:] == 1.0) and np.all(open_frac >= 0)
    assert block.shape is not None and block.shape_weight == opts.line_shape_prior > 0
    color = np.asarray(doc["lights"][0]["color"])
    np.testing.assert_allclose(
        doc["lights"][0]["power"], line_light_power(grid.ravel(), 1.0, phi_bins) * color
    )
    ies = read_ies(scan / "invert" / doc["lights"][0]["ies"])
    # vertical angle 0 is the nadir: theta = pi, phi = 0
    np.testing.assert_allclose(ies.candela[:, 0], grid[-1, 0], rtol=1e-5)
    assert ies.candela.max() <= grid.max() * (1 + 1e-5)
    assert (scan / "invert" / "gonio_tube.png").is_file()


def _lit_box_scan(root: Path, light: np.ndarray, albedo: float = 0.6) -> Path:
    """``_box_scan`` whose radiance is an isotropic point light's direct light only."""
    from reroom.invert.basis import InclinationBasis
    from reroom.invert.direct import point_light_transfer
    from reroom.rays import RayCaster

    scan = _box_scan(root)
    mesh = read_ply(scan / "hdr" / "hdr_mesh.ply")
    normals = np.asarray(mesh.vertex_normals)  # into the room (the box is inverted)
    f = point_light_transfer(
        RayCaster(mesh), mesh.vertices, normals, light, [0, 0, 1], InclinationBasis(1)
    )[:, 0]
    radiance = np.repeat((albedo / np.pi * 5.0 * f)[:, None], 3, axis=1)
    write_ply(
        scan / "hdr" / "hdr_mesh.ply",
        mesh,
        {"radiance": radiance.astype(np.float32), "observed": np.ones(len(f), np.uint8)},
    )
    return scan


@pytest.mark.parametrize("refine", [True, False])
def test_point_light_refined_towards_the_light_that_lit_the_room(
    tmp_path: Path, refine: bool
) -> None:
    from reroom.lights.lightset import Light, LightSet, write_lights

    truth = np.array([1.4, 1.1, 1.7])
    scan = _lit_box_scan(tmp_path, truth)
    nv = len(read_ply(scan / "hdr" / "hdr_mesh.ply").vertices)
    given = truth + np.array([0.1, 0.07, 0.0])
    lamp = Light(
        "lamp", "point", "user", {"position": given.tolist(), "axis": [0, 0, 1.0]}, {}, "t"
    )
    write_lights(LightSet([lamp], [], np.full(nv, -1, np.int32)), scan / "lights")
    opts = InvertOptions(
        rays_per_receiver=16, receiver_voxel=0.25, pictures=False, refine_points=refine
    )
    result = run_invert(scan, None, opts)
    doc = json.loads((scan / "invert" / "scene.json").read_text())
    entry = doc["lights"][0]
    found = np.asarray(entry["geometry"]["position"])
    assert entry["distribution"]["shadow_clearance"] == opts.point_clearance
    if refine:
        assert entry["position_refinement"]["kept"]
        # Given 0.12 m off; across the room it lands on the truth, the height trades a
        # little against the free 32-bin profile.
        assert np.linalg.norm(found[:2] - truth[:2]) < 0.01
        assert np.linalg.norm(found - truth) < 0.04
        assert any("point lights moved" in w for w in result.warnings)
        assert entry["position_refinement"]["cost_end"] < entry["position_refinement"]["cost_start"]
    else:
        np.testing.assert_allclose(found, given)
        assert "position_refinement" not in entry


def test_a_light_held_by_the_ceiling_stays_near_it_in_the_refinement(tmp_path: Path) -> None:
    """``evidence["mounted_on"]`` (localize's mount test) bounds how far the refinement
    takes a light below the surface holding it, even where the photos' light is lower."""
    from reroom.lights.lightset import Light, LightSet, write_lights

    truth = np.array([1.4, 1.1, 1.7])
    scan = _lit_box_scan(tmp_path, truth)
    nv = len(read_ply(scan / "hdr" / "hdr_mesh.ply").vertices)
    given = truth + np.array([0.05, 0.0, 0.2])
    evidence = {"mounted_on": {"surface_z": 2.0, "reason": "test"}}
    lamp = Light(
        "lamp", "point", "localize", {"position": given.tolist(), "axis": [0, 0, 1.0]},
        evidence, "t",
    )  # fmt: skip
    write_lights(LightSet([lamp], [], np.full(nv, -1, np.int32)), scan / "lights")
    found = {}
    for drop in (0.1, -1.0):
        opts = InvertOptions(
            rays_per_receiver=16, receiver_voxel=0.25, pictures=False, refine_mounted_drop=drop
        )
        run_invert(scan, tmp_path / f"inv{drop}", opts)
        doc = json.loads((tmp_path / f"inv{drop}" / "scene.json").read_text())
        entry = doc["lights"][0]
        found[drop] = np.asarray(entry["geometry"]["position"])
        assert ("lowest_z" in entry["position_refinement"]) == (drop >= 0)
    # Bounded: no lower than 0.1 m under the surface, where it started.
    assert found[0.1][2] >= 1.9 - 1e-6
    # Unbounded, the same data take it down towards the light that lit the room.
    assert found[-1.0][2] < 1.88


def test_a_light_placed_from_its_pool_edge_is_not_refined(tmp_path: Path) -> None:
    """A bulb ``reroom lights`` placed from its ceiling pool's edge (millimetres, from the
    rim and similar triangles) keeps that place; the same light from localization is
    refined towards the photos' light."""
    from reroom.lights.lightset import Light, LightSet, write_lights

    truth = np.array([1.4, 1.1, 1.7])
    scan = _lit_box_scan(tmp_path, truth)
    nv = len(read_ply(scan / "hdr" / "hdr_mesh.ply").vertices)
    given = truth + np.array([0.05, 0.0, 0.2])
    found = {}
    for how in ("pool edge", None):
        evidence = {"height_from": how} if how else {}
        lamp = Light(
            "lamp", "point", "localize", {"position": given.tolist(), "axis": [0, 0, 1.0]},
            evidence, "t",
        )  # fmt: skip
        write_lights(LightSet([lamp], [], np.full(nv, -1, np.int32)), scan / "lights")
        opts = InvertOptions(rays_per_receiver=16, receiver_voxel=0.25, pictures=False)
        run_invert(scan, tmp_path / f"inv{how}", opts)
        entry = json.loads((tmp_path / f"inv{how}" / "scene.json").read_text())["lights"][0]
        found[how] = (np.asarray(entry["geometry"]["position"]), entry["position_refinement"])
    pos, ref = found["pool edge"]
    np.testing.assert_allclose(pos, given)
    assert "pool" in ref["skipped"] and not ref["kept"]
    pos, ref = found[None]
    assert np.linalg.norm(pos - given) > 0.05 and ref["kept"]


def test_a_malformed_mount_record_is_ignored_with_a_note() -> None:
    from reroom.invert.pipeline import _mounted_surfaces
    from reroom.lights.lightset import Light

    def lamp(name: str, evidence: dict) -> Light:
        return Light(
            name, "point", "user", {"position": [1, 1, 2], "axis": [0, 0, 1]}, evidence, ""
        )

    notes: list[str] = []
    got = _mounted_surfaces(
        [
            lamp("good", {"mounted_on": {"surface_z": 2.7}}),
            lamp("nan", {"mounted_on": {"surface_z": float("nan")}}),
            lamp("text", {"mounted_on": "ceiling"}),
            lamp("none", {}),
        ],
        notes,
    )
    assert got == {"good": 2.7}
    assert len(notes) == 2 and "'nan'" in notes[0] and "'text'" in notes[1]
    assert all("without the mount's bound" in n for n in notes)


def _sunny_box_scan(root: Path, sun: np.ndarray | None, e_sun: float = 4.0) -> Path:
    """``_box_scan`` with a window on the wall y = 0 and, if ``sun``, its sunlit patch."""
    from reroom.invert.sun import sun_transfer
    from reroom.invert.windows import WindowOpening
    from reroom.lights.lightset import Light, LightSet, write_lights
    from reroom.rays import RayCaster

    scan = _box_scan(root, radiance=0.05)
    mesh = read_ply(scan / "hdr" / "hdr_mesh.ply")
    geometry = {
        "centre": [1.5, 0.0, 1.4],
        "half_u": [0.6, 0.0, 0.0],
        "half_v": [0.0, 0.0, 0.5],
        "normal": [0.0, 1.0, 0.0],
    }
    radiance = np.full((len(mesh.vertices), 3), 0.05)
    if sun is not None:
        # The closed wall lies in the opening's plane, which the rays stop short of.
        window = WindowOpening("w", **geometry)
        normals = np.asarray(mesh.vertex_normals)  # into the room (the box is inverted)
        f = sun_transfer(RayCaster(mesh), window, sun, mesh.vertices, normals)
        radiance += (0.5 / np.pi * e_sun * f)[:, None]
    write_ply(
        scan / "hdr" / "hdr_mesh.ply",
        mesh,
        {"radiance": radiance.astype(np.float32), "observed": np.ones(len(radiance), np.uint8)},
    )
    win = Light("window0", "window", "layout", geometry, {}, "test window")
    write_lights(LightSet([win], [], np.full(len(radiance), -1, np.int32)), scan / "lights")
    return scan


@pytest.mark.parametrize("sunny", [True, False])
def test_a_sun_through_the_window_is_found_solved_and_drawn(tmp_path: Path, sunny: bool) -> None:
    from reroom.invert.window_env import latlong_solid_angles
    from reroom.io.images import read_exr

    sun = np.array([0.3, -0.6, 0.74]) / np.linalg.norm([0.3, -0.6, 0.74])
    scan = _sunny_box_scan(tmp_path, sun if sunny else None)
    result = run_invert(scan, None, FAST)
    entry = json.loads((scan / "invert" / "scene.json").read_text())["lights"][0]
    assert entry["type"] == "window" and len(entry["distribution"]["cells"]) == 96
    env = read_exr(scan / "invert" / entry["environment_exr"])[..., :3]
    if not sunny:
        assert "sun" not in entry and not any("a sun found" in w for w in result.warnings)
        return
    found = entry["sun"]
    assert np.degrees(np.arccos(min(1.0, float(np.dot(found["direction"], sun))))) < 1.5
    # The patch is solved with the sun's own sharp transfer. The data fix albedo x
    # irradiance (0.5 x 4 on the floor): the uniform rest of this room reads as albedo 1,
    # as in the closed white room above, so the sun comes back as about 2.
    floor = result.solve.albedo[1]
    np.testing.assert_allclose(floor * np.asarray(found["irradiance"]), 2.0, rtol=0.1)
    assert any("a sun found" in w for w in result.warnings)
    # Its level is taken where it lights fully (eq. 5.8 weighs those receivers little).
    assert any("receivers it lights fully" in w for w in result.warnings)
    # The rendering map sends the sun's irradiance along its direction, from one texel.
    flux = (env * latlong_solid_angles(env.shape[0])[..., None]).reshape(-1, 3)
    assert env.shape[0] >= 256
    assert flux.max(axis=0) == pytest.approx(np.asarray(found["irradiance"]), rel=1e-3)


def test_window_smoothness_reaches_the_solve_and_bad_values_are_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:

    for bad in (-1.0, float("nan")):
        with pytest.raises(ValueError, match="window_smooth"):
            run_invert(tmp_path / "nothing_here", None, InvertOptions(window_smooth=bad))
        with pytest.raises(ValueError, match="normal_radius"):
            run_invert(tmp_path / "nothing_here", None, InvertOptions(normal_radius=bad))
    # the photos' lower bounds need the joint solver: refused before any work
    alternating = InvertOptions(window_photo_bounds=True, solve=SolveOptions(method="alternating"))
    with pytest.raises(ValueError, match="window_photo_bounds needs the joint solver"):
        run_invert(tmp_path / "nothing_here", None, alternating)
    assert not (tmp_path / "nothing_here").exists()

    seen = _spy_on_solve_blocks(monkeypatch)
    scan = _sunny_box_scan(tmp_path / "w", None)
    opts = dataclasses.replace(FAST, window_smooth=1e3, window_sun=False)
    result = run_invert(scan, None, opts)
    window = seen["window0"]
    assert window.adjacency_weights is not None
    np.testing.assert_allclose(window.adjacency_weights, 1e3)
    assert len(window.adjacency_weights) == len(window.adjacency)
    # Smoother cells: the jumps between neighbouring cells are smaller than at the
    # default weight (the same problem solved again).
    again = run_invert(scan, tmp_path / "w_default", dataclasses.replace(opts, window_smooth=1.0))
    i, j = window.adjacency[:, 0], window.adjacency[:, 1]
    jumps = [
        np.abs(c[i] - c[j]).sum()
        for c in (np.asarray(r.solve.intensities["window0"], float) for r in (result, again))
    ]
    assert jumps[0] < 0.9 * jumps[1], jumps


def test_normal_radius_gives_the_transfer_smoothed_normals(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import reroom.invert.pipeline as pipeline
    from reroom.invert.normals import smoothed_vertex_normals

    # the glowing box with its vertices jittered along their normals, as a fused scan
    scan = _box_scan(tmp_path)
    mesh = read_ply(scan / "hdr" / "hdr_mesh.ply")
    rng = np.random.default_rng(5)
    ring = np.asarray(trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).vertex_normals)
    jittered = np.asarray(mesh.vertices) + ring * rng.normal(0, 0.004, (len(ring), 1))
    noisy = trimesh.Trimesh(jittered, mesh.faces, process=False)
    attrs = {k: np.asarray(v) for k, v in mesh.vertex_attributes.items()}
    write_ply(scan / "hdr" / "hdr_mesh.ply", noisy, attrs)
    labels = read_ply(scan / "layout" / "layout_labels.ply")
    write_ply(scan / "layout" / "layout_labels.ply", noisy, dict(labels.vertex_attributes))

    seen = {}
    transfer = pipeline.hemisphere_transfer

    def spy(caster, m, sub, normals, *args, **kwargs):
        seen["normals"] = np.array(normals)
        return transfer(caster, m, sub, normals, *args, **kwargs)

    monkeypatch.setattr(pipeline, "hemisphere_transfer", spy)
    run_invert(scan, tmp_path / "smooth", dataclasses.replace(FAST, normal_radius=0.5))
    expected = smoothed_vertex_normals(read_ply(scan / "hdr" / "hdr_mesh.ply"), 0.5)
    np.testing.assert_allclose(seen["normals"], expected)
    report = json.loads((tmp_path / "smooth" / "report.json").read_text())
    assert report["options"]["normal_radius"] == 0.5
    run_invert(scan, tmp_path / "ring", FAST)
    assert not np.allclose(seen["normals"], expected)


def test_photo_colours_reach_the_solve_and_scene_json(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``photo_color``: the tube's and the panel's colours from the photos (stubbed here:
    the measurement is tested in test_invert_emitter_color.py) become the solve's colour
    priors, the panel is solved as colour x scalar, and scene.json records the colours;
    a colour the photos cannot give leaves the light to the solve, with a note."""
    import reroom.invert.pipeline as pipeline
    from reroom.invert.emitter_color import EmitterColor
    from reroom.lights.lightset import Light, LightSet, write_lights

    for bad in (-1.0, float("nan")):
        with pytest.raises(ValueError, match="photo_color must be >= 0"):
            run_invert(tmp_path / "nothing_here", None, InvertOptions(photo_color=bad))
    alternating = InvertOptions(photo_color=1.0, solve=SolveOptions(method="alternating"))
    with pytest.raises(ValueError, match="photo_color needs the joint solver"):
        run_invert(tmp_path / "nothing_here", None, alternating)

    scan = _box_scan(tmp_path, radiance=0.3)
    nv = len(read_ply(scan / "hdr" / "hdr_mesh.ply").vertices)
    geom = {"p0": [1.0, 1.25, 2.2], "p1": [2.0, 1.25, 2.2], "d_perp": [0, 0, 1.0], "radius": 0.02}
    panel_geom = {
        "centroid": [1.5, 0.6, 2.39], "normal": [0, 0, -1.0], "area": 0.16, "size": [0.4, 0.4],
        "axis_long": [1.0, 0, 0], "axis_short": [0, 1.0, 0],
    }  # fmt: skip
    lights = [
        Light("tube", "line", "user", geom, {}, "test"),
        Light("panel", "area", "user", panel_geom, {}, "test"),
    ]
    write_lights(LightSet(lights, [], np.full(nv, -1, np.int32)), scan / "lights")
    measured = {
        "tube": np.array([0.9, 1.0, 1.1]),
        "panel": np.array([1.1, 1.0, 0.9]),
    }

    def fake_color(scan_dir, name, points, facing, caster, notes):
        assert points.shape[1] == 3 and len(points) > 5
        if name not in measured:
            return None
        return EmitterColor(measured[name], np.full(3, 0.005), 200, 10)

    monkeypatch.setattr(pipeline, "_photo_color", fake_color)
    seen = _spy_on_solve_blocks(monkeypatch)
    opts = dataclasses.replace(FAST, bins=8, photo_color=100.0)
    result = run_invert(scan, None, opts)
    doc = json.loads((scan / "invert" / "scene.json").read_text())
    by_name = {e["name"]: e for e in doc["lights"]}
    for name, color in measured.items():
        block = seen[name]
        assert block.monochrome and block.color_prior_weight == 100.0
        np.testing.assert_allclose(block.color_prior, color)
        assert by_name[name]["color_from_photos"]["color"] == pytest.approx(color.tolist())
        unit = color / np.linalg.norm(color)
        np.testing.assert_allclose(result.solve.colors[name], unit, atol=2e-3)
    # without the option: no prior, the panel chromatic, no record
    plain = run_invert(scan, tmp_path / "plain", dataclasses.replace(FAST, photo_color=0.0))
    assert not seen["panel"].monochrome and seen["tube"].color_prior_weight == 0.0
    doc = json.loads((tmp_path / "plain" / "scene.json").read_text())
    assert not any("color_from_photos" in e for e in doc["lights"])
    assert plain.solve is not None
    # a colour the photos cannot give: no prior for that light
    measured.pop("panel")
    run_invert(scan, tmp_path / "half", opts)
    assert not seen["panel"].monochrome and seen["tube"].color_prior_weight == 100.0
    # nor one that varies too much between frames (_photo_color's gate)
    noisy = EmitterColor(np.array([0.9, 1.0, 1.1]), np.array([0.01, 0.01, 0.03]), 200, 10)
    notes: list[str] = []
    assert pipeline._checked_photo_color("tube", noisy, notes) is None
    assert "varies by +-3.0 %" in notes[-1], notes
    good = EmitterColor(np.array([0.9, 1.0, 1.1]), np.full(3, 0.01), 200, 10)
    assert pipeline._checked_photo_color("tube", good, notes) is good
    assert pipeline._checked_photo_color("tube", None, notes) is None
    assert "too few unsaturated pixels" in notes[-1]


def test_photo_colours_from_a_scan_without_photos_or_axes_leave_a_note(tmp_path: Path) -> None:
    """No frames or exposures to read, or an area light without its axes: the solve keeps
    each light's own colour, and the notes say why, naming what is missing."""
    from reroom.lights.lightset import Light, LightSet, write_lights

    scan = _box_scan(tmp_path, radiance=0.3)
    nv = len(read_ply(scan / "hdr" / "hdr_mesh.ply").vertices)
    geom = {"p0": [1.0, 1.25, 2.2], "p1": [2.0, 1.25, 2.2], "d_perp": [0, 0, 1.0], "radius": 0.02}
    panel = {"centroid": [1.5, 0.6, 2.39], "normal": [0, 0, -1.0], "area": 0.16}
    lights = [
        Light("tube", "line", "user", geom, {}, "test"),
        Light("panel", "area", "user", panel, {}, "test"),
    ]
    write_lights(LightSet(lights, [], np.full(nv, -1, np.int32)), scan / "lights")
    result = run_invert(scan, None, dataclasses.replace(FAST, bins=8, photo_color=1.0))
    notes = [w for w in result.warnings if "no colour from the photos" in w]
    assert any("'tube'" in w and "transforms.json" in w for w in notes), notes
    assert any("'panel'" in w and "axis_long" in w for w in notes), notes
    assert not any(b.color_prior_weight > 0 for b in result.lights)
    doc = json.loads((scan / "invert" / "scene.json").read_text())
    assert not any("color_from_photos" in e for e in doc["lights"])


def test_render_window_cells_give_the_renders_a_finer_window(tmp_path: Path) -> None:
    from reroom.io.images import read_exr

    for bad in (-1, -8):
        with pytest.raises(ValueError, match="render_window_cells"):
            run_invert(tmp_path / "nothing_here", None, InvertOptions(render_window_cells=bad))
    with pytest.raises(ValueError, match="render_window_smooth"):
        run_invert(tmp_path / "nothing_here", None, InvertOptions(render_window_smooth=-1.0))
    assert not (tmp_path / "nothing_here").exists()

    scan = _sunny_box_scan(tmp_path / "w", None)
    opts = dataclasses.replace(FAST, window_sun=False, render_window_cells=0)
    coarse = run_invert(scan, tmp_path / "coarse", opts)
    fine = run_invert(scan, tmp_path / "fine", dataclasses.replace(opts, render_window_cells=8))
    assert coarse.render_windows == {} and set(fine.render_windows) == {"window0"}
    # the solve itself, and every figure scene.json evaluates, are the coarse solve's
    np.testing.assert_array_equal(
        fine.solve.intensities["window0"], coarse.solve.intensities["window0"]
    )
    np.testing.assert_array_equal(fine.solve.albedo, coarse.solve.albedo)
    entries = {}
    for name in ("coarse", "fine"):
        scene = json.loads((tmp_path / name / "scene.json").read_text())
        entries[name] = scene["lights"][0]
    assert "render_distribution" not in entries["coarse"]
    assert entries["fine"]["distribution"] == entries["coarse"]["distribution"]
    assert entries["fine"]["power"] == entries["coarse"]["power"]
    render = entries["fine"]["render_distribution"]
    assert render["n"] == 8 and len(render["cells"]) == 6 * 64 and len(render["support"]) == 384
    assert render["objective"] <= render["objective_at_solved_cells"] * (1 + 1e-9)
    assert render["photo_bounds"] == {"cells": 0}  # no photos in this scan to bound it
    # the renders' map is the fine one, the cells' picture the coarse one
    env = read_exr(tmp_path / "fine" / entries["fine"]["environment_exr"])[..., :3]
    cells = read_exr(tmp_path / "fine" / entries["fine"]["environment_cells_exr"])[..., :3]
    same = read_exr(tmp_path / "coarse" / entries["coarse"]["environment_cells_exr"])[..., :3]
    np.testing.assert_allclose(cells, same)
    assert not np.allclose(env, cells)
    # the per-vertex albedos were divided by the fine model's irradiance
    assert any("render window window0: refitted" in w for w in fine.warnings)
    seen = np.isfinite(fine.albedo).all(axis=1) & np.isfinite(coarse.albedo).all(axis=1)
    assert seen.sum() > 100 and not np.allclose(fine.albedo[seen], coarse.albedo[seen])


def test_an_area_light_is_the_outline_of_its_vertices(tmp_path: Path) -> None:
    """``area_outline``: scene.json gives the area light its vertices' convex outline on
    its plane, counts its power over the outline's area and keeps the lights stage's area;
    without the option the geometry is the lights stage's."""
    from scipy.spatial import ConvexHull

    from reroom.lights.lightset import Light, LightSet, write_lights

    scan = _box_scan(tmp_path, radiance=0.3)
    v = np.asarray(read_ply(scan / "hdr" / "hdr_mesh.ply").vertices)
    on = (np.abs(v[:, 0] - 1.5) <= 0.5) & (np.abs(v[:, 1] - 1.25) <= 0.5) & (v[:, 2] > 2.4 - 1e-6)
    assert on.sum() >= 4
    geom = {"centroid": [1.5, 1.25, 2.4], "normal": [0.0, 0.0, -1.0], "area": 0.5}
    ids = np.where(on, 0, -1).astype(np.int32)
    write_lights(
        LightSet([Light("panel", "area", "user", geom, {}, "test")], [], ids), scan / "lights"
    )
    hull = ConvexHull(v[on][:, :2]).volume  # a 2-D hull's "volume" is its area
    run_invert(scan, None, dataclasses.replace(FAST, photo_color=0.0))
    doc = json.loads((scan / "invert" / "scene.json").read_text())
    panel = next(e for e in doc["lights"] if e["name"] == "panel")
    g = panel["geometry"]
    assert g["area"] == pytest.approx(hull, rel=1e-5) and g["area_of_vertices"] == 0.5
    outline = np.asarray(g["outline"])
    assert len(outline) >= 3
    np.testing.assert_allclose(outline[:, 2], 2.4, atol=1e-6)
    np.testing.assert_allclose(
        panel["power"], np.pi * np.asarray(panel["radiance"]) * hull, rtol=1e-4
    )
    run_invert(
        scan, tmp_path / "shares", dataclasses.replace(FAST, photo_color=0.0, area_outline=False)
    )
    doc = json.loads((tmp_path / "shares" / "scene.json").read_text())
    g = next(e for e in doc["lights"] if e["name"] == "panel")["geometry"]
    assert "outline" not in g and g["area"] == 0.5
