"""Linear bases for directional light distributions (thesis §5.5.2-5.5.4).

Every light model of the inverse rendering is a linear combination of *basis
lights*; these classes say which basis function a direction (or an emission
angle) belongs to:

* :class:`CubemapBasis` -- distant light, piecewise constant over the cells of a
  cube map (6 faces of ``n x n`` cells; the thesis's 4 x 4 gives 96 cells);
* :class:`SHBasis` -- distant light in real spherical harmonics (5 bands, 25
  functions in the thesis);
* :class:`InclinationBasis` -- piecewise constant in one angle ``theta in [0, pi]``:
  the inclination from a point light's axis, or a line light's angle around its
  line (32 bins in the thesis).

World directions are in the scan's frame: metres, +Z up.

Cube-map layout
---------------
Faces are ordered ``+X, -X, +Y, -Y, +Z, -Z`` (face ``2 * axis + (component < 0)``).
On each face a direction ``d`` with major axis ``a`` is projected to
``(u, v) = (d . U_f, d . V_f) / |d_a|`` in ``[-1, 1]^2`` with the face's tangent
axes ``U_f, V_f`` (:attr:`CubemapBasis.face_axes`); the cell is
``face * n * n + iv * n + iu`` with ``iu = floor((u + 1) n / 2)``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["CubemapBasis", "InclinationBasis", "SHBasis"]


def _unit_directions(directions: ArrayLike) -> np.ndarray:
    d = np.asarray(directions, dtype=np.float64)
    if d.ndim != 2 or d.shape[1] != 3:
        raise ValueError(f"directions must have shape (N, 3), got {d.shape}")
    norm = np.linalg.norm(d, axis=1, keepdims=True)
    if np.any(norm == 0) or not np.isfinite(norm).all():
        raise ValueError("directions must be finite and non-zero")
    return d / norm


# (major axis, sign) of each face and its tangent axes U, V (right-handed: U x V = outward).
_FACE_AXES = np.array(
    [
        [[0, 1, 0], [0, 0, 1]],  # +X
        [[0, 0, 1], [0, 1, 0]],  # -X
        [[0, 0, 1], [1, 0, 0]],  # +Y
        [[1, 0, 0], [0, 0, 1]],  # -Y
        [[1, 0, 0], [0, 1, 0]],  # +Z
        [[0, 1, 0], [1, 0, 0]],  # -Z
    ],
    dtype=np.float64,
)


class CubemapBasis:
    """Piecewise-constant distant light over the ``6 n^2`` cells of a cube map.

    Parameters
    ----------
    n:
        Cells along each edge of a face (the thesis uses 4: 96 cells).

    Attributes
    ----------
    n:
        Cells per face edge.
    size:
        Number of basis functions, ``6 n^2``.
    face_axes:
        ``(6, 2, 3)`` tangent axes ``(U, V)`` of each face (see the module notes).
    """

    def __init__(self, n: int = 4) -> None:
        if int(n) < 1:
            raise ValueError(f"a cube map needs at least one cell per face edge, got n={n}")
        self.n = int(n)
        self.size = 6 * self.n * self.n
        self.face_axes = _FACE_AXES.copy()

    def __repr__(self) -> str:
        return f"CubemapBasis(n={self.n})"

    def face_uv(self, directions: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Face index ``(N,)`` and face coordinates ``u, v`` in ``[-1, 1]`` of each direction."""
        d = _unit_directions(directions)
        a = np.abs(d)
        axis = np.argmax(a, axis=1)
        rows = np.arange(len(d))
        major = d[rows, axis]
        face = 2 * axis + (major < 0)
        ax = self.face_axes[face]
        inv = 1.0 / np.abs(major)
        u = np.einsum("ij,ij->i", d, ax[:, 0]) * inv
        v = np.einsum("ij,ij->i", d, ax[:, 1]) * inv
        return face, u, v

    def cell_of(self, directions: ArrayLike) -> np.ndarray:
        """Cell index ``(N,)`` (int64) of each ``(N, 3)`` direction (need not be unit length)."""
        face, u, v = self.face_uv(directions)
        n = self.n
        iu = np.clip(np.floor((u + 1.0) * (n / 2.0)).astype(np.int64), 0, n - 1)
        iv = np.clip(np.floor((v + 1.0) * (n / 2.0)).astype(np.int64), 0, n - 1)
        return (face * n + iv) * n + iu

    def _cell_corners_uv(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        n = self.n
        k = np.arange(self.size)
        iu, iv = k % n, (k // n) % n
        edges = np.linspace(-1.0, 1.0, n + 1)
        return edges[iu], edges[iu + 1], edges[iv], edges[iv + 1]

    def _points_on_faces(self, face: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Points ``major + u U + v V`` on the (extended) planes of the given faces."""
        axis, negative = face // 2, face % 2 == 1
        p = np.zeros((len(face), 3))
        p[np.arange(len(face)), axis] = np.where(negative, -1.0, 1.0)
        ax = self.face_axes[face]
        return p + u[:, None] * ax[:, 0] + v[:, None] * ax[:, 1]

    def cell_directions(self) -> np.ndarray:
        """``(size, 3)`` unit directions through the cells' centres (on the cube face)."""
        u0, u1, v0, v1 = self._cell_corners_uv()
        face = np.arange(self.size) // (self.n * self.n)
        p = self._points_on_faces(face, (u0 + u1) / 2.0, (v0 + v1) / 2.0)
        return p / np.linalg.norm(p, axis=1, keepdims=True)

    def cell_solid_angles(self) -> np.ndarray:
        """``(size,)`` exact solid angle of each cell (steradians; they sum to ``4 pi``).

        A rectangle ``[u0, u1] x [v0, v1]`` on the plane at unit distance subtends
        ``S(u1, v1) - S(u0, v1) - S(u1, v0) + S(u0, v0)`` with
        ``S(u, v) = atan(u v / sqrt(1 + u^2 + v^2))``.
        """
        u0, u1, v0, v1 = self._cell_corners_uv()

        def s(u: np.ndarray, v: np.ndarray) -> np.ndarray:
            return np.arctan2(u * v, np.sqrt(1.0 + u * u + v * v))

        return s(u1, v1) - s(u0, v1) - s(u1, v0) + s(u0, v0)

    def adjacency(self) -> np.ndarray:
        """``(M, 2)`` pairs ``i < j`` of cells sharing an edge, across face edges too.

        Each cell has four neighbours, so ``M = 2 * size`` (192 for ``n = 4``).
        """
        u0, u1, v0, v1 = self._cell_corners_uv()
        face = np.arange(self.size) // (self.n * self.n)
        uc, vc = (u0 + u1) / 2.0, (v0 + v1) / 2.0
        # Step a small fraction of a cell across each edge; past the face border the
        # point lies on the plane beyond the cube, and cell_of() finds the neighbour face.
        step = 0.25 * 2.0 / self.n
        probes = [(u0 - step, vc), (u1 + step, vc), (uc, v0 - step), (uc, v1 + step)]
        me = np.arange(self.size)
        pairs = []
        for pu, pv in probes:
            other = self.cell_of(self._points_on_faces(face, pu, pv))
            pairs.append(np.stack([np.minimum(me, other), np.maximum(me, other)], axis=1))
        return np.unique(np.concatenate(pairs), axis=0)

    def evaluate(self, directions: ArrayLike) -> np.ndarray:
        """``(N, size)`` indicator values: 1 in the direction's cell, 0 elsewhere."""
        cells = self.cell_of(directions)
        out = np.zeros((len(cells), self.size))
        out[np.arange(len(cells)), cells] = 1.0
        return out


class SHBasis:
    """Real spherical harmonics of ``bands`` bands (degrees ``0 .. bands - 1``).

    Function ``l * l + l + m`` is ``Y_lm`` (``-l <= m <= l``), orthonormal on the
    sphere: ``Y_l0 = K_l0 P_l^0(z)``, ``Y_lm = sqrt(2) K_lm cos(m phi) P_l^m(z)``
    for ``m > 0`` and ``sqrt(2) K_l|m| sin(|m| phi) P_l^|m|(z)`` for ``m < 0``,
    with ``K_lm = sqrt((2l + 1) (l - m)! / (4 pi (l + m)!))``, ``z = cos(theta)``
    the +Z component, ``phi = atan2(y, x)`` and the associated Legendre functions
    *without* the Condon-Shortley phase (so that e.g. ``Y_11`` is ``+x``-ward).

    Parameters
    ----------
    bands:
        Number of bands (the thesis uses 5: 25 functions).
    """

    def __init__(self, bands: int = 5) -> None:
        if int(bands) < 1:
            raise ValueError(f"need at least one band, got {bands}")
        self.bands = int(bands)
        self.size = self.bands * self.bands

    def __repr__(self) -> str:
        return f"SHBasis(bands={self.bands})"

    def evaluate(self, directions: ArrayLike) -> np.ndarray:
        """``(N, size)`` values of every basis function at each ``(N, 3)`` direction."""
        d = _unit_directions(directions)
        x, y, z = d[:, 0], d[:, 1], d[:, 2]
        phi = np.arctan2(y, x)
        s = np.sqrt(np.maximum(0.0, 1.0 - z * z))  # sin(theta)
        out = np.empty((len(d), self.size))
        for m in range(self.bands):
            # P_m^m = (2m - 1)!! s^m, then upward recurrence in l.
            p_mm = np.full_like(z, float(math.prod(range(1, 2 * m, 2)))) * s**m
            p_prev, p_cur = np.zeros_like(z), p_mm
            for ell in range(m, self.bands):
                if ell == m + 1:
                    p_prev, p_cur = p_cur, (2 * m + 1) * z * p_mm
                elif ell > m + 1:
                    p_prev, p_cur = (
                        p_cur,
                        ((2 * ell - 1) * z * p_cur - (ell + m - 1) * p_prev) / (ell - m),
                    )
                k = math.sqrt(
                    (2 * ell + 1)
                    * math.factorial(ell - m)
                    / (4 * math.pi * math.factorial(ell + m))
                )
                base = ell * ell + ell
                if m == 0:
                    out[:, base] = k * p_cur
                else:
                    out[:, base + m] = math.sqrt(2.0) * k * np.cos(m * phi) * p_cur
                    out[:, base - m] = math.sqrt(2.0) * k * np.sin(m * phi) * p_cur
        return out


class InclinationBasis:
    """Piecewise constant in an angle ``theta in [0, pi]``, ``bins`` equal bins.

    For a point light ``theta`` is the angle between the light's axis and the
    direction from the light to the receiver; for a line light, the angle between
    the line's ``d_perp`` (up made perpendicular to the line) and the direction
    from the line to the receiver, perpendicular to the line (see
    :func:`reroom.invert.point_light_transfer`, :func:`reroom.invert.line_light_transfer`).

    Parameters
    ----------
    bins:
        Number of bins (the thesis uses 32).
    """

    def __init__(self, bins: int = 32) -> None:
        if int(bins) < 1:
            raise ValueError(f"need at least one bin, got {bins}")
        self.bins = int(bins)
        self.size = self.bins

    def __repr__(self) -> str:
        return f"InclinationBasis(bins={self.bins})"

    def bin_of(self, cos_theta: ArrayLike) -> np.ndarray:
        """Bin index (int64) of each ``cos(theta)``; values are clipped to ``[-1, 1]``."""
        theta = np.arccos(np.clip(np.asarray(cos_theta, dtype=np.float64), -1.0, 1.0))
        return np.minimum((theta * (self.bins / np.pi)).astype(np.int64), self.bins - 1)

    def bin_edges(self) -> np.ndarray:
        """``(bins + 1,)`` bin edges in radians, from 0 to ``pi``."""
        return np.linspace(0.0, np.pi, self.bins + 1)

    def bin_centres(self) -> np.ndarray:
        """``(bins,)`` bin centres in radians."""
        e = self.bin_edges()
        return (e[:-1] + e[1:]) / 2.0
