"""The Manhattan-world frame of a room scan from a histogram of its surface normals.

Thesis §4.2.1 (after Furukawa et al. 2009): the up axis is the densest direction of the
normals within ``max_tilt_deg`` of the mesh's +Z (floor and ceiling, folded onto one
hemisphere), the two wall axes the densest direction of the horizontal normals folded
modulo 90°. Both peaks are then refined together by fitting one rotation to every normal
near one of the six signed axes (a weighted Kabsch / Procrustes step), which uses the
walls to pin the up axis and the floor to pin the walls.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from reroom.layout.errors import LayoutError


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _peak_direction_2d(
    folded: np.ndarray, weights: np.ndarray, bin_size: float, radius: float
) -> np.ndarray:
    """Densest direction of unit vectors near +Z, by a smoothed 2D histogram of (x, y)."""
    nb = int(np.ceil(2 * radius / bin_size))
    hist, xe, ye = np.histogram2d(
        folded[:, 0],
        folded[:, 1],
        bins=nb,
        range=[[-radius, radius], [-radius, radius]],
        weights=weights,
    )
    hist = ndimage.gaussian_filter(hist, 1.0)
    i, j = np.unravel_index(np.argmax(hist), hist.shape)
    x = 0.5 * (xe[i] + xe[i + 1])
    y = 0.5 * (ye[j] + ye[j + 1])
    return _unit(np.array([x, y, np.sqrt(max(0.0, 1 - x * x - y * y))]))


def _mean_shift(dirs: np.ndarray, weights: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Refine an (axial) direction by the weighted mean of the folded vectors near it."""
    d = start
    for cone in (10.0, 6.0, 4.0):
        c = np.cos(np.radians(cone))
        dots = dirs @ d
        near = np.abs(dots) > c
        if not near.any():
            break
        d = _unit((dirs[near] * (np.sign(dots[near]) * weights[near])[:, None]).sum(axis=0))
    return d


def _horizontal_axis(
    normals: np.ndarray, weights: np.ndarray, up: np.ndarray, max_slope_deg: float = 20.0
) -> np.ndarray:
    """The first wall axis: the peak of the horizontal normals' azimuth folded modulo 90°."""
    e1 = _unit(np.cross(up, [1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.cross(up, [0, 1.0, 0]))
    e2 = np.cross(up, e1)
    horiz = np.abs(normals @ up) < np.sin(np.radians(max_slope_deg))
    if horiz.sum() < 10:
        raise LayoutError(
            "Manhattan frame: found no vertical surfaces (walls) -- fewer than 10 vertex "
            f"normals within {max_slope_deg:.0f} degrees of horizontal"
        )
    n = normals[horiz]
    w = weights[horiz]
    phi4 = np.mod(4.0 * np.arctan2(n @ e2, n @ e1), 2 * np.pi)  # axial, 90-degree symmetric
    bins = 360
    hist, _ = np.histogram(phi4, bins=bins, range=(0, 2 * np.pi), weights=w)
    hist = ndimage.gaussian_filter1d(hist, 2.0, mode="wrap")
    peak = (np.argmax(hist) + 0.5) * 2 * np.pi / bins
    # Circular mean of the samples within 40 degrees of phi4 (10 degrees of azimuth).
    near = np.abs(np.angle(np.exp(1j * (phi4 - peak)))) < np.radians(40)
    mean = np.angle(np.sum(w[near] * np.exp(1j * phi4[near])))
    phi = mean / 4.0
    return np.cos(phi) * e1 + np.sin(phi) * e2


def _kabsch_refine(
    normals: np.ndarray, weights: np.ndarray, rot: np.ndarray, iterations: int = 4
) -> np.ndarray:
    """Refine a rotation (rows = axes) by fitting it to the normals near the six signed axes."""
    for cone in (15.0, 10.0, 7.0, 7.0)[:iterations]:
        local = np.stack([normals @ r for r in rot], axis=1)  # (see wallgrid.rotate)
        k = np.argmax(np.abs(local), axis=1)
        val = local[np.arange(len(local)), k]
        ok = np.abs(val) > np.cos(np.radians(cone))
        if ok.sum() < 10:
            break
        target = np.zeros((ok.sum(), 3))
        target[np.arange(ok.sum()), k[ok]] = np.sign(val[ok])
        # Find R minimising sum w |R n - t|^2: SVD of the weighted cross-covariance.
        h = (normals[ok] * weights[ok, None]).T @ target
        u, _, vt = np.linalg.svd(h)
        d = np.sign(np.linalg.det(u @ vt))
        rot = (u @ np.diag([1.0, 1.0, d]) @ vt).T
    return rot


def manhattan_frame(
    normals: np.ndarray,
    weights: np.ndarray | None = None,
    max_tilt_deg: float = 45.0,
) -> np.ndarray:
    """The rotation from mesh coordinates to the room's Manhattan frame.

    Parameters
    ----------
    normals:
        ``(V, 3)`` unit vertex normals (orientation does not matter).
    weights:
        ``(V,)`` per-vertex weights, typically the vertex areas (so dense regions of the
        mesh do not dominate); default uniform.
    max_tilt_deg:
        The true up direction is assumed to lie within this angle of the mesh's +Z
        (the thesis's assumption: +Z is closer to up than any other axis).

    Returns
    -------
    np.ndarray
        ``(3, 3)`` rotation ``R`` whose rows are the room's x, y and up axes in mesh
        coordinates, so ``R @ p`` are aligned coordinates. Of the four equivalent yaws the
        one closest to the mesh's own axes is returned (``R = I`` for an aligned mesh), and
        up is the sign pointing towards mesh +Z.

    Raises
    ------
    LayoutError
        If there are too few horizontal or vertical surfaces to find the axes.
    """
    n = np.asarray(normals, np.float64)
    w = np.ones(len(n)) if weights is None else np.asarray(weights, np.float64)
    good = np.linalg.norm(n, axis=1) > 0.5
    n, w = n[good], w[good]
    folded = n * np.where(n[:, 2] < 0, -1.0, 1.0)[:, None]
    radius = np.sin(np.radians(max_tilt_deg))
    cand = np.hypot(folded[:, 0], folded[:, 1]) < radius
    if cand.sum() < 10:
        raise LayoutError(
            "Manhattan frame: found no horizontal surfaces (floor or ceiling) -- fewer than "
            f"10 vertex normals within {max_tilt_deg:.0f} degrees of the mesh's +Z"
        )
    up = _peak_direction_2d(folded[cand], w[cand], np.sin(np.radians(1.5)), radius)
    up = _mean_shift(folded[cand], w[cand], up)
    if up[2] < 0:
        up = -up
    x = _horizontal_axis(n, w, up)
    x = _unit(x - (x @ up) * up)
    rot = np.stack([x, np.cross(up, x), up])
    rot = _kabsch_refine(n, w, rot)
    return canonical_yaw(rot)


def canonical_yaw(rot: np.ndarray) -> np.ndarray:
    """Of the rotations equal to ``rot`` up to a multiple of 90° about its up axis (its third
    row), the one closest to the identity, with the up axis pointing towards +Z."""
    rot = np.asarray(rot, np.float64)
    if rot[2, 2] < 0:  # flip up (and y, to stay right-handed)
        rot = rot * np.array([1.0, -1.0, -1.0])[:, None]
    best, best_tr = rot, -np.inf
    x, y = rot[0], rot[1]
    for k in range(4):
        c, s = [(1, 0), (0, 1), (-1, 0), (0, -1)][k]
        cand = np.stack([c * x + s * y, -s * x + c * y, rot[2]])
        tr = np.trace(cand)
        if tr > best_tr:
            best, best_tr = cand, tr
    return best


def rotation_angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle of the rotation ``a @ b.T`` in degrees (0 when ``a == b``)."""
    c = (np.trace(np.asarray(a) @ np.asarray(b).T) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))
