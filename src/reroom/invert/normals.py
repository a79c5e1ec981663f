"""Receiver normals for the transfer: the surface's orientation, not the mesh's noise.

Every transfer of eq. 5.6 weights light by the cosine to the receiver's normal. The
photos see the *true* surface, whose normal is smooth (a wall is flat); a fused scan's
per-vertex normal (the area-weighted normal of its one-ring,
:func:`reroom.hdr.observe.vertex_normals`) carries the reconstruction's noise. On a
24-frame 160x120 TSDF scan of `furnished` the one-ring normals of the walls lean 15°
from the wall's axis in the median, and the model's radiance at the true parameters
follows the lean (walls leaning up 20 % too bright where lit directly, leaning down
7 % too dark). With the true lights and the true radiance the solve then dimmed every
light by 20-40 % and raised the floor's albedo 21-36 % (docs/invert.md, "Session 32";
our reading: noise in the solve's regressors biases the fit toward weak lights, as
regression dilution does).

:func:`smoothed_vertex_normals` averages the face normals within a radius of each vertex
that agree with its current estimate (a bilateral filter on the normal field, iterated),
so that flat surfaces get their plane's normal while creases (a wall meeting the floor,
a table's edge) stay sharp. Written here because trimesh and Open3D smooth normals over
a fixed neighbour count or the one-ring only, not over a metric radius with an agreement
cut-off.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from reroom.hdr.observe import vertex_normals

__all__ = ["smoothed_vertex_normals"]


def smoothed_vertex_normals(
    mesh,
    radius: float,
    *,
    min_agreement: float = 0.7,
    iterations: int = 2,
) -> np.ndarray:
    """Unit vertex normals averaged over the faces within ``radius`` metres that agree.

    Parameters
    ----------
    mesh
        Any object with ``vertices (V, 3)`` and ``faces (F, 3)``.
    radius : float
        Metres from the vertex to a face's centroid. 0 returns the one-ring normals.
    min_agreement : float
        A face counts only where the cosine between its normal and the vertex's current
        normal is at least this (0.7: within about 45°), so that averaging never crosses
        a crease.
    iterations : int
        Rounds of the filter, each starting from the previous round's normals (the first
        from the one-ring normals).

    Returns
    -------
    ndarray, shape (V, 3)
        Unit normals; a vertex with no face (or no agreeing face) keeps its one-ring
        normal (zero for a vertex of no face, as :func:`vertex_normals`).

    Raises
    ------
    ValueError
        ``radius`` negative or not finite, ``min_agreement`` outside [-1, 1], or
        ``iterations`` < 1.
    """
    radius = float(radius)
    if not np.isfinite(radius) or radius < 0:
        raise ValueError(f"normal radius must be a finite number of metres >= 0, got {radius}")
    if not -1.0 <= float(min_agreement) <= 1.0:
        raise ValueError(f"min_agreement must be a cosine in [-1, 1], got {min_agreement}")
    if int(iterations) < 1:
        raise ValueError(f"iterations must be >= 1, got {iterations}")
    n0 = vertex_normals(mesh)
    if radius == 0:
        return n0
    v = np.asarray(mesh.vertices, np.float64)
    f = np.asarray(mesh.faces, np.int64)
    if len(f) == 0:
        return n0
    tri = v[f]
    weighted = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # length = 2 area
    length = np.linalg.norm(weighted, axis=1, keepdims=True)
    unit = np.divide(weighted, length, out=np.zeros_like(weighted), where=length > 0)
    pairs = cKDTree(v).sparse_distance_matrix(
        cKDTree(tri.mean(axis=1)), radius, output_type="coo_matrix"
    )
    rows, cols = pairs.row, pairs.col
    # sparse_distance_matrix leaves out pairs at distance exactly 0; a vertex's own
    # faces are never at distance 0 from it (their centroids are not their corners).
    n = n0
    for _ in range(int(iterations)):
        agree = np.einsum("ij,ij->i", n[rows], unit[cols]) >= min_agreement
        pick = sp.csr_matrix(
            (np.ones(int(agree.sum())), (rows[agree], cols[agree])), shape=(len(v), len(f))
        )
        s = pick @ weighted
        s_len = np.linalg.norm(s, axis=1, keepdims=True)
        n = np.where(s_len > 0, s / np.maximum(s_len, 1e-300), n0)
    return n
