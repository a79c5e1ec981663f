"""The open fraction of a bulb in its shade (the shape prior of shaded point lights)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

from reroom.invert.basis import InclinationBasis
from reroom.invert.point_fixture import (
    inclination_directions,
    point_inside_fraction,
    point_open_fraction,
)
from reroom.rays import RayCaster

RADIUS, BELOW, ABOVE = 0.15, 0.10, 0.12  # a drum shade around a bulb at the origin


def _shade() -> trimesh.Trimesh:
    """An open drum (no top, no bottom), its wall two-sided as a scanned shell is."""
    drum = trimesh.creation.cylinder(radius=RADIUS, height=BELOW + ABOVE, sections=128)
    keep = np.abs(drum.face_normals[:, 2]) < 0.5  # the side wall only
    wall = trimesh.Trimesh(drum.vertices, drum.faces[keep], process=False)
    wall.apply_translation((0, 0, 0.5 * (ABOVE - BELOW)))
    inner = wall.copy()
    inner.invert()  # the lining, facing the bulb
    inner.apply_scale((0.99, 0.99, 1.0))
    return trimesh.util.concatenate([wall, inner])


def _analytic(basis: InclinationBasis) -> np.ndarray:
    """Open fraction per bin: the cones through the top and the bottom openings (the
    lining's radius: it is what a ray from the bulb meets first)."""
    r = 0.99 * RADIUS
    top, bottom = np.arctan2(r, ABOVE), np.pi - np.arctan2(r, BELOW)
    e = basis.bin_edges()
    out = []
    for lo, hi in zip(e[:-1], e[1:], strict=True):
        band = np.cos(lo) - np.cos(hi)  # solid angle / 2 pi
        open_top = max(0.0, np.cos(lo) - np.cos(min(hi, top))) if lo < top else 0.0
        open_bot = max(0.0, np.cos(max(lo, bottom)) - np.cos(hi)) if hi > bottom else 0.0
        out.append((open_top + open_bot) / band)
    return np.asarray(out)


def test_the_open_fraction_is_the_shade_openings_cones() -> None:
    basis = InclinationBasis(32)
    caster = RayCaster(_shade(), eps=1e-6)
    ours = point_open_fraction(caster.occluded, (0, 0, 0), (0, 0, 1), basis, 0.3, samples=4096)
    np.testing.assert_allclose(ours, _analytic(basis), atol=0.02)
    # A bare bulb: open everywhere.
    never = lambda p, d, tmax: np.zeros(len(p), bool)  # noqa: E731
    np.testing.assert_array_equal(point_open_fraction(never, (0, 0, 0), (0, 0, 1), basis, 0.3), 1)


def test_directions_are_in_their_bins_and_uniform_in_solid_angle() -> None:
    basis = InclinationBasis(8)
    axis = np.array([0.0, 0.6, 0.8])
    d = inclination_directions(axis, basis, 1024, seed=1)
    assert d.shape == (8, 1024, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=2), 1.0)
    bins = basis.bin_of(d @ axis)
    assert np.all(bins == np.arange(8)[:, None])
    # Stratified in cos(theta): each bin's mean cosine is its band's middle.
    e = np.cos(basis.bin_edges())
    np.testing.assert_allclose((d @ axis).mean(axis=1), 0.5 * (e[:-1] + e[1:]), atol=2e-3)
    with pytest.raises(ValueError, match="non-zero direction"):
        inclination_directions((0, 0, 0), basis, 16)


def test_a_bulb_inside_closed_geometry_sees_back_faces() -> None:
    assert point_inside_fraction(RayCaster(_shade(), eps=1e-6), (0, 0, 0), 0.3) == 0.0
    blob = trimesh.creation.box(extents=(0.3, 0.3, 0.25))  # a shade the scan filled in
    assert point_inside_fraction(RayCaster(blob, eps=1e-6), (0, 0, 0), 0.3) > 0.9


def test_the_pipeline_gives_the_prior_to_shaded_bulbs_only() -> None:
    from reroom.invert.pipeline import InvertOptions, _point_open_shape

    basis = InclinationBasis(32)
    lamp = SimpleNamespace(
        name="point0",
        geometry={"position": [0.0, 0.0, 0.0], "axis": [0.0, 0.0, 1.0]},
        evidence={"height_from": "pool edge"},
    )
    notes: list[str] = []
    shape, info = _point_open_shape(_shade(), lamp, basis, InvertOptions(), notes)
    assert not notes and shape is not None
    np.testing.assert_allclose(shape, _analytic(basis), atol=0.05)
    assert len(info["open_fraction"]) == 32
    # A downlight (no shade's evidence), the prior off, a shade the scan closed.
    down = SimpleNamespace(name="d", geometry=lamp.geometry, evidence={})
    assert _point_open_shape(_shade(), down, basis, InvertOptions(), []) == (None, {})
    off = InvertOptions(point_shape_prior=0.0)
    assert _point_open_shape(_shade(), lamp, basis, off, []) == (None, {})
    blob = trimesh.creation.box(extents=(0.3, 0.3, 0.25))
    shape, info = _point_open_shape(blob, lamp, basis, InvertOptions(), notes)
    assert shape is None and info["fixture_inside_fraction"] > 0.9
    assert "closed the shade of point light 'point0'" in notes[0]
