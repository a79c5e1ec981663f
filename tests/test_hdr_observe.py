"""Vertex-to-pixel matching with visibility (reroom.hdr.observe)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from reroom.hdr.linearize import response_lut
from reroom.hdr.observe import (
    EDGE_FLAGS,
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


@pytest.mark.parametrize("sampling", ["nearest", "bilinear", "box3"])
def test_footprint_test_keeps_values_where_every_pixel_sees_the_vertex(box_scan, sampling):
    """With (nearly) every sample flagged, the footprint test reads the same pixels as
    the sampling itself wherever they all see the vertex's surface."""
    from reroom.hdr.observe import FOREIGN_FOOTPRINT, MIXED_FOOTPRINT

    scan = load_scan(box_scan)
    lut = response_lut("auto", scan.meta)
    frames = scan.frames[:3]
    plain = collect_observations(
        frames, scan.mesh, lut, ObserveOptions(sampling=sampling, footprint_test=False)
    )
    tested = collect_observations(
        frames, scan.mesh, lut, ObserveOptions(sampling=sampling, gradient_threshold=-1.0)
    )
    assert np.array_equal(plain.vertex, tested.vertex)
    edge = (tested.flags & EDGE_FLAGS) != 0
    assert edge.mean() > 0.2  # (pixels of zero gradient stay clean, untested)
    whole = edge & ((tested.flags & (MIXED_FOOTPRINT | FOREIGN_FOOTPRINT)) == 0)
    assert whole.sum() > 0.6 * edge.sum()  # a box room: most footprints lie on one face
    diff = np.abs(plain.linear_values(whole) - tested.linear_values(whole))
    assert diff.max() < 1e-3
    if sampling == "nearest":  # one pixel: on the vertex's surface or not
        assert not np.any(tested.flags & MIXED_FOOTPRINT)


def _bar_scene(tmp_path, with_backplate: bool) -> tuple[Path, np.ndarray, np.ndarray]:
    """A dark bar 3 pixels wide (2 cm deep) in front of a bright wall (and, if asked, of
    a brighter plate 3 cm behind its front face, a separate piece of mesh), seen by
    three cameras."""
    from reroom.hdr.synthetic import _box

    pieces = [box_room(SIZE, spacing=0.1, obstacle=False)]
    pieces += _box((3.4, 1.46, 0.6), (3.42, 1.54, 1.9), 0.02, inward=False)
    n_room_and_bar = sum(len(p[0]) for p in pieces)
    if with_backplate:
        pieces += _box((3.43, 1.3, 0.5), (3.44, 1.7, 2.0), 0.04, inward=False)
    verts, faces, off = [], [], 0
    for pv, pf in pieces:
        verts.append(pv)
        faces.append(pf + off)
        off += len(pv)
    v, f = np.vstack(verts), np.vstack(faces)
    n_room = len(pieces[0][0])
    on_bar = (np.arange(len(v)) >= n_room) & (np.arange(len(v)) < n_room_and_bar)
    rad = np.full((len(v), 3), 0.5)
    rad[on_bar] = 0.02
    rad[n_room_and_bar:] = 0.9
    poses = [look_at([1.0, 1.5 + dy, 1.3], [4.0, 1.5, 1.2]) for dy in (-0.2, 0.0, 0.2)]
    scan_dir = write_projected_scan(
        tmp_path / f"bar{int(with_backplate)}",
        v,
        f,
        rad,
        poses,
        Intrinsics.from_fov(128, 96, 70.0),
        scales=np.ones((3, 3)),
        noise_seed=None,
    )
    # The bar's faces turned to the cameras (x = 3.4).
    return scan_dir, v, on_bar & (np.abs(v[:, 0] - 3.4) < 1e-9)


def _bar_error(scan_dir: Path, front: np.ndarray, test: bool) -> float:
    from reroom.hdr.reproject import reproject_radiance

    scan = load_scan(scan_dir)
    lut = response_lut("auto", scan.meta)
    obs = collect_observations(scan.frames, scan.mesh, lut, ObserveOptions(footprint_test=test))
    r = reproject_radiance(obs, np.ones((3, 3)), level_linear=lut)
    seen = front & r.observed
    assert seen.sum() > 10
    return float(np.median(r.radiance[seen, 1] / 0.02 - 1.0))


def test_footprint_test_reads_a_thin_bar_without_the_wall_behind(tmp_path):
    """The 3x3 average of the bar's samples mixes in the wall; the footprint test keeps
    the bar's own pixels."""
    scan_dir, _, front = _bar_scene(tmp_path, with_backplate=False)
    assert _bar_error(scan_dir, front, test=False) > 1.0  # twice the bar's radiance and more
    assert abs(_bar_error(scan_dir, front, test=True)) < 0.1


def test_footprint_test_tells_a_separate_piece_close_behind(tmp_path, monkeypatch):
    """A brighter plate 3 cm behind the bar's face (an emitter in its housing) lies within the
    footprint's reach and faces the same way: only its being another piece of mesh
    keeps it out of the bar's values."""
    import reroom.hdr.observe as observe

    scan_dir, _, front = _bar_scene(tmp_path, with_backplate=True)
    assert abs(_bar_error(scan_dir, front, test=True)) < 0.1

    def one_piece(mesh):
        n, m = len(mesh.vertices), len(mesh.faces)
        return observe.MeshPieces(np.zeros(n, np.int64), np.zeros(m, np.int64))

    monkeypatch.setattr(observe.MeshPieces, "build", staticmethod(one_piece))
    assert _bar_error(scan_dir, front, test=True) > 0.5


def test_mesh_pieces_label_connected_parts():
    from reroom.hdr.observe import MeshPieces

    a = trimesh.creation.box()
    b = trimesh.creation.box()
    b.apply_translation([3, 0, 0])
    mesh = trimesh.util.concatenate([a, b])
    pieces = MeshPieces.build(mesh)
    assert len(np.unique(pieces.vertex)) == 2
    assert np.all(pieces.vertex[: len(a.vertices)] == pieces.vertex[0])
    assert pieces.vertex[0] != pieces.vertex[-1]
    assert np.array_equal(pieces.face, pieces.vertex[mesh.faces[:, 0]])


@pytest.mark.parametrize("radius", [0.0, -1.0, float("nan")])
def test_footprint_radius_must_be_positive(box_scan, radius):
    from reroom.errors import ReroomError

    scan = load_scan(box_scan)
    lut = response_lut("auto", scan.meta)
    with pytest.raises(ReroomError, match="footprint_radius"):
        collect_observations(
            scan.frames[:1], scan.mesh, lut, ObserveOptions(footprint_radius=radius)
        )
