"""Receiver normals averaged over a radius (reroom.invert.normals)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from reroom.hdr.observe import vertex_normals
from reroom.invert.normals import (
    AUTO_NOISE_DEG,
    AUTO_RADIUS,
    normal_lean_deg,
    receiver_normals,
    smoothed_vertex_normals,
)


def _noisy_grid(n: int = 60, step: float = 0.03, noise: float = 0.006, seed: int = 0):
    """A flat 1.8 m square in z = 0 (normal +z) with its vertices jittered in z, as a
    TSDF leaves a wall."""
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.arange(n) * step, np.arange(n) * step, indexing="ij")
    v = np.stack([x.ravel(), y.ravel(), rng.normal(0, noise, n * n)], 1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    f = np.concatenate(
        [np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)]
    )
    return trimesh.Trimesh(v, f, process=False)


def _tilt_deg(normals: np.ndarray, axis: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(normals @ axis, -1.0, 1.0)))


def test_a_noisy_plane_gets_its_plane_normal_back():
    mesh = _noisy_grid()
    inner = np.all((mesh.vertices[:, :2] > 0.2) & (mesh.vertices[:, :2] < 1.55), axis=1)
    z = np.array([0.0, 0.0, 1.0])
    ring = _tilt_deg(vertex_normals(mesh)[inner], z)
    smooth = _tilt_deg(smoothed_vertex_normals(mesh, 0.1)[inner], z)
    assert np.median(ring) > 5.0  # the noise the filter is for
    assert np.median(smooth) < 0.25 * np.median(ring)
    assert np.allclose(np.linalg.norm(smoothed_vertex_normals(mesh, 0.1), axis=1), 1.0)


def test_radius_zero_is_the_one_ring_and_bad_values_are_refused():
    mesh = _noisy_grid(n=10)
    np.testing.assert_array_equal(smoothed_vertex_normals(mesh, 0.0), vertex_normals(mesh))
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="radius"):
            smoothed_vertex_normals(mesh, bad)
    with pytest.raises(ValueError, match="min_agreement"):
        smoothed_vertex_normals(mesh, 0.1, min_agreement=2.0)
    with pytest.raises(ValueError, match="steps"):
        smoothed_vertex_normals(mesh, 0.1, steps=0)


def test_a_crease_stays_sharp():
    # A floor (normal +z) meeting a wall (normal +x) at a right angle: a floor vertex
    # 3 cm from the corner must keep the floor's normal, not lean toward the wall's,
    # though the wall's faces are within the radius.
    box = trimesh.creation.box(extents=[2.0, 2.0, 2.0])
    box = box.subdivide_to_size(0.03)
    box = trimesh.Trimesh(box.vertices, box.faces, process=True)
    n = smoothed_vertex_normals(box, 0.1)
    ring = vertex_normals(box)
    v = box.vertices
    top_near_edge = (
        (np.abs(v[:, 2] - 1.0) < 1e-9)
        & (np.abs(v[:, 1]) < 0.9)
        & (np.abs(v[:, 0] - 1.0) < 0.05)
        & (np.abs(v[:, 0] - 1.0) > 0.0)
    )
    assert top_near_edge.sum() > 10
    assert np.all(_tilt_deg(n[top_near_edge], np.array([0.0, 0.0, 1.0])) < 1.0)
    # and the wall's vertices beside the same edge keep the wall's
    side_near_edge = (
        (np.abs(v[:, 0] - 1.0) < 1e-9) & (np.abs(v[:, 1]) < 0.9) & (np.abs(v[:, 2] - 1.0) < 0.05)
    ) & (np.abs(v[:, 2] - 1.0) > 0.0)
    assert side_near_edge.sum() > 10
    assert np.all(_tilt_deg(n[side_near_edge], np.array([1.0, 0.0, 0.0])) < 1.0)
    assert not np.allclose(ring, n)  # the one-ring normals of the edges are 45°


def test_auto_diffuses_only_a_noisy_floor():
    noisy = _noisy_grid(noise=0.006)
    clean = _noisy_grid(noise=0.0)
    floor = np.ones(len(noisy.vertices), bool)
    n, info = receiver_normals(noisy, None, floor)
    assert info["floor_lean_deg"] > AUTO_NOISE_DEG and info["radius"] == AUTO_RADIUS
    np.testing.assert_allclose(n, smoothed_vertex_normals(noisy, AUTO_RADIUS))
    n, info = receiver_normals(clean, None, floor)
    assert info["floor_lean_deg"] < 0.01 and info["radius"] == 0.0
    np.testing.assert_array_equal(n, vertex_normals(clean))
    # explicit radii are taken as given; no floor: auto keeps the one-ring normals
    assert receiver_normals(clean, 0.05, floor)[1]["radius"] == 0.05
    n, info = receiver_normals(noisy, None, np.zeros(len(floor), bool))
    assert info == {"floor_lean_deg": None, "radius": 0.0}
    assert normal_lean_deg(vertex_normals(noisy), floor) == info_lean(noisy)


def info_lean(mesh) -> float:
    """The lean by hand: median angle from the mean normal."""
    n = vertex_normals(mesh)
    m = n.sum(0) / np.linalg.norm(n.sum(0))
    return float(np.degrees(np.arccos(np.median(np.clip(n @ m, -1, 1)))))
