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
  line (32 bins in the thesis);
* :class:`LineBasis` -- a line light's non-separable profile, piecewise constant in
  ``theta`` around the line and ``phi`` out of the plane perpendicular to it (the
  thesis's separable ``i(theta) cos(phi)`` is its ``phi_bins = 1`` case).

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

__all__ = ["CubemapBasis", "InclinationBasis", "LineBasis", "SHBasis"]


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


class LineBasis:
    """A line light's profile ``i(theta, phi)``, piecewise constant on ``theta x phi`` bins.

    A piece ``dx`` of the line sends the radiant intensity ``i(theta, phi) cos(phi) dx``
    along the unit direction ``e`` (from the line towards the receiver), where

    * ``theta in [0, pi]`` is the angle around the line between ``d_perp`` (up made
      perpendicular to the line) and ``e_perp``, the part of ``e`` perpendicular to the
      line, folded over both sides of ``d_perp`` as in :class:`InclinationBasis` (so
      ``theta`` does not wrap: bins 0 and ``theta_bins - 1`` are opposite directions);
    * ``phi`` is the angle between ``e`` and the plane perpendicular to the line,
      ``sin(phi) = e . t`` with ``t`` the unit vector from ``p0`` to ``p1``: positive
      towards ``p1``. ``cos(phi)`` is the projected length of ``dx`` seen from ``e``
      (the factor ``|a_perp| / |a|`` of eq. 5.11), so a bare tube of radius ``r`` and
      radiance ``L`` has ``i = 2 r L`` everywhere.

    ``theta`` has ``theta_bins`` equal bins of ``[0, pi]``. ``phi`` has ``phi_bins``
    equal bins of ``|phi| in [0, pi / 2]`` when ``fold`` is true (the default: a tube's
    two ends are alike, so light leaving towards ``p0`` and towards ``p1`` at the same
    ``|phi|`` share a bin, which halves the unknowns and doubles each bin's data; keeping
    the sign measured no better on the synthetic `furnished` tube, docs/invert.md), else
    of ``phi in [-pi / 2, pi / 2]`` (for a fixture open at one end only). With ``phi_bins = 1`` the profile does not depend on
    ``phi``: the thesis's separable model ``i(theta) cos(phi)`` of eq. 5.11-5.12, with
    the same bins and values as an :class:`InclinationBasis` of ``theta_bins``.

    Element ``k = theta_bin * phi_bins + phi_bin`` (theta-major), so a profile vector
    reshapes to ``(theta_bins, phi_bins)``.

    Parameters
    ----------
    theta_bins:
        Bins of ``theta`` (the thesis uses 32).
    phi_bins:
        Bins of ``phi`` (1: the separable model).
    fold:
        Whether ``phi`` and ``-phi`` share a bin.

    Attributes
    ----------
    theta_bins, phi_bins, fold:
        As given.
    size:
        Number of basis functions, ``theta_bins * phi_bins``.
    """

    def __init__(self, theta_bins: int = 32, phi_bins: int = 1, fold: bool = True) -> None:
        if int(theta_bins) < 1 or int(phi_bins) < 1:
            raise ValueError(f"need at least one bin of each angle, got {theta_bins} x {phi_bins}")
        self.theta_bins = int(theta_bins)
        self.phi_bins = int(phi_bins)
        self.fold = bool(fold)
        self.size = self.theta_bins * self.phi_bins

    def __repr__(self) -> str:
        return (
            f"LineBasis(theta_bins={self.theta_bins}, phi_bins={self.phi_bins}, fold={self.fold})"
        )

    @classmethod
    def from_basis(cls, basis: LineBasis | InclinationBasis) -> LineBasis:
        """``basis`` itself, or the separable (``phi_bins = 1``) basis of an inclination basis."""
        if isinstance(basis, LineBasis):
            return basis
        if isinstance(basis, InclinationBasis):
            return cls(basis.bins, 1)
        raise TypeError(f"not a line-light basis: {basis!r}")

    # -- bins --------------------------------------------------------------------------------

    def theta_edges(self) -> np.ndarray:
        """``(theta_bins + 1,)`` edges of the ``theta`` bins, radians, 0 to ``pi``."""
        return np.linspace(0.0, np.pi, self.theta_bins + 1)

    def theta_centres(self) -> np.ndarray:
        """``(theta_bins,)`` centres of the ``theta`` bins, radians."""
        e = self.theta_edges()
        return (e[:-1] + e[1:]) / 2.0

    def phi_edges(self) -> np.ndarray:
        """``(phi_bins + 1,)`` edges of the ``phi`` bins, radians.

        ``0 .. pi/2`` (of ``|phi|``) when folded, else ``-pi/2 .. pi/2``.
        """
        lo = 0.0 if self.fold else -np.pi / 2
        return np.linspace(lo, np.pi / 2, self.phi_bins + 1)

    def phi_centres(self) -> np.ndarray:
        """``(phi_bins,)`` centres of the ``phi`` bins, radians (of ``|phi|`` when folded)."""
        e = self.phi_edges()
        return (e[:-1] + e[1:]) / 2.0

    def index(self, theta_bin: ArrayLike, phi_bin: ArrayLike) -> np.ndarray:
        """Flat element index of ``(theta_bin, phi_bin)`` pairs."""
        return np.asarray(theta_bin, np.int64) * self.phi_bins + np.asarray(phi_bin, np.int64)

    def theta_bin_of(self, cos_theta: ArrayLike) -> np.ndarray:
        """``theta`` bin (int64) of each ``cos(theta)`` (clipped to ``[-1, 1]``)."""
        theta = np.arccos(np.clip(np.asarray(cos_theta, dtype=np.float64), -1.0, 1.0))
        return np.minimum((theta * (self.theta_bins / np.pi)).astype(np.int64), self.theta_bins - 1)

    def phi_bin_of(self, phi: ArrayLike) -> np.ndarray:
        """``phi`` bin (int64) of each signed ``phi`` in radians (clipped to ``[-pi/2, pi/2]``)."""
        p = np.clip(np.asarray(phi, dtype=np.float64), -np.pi / 2, np.pi / 2)
        lo = 0.0 if self.fold else -np.pi / 2
        x = (np.abs(p) if self.fold else p) - lo
        width = (np.pi / 2 - lo) / self.phi_bins
        return np.clip((x / width).astype(np.int64), 0, self.phi_bins - 1)

    def bin_of(self, cos_theta: ArrayLike, phi: ArrayLike) -> np.ndarray:
        """Flat element index of each direction given by ``cos(theta)`` and signed ``phi``."""
        return self.index(self.theta_bin_of(cos_theta), self.phi_bin_of(phi))

    def directions(self, d_perp: ArrayLike, tangent: ArrayLike) -> np.ndarray:
        """``(size, 3)`` unit directions at the bins' centres (on the ``+side`` half).

        ``tangent`` is the line's unit direction ``p0 -> p1``; ``d_perp`` is made
        perpendicular to it; ``side = tangent x d_perp``.
        """
        t = np.asarray(tangent, float) / np.linalg.norm(tangent)
        u = np.asarray(d_perp, float) - (np.asarray(d_perp, float) @ t) * t
        u /= np.linalg.norm(u)
        side = np.cross(t, u)
        th, ph = np.meshgrid(self.theta_centres(), self.phi_centres(), indexing="ij")
        th, ph = th.ravel(), ph.ravel()
        return (
            np.cos(ph)[:, None] * (np.cos(th)[:, None] * u + np.sin(th)[:, None] * side)
            + np.sin(ph)[:, None] * t
        )

    # -- measures ----------------------------------------------------------------------------

    def _fold_factor(self) -> float:
        # theta is folded over both sides of d_perp (x2); phi over both signs when folded.
        return 2.0 * (2.0 if self.fold else 1.0)

    def solid_angles(self) -> np.ndarray:
        """``(size,)`` solid angle of each bin's directions, both folds included (sum ``4 pi``).

        ``d omega = cos(phi) dphi dtheta`` over the full circle of ``theta``: a bin covers
        ``fold * dtheta * (sin phi_hi - sin phi_lo)``.
        """
        e = self.phi_edges()
        per_phi = np.sin(e[1:]) - np.sin(e[:-1])
        dtheta = np.pi / self.theta_bins
        return np.tile(self._fold_factor() * dtheta * per_phi, self.theta_bins)

    def power_weights(self) -> np.ndarray:
        """``(size,)`` flux per metre of line per unit ``i`` in each bin.

        ``integral_bin cos(phi) d omega = fold * dtheta * integral cos^2(phi) dphi``, so the
        power of a profile ``i`` on a line of length ``L`` is ``L * power_weights() @ i``;
        with ``phi_bins = 1`` a bin weighs ``pi * dtheta`` (eq. 5.11's ``pi L int i dtheta``).
        """
        e = self.phi_edges()

        def prim(p: np.ndarray) -> np.ndarray:  # integral of cos^2
            return p / 2.0 + np.sin(2.0 * p) / 4.0

        per_phi = prim(e[1:]) - prim(e[:-1])
        dtheta = np.pi / self.theta_bins
        return np.tile(self._fold_factor() * dtheta * per_phi, self.theta_bins)

    def adjacency(self, phi_weight: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """Neighbouring bins, for the solve's smoothness term.

        Pairs ``i < j`` of bins that share an edge: neighbours in ``theta`` at the same
        ``phi`` (a chain: ``theta`` is folded and does not wrap, as the point lights'
        :class:`InclinationBasis` chain), and neighbours in ``phi`` at the same ``theta``
        (a chain across ``phi = 0`` when not folded; folded, bin 0 borders its own mirror
        image, which needs no pair). All ``theta`` bins meet at ``|phi| = pi / 2`` (along
        the line), where the intensity ``i cos(phi)`` vanishes whatever ``i``; they are not
        coupled there.

        Parameters
        ----------
        phi_weight:
            Weight of the ``phi`` pairs (the ``theta`` pairs weigh 1).

        Returns
        -------
        pairs : ndarray of int64, shape (M, 2)
            ``theta`` pairs first (``phi_bins * (theta_bins - 1)``), then ``phi`` pairs
            (``theta_bins * (phi_bins - 1)``). With ``phi_bins = 1`` exactly the chain
            ``(k, k + 1)`` of an :class:`InclinationBasis`.
        weights : ndarray, shape (M,)
            1 for the ``theta`` pairs, ``phi_weight`` for the ``phi`` pairs.
        """
        nt, npb = self.theta_bins, self.phi_bins
        it, ip = np.meshgrid(np.arange(nt - 1), np.arange(npb), indexing="ij")
        theta_pairs = np.stack([self.index(it, ip).ravel(), self.index(it + 1, ip).ravel()], 1)
        it, ip = np.meshgrid(np.arange(nt), np.arange(npb - 1), indexing="ij")
        phi_pairs = np.stack([self.index(it, ip).ravel(), self.index(it, ip + 1).ravel()], 1)
        pairs = np.concatenate([theta_pairs, phi_pairs]).astype(np.int64).reshape(-1, 2)
        weights = np.concatenate([np.ones(len(theta_pairs)), np.full(len(phi_pairs), phi_weight)])
        return pairs, weights
