"""Chunk deletion and scan subsets of the incompleteness experiment (``reroom.invert.incomplete``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse.csgraph as csg
import trimesh

from reroom.invert.incomplete import delete_chunks, subset_scan, vertex_adjacency
from reroom.io.mesh import read_ply, write_ply


def _grid(n: int) -> trimesh.Trimesh:
    """An ``n x n`` vertex grid of triangles in the plane z = 0."""
    x, y = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float), indexing="ij")
    v = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1)
    i = np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]
    i = i.ravel()
    f = np.concatenate([np.stack([i, i + n, i + 1], 1), np.stack([i + 1, i + n, i + n + 1], 1)])
    return trimesh.Trimesh(v, f, process=False)


def test_delete_chunks_fraction_connected_protected_deterministic():
    mesh = _grid(60)  # 3600 vertices: chunks of 180
    n = len(mesh.vertices)
    protect = np.zeros(n, bool)
    protect[:120] = True  # the first two rows
    adj = vertex_adjacency(mesh.faces, n)
    for fraction in (0.05, 0.2, 0.35):
        keep = delete_chunks(mesh, fraction, np.random.default_rng(3), protect)
        gone = ~keep
        assert abs(gone.sum() - fraction * n) <= 0.05 * n
        assert not gone[protect].any()
        assert np.array_equal(
            keep, delete_chunks(mesh, fraction, np.random.default_rng(3), protect)
        )
    # one chunk is one connected region of its size
    keep = delete_chunks(mesh, 0.05, np.random.default_rng(1), protect)
    gone = np.flatnonzero(~keep)
    assert len(gone) == 180
    k, _ = csg.connected_components(adj[gone][:, gone], directed=False)
    assert k == 1
    # several chunks: each new one is connected, so there are at most as many regions
    keep = delete_chunks(mesh, 0.2, np.random.default_rng(1), protect)
    gone = np.flatnonzero(~keep)
    k, _ = csg.connected_components(adj[gone][:, gone], directed=False)
    assert 1 <= k <= 4
    assert not np.array_equal(keep, delete_chunks(mesh, 0.2, np.random.default_rng(2), protect))
    assert delete_chunks(mesh, 0.0, np.random.default_rng(0), protect).all()
    with pytest.raises(ValueError):
        delete_chunks(mesh, 0.99, np.random.default_rng(0), np.ones(n, bool))


def test_subset_scan_remaps_vertices(tmp_path: Path):
    mesh = _grid(4)  # 16 vertices, 18 faces
    n = len(mesh.vertices)
    scan = tmp_path / "scan"
    for d in ("hdr", "layout", "lights", "images", "ground_truth/scene"):
        (scan / d).mkdir(parents=True)
    idx = np.arange(n)
    write_ply(
        scan / "hdr" / "hdr_mesh.ply",
        mesh,
        {"radiance": np.stack([idx, idx, idx], 1).astype(float), "observed": np.ones(n, np.uint8)},
    )
    write_ply(scan / "layout" / "layout_labels.ply", mesh, {"label": idx.astype(np.int32)})
    write_ply(scan / "ground_truth" / "vertices.ply", mesh, {"part": idx.astype(np.int32)})
    ids = np.full(n, -1, np.int32)
    ids[15] = 0
    np.savez(scan / "lights" / "lights_vertices.npz", light_id=ids)
    np.savez(
        scan / "hdr" / "hdr_extras.npz",
        best_frame=idx.astype(np.int32),
        seam_vertex=np.array([0, 5, 15, 5], np.int32),
        seam_frame=np.array([1, 2, 3, 4], np.int32),
        scales=np.ones((2, 3)),
    )
    (scan / "lights" / "lights.json").write_text(
        json.dumps({"format": "reroom-lights", "n_vertices": n, "lights": []})
    )
    # `reroom localize`'s own file: point lights alone, no per-vertex ids (n_vertices 0)
    (scan / "localize").mkdir()
    (scan / "localize" / "lights.json").write_text(
        json.dumps({"format": "reroom-lights", "n_vertices": 0, "lights": []})
    )
    np.savez(scan / "localize" / "lights_vertices.npz", light_id=np.zeros(0, np.int32))
    (scan / "images" / "frame_00000.png").write_bytes(b"png")
    (scan / "transforms.json").write_text("{}")
    (scan / "ground_truth" / "scene" / "scene.json").write_text("{}")
    (scan / "invert").mkdir()
    # `reroom run`'s renders: a light's mesh can share the vertex count, not the faces
    (scan / "render" / "edits").mkdir(parents=True)
    write_ply(
        scan / "render" / "edits" / "light.ply", trimesh.Trimesh(mesh.vertices, mesh.faces[::-1])
    )
    (scan / "run.json").write_text("{}")

    keep = np.ones(n, bool)
    keep[5] = False  # an interior vertex: its six faces go
    keep[3] = False  # a corner: its one face goes, and vertex 2... stays in other faces
    out = tmp_path / "sub"
    info = subset_scan(scan, keep, out)

    sub = read_ply(out / "hdr" / "hdr_mesh.ply")
    old = info["old_index"]
    assert 5 not in old and 3 not in old
    # the radiance encodes the old index: every attribute follows its vertex
    assert np.array_equal(sub.vertex_attributes["radiance"][:, 0], old)
    assert np.array_equal(
        read_ply(out / "layout" / "layout_labels.ply").vertex_attributes["label"], old
    )
    assert np.allclose(sub.vertices, mesh.vertices[old])
    # each new face is an old face with three kept vertices, renumbered
    old_faces = {tuple(f) for f in np.asarray(mesh.faces) if keep[f].all()}
    assert {tuple(old[f]) for f in np.asarray(sub.faces)} == old_faces
    assert len(sub.faces) == len(old_faces) == info["faces"][1]
    assert np.array_equal(np.load(out / "lights" / "lights_vertices.npz")["light_id"], ids[old])
    extras = np.load(out / "hdr" / "hdr_extras.npz")
    assert np.array_equal(old[extras["seam_vertex"]], [0, 15])
    assert np.array_equal(extras["seam_frame"], [1, 3])
    assert np.array_equal(extras["best_frame"], old)
    assert json.loads((out / "lights" / "lights.json").read_text())["n_vertices"] == len(old)
    assert (out / "images").is_symlink() and (out / "transforms.json").is_symlink()
    assert (out / "localize" / "lights.json").is_symlink()  # nothing per vertex in it
    assert (out / "ground_truth" / "scene").is_symlink()
    assert np.array_equal(
        read_ply(out / "ground_truth" / "vertices.ply").vertex_attributes["part"], old
    )
    assert not (out / "invert").exists() and not (out / "render").exists()
    assert not (out / "run.json").exists()
    with pytest.raises(ValueError, match="must not be"):
        subset_scan(scan, keep, scan / "sub")
    with pytest.raises(ValueError, match="keep has shape"):
        subset_scan(scan, keep[:-1], tmp_path / "bad")
    # a lights.json written for another mesh is refused, naming the file
    (scan / "lights" / "lights.json").write_text(json.dumps({"n_vertices": n + 1, "lights": []}))
    with pytest.raises(ValueError, match="lights.json: n_vertices"):
        subset_scan(scan, keep, tmp_path / "bad2")
    assert not list(tmp_path.glob("sub/**/.*.tmp*")), "no temporary file may be left behind"


def test_delete_chunks_bad_input():
    mesh = _grid(10)
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="fraction"):
        delete_chunks(mesh, 1.0, rng)
    with pytest.raises(ValueError, match="unprotected"):
        delete_chunks(mesh, 0.5, rng, protect=np.arange(100) > 10)


def test_the_ablation_leaves_out_everything_a_run_derives_from_invert():
    from reroom.invert.incomplete import DERIVED_OUTPUTS
    from reroom.run import RESERVED, STAGES

    inputs = {*STAGES[: STAGES.index("invert")], "localize"}
    assert set(DERIVED_OUTPUTS) == set(RESERVED) - inputs
