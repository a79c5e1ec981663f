"""How much of a bulb's light its shade leaves open, in each inclination bin.

A lamp's bulb sends about the same intensity in every direction; in a shade, each
direction keeps it or loses it as the shade blocks it, so the light leaving the lamp is
``i(theta) = i0 * open(theta)``, ``open`` the fraction of each inclination band whose
rays from the bulb leave the shade. :func:`point_open_fraction` integrates it per bin of
an :class:`~reroom.invert.basis.InclinationBasis`; the inverse rendering uses it as the
shape prior of a point light that localization placed inside a shade (as the line
lights use :func:`reroom.invert.line_fixture.line_open_fraction`), and the evaluation's
true profile (:func:`reroom.invert.evaluate.true_point_profile`) samples the same
directions (:func:`inclination_directions`).

A point light whose distribution comes from a reflector (a recessed downlight, a
spot) has no such shape: the shade's evidence (``evidence.height_from == "pool
edge"``, from :mod:`reroom.localize`) is what tells them apart. Written by hand: no
library integrates a point's visibility over inclination bands; the rays go to Embree.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike

from reroom.invert.basis import InclinationBasis
from reroom.invert.line_fixture import back_face_fraction
from reroom.rays import RayCaster

__all__ = ["inclination_directions", "point_inside_fraction", "point_open_fraction"]


def _frame(axis: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``axis`` normalised and two unit vectors perpendicular to it and each other.

    Not :func:`reroom.rays.sampling.orthonormal_basis`: this is the frame the
    evaluation's true point profile has always used, so its figures stay comparable.
    """
    a = np.asarray(axis, float).reshape(3)
    norm = float(np.linalg.norm(a))
    if not norm > 0 or not np.isfinite(norm):
        raise ValueError(f"a point light's axis must be a non-zero direction, got {a.tolist()}")
    a = a / norm
    helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(a, helper)
    e1 /= np.linalg.norm(e1)
    return a, e1, np.cross(a, e1)


def inclination_directions(
    axis: ArrayLike, basis: InclinationBasis, samples: int, seed: int = 0
) -> np.ndarray:
    """``(bins, samples', 3)`` unit directions, jittered-stratified within each bin's band.

    Uniform in solid angle (``cos theta`` and azimuth stratified, ``sqrt(samples)`` strata
    of ``cos theta`` times ``samples / sqrt(samples)`` of azimuth), ``theta`` from ``axis``.
    """
    a, e1, e2 = _frame(axis)
    bins = basis.bins
    n_c = max(1, int(np.sqrt(samples)))
    n_p = max(1, samples // n_c)
    rng = np.random.default_rng(seed)
    edges = np.cos(basis.bin_edges())
    ic, ip = np.meshgrid(np.arange(n_c), np.arange(n_p), indexing="ij")
    fc = (ic.ravel() + rng.random((bins, ic.size))) / n_c
    phi = 2 * np.pi * (ip.ravel() + rng.random((bins, ip.size))) / n_p
    cos_t = edges[:-1, None] + (edges[1:] - edges[:-1])[:, None] * fc
    sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t**2))
    return (
        cos_t[..., None] * a
        + (sin_t * np.cos(phi))[..., None] * e1
        + (sin_t * np.sin(phi))[..., None] * e2
    )


def point_open_fraction(
    occluded: Callable[..., np.ndarray],
    position: ArrayLike,
    axis: ArrayLike,
    basis: InclinationBasis,
    reach: float,
    *,
    samples: int = 1024,
    seed: int = 0,
) -> np.ndarray:
    """Fraction of each inclination band whose rays from ``position`` leave the fixture.

    Parameters
    ----------
    occluded : callable
        ``occluded(points, directions, tmax=reach) -> (N,) bool``, e.g. a
        :meth:`reroom.rays.RayCaster.occluded` of the scanned faces around the light.
    position, axis : array_like, shape (3,)
        The light and its axis (``theta = 0``).
    basis : InclinationBasis
    reach : float
        Metres: hits farther than this are not the fixture.
    samples, seed
        Directions per bin (see :func:`inclination_directions`).

    Returns
    -------
    ndarray, shape (basis.bins,)
        Open fraction in ``[0, 1]`` per bin.
    """
    d = inclination_directions(axis, basis, samples, seed)
    p = np.asarray(position, float).reshape(3)
    hit = occluded(np.broadcast_to(p, (d.shape[0] * d.shape[1], 3)), d.reshape(-1, 3), tmax=reach)
    return 1.0 - np.asarray(hit, float).reshape(d.shape[:2]).mean(axis=1)


def point_inside_fraction(
    caster: RayCaster, position: ArrayLike, reach: float, rays: int = 4096, seed: int = 0
) -> float:
    """Fraction of rays from ``position`` whose first hit within ``reach`` is a back face.

    0 for a bulb inside a scanned shade whose faces point outwards (a fused shade's
    surface does); a bulb placed inside a closed blob of geometry (a shade the scan
    filled in) sees back faces, and :func:`point_open_fraction` would then call the
    blob's inside open. Needs consistently wound faces.
    """
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(rays, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    p = np.broadcast_to(np.asarray(position, float).reshape(3), d.shape)
    return back_face_fraction(caster, p, d, reach)
