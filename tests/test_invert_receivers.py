"""``reroom.invert.receivers.near_occlusion``: which receivers have geometry close by."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from reroom.hdr.observe import vertex_normals
from reroom.invert.receivers import near_occlusion
from reroom.rays import RayCaster


def _room() -> trimesh.Trimesh:
    """A closed 3 x 2.5 x 2.4 m room (normals inwards) with a 0.5 m cube over the floor."""
    box = trimesh.creation.box(extents=(3.0, 2.5, 2.4))
    box.apply_translation((1.5, 1.25, 1.2))
    for _ in range(4):
        box = box.subdivide()
    box.invert()
    cube = trimesh.creation.box(extents=(0.5, 0.5, 0.5))
    cube.apply_translation((2.0, 1.25, 0.25 + 0.03))  # 3 cm above the floor: a contact gap
    return trimesh.util.concatenate([box, cube])


def test_open_floor_is_free_and_seams_and_gaps_are_blocked() -> None:
    mesh = _room()
    caster = RayCaster(mesh)
    p = np.asarray(mesh.vertices)
    nrm = vertex_normals(mesh)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    floor = np.isclose(p[:, 2], 0.0)
    middle = floor & (np.abs(p[:, 0] - 0.75) < 0.3) & (np.abs(p[:, 1] - 1.25) < 0.3)
    seam = floor & np.isclose(p[:, 1], 0.0) & (p[:, 0] > 0.2) & (p[:, 0] < 2.8)
    under = floor & (np.abs(p[:, 0] - 2.0) < 0.2) & (np.abs(p[:, 1] - 1.25) < 0.2)
    assert middle.any() and seam.any() and under.any()
    idx = np.flatnonzero(middle | seam | under)
    blocked = near_occlusion(caster, mesh, idx, nrm[idx], distance=0.05, rays=256, seed=1)
    got = dict(zip(idx.tolist(), blocked, strict=True))
    # open floor: nothing within 5 cm
    assert max(got[i] for i in np.flatnonzero(middle)) == 0.0
    # a floor-wall seam vertex (normal halfway between them): the wall blocks the wedge
    # of directions into it, ~(1 - cos 45 deg) / 2 of the cosine-weighted hemisphere --
    # above the pipeline's default threshold (0.05)
    seam_blocked = np.array([got[i] for i in np.flatnonzero(seam)])
    assert np.all(seam_blocked > 0.05) and np.all(seam_blocked < 0.25)
    # under the cube, 3 cm gap: mostly enclosed (only grazing rays leave within 5 cm)
    assert min(got[i] for i in np.flatnonzero(under)) > 0.5


def test_distance_and_empty_input() -> None:
    mesh = _room()
    caster = RayCaster(mesh)
    assert near_occlusion(caster, mesh, np.zeros(0, int), np.zeros((0, 3)), 0.05).shape == (0,)
    with pytest.raises(ValueError, match="distance"):
        near_occlusion(caster, mesh, np.array([0]), np.array([[0.0, 0.0, 1.0]]), 0.0)
    # a longer reach sees more: the seam's wedge grows with it, never shrinks
    p = np.asarray(mesh.vertices)
    nrm = vertex_normals(mesh)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    floor = np.flatnonzero(np.isclose(p[:, 2], 0.0) & (p[:, 0] > 0.2) & (p[:, 0] < 1.2))
    short = near_occlusion(caster, mesh, floor, nrm[floor], 0.05, rays=64, seed=0)
    far = near_occlusion(caster, mesh, floor, nrm[floor], 2.0, rays=64, seed=0)
    assert np.all(far >= short)
