"""Floor and ceiling heights from histograms of the heights of horizontal surfaces (§4.2.2).

The vertices whose normals are nearly vertical are histogrammed by height with bins of
the mesh resolution ``r``. The floor is the first (lowest) local maximum that is a real
surface rather than noise: at least ``min_peak`` of the tallest peak. The ceiling is the
same search from the top. Each peak is then refined to sub-bin precision by the weighted
median height of the vertices within one bin of it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage


@dataclass(frozen=True)
class PlaneFit:
    """A horizontal plane found in a height histogram.

    Attributes
    ----------
    z:
        Height of the plane (aligned frame, metres).
    support:
        Total weight (area, m²) of the vertices within one bin of it.
    spread:
        Median absolute deviation of those vertices' heights (metres): the plane's
        thickness in the scan (noise plus tilt).
    """

    z: float
    support: float
    spread: float


def _local_maxima(hist: np.ndarray) -> np.ndarray:
    """Indices of the plateau-aware local maxima of a 1D histogram."""
    left = np.concatenate([[-np.inf], hist[:-1]])
    right = np.concatenate([hist[1:], [-np.inf]])
    return np.flatnonzero((hist > left) & (hist >= right) & (hist > 0))


def _refine(z: np.ndarray, w: np.ndarray, centre: float, half: float) -> PlaneFit:
    near = np.abs(z - centre) <= half
    zs, ws = z[near], w[near]
    order = np.argsort(zs)
    zs, ws = zs[order], ws[order]
    cw = np.cumsum(ws)
    med = float(zs[np.searchsorted(cw, 0.5 * cw[-1])])
    mad = float(np.median(np.abs(zs - med)))
    return PlaneFit(med, float(ws.sum()), mad)


def horizontal_planes(
    z: np.ndarray,
    nz: np.ndarray,
    weights: np.ndarray,
    bin_size: float,
    cos_vertical: float = np.cos(np.radians(25.0)),
    min_peak: float = 0.2,
    oriented: bool = True,
) -> tuple[PlaneFit | None, PlaneFit | None]:
    """The floor and ceiling planes of a scan, in the Manhattan frame.

    Parameters
    ----------
    z:
        ``(V,)`` vertex heights (aligned frame).
    nz:
        ``(V,)`` vertical component of the unit vertex normals. Upward-facing vertices
        (``nz > cos_vertical``) vote for the floor, downward-facing ones for the ceiling.
    weights:
        ``(V,)`` vertex areas.
    bin_size:
        Histogram bin width, the mesh resolution ``r`` (metres).
    cos_vertical:
        How vertical a normal must be to count.
    min_peak:
        A local maximum counts as a plane only if its bin holds at least this fraction
        of the tallest bin (so noise specks below the floor are skipped).
    oriented:
        Whether the normals point out of the surfaces into the room (fused scans do);
        if not, any vertical normal votes for both planes, as in the thesis.

    Returns
    -------
    floor, ceiling
        :class:`PlaneFit` or ``None`` where none was found. The ceiling is only accepted
        above the floor.
    """
    z = np.asarray(z, np.float64)
    if len(z) == 0:
        return None, None
    lo, hi = float(z.min()) - bin_size, float(z.max()) + bin_size
    nbins = max(3, int(np.ceil((hi - lo) / bin_size)))
    edges = lo + bin_size * np.arange(nbins + 1)

    def find(mask: np.ndarray, from_top: bool) -> PlaneFit | None:
        if mask.sum() < 3:
            return None
        hist, _ = np.histogram(z[mask], bins=edges, weights=weights[mask])
        # A light smoothing so a plane straddling two bins is one peak, not two.
        sm = ndimage.convolve1d(hist, np.array([0.25, 0.5, 0.25]), mode="constant")
        peaks = _local_maxima(sm)
        if len(peaks) == 0:
            return None
        strong = peaks[sm[peaks] >= min_peak * sm[peaks].max()]
        k = strong[-1] if from_top else strong[0]
        centre = 0.5 * (edges[k] + edges[k + 1])
        return _refine(z[mask], weights[mask], centre, 1.5 * bin_size)

    if oriented:
        floor = find(nz > cos_vertical, from_top=False)
        ceiling = find(nz < -cos_vertical, from_top=True)
    else:
        floor = find(np.abs(nz) > cos_vertical, from_top=False)
        ceiling = find(np.abs(nz) > cos_vertical, from_top=True)
    if floor is not None and ceiling is not None and ceiling.z <= floor.z + 3 * bin_size:
        ceiling = None
    return floor, ceiling
