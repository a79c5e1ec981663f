"""A window's environment map for rendering, from the photos' pixels seen through it.

The inverse rendering solves a window's distant light on a coarse cube-map basis (96
cells): enough for the light it sends into the room, but a new camera looking *at* the
window sees a few flat blocks. The input photos, though, look through the opening:
:func:`observe_windows` casts every (or every ``stride``-th) pixel ray of every frame
against the HDR mesh, keeps those that leave through a window
(:func:`reroom.invert.windows.rays_through_windows`), linearises the pixels with the
HDR stage's response and divides by the frame's exposure ``scale``
(``hdr/exposures.json``: linear pixel = scale x radiance), so the samples are in the HDR
mesh's radiance units, and bins them by direction into a lat-long map (the portal's
convention, :mod:`reroom.render.emitters`).

:func:`refine_cells` then combines the photos with the solved cells so that the
*lighting* stays the solve's: within each cube cell the photos only give the *shape*.

* The photos' value of a texel is the mean of its unsaturated samples; a texel seen only
  saturated (8-bit code >= 255 in some channel) has a lower bound instead,
  ``linear / scale`` of its brightest sample (:func:`fill_gaps` first fills single
  empty texels inside the seen region from their neighbours).
* A cell with at least ``min_texels`` texels seen unsaturated (and ``min_samples``
  unsaturated samples) gets ``solved x value / mean value`` on its seen texels (the mean
  solid-angle weighted over the cell's seen texels, saturated ones counted at their
  bound, so a clipped bright sky does not inflate the unsaturated texels next to it) and
  its solved value on the texels no photo saw. The cell's mean is then its solved value.
  Other cells keep their solved value everywhere.
* A saturated texel is at least as bright as its bound: where the value above falls
  below the bound (in any cell), the texel is raised to it, and the energy this adds is
  taken back from the cell's other texels (scaled down together), so the cell's mean
  stays the solved value. Where the bounds alone hold more than the cell's solved
  energy, the whole cell is scaled down to that energy (the solve's light wins over the
  bound; counted as ``cells_bound_capped``).

So every cell keeps its solved mean channel by channel: the power, the light the room
receives at the cube map's resolution and the albedos solved with it stay consistent;
only where the light comes from *within* a cell changes, and the directions no photo saw
look as before.

:func:`cell_means` gives the solve the photos' radiance of the cells they see cleanly
(no saturated sample in the cell), for ``InvertOptions.window_photo_prior``;
:func:`cell_lower_bounds` what their pixels, clipped ones included, prove about every
cell, for ``InvertOptions.window_photo_bounds``.
"""

from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from reroom.errors import ReroomError, ScanError
from reroom.invert.basis import CubemapBasis
from reroom.invert.photos import frame_scale, open_photos, pixel_grid
from reroom.invert.windows import WindowOpening, rays_through_windows

__all__ = [
    "WindowPhotos",
    "WindowView",
    "cell_lower_bounds",
    "cell_means",
    "cell_shapes",
    "fill_gaps",
    "latlong_directions",
    "latlong_lookup",
    "latlong_solid_angles",
    "map_cell_means",
    "observe_windows",
    "photo_environments",
    "read_view_hdri",
    "refine_cells",
    "view_map",
]


def latlong_directions(height: int) -> np.ndarray:
    """``(height, 2 height, 3)`` unit directions of the texel centres of a lat-long map.

    Row 0 is the zenith, ``u = 0.5 - atan2(y, x) / 2 pi`` (the portal's convention, as
    :func:`reroom.invert.export.latlong_from_cubemap`).
    """
    h, w = int(height), 2 * int(height)
    theta = (np.arange(h) + 0.5) / h * np.pi
    phi = (0.5 - (np.arange(w) + 0.5) / w) * 2 * np.pi
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    return np.stack(
        np.broadcast_arrays(st * np.cos(phi)[None, :], st * np.sin(phi)[None, :], ct), axis=-1
    )


def latlong_solid_angles(height: int) -> np.ndarray:
    """``(height, 2 height)`` solid angle of each texel (they sum to ``4 pi``)."""
    h, w = int(height), 2 * int(height)
    edges = np.cos(np.linspace(0.0, np.pi, h + 1))
    return np.repeat(((edges[:-1] - edges[1:]) * 2 * np.pi / w)[:, None], w, axis=1)


def _texel_index(directions: np.ndarray, height: int) -> np.ndarray:
    """Flat lat-long texel index of unit directions ``(N, 3)``."""
    h, w = int(height), 2 * int(height)
    d = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    u = np.mod(0.5 - np.arctan2(d[:, 1], d[:, 0]) / (2 * np.pi), 1.0)
    v = np.arccos(np.clip(d[:, 2], -1.0, 1.0)) / np.pi
    col = np.minimum((u * w).astype(np.int64), w - 1)
    row = np.minimum((v * h).astype(np.int64), h - 1)
    return row * w + col


@dataclass
class WindowPhotos:
    """What the photos saw through one window, per texel of a ``(H, 2H)`` lat-long map.

    Attributes
    ----------
    mean:
        ``(H, W, 3)`` mean radiance of the unsaturated samples (HDR mesh units); NaN
        where there is none.
    count:
        ``(H, W)`` number of unsaturated samples.
    bound:
        ``(H, W, 3)`` largest lower bound from saturated samples (``linear / scale``, 0
        where there is none).
    saturated:
        ``(H, W)`` number of saturated samples.
    channel_mean:
        ``(H, W, 3)`` per channel, the mean over every sample whose code in *that*
        channel is below the white level (a pixel clipped in red and green still
        measures its blue); NaN where there is none. None when not gathered.
    """

    mean: np.ndarray
    count: np.ndarray
    bound: np.ndarray
    saturated: np.ndarray
    channel_mean: np.ndarray | None = None

    @property
    def height(self) -> int:
        return int(self.mean.shape[0])


@dataclass
class _Accumulator:
    height: int
    total: np.ndarray = field(init=False)
    count: np.ndarray = field(init=False)
    bound: np.ndarray = field(init=False)
    saturated: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        n = 2 * self.height * self.height
        self.total = np.zeros((n, 3))
        self.count = np.zeros(n, np.int64)
        self.bound = np.zeros((n, 3))
        self.saturated = np.zeros(n, np.int64)
        self.channel_total = np.zeros((n, 3))
        self.channel_count = np.zeros((n, 3), np.int64)

    def add(
        self,
        directions: np.ndarray,
        values: np.ndarray,
        sat: np.ndarray,
        clipped: np.ndarray | None = None,
    ) -> None:
        """Samples: their directions, radiance, whether saturated (any channel) and, per
        channel, whether that channel clipped (default: all of a saturated sample's)."""
        idx = _texel_index(directions, self.height)
        ok = ~sat
        n = len(self.count)
        clipped = np.repeat(sat[:, None], 3, axis=1) if clipped is None else clipped
        self.count += np.bincount(idx[ok], minlength=n)
        for c in range(3):
            self.total[:, c] += np.bincount(idx[ok], weights=values[ok, c], minlength=n)
            np.maximum.at(self.bound[:, c], idx[sat], values[sat, c])
            fine = ~clipped[:, c]
            self.channel_total[:, c] += np.bincount(idx[fine], weights=values[fine, c], minlength=n)
            self.channel_count[:, c] += np.bincount(idx[fine], minlength=n)
        self.saturated += np.bincount(idx[sat], minlength=n)

    def result(self) -> WindowPhotos:
        h, w = self.height, 2 * self.height
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = np.where(self.count[:, None] > 0, self.total / self.count[:, None], np.nan)
            channel = np.where(
                self.channel_count > 0, self.channel_total / self.channel_count, np.nan
            )
        return WindowPhotos(
            mean.reshape(h, w, 3),
            self.count.reshape(h, w),
            self.bound.reshape(h, w, 3),
            self.saturated.reshape(h, w),
            channel.reshape(h, w, 3),
        )


def _interior(mask: np.ndarray) -> np.ndarray:
    """Pixels whose 4 neighbours have the same (non-negative) label: no mixed rim pixels."""
    out = mask >= 0
    out[0, :] = out[-1, :] = False
    out[:, 0] = out[:, -1] = False
    c = mask[1:-1, 1:-1]
    inner = (
        (mask[:-2, 1:-1] == c)
        & (mask[2:, 1:-1] == c)
        & (mask[1:-1, :-2] == c)
        & (mask[1:-1, 2:] == c)
    )
    out[1:-1, 1:-1] &= inner
    return out


def fill_gaps(photos: WindowPhotos) -> WindowPhotos:
    """Fill texels no sample fell in from their 8 neighbours (one pass).

    A pixel of a low-resolution frame is about as wide as a texel, so the samples of
    one view leave scattered empty texels inside the region seen. An empty texel with
    seen neighbours takes, when most of their samples are unsaturated, the mean of those
    samples; otherwise the smallest positive bound among its saturated neighbours.
    Counts stay those of the real samples (a filled texel has count 0 and a finite
    ``mean``, or a positive ``bound``).
    """
    h, w = photos.mean.shape[:2]
    count = photos.count.astype(np.float64)
    total = np.nan_to_num(photos.mean) * count[..., None]
    sat = photos.saturated.astype(np.float64)
    big = np.where(photos.saturated[..., None] > 0, photos.bound, np.inf)

    def neighbours(x: np.ndarray, fn, init: float) -> np.ndarray:
        pad = np.full((h + 2, w + 2, *x.shape[2:]), init)
        pad[1:-1, 1:-1] = x
        pad[1:-1, 0], pad[1:-1, -1] = x[:, -1], x[:, 0]  # periodic in u
        out = np.full_like(x, init, dtype=np.float64)
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                if dy or dx:
                    out = fn(out, pad[1 + dy : h + 1 + dy, 1 + dx : w + 1 + dx])
        return out

    n_count = neighbours(count, np.add, 0.0)
    n_total = neighbours(total, np.add, 0.0)
    n_sat = neighbours(sat, np.add, 0.0)
    n_bound = neighbours(big, np.minimum, np.inf)
    empty = (photos.count == 0) & (photos.saturated == 0)
    fill_mean = empty & (n_count > 0) & (n_count >= n_sat)
    fill_bound = empty & (n_sat > n_count) & np.isfinite(n_bound).all(axis=-1)
    mean = photos.mean.copy()
    bound = photos.bound.copy()
    mean[fill_mean] = n_total[fill_mean] / n_count[fill_mean][:, None]
    bound[fill_bound] = n_bound[fill_bound]
    channel = photos.channel_mean
    if channel is not None:  # each channel's measured texels' mean, as ``mean``'s
        channel = channel.copy()
        have = np.isfinite(channel)
        for c in range(3):
            n_have = neighbours(have[..., c].astype(np.float64), np.add, 0.0)
            n_sum = neighbours(np.where(have[..., c], channel[..., c], 0.0), np.add, 0.0)
            fill = empty & ~have[..., c] & (n_have > 0)
            channel[fill, c] = n_sum[fill] / n_have[fill]
    return WindowPhotos(mean, photos.count.copy(), bound, photos.saturated.copy(), channel)


def _may_see_windows(frame, openings: list[WindowOpening], grid: int = 9) -> bool:
    """Whether any window may be in the frame's view (so its pixels are worth casting).

    A ``grid x grid`` lattice of points on each window rectangle is projected into the
    frame; the frame is kept when any point lands in the image in front of the camera.
    Most frames of a walk-through never look at a window, and casting every pixel of
    each (tens of millions of rays for 300 frames of 640x360) would cost far more than
    the pixels that do see one. A window could only slip between the lattice points when
    the camera stands within about a lattice spacing of the glass; nothing is lost then
    but that frame.
    """
    s = np.linspace(-1.0, 1.0, grid)
    su, sv = np.meshgrid(s, s)
    for win in openings:
        pts = win.centre + su.reshape(-1, 1) * win.half_u + sv.reshape(-1, 1) * win.half_v
        _, _, inside = frame.project(pts)
        if np.any(inside):
            return True
    return False


def observe_windows(
    scan_dir: str | Path,
    mesh,
    openings: list[WindowOpening],
    *,
    height: int = 128,
    max_rays_per_frame: int = 60_000,
    saturation_level: int = 255,
    erode: bool = True,
    caster=None,
    also_heights: tuple[int, ...] = (),
) -> tuple[list[WindowPhotos], dict[str, Any]]:
    """Bin the photos' pixels seen through each window into a lat-long map per window.

    Parameters
    ----------
    scan_dir:
        The scan (``transforms.json``, images, ``hdr/exposures.json``).
    mesh:
        The HDR mesh (``trimesh.Trimesh``) the rays are cast against.
    openings:
        The windows.
    height:
        Rows of the lat-long maps (width ``2 height``).
    max_rays_per_frame:
        Pixels are taken on a regular grid with this many at most per frame.
    saturation_level:
        An 8-bit code at or above it in any channel marks a pixel saturated: its
        value is only a lower bound.
    erode:
        Drop pixels next to a pixel that does not look through the same window (they
        mix the window's rim with the outdoors).
    caster:
        A :class:`reroom.rays.RayCaster` on ``mesh`` (built if not given).
    also_heights:
        Further map heights to bin the same pixels into, from the same rays (one cast
        and one read of each frame for all of them).

    Returns
    -------
    photos, stats
        One :class:`WindowPhotos` per opening, and counts (frames used, frames skipped
        with the reason, samples, saturated samples) plus ``notes``; with
        ``also_heights``, ``stats["also"][h]`` holds the openings' maps at height ``h``.

    Frames whose image cannot be read are skipped with a warning naming the file;
    frames without an exposure (``scale`` null) are skipped silently (counted).
    """
    from reroom.hdr.linearize import linearize
    from reroom.rays import RayCaster

    notes: list[str] = []
    scan, scales, lut = open_photos(scan_dir, notes.append)
    caster = caster if caster is not None else RayCaster(mesh)
    heights = [int(height), *(int(h) for h in also_heights)]
    accs = [[_Accumulator(h) for _ in openings] for h in heights]
    stats: dict[str, Any] = {
        "frames": len(scan.frames),
        "frames_used": 0,
        "frames_no_exposure": 0,
        "frames_unreadable": [],
        "samples": [0] * len(openings),
        "saturated": [0] * len(openings),
    }
    for j, frame in enumerate(scan.frames):
        scale = frame_scale(scales, j)
        if scale is None:
            stats["frames_no_exposure"] += 1
            continue
        k = frame.intrinsics
        if not _may_see_windows(frame, openings):
            stats["frames_used"] += 1
            stats["frames_skipped_no_window"] = stats.get("frames_skipped_no_window", 0) + 1
            continue
        rows, cols = pixel_grid(k.width, k.height, max_rays_per_frame)
        jj, ii = np.meshgrid(cols, rows)
        uv = np.stack([jj.ravel() + 0.5, ii.ravel() + 0.5], axis=1)
        o, d = frame.pixel_rays(uv)
        hits = caster.intersect(o, d, tmin=caster.eps)
        win = rays_through_windows(o, d, hits.t, openings)
        if not (win >= 0).any():
            stats["frames_used"] += 1
            continue
        try:
            img = frame.load_image()
        except (ReroomError, OSError, ValueError) as exc:
            msg = f"window photos: skipped frame {frame.image_path}: cannot read it ({exc})"
            warnings.warn(msg, stacklevel=2)
            stats["frames_unreadable"].append(str(frame.image_path))
            notes.append(msg)
            continue
        keep = _interior(win.reshape(len(rows), len(cols))).ravel() if erode else win >= 0
        codes = img[ii.ravel(), jj.ravel()]
        values = linearize(codes, lut).astype(np.float64) / scale
        clipped = codes >= saturation_level
        sat = clipped.any(axis=1)
        for w in range(len(openings)):
            sel = keep & (win == w)
            if sel.any():
                for acc in accs:
                    acc[w].add(d[sel], values[sel], sat[sel], clipped[sel])
                stats["samples"][w] += int(sel.sum())
                stats["saturated"][w] += int(sat[sel].sum())
        stats["frames_used"] += 1
    stats["notes"] = notes
    if also_heights:
        stats["also"] = {
            h: [a.result() for a in acc] for h, acc in zip(heights[1:], accs[1:], strict=True)
        }
    return [a.result() for a in accs[0]], stats


def refine_cells(
    cells: np.ndarray,
    basis: CubemapBasis,
    photos: WindowPhotos,
    *,
    min_texels: int = 8,
    min_samples: int = 32,
    use_bounds: bool = True,
) -> tuple[np.ndarray, dict[str, Any]]:
    """The ``(H, 2H, 3)`` rendering map of a window: its solved cells shaped by the photos.

    See the module notes for the rule. Every cube cell keeps its solved mean over its
    texels (solid-angle weighted; a texel belongs to the cell of its centre, as in
    :func:`reroom.invert.export.latlong_from_cubemap`), channel by channel; a cell whose
    solved value is not positive is left as solved.

    Returns
    -------
    env, info
        The map, and counts: ``cells_refined`` (shaped by unsaturated texels),
        ``cells_bound_raised`` (with texels raised to their saturated bound),
        ``cells_bound_capped`` (bounds above the solved energy: scaled down),
        ``texels_observed``, ``texels_saturated_only``, and ``solved_over_photos``
        (median over refined cells of solved / mean observed luminance: 1 when the solve
        and the photos agree on the window's brightness).
    """
    cells = np.asarray(cells, np.float64)
    h = photos.height
    cell = basis.cell_of(latlong_directions(h).reshape(-1, 3))
    area = latlong_solid_angles(h).ravel()
    mean = photos.mean.reshape(-1, 3)
    count = photos.count.ravel()
    bound = photos.bound.reshape(-1, 3)
    seen = np.isfinite(mean).all(axis=1)
    sat_only = (bound > 0).any(axis=1) & ~seen
    if not use_bounds:
        sat_only[:] = False
    # The shape: unsaturated texels' mean, saturated-only texels' lower bound.
    shape = np.where(seen[:, None], np.nan_to_num(mean), bound)
    out = cells[cell].copy()
    refined = raised = capped = 0
    ratios = []
    lum = np.array([0.2126, 0.7152, 0.0722])
    order = np.argsort(cell, kind="stable")
    starts = np.searchsorted(cell[order], np.arange(basis.size + 1))
    for j in range(basis.size):
        m = order[starts[j] : starts[j + 1]]
        if len(m) == 0:
            continue
        a = area[m]
        s = sat_only[m]
        u = seen[m]
        enough = u.sum() >= min_texels and count[m][u].sum() >= min_samples
        shaped = u | s  # the texels the photos give a value (or a bound) for
        obs = None
        if enough:
            obs = (a[shaped, None] * shape[m][shaped]).sum(0) / a[shaped].sum()
            if float(obs @ lum) > 0 and float(cells[j] @ lum) > 0:
                ratios.append(float(cells[j] @ lum) / float(obs @ lum))
        did_refine = did_raise = did_cap = False
        for c in range(3):
            target = cells[j, c]
            if not target > 0:
                continue
            vals = np.full(len(m), target)
            if obs is not None and obs[c] > 0:
                vals[shaped] = target * shape[m][shaped, c] / obs[c]
                did_refine = True
            lift = s & (bound[m, c] > vals)
            if lift.any():
                did_raise = True
                vals[lift] = bound[m][lift, c]
                total = target * a.sum()
                fixed = float((a[lift] * vals[lift]).sum())
                rest = float((a[~lift] * vals[~lift]).sum())
                if fixed <= total and rest > 0:
                    vals[~lift] *= (total - fixed) / rest
                else:
                    did_cap = True
                    vals *= total / float((a * vals).sum())
            out[m, c] = vals
        refined += did_refine
        raised += did_raise
        capped += did_cap
    info = {
        "cells_refined": int(refined),
        "cells_bound_raised": int(raised),
        "cells_bound_capped": int(capped),
        "texels_observed": int(seen.sum()),
        "texels_saturated_only": int(sat_only.sum()),
        "solved_over_photos": float(np.median(ratios)) if ratios else None,
    }
    return out.reshape(h, 2 * h, 3), info


def _local_colour(mean: np.ndarray, seen: np.ndarray, ref: np.ndarray, radius: int) -> np.ndarray:
    """``(H, W, 3)`` the luminance-weighted mean colour of the texels seen unsaturated
    within ``radius`` texels (``ref`` where none is)."""
    from scipy.ndimage import uniform_filter

    lum = np.where(seen, np.nan_to_num(mean) @ np.array([0.2126, 0.7152, 0.0722]), 0.0)
    size = 2 * int(radius) + 1
    w = uniform_filter(lum, size, mode="wrap")
    out = np.empty(mean.shape)
    for c in range(3):
        out[..., c] = uniform_filter(lum * np.nan_to_num(mean[..., c]), size, mode="wrap")
    good = w > 1e-12 * max(float(lum.max()), 1e-300)
    out[good] /= w[good, None]
    out[~good] = ref
    out[good] = np.where(out[good] > 0, out[good], ref)
    return out


def view_map(
    photos: WindowPhotos, env: np.ndarray, reference_share: float = 0.2, radius: int = 10
) -> tuple[np.ndarray, dict[str, Any]]:
    """The window as a camera looking through it sees it: the photos' own radiance.

    :func:`refine_cells` keeps every cell's solved mean, so that the light the window
    sends into the room stays the solve's; looked at directly, though, a cell's mean is
    only as good as the solve of that cell from the room's light (on `furnished`, a
    frame that looks out of the window saw the outdoors through it at 1.03 / 0.86 / 0.77
    of the truth: the cells' colour). The photos measured what they saw:

    * a texel seen unsaturated shows the mean of its unsaturated samples;
    * a texel seen only in pixels that clipped in some channels shows, in each channel
      some sample did not clip, that channel's mean (``channel_mean``), and in the
      clipped channels the larger of their bound and the measured channels times the
      colour of the texels seen unsaturated within ``radius`` texels (weighted by
      their luminance; where there are none, of the brightest ``reference_share`` seen
      anywhere): a clipped patch is taken to have the colour of what is seen around it,
      as far as that is brighter than the bound;
    * a texel seen clipped in every channel shows the lighting map ``env`` (resampled,
      bilinear) raised to its bound; one no photo saw, ``env``.

    The renderer shows this map to the camera only (:mod:`reroom.render.frames`); the
    room is lit by ``env``. Returns the ``(H, 2H, 3)`` map (``photos``' resolution;
    :func:`fill_gaps` it first) and counts: ``texels_measured``,
    ``texels_partly_clipped`` and ``texels_from_light``.
    """
    from reroom.render.emitters import latlong_lookup as bilinear

    h = photos.height
    d = latlong_directions(h).reshape(-1, 3)
    base = bilinear(np.asarray(env, np.float64), d).reshape(h, 2 * h, 3)
    seen = np.isfinite(photos.mean).all(axis=-1)
    out = np.where(seen[..., None], np.nan_to_num(photos.mean), np.maximum(base, photos.bound))
    partly = np.zeros_like(seen)
    if photos.channel_mean is not None and seen.any():
        exact = np.isfinite(photos.channel_mean) & ~seen[..., None]
        partly = exact.any(axis=-1) & ~exact.all(axis=-1)
        lum = np.nan_to_num(photos.mean[seen]) @ np.array([0.2126, 0.7152, 0.0722])
        top = lum >= np.quantile(lum, 1.0 - reference_share)
        ref = np.median(np.nan_to_num(photos.mean[seen][top]), axis=0)
        if np.all(ref > 0) and partly.any():
            cm = np.where(exact, photos.channel_mean, np.nan)[partly]
            colour = _local_colour(photos.mean, seen, ref, radius)[partly]
            level = np.nanmean(cm / colour, axis=-1)  # the measured channels over the colour
            guess = np.maximum(photos.bound[partly], level[:, None] * colour)
            out[partly] = np.where(np.isfinite(cm), cm, guess)
        else:
            partly[:] = False
    info = {
        "texels_measured": int(seen.sum()),
        "texels_partly_clipped": int(partly.sum()),
        "texels_from_light": int((~seen & ~partly).sum()),
    }
    return np.maximum(out, 0.0), info


def cell_means(
    photos: WindowPhotos,
    basis: CubemapBasis,
    *,
    min_texels: int = 8,
    min_samples: int = 32,
) -> tuple[np.ndarray, np.ndarray]:
    """The photos' radiance of each cube cell where they see it cleanly, for the solve.

    Only *clean* texels count: seen unsaturated and never saturated. A texel with some
    saturated samples keeps only its darker views, so its unsaturated mean is biased
    low; and a cell with any saturated texel is left out whole, as its clean texels are
    then its darker part (a bright sky clipped beside them). A cell with at least
    ``min_texels`` clean texels and ``min_samples`` samples in them, and no saturated
    sample, gets their solid-angle weighted mean; the fraction of the cell's solid angle
    they cover says how much of the cell that mean stands for.

    Returns
    -------
    means : ndarray, shape (basis.size, 3)
        Radiance (HDR mesh units) per cell; NaN where the photos do not see it cleanly.
    fraction : ndarray, shape (basis.size,)
        Clean texels' share of each cell's solid angle (0 where ``means`` is NaN).
    """
    h = photos.height
    cell = basis.cell_of(latlong_directions(h).reshape(-1, 3))
    area = latlong_solid_angles(h).ravel()
    mean = photos.mean.reshape(-1, 3)
    count = photos.count.ravel()
    clean = np.isfinite(mean).all(axis=1) & (photos.saturated.ravel() == 0) & (count > 0)
    n = basis.size
    texels = np.bincount(cell[clean], minlength=n)
    samples = np.bincount(cell[clean], weights=count[clean], minlength=n)
    a_clean = np.bincount(cell[clean], weights=area[clean], minlength=n)
    a_cell = np.bincount(cell, weights=area, minlength=n)
    means = np.full((n, 3), np.nan)
    clipped = np.bincount(cell, weights=photos.saturated.ravel(), minlength=n) > 0
    ok = (texels >= min_texels) & (samples >= min_samples) & (a_clean > 0) & ~clipped
    for c in range(3):
        total = np.bincount(cell[clean], weights=area[clean] * mean[clean, c], minlength=n)
        means[ok, c] = total[ok] / a_clean[ok]
    fraction = np.where(ok, a_clean / np.maximum(a_cell, 1e-300), 0.0)
    return means, fraction


def cell_lower_bounds(photos: WindowPhotos, basis: CubemapBasis) -> np.ndarray:
    """What the photos prove about each cube cell's mean radiance: a lower bound.

    Each texel the photos saw counts at the larger of its unsaturated samples' mean and
    its saturated samples' bound (a clipped pixel says only "at least this bright"),
    each texel no photo saw at 0, and the cell's bound is their solid-angle weighted
    mean over the whole cell. It is weak where a bright sky is clipped (a few per cent
    of the truth on `furnished`) and nearer the truth in the dim cells near the horizon,
    which the solve can otherwise leave at 0 (docs/invert.md, session 31).

    Returns
    -------
    ndarray, shape (basis.size, 3)
        Radiance (HDR mesh units) per cell; 0 where the photos see nothing of it.
    """
    h = photos.height
    cell = basis.cell_of(latlong_directions(h).reshape(-1, 3))
    area = latlong_solid_angles(h).ravel()
    mean = photos.mean.reshape(-1, 3)
    unsat = np.isfinite(mean).all(axis=1) & (photos.count.ravel() > 0)
    value = np.maximum(
        np.where(unsat[:, None], np.nan_to_num(mean), 0.0), photos.bound.reshape(-1, 3)
    )
    a_cell = np.bincount(cell, weights=area, minlength=basis.size)
    total = np.stack(
        [np.bincount(cell, weights=area * value[:, c], minlength=basis.size) for c in range(3)], 1
    )
    return total / np.maximum(a_cell, 1e-300)[:, None]


def cell_shapes(
    photos: WindowPhotos,
    basis: CubemapBasis,
    *,
    min_texels: int = 8,
    min_samples: int = 32,
) -> tuple[np.ndarray, dict[str, Any]]:
    """The photos' luminance pattern within each cube cell, for the window's transfer.

    A cell's basis function is constant over its solid angle, but the sky it stands for is
    not: receivers that see only part of a cell through the opening get that part's
    light, not the cell's mean. The photos show the pattern where they see the view, so
    the transfer can weight each direction by it (the cell's value stays its mean). Per
    texel: the unsaturated mean where there is one, the saturated samples' lower bound
    where there is only that (raised to at least the cell's seen mean), and the cell's
    seen mean where no photo looked; the texels' solid-angle weighted mean is then scaled
    to 1 in every cell. A cell with fewer than ``min_texels`` seen texels or
    ``min_samples`` samples stays flat (1).

    Returns
    -------
    shape : ndarray, shape (H, 2H)
        Luminance weight per texel, mean 1 over each cube cell.
    info : dict
        ``cells_shaped``, and ``spread``: the solid-angle weighted standard deviation of the
        shape over the shaped cells (0 for a sky that is flat within every cell).
    """
    h = photos.height
    cell = basis.cell_of(latlong_directions(h).reshape(-1, 3))
    area = latlong_solid_angles(h).ravel()
    lum = np.array([0.2126, 0.7152, 0.0722])
    count = photos.count.ravel()
    seen = np.isfinite(photos.mean.reshape(-1, 3)).all(axis=1) & (count > 0)
    value = np.where(seen, np.nan_to_num(photos.mean.reshape(-1, 3)) @ lum, 0.0)
    bound = photos.bound.reshape(-1, 3) @ lum
    n = basis.size
    texels = np.bincount(cell[seen], minlength=n)
    samples = np.bincount(cell[seen], weights=count[seen], minlength=n)
    a_seen = np.bincount(cell[seen], weights=area[seen], minlength=n)
    seen_mean = np.bincount(cell[seen], weights=area[seen] * value[seen], minlength=n)
    seen_mean = np.where(a_seen > 0, seen_mean / np.maximum(a_seen, 1e-300), 0.0)
    ok = (texels >= min_texels) & (samples >= min_samples) & (seen_mean > 0)
    level = seen_mean[cell]
    raw = np.where(seen, value, np.where(bound > 0, np.maximum(bound, level), level))
    cell_mean = np.bincount(cell, weights=area * raw, minlength=n) / np.maximum(
        np.bincount(cell, weights=area, minlength=n), 1e-300
    )
    shape = np.ones(len(cell))
    use = ok[cell] & (cell_mean[cell] > 0)
    shape[use] = raw[use] / cell_mean[cell[use]]
    spread = 0.0
    if use.any():
        spread = float(np.sqrt(np.average((shape[use] - 1.0) ** 2, weights=area[use])))
    return shape.reshape(h, 2 * h), {"cells_shaped": int(ok.sum()), "spread": round(spread, 4)}


def latlong_lookup(values: np.ndarray):
    """``f(directions (N, 3)) -> (N,)``: the texel of a ``(H, 2H)`` lat-long map each
    direction falls in (nearest texel, as the photos were binned)."""
    flat = np.asarray(values, np.float64).ravel()
    height = int(np.asarray(values).shape[0])

    def lookup(directions: np.ndarray) -> np.ndarray:
        return flat[_texel_index(np.asarray(directions, np.float64), height)]

    return lookup


@functools.lru_cache(maxsize=2)
def _read_view(path: str, mtime_ns: int) -> np.ndarray:
    """A view HDRI's pixels; cached: the solve and the outputs of one run read it again."""
    from reroom.render.emitters import load_hdri

    return load_hdri(path)


def read_view_hdri(path: str | Path) -> np.ndarray:
    """A captured window view's ``(H, W, 3)`` pixels, checked.

    Raises
    ------
    ScanError
        Naming the file when it is missing or unreadable, or when it is black or not
        finite (no pattern to take from it).
    """
    p = Path(path)
    if not p.is_file():
        raise ScanError(p, "the window's view HDRI is missing")
    try:
        image = _read_view(str(p), p.stat().st_mtime_ns)
    except (ReroomError, OSError, ValueError, RuntimeError) as exc:
        raise ScanError(p, f"cannot read the window's view HDRI ({exc})") from exc
    if not np.isfinite(image).all() or not (image.max() > 0):
        raise ScanError(p, "the window's view HDRI is black or not finite")
    return image


def map_cell_means(
    image: np.ndarray, basis: CubemapBasis, directions: np.ndarray, rotation_deg: float = 0.0
) -> np.ndarray:
    """``(basis.size, 3)`` mean of a lat-long map over the ``directions`` in each cube cell.

    The map is looked up bilinearly (:func:`reroom.render.emitters.latlong_lookup`, the
    portal's convention); a cell no direction falls in gets 0.
    """
    from reroom.render.emitters import latlong_lookup as lookup

    d = np.asarray(directions, np.float64)
    cell = basis.cell_of(d)
    vals = lookup(image, d, rotation_deg)
    count = np.bincount(cell, minlength=basis.size).astype(float)
    sums = np.stack(
        [np.bincount(cell, weights=vals[:, c], minlength=basis.size) for c in range(3)], 1
    )
    return sums / np.maximum(count, 1.0)[:, None]


@dataclass
class WindowView:
    """A captured HDRI of the view outside a window, for its pattern within each cube cell.

    The frames, exposed for the room, clip most of what they see through a window, so
    they cannot say how a cell's light is spread over it (:func:`cell_shapes`). An HDRI
    taken at the window (bracketed exposures merged; any overall scale) can: the solve
    still finds each cell's level, and the view says how it is spread. The map is
    equirectangular in the scan's frame (zenith up, the convention of
    :func:`reroom.render.emitters.latlong_direction_to_uv`) turned by ``rotation_deg``
    about +Z; ``means`` are its cell means over the directions that leave the room
    through the window (``d . n_in < 0``), which is what a cell's basis light stands for.
    """

    image: np.ndarray
    rotation_deg: float
    means: np.ndarray

    @classmethod
    def from_image(
        cls,
        image: np.ndarray,
        basis: CubemapBasis,
        inward_normal: np.ndarray,
        rotation_deg: float = 0.0,
        samples: int = 200_000,
        seed: int = 0,
    ) -> WindowView:
        rng = np.random.default_rng(seed)
        d = rng.standard_normal((samples, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        d = d[d @ np.asarray(inward_normal, float) < 0]
        means = map_cell_means(image, basis, d, rotation_deg)
        return cls(np.asarray(image), float(rotation_deg), means)

    @classmethod
    def load(
        cls,
        path: str | Path,
        basis: CubemapBasis,
        inward_normal: np.ndarray,
        rotation_deg: float = 0.0,
        seed: int = 0,
    ) -> WindowView:
        """:meth:`from_image` of an EXR file (read once per file and modification time;
        :func:`read_view_hdri` checks it)."""
        return cls.from_image(read_view_hdri(path), basis, inward_normal, rotation_deg, seed=seed)

    def _ratio(self, directions: np.ndarray, basis: CubemapBasis) -> np.ndarray:
        from reroom.render.emitters import latlong_lookup as lookup

        d = np.asarray(directions, np.float64)
        return lookup(self.image, d, self.rotation_deg), self.means[basis.cell_of(d)]

    def weight(self, basis: CubemapBasis):
        """``f(directions (N, 3)) -> (N,)``: luminance over the cell's mean luminance (1
        where the cell's mean is 0), for :func:`reroom.invert.portal.window_portal_transfer`."""
        lum = np.array([0.2126, 0.7152, 0.0722])

        def weight(directions: np.ndarray) -> np.ndarray:
            v, m = self._ratio(directions, basis)
            ml = m @ lum
            return np.where(ml > 0, (v @ lum) / np.maximum(ml, 1e-300), 1.0)

        return weight

    def environment(self, cells: np.ndarray, basis: CubemapBasis, height: int) -> np.ndarray:
        """``(H, 2H, 3)`` rendering map: each solved cell spread as the view spreads it,
        channel by channel (the cell's value where the view's cell mean is 0)."""
        d = latlong_directions(height).reshape(-1, 3)
        v, m = self._ratio(d, basis)
        c = np.asarray(cells, np.float64)[basis.cell_of(d)]
        out = np.where(m > 0, c * v / np.maximum(m, 1e-300), c)
        return out.reshape(height, 2 * height, 3)


def photo_environments(
    scan_dir: str | Path,
    mesh,
    windows: list[tuple[WindowOpening, np.ndarray]],
    basis: CubemapBasis | list[CubemapBasis],
    *,
    height: int = 128,
    caster=None,
    fill: bool = True,
    view_height: int = 0,
    **observe: Any,
) -> tuple[list[np.ndarray], list[dict[str, Any]], dict[str, Any]]:
    """Rendering maps of windows from the photos and their solved cells.

    ``windows`` pairs each opening with its ``(6 n^2, 3)`` solved cells, on ``basis``
    (one for all, or one per window). Returns the
    maps (:func:`refine_cells`, after :func:`fill_gaps` if ``fill``), a dict of figures per window (with its ``samples`` and
    ``saturated`` counts), and the frame statistics of :func:`observe_windows`.

    With ``view_height`` > 0 each window's figures also hold ``view_map``, the map a
    camera looking through it is shown (:func:`view_map`, at that many rows; the photos
    binned again at that resolution), and ``view`` its counts.
    """
    also = (int(view_height),) if view_height > 0 else ()
    photos, stats = observe_windows(
        scan_dir, mesh, [w for w, _ in windows], height=height, caster=caster,
        also_heights=also, **observe,
    )  # fmt: skip
    fine_photos = stats.pop("also", {}).get(int(view_height))
    bases = list(basis) if isinstance(basis, list | tuple) else [basis] * len(windows)
    if len(bases) != len(windows):
        raise ValueError(f"{len(bases)} bases for {len(windows)} windows")
    maps, infos = [], []
    for k, ((_, cells), ph) in enumerate(zip(windows, photos, strict=True)):
        env, info = refine_cells(cells, bases[k], fill_gaps(ph) if fill else ph)
        info["samples"] = stats["samples"][k]
        info["saturated"] = stats["saturated"][k]
        maps.append(env)
        infos.append(info)
    if fine_photos is not None:
        # The same pixels binned at the view's resolution in the same pass.
        for k, ph in enumerate(fine_photos):
            # Two passes: a frame's pixels land a texel or two apart at this resolution.
            ph = fill_gaps(fill_gaps(ph)) if fill else ph
            view, vinfo = view_map(ph, maps[k])
            infos[k]["view_map"] = view
            infos[k]["view"] = {**vinfo, "height": int(view_height)}
    return maps, infos, stats
