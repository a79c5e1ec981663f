"""One albedo per furnishing for rendering: the objects' per-vertex albedo made robust.

``reroom invert`` solves an albedo ``pi L / E`` for every vertex a photo saw. On the room's
planes that works (photo textures take over there anyway); on furniture it is poor where
it matters for light transport. A vertex's HDR radiance ``L`` is the mean of the pixels
around its projection, a few centimetres of surface, while ``E`` is the irradiance at the
point. Along a crease, a box edge shared by a lit and a dark face, or where an object
stands on the floor, the point is far darker than the pixels around it, and the albedo
comes out several times too high; and every vertex no photo saw (a sofa's back and
underside, the inside of a cabinet) has no albedo at all. Rendered as they are, the
furniture of the synthetic `furnished` scan reflected 1.3-2.8 times the light its true
albedo does (area-weighted, session 20), which made every render's multi-bounce light
too bright.

:func:`object_albedo` treats each furnishing as one object: the unlabelled vertices
(neither wall, floor, ceiling, door, window nor baseboard) joined by the mesh's edges and
by proximity (boxes that touch, a fused mesh's gaps), and gives each object the median
albedo of its seen vertices. A seen vertex keeps its own albedo when it is within a factor
``ratio`` of that median (in luminance); otherwise, and where unseen, it takes the median.
"""

from __future__ import annotations

import numpy as np

__all__ = ["DEFAULT_MERGE_RADIUS", "DEFAULT_OUTLIER_RATIO", "object_albedo"]

#: Unlabelled vertices this close (metres) belong to one object even when no mesh edge
#: joins them: the boxes of a sofa, a chair's seat and legs.
DEFAULT_MERGE_RADIUS = 0.03

#: A seen vertex whose luminance is more than this factor off its object's median takes
#: the median.
DEFAULT_OUTLIER_RATIO = 1.5

_LUMA = np.array([0.2126, 0.7152, 0.0722])


def object_albedo(
    vertices: np.ndarray,
    faces: np.ndarray,
    albedo: np.ndarray,
    known: np.ndarray,
    objects: np.ndarray,
    *,
    merge_radius: float = DEFAULT_MERGE_RADIUS,
    ratio: float = DEFAULT_OUTLIER_RATIO,
    min_known: int = 3,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-vertex albedo of the furnishings, one robust albedo per object.

    Parameters
    ----------
    vertices : ndarray, shape (n, 3)
        Mesh vertices (metres).
    faces : ndarray of int, shape (m, 3)
        Mesh triangles.
    albedo : ndarray, shape (n, 3)
        Per-vertex albedo as solved (rows not ``known`` are ignored).
    known : ndarray of bool, shape (n,)
        Vertices with a solved albedo.
    objects : ndarray of bool, shape (n,)
        Vertices that belong to furnishings (unlabelled by the layout).
    merge_radius : float
        Unlabelled vertices closer than this join one object.
    ratio : float
        A known vertex more than this factor above or below its object's median
        luminance takes the median.
    min_known : int
        Objects with fewer known vertices are left as they are.

    Returns
    -------
    albedo : ndarray, shape (n, 3)
        ``albedo`` with the objects' vertices replaced as described (other rows
        unchanged).
    known : ndarray of bool, shape (n,)
        ``known`` plus the objects' vertices given an albedo here.

    Examples
    --------
    Two triangles of one object, one vertex unseen and one far too bright:

    >>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    >>> f = np.array([[0, 1, 2], [1, 3, 2]])
    >>> a = np.array([[0.3] * 3, [0.32] * 3, [0.9] * 3, [0.0] * 3])
    >>> out, k = object_albedo(v, f, a, np.array([1, 1, 1, 0], bool), np.ones(4, bool))
    >>> np.round(out[:, 0], 2).tolist(), k.tolist()
    ([0.3, 0.32, 0.32, 0.32], [True, True, True, True])
    """
    # Objects are the connected components of a graph: scipy's csgraph, with the
    # proximity edges from a k-d tree; no mesh library segments by label and distance.
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    from reroom.layout.meshops import vertex_adjacency

    vertices = np.asarray(vertices, np.float64)
    albedo = np.asarray(albedo, np.float64).copy()
    known = np.asarray(known, bool).copy()
    objects = np.asarray(objects, bool)
    n = len(albedo)
    idx = np.flatnonzero(objects)
    if len(idx) == 0:
        return albedo, known
    # The mesh's edges between two object vertices, and the proximity pairs.
    keep = sp.diags(objects.astype(np.float64))
    graph = keep @ vertex_adjacency(np.asarray(faces, np.int64).reshape(-1, 3), n) @ keep
    if merge_radius > 0:
        near = idx[cKDTree(vertices[idx]).query_pairs(merge_radius, output_type="ndarray")]
        graph = graph + sp.coo_matrix((np.ones(len(near)), (near[:, 0], near[:, 1])), (n, n))
    _, comp = connected_components(sp.csr_matrix(graph), directed=False)
    lum = albedo @ _LUMA
    for c in np.unique(comp[idx]):
        members = objects & (comp == c)
        seen = members & known
        if seen.sum() < min_known:
            continue
        median = np.median(albedo[seen], axis=0)
        level = float(median @ _LUMA)
        keep = seen & (lum <= ratio * level) & (lum * ratio >= level)
        albedo[members & ~keep] = median
        known[members] = True
    return albedo, known
