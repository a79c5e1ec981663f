"""Point-light refinement against the solved lighting (reroom.invert.refine_points)."""

from __future__ import annotations

import numpy as np
import trimesh

from reroom.invert.basis import InclinationBasis
from reroom.invert.direct import point_light_transfer
from reroom.invert.refine_points import refine_point_position
from reroom.rays import RayCaster


def _room() -> tuple[RayCaster, np.ndarray, np.ndarray]:
    """A 4 x 3 x 2.5 m box seen from inside, with receivers on its floor, walls and ceiling."""
    box = trimesh.creation.box(extents=(4.0, 3.0, 2.5))
    box.apply_translation([2.0, 1.5, 1.25])
    pts, faces = trimesh.sample.sample_surface_even(box, 6000, seed=3)
    normals = -box.face_normals[faces]  # inward
    return RayCaster(box), np.asarray(pts), normals


def _lamp_profile(basis: InclinationBasis) -> np.ndarray:
    """A shaded lamp: bright down and up, dark sideways (what a shade does)."""
    return 0.2 + 2.0 * np.abs(np.cos(basis.bin_centres())) ** 3


def _lamp_target(caster, p, n, truth, color, basis) -> np.ndarray:
    """What the receivers see of a lamp at ``truth`` (``_lamp_profile``, ``color``)."""
    f = point_light_transfer(caster, p, n, truth, [0, 0, 1], basis, clearance=0.05)
    return (f @ _lamp_profile(basis))[:, None] * color[None, :]


def test_refinement_moves_a_misplaced_light_to_the_truth() -> None:
    caster, p, n = _room()
    basis = InclinationBasis(32)
    truth = np.array([1.3, 1.1, 1.6])
    color = np.array([0.7, 0.6, 0.4])
    color /= np.linalg.norm(color)
    target = _lamp_target(caster, p, n, truth, color, basis)
    start = truth + np.array([0.09, -0.07, 0.05])
    ref = refine_point_position(
        caster, p, n, target, np.ones_like(target), color, start, [0, 0, 1], basis,
        clearance=0.05, max_shift=0.3,
    )  # fmt: skip
    assert np.linalg.norm(ref.position - truth) < 0.01
    assert ref.cost_end < 1e-3 * ref.cost_start
    assert ref.shift > 0.1


def test_refinement_stays_put_at_the_truth_and_within_its_bounds() -> None:
    caster, p, n = _room()
    basis = InclinationBasis(32)
    truth = np.array([2.5, 1.8, 2.0])
    color = np.ones(3) / np.sqrt(3)
    target = _lamp_target(caster, p, n, truth, color, basis)
    ref = refine_point_position(
        caster, p, n, target, np.ones_like(target), color, truth, [0, 0, 1], basis,
        clearance=0.05,
    )  # fmt: skip
    assert ref.shift < 0.005
    # A far-off start cannot leave the allowed ball.
    far = truth + np.array([0.5, 0.0, 0.0])
    ref = refine_point_position(
        caster, p, n, target, np.ones_like(target), color, far, [0, 0, 1], basis,
        clearance=0.05, max_shift=0.1,
    )  # fmt: skip
    assert ref.shift <= 0.1 + 1e-9
    assert ref.cost_end <= ref.cost_start


def test_refinement_without_usable_receivers_returns_the_start() -> None:
    caster, p, n = _room()
    basis = InclinationBasis(32)
    target = np.zeros((len(p), 3))
    ref = refine_point_position(
        caster, p, n, target, np.zeros_like(target), np.ones(3) / np.sqrt(3),
        np.array([2.0, 1.5, 1.5]), [0, 0, 1], basis,
    )  # fmt: skip
    assert ref.shift == 0.0 and ref.evaluations <= 1


def test_refinement_across_the_room_keeps_the_height() -> None:
    caster, p, n = _room()
    basis = InclinationBasis(32)
    truth = np.array([1.3, 1.1, 1.6])
    color = np.ones(3) / np.sqrt(3)
    target = _lamp_target(caster, p, n, truth, color, basis)
    start = truth + np.array([0.08, -0.06, 0.0])
    ref = refine_point_position(
        caster, p, n, target, np.ones_like(target), color, start, [0, 0, 1], basis,
        clearance=0.05, free=(0, 1),
    )  # fmt: skip
    assert ref.position[2] == start[2]
    assert np.linalg.norm(ref.position - truth) < 0.01


def test_extra_starts_keep_the_best_place() -> None:
    """More starts never end worse, and one in the right basin is taken."""
    caster, p, n = _room()
    basis = InclinationBasis(32)
    truth = np.array([2.2, 1.4, 2.3])
    color = np.ones(3) / np.sqrt(3)
    target = _lamp_target(caster, p, n, truth, color, basis)
    start = truth + np.array([0.2, -0.1, -0.15])
    kw = dict(clearance=0.05, max_shift=0.3, max_evaluations=15)
    one = refine_point_position(
        caster, p, n, target, np.ones_like(target), color, start, [0, 0, 1], basis, **kw
    )
    two = refine_point_position(
        caster, p, n, target, np.ones_like(target), color, start, [0, 0, 1], basis, **kw,
        extra_starts=(truth + 0.004,),
    )  # fmt: skip
    assert two.cost_end <= one.cost_end
    assert np.linalg.norm(two.position - truth) < 0.01
    assert two.cost_start == one.cost_start  # measured at the given position either way
    assert two.evaluations > one.evaluations
