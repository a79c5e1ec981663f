"""Bright connected components of the HDR mesh and their shape (thesis §5.5.1, §5.5.4).

A *candidate* is a connected set of mesh vertices whose HDR luminance is above a
threshold (:func:`bright_components`). :func:`describe_component` measures what the
decision needs: size, area, principal axes (the thesis's PCA test for line lights),
the mean normal, the height, and the *edge contrast* -- the component's radiance
over that of the ring of vertices just outside it. An emitter's edge is a step (a
panel at 5 next to a ceiling at 0.3), a lit pool of light fades out (contrast near
1), which is how a lamp's bright spot on the ceiling is told from a ceiling panel.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

__all__ = [
    "Component",
    "bright_components",
    "describe_component",
    "fit_circle",
]


def bright_components(
    adjacency: sp.csr_matrix, bright: np.ndarray
) -> tuple[np.ndarray, list[np.ndarray]]:
    """Connected components of the bright vertices along mesh edges.

    Returns
    -------
    label:
        ``(V,)`` int32 component of each vertex, -1 where not bright.
    members:
        Vertex indices of each component, largest first.
    """
    idx = np.flatnonzero(bright)
    label = np.full(len(bright), -1, np.int32)
    if len(idx) == 0:
        return label, []
    sub = adjacency[idx][:, idx]
    n, lab = connected_components(sub, directed=False)
    order = np.argsort(-np.bincount(lab, minlength=n), kind="stable")
    rank = np.empty(n, np.int64)
    rank[order] = np.arange(n)
    label[idx] = rank[lab]
    members = [idx[lab == c] for c in order]
    return label, members


@dataclass
class Component:
    """Measurements of one bright component (world coordinates, metres).

    Attributes
    ----------
    vertices:
        Its vertex indices.
    centroid:
        Area-weighted centroid.
    normal:
        Area-weighted mean vertex normal, normalised (zero if they cancel out).
    normal_spread:
        Length of the unnormalised mean normal (1 = flat, ~0 = closed or curved).
    area:
        Surface area, m².
    axes:
        ``(3, 3)`` rows: the sides of the minimum-area bounding rectangle in the
        plane of the two largest principal directions (longer first), then the
        smallest principal direction.
    extent:
        ``(3,)`` max - min of the positions along each principal direction.
    center:
        Middle of the min/max range along each principal direction (world point).
    eigenvalues:
        ``(3,)`` variances along the principal directions.
    mean_radiance:
        ``(3,)`` area-weighted mean HDR radiance.
    mean_luminance, peak_luminance:
        Of the HDR luminance (peak: 95th percentile).
    edge_contrast:
        Mean luminance of the component over the median luminance of the observed
        vertices within a few centimetres outside it (inf if none is observed).
    section_center:
        A point on the axis of the cylinder through the component's cross-section (the
        circle fitted to its positions in the plane of ``axes[1]`` and ``axes[2]``, at
        the middle of ``axes[0]``): a tube's axis, which ``center`` misses when the scan
        shows only the tube's lower half. NaN when the fit fails.
    section_radius:
        That circle's radius (NaN when the fit fails); for a long thin component whose
        cross-sections agree on a tube, their circles' median radius.
    section_from_slices:
        Whether the cross-sections agreed on a tube (:func:`_tube_slices`): the axes
        then run along the line through their centres, and ``section_radius`` is theirs.
    """

    vertices: np.ndarray
    centroid: np.ndarray
    normal: np.ndarray
    normal_spread: float
    area: float
    axes: np.ndarray
    extent: np.ndarray
    center: np.ndarray
    eigenvalues: np.ndarray
    mean_radiance: np.ndarray
    mean_luminance: float
    peak_luminance: float
    edge_contrast: float
    section_center: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    section_radius: float = float("nan")
    section_from_slices: bool = False

    @property
    def size(self) -> tuple[float, float]:
        """The two largest extents (m): length x width."""
        return float(self.extent[0]), float(self.extent[1])


def describe_component(
    members: np.ndarray,
    vertices: np.ndarray,
    normals: np.ndarray,
    areas: np.ndarray,
    radiance: np.ndarray,
    luminance: np.ndarray,
    observed: np.ndarray,
    tree: cKDTree,
    ring_radius: float,
) -> Component:
    """Measure one component (see :class:`Component`).

    ``tree`` is a KD-tree of all mesh vertices; the ring used for the edge contrast
    is every vertex within ``ring_radius`` of the component but not in it (by
    distance, not along edges: a scanned panel is often a separate piece of mesh).
    """
    p = vertices[members]
    w = np.maximum(areas[members], 1e-12)
    ws = w.sum()
    centroid = (p * w[:, None]).sum(0) / ws
    mean_n = (normals[members] * w[:, None]).sum(0) / ws
    spread = float(np.linalg.norm(mean_n))
    normal = mean_n / spread if spread > 1e-9 else np.zeros(3)
    q = p - centroid
    cov = (q * w[:, None]).T @ q / ws
    evals, evecs = np.linalg.eigh(cov)
    order = np.argsort(evals)[::-1]
    evals, axes = np.maximum(evals[order], 0.0), evecs[:, order].T
    axes = _min_area_axes(q, axes)
    slices = _tube_slices(q @ axes.T)
    along = None if slices is None else _axes_along(axes, slices)
    if along is not None:
        axes = along
    coords = q @ axes.T
    lo, hi = coords.min(0), coords.max(0)
    center = centroid + ((lo + hi) / 2) @ axes
    sec_center, sec_radius = np.full(3, np.nan), float("nan")
    if len(p) >= 3:
        (c1, c2), sec_radius = fit_circle(coords[:, 1:3])
        sec_center = centroid + np.array([(lo[0] + hi[0]) / 2, c1, c2]) @ axes
        if along is not None:
            # The slices' circles, fitted along the corrected axis, are the tube's own.
            slices = _tube_slices(coords)
            if slices is not None:
                sec_radius = float(np.median(slices[:, 3]))
    lum = luminance[members]
    ring = _outer_ring(members, p, tree, ring_radius)
    ring = ring[observed[ring]]
    outside = float(np.median(luminance[ring])) if len(ring) else 0.0
    mean_lum = float((lum * w).sum() / ws)
    contrast = mean_lum / outside if outside > 0 else float("inf")
    return Component(
        vertices=members,
        centroid=centroid,
        normal=normal,
        normal_spread=spread,
        area=float(areas[members].sum()),
        axes=axes,
        extent=hi - lo,
        center=center,
        eigenvalues=evals,
        mean_radiance=(radiance[members] * w[:, None]).sum(0) / ws,
        mean_luminance=mean_lum,
        peak_luminance=float(np.percentile(lum, 95)),
        edge_contrast=contrast,
        section_center=sec_center,
        section_radius=sec_radius,
        section_from_slices=along is not None,
    )


def fit_circle(xy: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre ``(2,)`` and radius of the circle through 2D points, least squares.

    Kasa's algebraic fit (``x^2 + y^2 = 2 a x + 2 b y + c``, linear): unlike the points'
    mean, it finds the centre of an arc, e.g. a lamp shade in a corner that the scan
    shows on one side only.
    """
    x, y = xy[:, 0], xy[:, 1]
    a = np.column_stack([2.0 * x, 2.0 * y, np.ones_like(x)])
    sol, *_ = np.linalg.lstsq(a, x * x + y * y, rcond=None)
    centre = sol[:2]
    return centre, float(np.sqrt(max(sol[2] + centre @ centre, 0.0)))


#: Cross-sections a long thin component is cut into to find its axis, and the fewest
#: vertices a cross-section needs for its circle.
TUBE_SLICES = 8
TUBE_SLICE_VERTICES = 5


def _tube_slices(coords: np.ndarray) -> np.ndarray | None:
    """Circles fitted to the cross-sections of a long thin component: ``(k, 5)`` rows of
    position along ``axes[0]``, centre (two coordinates along ``axes[1]``, ``axes[2]``),
    radius and vertex count; None for a component that is not long and thin (width
    over a fifth of its length) or has under four usable cross-sections.

    A tube seen from below shows a different side at each end (the cameras stand at
    different places along it), so its vertices' principal axis tilts by a few tenths
    of a degree (0.4 degree on a walk of `furnished`), which over 1.2 m widens it by
    8 mm and throws the circle of its whole cross-section off (1.5 cm against the true
    1.6); each short slice's circle still finds the axis (docs/lights.md).
    """
    ext = np.ptp(coords, axis=0) if len(coords) else np.zeros(3)
    if ext[0] <= 0 or ext[1] > 0.2 * ext[0]:
        return None
    edges = np.linspace(coords[:, 0].min(), coords[:, 0].max(), TUBE_SLICES + 1)
    part = np.clip(np.searchsorted(edges, coords[:, 0], side="right") - 1, 0, TUBE_SLICES - 1)
    rows = []
    for k in range(TUBE_SLICES):
        m = part == k
        if m.sum() >= TUBE_SLICE_VERTICES:
            centre, radius = fit_circle(coords[m, 1:3])
            if np.isfinite(radius) and radius > 0:
                rows.append([(edges[k] + edges[k + 1]) / 2, *centre, radius, m.sum()])
    if len(rows) < 4:
        return None
    out = np.asarray(rows, float)
    # Slices whose circle is far from the others' (an end cap, a stray vertex) do not
    # count; the rest must agree on a tube.
    med = np.median(out[:, 3])
    out = out[(out[:, 3] > 0.5 * med) & (out[:, 3] < 2.0 * med)]
    return out if len(out) >= 4 else None


def _axes_along(axes: np.ndarray, slices: np.ndarray) -> np.ndarray | None:
    """``axes`` turned so that the first runs through the slices' circle centres (a
    straight line fitted to them, weighted by their vertex counts); None where that
    line is more than 3 degrees off, or a centre more than a fifth of the median radius
    from it: not a tube the slices agree on (a fused scan's blob of tube and housing
    gives circles that wander by centimetres)."""
    w = np.sqrt(slices[:, 4])
    f1 = np.polyfit(slices[:, 0], slices[:, 1], 1, w=w)
    f2 = np.polyfit(slices[:, 0], slices[:, 2], 1, w=w)
    b1, b2 = f1[0], f2[0]
    off = np.hypot(
        slices[:, 1] - np.polyval(f1, slices[:, 0]), slices[:, 2] - np.polyval(f2, slices[:, 0])
    )
    if np.hypot(b1, b2) > np.tan(np.radians(3.0)) or off.max() > 0.2 * np.median(slices[:, 3]):
        return None
    a0 = axes[0] + b1 * axes[1] + b2 * axes[2]
    a0 /= np.linalg.norm(a0)
    a1 = axes[1] - (axes[1] @ a0) * a0
    a1 /= np.linalg.norm(a1)
    a2 = np.cross(a0, a1)
    return np.stack([a0, a1, a2 if a2 @ axes[2] >= 0 else -a2])


def _min_area_axes(q: np.ndarray, axes: np.ndarray, steps: int = 90) -> np.ndarray:
    """Turn the two in-plane principal axes to the minimum-area bounding rectangle.

    PCA axes of a square (or any shape with equal in-plane variances) are arbitrary:
    a 0.6 m square panel would measure 0.85 m along its diagonal. The rectangle of
    least area over ``steps`` rotations (1 degree apart) gives the true sides; the
    longer side comes first.
    """
    uv = q @ axes[:2].T
    theta = np.linspace(0.0, np.pi / 2, steps, endpoint=False)
    c, s = np.cos(theta), np.sin(theta)
    x = uv[:, :1] * c + uv[:, 1:2] * s  # (n, steps)
    y = -uv[:, :1] * s + uv[:, 1:2] * c
    area = np.ptp(x, axis=0) * np.ptp(y, axis=0)
    best = int(np.argmin(area))
    a0 = c[best] * axes[0] + s[best] * axes[1]
    a1 = -s[best] * axes[0] + c[best] * axes[1]
    if np.ptp(y[:, best]) > np.ptp(x[:, best]):
        a0, a1 = a1, a0
    return np.stack([a0, a1, axes[2]])


def _outer_ring(
    members: np.ndarray, points: np.ndarray, tree: cKDTree, radius: float
) -> np.ndarray:
    """Vertices within ``radius`` of the ``members`` (at ``points``) but not members."""
    near = tree.query_ball_point(points, radius, return_sorted=False)
    found = np.unique(np.concatenate([np.asarray(x, np.int64) for x in near]))
    return np.setdiff1d(found, members, assume_unique=True)
