"""The radiance given to unobserved surfaces for the indirect light (reroom.invert.fill)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from reroom.hdr.observe import vertex_normals
from reroom.invert import InvertOptions, run_invert
from reroom.invert.fill import bounce_fill
from reroom.invert.transfer import hemisphere_transfer
from reroom.rays import RayCaster


def _inward_box() -> trimesh.Trimesh:
    box = trimesh.creation.box(extents=(4.0, 3.0, 2.5)).subdivide_to_size(0.25)
    box.invert()  # faces point into the room
    return box


@pytest.mark.parametrize("voxel", [0.0, 0.6])
def test_uniform_room_fills_one_bounce_exactly(voxel: float) -> None:
    box = _inward_box()
    nv = len(box.vertices)
    rad = np.tile([1.0, 2.0, 0.5], (nv, 1))
    hidden = box.vertices[:, 0] > 1.2  # a strip of the room no photo saw
    excluded = np.zeros(nv, bool)
    excluded[np.flatnonzero(hidden)[:5]] = True
    none = np.full(nv, -1)
    filled, reached = bounce_fill(
        RayCaster(box), box, np.where(hidden[:, None], np.nan, rad), ~hidden,
        vertex_normals(box), none, none, excluded, albedo=0.4, rays_per_vertex=64, voxel=voxel,
    )  # fmt: skip
    # Every observed surface sends L, and eq. 5.9 fills the rest of each hidden vertex's
    # hemisphere with it: E = pi L exactly, so the fill is rho L.
    np.testing.assert_array_equal(reached, hidden & ~excluded)
    np.testing.assert_allclose(filled[reached], 0.4 * rad[reached], rtol=1e-9)
    np.testing.assert_array_equal(filled[~hidden], rad[~hidden])
    assert np.all(filled[excluded] == 0)


def _room_with_a_table() -> tuple[trimesh.Trimesh, np.ndarray, np.ndarray]:
    """An inward box with a dark floor and a thin table 0.1 m above it.

    Returns the mesh, the radiance (floor 0.1, everything else 1) and the table's
    underside (facing the floor), which no photo sees.
    """
    room = _inward_box()
    table = trimesh.creation.box(extents=(1.2, 1.2, 0.04)).subdivide_to_size(0.1)
    table.apply_translation([0.0, 0.0, -1.25 + 0.12])
    mesh = trimesh.util.concatenate([room, table])
    nr = len(room.vertices)
    rad = np.ones((len(mesh.vertices), 3))
    floor = np.zeros(len(mesh.vertices), bool)
    floor[:nr] = room.vertices[:, 2] < -1.24
    rad[floor] = 0.1
    underside = np.zeros(len(mesh.vertices), bool)
    underside[nr:] = table.vertices[:, 2] < -1.25 + 0.11
    return mesh, rad, underside


def test_a_hidden_underside_takes_the_dark_floor_it_faces() -> None:
    mesh, rad, underside = _room_with_a_table()
    nv = len(mesh.vertices)
    none = np.full(nv, -1)
    normals = vertex_normals(mesh)
    caster = RayCaster(mesh)
    filled, reached = bounce_fill(
        caster, mesh, rad, ~underside, normals, none, none, albedo=0.5, voxel=0.0, seed=3
    )
    assert reached[underside].all() and not reached[~underside].any()
    # Its hemisphere is mostly the dark floor (0.1) and a little of the bright walls.
    assert 0.05 * 0.5 < filled[underside, 0].mean() < 0.3 * 0.5
    # Floor receivers under and beside the table: eq. 5.9 would fill the underside's
    # share with the mean of what else they see (the bright room), the bounce with its
    # own dark estimate, so their indirect light is lower.
    floor_recv = np.flatnonzero(
        (mesh.vertices[:, 2] < -1.24) & (np.abs(mesh.vertices[:, :2]) < 0.8).all(1)
    )
    mean = hemisphere_transfer(
        caster, mesh, floor_recv, normals, rad, ~underside, none, [], None, rays_per_vertex=128
    )
    bounce = hemisphere_transfer(
        caster,
        mesh,
        floor_recv,
        normals,
        filled,
        np.ones(nv, bool),
        none,
        [],
        None,
        rays_per_vertex=128,
    )
    e_mean = mean.indirect_rescaled()[:, 0].sum()
    e_bounce = bounce.indirect_rescaled()[:, 0].sum()
    assert e_bounce < 0.8 * e_mean


def test_bad_fill_options_are_refused(tmp_path) -> None:
    mesh, rad, underside = _room_with_a_table()
    none = np.full(len(mesh.vertices), -1)
    with pytest.raises(ValueError, match="albedo"):
        bounce_fill(
            RayCaster(mesh), mesh, rad, ~underside, vertex_normals(mesh), none, none, albedo=0.0
        )
    with pytest.raises(ValueError, match=r"observed has shape \(3,\)"):
        bounce_fill(RayCaster(mesh), mesh, rad, np.ones(3, bool), vertex_normals(mesh), none, none)
    with pytest.raises(ValueError, match="unobserved_fill"):
        run_invert(tmp_path, options=InvertOptions(unobserved_fill="harmonic"))
    with pytest.raises(ValueError, match="fill_albedo"):
        run_invert(tmp_path, options=InvertOptions(fill_albedo=1.5))
    with pytest.raises(ValueError, match="albedo_footprint_rings"):
        run_invert(tmp_path, options=InvertOptions(albedo_footprint_rings=-1))
