"""A line light's tube and fixture from the photos, where the scan does not resolve them.

A depth-fused (TSDF) scan closes a baffled fixture into a solid block with the tube half
inside it (:func:`reroom.invert.line_fixture.inside_fraction`). The detected axis then
sits on the block's draped underside (4 cm low and 2 cm to the side on the fused
`furnished` scan) and the block says nothing about where the fixture lets light out, so
the line lights' shape prior (:func:`reroom.invert.line_fixture.line_open_fraction`)
had to be dropped. The photos see both:

* **The axis.** A tube clips to a thin saturated stripe in every auto-exposed photo
  that sees it. Where the fixture leaves it whole (views within ``stripe_max_alpha``
  of straight below, across the tube), the stripe's middle is the projection of the
  axis: each stripe sample back-projects to a ray that passes through the axis, and
  the axis's offsets in its cross-section at its two ends are the robust least-squares
  fit to those rays (a linear problem: four unknowns, or two, one offset for both ends,
  where the stripes do not cover both halves of the tube). :func:`observe_tube`
  returns it.
* **The radius**, from the stripe's width: the tube saturates a pixel as soon as it
  covers a small part of it, so the run of saturated samples along the stripe's
  normal (bilinear between pixel centres) spans about the tube's projected width. The
  rays through the run's two ends graze the tube, so each passes the axis at the
  tube's radius: the radius is the median of their distances from the fitted axis,
  over the views that see the tube whole (within ``stripe_max_alpha``). Converted
  with the depth over the focal length instead, a width off the image's centre reads
  up to ``1 / cos`` of its angle too wide: on the issue's 300-frame 320x180 fused
  `furnished` the radius came out 17.5 mm that way, 16.3 mm from the rays (the truth
  16.0), and a tube drawn from it glowed 8 % too dim (docs/invert.md, "Session 52").
* **The cut-off.** Seen from further to the side, baffles hide the tube: a frame that
  sees the tube's place (nothing else in the way) shows the stripe or does not. Across
  the tube the angle where the stripe goes out is where the baffle's edge meets the line
  tangent to the tube's far side (:attr:`PhotoTube.cutoff_deg`, per side); a stripe
  narrower than the tube's width shows how much of it the edge leaves
  (:func:`trough_edges`).

:func:`trough_fixture` turns that into a fixture the shape prior can cast rays at: a
trough of two baffles under a ceiling, the baffles' bottom edges at the scanned
block's lowest point (the fused surface keeps the block's outside) and as far out as
the photos put them, the ceiling at the block's highest point. Written by hand:
no library reads a tube out of photos; the rays go to Embree.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.ndimage import map_coordinates

from reroom.invert.line_fixture import _axis
from reroom.rays import RayCaster
from reroom.rays.geometry import segment_distance

__all__ = [
    "PhotoTube",
    "TubeSighting",
    "cutoff_angle",
    "observe_tube",
    "points_in_view",
    "trough_edges",
    "trough_fixture",
    "tube_extent",
    "TubeExtent",
    "Trough",
]


@dataclass(frozen=True)
class TubeSighting:
    """One frame's view of a tube's place.

    ``alpha_deg`` is the direction from the tube to the camera in the tube's
    cross-section, from straight down (0) toward the line's ``side`` (positive) or away
    from it (negative); ``bright`` says whether the photo shows the saturated stripe at
    most of the ``samples`` axis points it sees unobstructed; ``width_m`` is the
    stripe's median width there (metres at the tube; None where no clean stripe was
    found): the part of the tube the fixture leaves visible; ``pixel_m`` is a pixel's
    footprint at the tube (metres; None for a dark sighting), what a width is good to.
    """

    frame: int
    alpha_deg: float
    bright: bool
    samples: int
    width_m: float | None = None
    pixel_m: float | None = None


@dataclass
class PhotoTube:
    """What the photos say about a line light's tube (see the module notes).

    Attributes
    ----------
    p0, p1:
        The axis, moved by ``offset`` (metres along ``side`` and ``up``) from the axis
        given; the given one when the stripes were too few (``stripe_samples`` below
        the minimum).
    stripe_samples, stripe_frames:
        Stripe centres used for the axis and the frames they came from.
    residual_m:
        Robust spread (1.4826 MAD) of the stripe rays' distances to the fitted axis.
    radius:
        The tube's radius (metres): the median distance from the fitted axis of the
        rays through the ends of the saturated stripes seen within ``stripe_max_alpha``;
        where there are none, the median half-width of every stripe (depth over focal
        length); None without stripes.
    sightings:
        Every frame that sees the tube's place.
    cutoff_deg:
        The cut-off across the tube on the ``-side`` and ``+side`` (positive degrees
        from straight down; None where the photos show no frame that lost the tube).
    """

    p0: np.ndarray
    p1: np.ndarray
    offset: tuple[float, float]
    stripe_samples: int
    stripe_frames: int
    residual_m: float | None
    radius: float | None
    sightings: list[TubeSighting] = field(default_factory=list)
    cutoff_deg: tuple[float | None, float | None] = (None, None)

    def summary(self) -> dict[str, Any]:
        """JSON-ready figures (for ``invert_info.json``)."""
        bright = sum(s.bright for s in self.sightings)
        return {
            "axis_offset_m": [round(self.offset[0], 4), round(self.offset[1], 4)],
            "stripe_samples": self.stripe_samples,
            "stripe_frames": self.stripe_frames,
            "axis_residual_m": None if self.residual_m is None else round(self.residual_m, 4),
            "radius_m": None if self.radius is None else round(self.radius, 4),
            "frames_seeing": len(self.sightings),
            "frames_bright": int(bright),
            "cutoff_deg": [None if c is None else round(c, 1) for c in self.cutoff_deg],
        }


def _frame_axes(p0: np.ndarray, p1: np.ndarray, up: ArrayLike) -> tuple[np.ndarray, ...]:
    """Unit axis direction, ``up`` made perpendicular to it, and ``side = dh x up``."""
    _, dh, _ = _axis(p0, p1)
    u = np.asarray(up, float).reshape(3)
    u = u - (u @ dh) * dh
    if np.linalg.norm(u) < 1e-9:
        raise ValueError("up is parallel to the line light")
    u = u / np.linalg.norm(u)
    return dh, u, np.cross(dh, u)


def points_in_view(
    frame: Any, caster: RayCaster, points: np.ndarray, margin: float = 0.05
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where ``points`` project in ``frame`` (``uv``, ``depth``) and which it sees: inside
    the image with nothing of ``caster`` nearer than ``margin`` before them."""
    uv, depth, inside = frame.project(points)
    seen = inside.copy()
    if inside.any():
        c = np.asarray(frame.center, float)
        rays = points[inside] - c
        dist = np.linalg.norm(rays, axis=1)
        hits = caster.intersect(np.repeat(c[None], len(rays), 0), rays / dist[:, None])
        seen[inside] = ~(hits.hit & (hits.t < dist - margin))
    return uv, depth, seen


def cutoff_angle(angles: ArrayLike, bright: ArrayLike, min_dark: int = 2) -> float | None:
    """The angle that best splits bright sightings (below it) from dark ones (above).

    ``angles`` are positive degrees from straight down on one side of the tube. The
    split minimises the sightings on the wrong side of it (ties: the widest gap) and
    lies halfway between the last bright and the first dark angle. None with fewer than
    ``min_dark`` dark sightings beyond the nearest bright one or no bright sighting.

    >>> cutoff_angle([10, 30, 45, 50, 61, 65], [True, True, True, True, False, False])
    55.5
    """
    a = np.asarray(angles, float)
    b = np.asarray(bright, bool)
    if not b.any() or np.count_nonzero(~b & (a > a[b].min())) < min_dark:
        return None
    order = np.argsort(a)
    a, b = a[order], b[order]
    best, split = None, None
    for k in range(1, len(a)):
        if a[k] == a[k - 1]:
            continue
        wrong = np.count_nonzero(~b[:k]) + np.count_nonzero(b[k:])
        key = (wrong, -(a[k] - a[k - 1]))
        if best is None or key < best:
            best, split = key, 0.5 * (a[k] + a[k - 1])
    return None if split is None else float(split)


#: Stripes seen whole (within ``stripe_max_alpha``) needed for the radius from their
#: edge rays; with fewer, the median half-width of every stripe.
MIN_EDGE_RAYS = 5


def _line_distance(o: np.ndarray, d: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """Distance of each line ``o + s d`` (rows) from the line through ``p0`` and ``p1``."""
    t = (p1 - p0) / np.linalg.norm(p1 - p0)
    n = np.cross(np.asarray(d, float), t)
    length = np.linalg.norm(n, axis=1)
    gap = np.abs(np.sum((np.asarray(o, float) - p0) * n, axis=1)) / np.maximum(length, 1e-12)
    # A ray along the axis: its distance from the axis line, not from a point on it.
    along = length < 1e-9
    if along.any():
        q = np.asarray(o, float)[along] - p0
        gap[along] = np.linalg.norm(q - np.outer(q @ t, t), axis=1)
    return gap


def _stripe_centre(
    img: np.ndarray, uv: np.ndarray, normal: np.ndarray, level: float, half: float = 6.0
) -> tuple[float, float] | None:
    """Offset (pixels along ``normal``) of the saturated run's middle at ``uv``, and its length.

    None when the run touches the ends of the profile or is broken (another bright
    thing beside the tube).
    """
    s = np.arange(-half, half + 1e-9, 0.1)
    q = uv[None, :] + s[:, None] * normal[None, :]
    prof = map_coordinates(img, [q[:, 1] - 0.5, q[:, 0] - 0.5], order=1, mode="nearest")
    run = np.flatnonzero(prof >= level)
    if len(run) == 0 or run[0] == 0 or run[-1] == len(s) - 1:
        return None
    if run[-1] - run[0] + 1 != len(run):
        return None
    return 0.5 * (s[run[0]] + s[run[-1]]), float(s[run[-1]] - s[run[0]])


def observe_tube(
    frames: Sequence[Any],
    load_image: Callable[[Any], np.ndarray | None],
    caster: RayCaster,
    p0: ArrayLike,
    p1: ArrayLike,
    up: ArrayLike,
    *,
    points: int = 21,
    saturation: int = 245,
    stripe_max_alpha: float = 35.0,
    min_stripes: int = 20,
    search: float = 0.1,
) -> PhotoTube:
    """The tube's axis, radius and cut-off angles from the frames (see the module notes).

    Parameters
    ----------
    frames:
        :class:`reroom.scan.Frame` objects (``project``, ``pixel_rays``, ``center``).
    load_image:
        ``load_image(frame) -> (H, W, 3)`` 8-bit image, or None to skip the frame
        (called only for frames that see the tube's place).
    caster:
        The scan's geometry *without* the tube's fixture (e.g. the faces farther than
        25 cm from the axis): what may stand between a camera and the tube.
    p0, p1, up:
        The detected axis and the line's ``d_perp``.
    points:
        Axis points sampled (5-95 % of the length).
    saturation:
        8-bit level (channel mean) at or above which a pixel counts as saturated.
    stripe_max_alpha:
        Only views within this many degrees of straight below, across the tube, give
        stripe centres (further out a baffle may hide part of the tube and shift them).
    min_stripes:
        Fewer stripe centres than this leave the axis where it was. The axis may tilt
        from the given one only where at least a fifth of them lie on each half of
        the tube; otherwise it moves parallel to itself.
    search:
        Metres on each side of the given axis, at the tube, where the stripe is looked
        for (plus 3 pixels): the detected axis may be a few centimetres off.
    """
    a0, a1 = np.asarray(p0, float).reshape(3), np.asarray(p1, float).reshape(3)
    dh, u, side = _frame_axes(a0, a1, up)
    t = np.linspace(0.05, 0.95, points)
    pts = a0 + t[:, None] * (a1 - a0)
    mid = pts.mean(axis=0)
    sightings: list[TubeSighting] = []
    rows, rhs, widths, stripe_frames, where = [], [], [], set(), []
    edge_rays: list[tuple[np.ndarray, np.ndarray]] = []
    for fr in frames:
        c = np.asarray(fr.center, float)
        w = c - mid
        if w @ u >= 0:  # a camera level with or above the tube sees into its fixture's top
            continue
        uv, depth, seen = points_in_view(fr, caster, pts)
        if not seen.any():
            continue
        img = load_image(fr)
        if img is None:  # unreadable: neither bright nor dark
            continue
        img8 = np.asarray(img)
        lum = img8.astype(np.float32).mean(axis=2)
        h, wd = lum.shape
        alpha = float(np.degrees(np.arctan2(w @ side, -(w @ u))))
        ks = np.flatnonzero(seen)
        bright = 0
        for k in ks:
            i, j = int(uv[k, 1]), int(uv[k, 0])
            patch = img8[max(i - 1, 0) : min(i + 2, h), max(j - 1, 0) : min(j + 2, wd)]
            bright += bool((patch.min(axis=2) >= saturation).any())
        is_bright = bright > 0.5 * len(ks)
        frame_widths = []
        pixel_m = None
        if is_bright:
            uv2, _, _ = fr.project(pts + 0.01 * dh)
            f_px = float(fr.intrinsics.fx)
            pixel_m = float(np.median(depth[ks])) / f_px
            for k in ks:
                tan = uv2[k] - uv[k]
                if np.linalg.norm(tan) < 1e-9:
                    continue
                tan = tan / np.linalg.norm(tan)
                normal = np.array([-tan[1], tan[0]])
                half = 3.0 + search * f_px / max(depth[k], 1e-6)
                found = _stripe_centre(lum, uv[k], normal, saturation, half)
                if found is None:
                    continue
                off, run = found
                frame_widths.append(run * depth[k] / f_px)
                if abs(alpha) > stripe_max_alpha:
                    continue
                o, d = fr.pixel_rays((uv[k] + off * normal)[None, :])
                # Projected along the axis, the axis is a point and the ray a line
                # through it: the ray meets the axis iff its projection passes there.
                rel = o[0] - pts[k]
                ys, zs = rel @ side, rel @ u
                ds, du = d[0] @ side, d[0] @ u
                n = np.hypot(ds, du)
                if n < 0.05:  # a ray along the axis says nothing about where it lies
                    continue
                # The rays through the run's ends graze the tube: the radius, below.
                ends_uv = uv[k] + np.outer([off - 0.5 * run, off + 0.5 * run], normal)
                edge_rays.append(fr.pixel_rays(ends_uv))
                ds, du = ds / n, du / n
                # The axis at t[k], (1 - t) (s0, v0) + t (s1, v1), lies on the ray's line.
                tk = t[k]
                rows.append([du * (1 - tk), -ds * (1 - tk), du * tk, -ds * tk])
                rhs.append(ys * du - zs * ds)
                where.append(tk)
                widths.append(frame_widths[-1])
                stripe_frames.add(int(fr.index))
        width = float(np.median(frame_widths)) if frame_widths else None
        sightings.append(TubeSighting(int(fr.index), alpha, is_bright, len(ks), width, pixel_m))
    ends, residual, radius = np.zeros(4), None, None
    if widths:
        radius = float(np.median(widths)) / 2.0
    if len(rows) >= min_stripes:
        a, b = np.asarray(rows), np.asarray(rhs)
        halves = np.asarray(where) < 0.5
        tilt = min(np.count_nonzero(halves), np.count_nonzero(~halves)) >= 0.2 * len(rows)
        if not tilt:  # one offset for both ends: the samples cannot pin the direction
            a = np.stack([a[:, 0] + a[:, 2], a[:, 1] + a[:, 3]], axis=1)
        sol = np.linalg.lstsq(a, b, rcond=None)[0]
        res = a @ sol - b
        for _ in range(8):  # Huber-style reweighting: a stripe beside a bright neighbour
            scale = 1.4826 * np.median(np.abs(res)) + 1e-6
            wgt = 1.0 / np.maximum(1.0, np.abs(res) / (2.0 * scale))
            sol = np.linalg.lstsq(a * wgt[:, None], b * wgt, rcond=None)[0]
            res = a @ sol - b
        ends = sol if tilt else np.concatenate([sol, sol])
        residual = float(1.4826 * np.median(np.abs(res)))
    angles = np.array([s.alpha_deg for s in sightings])
    bright = np.array([s.bright for s in sightings], bool)
    cut = []
    for sign in (-1.0, 1.0):
        m = sign * angles > 0
        cut.append(cutoff_angle(sign * angles[m], bright[m]) if m.any() else None)
    # The fit gives the axis at t = 0 and t = 1 of the sampled span, i.e. at p0 and p1.
    f0, f1 = a0 + ends[0] * side + ends[1] * u, a1 + ends[2] * side + ends[3] * u
    if len(edge_rays) >= MIN_EDGE_RAYS:
        grazing = [_line_distance(o, d, f0, f1).mean() for o, d in edge_rays]
        radius = float(np.median(grazing))
    return PhotoTube(
        f0,
        f1,
        (float(0.5 * (ends[0] + ends[2])), float(0.5 * (ends[1] + ends[3]))),
        len(rows),
        len(stripe_frames),
        residual,
        radius,
        sightings,
        (cut[0], cut[1]),
    )


@dataclass(frozen=True)
class TubeExtent:
    """Where along its axis the photos show a tube (see :func:`tube_extent`).

    ``p0, p1`` are the ends (on the axis given, in its direction); ``s`` the axis
    samples (metres from the given ``p0``), with the frames that see each unobstructed
    against the fixture (``seen``) and those whose photo is saturated there
    (``bright``); ``moved_m`` how far each end moved outward to meet the stripe (0 or at
    least ``min_move``); ``shift_m`` how far the whole span moved along the axis (towards
    ``p1`` positive) to sit centred on the stripe, its length kept.
    """

    p0: np.ndarray
    p1: np.ndarray
    s: np.ndarray
    seen: np.ndarray
    bright: np.ndarray
    moved_m: tuple[float, float]
    shift_m: float = 0.0

    def summary(self) -> dict[str, Any]:
        """JSON-ready figures."""
        return {
            "ends_moved_m": [round(m, 3) for m in self.moved_m],
            "centre_shift_m": round(self.shift_m, 4),
            "samples_seen": int(np.count_nonzero(self.seen)),
            "samples_bright": int(np.count_nonzero(self.bright)),
        }


def tube_extent(
    frames: Sequence[Any],
    load_image: Callable[[Any], np.ndarray | None],
    occluders: RayCaster,
    background: RayCaster,
    p0: ArrayLike,
    p1: ArrayLike,
    up: ArrayLike,
    *,
    reach: float = 1.0,
    step: float = 0.005,
    saturation: int = 245,
    min_views: int = 1,
    behind: float = 0.3,
    min_move: float = 0.08,
) -> TubeExtent:
    """How far along its axis a tube runs, from the photos' saturated stripe.

    A depth-fused scan can hold only part of a tube bright (on the 60-frame 160x120
    fused ``furnished`` scan, 0.60 of its 1.20 m: at that resolution most views
    of the rest mix the thin tube with the dark fixture around it, so no vertex
    there is clipped or above the threshold). A photo that shows the tube at all
    shows the stripe saturated wherever it sees the tube, though: the tube saturates a
    pixel as soon as it covers a sliver of it. So ``frames`` should be those whose
    view across the tube the fixture leaves open (the bright sightings of
    :func:`observe_tube`): from further to the side a baffle hides the whole tube.

    The axis is sampled every ``step`` metres from ``reach`` before ``p0`` to ``reach``
    beyond ``p1``. A frame counts at a sample when it sees it from below, with nothing
    of ``occluders`` (the scan less the fixture, :func:`caster_without_fixture` of the
    extended axis) in the way and something of ``background`` (the whole scan) within
    ``behind`` metres past it (so that a window or lamp far behind the axis is not
    read as the tube); it counts as bright when a pixel within 3 pixels of the axis's
    projection, across it, is saturated in every channel. A sample is bright when at least ``min_views`` frames
    count and half of them are bright, dark when as many count and fewer are bright,
    unknown otherwise. The tube runs over the unbroken stretch of bright and unknown
    samples around the middle of the given span, trimmed to its outermost bright
    samples. An end moves only outward and by at least ``min_move`` metres: the stripe
    overshoots a tube's end by a few centimetres (a pixel the end covers in part is
    saturated already, and so is the fixture's inside next to the end, lit from a few
    centimetres away): 2-3 cm on the 300-frame 320x180 fused ``furnished`` scan and 5 cm
    on the 60-frame 160x120 one, at ends the scan had right. A stretch that does not
    reach the given middle moves nothing.

    Where no end moves and the stripe is bounded by dark samples at both ends, the span
    keeps its length and moves along the axis to the stripe's centre (at most
    ``min_move``): the overshoot is about the same at both ends, so the centre is the
    photos' to under a centimetre, while a fused scan's bright span sits on its voxel
    grid (on the issue's scan, 3 cm voxels, the tube's span was right in length and
    2.1 cm off along it; centred, 0.8 cm). Each end of the stripe is where half the
    frames that see it are saturated, interpolated between samples.
    """
    a0, a1 = np.asarray(p0, float).reshape(3), np.asarray(p1, float).reshape(3)
    dh, u, _ = _frame_axes(a0, a1, up)
    length = float(np.linalg.norm(a1 - a0))
    s = np.arange(-reach, length + reach + 1e-9, step)
    pts = a0 + s[:, None] * dh
    seen = np.zeros(len(s), np.int64)
    bright = np.zeros(len(s), np.int64)
    for fr in frames:
        c = np.asarray(fr.center, float)
        below = (c - pts) @ u < 0
        if not below.any():
            continue
        uv, _, inside = fr.project(pts)
        ok = inside & below
        if not ok.any():
            continue
        dirs = pts - c
        dist = np.linalg.norm(dirs, axis=1)
        dirs = dirs / dist[:, None]
        origins = np.repeat(c[None], len(pts), 0)
        block = occluders.intersect(origins, dirs)
        back = background.intersect(origins, dirs)
        ok &= ~(block.hit & (block.t < dist - 0.05))
        ok &= back.hit & (back.t < dist + behind)
        if not ok.any():
            continue
        img = load_image(fr)
        if img is None:
            continue
        low = np.asarray(img).min(axis=2).astype(np.float32)
        # Across the stripe only (3 pixels each way: the axis may be a pixel off), never
        # along it, so that the ends do not grow by the search.
        tip, _, _ = fr.project(pts + 0.01 * dh)
        tan = tip - uv
        tan /= np.maximum(np.linalg.norm(tan, axis=1, keepdims=True), 1e-9)
        normal = np.stack([-tan[:, 1], tan[:, 0]], axis=1)
        for k in np.flatnonzero(ok):
            q = uv[k][None, :] + np.arange(-3.0, 3.01, 0.5)[:, None] * normal[k][None, :]
            prof = map_coordinates(low, [q[:, 1] - 0.5, q[:, 0] - 0.5], order=0, mode="nearest")
            seen[k] += 1
            bright[k] += bool((prof >= saturation).any())
    counted = seen >= min_views
    is_bright = counted & (2 * bright >= seen)
    is_dark = counted & ~is_bright
    mid = int(np.argmin(np.abs(s - length / 2)))
    lo, hi = mid, mid
    while lo > 0 and not is_dark[lo - 1]:
        lo -= 1
    while hi < len(s) - 1 and not is_dark[hi + 1]:
        hi += 1
    lit = np.flatnonzero(is_bright[lo : hi + 1]) + lo
    start, end, shift = 0.0, length, 0.0
    if len(lit) and not is_dark[mid]:
        # The outermost bright samples, not half a step beyond: a pixel the tube's end
        # covers in part is saturated already, so they overshoot by up to a pixel.
        first, last = s[lit[0]], s[lit[-1]]
        start = first if first <= -min_move else 0.0
        end = last if last >= length + min_move else length
        grown = start != 0.0 or end != length
        inner = 0 < lit[0] and lit[-1] < len(s) - 1
        if not grown and inner and is_dark[lit[0] - 1] and is_dark[lit[-1] + 1]:
            frac = bright / np.maximum(seen, 1)
            centre = 0.5 * (
                _half_crossing(s, frac, lit[0] - 1, lit[0])
                + _half_crossing(s, frac, lit[-1] + 1, lit[-1])
            )
            if abs(centre - 0.5 * length) < min_move:
                shift = float(centre - 0.5 * length)
                start, end = shift, length + shift
    return TubeExtent(
        a0 + start * dh,
        a0 + end * dh,
        s,
        seen,
        bright,
        (0.0, 0.0) if shift else (float(-start), float(end - length)),
        shift,
    )


def _half_crossing(s: np.ndarray, frac: np.ndarray, dark: int, lit: int) -> float:
    """Where the saturated fraction of the views crosses one half between the samples
    ``dark`` (below a half) and ``lit`` (at least a half), linearly."""
    f0, f1 = float(frac[dark]), float(frac[lit])
    w = (0.5 - f0) / (f1 - f0) if f1 > f0 else 1.0
    return float(s[dark] + np.clip(w, 0.0, 1.0) * (s[lit] - s[dark]))


def _edge_at_hide(alpha_deg: float, radius: float, bottom: float) -> float:
    """Edge distance whose baffle hides the whole tube from ``alpha_deg`` on.

    The edge at depth ``bottom`` on the line tangent to the tube's far side:
    ``y cos a - bottom sin a = -r``.
    """
    a = np.radians(alpha_deg)
    return float((bottom * np.sin(a) - radius) / max(np.cos(a), 1e-6))


@dataclass(frozen=True)
class Trough:
    """A trough around a tube, from the photos (see :func:`trough_edges`).

    ``edges`` are the baffles' bottom edges' distances from the axis on the ``-side`` and
    ``+side``, ``bottom`` their depth below the axis (metres), ``how`` says per side what
    bounded the edge, and ``bottom_from`` where the depth came from.
    """

    edges: tuple[float, float]
    bottom: float
    how: list[str]
    bottom_from: str


def trough_edges(
    tube: PhotoTube,
    bottom: float,
    radius: float,
    partial: float = 0.8,
    bottom_sigma: float = 0.01,
    width_sigma_px: float = 0.5,
    width_sigma_m: float = 0.002,
    min_tube_px: float = 2.0,
    min_samples: int = 3,
) -> Trough | None:
    """The baffles' bottom edges (distance from the axis per side) and their depth.

    Per side, from the sightings there, a baffle edge at ``y`` across and ``b`` below
    the axis:

    * a bright sighting whose stripe is narrower than ``partial`` of the tube's width
      sees the part of the tube the edge leaves, ``w = r + y cos a - b sin a`` (only
      where the whole tube would span ``min_tube_px`` pixels or more, a 160x120 photo
      showing the 3 cm tube 1.7 pixels wide, and the width is a median over at least
      ``min_samples`` points along the tube: one stripe sample is too noisy);
    * the cut-off bracket (last bright to first dark angle) bounds ``y`` between the
      edges that would hide the tube at those two angles (``y cos a - b sin a = -r``);
      without partial sightings the edge hides it halfway between them.

    ``bottom`` is the scanned fixture's depth below the axis. On a fused scan it is a
    few millimetres off (the block's underside is quantised by the fusion's voxels),
    and with it the part-hidden views and the bracket can disagree: on the fused
    `furnished` scans the views put the edge at 70 mm and the bracket at most at 58 mm
    with the scanned 54 mm depth. So where part-hidden views exist the depth is fitted
    with the edges: each candidate depth within four ``bottom_sigma`` of the scanned one
    (0.5 mm steps) gets per side the median edge of its part-hidden views clipped to its
    bracket, and costs the views' squared misfits, each over its width's error squared,
    plus its squared distance from the scanned depth over ``bottom_sigma`` squared; the
    cheapest wins. A width is good to ``width_sigma_px`` of the view's pixel footprint
    at the tube (``width_sigma_m`` where the sighting has none): the stripe's edges are
    interpolated between pixels, and saturation spreads them by a fraction of a pixel
    (the photos' radius is 0.9-1.8 mm over the truth on `furnished`, a tenth to a fifth
    of a pixel), so a 160x120 photo's width says little and a 640x360 one's much. Of a
    quarter, a half and a whole pixel, a half gave the best open fraction on the 320x180
    fused `furnished` scan and came within 0.3 points of the best (a whole) on the
    640x360 one (docs/invert.md, session 27). ``bottom_sigma``:
    about a 3 cm voxel's quantisation. Written by hand: a one-parameter search with a
    median inner fit.

    A side the photos do not bound takes the other's edge (fixtures are symmetric).
    Returns None without any cut-off or when an edge would fall within the tube's own
    width.
    """
    sides = []  # per side: (lo, hi, part-hidden views' angles, widths, their errors) or None
    for sign, cut in zip((-1.0, 1.0), tube.cutoff_deg, strict=True):
        if cut is None:
            sides.append(None)
            continue
        a = np.array([sign * s.alpha_deg for s in tube.sightings])
        b = np.array([s.bright for s in tube.sightings], bool)
        side = a > 0
        lo = float(a[side & b & (a < cut)].max())
        hi = float(a[side & ~b & (a > cut)].min())
        views = [
            (ai, s.width_m, width_sigma_m if s.pixel_m is None else width_sigma_px * s.pixel_m)
            for s, ai in zip(tube.sightings, a, strict=True)
            if ai > 0
            and s.bright
            and s.width_m is not None
            and s.width_m < partial * 2 * radius
            and s.samples >= min_samples
            and (s.pixel_m is None or 2 * radius >= min_tube_px * s.pixel_m)
        ]
        ang = np.radians([v[0] for v in views])
        w, sig = np.array([v[1] for v in views], float), np.array([v[2] for v in views], float)
        sides.append((lo, hi, ang, w, sig))
    if all(s is None for s in sides):
        return None

    def fit(depth: float) -> tuple[list[float | None], float]:
        """Each side's edge at this depth, and the part-hidden views' weighted misfit."""
        out: list[float | None] = []
        misfit = 0.0
        for s in sides:
            if s is None:
                out.append(None)
                continue
            lo, hi, ang, w, sig = s
            y_lo, y_hi = _edge_at_hide(lo, radius, depth), _edge_at_hide(hi, radius, depth)
            if len(w) == 0:
                out.append(0.5 * (y_lo + y_hi))
                continue
            c, sn = np.cos(ang), np.sin(ang)
            y = float(np.clip(np.median((w - radius + depth * sn) / c), y_lo, y_hi))
            misfit += float(np.sum(((w - radius - y * c + depth * sn) / sig) ** 2))
            out.append(y)
        return out, misfit

    if any(s is not None and len(s[3]) for s in sides):
        depths = np.arange(bottom - 4 * bottom_sigma, bottom + 4 * bottom_sigma + 1e-9, 5e-4)
        depths = depths[depths > radius]
        costs = [fit(d)[1] + ((d - bottom) / bottom_sigma) ** 2 for d in depths]
        depth = float(depths[int(np.argmin(costs))]) if len(depths) else bottom
        bottom_from = f"fitted to the part-hidden views (scanned {1000 * bottom:.0f} mm)"
    else:
        depth, bottom_from = bottom, "scanned"
    out, _ = fit(depth)
    how = []
    for s in sides:
        if s is None:
            how.append("mirrored")
        elif len(s[3]):
            how.append(f"{len(s[3])} partial views, hidden from {s[0]:.1f}-{s[1]:.1f} deg")
        else:
            how.append(f"hidden from {s[0]:.1f}-{s[1]:.1f} deg")
    known = [y for y in out if y is not None]
    edges = tuple(y if y is not None else known[0] for y in out)
    if min(edges) <= radius:
        return None
    return Trough((float(edges[0]), float(edges[1])), depth, how, bottom_from)


def trough_fixture(
    p0: ArrayLike,
    p1: ArrayLike,
    up: ArrayLike,
    edges: tuple[float, float],
    bottom: float,
    top: float,
    overhang: float = 0.05,
    ceiling: float = 0.5,
) -> RayCaster:
    """A ray caster of a trough around the tube: two baffles under a ceiling.

    ``edges`` are the baffles' distances from the axis on the ``-side`` and ``+side``,
    ``bottom`` and ``top`` the metres below and above the axis where they end. The
    baffles run ``overhang`` beyond the tube's ends, which stay open; the top is a
    plane reaching ``ceiling`` metres beyond the trough on every side (the housing, or
    the ceiling the fixture hangs from: light that leaves the ends upwards meets it a
    few centimetres on, as it would the scanned ceiling).
    """
    a0, a1 = np.asarray(p0, float).reshape(3), np.asarray(p1, float).reshape(3)
    dh, u, side = _frame_axes(a0, a1, up)
    e0, e1 = a0 - overhang * dh, a1 + overhang * dh
    quads = []
    for sgn, e in ((-1.0, edges[0]), (1.0, edges[1])):
        lo, hi = sgn * e * side - bottom * u, sgn * e * side + top * u
        quads.append([e0 + lo, e1 + lo, e1 + hi, e0 + hi])
    c0, c1 = a0 - ceiling * dh + top * u, a1 + ceiling * dh + top * u
    s0, s1 = -(edges[0] + ceiling) * side, (edges[1] + ceiling) * side
    quads.append([c0 + s0, c1 + s0, c1 + s1, c0 + s1])
    v = np.asarray(quads, float).reshape(-1, 3)
    f = np.array([[4 * k + i for i in tri] for k in range(3) for tri in ((0, 1, 2), (0, 2, 3))])
    return RayCaster(v, f, eps=1e-6)


def fixture_extent(
    vertices: ArrayLike,
    p0: ArrayLike,
    p1: ArrayLike,
    up: ArrayLike,
    radius: float,
    reach: float = 0.15,
) -> tuple[float, float] | None:
    """Metres below and above the axis that the scanned geometry around the tube spans.

    Over the vertices within ``reach`` of the axis (across), along its length (10 cm
    more at each end, where a fixture's ends are) and off
    the tube itself (farther than ``max(2 r, r + 1 cm)`` from the axis, as
    :func:`reroom.invert.line_fixture.scan_fixture_caster` has it): the 2nd percentile
    of their depth below it and the 98th of their height above it (on a fused scan the
    block's underside and the ceiling). None with fewer than 4 such vertices.
    """
    a0, a1 = np.asarray(p0, float).reshape(3), np.asarray(p1, float).reshape(3)
    dh, u, side = _frame_axes(a0, a1, up)
    v = np.asarray(vertices, float)
    rel = v - a0
    along = rel @ dh
    length = float(np.linalg.norm(a1 - a0))
    across = np.hypot(rel @ side, rel @ u)
    near = (
        (along > -0.1)
        & (along < length + 0.1)
        & (np.abs(rel @ side) < reach)
        & (np.abs(rel @ u) < 0.3)
        & (across > max(2.0 * radius, radius + 0.01))
    )
    if np.count_nonzero(near) < 4:
        return None
    h = rel[near] @ u
    return float(-np.percentile(h, 2)), float(np.percentile(h, 98))


def caster_without_fixture(vertices: ArrayLike, faces: ArrayLike, p0, p1, clear: float = 0.25):
    """A caster of the scanned faces farther than ``clear`` from the axis (None if none)."""
    v = np.asarray(vertices, float)
    f = np.asarray(faces, np.int64)
    near = segment_distance(v, np.asarray(p0, float), np.asarray(p1, float)) < clear
    keep = ~near[f].any(axis=1)
    if not keep.any():
        return None
    return RayCaster(v, f[keep])
