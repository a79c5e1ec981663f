"""A solved point light's profile at twice the resolution, from the data it was solved on.

The solve of eq. 5.7 gives each point light 32 inclination bins of 5.6 degrees (the
thesis's resolution), and every light, albedo and the light's own power come out of that
solve. A downlight's beam has structure finer than a bin (`furnished`'s IES profile peaks
at 0 and 15 degrees, dips at 5 and cuts off between 26 and 30), so the solved profile
lays its sharp scallops on the walls as wide ramps, and the photo textures, fitted to the
model's light, hold the difference: switched off or moved, the light leaves a ghost of
its scallops where it was (docs/invert.md, session 28).

:func:`split_bins` refines the profile *after* the solve, with everything else held: each
bin is split in two, and the share of the bin's flux that goes into its first half is
fitted to the receivers by bounded weighted least squares (the solve's own final weights,
eq. 5.8 and Huber). Each bin's flux, so the light's power and its 32-bin distribution,
stays exactly what the solve found: the split only says where inside each bin the light
goes. A weak ridge toward the even split (equal intensity in both halves) holds the bins
that few receivers see. Solving at 64 bins from the start instead gave the point lights
freedom that the flat valley between lights turned into error elsewhere (the `furnished`
window 5 points weaker and the tube 7 points stronger, docs/invert.md, session 28).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import lsq_linear

from reroom.invert.basis import InclinationBasis

__all__ = ["apply_shares", "bin_solid_angles", "coarsen", "split_bins"]


def bin_solid_angles(basis: InclinationBasis) -> np.ndarray:
    """``(bins,)`` solid angle of each inclination bin (sum ``4 pi``)."""
    e = basis.bin_edges()
    return 2.0 * np.pi * (np.cos(e[:-1]) - np.cos(e[1:]))


def apply_shares(coarse: np.ndarray, share: np.ndarray) -> np.ndarray:
    """``(2m, ...)`` half-bin intensities that put ``share[k]`` of bin ``k``'s flux in its
    first half and the rest in its second (``coarse``: ``(m,)`` or ``(m, 3)``)."""
    coarse = np.asarray(coarse, np.float64)
    m = coarse.shape[0]
    omega_fine = bin_solid_angles(InclinationBasis(2 * m))
    flux = coarse * (omega_fine[0::2] + omega_fine[1::2]).reshape((m,) + (1,) * (coarse.ndim - 1))
    s = np.asarray(share, np.float64).reshape((m,) + (1,) * (coarse.ndim - 1))
    fine = np.empty((2 * m,) + coarse.shape[1:])
    fine[0::2] = flux * s / omega_fine[0::2].reshape(s.shape)
    fine[1::2] = flux * (1.0 - s) / omega_fine[1::2].reshape(s.shape)
    return fine


def coarsen(fine: np.ndarray) -> np.ndarray:
    """The ``m`` bins carrying the same flux as ``2m`` half bins (the inverse of
    :func:`apply_shares` for the intensities)."""
    fine = np.asarray(fine, np.float64)
    w = bin_solid_angles(InclinationBasis(len(fine))).reshape((len(fine),) + (1,) * (fine.ndim - 1))
    return (fine[0::2] * w[0::2] + fine[1::2] * w[1::2]) / (w[0::2] + w[1::2])


def split_bins(
    coarse: np.ndarray,
    fine_transfer: np.ndarray,
    target: np.ndarray,
    gain: np.ndarray,
    weights: np.ndarray,
    ridge: float = 1e-2,
) -> tuple[np.ndarray, np.ndarray]:
    """Split each of a light's ``m`` inclination bins in two, keeping each bin's flux.

    Parameters
    ----------
    coarse:
        ``(m, 3)`` the solved intensities per bin and channel (per steradian).
    fine_transfer:
        ``(n, 2m)`` the light's transfer at the receivers for the ``2m`` half bins
        (:func:`reroom.invert.direct.point_light_transfer` with ``InclinationBasis(2m)``).
    target:
        ``(n, 3)`` what the light must explain: the observed radiance less the model of
        everything else (``Lbar - rho / pi (E_ind + sum of the other lights)``).
    gain:
        ``(n, 3)`` the factor from irradiance to radiance at each receiver (``rho / pi``).
    weights:
        ``(n, 3)`` weight of each data term (the solve's final weights; 0 leaves it out).
    ridge:
        Weight of the pull toward the even split, relative to the mean of the normal
        matrix's diagonal: a half bin that sees less data than that stays even.

    Returns
    -------
    fine:
        ``(2m, 3)`` intensities per half bin; ``fine[2k] * omega[2k] + fine[2k + 1] *
        omega[2k + 1] == coarse[k] * Omega[k]`` for every bin and channel.
    share:
        ``(m,)`` the fitted share of each bin's flux in its first half (toward the axis).
    """
    coarse = np.asarray(coarse, np.float64)
    m = coarse.shape[0]
    f = np.asarray(fine_transfer, np.float64)
    if f.shape[1] != 2 * m:
        raise ValueError(f"fine_transfer has {f.shape[1]} columns, expected {2 * m}")
    omega_fine = bin_solid_angles(InclinationBasis(2 * m))
    omega = omega_fine[0::2] + omega_fine[1::2]
    flux = coarse * omega[:, None]  # (m, 3)
    per_sr_a = f[:, 0::2] / omega_fine[0::2]  # irradiance per unit flux of each half
    per_sr_b = f[:, 1::2] / omega_fine[1::2]
    even = omega_fine[0::2] / omega  # the share that gives both halves one intensity
    sw = np.sqrt(np.clip(np.asarray(weights, np.float64), 0.0, None))
    g = np.asarray(gain, np.float64)
    # target_c = g_c (B + D t) . flux_c for each channel c, stacked over channels.
    rows_a, rows_b = [], []
    for c in range(3):
        a = g[:, c : c + 1] * (per_sr_a - per_sr_b) * flux[None, :, c]
        base = g[:, c] * (per_sr_b @ flux[:, c])
        rows_a.append(sw[:, c : c + 1] * a)
        rows_b.append(sw[:, c] * (np.asarray(target, np.float64)[:, c] - base))
    a = np.concatenate(rows_a)
    b = np.concatenate(rows_b)
    diag = (a * a).sum(axis=0)
    lam = ridge * float(diag.mean()) if diag.any() else 1.0
    a = np.concatenate([a, np.sqrt(lam) * np.eye(m)])
    b = np.concatenate([b, np.sqrt(lam) * even])
    share = lsq_linear(a, b, bounds=(0.0, 1.0), method="bvls").x
    return apply_shares(coarse, share), share
