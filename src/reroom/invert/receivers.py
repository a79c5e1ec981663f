"""Which receiving vertices the eq. 5.7 solve can trust: away from nearby geometry.

The model of eq. 5.6 evaluates every transfer *at the vertex*: its hemisphere, shadow
rays and indirect light start there. The HDR radiance of that vertex, though, is what
the photos show over a pixel footprint around it, on the true surface. The two agree
on open surfaces and disagree where other geometry is within a few centimetres:

* at a seam (wall meets floor, a shelf stands against a wall) the vertex lies in the
  plane of the neighbouring surface, so half its hemisphere and many of its shadow
  rays are blocked at distance 0, while the photo shows the lit surface a pixel away;
* in a contact gap (floor under a sofa's skirt, wall behind a cabinet) the mesh is
  too coarse for the occlusion that the photo's pixels average over.

Such a vertex's transfer is far too small for its radiance, so it reads as a bright,
"high albedo" vertex; the solve's light/albedo gauge turns a few percent of them into
albedos 5-10 % high and lights 20-30 % weak (``docs/invert.md``, "Near geometry").
:func:`near_occlusion` measures how much of each vertex's cosine-weighted hemisphere
is blocked within a short distance; the pipeline leaves the vertices above a threshold
out of the lighting solve (they still get a per-vertex albedo, flagged).
"""

from __future__ import annotations

import numpy as np
import trimesh

from reroom.rays import RayCaster
from reroom.rays.sampling import sample_hemisphere

__all__ = ["near_occlusion"]


def near_occlusion(
    caster: RayCaster,
    mesh: trimesh.Trimesh,
    vertices: np.ndarray,
    normals: np.ndarray,
    distance: float,
    rays: int = 64,
    offset: float = 0.05,
    seed: int = 0,
) -> np.ndarray:
    """Fraction of each vertex's cosine-weighted hemisphere blocked within ``distance``.

    Parameters
    ----------
    caster : RayCaster
        Built on ``mesh``.
    mesh : trimesh.Trimesh
        The scan mesh.
    vertices : ndarray of int, shape (n,)
        The receiving vertices.
    normals : ndarray, shape (n, 3)
        Their unit normals.
    distance : float
        Metres: hits closer than this count as blocked.
    rays : int
        Stratified cosine-weighted rays per vertex.
    offset : float
        Ray origins start ``offset`` times the vertex's mean edge length along the
        normal (at least ``caster.eps``), as the hemisphere transfer's do.
    seed : int
        Seed of the ray sampling.

    Returns
    -------
    ndarray, shape (n,)
        The blocked fraction, 0 (open) to 1 (enclosed).
    """
    from reroom.invert.transfer import mean_edge_lengths

    recv = np.asarray(vertices, dtype=np.int64).ravel()
    if len(recv) == 0:
        return np.zeros(0)
    if distance <= 0:
        raise ValueError(f"distance must be > 0, got {distance}")
    nrm = np.asarray(normals, dtype=np.float64).reshape(len(recv), 3)
    edge = mean_edge_lengths(mesh)[recv]
    origins = np.asarray(mesh.vertices, dtype=np.float64)[recv]
    origins = origins + np.maximum(offset * edge, caster.eps)[:, None] * nrm
    blocked = np.zeros(len(recv))
    per_call = max(1, 2_000_000 // rays)  # memory bound: ~400 bytes per ray
    rng = np.random.default_rng(seed)
    for s in range(0, len(recv), per_call):
        e = min(s + per_call, len(recv))
        dirs, _ = sample_hemisphere(nrm[s:e], rays, rng=rng)
        hit = caster.occluded(np.repeat(origins[s:e], rays, axis=0), dirs.reshape(-1, 3), distance)
        blocked[s:e] = hit.reshape(e - s, rays).mean(axis=1)
    return blocked
