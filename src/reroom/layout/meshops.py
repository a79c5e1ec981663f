"""Mesh helpers: normals, areas, resolution, adjacency, graph morphology, harmonic fill.

Written for the layout stage; the later stages (inverse rendering, edits) use them too.

All functions take plain arrays (``vertices (V, 3)``, ``faces (F, 3)``) so they work on
any mesh, including ones built in tests.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

# Re-exported: the layout and later stages import it from here.
from reroom.rays.geometry import vertex_adjacency  # noqa: F401


def face_cross(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(F, 3)`` cross products of the face edges: normal times twice the area."""
    tri = vertices[faces]
    return np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(V, 3)`` area-weighted unit vertex normals (zero for isolated vertices)."""
    fc = face_cross(vertices, faces)
    n = len(vertices)
    idx = faces.ravel()
    # bincount is ~20x faster than np.add.at for scattering face normals to vertices.
    acc = np.stack(
        [np.bincount(idx, weights=np.repeat(fc[:, c], 3), minlength=n) for c in range(3)], axis=1
    )
    length = np.linalg.norm(acc, axis=1, keepdims=True)
    return np.divide(acc, length, out=np.zeros_like(acc), where=length > 0)


def vertex_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(V,)`` one third of the area of the faces around each vertex (its share of surface)."""
    area = 0.5 * np.linalg.norm(face_cross(vertices, faces), axis=1)
    return np.bincount(faces.ravel(), weights=np.repeat(area / 3.0, 3), minlength=len(vertices))


def mean_edge_length(vertices: np.ndarray, faces: np.ndarray) -> float:
    """The mesh resolution ``r`` of the thesis: the mean edge length.

    Averaged over the three edges of every face, so an interior edge counts twice and a
    boundary edge once; on a scan mesh this differs from the mean over unique edges by
    well under 1 % and avoids a costly de-duplication.
    """
    f = np.asarray(faces, np.int64)
    if len(f) == 0:
        return 0.0
    v = np.asarray(vertices, np.float64)
    tri = v[f]
    e = np.concatenate([tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 1], tri[:, 0] - tri[:, 2]])
    return float(np.sqrt(np.einsum("ij,ij->i", e, e)).mean())


def harmonic_fill(values: np.ndarray, fixed: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """``values`` with the free (not ``fixed``) nodes replaced by their harmonic interpolation.

    The graph Laplacian of ``pairs`` (each pair of node indices one edge of weight 1;
    give each edge once) is solved for the free nodes with the fixed ones as boundary
    values (each free node the mean of its neighbours): on a chain this is the linear
    interpolation between fixed nodes and the nearest fixed value beyond the last. Free
    nodes whose connected component has no fixed node keep their values. ``values`` may
    be ``(N,)`` or ``(N, C)`` (each column filled alike).
    """
    from scipy.sparse.csgraph import connected_components
    from scipy.sparse.linalg import spsolve

    n = len(values)
    fixed = np.asarray(fixed, bool)
    pairs = np.asarray(pairs, np.int64).reshape(-1, 2)
    w = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n)).tocsr()
    w = w + w.T
    lap = (sp.diags(np.asarray(w.sum(axis=1)).ravel()) - w).tocsr()
    _, comp = connected_components(w, directed=False)
    has_fixed = np.bincount(comp, weights=fixed.astype(float), minlength=comp.max() + 1) > 0
    solve = ~fixed & has_fixed[comp]
    out = np.array(values, copy=True)
    if solve.any():
        a = lap[solve][:, solve].tocsc()
        b = -(lap[solve][:, fixed] @ out[fixed])
        out[solve] = np.atleast_1d(spsolve(a, b))
    return out


def dilate(mask: np.ndarray, adjacency: sp.csr_matrix, steps: int = 1) -> np.ndarray:
    """Graph dilation: a vertex joins the mask if any neighbour is in it (``steps`` times)."""
    out = np.asarray(mask, bool).copy()
    for _ in range(steps):
        out |= (adjacency @ out.astype(np.uint8)) > 0
    return out


def erode(mask: np.ndarray, adjacency: sp.csr_matrix, steps: int = 1) -> np.ndarray:
    """Graph erosion: a vertex stays only if every neighbour is in the mask."""
    return ~dilate(~np.asarray(mask, bool), adjacency, steps)


def close_labels(
    labels: np.ndarray,
    adjacency: sp.csr_matrix,
    classes: tuple[int, ...],
    unlabelled: int,
    steps: int = 2,
) -> np.ndarray:
    """Morphological closing of each class along the mesh, filling only unlabelled vertices.

    Each class in ``classes`` is dilated then eroded by ``steps`` rings; vertices that were
    ``unlabelled`` and fall inside exactly one closed class take it. Labelled vertices never
    change, so closing cannot swallow a neighbouring class, and a vertex claimed by two
    closings (a seam between classes) stays unlabelled.
    """
    out = labels.copy()
    free = labels == unlabelled
    claims = np.zeros(len(labels), np.int32)
    new = np.full(len(labels), unlabelled, labels.dtype)
    for c in classes:
        closed = erode(dilate(labels == c, adjacency, steps), adjacency, steps)
        hit = closed & free
        claims += hit
        new[hit] = c
    take = free & (claims == 1)
    out[take] = new[take]
    return out


def open_labels(
    labels: np.ndarray,
    adjacency: sp.csr_matrix,
    classes: tuple[int, ...],
    unlabelled: int,
    steps: int = 1,
) -> np.ndarray:
    """Morphological opening of each class: specks thinner than ``2 steps`` rings go unlabelled."""
    out = labels.copy()
    for c in classes:
        m = labels == c
        opened = dilate(erode(m, adjacency, steps), adjacency, steps) & m
        out[m & ~opened] = unlabelled
    return out
