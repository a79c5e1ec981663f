"""Small geometry helpers shared by the stages: distances to segments (line lights'
capsules, fittings) and the vertex graph of a triangle mesh (its pieces, bright
components, smoothness pairs). They live here, below every stage, so that the HDR stage
can use them as well as the stages after it."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike
from scipy.sparse import csgraph

__all__ = ["mesh_pieces", "segment_closest", "segment_distance", "vertex_adjacency"]


def segment_closest(p: ArrayLike, a: ArrayLike, b: ArrayLike) -> np.ndarray:
    """``(N, 3)``: the point of the segment ``a``-``b`` nearest each point of ``p``."""
    p = np.asarray(p, float)
    a = np.asarray(a, float)
    ab = np.asarray(b, float) - a
    t = np.clip(((p - a) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
    return a + t[:, None] * ab


def segment_distance(p: ArrayLike, a: ArrayLike, b: ArrayLike) -> np.ndarray:
    """Distance of each point of ``p`` ``(N, 3)`` to the segment ``a``-``b`` (a point if equal)."""
    return np.linalg.norm(np.asarray(p, float) - segment_closest(p, a, b), axis=1)


def vertex_adjacency(faces: ArrayLike, n_vertices: int) -> sp.csr_matrix:
    """Symmetric ``(V, V)`` boolean adjacency of vertices sharing an edge (no self loops)."""
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    i = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
    j = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    a = sp.coo_matrix((np.ones(len(i), bool), (i, j)), shape=(n_vertices, n_vertices)).tocsr()
    a = (a + a.T).tocsr()
    a.setdiag(False)
    a.eliminate_zeros()
    return a


def mesh_pieces(faces: ArrayLike, n_vertices: int) -> np.ndarray:
    """``(V,)`` the connected piece of each vertex (vertices joined by the faces' edges;
    an isolated vertex is a piece of its own)."""
    _, labels = csgraph.connected_components(vertex_adjacency(faces, n_vertices), directed=False)
    return labels
