"""Transfer from area lights by sampling the emitting surface, with shadow rays.

The hemisphere transfer (:func:`reroom.invert.hemisphere_transfer`) also returns an
area-light transfer, counting the cosine-weighted rays that hit the light. That
estimate is unbiased but, for a small or distant light, far too noisy to fit: a
0.6 m ceiling panel seen from 3-4 m covers ~1e-3 of the cosine-weighted
hemisphere, so at 512 rays most wall vertices get *no* hit (transfer 0) and a few
get one (transfer ~3x too high). On the synthetic ``furnished`` scan, 12 % of the
clustered vertices that see the panel had a zero transfer. With a robust (Huber)
loss the over-bright vertices are discounted as outliers and the dark ones are
kept, so the fit sees a dim panel and raises the albedos to explain the missing
light (issue #5: panel power -65 %, wall albedo +15-23 %).

:func:`area_light_transfer` integrates over the light instead,
``F(x) = integral_A V(x, y) cos_x cos_y / |x - y|^2 dA_y``, with stratified
samples on the light's triangles and one shadow ray each. The integrand is smooth
away from shadow edges, so a few hundred samples give ~1 % per vertex.

Which surface emits follows :func:`~reroom.invert.hemisphere_transfer`: a point of
a triangle belongs to the light with the barycentric share of the triangle's light
vertices (so the light ends half-way into its rim triangles), and only the front
side of a triangle (the mesh's winding) emits, as only front-face hits count there.
"""

from __future__ import annotations

import numpy as np
import trimesh
from numpy.typing import ArrayLike

from reroom.invert._kernels import area_samples
from reroom.invert.area_region import AreaRegion
from reroom.invert.direct import receiver_arrays
from reroom.rays import RayCaster

__all__ = ["DEFAULT_AREA_SAMPLES", "area_light_transfer"]

#: Samples on the light per receiver (see ``docs/invert.md``).
DEFAULT_AREA_SAMPLES = 256
#: Receivers per batch (samples x batch shadow rays at a time).
_RECEIVERS_PER_BATCH = 4096


def area_light_transfer(
    caster: RayCaster,
    mesh: trimesh.Trimesh,
    light_vertices: ArrayLike,
    points: ArrayLike,
    normals: ArrayLike,
    samples: int = DEFAULT_AREA_SAMPLES,
    *,
    seed: int = 0,
    offset: float | None = None,
    region: AreaRegion | None = None,
) -> np.ndarray:
    """Irradiance at each point per unit radiance of an area light (``integral cos dw``).

    Parameters
    ----------
    caster:
        Ray caster of ``mesh`` (for the shadow rays).
    mesh:
        The scan mesh, consistently wound (the front side of the light emits).
    light_vertices:
        ``(V,)`` bool: the mesh vertices on the light's emitting surface.
    points, normals:
        ``(N, 3)`` receiving points and their normals.
    samples:
        Points sampled on the light per receiver (stratified by area).
    seed:
        Seed of the sampling (the result is deterministic for a seed).
    offset:
        Metres the shadow rays start above the receiver along its normal;
        default ``caster.eps``.
    region:
        The light's outline (:func:`reroom.invert.area_region.area_region`): the light
        is then the part of the triangles touching its vertices that projects inside
        it, instead of the barycentric share of their light corners.

    Returns
    -------
    ndarray, shape (N,)
        ``integral_A V cos_x cos_y / d^2 dA``: the same quantity as
        :attr:`HemisphereTransfer.area`, without its sampling noise.

    Raises
    ------
    ValueError
        If the shapes do not match, ``samples < 1`` or a normal is zero.
    """
    if samples < 1:
        raise ValueError(f"samples must be positive, got {samples}")
    verts = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    on = np.asarray(light_vertices, dtype=bool)
    if on.shape != (len(verts),):
        raise ValueError(f"light_vertices must have shape ({len(verts)},), got {on.shape}")
    p, n = receiver_arrays(points, normals)
    out = np.zeros(len(p))

    # Triangles touching the light, weighted by area x the mean light share of their corners.
    share3 = on[faces].astype(np.float64)
    mean_share = share3.mean(axis=1)
    keep = np.flatnonzero(mean_share > 0)
    if len(keep) == 0 or len(p) == 0:
        return out
    tri = verts[faces[keep]]
    share3, mean_share = share3[keep], mean_share[keep]
    if region is not None:
        # Whole triangles, each sample then in or out of the outline; a triangle whose
        # corners are all inside lies inside (the outline is convex): only the others'
        # samples are tested (the rim's, a few per cent of a fused panel's).
        share3 = np.ones_like(share3)
        mean_share = np.ones_like(mean_share)
        straddles = ~region.contains(tri.reshape(-1, 3)).reshape(-1, 3).all(axis=1)
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    double_area = np.linalg.norm(cross, axis=1)
    front = cross / np.maximum(double_area, 1e-300)[:, None]
    weight = 0.5 * double_area * mean_share
    total = float(weight.sum())
    if total <= 0:
        return out
    cdf = np.cumsum(weight) / total
    eps = caster.eps if offset is None else float(offset)
    rng = np.random.default_rng(seed)

    for b0 in range(0, len(p), _RECEIVERS_PER_BATCH):
        b1 = min(len(p), b0 + _RECEIVERS_PER_BATCH)
        m = b1 - b0
        # Stratified in the area CDF: every receiver samples all of a large light.
        u = (np.arange(samples)[None, :] + rng.random((m, samples))).ravel() / samples
        f = np.minimum(np.searchsorted(cdf, u), len(cdf) - 1)
        r1 = rng.random(m * samples)
        r2 = rng.random(m * samples)
        # Point on the light (square-root barycentrics) and the integrand, weighted by
        # the barycentric light share over the mean the CDF used (a numba loop: the
        # numpy version's (m x samples, 3, 3) temporaries took most of the time).
        value, y = area_samples(
            p[b0:b1], n[b0:b1], tri, front, share3, mean_share, f, r1, r2, samples
        )
        if region is not None:
            test = np.flatnonzero(straddles[f] & (value > 0))
            value[test[~region.contains(y[test])]] = 0.0
        live = np.flatnonzero(value > 0)
        if len(live):
            rec = b0 + live // samples
            nx = n[rec]
            start = p[rec] + eps * nx
            seg = y[live] - start
            seg_len = np.linalg.norm(seg, axis=1)
            # Stop just short of the light's own surface (it would occlude itself).
            stop = seg_len - np.maximum(1e-3 * seg_len, 2.0 * caster.eps)
            test = stop > 0
            blocked = np.zeros(len(live), dtype=bool)
            if test.any():
                blocked[test] = caster.occluded(start[test], seg[test], tmax=stop[test])
            value[live[blocked]] = 0.0
        out[b0:b1] = total * value.reshape(m, samples).mean(axis=1)
    return out
