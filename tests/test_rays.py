"""Tests of reroom.rays against analytic cases: cube, plane, sphere, shadows, sampling."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from reroom.errors import ReroomError
from reroom.rays import RayCaster, orthonormal_basis, sample_hemisphere


def unit_dirs(rng: np.random.Generator, n: int) -> np.ndarray:
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


@pytest.fixture(scope="module")
def cube() -> RayCaster:
    # Axis-aligned cube [-0.5, 0.5]^3.
    return RayCaster(trimesh.creation.box(extents=(1.0, 1.0, 1.0)))


@pytest.fixture(scope="module")
def sphere_mesh() -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions=5, radius=1.0)


@pytest.fixture(scope="module")
def sphere(sphere_mesh: trimesh.Trimesh) -> RayCaster:
    return RayCaster(sphere_mesh)


def floor_and_box() -> trimesh.Trimesh:
    """A 6 x 6 m floor at z = 0 and a 1 m box spanning z in [1, 2] above its centre."""
    floor = trimesh.Trimesh(
        vertices=[[-3, -3, 0], [3, -3, 0], [3, 3, 0], [-3, 3, 0]], faces=[[0, 1, 2], [0, 2, 3]]
    )
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    box.apply_translation([0.0, 0.0, 1.5])
    return trimesh.util.concatenate([floor, box])


# -- closest hits ---------------------------------------------------------------------------


def test_cube_hits_from_outside_along_axes(cube: RayCaster) -> None:
    origins = np.array([[3.0, 0.1, 0.2], [-2.0, 0.0, 0.0], [0.0, 0.3, 5.0], [0.2, -4.0, -0.1]])
    directions = np.array([[-1.0, 0, 0], [2.0, 0, 0], [0, 0, -0.5], [0, 1.0, 0]])
    hits = cube.intersect(origins, directions)
    np.testing.assert_allclose(hits.t, [2.5, 1.5, 4.5, 3.5], rtol=1e-6)
    assert hits.hit.all()
    np.testing.assert_allclose(hits.normals, [[1, 0, 0], [-1, 0, 0], [0, 0, 1], [0, -1, 0]])
    expected = origins + hits.t[:, None] * directions / np.linalg.norm(directions, axis=1)[:, None]
    np.testing.assert_allclose(hits.points, expected, atol=1e-6)


def test_cube_exit_distance_from_inside(cube: RayCaster) -> None:
    rng = np.random.default_rng(0)
    o = rng.uniform(-0.4, 0.4, (5000, 3))
    d = unit_dirs(rng, 5000)
    # Slab exit distance: the nearest of the three planes the ray heads for.
    expected = np.min((0.5 * np.sign(d) - o) / d, axis=1)
    hits = cube.intersect(o, d)
    assert hits.hit.all()
    np.testing.assert_allclose(hits.t, expected, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(np.abs(hits.points).max(axis=1), 0.5, atol=1e-6)


def test_plane_hits_and_misses() -> None:
    plane = RayCaster(
        np.array([[-100, -100, 0], [100, -100, 0], [100, 100, 0], [-100, 100, 0.0]]),
        np.array([[0, 1, 2], [0, 2, 3]]),
    )
    rng = np.random.default_rng(1)
    o = np.column_stack([rng.uniform(-2, 2, (1000, 2)), rng.uniform(0.5, 3, 1000)])
    d = unit_dirs(rng, 1000)
    d[:, 2] = -np.abs(d[:, 2]) - 0.3  # all heading down steeply enough to land on the plane
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    hits = plane.intersect(o, d)
    np.testing.assert_allclose(hits.t, -o[:, 2] / d[:, 2], rtol=1e-5)
    np.testing.assert_allclose(hits.points[:, 2], 0.0, atol=1e-5)
    # Barycentrics reproduce the hit point on its triangle, to float32 precision relative
    # to the triangle's 200 m size.
    tri = plane.vertices[plane.faces[hits.face]]
    bary_points = np.einsum("nk,nkj->nj", hits.barycentric, tri)
    np.testing.assert_allclose(bary_points, hits.points, atol=200 * 3e-7)

    up = plane.intersect(o, -d)
    assert not up.hit.any()
    assert np.isinf(up.t).all() and (up.face == -1).all() and np.isnan(up.points).all()
    assert np.isnan(up.uv).all() and np.isnan(up.normals).all()

    # tmax shorter than the hit distance: a miss; tmin beyond it: a miss too.
    t = hits.t
    assert not plane.intersect(o, d, tmax=t * 0.99).hit.any()
    assert not plane.intersect(o, d, tmin=t * 1.01).hit.any()
    np.testing.assert_allclose(plane.intersect(o, d, tmin=t * 0.5).t, t, rtol=1e-5)


def test_mesh_far_from_the_origin_keeps_precision() -> None:
    """Float32 spacing at 1e5 m is 8 mm; centring the mesh keeps hits exact to microns."""
    offset = np.array([1e5, -2e5, 300.0])
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    rc = RayCaster(box.vertices + offset, box.faces)
    rng = np.random.default_rng(9)
    o = offset + rng.uniform(-0.4, 0.4, (2000, 3))
    d = unit_dirs(rng, 2000)
    expected = np.min((0.5 * np.sign(d) - (o - offset)) / d, axis=1)
    np.testing.assert_allclose(rc.intersect(o, d).t, expected, rtol=1e-5, atol=1e-6)


def test_ray_from_a_surface_needs_tmin() -> None:
    plane = RayCaster(np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0.0]]), np.array([[0, 1, 2]]))
    # Robust traversal reports the surface the ray starts on, at t = 0 ...
    assert plane.intersect([0, 0, 0], [0.3, 0, 1]).t[0] == pytest.approx(0.0, abs=1e-6)
    # ... which an offset of eps along the ray skips.
    assert not plane.intersect([0, 0, 0], [0.3, 0, 1], tmin=plane.eps).hit.any()


def test_sphere_hits_from_centre_and_outside(
    sphere: RayCaster, sphere_mesh: trimesh.Trimesh
) -> None:
    rng = np.random.default_rng(2)
    d = unit_dirs(rng, 20000)
    hits = sphere.intersect(np.zeros(3), d)
    # The icosphere is inscribed in the unit sphere: its faces sag by < 1e-3 at level 5.
    assert hits.hit.all()
    assert (hits.t <= 1.0 + 1e-6).all() and (hits.t > 1.0 - 1e-3).all()
    # The hit face's normal points outwards, roughly along the ray.
    assert (np.einsum("ij,ij->i", hits.normals, d) > 0.99).all()
    # Rays aimed at the mesh vertices hit at radius 1. Embree is not perfectly watertight
    # even in robust mode: a few rays through a vertex slip between its triangles.
    at_vertices = sphere.intersect(np.zeros(3), sphere_mesh.vertices)
    assert at_vertices.hit.mean() > 0.99
    np.testing.assert_allclose(at_vertices.t[at_vertices.hit], 1.0, rtol=1e-6)
    # From outside at distance 3, aimed at the centre: first hit at 3 - r.
    o = 3.0 * d[:500]
    outside = sphere.intersect(o, -o)
    assert (outside.t >= 2.0 - 1e-6).all() and (outside.t < 2.0 + 1e-3).all()


# -- occlusion and visibility -------------------------------------------------------------


def test_occlusion_by_a_blocker(cube: RayCaster) -> None:
    a = np.array([[-2.0, 0.0, 0.0], [-2.0, 2.0, 0.0], [-2.0, 0.0, 0.0]])
    b = np.array([[2.0, 0.0, 0.0], [2.0, 2.0, 0.0], [-0.6, 0.0, 0.0]])
    seg = b - a
    dist = np.linalg.norm(seg, axis=1)
    blocked = cube.occluded(a, seg, tmax=dist)
    np.testing.assert_array_equal(blocked, [True, False, False])
    # Same answer as a closest-hit query.
    np.testing.assert_array_equal(cube.intersect(a, seg, tmax=dist).hit, blocked)


def test_shadow_of_a_box_on_the_floor() -> None:
    rc = RayCaster(floor_and_box())
    g = np.linspace(-2.9, 2.9, 59)
    x, y = np.meshgrid(g, g)
    pts = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    up = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    cheb = np.max(np.abs(pts[:, :2]), axis=1)

    # Point light at height 4: the box's top face (z = 2) projects to |x|, |y| < 1,
    # which contains the projection of its bottom face (z = 1, |x|, |y| < 2/3).
    light = np.array([0.0, 0.0, 4.0])
    vis = rc.visible_points(pts, up, light)
    clear = np.abs(cheb - 1.0) > 0.02
    np.testing.assert_array_equal(vis[clear], cheb[clear] > 1.0)

    # One target per point, straight above it: shadowed exactly over the box footprint.
    above = pts + [0.0, 0.0, 4.0]
    vis = rc.visible_points(pts, up, above)
    clear = np.abs(cheb - 0.5) > 0.02
    np.testing.assert_array_equal(vis[clear], cheb[clear] > 0.5)

    # Normals facing away from the light: not visible, whatever the geometry.
    assert not rc.visible_points(pts, -up, light).any()
    # Without normals the start is offset along the segment instead; same shadow.
    vis_nn = rc.visible_points(pts, None, light)
    clear = np.abs(cheb - 1.0) > 0.02
    np.testing.assert_array_equal(vis_nn[clear], cheb[clear] > 1.0)

    # Several targets at once.
    targets = np.array([light, [0.0, 0.0, 0.5], [0.0, 0.0, 2.5]])
    mat = rc.visibility_matrix(pts, up, targets)
    assert mat.shape == (len(pts), 3)
    np.testing.assert_array_equal(mat[:, 0], rc.visible_points(pts, up, light))
    # Under the box the target sees the whole floor; just above it, the top face
    # (z = 2) casts a shadow 2.5 / 0.5 = 5 times its size.
    assert mat[:, 1].all()
    clear = np.abs(cheb - 2.5) > 0.02
    np.testing.assert_array_equal(mat[clear, 2], cheb[clear] > 2.5)


def test_vertex_visibility_on_a_convex_mesh(sphere_mesh: trimesh.Trimesh) -> None:
    """From far away, a vertex of a convex mesh is visible iff it faces the eye."""
    rc = RayCaster(sphere_mesh)
    eye = np.array([20.0, 5.0, -3.0])
    v, n = sphere_mesh.vertices, sphere_mesh.vertex_normals
    vis = rc.visible_points(v, n, eye)
    cos = np.einsum("ij,ij->i", n, (eye - v) / np.linalg.norm(eye - v, axis=1)[:, None])
    assert vis[cos > 0.02].all()
    assert not vis[cos < 0].any()


# -- threading ------------------------------------------------------------------------------


def test_chunked_threads_match_single_thread(sphere_mesh: trimesh.Trimesh) -> None:
    rng = np.random.default_rng(3)
    o = rng.uniform(-1.5, 1.5, (60000, 3))
    d = unit_dirs(rng, 60000)
    single = RayCaster(sphere_mesh, threads=1, chunk_size=10**9)
    multi = RayCaster(sphere_mesh, threads=4, chunk_size=997)
    a, b = single.intersect(o, d), multi.intersect(o, d)
    for field in ("t", "face", "uv", "points", "normals"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    np.testing.assert_array_equal(single.occluded(o, d, 0.7), multi.occluded(o, d, 0.7))


# -- validation -----------------------------------------------------------------------------


def test_input_validation(cube: RayCaster) -> None:
    with pytest.raises(ValueError, match="origins contain non-finite"):
        cube.intersect([[0, 0, np.nan]], [[1, 0, 0]])
    with pytest.raises(ValueError, match="directions contain non-finite"):
        cube.occluded([[0, 0, 0]], [[np.inf, 0, 0]])
    with pytest.raises(ValueError, match="zero-length"):
        cube.intersect([[0, 0, 0], [0, 0, 0]], [[1, 0, 0], [0, 0, 0]])
    with pytest.raises(ValueError, match="shape"):
        cube.intersect(np.zeros((4, 2)), np.ones((4, 2)))
    with pytest.raises(ValueError, match="broadcast"):
        cube.intersect(np.zeros((4, 3)), np.ones((5, 3)))
    with pytest.raises(ValueError, match="tmax must not be smaller"):
        cube.intersect([0, 0, 0], [1, 0, 0], tmin=1.0, tmax=0.5)
    with pytest.raises(ValueError, match="points contain non-finite"):
        cube.visible_points([[np.nan, 0, 0]], None, [0, 0, 3])
    with pytest.raises(ValueError, match="zero vectors"):
        cube.visible_points([[0, 0, 0.5]], [[0, 0, 0]], [0, 0, 3])


def test_bad_meshes() -> None:
    with pytest.raises(ReroomError, match="empty mesh"):
        RayCaster(trimesh.Trimesh())
    with pytest.raises(ReroomError, match="empty mesh"):
        RayCaster(np.zeros((3, 3)), np.zeros((0, 3), dtype=int))
    with pytest.raises(ReroomError, match="face indices"):
        RayCaster(np.zeros((3, 3)), np.array([[0, 1, 3]]))
    with pytest.raises(ReroomError, match="non-finite"):
        RayCaster(np.array([[0, 0, 0], [1, 0, 0], [0, np.nan, 0]]), np.array([[0, 1, 2]]))


# -- hemisphere sampling --------------------------------------------------------------------


def awkward_normals(rng: np.random.Generator, n: int) -> np.ndarray:
    # Include the poles, where naive frame constructions break down.
    return np.vstack([[0, 0, 1.0], [0, 0, -1.0], [1.0, 0, 0], unit_dirs(rng, n - 3)])


@pytest.mark.parametrize("cosine", [True, False])
@pytest.mark.parametrize("stratified", [True, False])
def test_hemisphere_samples_are_unit_and_above(cosine: bool, stratified: bool) -> None:
    rng = np.random.default_rng(4)
    n = awkward_normals(rng, 500)
    dirs, pdf = sample_hemisphere(n, 16, rng, cosine=cosine, stratified=stratified)
    assert dirs.shape == (500, 16, 3) and pdf.shape == (500, 16)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=-1), 1.0, atol=1e-12)
    cos = np.einsum("nkj,nj->nk", dirs, n)
    assert (cos >= 0).all()
    expected_pdf = cos / np.pi if cosine else np.full_like(cos, 1 / (2 * np.pi))
    np.testing.assert_allclose(pdf, expected_pdf, atol=1e-12)


def test_orthonormal_basis() -> None:
    n = awkward_normals(np.random.default_rng(5), 200)
    t, b = orthonormal_basis(n)
    frame = np.stack([t, b, n], axis=-1)
    np.testing.assert_allclose(
        frame.transpose(0, 2, 1) @ frame, np.broadcast_to(np.eye(3), frame.shape), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(frame), 1.0, atol=1e-12)


def test_cosine_and_uniform_moments() -> None:
    rng = np.random.default_rng(6)
    n = awkward_normals(rng, 2000)
    dirs, pdf = sample_hemisphere(n, 64, rng, cosine=True)
    cos = np.einsum("nkj,nj->nk", dirs, n)
    assert cos.mean() == pytest.approx(2 / 3, abs=2e-3)
    assert (cos > 0.5).mean() == pytest.approx(0.75, abs=5e-3)  # P(cos > c) = 1 - c^2
    # The mean direction is (2/3) n, so the local frames are oriented correctly.
    residual = dirs.mean(axis=1) - 2 / 3 * n
    np.testing.assert_allclose(residual.mean(axis=0), 0.0, atol=2e-3)
    assert np.abs(residual).max() < 0.1
    # Irradiance from a uniform sky of radiance 1 is pi; cosine sampling gets it exactly.
    np.testing.assert_allclose(cos / pdf, np.pi, rtol=1e-9)

    dirs, pdf = sample_hemisphere(n, 64, rng, cosine=False)
    cos = np.einsum("nkj,nj->nk", dirs, n)
    assert cos.mean() == pytest.approx(0.5, abs=2e-3)
    assert (cos > 0.5).mean() == pytest.approx(0.5, abs=5e-3)  # cos is uniform on [0, 1]
    assert (cos / pdf).mean() == pytest.approx(np.pi, rel=5e-3)


@pytest.mark.parametrize("n_per_point", [16, 12, 7])  # square grid, 3 x 4 grid, Latin hypercube
@pytest.mark.parametrize("cosine", [True, False])
def test_stratification_lowers_variance(n_per_point: int, cosine: bool) -> None:
    """Per-point irradiance estimates under a non-uniform sky vary less when stratified."""
    rng = np.random.default_rng(7)
    normals = np.tile([0.0, 0.0, 1.0], (4000, 1))
    sun = np.array([0.6, 0.0, 0.8])

    def estimates(stratified: bool) -> np.ndarray:
        d, pdf = sample_hemisphere(normals, n_per_point, rng, cosine=cosine, stratified=stratified)
        radiance = 1.0 + 4.0 * np.maximum(d @ sun, 0.0) ** 2
        return (radiance * d[..., 2] / pdf).mean(axis=1)

    strat, plain = estimates(True), estimates(False)
    assert strat.mean() == pytest.approx(plain.mean(), rel=0.02)
    assert strat.var() < 0.5 * plain.var()


def test_sampling_is_deterministic_and_validated() -> None:
    a = sample_hemisphere([0.0, 0.0, 2.0], 9, 42)
    b = sample_hemisphere([0.0, 0.0, 2.0], 9, np.random.default_rng(42))
    np.testing.assert_array_equal(a[0], b[0])
    assert a[0].shape == (9, 3) and a[1].shape == (9,)
    with pytest.raises(ValueError, match="zero"):
        sample_hemisphere([[0.0, 0.0, 0.0]], 4, 0)
    with pytest.raises(ValueError, match="non-finite"):
        sample_hemisphere([[0.0, np.nan, 1.0]], 4, 0)
    with pytest.raises(ValueError, match="n_per_point"):
        sample_hemisphere([[0.0, 0.0, 1.0]], 0, 0)


# -- Mitsuba backend ------------------------------------------------------------------------


def test_mitsuba_backend_agrees_with_embree(sphere_mesh: trimesh.Trimesh) -> None:
    from reroom.render import mitsuba_info

    if not mitsuba_info().vectorized:
        pytest.skip("no vectorised Mitsuba variant on this machine")
    rng = np.random.default_rng(8)
    o = rng.uniform(-1.5, 1.5, (20000, 3))
    d = unit_dirs(rng, 20000)
    emb = RayCaster(sphere_mesh)
    mit = RayCaster(sphere_mesh, backend="mitsuba")
    a, b = emb.intersect(o, d), mit.intersect(o, d)
    np.testing.assert_array_equal(a.hit, b.hit)
    assert (a.face == b.face).mean() > 0.999  # rays through shared edges may pick either face
    np.testing.assert_allclose(a.t, b.t, rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(emb.occluded(o, d, 0.5), mit.occluded(o, d, 0.5))
