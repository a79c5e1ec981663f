"""Artificially incomplete scans: the mesh-incompleteness experiment (thesis Fig. 5.9).

:func:`delete_chunks` picks connected regions of a mesh to delete, each grown
breadth-first over the vertex adjacency from a random seed vertex, and
:func:`subset_scan` writes a copy of a scan folder with only the kept vertices, every
per-vertex file subset consistently. ``benchmarks/bench_incompleteness.py`` runs
``reroom invert`` on such copies.

The thesis deletes chunks of 5 % of the *triangle* count grown over triangles; here the
chunks are 5 % of the *vertex* count grown over vertices (the per-vertex files are what
the pipeline reads). A triangle survives when its three vertices do, so slightly more
than ``fraction`` of the triangles go.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from reroom.io.atomic import atomic_path, atomic_write_json

__all__ = ["CHUNK_FRACTION", "DERIVED_OUTPUTS", "delete_chunks", "subset_scan", "vertex_adjacency"]

#: Size of one deleted region, as a fraction of the vertex count (thesis: 5 %).
CHUNK_FRACTION = 0.05


def vertex_adjacency(faces: np.ndarray, n_vertices: int) -> sp.csr_matrix:
    """Symmetric boolean ``(V, V)`` vertex adjacency of a triangle mesh.

    Parameters
    ----------
    faces : ndarray, shape (F, 3)
        Vertex indices of the triangles.
    n_vertices : int
        Number of vertices ``V``.

    Returns
    -------
    scipy.sparse.csr_matrix
        ``A[i, j]`` is true when an edge joins vertices ``i`` and ``j``.
    """
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    i = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
    j = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    a = sp.coo_matrix((np.ones(len(i), bool), (i, j)), shape=(n_vertices, n_vertices)).tocsr()
    return (a + a.T).astype(bool).tocsr()


def _grow(adj: sp.csr_matrix, seed: int, free: np.ndarray, size: int) -> np.ndarray:
    """Up to ``size`` free vertices reached breadth-first from ``seed`` (free itself).

    Level-synchronous BFS: each level is the free, unvisited neighbours of the previous
    one, in order of first appearance; the last level is cut to fit ``size``.
    """
    taken = [np.array([seed], np.int64)]
    visited = np.zeros(adj.shape[0], bool)
    visited[seed] = True
    count, frontier = 1, taken[0]
    while count < size and len(frontier):
        nbrs = adj[frontier].indices
        nbrs = nbrs[free[nbrs] & ~visited[nbrs]]
        if not len(nbrs):
            break
        _, first = np.unique(nbrs, return_index=True)
        level = nbrs[np.sort(first)][: size - count]
        visited[level] = True
        taken.append(level)
        count += len(level)
        frontier = level
    return np.concatenate(taken)


def delete_chunks(
    mesh,
    fraction: float,
    rng: np.random.Generator,
    protect: np.ndarray | None = None,
    *,
    chunk_fraction: float = CHUNK_FRACTION,
) -> np.ndarray:
    """Choose connected regions to delete: ``fraction`` of the vertices, in chunks.

    Each chunk holds ``round(chunk_fraction * V)`` vertices (the last one fewer when
    ``fraction`` is not a multiple of ``chunk_fraction``) and is grown breadth-first over
    the vertex adjacency from a seed vertex drawn uniformly among those neither deleted
    nor protected, through such vertices only. Should the seed's free region run out
    before the chunk is full, the chunk goes on from a new random seed (it is then not
    connected; on a scan mesh this only happens when most of it is gone).

    Parameters
    ----------
    mesh : trimesh.Trimesh or object with ``vertices`` and ``faces``
        The mesh.
    fraction : float
        Fraction of the vertices to delete, in ``[0, 1)``.
    rng : numpy.random.Generator
        Source of the seed vertices (the result is a function of its state).
    protect : ndarray of bool, shape (V,), optional
        Vertices never deleted (e.g. the detected lights' own vertices,
        ``light_id >= 0``), so that the light set still matches the mesh.
    chunk_fraction : float
        Size of one chunk as a fraction of ``V`` (thesis: 5 %).

    Returns
    -------
    ndarray of bool, shape (V,)
        The keep mask: false for the deleted vertices.

    Raises
    ------
    ValueError
        ``fraction`` is outside ``[0, 1)`` or more vertices are asked for than are
        unprotected.
    """
    n = len(mesh.vertices)
    if not 0.0 <= fraction < 1.0:
        raise ValueError(f"fraction must be in [0, 1), got {fraction}")
    free = np.ones(n, bool) if protect is None else ~np.asarray(protect, bool).copy()
    target = int(round(fraction * n))
    if target > free.sum():
        raise ValueError(f"cannot delete {target} of {n} vertices: only {free.sum()} unprotected")
    chunk = max(1, int(round(chunk_fraction * n)))
    adj = vertex_adjacency(mesh.faces, n)
    keep = np.ones(n, bool)
    deleted = 0
    while deleted < target:
        size = min(chunk, target - deleted)
        while size > 0:
            candidates = np.flatnonzero(free)
            seed = int(candidates[rng.integers(len(candidates))])
            region = _grow(adj, seed, free, size)
            free[region] = False
            keep[region] = False
            deleted += len(region)
            size -= len(region)
    return keep


# ---------------------------------------------------------------- scan subsets


def _remap(mesh, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Faces with three kept vertices, the vertices they use, and the old->new map."""
    faces = np.asarray(mesh.faces, np.int64)
    fkeep = keep[faces].all(axis=1)
    used = np.zeros(len(keep), bool)
    used[faces[fkeep].ravel()] = True
    old = np.flatnonzero(used)
    new_of_old = np.full(len(keep), -1, np.int64)
    new_of_old[old] = np.arange(len(old))
    return old, new_of_old[faces[fkeep]], new_of_old


def _subset_ply(src: Path, dst: Path, n: int, faces: np.ndarray, old, new_faces) -> bool:
    """Write ``src``'s subset to ``dst`` if it is a per-vertex mesh of ``n`` vertices."""
    import trimesh

    from reroom.io.mesh import read_ply, write_ply

    m = read_ply(src)
    if len(m.vertices) != n:
        return False
    if not np.array_equal(np.asarray(m.faces, np.int64), faces):
        raise ValueError(f"{src}: {n} vertices but other faces than the HDR mesh's")
    attrs = {k: np.asarray(v)[old] for k, v in m.vertex_attributes.items()}
    sub = trimesh.Trimesh(np.asarray(m.vertices)[old], new_faces, process=False)
    write_ply(dst, sub, attrs)
    return True


def _subset_npz(src: Path, dst: Path, n: int, old, new_of_old) -> bool:
    """Subset the per-vertex arrays of an ``.npz`` (and remap ``*_vertex`` index arrays).

    Arrays of first dimension ``n`` are per vertex. An array ``P_vertex`` holds vertex
    indices: its rows whose vertex is deleted are dropped from every ``P_*`` array of the
    same length, and the rest are renumbered (``hdr_extras.npz``'s ``seam_*``).
    """
    with np.load(src) as z:
        data = {k: z[k] for k in z.files}
    if not any(v.ndim and len(v) == n for v in data.values()):
        return False
    out = {}
    rows: dict[str, np.ndarray] = {}
    for k, v in data.items():
        if k.endswith("_vertex") and v.ndim == 1 and np.issubdtype(v.dtype, np.integer):
            prefix = k[: -len("vertex")]
            rows[prefix] = new_of_old[v] >= 0
    for k, v in data.items():
        prefix = next(
            (p for p in rows if k.startswith(p) and v.ndim and len(v) == len(rows[p])), None
        )
        if prefix is not None:
            v = v[rows[prefix]]
            out[k] = new_of_old[v].astype(v.dtype) if k == prefix + "vertex" else v
        elif v.ndim and len(v) == n:
            out[k] = v[old]
        else:
            out[k] = v
    with atomic_path(dst) as tmp:
        np.savez_compressed(tmp, **out)
    return True


#: Top-level entries of a scan that later stages derive from ``invert/`` (``reroom run``
#: writes them into the scan, :data:`reroom.run.RESERVED` less the stages before
#: ``invert``; kept here because the inverse rendering does not import the run, and a
#: test holds the two together): an ablated copy must not take them along.
DERIVED_OUTPUTS = (
    "invert", "rerender", "render", "edits", "report", "report.html", "run.json",
    "model_meshes",
)  # fmt: skip


def subset_scan(
    scan: str | Path,
    keep: np.ndarray,
    out: str | Path,
    *,
    skip: tuple[str, ...] = DERIVED_OUTPUTS,
) -> dict:
    """Write a copy of ``scan`` that holds only the kept vertices.

    The vertex set is that of ``hdr/hdr_mesh.ply``. A face survives when its three
    vertices are kept; vertices then used by no face are dropped as well, and the rest
    renumbered in their old order. Every file is handled by what it holds:

    * a ``.ply`` with the HDR mesh's vertex count (``hdr/hdr_mesh.ply``, ``mesh.ply``,
      ``layout/layout_labels.ply``, ``ground_truth/vertices.ply``, ...): vertices,
      per-vertex attributes and faces subset (its faces must equal the HDR mesh's);
    * a ``.npz`` with per-vertex arrays (``lights/lights_vertices.npz``,
      ``hdr/hdr_extras.npz``): those arrays subset, ``*_vertex`` index arrays remapped
      (see :func:`_subset_npz`);
    * ``lights/lights.json``: copied with ``n_vertices`` updated. Nothing else in it is
      a vertex index: ``light_index`` is the light's position in the list (what
      ``light_id`` refers to), and ``evidence.vertices`` are counts on the original
      mesh, kept as the record of what detection saw;
    * ``ground_truth/ground_truth.json``: copied with ``vertices`` / ``faces`` updated;
    * anything else (images, ``transforms.json``, ``layout/layout.json``,
      ``ground_truth/scene/``, ``hdr/exposures.json``, ...): a symbolic link to the
      original (absolute path), file or whole folder.

    Top-level entries named in ``skip`` (default :data:`DERIVED_OUTPUTS`: the old
    ``invert/`` and what ``reroom run`` derives from it, whose meshes are not the HDR
    mesh's even where their vertex count is) are left out. The source scan is only read.

    Parameters
    ----------
    scan : path
        The source scan folder.
    keep : ndarray of bool, shape (V,)
        Vertices to keep (e.g. from :func:`delete_chunks`).
    out : path
        The new scan folder (created; must not be ``scan`` or inside it).
    skip : tuple of str
        Top-level entries of ``scan`` not copied.

    Returns
    -------
    dict
        ``vertices`` / ``faces`` before and after, ``old_index`` (ndarray: the original
        index of each new vertex), and the files ``subset`` and ``linked``.
    """
    from reroom.io.mesh import read_ply

    scan, out = Path(scan).resolve(), Path(out).resolve()
    if out == scan or scan in out.parents:
        raise ValueError(f"{out} must not be {scan} or inside it")
    hdr = read_ply(scan / "hdr" / "hdr_mesh.ply")
    n = len(hdr.vertices)
    keep = np.asarray(keep, bool)
    if keep.shape != (n,):
        raise ValueError(f"keep has shape {keep.shape}, the HDR mesh {n} vertices")
    faces = np.asarray(hdr.faces, np.int64)
    old, new_faces, new_of_old = _remap(hdr, keep)
    info = {
        "vertices": [n, int(len(old))],
        "faces": [int(len(faces)), int(len(new_faces))],
        "old_index": old,
        "subset": [],
        "linked": [],
    }

    def visit(src: Path, dst: Path) -> None:
        rel = str(src.relative_to(scan))
        if src.is_dir():
            holds_vertex_data = any(
                p.suffix in (".ply", ".npz") or p.name in ("lights.json", "ground_truth.json")
                for p in src.rglob("*")
            )
            if not holds_vertex_data or rel == os.path.join("ground_truth", "scene"):
                dst.symlink_to(src, target_is_directory=True)
                info["linked"].append(rel)
                return
            dst.mkdir(parents=True, exist_ok=True)
            for child in sorted(src.iterdir()):
                if src == scan and child.name in skip:
                    continue
                visit(child, dst / child.name)
            return
        done = False
        if src.suffix == ".ply":
            done = _subset_ply(src, dst, n, faces, old, new_faces)
        elif src.suffix == ".npz":
            done = _subset_npz(src, dst, n, old, new_of_old)
        elif src.name == "lights.json":
            d = json.loads(src.read_text())
            have = int(d.get("n_vertices", n))
            # 0: no per-vertex light ids (``reroom localize``'s file of point lights
            # alone), nothing to subset, so it is linked as it is.
            if have not in (n, 0):
                raise ValueError(f"{src}: n_vertices {d.get('n_vertices')} != {n}")
            if have == n:
                d["n_vertices"] = int(len(old))
                d.setdefault("notes", []).append(
                    f"subset of {src}: {len(old)} of {n} vertices kept (incompleteness experiment)"
                )
                atomic_write_json(dst, d)
                done = True
        elif src.name == "ground_truth.json":
            d = json.loads(src.read_text())
            d["vertices"], d["faces"] = int(len(old)), int(len(new_faces))
            atomic_write_json(dst, d)
            done = True
        if done:
            info["subset"].append(rel)
        else:
            dst.symlink_to(src)
            info["linked"].append(rel)

    out.mkdir(parents=True, exist_ok=True)
    for child in sorted(scan.iterdir()):
        if child.name in skip:
            continue
        visit(child, out / child.name)
    return info
