"""The renderer's per-vertex albedo: unseen vertices filled, furnishings one albedo each."""

from __future__ import annotations

import numpy as np
import trimesh

from reroom.edit.model import fill_unknown_albedo
from reroom.edit.objects import object_albedo


def _grid(nx: int, ny: int, origin=(0.0, 0.0, 0.0), step: float = 0.1):
    """A flat ``nx`` x ``ny`` vertex grid in z = origin[2], triangulated."""
    x, y = np.meshgrid(np.arange(nx) * step, np.arange(ny) * step, indexing="ij")
    v = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1) + np.asarray(origin)
    i = np.arange(nx * ny).reshape(nx, ny)
    a, b, c, d = i[:-1, :-1].ravel(), i[1:, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, 1:].ravel()
    f = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    return v, f, i


def test_fill_interpolates_between_known_neighbours_and_keeps_known_rows() -> None:
    v, f, i = _grid(11, 4)
    albedo = np.zeros((len(v), 3))
    known = np.zeros(len(v), bool)
    albedo[i[0]] = [0.2, 0.3, 0.4]
    albedo[i[-1]] = [0.8, 0.6, 0.4]
    known[i[0]] = known[i[-1]] = True
    out = fill_unknown_albedo(albedo, f, known)
    # Harmonic: every filled vertex is the mean of its mesh neighbours, per channel.
    mesh = trimesh.Trimesh(v, f, process=False)
    for j in np.flatnonzero(~known):
        np.testing.assert_allclose(out[j], out[mesh.vertex_neighbors[j]].mean(axis=0), atol=1e-9)
    # ... which in this strip rises from one end to the other.
    assert np.all(np.diff(out[i[:, 1], 0]) > 0)
    np.testing.assert_array_equal(out[known], albedo[known])
    assert out.min() >= 0.2 - 1e-12 and out.max() <= 0.8 + 1e-12


def test_fill_gives_a_part_with_nothing_known_the_median() -> None:
    v1, f1, _ = _grid(3, 3)
    v2, f2, _ = _grid(3, 3, origin=(5.0, 0.0, 0.0))
    f = np.concatenate([f1, f2 + len(v1)])
    albedo = np.zeros((len(v1) + len(v2), 3))
    known = np.zeros(len(albedo), bool)
    albedo[: len(v1)] = np.linspace(0.1, 0.9, len(v1))[:, None]
    known[: len(v1)] = True
    out = fill_unknown_albedo(albedo, f, known)
    median = np.median(albedo[: len(v1)], axis=0)
    np.testing.assert_allclose(out[len(v1) :], np.tile(median, (len(v2), 1)))
    # Nothing known at all: a neutral grey, and nothing to fill: unchanged.
    assert np.all(fill_unknown_albedo(albedo, f, np.zeros(len(albedo), bool)) == 0.5)
    np.testing.assert_array_equal(
        fill_unknown_albedo(albedo, f, np.ones(len(albedo), bool)), albedo
    )


def _two_touching_boxes():
    """A seat box and a back box 1 cm apart (no shared vertex), as a sofa is built,
    their faces split to 5 cm as a scan's are."""

    def box(extents, centre):
        b = trimesh.creation.box(extents=extents)
        b.apply_translation(centre)
        v, f = trimesh.remesh.subdivide_to_size(b.vertices, b.faces, max_edge=0.05)
        return trimesh.Trimesh(v, f)

    seat = box((1.0, 0.6, 0.4), (0.0, 0.0, 0.2))
    back = box((1.0, 0.2, 0.5), (0.0, 0.41, 0.45))
    v = np.concatenate([seat.vertices, back.vertices])
    f = np.concatenate([seat.faces, back.faces + len(seat.vertices)])
    return v, f, len(seat.vertices)


def test_object_albedo_joins_touching_boxes_and_replaces_outliers() -> None:
    v, f, n_seat = _two_touching_boxes()
    n = len(v)
    blue = np.array([0.2, 0.28, 0.45])
    albedo = np.tile(blue, (n, 1))
    known = np.zeros(n, bool)
    known[:n_seat] = True  # the seat is seen, the back is not
    albedo[1] = blue * 1.2  # within the ratio: kept
    albedo[2] = blue * 3.0  # a crease vertex, three times too bright: replaced
    albedo[n_seat:] = -1.0  # unseen
    out, k = object_albedo(v, f, albedo, known, np.ones(n, bool))
    assert k.all()
    np.testing.assert_allclose(out[1], blue * 1.2)
    np.testing.assert_allclose(out[2], blue)
    np.testing.assert_allclose(out[n_seat:], np.tile(blue, (n - n_seat, 1)))
    # Without the proximity join the unseen back is its own object, with nothing known.
    out0, k0 = object_albedo(v, f, albedo, known, np.ones(n, bool), merge_radius=0.0)
    assert not k0[n_seat:].any() and np.all(out0[n_seat:] == -1.0)


def test_object_albedo_leaves_labelled_vertices_and_thin_evidence_alone() -> None:
    v, f, n_seat = _two_touching_boxes()
    n = len(v)
    albedo = np.full((n, 3), 0.5)
    albedo[0] = 0.05
    known = np.ones(n, bool)
    objects = np.ones(n, bool)
    objects[:4] = False  # say four seat corners are labelled floor
    out, _ = object_albedo(v, f, albedo, known, objects)
    np.testing.assert_array_equal(out[:4], albedo[:4])  # not an object's: untouched
    # An object with fewer known vertices than min_known is left as it is.
    few = np.zeros(n, bool)
    few[[n_seat, n_seat + 1]] = True
    lone = np.zeros(n, bool)
    lone[n_seat:] = True
    out2, k2 = object_albedo(v, f, albedo, few, lone, merge_radius=0.0)
    np.testing.assert_array_equal(out2, albedo)
    np.testing.assert_array_equal(k2, few)
    # No objects at all: nothing changes.
    out3, k3 = object_albedo(v, f, albedo, known, np.zeros(n, bool))
    np.testing.assert_array_equal(out3, albedo)
    np.testing.assert_array_equal(k3, known)
