"""Area-light transfer by sampling the light (reroom.invert.area), issue #5 regression."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from meshes import grid_plane

from reroom.hdr.observe import vertex_normals
from reroom.invert import (
    InverseProblem,
    LightBlock,
    SolveOptions,
    area_light_transfer,
    hemisphere_transfer,
    solve_lighting,
)
from reroom.rays import RayCaster


def rect_ff(x0: float, x1: float, y0: float, y1: float, h: float) -> float:
    """``integral cos dw`` (= pi x form factor) of ``[x0, x1] x [y0, y1]`` at height ``h``.

    Seen from the origin facing up, the rectangle facing down (closed form per corner).
    """

    def corner(x: float, y: float) -> float:
        if x == 0 or y == 0:
            return 0.0
        a, b = abs(x) / h, abs(y) / h
        sa, sb = np.sqrt(1 + a * a), np.sqrt(1 + b * b)
        f = (a / sa * np.arctan(b / sa) + b / sb * np.arctan(a / sb)) / (2 * np.pi)
        return float(np.sign(x) * np.sign(y) * f)

    return np.pi * (corner(x1, y1) - corner(x0, y1) - corner(x1, y0) + corner(x0, y0))


def scene_with_light(light_half: float, light_x: float, h: float):
    """A 4 m floor (0.25 m grid) under a square light facing down; light vertex flags."""
    floor = grid_plane(2.0, 0.25)
    light = grid_plane(light_half, light_half / 2, z=h, up=False, x0=light_x)
    mesh = trimesh.util.concatenate([floor, light])
    on = np.zeros(len(mesh.vertices), bool)
    on[len(floor.vertices) :] = True
    recv = np.flatnonzero(~on & (np.abs(mesh.vertices[:, :2]).max(axis=1) <= 1.5))
    return mesh, on, recv


def expected_ff(mesh, recv, half: float, x0: float, h: float) -> np.ndarray:
    x, y = mesh.vertices[recv, 0], mesh.vertices[recv, 1]
    return np.array(
        [
            rect_ff(x0 - half - xi, x0 + half - xi, -half - yi, half - yi, h)
            for xi, yi in zip(x, y, strict=True)
        ]
    )


def _hemisphere_counts(caster, mesh, recv, nrm, on):
    """The old way: the area light's transfer from 512 hemisphere rays' hit counts."""
    nv = len(mesh.vertices)
    return hemisphere_transfer(
        caster,
        mesh,
        recv,
        nrm,
        np.zeros((nv, 3)),
        np.ones(nv, bool),
        np.where(on, 0, -1),
        [],
        None,
        rays_per_vertex=512,
        seed=1,
    )


def test_matches_rectangle_form_factor_per_vertex():
    half, h = 0.6, 1.0
    mesh, on, recv = scene_with_light(half, 0.0, h)
    caster = RayCaster(mesh)
    f = area_light_transfer(caster, mesh, on, mesh.vertices[recv], vertex_normals(mesh)[recv])
    # The light's vertices are all flagged, so its whole surface emits: the rectangle. A
    # 1.2 m light 1 m away is the hard case for 256 samples (1/d^2 varies 4x over it).
    expected = expected_ff(mesh, recv, half, 0.0, h)
    np.testing.assert_allclose(f, expected, rtol=0.05)
    assert abs(f.sum() / expected.sum() - 1) < 0.005
    again = area_light_transfer(caster, mesh, on, mesh.vertices[recv], vertex_normals(mesh)[recv])
    np.testing.assert_array_equal(f, again)  # seeded


def test_small_distant_light_per_vertex_where_hemisphere_rays_fail():
    """The issue #5 case: a 0.3 m light seen from 1-3 m covers ~1e-3 of the hemisphere."""
    half, h, x0 = 0.15, 2.5, 1.5
    mesh, on, recv = scene_with_light(half, x0, h)
    caster = RayCaster(mesh)
    nrm = vertex_normals(mesh)
    truth = expected_ff(mesh, recv, half, x0, h)
    sampled = area_light_transfer(caster, mesh, on, mesh.vertices[recv], nrm[recv])
    np.testing.assert_allclose(sampled, truth, rtol=0.02)
    hemi = _hemisphere_counts(caster, mesh, recv, nrm, on)
    # What the pipeline used before: unbiased on average, useless per vertex.
    assert abs(hemi.area[:, 0].sum() / truth.sum() - 1) < 0.15
    assert np.mean(hemi.area[:, 0] == 0) > 0.1
    assert np.median(np.abs(hemi.area[:, 0] / truth - 1)) > 0.3


def test_shadow_back_side_and_partial_light():
    half, h = 0.6, 1.0
    mesh, on, recv = scene_with_light(half, 0.0, h)
    # A slab at z = 0.5 over x in [-1.7, -0.1]: a segment from a floor point x to a light
    # point x_l (|x_l| <= 0.6, z = 1) crosses z = 0.5 at (x + x_l) / 2. All of the light is
    # hidden for x <= -0.8 and none of it for x >= 0.4 (0.1 m margins for the thickness).
    slab = trimesh.creation.box(extents=[1.6, 4.0, 0.05])
    slab.apply_translation([-0.9, 0.0, 0.5])
    scene = trimesh.util.concatenate([mesh, slab])
    on_s = np.concatenate([on, np.zeros(len(slab.vertices), bool)])
    caster = RayCaster(scene)
    nrm = vertex_normals(mesh)[recv]
    f = area_light_transfer(caster, scene, on_s, mesh.vertices[recv], nrm)
    x = mesh.vertices[recv, 0]
    dark = x <= -0.9
    assert dark.any() and np.all(f[dark] == 0)
    assert np.all(f[(x > -0.7) & (x < 0.3)] > 0)  # penumbra
    lit = x >= 0.5
    np.testing.assert_allclose(f[lit], expected_ff(mesh, recv[lit], half, 0.0, h), rtol=0.05)
    # Receivers facing away (normals flipped) and a light facing away get nothing.
    assert np.all(area_light_transfer(caster, scene, on_s, mesh.vertices[recv], -nrm) == 0)
    flipped = mesh.copy()
    flipped.faces[len(grid_plane(2.0, 0.25).faces) :] = flipped.faces[
        len(grid_plane(2.0, 0.25).faces) :, ::-1
    ]
    f_back = area_light_transfer(RayCaster(flipped), flipped, on, mesh.vertices[recv], nrm)
    assert np.all(f_back == 0)
    # Only the light's interior vertices flagged: it ends half-way into its rim triangles,
    # as hemisphere_transfer's barycentric shares do (grid step = half / 2: 5 x 5 nodes).
    v = mesh.vertices
    inner = on & (np.abs(v[:, 0]) < half - 1e-9) & (np.abs(v[:, 1]) < half - 1e-9)
    centre = recv[np.argmin(np.linalg.norm(v[recv, :2], axis=1))]
    f_in = area_light_transfer(
        RayCaster(mesh), mesh, inner, v[[centre]], vertex_normals(mesh)[[centre]], 4096
    )
    nv = len(v)
    hemi = hemisphere_transfer(
        RayCaster(mesh),
        mesh,
        [centre],
        vertex_normals(mesh),
        np.zeros((nv, 3)),
        np.ones(nv, bool),
        np.where(inner, 0, -1),
        [],
        None,
        rays_per_vertex=65536,
        seed=2,
    )
    assert f_in[0] == pytest.approx(hemi.area[0, 0], rel=0.02)
    assert f_in[0] < 0.9 * rect_ff(-half, half, -half, half, h)


def test_solve_with_sampled_transfer_recovers_albedo_and_power():
    """End to end on exact synthetic data: the noisy hemisphere column biased the solve."""
    half, h, x0 = 0.15, 2.5, 1.5
    mesh, on, recv = scene_with_light(half, x0, h)
    caster = RayCaster(mesh)
    nrm = vertex_normals(mesh)
    truth_f = expected_ff(mesh, recv, half, x0, h)
    rng = np.random.default_rng(0)
    rho, le = np.array([0.6, 0.5, 0.4]), 40.0
    # Indirect light comparable to the direct light, varying over the floor.
    e_ind = (0.5 + rng.random(len(recv)))[:, None] * np.array([1.0, 0.9, 0.8]) * truth_f.mean() * le
    radiance = rho / np.pi * (e_ind + truth_f[:, None] * le)

    def solve(column: np.ndarray):
        problem = InverseProblem(
            radiance=radiance,
            indirect=e_ind,
            cluster=np.zeros(len(recv), int),
            cluster_names=["floor"],
            transfer=column[:, None],
            lights=[LightBlock("panel", "area", 1)],
        )
        return solve_lighting(problem, SolveOptions(min_cluster_vertices=1))

    sampled = area_light_transfer(caster, mesh, on, mesh.vertices[recv], nrm[recv])
    res = solve(sampled)
    np.testing.assert_allclose(res.albedo[0], rho, rtol=0.02)
    np.testing.assert_allclose(res.intensities["panel"][0], le, rtol=0.03)
    hemi = _hemisphere_counts(caster, mesh, recv, nrm, on)
    biased = solve(hemi.area[:, 0])
    # The symptom of issue #5: albedo too high, light too dim.
    assert biased.albedo[0, 0] > rho[0] * 1.05
    assert biased.intensities["panel"][0, 0] < le * 0.9


def test_bad_input():
    mesh, on, recv = scene_with_light(0.6, 0.0, 1.0)
    caster = RayCaster(mesh)
    p, n = mesh.vertices[recv], vertex_normals(mesh)[recv]
    with pytest.raises(ValueError, match="light_vertices"):
        area_light_transfer(caster, mesh, on[:-1], p, n)
    with pytest.raises(ValueError, match="samples"):
        area_light_transfer(caster, mesh, on, p, n, 0)
    with pytest.raises(ValueError, match="non-zero"):
        area_light_transfer(caster, mesh, on, p, np.zeros_like(n))
    assert np.all(area_light_transfer(caster, mesh, np.zeros_like(on), p, n) == 0)


def fused_ceiling(h: float, light_half: float, step: float):
    """A floor under one ceiling surface (a grid facing down) whose vertices within
    ``light_half`` of the centre are the light's: a depth-fused panel, no piece of its
    own, so its rim triangles join it to the ceiling around it."""
    floor = grid_plane(2.0, 0.25)
    ceiling = grid_plane(1.2, step, z=h, up=False)
    mesh = trimesh.util.concatenate([floor, ceiling])
    on = np.zeros(len(mesh.vertices), bool)
    c = mesh.vertices[len(floor.vertices) :]
    on[len(floor.vertices) :] = np.abs(c[:, :2]).max(axis=1) <= light_half + 1e-9
    recv = np.flatnonzero(
        ~on & (mesh.vertices[:, 2] < 0.5) & (np.abs(mesh.vertices[:, :2]).max(1) <= 1.5)
    )
    return mesh, on, recv


def test_area_region_outline_and_containment():
    from reroom.invert.area_region import area_region

    rng = np.random.default_rng(3)
    pts = np.column_stack(
        [rng.uniform(-0.3, 0.3, 500), rng.uniform(-0.2, 0.2, 500), np.full(500, 2.7)]
    )
    pts[:4, :2] = [[-0.3, -0.2], [0.3, -0.2], [0.3, 0.2], [-0.3, 0.2]]
    region = area_region(pts, [0.0, 0.0, -1.0])
    assert region is not None
    assert region.area == pytest.approx(0.24, rel=1e-9)
    inside = region.contains(
        [[0.0, 0.0, 2.7], [0.29, 0.19, 2.5], [0.31, 0.0, 2.7], [0.0, -0.21, 2.7]]
    )
    np.testing.assert_array_equal(inside, [True, True, False, False])
    assert area_region(pts[:2], [0.0, 0.0, -1.0]) is None  # two points span no outline
    line = np.column_stack([np.linspace(0, 1, 5), np.zeros(5), np.full(5, 2.7)])
    assert area_region(line, [0.0, 0.0, -1.0]) is None


def test_clip_to_region_keeps_the_inside_on_each_face_in_its_winding():
    from reroom.invert.area_region import area_region, clip_to_region

    corners = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [1.0, 1.0, 1.0], [0.0, 1.0, 1.0]])
    region = area_region(corners, [0.0, 0.0, -1.0])
    # A tilted triangle half across the square's edge x = 1, wound to face down.
    tri = np.array([[0.5, 0.2, 1.0], [1.5, 0.8, 1.2], [1.5, 0.2, 1.2]])
    v, f = clip_to_region(tri, [[0, 1, 2]], region)
    piece = trimesh.Trimesh(v, f, process=False)
    whole = trimesh.Trimesh(tri, [[0, 1, 2]], process=False)
    # Inside: the part with x <= 1, on the triangle's own (tilted) plane.
    assert v[:, 0].max() <= 1.0 + 1e-9
    np.testing.assert_allclose((v - tri[0]) @ whole.face_normals[0], 0.0, atol=1e-12)
    flat_piece = piece.area * abs(piece.face_normals[:, 2]).mean()
    assert flat_piece == pytest.approx(0.5 * 0.5 * 0.3, rel=1e-9)  # its shadow on z: x 0.5-1
    assert np.all(piece.face_normals @ whole.face_normals[0] > 0.999)  # winding kept
    v2, f2 = clip_to_region(tri + [5.0, 0.0, 0.0], [[0, 1, 2]], region)
    assert len(v2) == 0 and len(f2) == 0


def test_a_fused_panel_emits_from_its_outline_not_half_its_rim():
    """The fused-scan case (docs/invert.md, "An area light's outline"): the light's
    vertices are a 0.6 m square of one ceiling surface; its barycentric share reaches half
    a rim triangle further (0.7 m at a 0.1 m grid), its outline is the square."""
    from reroom.invert.area_region import area_region

    h, half, step = 2.0, 0.3, 0.1
    mesh, on, recv = fused_ceiling(h, half, step)
    caster = RayCaster(mesh)
    nrm = vertex_normals(mesh)
    region = area_region(mesh.vertices[on], [0.0, 0.0, -1.0])
    assert region.area == pytest.approx(0.36, rel=1e-9)
    outlined = area_light_transfer(
        caster, mesh, on, mesh.vertices[recv], nrm[recv], 1024, region=region
    )
    shared = area_light_transfer(caster, mesh, on, mesh.vertices[recv], nrm[recv], 1024)
    expected = expected_ff(mesh, recv, half, 0.0, h)
    np.testing.assert_allclose(outlined, expected, rtol=0.03)
    assert abs(outlined.sum() / expected.sum() - 1) < 0.005
    # The barycentric share: the square and half a step more on every side, 0.48 m^2
    # against 0.36 (a third more light, a little more still at the near receivers).
    ratio = shared.sum() / outlined.sum()
    assert 1.3 < ratio < 1.42


def test_hemisphere_rays_take_a_fused_panel_from_its_outline_and_its_rim_as_surface():
    """The hemisphere rays' classes follow the outline too: a hit on a rim triangle is
    light inside the outline and the ceiling's surface outside it (docs/invert.md, "An
    area light's outline")."""
    from reroom.invert.area_region import area_region

    h, half, step = 2.0, 0.3, 0.1
    mesh, on, recv = fused_ceiling(h, half, step)
    caster = RayCaster(mesh)
    nrm = vertex_normals(mesh)
    region = area_region(mesh.vertices[on], [0.0, 0.0, -1.0])
    nv = len(mesh.vertices)
    # The ceiling (light vertices included: their radiance is never read) at 1, the floor 0.
    radiance = np.repeat((mesh.vertices[:, 2] > 1.0)[:, None], 3, axis=1).astype(float)
    args = (caster, mesh, recv, nrm, radiance, np.ones(nv, bool), np.where(on, 0, -1), [], None)
    outlined = hemisphere_transfer(*args, rays_per_vertex=2048, seed=2, area_regions=[region])
    shared = hemisphere_transfer(*args, rays_per_vertex=2048, seed=2)
    light = expected_ff(mesh, recv, half, 0.0, h)
    ceiling = expected_ff(mesh, recv, 1.2, 0.0, h) - light
    assert outlined.area[:, 0].sum() / light.sum() == pytest.approx(1.0, abs=0.03)
    assert outlined.indirect[:, 0].sum() / ceiling.sum() == pytest.approx(1.0, abs=0.01)
    # Shared by barycentric weight the light reaches half a rim triangle further: a third
    # more light, and as much less ceiling.
    assert 1.25 < shared.area[:, 0].sum() / outlined.area[:, 0].sum() < 1.5
    lost = (outlined.indirect[:, 0].sum() - shared.indirect[:, 0].sum()) / light.sum()
    assert 0.25 < lost < 0.5


def test_a_recessed_panels_fused_rim_is_left_out_of_its_outline():
    """A recessed panel fused on a turned grid (docs/invert.md, "Session 50"): the rim's
    slope takes the face's radiance past two of its edges, 7-16 mm above the face. The
    outline is the hull of the vertices on the face's plane; a dome keeps every vertex."""
    from reroom.invert.area_region import area_region, on_emitting_plane

    rng = np.random.default_rng(5)
    g = np.linspace(-0.3, 0.3, 21)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    face = np.column_stack([x, y, 2.68 + rng.normal(0.0, 0.0015, x.size)])
    # The slope past the -x and +y edges: 1-4 cm out, rising towards the ceiling at 2.70.
    out = np.repeat(np.linspace(0.01, 0.04, 4), 21)
    along = np.tile(g, 4)
    lift = 2.68 + np.clip(0.007 + 0.3 * (out - 0.01), 0.0, 0.018)
    slope = np.concatenate(
        [
            np.column_stack([-0.3 - out, along, lift]),
            np.column_stack([along, 0.3 + out, lift]),
        ]
    )
    pts = np.concatenate([face, slope])
    normal = [np.sin(np.radians(1.0)), 0.0, -np.cos(np.radians(1.0))]  # a degree off
    keep = on_emitting_plane(pts, normal)
    assert keep[: len(face)].all() and not keep[len(face) :].any()
    assert area_region(pts[keep], normal).area == pytest.approx(0.36, rel=0.01)
    assert area_region(pts, normal).area > 0.38  # the hull of them all: (0.64)^2
    # Not flat: a dome's vertices have no plane to keep them on, so all are kept.
    th, ph = rng.uniform(0.0, 1.2, 500), rng.uniform(0.0, 2 * np.pi, 500)
    dome = np.column_stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), -np.cos(th)])
    assert on_emitting_plane(0.2 * dome + [0.0, 0.0, 2.7], [0.0, 0.0, -1.0]).all()
    # Too few points or not finite: everything kept.
    assert on_emitting_plane(face[:2], normal).all()
    bad = face.copy()
    bad[0, 0] = np.nan
    assert on_emitting_plane(bad, normal).all()
