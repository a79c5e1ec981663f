"""The light from what the scan does not hold: rays that leave the mesh through its holes.

A scan rarely closes. Five Kinect frames of a dining room leave its ceiling unseen and the
fused mesh full of holes; a 300-frame synthetic scan leaves gaps under furniture. The
solve (eq. 5.9, :meth:`~reroom.invert.transfer.HemisphereTransfer.indirect_rescaled`)
gives every hemisphere direction that leaves through such a hole the mean radiance of
the directions the receiver does see. A renderer that lets those rays escape into black
lights the room with less than the solve assumed, and the re-rendered photos come out
dark: on slambook2 the unedited input frames rendered at 0.11 and 0.38 of the photos'
brightness.

:func:`unseen_surroundings` measures how much of the receivers' hemisphere leaves the
mesh (cosine-weighted rays that hit nothing and cross no window opening) and the
radiance the solve gave those directions, averaged over the receivers by how much of
their hemisphere escapes. ``scene.json`` keeps both (``surroundings``); where the
escaping share is worth rendering, :func:`reroom.edit.model.model_scene` adds a constant
environment of that radiance, which only rays that leave the mesh can see. What it
stands for is the unseen room as the photos' mean showed it: it does not dim when a
light is switched off.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from reroom.invert.transfer import HemisphereTransfer
from reroom.invert.windows import WindowOpening, rays_through_windows
from reroom.rays import sample_hemisphere

__all__ = ["unseen_surroundings"]


def unseen_surroundings(
    caster,
    mesh,
    openings: list[WindowOpening],
    hemi: HemisphereTransfer,
    *,
    rays: int = 32,
    max_points: int = 4000,
    min_escape: float = 0.01,
    seed: int = 0,
) -> dict[str, Any]:
    """How much of the receivers' hemisphere leaves the mesh, and the radiance eq. 5.9
    gave it.

    Rays start inside faces whose three corners are receivers (points drawn by area, 1 mm
    above the face along its own normal), not at vertices: a vertex on the seam of a
    wall and the floor has a normal between the two, and rays from it slip through the
    seam (on the clean `furnished` mesh 5 % of such rays did, the room being closed).

    Parameters
    ----------
    caster:
        :class:`~reroom.rays.RayCaster` of ``mesh``.
    mesh:
        The scan mesh (its faces' winding points into the room).
    openings:
        The windows: rays through them are the window's light, not an escape.
    hemi:
        The receivers' hemisphere transfer, one row per receiver (its ``indirect`` and
        ``p_observed`` give each receiver's mean observed radiance, what eq. 5.9 fills
        its unseen directions with).
    rays, max_points:
        Cosine-weighted rays per point, and at most this many points.
    min_escape:
        Below this mean escaping share the mesh is taken as closed: ``radiance`` is None
        and nothing is rendered for it.

    Returns
    -------
    dict
        ``escape_fraction`` (cosine-weighted share of the hemisphere that leaves the mesh,
        over the receivers' surface), ``radiance`` (RGB in the HDR mesh's units, or
        None), ``points`` and ``rays_per_point``.
    """
    rng = np.random.default_rng(seed)
    info: dict[str, Any] = {
        "escape_fraction": 0.0,
        "radiance": None,
        "points": 0,
        "rays_per_point": int(rays),
        "min_escape": float(min_escape),
    }
    faces = np.asarray(mesh.faces, np.int64)
    vertices = np.asarray(mesh.vertices, np.float64)
    row = np.full(len(vertices), -1, np.int64)
    po = np.asarray(hemi.p_observed, np.float64)
    seen = po > 0
    row[np.asarray(hemi.vertices)[seen]] = np.flatnonzero(seen)
    ok = (row[faces] >= 0).all(axis=1)
    area = np.asarray(mesh.area_faces, np.float64) * ok
    if not ok.any() or area.sum() <= 0:
        return info
    pick = rng.choice(len(faces), min(max_points, int(ok.sum())), p=area / area.sum())
    bary = rng.dirichlet(np.ones(3), len(pick))
    tri = vertices[faces[pick]]
    points = np.einsum("ij,ijk->ik", bary, tri)
    n = np.asarray(mesh.face_normals, np.float64)[pick]
    dirs, _ = sample_hemisphere(n, rays, rng)
    dirs = dirs.reshape(-1, 3)
    origins = np.repeat(points + max(1e-3, 10 * caster.eps) * n, rays, axis=0)
    hits = caster.intersect(origins, dirs, tmin=caster.eps)
    # A miss that crossed a window is the window's light (the hemisphere transfer's rule).
    escaped = ~np.asarray(hits.hit, bool) & (
        rays_through_windows(origins, dirs, hits.t, openings) < 0
    )
    share = escaped.reshape(len(pick), rays).mean(axis=1)
    # Each receiver's mean observed radiance: E_ind = integral L cos dw over the
    # observed directions, and the cosine integral of the whole hemisphere is pi.
    r = row[faces[pick]]
    mean_seen = (np.asarray(hemi.indirect, np.float64)[r] / (np.pi * po[r][..., None])).mean(axis=1)
    info["points"] = int(len(pick))
    info["escape_fraction"] = float(share.mean())
    if share.mean() >= min_escape and share.sum() > 0:
        info["radiance"] = (share @ mean_seen / share.sum()).tolist()
    return info
