"""Vertex-to-pixel matching with visibility (reroom.hdr.observe)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from reroom.hdr.linearize import response_lut
from reroom.hdr.observe import (
    NEAR_IMAGE_EDGE,
    ObserveOptions,
    collect_observations,
    vertex_normals,
)
from reroom.hdr.synthetic import box_room, write_projected_scan
from reroom.rays import RayCaster
from reroom.scan import Intrinsics, load_scan, look_at

SIZE = (4.0, 3.0, 2.5)


@pytest.fixture(scope="module")
def box_scan(tmp_path_factory) -> Path:
    """A box room with a block on the floor, seen by 6 frames; the radiance has a sharp edge."""
    v, f = box_room(SIZE, spacing=0.1)
    rad = np.full((len(v), 3), 0.3)
    rad[v[:, 0] < 1.0] = 0.05  # a dark band on every wall: a strong texture edge at x = 1
    poses = [
        look_at([0.5, 1.5, 1.5], [4.0, 1.5, 0.6]),  # looks at the block: hides part of the wall
        look_at([2.0, 0.4, 1.4], [2.0, 3.0, 1.2]),
        look_at([3.5, 2.5, 1.6], [0.0, 0.5, 1.0]),
        look_at([2.0, 1.5, 1.5], [2.0, 1.5, 5.0], up=[0, 1, 0]),  # the ceiling
        look_at([1.0, 1.0, 1.2], [0.0, 0.0, 1.2]),
        look_at([2.5, 1.0, 1.5], [1.0, 3.0, 0.5]),
    ]
    out = tmp_path_factory.mktemp("hdr") / "box"
    write_projected_scan(
        out,
        v,
        f,
        rad,
        poses,
        Intrinsics.from_fov(64, 48, 70.0),
        scales=np.ones((6, 3)),
        noise_seed=None,
    )
    return out


@pytest.mark.parametrize("visibility", ["depth", "rays"])
def test_hidden_vertices_are_not_observed(box_scan, visibility):
    scan = load_scan(box_scan)
    lut = response_lut("auto", scan.meta)
    opt = ObserveOptions(visibility=visibility, gradient_threshold=np.inf)
    obs = collect_observations(scan.frames[:1], scan.mesh, lut, opt)
    v = np.asarray(scan.mesh.vertices)
    seen = np.zeros(len(v), bool)
    seen[obs.vertex] = True
    # The wall x = 4 behind the block (as seen from frame 0) is hidden.
    eye = scan.frames[0].center
    caster = RayCaster(scan.mesh)
    wall = np.flatnonzero((np.abs(v[:, 0] - SIZE[0]) < 1e-9) & (v[:, 2] < 0.6))
    wall = wall[(np.abs(v[wall, 1] - 1.5) < 0.15) & (v[wall, 2] > 0.05)]
    d = v[wall] - eye
    hit = caster.intersect(np.broadcast_to(eye, d.shape), d)
    hidden = wall[hit.t < np.linalg.norm(d, axis=1) - 0.05]
    assert len(hidden) > 3
    assert not seen[hidden].any()
    # The block's front face is seen.
    front = np.flatnonzero(np.abs(v[:, 0] - (SIZE[0] * 0.55 - 0.3)) < 1e-6)
    assert seen[front].sum() > 3
    # Samples are the pixels the vertices project to.
    assert obs.value.dtype == np.uint8 and obs.geometry.dtype == np.float32
    assert np.all(obs.geometry > 0)
    assert obs.frame_stats["visible"][0] <= obs.frame_stats["candidates"][0]


@pytest.mark.parametrize("visibility", ["depth", "rays"])
def test_samples_are_truly_visible(box_scan, visibility):
    """Every sample is a vertex that the camera ray through it reaches first."""
    scan = load_scan(box_scan)
    lut = response_lut("auto", scan.meta)
    opt = ObserveOptions(visibility=visibility, gradient_threshold=np.inf, keep_flagged=False)
    obs = collect_observations(scan.frames, scan.mesh, lut, opt)
    caster = RayCaster(scan.mesh)
    v = np.asarray(scan.mesh.vertices)
    eyes = np.array([f.center for f in scan.frames])[obs.frame]
    d = v[obs.vertex] - eyes
    dist = np.linalg.norm(d, axis=1)
    hit = caster.intersect(eyes, d)
    truly = hit.t > dist * (1 - 0.01)
    assert truly.mean() > 0.995
    # Most candidates are visible here, and most visible ones are kept (the depth
    # test drops those at depth edges and creases).
    assert obs.frame_stats["visible"].sum() > 0.75 * obs.frame_stats["candidates"].sum()
    assert len(obs) > 0.9 * obs.frame_stats["visible"].sum()


def test_gradient_test_drops_samples_at_texture_edges(box_scan):
    scan = load_scan(box_scan)
    lut = response_lut("auto", scan.meta)
    v = np.asarray(scan.mesh.vertices)
    keep_all = collect_observations(
        scan.frames, scan.mesh, lut, ObserveOptions(gradient_threshold=np.inf)
    )
    filtered = collect_observations(scan.frames, scan.mesh, lut, ObserveOptions())
    near_edge = np.abs(v[:, 0] - 1.0) < 0.06
    assert not np.any(keep_all.flags & NEAR_IMAGE_EDGE)  # the test is off: only depth edges
    frac_all = near_edge[keep_all.vertex].mean()
    frac_clean = near_edge[filtered.vertex[filtered.clean]].mean()
    assert frac_clean < 0.3 * frac_all
    flagged = filtered.flags & NEAR_IMAGE_EDGE > 0
    # Flagged samples lie near the edge (within a few pixels, which at grazing angles
    # span tens of centimetres of wall).
    assert (np.abs(v[filtered.vertex[flagged], 0] - 1.0) < 0.5).mean() > 0.8
    # Flat areas stay clean; flagged samples are kept (for reprojection) unless asked not to.
    assert filtered.clean.sum() > 0.6 * len(keep_all)
    assert len(filtered) == len(keep_all)
    dropped = collect_observations(scan.frames, scan.mesh, lut, ObserveOptions(keep_flagged=False))
    assert len(dropped) == filtered.clean.sum() and dropped.clean.all()


def test_unreadable_frame_is_skipped_with_warning(box_scan, tmp_path):
    import shutil

    scan_dir = tmp_path / "broken"
    shutil.copytree(box_scan, scan_dir)
    (scan_dir / "images" / "frame_00001.png").write_bytes(
        (scan_dir / "images" / "frame_00001.png").read_bytes()[:200]
    )
    scan = load_scan(scan_dir)
    lut = response_lut("auto", scan.meta)
    with pytest.warns(UserWarning, match="frame 1: skipped"):
        obs = collect_observations(scan.frames, scan.mesh, lut)
    assert obs.frame_stats["kept"][1] == 0
    assert obs.frame_stats["error"][1]
    assert obs.frame_stats["kept"][0] > 0


def test_vertex_normals_and_degenerate_vertices():
    mesh = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5]], [[0, 1, 2]], process=False)
    n = vertex_normals(mesh)
    np.testing.assert_allclose(n[:3], [[0, 0, 1]] * 3)
    np.testing.assert_allclose(n[3], 0.0)  # a vertex of no face
