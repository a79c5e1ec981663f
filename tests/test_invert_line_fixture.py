"""The open fraction of a line light's tube in its fixture (the line lights' shape prior)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from reroom.invert.basis import LineBasis
from reroom.invert.line_fixture import (
    MAX_INSIDE_FRACTION,
    cos2_quantiles,
    inside_fraction,
    line_open_fraction,
    scan_fixture_caster,
)
from reroom.rays import RayCaster

P0, P1, UP = np.array([0.0, 0.0, 0.0]), np.array([1.2, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])


def _ceiling(height: float) -> RayCaster:
    """A wide horizontal plane ``height`` above the tube's axis, facing down at it."""
    plane = trimesh.Trimesh(
        [[-5, -5, height], [5, -5, height], [5, 5, height], [-5, 5, height]],
        [[0, 2, 1], [0, 3, 2]],
    )
    return RayCaster(plane, eps=1e-6)


def test_a_bare_tube_is_open_everywhere() -> None:
    basis = LineBasis(8, 3)
    never = lambda p, d, tmax: np.zeros(len(p), bool)  # noqa: E731
    np.testing.assert_array_equal(line_open_fraction(never, P0, P1, UP, 0.016, basis, 0.3), 1.0)


def test_a_plane_above_the_tube_closes_the_steep_upward_bins() -> None:
    # A thin tube under a plane 5 cm up, fixture reach 30 cm: a direction w is blocked
    # iff w_z = cos(theta) cos(phi) > 0.05 / 0.3. Check every bin against a direct
    # quadrature of that indicator (uniform in theta, cos^2-weighted in phi).
    basis = LineBasis(16, 3)
    h, reach = 0.05, 0.3
    got = line_open_fraction(
        _ceiling(h).occluded, P0, P1, UP, 1e-5, basis, reach, samples=16, angles=16
    ).reshape(16, 3)
    t_edges, p_edges = basis.theta_edges(), basis.phi_edges()
    for k in range(16):
        for j in range(3):
            theta = np.linspace(t_edges[k], t_edges[k + 1], 401)[:, None]
            phi = cos2_quantiles(p_edges[j], p_edges[j + 1], (np.arange(400) + 0.5) / 400)
            expected = np.mean(np.cos(theta) * np.cos(phi)[None, :] <= h / reach)
            assert got[k, j] == pytest.approx(expected, abs=0.06), (k, j)
    assert np.all(got[:4, 0] == 0.0)  # steep upward: always blocked
    assert np.all(got[8:] == 1.0)  # downward: never


def test_scan_fixture_drops_the_tube_itself() -> None:
    tube = trimesh.creation.cylinder(radius=0.016, segment=[P0, P1], sections=16)
    housing = trimesh.creation.box(extents=(1.3, 0.16, 0.01))
    housing.apply_translation((0.6, 0.0, 0.06))
    far = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    far.apply_translation((0.6, 2.0, 0.0))
    scan = trimesh.util.concatenate([tube, housing, far])
    caster = scan_fixture_caster(scan.vertices, scan.faces, P0, P1, 0.016, 0.3)
    assert caster.n_faces == len(housing.faces)  # neither the tube nor the far box
    basis = LineBasis(8, 1)
    frac = line_open_fraction(caster.occluded, P0, P1, UP, 0.016, basis, 0.3)
    assert frac[0] < 0.01 and np.all(frac[4:] == 1.0)  # a little leaves by the ends
    assert scan_fixture_caster(tube.vertices, tube.faces, P0, P1, 0.016, 0.3) is None


def test_bad_lines_raise() -> None:
    never = lambda p, d, tmax: np.zeros(len(p), bool)  # noqa: E731
    basis = LineBasis(4, 1)
    with pytest.raises(ValueError, match="zero length"):
        line_open_fraction(never, P0, P0, UP, 0.01, basis, 0.3)
    with pytest.raises(ValueError, match="parallel"):
        line_open_fraction(never, P0, P1, [1.0, 0, 0], 0.01, basis, 0.3)
    with pytest.raises(ValueError, match="radius must be positive"):
        line_open_fraction(never, P0, P1, UP, 0.0, basis, 0.3)
    with pytest.raises(ValueError, match="zero length"):
        inside_fraction(_ceiling(0.05), P0, P0, 0.01, 0.3)


def test_a_tube_inside_a_closed_block_is_flagged() -> None:
    # A fused scan can close a baffles' channel into a block with the tube half inside it.
    block = trimesh.creation.box(extents=(1.4, 0.16, 0.12))
    block.apply_translation((0.6, 0.0, 0.06))  # bottom face at z = 0: the tube's axis
    caster = RayCaster(block, eps=1e-6)
    inside = inside_fraction(caster, P0, P1, 0.016, 0.3)
    assert 0.2 < inside < 0.6  # the upper half's rays leave the block through back faces
    assert inside > MAX_INSIDE_FRACTION
    # Under a housing (its underside faces the tube) every first hit is a front face.
    assert inside_fraction(_ceiling(0.05), P0, P1, 0.016, 0.3) == 0.0


def test_the_pipeline_drops_the_prior_for_an_unresolved_fixture() -> None:
    from reroom.invert.pipeline import InvertOptions, _line_open_shape

    geometry = {"p0": P0, "p1": P1, "d_perp": UP, "radius": 0.016}
    basis = LineBasis(8, 3)
    housing = trimesh.Trimesh(  # an underside 5 cm above the tube, facing it
        [[-0.1, -0.1, 0.05], [1.3, -0.1, 0.05], [1.3, 0.1, 0.05], [-0.1, 0.1, 0.05]],
        [[0, 2, 1], [0, 3, 2]],
    )
    notes: list[str] = []
    scan = Path("no-scan-here")
    shape, info, g = _line_open_shape(
        scan, housing, "tube", geometry, basis, InvertOptions(), notes
    )
    assert shape is not None and not notes and len(info["open_fraction"]) == 8 * 3
    assert g is geometry
    block = trimesh.creation.box(extents=(1.4, 0.16, 0.12))
    block.apply_translation((0.6, 0.0, 0.06))  # a fused channel: the tube half inside
    # Without the photos' fixture (tests/test_invert_line_photos.py has it with photos).
    no_photos = InvertOptions(line_photo_fixture=False)
    shape, info, _ = _line_open_shape(scan, block, "tube", geometry, basis, no_photos, notes)
    assert shape is None and info["fixture_inside_fraction"] > MAX_INSIDE_FRACTION
    assert "does not resolve the fixture of line light 'tube'" in notes[0]
    assert "no shape prior" in notes[0]
    off = InvertOptions(line_shape_prior=0.0)
    assert _line_open_shape(scan, housing, "tube", geometry, basis, off, []) == (None, {}, geometry)


def test_a_line_lights_fitting_reaches_its_detected_width() -> None:
    """A fused scan's tube and housing glow as one blob wider than the tube: the vertices
    within half that width (plus the margin) are the fitting, not receivers."""
    from reroom.invert.pipeline import _fixture_vertices
    from reroom.lights.lightset import Light

    g = {"p0": [0.0, 0.0, 2.5], "p1": [1.0, 0.0, 2.5], "d_perp": [0, 0, 1], "radius": 0.016}
    pts = np.array([[0.5, 0.0, 2.5 - d] for d in (0.06, 0.07, 0.075, 0.09)])
    bare = Light("line0", "line", "user", g, {}, "")
    assert _fixture_vertices(pts, [bare], 0.05).tolist() == [True, False, False, False]
    blob = Light("line0", "line", "detected", g, {"size_m": [1.0, 0.054]}, "")
    assert _fixture_vertices(pts, [blob], 0.05).tolist() == [True, True, True, False]
    thin = Light("line0", "line", "detected", g, {"size_m": [1.0, 0.02]}, "")
    assert _fixture_vertices(pts, [thin], 0.05).tolist() == [True, False, False, False]
