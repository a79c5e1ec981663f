"""3D scenes for light localization: box rooms, the 3D candidate proposer, light bounds.

:class:`FieldProposer3D` is the 3D counterpart of
:class:`~reroom.localize.fields.FieldProposer2D`: given the unexplained light ``B'`` on
the measurements it computes ``D``, ``L`` and ``V`` on a voxel grid (only a window around
``near`` when the refinement asks for the candidates near one hypothesis) and returns
the candidate light positions. It takes any ``(N, 3)`` measurements and a mask of the
voxels allowed to hold a light, so it serves the synthetic boxes of Table 6.2 and the
room-scale scans (:mod:`reroom.localize.scan`) alike.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from reroom.localize.fields3d import (
    VoxelGrid,
    find_peaks_3d,
    intensity_distance_field_3d,
    limiter_count_3d,
)
from reroom.localize.measurements import LocalizeError, Measurements

__all__ = [
    "FieldProposer3D",
    "VoteParams3D",
    "box_measurements",
    "box_light_bounds",
    "box_valid_mask",
]


def box_measurements(size: ArrayLike = 1.0, per_side: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """Measurement sites on the six inner faces of an axis-aligned box ``[0, size]``.

    Each face is cut into ``per_side x per_side`` equal cells and a site placed at each
    cell's centre, its normal pointing into the box.

    Returns
    -------
    points, normals:
        ``(6 per_side^2, 3)`` arrays.
    """
    size = np.broadcast_to(np.asarray(size, dtype=np.float64), (3,))
    if per_side < 1 or np.any(size <= 0):
        raise LocalizeError(
            f"box_measurements: need per_side >= 1 and size > 0, got {per_side}, {size}"
        )
    u = (np.arange(per_side) + 0.5) / per_side
    a, b = np.meshgrid(u, u, indexing="ij")
    a, b = a.ravel(), b.ravel()
    pts, nrm = [], []
    for axis in range(3):
        others = [c for c in range(3) if c != axis]
        for side in (0.0, 1.0):
            p = np.empty((a.size, 3))
            p[:, axis] = side * size[axis]
            p[:, others[0]] = a * size[others[0]]
            p[:, others[1]] = b * size[others[1]]
            n = np.zeros((a.size, 3))
            n[:, axis] = 1.0 if side == 0.0 else -1.0
            pts.append(p)
            nrm.append(n)
    return np.concatenate(pts), np.concatenate(nrm)


def box_light_bounds(size: ArrayLike = 1.0, margin: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """The box ``[margin, size - margin]`` that contains every light of a box room."""
    size = np.broadcast_to(np.asarray(size, dtype=np.float64), (3,))
    return np.full(3, margin), size - margin


def box_valid_mask(grid: VoxelGrid, size: ArrayLike, margin: float) -> np.ndarray:
    """Voxels at least ``margin`` from every face of the box ``[0, size]``."""
    size = np.broadcast_to(np.asarray(size, dtype=np.float64), (3,))
    c = grid.centres()
    return np.all((c >= margin) & (c <= size - margin), axis=-1)


@dataclass(frozen=True)
class VoteParams3D:
    """Settings of the 3D voting function and candidate extraction.

    Attributes
    ----------
    radius:
        Radius (voxels) of the ball whose distinct limiters are counted, and of the
        local-maximum test.
    start_height:
        First peak level ``H`` in units of ``|Q|`` (thesis: ``|Q| / 10``).
    decay:
        Factor by which ``H`` is lowered until a maximum passes (as the 2D count).
    merge:
        Candidates closer than this fraction of the scene radius are combined (thesis: 0.1).
    max_candidates:
        Keep only this many of the strongest candidates per proposal (None: all). Noisy
        scan data makes many near-equal maxima; Algorithm 1 finds the rest later.
    """

    radius: int = 2
    start_height: float = 0.1
    decay: float = 0.9
    merge: float = 0.1
    max_candidates: int | None = None


class FieldProposer3D:
    """Candidate light positions from the 3D voting function of a set of measurements.

    Parameters
    ----------
    points, normals:
        ``(N, 3)`` measurement sites and unit normals.
    grid:
        Voxel grid of the search.
    valid:
        ``(nx, ny, nz)`` bool: voxels allowed to hold a light (free space, away from
        surfaces: the false-peak filter of §6.3.6).
    scene_radius:
        Half the diagonal of the scene's bounding box; the merge distance is a fraction
        of it.
    params:
        :class:`VoteParams3D`.
    """

    def __init__(
        self,
        points: ArrayLike,
        normals: ArrayLike,
        grid: VoxelGrid,
        valid: np.ndarray,
        scene_radius: float,
        params: VoteParams3D | None = None,
    ) -> None:
        self.params = params or VoteParams3D()
        self.points = np.ascontiguousarray(points, dtype=np.float64)
        self.normals = np.ascontiguousarray(normals, dtype=np.float64)
        self.grid = grid
        self.valid = np.asarray(valid, dtype=bool)
        if self.valid.shape != grid.shape:
            raise LocalizeError(f"valid mask has shape {self.valid.shape}, grid {grid.shape}")
        self.merge_distance = self.params.merge * float(scene_radius)
        self.start_height = self.params.start_height * len(self.points)

    def measurements(self, values: ArrayLike) -> Measurements:
        """The sites carrying ``values``."""
        return Measurements(self.points, self.normals, np.asarray(values, dtype=np.float64))

    def fields(
        self, values: ArrayLike, window: tuple[slice, slice, slice] | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``D``, ``L`` and ``V`` for ``values`` on the grid (or ``window`` of it).

        ``V`` is the distinct-limiter count plus ``D / (2 max D)``: the count saturates
        at the ball's size within a few voxels of a light, and ``D``, which peaks at a
        lone light (eq. 6.5), breaks the ties.
        """
        d, lim = intensity_distance_field_3d(self.measurements(values), self.grid, window)
        v = limiter_count_3d(lim, self.params.radius)
        finite = np.isfinite(d)
        top = float(d[finite].max()) if finite.any() else 0.0
        if top > 0:
            v += np.where(finite, d, 0.0) / (2.0 * top)
        return d, lim, v

    def __call__(
        self, values: ArrayLike, near: ArrayLike | None = None, within: float | None = None
    ) -> np.ndarray:
        """``(M, 3)`` candidate light positions for the light ``values`` (strongest first)."""
        prm = self.params
        if near is None:
            window = (slice(None),) * 3
            _, _, v = self.fields(values)
            valid = self.valid
        else:
            if within is None:
                raise LocalizeError("FieldProposer3D: 'near' needs 'within'")
            near = np.asarray(near, dtype=np.float64)
            # The ball of V and the peak test need two radii of field beyond the disc.
            window = self.grid.window(near, within + (2 * prm.radius + 1) * self.grid.voxel)
            if any(w.stop <= w.start for w in window):
                return np.zeros((0, 3))
            _, _, v = self.fields(values, window)
            centres = self.grid.centres(window)
            dist = np.linalg.norm(centres - near, axis=-1)
            valid = self.valid[window] & (dist < within)
        centres = self.grid.centres(window)
        pos, _ = find_peaks_3d(
            v, centres, valid, prm.radius, self.start_height, self.merge_distance, prm.decay
        )
        return pos if prm.max_candidates is None else pos[: prm.max_candidates]
