"""The window's transfer by sampling the opening (reroom.invert.portal) against references."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from meshes import grid_plane
from test_invert_transfer import rect_ff_offset

from reroom.hdr.observe import vertex_normals
from reroom.invert import CubemapBasis, SHBasis, WindowOpening, hemisphere_transfer
from reroom.invert.portal import window_portal_transfer
from reroom.rays import RayCaster

H, A, B = 1.5, 0.8, 0.5  # a 1.6 x 1.0 m opening 1.5 m above a floor


def _room(with_pane: bool = False):
    """A floor under a ceiling with a hole (the window), a plate shadowing part of the
    floor, and optionally a glazed pane filling the hole."""
    floor = grid_plane(1.0, 0.25)
    ceiling = grid_plane(4.0, 0.1, z=H, up=False)
    c = ceiling.triangles_center
    keep = ~((np.abs(c[:, 0]) < A) & (np.abs(c[:, 1]) < B))
    ceiling = trimesh.Trimesh(ceiling.vertices, ceiling.faces[keep])
    plate = trimesh.creation.box([0.6, 0.6, 0.01])
    plate.apply_translation([0.9, 0.0, 0.6])
    parts = [floor, ceiling, plate]
    if with_pane:
        pane = grid_plane(1.0, 0.1, z=H, up=False)
        parts.append(trimesh.Trimesh(pane.vertices * [A, B, 1.0], pane.faces))
    mesh = trimesh.util.concatenate(parts)
    window = WindowOpening("w", [0, 0, H], [A, 0, 0], [0, B, 0], [0, 0, -1.0])
    recv = np.flatnonzero(
        (np.abs(mesh.vertices[:, 2]) < 1e-9) & (np.hypot(*mesh.vertices[:, :2].T) <= 1.0)
    )
    return mesh, window, recv


def test_portal_matches_the_form_factor_unshadowed():
    mesh, window, recv = _room()
    p = mesh.vertices[recv]
    free = p[:, 0] < 0.3  # the plate shadows x > ~0.3
    f = window_portal_transfer(
        RayCaster(mesh), window, CubemapBasis(4), p, np.tile([0, 0, 1.0], (len(p), 1)), 256
    )
    ff = np.array([rect_ff_offset(-A - x, A - x, -B - y, B - y, H) for x, y, _ in p])
    # Stratified samples of a smooth integrand: well under 1 % per receiver.
    np.testing.assert_allclose(f.sum(axis=1)[free], np.pi * ff[free], rtol=0.01)
    ratio = f.sum(axis=1) / (np.pi * ff)
    assert (ratio[~free] < 1.01).all()  # at most the rim of the plate's shadow ...
    assert (ratio[p[:, 0] > 0.6] < 0.9).all()  # ... and deep in it under the plate


@pytest.mark.parametrize("basis", [CubemapBasis(4), SHBasis(3)], ids=["cubemap", "sh"])
def test_portal_matches_brute_force_hemisphere_rays_per_basis_function(basis):
    mesh, window, recv = _room()
    nv = len(mesh.vertices)
    caster = RayCaster(mesh)
    normals = vertex_normals(mesh)
    hemi = hemisphere_transfer(
        caster, mesh, recv, normals, np.zeros((nv, 3)), np.ones(nv, bool), np.full(nv, -1),
        [window], basis, rays_per_vertex=16384, seed=2, window_tolerance=0.0,
    )  # fmt: skip
    portal = window_portal_transfer(
        caster, window, basis, mesh.vertices[recv], normals[recv], 1024, seed=3
    )
    ref = hemi.distant[:, 0, :]
    scale = np.abs(ref).sum(axis=1).max()
    # Shadowed and unshadowed receivers alike, basis function by basis function: both are
    # estimates of one integral (16384 rays leave ~1 % noise where the window is small).
    assert np.abs(portal - ref).max() < 0.03 * scale
    np.testing.assert_allclose(portal.sum(axis=0), ref.sum(axis=0), atol=0.01 * np.abs(ref).sum())


def test_portal_passes_the_windows_own_pane_and_nothing_else():
    mesh, window, recv = _room(with_pane=True)
    open_mesh, _, _ = _room()
    nf = len(mesh.faces)
    pane = np.zeros(nf, bool)
    pane[len(open_mesh.faces) :] = True
    p = mesh.vertices[recv]
    n = np.tile([0, 0, 1.0], (len(p), 1))
    basis = CubemapBasis(4)
    opened = window_portal_transfer(RayCaster(open_mesh), window, basis, p, n, 256)
    # A pane in the opening's plane does not block within the tolerance ...
    glazed = window_portal_transfer(RayCaster(mesh), window, basis, p, n, 256)
    np.testing.assert_allclose(glazed, opened, atol=1e-12)
    # ... and one a little in front of it (and wider: nothing slips past its rim) is
    # passed when flagged as the window's surface.
    low = mesh.copy()
    on = np.unique(low.faces[pane])
    low.vertices[on] = low.vertices[on] * [1.5, 1.5, 1.0] - [0, 0, 0.1]
    blocked = window_portal_transfer(RayCaster(low), window, basis, p, n, 256)
    assert blocked.sum() < 1e-9
    flagged = window_portal_transfer(RayCaster(low), window, basis, p, n, 256, pane_faces=pane)
    np.testing.assert_allclose(flagged, opened, atol=1e-12)


def test_portal_receivers_behind_or_facing_away_get_nothing_and_bad_input_is_named():
    mesh, window, _ = _room()
    caster = RayCaster(mesh)
    basis = CubemapBasis(2)
    pts = np.array([[0, 0, 2.0], [0, 0, 0.0]])  # above the opening; on the floor facing down
    nrm = np.array([[0, 0, 1.0], [0, 0, -1.0]])
    assert not window_portal_transfer(caster, window, basis, pts, nrm, 16).any()
    assert window_portal_transfer(
        caster, window, basis, np.zeros((0, 3)), np.zeros((0, 3))
    ).shape == (
        0,
        basis.size,
    )
    with pytest.raises(ValueError, match="samples"):
        window_portal_transfer(caster, window, basis, pts, nrm, 0)
    with pytest.raises(ValueError, match="non-zero"):
        window_portal_transfer(caster, window, basis, pts, np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        window_portal_transfer(caster, window, basis, pts, nrm[:1])


def test_portal_direction_weight_scales_each_direction():
    mesh, window, recv = _room()
    caster, basis = RayCaster(mesh), CubemapBasis(4)
    p, n = mesh.vertices[recv], np.tile([0, 0, 1.0], (len(recv), 1))
    flat = window_portal_transfer(caster, window, basis, p, n, 64, seed=1)
    # The same samples (same seed): a constant weight scales the transfer exactly.
    twice = window_portal_transfer(
        caster, window, basis, p, n, 64, seed=1, direction_weight=lambda d: np.full(len(d), 2.0)
    )
    np.testing.assert_allclose(twice, 2.0 * flat, rtol=1e-12)
    # A weight that keeps the directions towards +x only: receivers left of the opening
    # (x < -A, looking up and to the right through it) keep all their light, those right
    # of it none.
    east = window_portal_transfer(
        caster, window, basis, p, n, 64, seed=1,
        direction_weight=lambda d: (d[:, 0] > 0).astype(float),
    )  # fmt: skip
    left, right = p[:, 0] < -A, p[:, 0] > A
    assert left.any() and right.any()
    np.testing.assert_allclose(east[left], flat[left], rtol=1e-12)
    assert np.all(east[right] == 0) and np.any(flat[right] > 0)


def test_window_axes_rounded_in_a_file_are_made_perpendicular_and_skewed_ones_refused():
    """A window of a rotated room, its axes rounded to 6 decimals as lights.json keeps
    them (the real slambook2 scan's window failed this check before session 20)."""
    from reroom.errors import ReroomError

    u = np.round([-0.154928, 0.31384, -0.00138], 6)
    v = np.round([-0.002343, -0.000189, 0.219987], 6)
    assert abs(u @ v) / np.linalg.norm(u) / np.linalg.norm(v) > 1e-6  # off by rounding
    w = WindowOpening("w", [0, 7, 0.7], u, v, [-0.9, -0.44, -0.01])
    assert abs(w.half_u @ w.half_v) < 1e-15
    np.testing.assert_allclose(w.half_v, v, atol=1e-6)  # moved by the rounding only
    np.testing.assert_array_equal(w.half_u, u)
    with pytest.raises(ReroomError, match="not perpendicular"):
        WindowOpening("skewed", [0, 0, 1.0], [0.5, 0, 0], [0.05, 0.3, 0], [0, 0, -1.0])
