"""Transfer of every light model against analytic or brute-force references (reroom.invert)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from meshes import grid_plane

from reroom.errors import ReroomError
from reroom.hdr.observe import vertex_normals
from reroom.invert import (
    CubemapBasis,
    InclinationBasis,
    LineBasis,
    SHBasis,
    WindowOpening,
    hemisphere_transfer,
    line_light_transfer,
    point_light_transfer,
)
from reroom.rays import RayCaster

# -- helpers ---------------------------------------------------------------------------------


def rect_form_factor(a: float, b: float, h: float) -> float:
    """Point-to-parallel-rectangle form factor, point below a corner of the ``a x b`` rectangle."""
    x, y = a / h, b / h
    sx, sy = np.sqrt(1 + x * x), np.sqrt(1 + y * y)
    return float((x / sx * np.arctan(y / sx) + y / sy * np.arctan(x / sy)) / (2 * np.pi))


def rect_ff_offset(x0: float, x1: float, y0: float, y1: float, h: float) -> float:
    """Form factor of ``[x0, x1] x [y0, y1]`` at height ``h`` seen from the origin, facing up."""

    def corner(x: float, y: float) -> float:
        return np.sign(x) * np.sign(y) * rect_form_factor(abs(x), abs(y), h)

    return corner(x1, y1) - corner(x0, y1) - corner(x1, y0) + corner(x0, y0)


def unit_rows(a: np.ndarray) -> np.ndarray:
    return a / np.linalg.norm(a, axis=1, keepdims=True)


# -- bases ------------------------------------------------------------------------------------


def _area_only_transfer(mesh, recv, area_of, rays: int, seed: int):
    """Hemisphere transfer of ``recv`` in a scene lit only by area lights (``area_of``)."""
    nv = len(mesh.vertices)
    return hemisphere_transfer(
        RayCaster(mesh),
        mesh,
        recv,
        vertex_normals(mesh),
        np.zeros((nv, 3)),
        np.ones(nv, bool),
        area_of,
        [],
        None,
        rays_per_vertex=rays,
        seed=seed,
    )


def test_cubemap_solid_angles_cells_and_adjacency():
    basis = CubemapBasis(4)
    assert basis.size == 96
    omega = basis.cell_solid_angles()
    assert omega.sum() == pytest.approx(4 * np.pi, abs=1e-12)
    assert (basis.cell_of(basis.cell_directions()) == np.arange(96)).all()

    # Solid angles vs the share of uniformly random directions landing in each cell.
    rng = np.random.default_rng(1)
    d = unit_rows(rng.normal(size=(400_000, 3)))
    share = np.bincount(basis.cell_of(d), minlength=96) / len(d) * 4 * np.pi
    sigma = np.sqrt(omega / (4 * np.pi) / len(d)) * 4 * np.pi
    assert np.all(np.abs(share - omega) < 5 * sigma)

    # Adjacency vs brute force: cells of direction pairs a tiny step apart.
    adj = basis.adjacency()
    assert adj.shape == (192, 2)
    assert (np.bincount(adj.ravel(), minlength=96) == 4).all()
    step = unit_rows(np.cross(d, rng.normal(size=d.shape))) * 1e-3
    c0, c1 = basis.cell_of(d), basis.cell_of(d + step)
    moved = c0 != c1
    found = {(min(a, b), max(a, b)) for a, b in zip(c0[moved], c1[moved], strict=True)}
    expected = {tuple(p) for p in adj.tolist()}
    # Steps across a corner can join diagonal cells, rarely; every true edge must be seen.
    assert expected <= found
    assert len(found - expected) <= 0.01 * moved.sum()


def test_sh_orthonormal_and_constant_projection():
    basis = SHBasis(5)
    assert basis.size == 25
    # Gauss-Legendre in z times uniform phi integrates these polynomials exactly.
    z, wz = np.polynomial.legendre.leggauss(12)
    phi = (np.arange(24) + 0.5) * 2 * np.pi / 24
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    s = np.sqrt(1 - zz**2)
    d = np.stack([s * np.cos(pp), s * np.sin(pp), zz], -1).reshape(-1, 3)
    w = (wz[:, None] * np.full(len(phi), 2 * np.pi / len(phi))).ravel()
    y = basis.evaluate(d)
    gram = (y * w[:, None]).T @ y
    np.testing.assert_allclose(gram, np.eye(25), atol=1e-12)
    # A constant c projects onto Y00 only, with coefficient c sqrt(4 pi).
    coef = (y * w[:, None]).sum(axis=0) * 3.0
    np.testing.assert_allclose(coef, np.r_[3.0 * np.sqrt(4 * np.pi), np.zeros(24)], atol=1e-12)
    # Sign convention: Y_11 grows along +x, Y_1-1 along +y, Y_10 along +z.
    y1 = basis.evaluate(np.eye(3))
    assert y1[0, 3] > 0 and y1[1, 1] > 0 and y1[2, 2] > 0


def test_inclination_bins():
    b = InclinationBasis(32)
    theta = np.array([0.0, np.pi / 64 - 1e-9, np.pi / 2 + 1e-9, np.pi])
    assert b.bin_of(np.cos(theta)).tolist() == [0, 0, 16, 31]
    assert b.bin_of([1.5, -2.0]).tolist() == [0, 31]


def _line_angles(d: np.ndarray, tangent: np.ndarray, up: np.ndarray):
    """``cos(theta)`` around the line from ``up`` and signed ``phi`` of unit directions."""
    along = d @ tangent
    perp = d - np.outer(along, tangent)
    return perp @ up / np.linalg.norm(perp, axis=1), np.arcsin(np.clip(along, -1, 1))


@pytest.mark.parametrize("fold", [True, False])
def test_line_basis_bins_solid_angles_and_adjacency(fold):
    b = LineBasis(8, 3, fold)
    assert b.size == 24
    t, up = np.array([1.0, 0, 0]), np.array([0, 0, 1.0])
    # Bin centres round-trip through bin_of, on either side of up (theta folds).
    d = b.directions(up, t)
    assert np.all(b.bin_of(*_line_angles(d, t, up)) == np.arange(b.size))
    mirror = d * [1, -1, 1]
    assert np.all(b.bin_of(*_line_angles(mirror, t, up)) == np.arange(b.size))
    # Solid angles: sum 4 pi, each the share of 400k random directions (5 sigma).
    sa = b.solid_angles()
    assert sa.sum() == pytest.approx(4 * np.pi, rel=1e-12)
    rng = np.random.default_rng(0)
    dirs = unit_rows(rng.normal(size=(400_000, 3)))
    count = np.bincount(b.bin_of(*_line_angles(dirs, t, up)), minlength=b.size)
    p = sa / (4 * np.pi)
    assert np.all(np.abs(count / len(dirs) - p) < 5 * np.sqrt(p * (1 - p) / len(dirs)))
    # Power weights: flux per metre of i = 1 in a bin, the mean of cos(phi) over the bin x 4 pi.
    cos_phi = np.sqrt(1 - (dirs @ t) ** 2)
    mc = np.bincount(b.bin_of(*_line_angles(dirs, t, up)), cos_phi, b.size) * 4 * np.pi / len(dirs)
    np.testing.assert_allclose(b.power_weights(), mc, rtol=0.05)  # ~16k samples a bin
    assert b.power_weights().sum() == pytest.approx(np.pi**2, rel=1e-12)  # bare line: pi^2 i
    # Adjacency: exactly the pairs of bins whose centres are one bin apart in one angle.
    pairs, weights = b.adjacency(phi_weight=5.0)
    it, ip = np.divmod(np.arange(b.size), 3)
    brute = {
        (i, j)
        for i in range(b.size)
        for j in range(i + 1, b.size)
        if abs(it[i] - it[j]) + abs(ip[i] - ip[j]) == 1
    }
    assert {tuple(x) for x in pairs.tolist()} == brute and len(pairs) == len(brute)
    is_phi = it[pairs[:, 0]] == it[pairs[:, 1]]
    np.testing.assert_array_equal(weights, np.where(is_phi, 5.0, 1.0))


def test_line_basis_with_one_phi_bin_is_the_inclination_basis():
    b, inc = LineBasis(32, 1), InclinationBasis(32)
    np.testing.assert_array_equal(b.theta_edges(), inc.bin_edges())
    cos_t = np.linspace(-1, 1, 101)
    np.testing.assert_array_equal(b.bin_of(cos_t, np.linspace(-1.5, 1.5, 101)), inc.bin_of(cos_t))
    pairs, weights = b.adjacency()
    np.testing.assert_array_equal(pairs, np.stack([np.arange(31), np.arange(1, 32)], axis=1))
    np.testing.assert_array_equal(weights, np.ones(31))
    np.testing.assert_allclose(b.power_weights(), np.full(32, np.pi * np.pi / 32))
    assert LineBasis.from_basis(inc).size == 32 and LineBasis.from_basis(b) is b
    with pytest.raises(ValueError, match="at least one"):
        LineBasis(8, 0)


# -- point lights -----------------------------------------------------------------------------


def test_point_light_over_plane_matches_closed_form_and_shadows():
    plane = grid_plane(6.0, 0.25)
    light = np.array([0.3, -0.2, 2.0])
    basis = InclinationBasis(32)
    p, n = plane.vertices, np.tile([0.0, 0.0, 1.0], (len(plane.vertices), 1))
    f = point_light_transfer(RayCaster(plane), p, n, light, [0, 0, 1], basis)
    a = p - light  # light -> receiver
    d = np.linalg.norm(a, axis=1)
    expected = (light[2] - p[:, 2]) / d / d**2
    np.testing.assert_allclose(f.sum(axis=1), expected, rtol=1e-12)
    theta = np.arccos(a[:, 2] / d)
    assert (f.argmax(axis=1) == np.minimum((theta / np.pi * 32).astype(int), 31)).all()
    assert ((f > 0).sum(axis=1) == 1).all()
    assert (theta > np.pi / 2).all()  # receivers below the light: lower hemisphere bins

    # An occluder box between light and plane: zero in its shadow, exact elsewhere.
    box = trimesh.creation.box(extents=(1.0, 0.8, 0.4))
    box.apply_translation([0.0, 0.0, 1.0])
    scene = trimesh.util.concatenate([plane, box])
    f2 = point_light_transfer(RayCaster(scene), p, n, light, [0, 0, 1], basis).sum(axis=1)
    # Analytic shadow: the segment receiver -> light crosses the box (slab test).
    lo, hi = box.bounds
    seg = light - p
    with np.errstate(divide="ignore"):
        t0, t1 = (lo - p) / seg, (hi - p) / seg
    tin = np.minimum(t0, t1).max(axis=1)
    tout = np.maximum(t0, t1).min(axis=1)
    shadow = (tin < tout) & (tout > 0) & (tin < 1)
    # Leave out receivers whose ray grazes the box (within 1 cm at the box's height).
    xy_at = p + seg * ((1.0 - p[:, 2]) / seg[:, 2])[:, None]
    margin = np.minimum.reduce(
        [np.abs(np.abs(xy_at[:, 0]) - 0.5), np.abs(np.abs(xy_at[:, 1]) - 0.4)]
    )
    clear = margin > 0.05
    assert shadow.sum() > 20
    assert (f2[shadow & clear] == 0).all()
    np.testing.assert_allclose(f2[~shadow & clear], expected[~shadow & clear], rtol=1e-12)

    # A light a centimetre off the plane: the receivers within `fixture` of it are its fitting.
    near_light = np.array([0.0, 0.0, 0.01])
    up = np.tile([0.0, 0.0, 1.0], (len(p), 1))
    free = point_light_transfer(RayCaster(plane), p, up, near_light, [0, 0, 1], basis)
    fit = point_light_transfer(RayCaster(plane), p, up, near_light, [0, 0, 1], basis, fixture=0.2)
    inside = np.linalg.norm(p - near_light, axis=1) <= 0.2
    assert inside.sum() >= 1 and (~inside).sum() > 100
    assert (fit[inside] == 0).all() and free[inside].sum() > 0
    np.testing.assert_array_equal(fit[~inside], free[~inside])


def test_point_light_irradiance_is_the_transfer_read_as_the_renderer_reads_it():
    from reroom.invert.direct import point_light_irradiance

    plane = grid_plane(6.0, 0.25)
    light = np.array([0.3, -0.2, 2.0])
    caster = RayCaster(plane)
    p, n = plane.vertices, np.tile([0.0, 0.0, 1.0], (len(plane.vertices), 1))
    basis = InclinationBasis(32)
    rng = np.random.default_rng(5)
    intens = rng.uniform(0.5, 2.0, (32, 3))
    f = point_light_transfer(caster, p, n, light, [0, 0, 1], basis)
    # Read per bin ("constant"), it is exactly the transfer times the profile.
    got = point_light_irradiance(caster, p, n, light, [0, 0, 1], intens, interpolation="constant")
    np.testing.assert_allclose(got, f @ intens, rtol=1e-12)
    # Read between bin centres ("linear", the renderer's default): the geometry times
    # the profile interpolated at each receiver's angle.
    lin = point_light_irradiance(caster, p, n, light, [0, 0, 1], intens)
    a = p - light
    d = np.linalg.norm(a, axis=1)
    theta = np.arccos(a[:, 2] / d)
    centres = (np.arange(32) + 0.5) * np.pi / 32
    for c in range(3):
        want = f.sum(axis=1) * np.interp(theta, centres, intens[:, c])
        np.testing.assert_allclose(lin[:, c], want, rtol=1e-9)
    with pytest.raises(ValueError, match=r"intensities must be \(bins, 3\)"):
        point_light_irradiance(caster, p, n, light, [0, 0, 1], intens[:, 0])


# -- line lights ------------------------------------------------------------------------------


def eq_5_11_quadrature(p, n, p0, p1, samples=20_000):
    """Eq. 5.11 without occlusion by a fine midpoint rule."""
    d = p1 - p0
    length = np.linalg.norm(d)
    dh = d / length
    x = (np.arange(samples) + 0.5) / samples * length
    out = np.zeros(len(p))
    for i in range(len(p)):
        a = p0 + x[:, None] * dh - p[i]
        r = np.linalg.norm(a, axis=1)
        a_perp = a - (a @ dh)[:, None] * dh
        cos_r = np.maximum(a @ n[i], 0) / r
        cos_phi = np.linalg.norm(a_perp, axis=1) / r
        out[i] = np.sum(cos_r / r**2 * cos_phi) * length / samples
    return out


def _line_scene():
    """A floor plane, a 1.2 m line 2.2 m above it, and receivers: on the floor (under and
    beyond the line's ends) and tilted ones in the air (their horizon cuts the line)."""
    plane = grid_plane(3.0, 0.5)
    rng = np.random.default_rng(2)
    p0, p1 = np.array([-0.6, 0.1, 2.2]), np.array([0.6, 0.1, 2.2])
    p = np.concatenate([plane.vertices[::3], rng.uniform([-2, -2, 0.5], [2, 2, 2.0], (20, 3))])
    n = np.concatenate(
        [
            np.tile([0.0, 0.0, 1.0], (len(plane.vertices[::3]), 1)),
            unit_rows(rng.normal(size=(20, 3))),
        ]
    )
    return RayCaster(plane), p0, p1, p, n


def test_line_light_matches_quadrature_and_bins():
    caster, p0, p1, p, n = _line_scene()
    basis = InclinationBasis(32)
    ref = eq_5_11_quadrature(p, n, p0, p1)
    exact = line_light_transfer(caster, p, n, p0, p1, [0, 0, 1], basis, segments=4)
    np.testing.assert_allclose(exact.sum(axis=1), ref, rtol=1e-6, atol=1e-9 * ref.max())
    # Bins: emission angle around the line from up; floor receivers are below (theta > pi/2).
    rel = p - p0
    e_perp = rel - np.outer(rel @ [1.0, 0, 0], [1.0, 0, 0])
    theta = np.arccos(e_perp[:, 2] / np.linalg.norm(e_perp, axis=1))
    lit = exact.sum(axis=1) > 0
    assert (
        exact[lit].argmax(axis=1) == np.minimum((theta[lit] / np.pi * 32).astype(int), 31)
    ).all()
    # Eq. 5.12 (midpoint) converges to the same with the segment count.
    errors = [
        np.abs(
            line_light_transfer(
                caster, p, n, p0, p1, [0, 0, 1], basis, s, quadrature="midpoint"
            ).sum(1)
            - ref
        ).max()
        / ref.max()
        for s in (2, 8, 32)
    ]
    assert errors[0] > errors[1] > errors[2] and errors[2] < 1e-3


def _floor_under_blocker(extents, centre):
    """A 2 m floor grid under a box blocker: its caster, the floor's vertices and normals."""
    plane = grid_plane(2.0, 0.1)
    blocker = trimesh.creation.box(extents=extents)
    blocker.apply_translation(centre)
    caster = RayCaster(trimesh.util.concatenate([plane, blocker]))
    p = plane.vertices
    return caster, p, np.tile([0.0, 0.0, 1.0], (len(p), 1))


def test_line_light_shadow_converges_with_segments():
    # the blocker hides part of the line from part of the floor
    caster, p, n = _floor_under_blocker((0.3, 3.0, 0.05), [0.25, 0.0, 1.2])
    plane = grid_plane(2.0, 0.1)
    p0, p1, basis = np.array([-0.8, 0.0, 2.0]), np.array([0.8, 0.0, 2.0]), InclinationBasis(8)
    ref = line_light_transfer(caster, p, n, p0, p1, [0, 0, 1], basis, 2048).sum(1)
    free = line_light_transfer(RayCaster(plane), p, n, p0, p1, [0, 0, 1], basis, 4).sum(1)
    assert (ref < 0.95 * free).sum() > 50  # the blocker casts a real penumbra
    err = [
        np.abs(line_light_transfer(caster, p, n, p0, p1, [0, 0, 1], basis, s).sum(1) - ref).max()
        / ref.max()
        for s in (4, 16, 64)
    ]
    assert err[0] > err[1] > err[2]
    assert err[2] < 0.02


def eq_5_11_phi_quadrature(p, n, p0, p1, basis, samples=20_000):
    """Eq. 5.11 without occlusion by a fine midpoint rule, per ``phi`` bin of ``basis``."""
    d = p1 - p0
    length = np.linalg.norm(d)
    dh = d / length
    x = (np.arange(samples) + 0.5) / samples * length
    out = np.zeros((len(p), basis.phi_bins))
    for i in range(len(p)):
        a = p0 + x[:, None] * dh - p[i]  # towards the light
        r = np.linalg.norm(a, axis=1)
        a_perp = a - (a @ dh)[:, None] * dh
        cos_r = np.maximum(a @ n[i], 0) / r
        cos_phi = np.linalg.norm(a_perp, axis=1) / r
        phi = np.arcsin(np.clip(-(a @ dh) / r, -1, 1))  # emission direction: line -> receiver
        j = basis.phi_bin_of(phi)
        out[i] = np.bincount(j, cos_r / r**2 * cos_phi, basis.phi_bins) * length / samples
    return out


@pytest.mark.parametrize("fold", [True, False])
def test_line_light_phi_bins_match_quadrature(fold):
    caster, p0, p1, p, n = _line_scene()
    basis = LineBasis(32, 5, fold)
    f = line_light_transfer(caster, p, n, p0, p1, [0, 0, 1], basis, segments=4)
    assert f.shape == (len(p), basis.size)
    grid = f.reshape(len(p), 32, 5)
    # One theta bin per receiver, as the separable model's; its phi bins split eq. 5.11.
    old = line_light_transfer(caster, p, n, p0, p1, [0, 0, 1], InclinationBasis(32), 4)
    np.testing.assert_allclose(grid.sum(axis=2), old, rtol=1e-12, atol=1e-15 * old.max())
    assert ((grid.sum(axis=2) > 0).sum(axis=1) <= 1).all()
    ref = eq_5_11_phi_quadrature(p, n, p0, p1, basis)
    # The midpoint rule errs by O(1/samples) where a bin edge cuts the line.
    np.testing.assert_allclose(grid.sum(axis=1), ref, rtol=0, atol=2e-4 * ref.max())
    # Receivers beyond an end see it only at large |phi| (not in the bin of phi = 0);
    # folded, both ends alike.
    beyond = (np.abs(p[:, 0]) > 1.3) & (np.abs(p[:, 1] - 0.1) < 0.3) & (old.sum(1) > 0)
    assert beyond.sum() >= 2
    assert np.all(grid[beyond].sum(axis=1)[:, basis.phi_bin_of(0.0)] == 0)
    if not fold:  # past p1 (x > 0.6) the light leaves towards +phi, past p0 towards -phi
        plus = grid.sum(axis=1)[:, 3:].sum(1)
        minus = grid.sum(axis=1)[:, :2].sum(1)
        assert np.all(minus[beyond & (p[:, 0] > 0)] == 0) and np.all(
            plus[beyond & (p[:, 0] > 0)] > 0
        )
        assert np.all(plus[beyond & (p[:, 0] < 0)] == 0) and np.all(
            minus[beyond & (p[:, 0] < 0)] > 0
        )
    # Eq. 5.12 (midpoint): each piece in the bin of its centre; same sums as the 1D one.
    mid = line_light_transfer(caster, p, n, p0, p1, [0, 0, 1], basis, 8, quadrature="midpoint")
    mid1 = line_light_transfer(
        caster, p, n, p0, p1, [0, 0, 1], InclinationBasis(32), 8, quadrature="midpoint"
    )
    np.testing.assert_allclose(mid.reshape(len(p), 32, 5).sum(2), mid1, rtol=1e-12)


def test_line_light_phi_bins_share_the_shadow_rays():
    caster, p, n = _floor_under_blocker((0.3, 3.0, 0.05), [0.25, 0.0, 1.2])
    plane = grid_plane(2.0, 0.1)
    p0, p1 = np.array([-0.8, 0.0, 2.0]), np.array([0.8, 0.0, 2.0])
    one = line_light_transfer(caster, p, n, p0, p1, [0, 0, 1], InclinationBasis(8), 16)
    two = line_light_transfer(caster, p, n, p0, p1, [0, 0, 1], LineBasis(8, 4), 16)
    free = line_light_transfer(RayCaster(plane), p, n, p0, p1, [0, 0, 1], LineBasis(8, 4), 16)
    assert (one.sum(1) < 0.95 * free.sum(1)).sum() > 50  # a real penumbra
    np.testing.assert_allclose(two.reshape(len(p), 8, 4).sum(2), one, rtol=1e-12)


# -- hemisphere transfer: area lights, distant light, indirect --------------------------------


def _receivers(mesh: trimesh.Trimesh, radius: float) -> np.ndarray:
    v = mesh.vertices
    return np.flatnonzero((np.abs(v[:, 2]) < 1e-9) & (np.hypot(v[:, 0], v[:, 1]) <= radius))


def test_area_light_form_factor_square():
    floor = grid_plane(2.0, 0.25)
    h, a = 1.0, 0.6
    light = grid_plane(a, 0.2, z=h, up=False)  # a 1.2 m square facing down
    mesh = trimesh.util.concatenate([floor, light])
    nv = len(mesh.vertices)
    area_of = np.full(nv, -1)
    area_of[len(floor.vertices) :] = 0
    recv = _receivers(mesh, 1.0)
    tr = _area_only_transfer(mesh, recv, area_of, 1024, seed=3)
    x, y = mesh.vertices[recv, 0], mesh.vertices[recv, 1]
    expected = np.pi * np.array(
        [rect_ff_offset(-a - xi, a - xi, -a - yi, a - yi, h) for xi, yi in zip(x, y, strict=True)]
    )
    # Jittered sampling: a light's rim crosses ~sqrt(N) strata, so per vertex the error is
    # a few per cent at 1024 rays (measured: max 3.5 %); over 49 vertices it averages out.
    np.testing.assert_allclose(tr.area[:, 0], expected, rtol=0.06)
    assert abs(np.mean(tr.area[:, 0] / expected) - 1) < 0.01
    np.testing.assert_allclose(tr.p_light, tr.area[:, 0] / np.pi, rtol=1e-12)
    np.testing.assert_allclose(tr.p_light + tr.p_observed + tr.p_unobserved, 1.0)


def test_area_light_form_factor_disc():
    floor = grid_plane(1.0, 0.25)
    h, r = 0.8, 0.5
    disc = trimesh.creation.annulus(r_min=0.0, r_max=r, height=1e-3, sections=256)
    disc = trimesh.Trimesh(disc.vertices, disc.faces)
    disc.apply_translation([0, 0, h])  # a thin closed disc: its underside faces the floor
    mesh = trimesh.util.concatenate([floor, disc])
    nv = len(mesh.vertices)
    area_of = np.full(nv, -1)
    area_of[len(floor.vertices) :] = 0
    recv = np.flatnonzero(np.linalg.norm(mesh.vertices, axis=1) < 1e-9)
    tr = _area_only_transfer(mesh, recv, area_of, 4096, seed=4)
    # Irradiance of a coaxial disc of unit radiance: pi r^2 / (h^2 + r^2) (polygonal: cos(pi/256)^2).
    expected = np.pi * r**2 / (h**2 + r**2) * np.cos(np.pi / 256) ** 2
    assert tr.area[0, 0] == pytest.approx(expected, rel=0.01)


def _open_sky_transfer(window: WindowOpening, basis, rays: int = 1024, pane=None, ceiling=None):
    """Receivers on a floor under a window; the window is an opening or, with ``pane``, a
    mesh of window-flagged vertices; ``ceiling`` is an extra unflagged mesh."""
    floor = grid_plane(1.0, 0.25)
    parts = [floor] + [m for m in (ceiling, pane) if m is not None]
    mesh = trimesh.util.concatenate(parts)
    nv = len(mesh.vertices)
    window_of = np.full(nv, -1)
    if pane is not None:
        window_of[nv - len(pane.vertices) :] = 0
    recv = _receivers(mesh, 0.5)
    return (
        recv,
        mesh,
        hemisphere_transfer(
            RayCaster(mesh),
            mesh,
            recv,
            vertex_normals(mesh),
            np.zeros((nv, 3)),
            np.ones(nv, bool),
            np.full(nv, -1),
            [window] if pane is None else [],
            basis,
            rays_per_vertex=rays,
            seed=5,
            window_of_vertex=window_of if pane is not None else None,
        ),
    )


def test_distant_fully_open_sky_splits_pi_over_cells():
    basis = CubemapBasis(4)
    sky = WindowOpening("sky", [0, 0, 1.0], [1e4, 0, 0], [0, 1e4, 0], [0, 0, -1.0])
    recv, _, tr = _open_sky_transfer(sky, basis)
    total = tr.distant.sum(axis=(1, 2))
    np.testing.assert_allclose(total, np.pi * tr.p_light, rtol=1e-12)
    np.testing.assert_allclose(tr.p_light, 1.0, atol=1e-6)
    # Per cell: integral of cos over the cell (upper hemisphere) by fine quadrature.
    rng = np.random.default_rng(6)
    d = unit_rows(rng.normal(size=(2_000_000, 3)))
    w = np.maximum(d[:, 2], 0) * 4 * np.pi / len(d)
    ref = np.bincount(basis.cell_of(d), w, minlength=basis.size)
    got = tr.distant[:, 0, :].mean(axis=0)
    assert np.abs(got - ref).max() < 0.01 * np.pi
    assert np.abs(got - ref).sum() < 0.05 * np.pi

    # Spherical harmonics: Y00 integrates to pi Y00, Y10 to sqrt(3 / 4 pi) 2 pi / 3.
    _, _, tr_sh = _open_sky_transfer(sky, SHBasis(3))
    np.testing.assert_allclose(tr_sh.distant[:, 0, 0], np.pi / (2 * np.sqrt(np.pi)), rtol=1e-9)
    np.testing.assert_allclose(
        tr_sh.distant[:, 0, 2], np.sqrt(3 / (4 * np.pi)) * 2 * np.pi / 3, rtol=0.01
    )


def test_distant_rectangular_window_form_factor_and_pane_vertices():
    basis = CubemapBasis(4)
    h, a, b = 1.5, 0.8, 0.5
    win = WindowOpening("w", [0, 0, h], [a, 0, 0], [0, b, 0], [0, 0, -1.0])
    # A ceiling with a hole where the window is.
    ceiling = grid_plane(4.0, 0.1, z=h, up=False)
    centres = ceiling.triangles_center
    keep = ~((np.abs(centres[:, 0]) < a) & (np.abs(centres[:, 1]) < b))
    ceiling = trimesh.Trimesh(ceiling.vertices, ceiling.faces[keep])
    recv, mesh, tr = _open_sky_transfer(win, basis, ceiling=ceiling)
    x, y = mesh.vertices[recv, 0], mesh.vertices[recv, 1]
    ff = np.array(
        [rect_ff_offset(-a - xi, a - xi, -b - yi, b - yi, h) for xi, yi in zip(x, y, strict=True)]
    )
    # Monte-Carlo error at 1024 jittered rays: a few per cent per vertex (see the area test).
    np.testing.assert_allclose(tr.distant.sum(axis=(1, 2)), np.pi * ff, rtol=0.07)
    assert abs(np.mean(tr.distant.sum(axis=(1, 2)) / (np.pi * ff)) - 1) < 0.015
    np.testing.assert_allclose(tr.p_light * np.pi, tr.distant.sum(axis=(1, 2)), rtol=1e-12)
    # Rays escaping past the ceiling's outer edge are holes: unobserved.
    outside = 1 - np.array(
        [rect_ff_offset(-4 - xi, 4 - xi, -4 - yi, 4 - yi, h) for xi, yi in zip(x, y, strict=True)]
    )
    np.testing.assert_allclose(tr.p_unobserved, outside, rtol=0.1, atol=0.002)
    # A glazed pane: window-flagged vertices in place of the opening give the same transfer.
    pane = grid_plane(1.0, 0.1, z=h, up=False)
    pane = trimesh.Trimesh(pane.vertices * [a, b, 1.0], pane.faces)
    _, _, tr_pane = _open_sky_transfer(win, basis, pane=pane, ceiling=ceiling)
    np.testing.assert_allclose(tr_pane.distant.sum(axis=(1, 2)), np.pi * ff, rtol=0.07)
    assert np.abs(tr_pane.distant - tr.distant).max() < 0.02


def _inward_box() -> trimesh.Trimesh:
    box = trimesh.creation.box(extents=(4.0, 3.0, 2.5)).subdivide_to_size(0.25)
    box.invert()  # faces point into the room
    return box


def test_indirect_closed_box_uniform_and_rescaled():
    box = _inward_box()
    nv = len(box.vertices)
    rad = np.tile([1.0, 2.0, 0.5], (nv, 1))
    recv = np.flatnonzero(box.vertices[:, 2] < -1.2)
    args = (vertex_normals(box), rad)
    none = np.full(nv, -1)
    tr = hemisphere_transfer(
        RayCaster(box), box, recv, *args, np.ones(nv, bool), none, [], None, rays_per_vertex=64
    )
    np.testing.assert_allclose(tr.indirect, np.pi * rad[recv], rtol=1e-12)
    np.testing.assert_allclose(tr.p_observed, 1.0)
    # A ray count with no near-square grid takes the Latin-hypercube path; progress reports.
    calls = []
    odd = hemisphere_transfer(
        RayCaster(box), box, recv, *args, np.ones(nv, bool), none, [], None,
        rays_per_vertex=14, progress=lambda d, n: calls.append((d, n)), batch_rays=14 * 50,
    )  # fmt: skip
    np.testing.assert_allclose(odd.indirect, np.pi * rad[recv], rtol=1e-12)
    assert calls[-1] == (len(recv), len(recv)) and len(calls) == -(-len(recv) // 50)
    # Half the walls unobserved: eq. 5.9 recovers pi L.
    half = box.vertices[:, 0] > 0.1
    tr2 = hemisphere_transfer(
        RayCaster(box), box, recv, *args, ~half, none, [], None, rays_per_vertex=64
    )
    assert 0.2 < tr2.p_unobserved.mean() < 0.8
    np.testing.assert_allclose(tr2.indirect_rescaled(), np.pi * rad[recv], rtol=1e-9)


def test_indirect_linear_radiance_matches_area_quadrature():
    """E = integral over the walls of L cos cos / r^2 dA, by a fine deterministic quadrature."""
    box = _inward_box()
    nv = len(box.vertices)
    lo, hi = box.bounds

    def radiance(x):  # linear in position: barycentric interpolation is exact
        return 1.0 + 0.4 * (x[:, 2] - lo[2]) + 0.1 * x[:, 0]

    rad = np.repeat(radiance(box.vertices)[:, None], 3, axis=1)
    v = box.vertices
    recv = np.flatnonzero(
        (v[:, 2] < lo[2] + 1e-9) & (np.abs(v[:, 0]) < 1.2) & (np.abs(v[:, 1]) < 1.2)
    )
    recv = recv[:: max(1, len(recv) // 6)]
    tr = hemisphere_transfer(
        RayCaster(box), box, recv, vertex_normals(box), rad, np.ones(nv, bool),
        np.full(nv, -1), [], None, rays_per_vertex=2048, seed=7,
    )  # fmt: skip
    # Quadrature over the five faces other than the floor (midpoints of a fine grid).
    m = 400
    ref = np.zeros(len(recv))
    for axis in range(3):
        for side in (0, 1):
            if axis == 2 and side == 0:
                continue
            others = [k for k in range(3) if k != axis]
            s = (np.arange(m) + 0.5) / m
            g0 = lo[others[0]] + s * (hi[others[0]] - lo[others[0]])
            g1 = lo[others[1]] + s * (hi[others[1]] - lo[others[1]])
            a0, a1 = np.meshgrid(g0, g1, indexing="ij")
            x = np.zeros((m * m, 3))
            x[:, others[0]], x[:, others[1]] = a0.ravel(), a1.ravel()
            x[:, axis] = (lo, hi)[side][axis]
            da = (hi[others[0]] - lo[others[0]]) * (hi[others[1]] - lo[others[1]]) / m**2
            nx = np.zeros(3)
            nx[axis] = 1.0 if side == 0 else -1.0
            for i, v in enumerate(recv):
                r = x - box.vertices[v]
                d2 = np.einsum("ij,ij->i", r, r)
                cos_r = r[:, 2] / np.sqrt(d2)
                cos_x = -(r @ nx) / np.sqrt(d2)
                ref[i] += np.sum(radiance(x) * cos_r * cos_x / d2) * da
    np.testing.assert_allclose(tr.indirect[:, 0], ref, rtol=0.01)


def test_back_faces_and_holes_are_unobserved():
    floor = grid_plane(1.0, 0.25)
    lid = grid_plane(20.0, 5.0, z=1.0, up=True)  # its back face looks down at the floor
    mesh = trimesh.util.concatenate([floor, lid])
    nv = len(mesh.vertices)
    recv = _receivers(mesh, 0.5)
    tr = hemisphere_transfer(
        RayCaster(mesh), mesh, recv, vertex_normals(mesh), np.ones((nv, 3)), np.ones(nv, bool),
        np.full(nv, -1), [], None, rays_per_vertex=256,
    )  # fmt: skip
    assert (tr.indirect == 0).all()
    np.testing.assert_allclose(tr.p_unobserved, 1.0)


def test_window_from_layout_in_mesh_frame():
    c, s = np.cos(0.3), np.sin(0.3)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])  # aligned = rot @ mesh
    layout = {
        "rotation": rot.tolist(),
        "rooms": [
            {
                "name": "room0",
                "walls": [
                    {"start": [0, 0], "end": [4, 0], "inward_normal": [0, 1]},
                    {"start": [4, 0], "end": [4, 3], "inward_normal": [-1, 0]},
                ],
                "openings": [
                    {"kind": "door", "wall": 0, "s0": 0.2, "s1": 1.0, "z0": 0, "z1": 2, "depth": 0},
                    {"kind": "window", "wall": 1, "s0": 1.0, "s1": 2.0, "z0": 0.9, "z1": 2.1,
                     "depth": 0.2},
                ],
            }
        ],
    }  # fmt: skip
    (w,) = WindowOpening.from_layout(layout)
    np.testing.assert_allclose(rot @ w.centre, [4.2, 1.5, 1.5], atol=1e-12)
    np.testing.assert_allclose(rot @ w.normal, [-1, 0, 0], atol=1e-12)
    assert w.area == pytest.approx(1.2)
    (flat,) = WindowOpening.from_layout(layout, at_depth=False)
    np.testing.assert_allclose(rot @ flat.centre, [4.0, 1.5, 1.5], atol=1e-12)
    with pytest.raises(ReroomError, match="layout.json"):
        WindowOpening.from_layout({"rooms": [{"openings": []}]})


def test_bad_input_names_the_problem():
    box = _inward_box()
    nv = len(box.vertices)
    with pytest.raises(ReroomError, match="radiance"):
        hemisphere_transfer(
            RayCaster(box), box, [0], vertex_normals(box), np.zeros((3, 3)), np.ones(nv, bool),
            np.full(nv, -1), [], None,
        )  # fmt: skip


def test_line_light_inside_its_own_tube_is_not_shadowed():
    plane = grid_plane(2.0, 0.25)
    tube = trimesh.creation.cylinder(radius=0.016, segment=[[-0.6, 0, 2.0], [0.6, 0, 2.0]])
    p = plane.vertices
    n = np.tile([0.0, 0.0, 1.0], (len(p), 1))
    args = ([-0.6, 0, 2.0], [0.6, 0, 2.0], [0, 0, 1], InclinationBasis(32), 16)
    free = line_light_transfer(RayCaster(plane), p, n, *args)
    caster = RayCaster(trimesh.util.concatenate([plane, tube]))
    np.testing.assert_allclose(line_light_transfer(caster, p, n, *args), free, rtol=1e-12)
    # Without clearance the tube's own mesh hides the line from every receiver.
    assert line_light_transfer(caster, p, n, *args, clearance=0.0).sum() == 0


def test_kernel_window_test_matches_reference():
    from reroom.invert import _kernels as K
    from reroom.invert.transfer import _region_arrays, _window_arrays
    from reroom.invert.windows import rays_through_windows

    rng = np.random.default_rng(8)
    wins = [
        WindowOpening("a", [0, 0, 1.0], [0.5, 0, 0], [0, 0.3, 0], [0, 0, -1.0]),
        WindowOpening("b", [1.0, 0, 0.5], [0, 0.4, 0], [0, 0, 0.3], [-1.0, 0, 0]),
    ]
    n = 20000
    org = rng.uniform(-0.5, 0.5, (n, 3))
    dirs = unit_rows(rng.normal(size=(n, 3)))
    t_hit = np.where(rng.random(n) < 0.5, np.inf, rng.uniform(0, 2, n))
    ref = rays_through_windows(org, dirs, t_hit, wins, tolerance=0.02)
    through, pane = np.empty(n, np.int64), np.empty(n, bool)
    nv = 3
    K.accumulate(
        n, org, dirs, t_hit, np.full(n, -1), np.zeros((n, 2)), np.zeros((1, 3), np.int32),
        np.zeros((1, 3)), np.zeros((nv, 8)), *_window_arrays(wins), 0.02, *_region_arrays(None, 0),
        np.zeros((1, 3)), np.zeros(1),
        np.zeros(1), np.zeros(1), np.zeros((1, 1)), through, pane,
    )  # fmt: skip
    assert (ref >= 0).sum() > 1000 and (ref == 1).sum() > 100
    np.testing.assert_array_equal(through, ref)


def test_voxel_receivers_and_spread_transfer():
    from reroom.invert import spread_transfer, voxel_receivers

    box = _inward_box()
    nv = len(box.vertices)
    normals = vertex_normals(box)
    rad = np.repeat((1.0 + 0.3 * box.vertices[:, 2])[:, None], 3, axis=1)
    everything = np.arange(nv)
    sub = voxel_receivers(box.vertices, normals, everything, 0.5)
    # One receiver per occupied (voxel, octant) cell.
    key = np.c_[np.floor(box.vertices / 0.5).astype(int), (normals > 0) @ [1, 2, 4]]
    assert len(sub) == len(np.unique(key, axis=0)) < nv / 3
    args = (normals, rad, np.ones(nv, bool), np.full(nv, -1), [], None)
    caster = RayCaster(box)
    full = hemisphere_transfer(caster, box, everything, *args, rays_per_vertex=256, seed=1)
    part = hemisphere_transfer(caster, box, sub, *args, rays_per_vertex=256, seed=1)
    spread = spread_transfer(part, box.vertices, normals, everything)
    assert (spread.vertices == everything).all()
    # Receivers copy themselves; others copy a neighbour on the same face (similar normal).
    at = np.searchsorted(everything, sub)
    np.testing.assert_array_equal(spread.indirect[at], part.indirect)
    flat = np.abs(normals).max(axis=1) > 0.99
    rel = np.abs(spread.indirect[flat, 0] / full.indirect[flat, 0] - 1)
    assert np.median(rel) < 0.05 and rel.max() < 0.3


def test_inset_points_move_border_vertices_inwards_only():
    from reroom.invert.transfer import inset_points

    # A 5x5-vertex grid on z = 0 (edge 0.25 m): interior vertices stay, border ones move
    # into the grid, by at most inset x their mean edge length.
    xs = np.linspace(0.0, 1.0, 5)
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    verts = np.c_[gx.ravel(), gy.ravel(), np.zeros(25)]
    faces = []
    for i in range(4):
        for j in range(4):
            a, b, c, d = i * 5 + j, (i + 1) * 5 + j, (i + 1) * 5 + j + 1, i * 5 + j + 1
            faces += [[a, b, c], [a, c, d]]
    mesh = trimesh.Trimesh(verts, np.array(faces), process=False)
    idx = np.arange(25)
    normals = np.tile([0.0, 0.0, 1.0], (25, 1))
    moved = inset_points(mesh, idx, normals, inset=0.25)
    shift = moved - verts
    border = (gx.ravel() == 0) | (gx.ravel() == 1) | (gy.ravel() == 0) | (gy.ravel() == 1)
    assert np.allclose(shift[:, 2], 0.0)
    np.testing.assert_allclose(shift[~border], 0.0, atol=1e-12)
    assert np.all(np.linalg.norm(shift[border], axis=1) > 0.01)
    assert np.all(np.linalg.norm(shift, axis=1) <= 0.25 * 0.25 * np.sqrt(2) + 1e-12)
    # border points move into the square, never out of it
    assert np.all((moved[:, :2] >= -1e-12) & (moved[:, :2] <= 1 + 1e-12))
    assert np.all(moved[border & (gx.ravel() == 0), 0] > 0)
    np.testing.assert_allclose(inset_points(mesh, idx, normals, inset=0.0), verts)


def test_point_geometry_without_occlusion_is_the_unshadowed_bound():
    """``occlusion=False`` (the photo fit's cheap first pass) differs from the shadowed
    geometry exactly where a blocker hides the light, and there it is the larger."""
    from reroom.invert.direct import _point_geometry

    caster, p, n = _floor_under_blocker((0.4, 0.4, 0.05), [0.0, 0.0, 1.0])
    args = (caster, p, n, [0.0, 0.0, 2.0], [0.0, 0.0, 1.0], None, 0.0, 0.0)
    shadowed, cos_s = _point_geometry(*args)
    free, cos_f = _point_geometry(*args, occlusion=False)
    np.testing.assert_array_equal(cos_s, cos_f)
    hidden = shadowed == 0
    assert 20 < hidden.sum() < len(p) // 2  # the blocker's shadow under the light
    np.testing.assert_array_equal(shadowed[~hidden], free[~hidden])
    assert np.all(free[hidden] > 0)
