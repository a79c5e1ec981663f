"""Radiance of the surfaces no photo saw, for the indirect light of the others.

The indirect light at a receiver (:func:`reroom.invert.transfer.hemisphere_transfer`)
comes from the radiance the photos show on the surfaces its rays hit. Some rays land on
surfaces no frame observed: the undersides of tables and chairs, the wall behind a sofa,
the gaps between furniture and floor. Eq. 5.9 of the thesis fills that share of each
receiver's hemisphere with the mean radiance of the observed share. But those surfaces
are hidden *because* they face away from the open room, and what faces away from the
room also faces away from its lights: on the synthetic `furnished` scan the surfaces the
HDR mesh misses send the floor's receivers 0.056 per unit of hemisphere against 0.224
from the observed ones (`benchmarks/bench_invert_diagnosis.py --unobserved`). The eq. 5.9
fill puts the floor's indirect light 6 % (the walls' 2 %) above what the fully observed
truth gives, which alone moves the solve to albedos 3-5 % low and the lights 4-12 %
strong (docs/invert.md, "Session 14").

:func:`bounce_fill` gives each unobserved vertex one bounce of the observed light
instead: ``L_u = rho / pi * E_obs(u)``, with ``E_obs(u)`` the irradiance from the
observed surfaces its own hemisphere rays hit (eq. 5.9 inside it) and ``rho`` a typical
reflectance. Direct light is left out: it is unknown before the solve, and hidden surfaces
rarely see a light. Interpolating the neighbours' radiance over the mesh instead (the
harmonic fill, measured once) gave the hidden surfaces the brightness of their observed
rims, no better than eq. 5.9.
"""

from __future__ import annotations

import numpy as np
import trimesh
from numpy.typing import ArrayLike

from reroom.invert.subsample import spread_transfer, voxel_receivers
from reroom.invert.transfer import hemisphere_transfer
from reroom.rays import RayCaster

__all__ = ["DEFAULT_FILL_ALBEDO", "bounce_fill"]

#: Reflectance given to the surfaces no photo saw (their true mean on `furnished`: 0.24-0.80
#: by surface, 0.34 over all of them).
DEFAULT_FILL_ALBEDO = 0.5


def bounce_fill(
    caster: RayCaster,
    mesh: trimesh.Trimesh,
    radiance: ArrayLike,
    observed: ArrayLike,
    normals: ArrayLike,
    area_of: ArrayLike,
    window_of: ArrayLike,
    excluded: ArrayLike | None = None,
    *,
    albedo: float = DEFAULT_FILL_ALBEDO,
    rays_per_vertex: int = 128,
    voxel: float = 0.1,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """One bounce of the observed light onto every unobserved vertex.

    Parameters
    ----------
    caster, mesh:
        The scan mesh and a ray caster built on it.
    radiance, observed:
        ``(V, 3)`` radiance and ``(V,)`` observed flags (``hdr_mesh.ply``).
    normals:
        ``(V, 3)`` vertex normals (zero rows are skipped).
    area_of, window_of:
        ``(V,)`` the area light / window whose surface each vertex is (-1 elsewhere), as
        :func:`~reroom.invert.transfer.hemisphere_transfer` takes them: their light is
        unknown here and is left out.
    excluded:
        ``(V,)`` bool, optional: vertices that get no value (the emitters' surfaces).
    albedo:
        The reflectance ``rho`` given to every unobserved vertex.
    rays_per_vertex, voxel, seed:
        Hemisphere rays per filled vertex; one vertex per ``voxel`` (metres) and normal
        octant is cast from, the others copy its nearest (as the receivers do).

    Raises
    ------
    ValueError
        If ``albedo`` is outside ``(0, 1]`` or an array does not have one row per vertex.

    Returns
    -------
    filled : ndarray, shape (V, 3)
        ``radiance`` with the filled vertices' estimate (other unobserved rows 0).
    reached : ndarray, shape (V,), bool
        The vertices that got a value.
    """
    if not 0.0 < albedo <= 1.0:
        raise ValueError(f"albedo must be in (0, 1], got {albedo}")
    rad = np.asarray(radiance, dtype=np.float64)
    obs = np.asarray(observed, dtype=bool)
    nrm = np.asarray(normals, dtype=np.float64)
    nv = len(mesh.vertices)
    skip = np.zeros(nv, bool) if excluded is None else np.asarray(excluded, bool)
    for name, arr, shape in [
        ("radiance", rad, (nv, 3)),
        ("observed", obs, (nv,)),
        ("normals", nrm, (nv, 3)),
        ("area_of", np.asarray(area_of), (nv,)),
        ("window_of", np.asarray(window_of), (nv,)),
        ("excluded", skip, (nv,)),
    ]:
        if arr.shape != shape:
            raise ValueError(f"{name} has shape {arr.shape}; the mesh needs {shape}")
    filled = np.where(obs[:, None], rad, 0.0)
    targets = np.flatnonzero(~obs & ~skip & (np.linalg.norm(nrm, axis=1) > 0))
    reached = np.zeros(nv, dtype=bool)
    if len(targets) == 0 or not obs.any():
        return filled, reached
    pts = np.asarray(mesh.vertices, dtype=np.float64)
    sub = voxel_receivers(pts, nrm, targets, voxel) if voxel > 0 else targets
    hemi = hemisphere_transfer(
        caster,
        mesh,
        sub,
        nrm,
        filled,
        obs,
        np.asarray(area_of),
        [],
        None,
        rays_per_vertex=rays_per_vertex,
        seed=seed,
        window_of_vertex=np.asarray(window_of),
    )
    if len(sub) != len(targets):
        hemi = spread_transfer(hemi, pts, nrm, targets)
    filled[targets] = albedo / np.pi * hemi.indirect_rescaled()
    reached[targets] = True
    return filled, reached
