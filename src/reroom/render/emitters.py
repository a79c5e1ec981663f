"""Python-defined Mitsuba 3 emitters: goniometric (IES) point lights and window portals.

Both plugins are written against Mitsuba's vectorised (``llvm_ad_rgb`` /
``cuda_ad_rgb``) Python emitter interface and work with the standard ``path``
integrator: next-event estimation calls :meth:`sample_direction`, and
multiple importance sampling calls :meth:`pdf_direction` / :meth:`eval` when
a BSDF-sampled ray hits the window. Call :func:`register_emitters` (the dict
builders below do it for you) before ``mi.load_dict``. RGB variants only.

``reroom_goniometric`` -- a point light with a tabulated intensity distribution
--------------------------------------------------------------------------------
Radiant intensity in direction ``d`` (world) is
``I(d) = scale * color * table(theta, phi)`` in W/sr: the same unit as the
``intensity`` of Mitsuba's built-in ``point`` emitter (an isotropic table of 1
with ``scale = I`` renders exactly like ``point`` with intensity ``I``). A
table in candela from :meth:`reroom.io.ies.IESProfile.to_tabulated` with
``scale = 1`` therefore renders "1 cd as 1 W/sr"; use ``scale = 1/683`` for a
photometric-to-radiometric conversion at 555 nm, or :func:`goniometric_light`
with ``flux=`` to fix the emitted power instead.

``(theta, phi)`` are type C angles in the **luminaire frame**: theta from the
nadir, which is the frame's -Z axis; phi from +X towards +Y. The frame is the
rotation part of ``to_world`` (default identity, so the nadir points down the
world's -Z); the position is ``position`` or else ``to_world``'s translation.
The table is a node grid: ``table[i, j]`` is the intensity at
``theta_i = pi i / (n_theta - 1)``, ``phi_j = 2 pi j / (n_phi - 1)`` (last column
= first column), interpolated bilinearly in ``(theta, phi)``. The light is a
delta position (``EmitterFlags.DeltaPosition``): NEE is exact, BSDF-sampled
rays never hit it, and ``sample_ray`` importance-samples the table (for light
tracing).

Properties: ``position`` (point), ``to_world`` (transform), ``intensity``
(``TensorXf (n_theta, n_phi)`` or a float for isotropic), ``color`` (3 floats,
default 1), ``scale`` (float, default 1), ``clearance`` (metres, default 0).

``clearance`` makes the table the light *as seen from outside a sphere* of that radius
around the position, as ``reroom invert`` solves it (``InvertOptions.point_clearance``):
nothing within the sphere shadows the light, so a lamp's own shade or a downlight's can,
whose occlusion is already in the solved table, does not block it a second time. The
shadow ray of next-event estimation then ends where it enters the sphere; a point inside
the sphere is not shadowed at all (as in :func:`reroom.invert.direct.point_light_transfer`).

``reroom_portal`` -- daylight through a window opening
--------------------------------------------------------
Attach it to a shape (a ``rectangle``) that fills a window opening with its
normal facing **into** the room, and give that shape a black BSDF. A ray from
inside that hits the front of the portal receives the outdoor radiance
``L = scale * hdri(d)`` for the direction ``d`` looking out through the window;
the back side emits nothing. NEE samples points uniformly on the shape (pdf in
solid angle ``r^2 / (|cos| A)``) or, for peaked skies, directions from the map (see
below); MIS uses the same mixture pdf.

Why not an ``envmap``: inside a closed room an environment emitter samples
directions over the whole sphere, and almost all of them end on a wall, so
its NEE samples are wasted (shadow rays that always fail) and the window is
found mostly by BSDF sampling. Sampling the opening directly puts every
light sample through the window. The black BSDF makes paths end at the
portal, as they would when escaping to the environment.

HDRI convention (equirectangular / lat-long, world +Z up; the same ``u`` as
Blender's equirectangular world mapping):
row 0 is the zenith; pixel ``(row r, column c)`` is centred at polar angle
``theta = pi (r + 0.5) / H`` from +Z and ``u = (c + 0.5) / W`` with
``u = 0.5 - atan2(d_y, d_x) / (2 pi)`` (mod 1): the image centre looks along +X,
``u = 0.25`` along +Y, ``u = 0`` / ``1`` along -X, and the image seen from inside
the sphere is not mirrored. ``rotation`` (degrees) turns the environment
counter-clockwise about +Z (seen from above): what the unrotated map shows
at azimuth ``a`` appears at ``a + rotation``. Lookups are bilinear, periodic in
``u`` and clamped in ``theta``. :func:`envmap_emitter` builds Mitsuba's
built-in ``envmap`` with the same orientation.

Properties: ``filename`` (EXR path) or ``data`` (``TensorXf (H, W, 3)``) or
``bitmap`` (``mi.Bitmap``); ``scale`` (float, default 1); ``rotation``
(degrees, default 0); ``outward`` (3 floats: the direction looking out through the
opening, optional); ``sky_sampling`` (the share of NEE samples drawn from the map,
default :func:`default_sky_sampling`).

Next-event estimation mixes two strategies. A share ``1 - s`` of the samples takes a
uniform point on the opening; a share ``s`` draws a direction from the map itself (a
pixel with probability proportional to its luminance x solid angle x the cosine at
the opening when ``outward`` is given) and follows it to the opening, carrying
nothing when it misses. Both pdfs are summed (a one-sample mixture) for the
sample's weight and for MIS, so the estimate is unbiased for any ``s``. A low sun
(``sunrise``, ``city``) is found by the second strategy at every sample that can see
it; uniform points find it one time in hundreds (fireflies). ``s`` defaults to 0 for
skies about as even as the bundled ``courtyard`` and rises to 0.5 for a dominant sun.

Pitfalls
--------
* Shadow rays treat every surface as opaque, including glass, so a pane
  between the room and the portal blocks all NEE. Put the portal on the
  room side of any glazing (the glass behind it is then never reached) and
  fold the glass transmittance (about 0.8-0.9) into ``scale``.
* Scenes with Mitsuba's ``envmap`` must be loaded with ``optimize=False``
  (see :func:`envmap_emitter`); the portal itself does not depend on the
  scene's bounding box.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
from scipy.ndimage import correlate1d

from reroom.io.ies import IESProfile, IntensityGrid
from reroom.render.mitsuba_env import mitsuba

__all__ = [
    "CANDELA_TO_W_PER_SR",
    "GONIOMETRIC",
    "PORTAL",
    "SKY_PEAKEDNESS_THRESHOLD",
    "default_sky_sampling",
    "envmap_emitter",
    "goniometric_light",
    "latlong_direction_to_uv",
    "latlong_lookup",
    "load_hdri",
    "luminaire_frame",
    "portal_emitter",
    "register_emitters",
    "sky_peakedness",
    "window_portal",
]

GONIOMETRIC = "reroom_goniometric"
PORTAL = "reroom_portal"

#: ``scale`` that turns a candela table into W/sr at 555 nm (683 lm/W).
CANDELA_TO_W_PER_SR = 1.0 / 683.0

_REGISTERED: set[str] = set()


# ---------------------------------------------------------------------- registration
def make_shadow_end(mi: ModuleType) -> Any:
    """``shadow_end(p, d, dist, clear)``: where a shadow ray towards a light should stop.

    Mitsuba tests next-event visibility from the shading point ``p`` to the sample's
    ``ds.p``. A light that must not be shadowed by anything within ``clear`` of it (along
    the ray: ``dist`` is the distance to the light along the unit direction ``d``, and
    ``clear`` may vary per ray) gets ``ds.p`` moved to where the ray enters that region;
    when ``p`` is inside it, to ``p`` itself plus a hair, which leaves nothing to test.
    ``ds.d`` and ``ds.dist`` keep the true direction and distance.
    """
    import drjit as dr

    def shadow_end(p: Any, d: Any, dist: Any, clear: Any) -> Any:
        stop = dr.maximum(dist - clear, 1e-4)
        return p + d * dr.minimum(stop, dist)

    return shadow_end


def register_emitters() -> ModuleType:
    """Register ``reroom_goniometric``, ``reroom_portal`` and ``reroom_line`` (idempotent).

    Returns
    -------
    module
        The Mitsuba module (variant set by :func:`reroom.render.mitsuba`).
    """
    mi = mitsuba()
    variant = mi.variant()
    if variant not in _REGISTERED:
        from reroom.render.line_emitter import LINE, make_line_class

        gonio_cls, portal_cls = _make_classes(mi)
        line_cls = make_line_class(mi)
        mi.register_emitter(GONIOMETRIC, lambda props: gonio_cls(props))
        mi.register_emitter(PORTAL, lambda props: portal_cls(props))
        mi.register_emitter(LINE, lambda props: line_cls(props))
        _REGISTERED.add(variant)
    return mi


# ---------------------------------------------------------------------- pure-numpy helpers
def luminaire_frame(
    nadir: Sequence[float] = (0.0, 0.0, -1.0), azimuth0: Sequence[float] = (1.0, 0.0, 0.0)
) -> np.ndarray:
    """Rotation (3x3, luminaire to world) whose -Z axis is ``nadir`` and +X is near ``azimuth0``.

    ``azimuth0`` (the world direction of type C ``phi = 0``) is projected
    perpendicular to ``nadir``; the default frame is the identity.
    """
    n = np.asarray(nadir, dtype=np.float64)
    n = n / np.linalg.norm(n)
    z = -n
    x = np.asarray(azimuth0, dtype=np.float64)
    x = x - z * (x @ z)
    if np.linalg.norm(x) < 1e-8:  # azimuth0 parallel to the nadir: pick any perpendicular
        x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=1)


def latlong_direction_to_uv(dirs: np.ndarray, rotation_deg: float = 0.0) -> np.ndarray:
    """Lat-long texture coordinates ``(..., 2)`` (u, v in [0, 1)) of world directions ``(..., 3)``.

    ``v = theta / pi`` from the zenith (+Z), ``u = 0.5 - azimuth / (2 pi)`` with the
    azimuth measured from +X towards +Y after undoing ``rotation_deg``.
    """
    d = np.asarray(dirs, dtype=np.float64)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    az = np.arctan2(d[..., 1], d[..., 0]) - math.radians(rotation_deg)
    u = np.mod(0.5 - az / (2 * np.pi), 1.0)
    v = np.arccos(np.clip(d[..., 2], -1.0, 1.0)) / np.pi
    return np.stack([u, v], axis=-1)


def latlong_lookup(image: np.ndarray, dirs: np.ndarray, rotation_deg: float = 0.0) -> np.ndarray:
    """Bilinear lookup of a lat-long image ``(H, W, C)`` in world directions (numpy reference).

    Identical (up to float32 rounding) to what ``reroom_portal`` evaluates.
    """
    img = np.asarray(image, dtype=np.float64)
    h, w = img.shape[:2]
    uv = latlong_direction_to_uv(dirs, rotation_deg)
    fx = np.mod(uv[..., 0] * w - 0.5, w)
    x0 = np.minimum(np.floor(fx).astype(np.int64), w - 1)
    wx = (fx - x0)[..., None]
    x1 = (x0 + 1) % w
    fy = np.clip(uv[..., 1] * h - 0.5, 0.0, h - 1)
    y0 = np.minimum(np.floor(fy).astype(np.int64), h - 2)
    wy = (fy - y0)[..., None]
    top = img[y0, x0] * (1 - wx) + img[y0, x1] * wx
    bot = img[y0 + 1, x0] * (1 - wx) + img[y0 + 1, x1] * wx
    return top * (1 - wy) + bot * wy


def load_hdri(source: str | Path | np.ndarray, max_width: int | None = None) -> np.ndarray:
    """Load a lat-long HDRI as float32 ``(H, W, 3)``, clamped to >= 0, optionally box-downsized.

    Parameters
    ----------
    source:
        An EXR path (read with :func:`reroom.io.images.read_exr`) or an array.
    max_width:
        If given, halve the resolution by 2x2 box averaging until ``W <= max_width``
        (keeps the integral of the map; use it to make smooth test maps).
    """
    if isinstance(source, str | Path):
        from reroom.io.images import read_exr

        img = read_exr(source)
    else:
        img = np.asarray(source)
    img = np.asarray(img, dtype=np.float32)
    if img.ndim != 3 or img.shape[2] < 3:
        raise ValueError(f"expected an (H, W, 3) lat-long image, got {img.shape}")
    # DWAB-compressed EXRs decode with small negative values; radiance cannot be negative.
    img = np.maximum(img[..., :3], 0.0)
    while max_width is not None and img.shape[1] > max_width and img.shape[0] % 2 == 0:
        if img.shape[1] % 2:
            break
        img = 0.25 * (img[0::2, 0::2] + img[1::2, 0::2] + img[0::2, 1::2] + img[1::2, 1::2])
    return np.ascontiguousarray(img, dtype=np.float32)


def _rot_z(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _affine(linear: np.ndarray, translation: Sequence[float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = linear
    m[:3, 3] = translation
    return m


def _grid_size(angles_deg: np.ndarray, span: float) -> int:
    """Node count of a regular grid over ``[0, span]`` that contains ``angles_deg`` if possible."""
    a = np.asarray(angles_deg, dtype=np.float64)
    for step in (5.0, 2.5, 1.0, 0.5, 0.25):
        if np.allclose(a / step, np.round(a / step), atol=1e-6):
            return int(round(span / step)) + 1
    finest = float(np.min(np.diff(a))) if a.size > 1 else span
    step = 0.5 if finest >= 0.5 else 0.25
    return int(round(span / step)) + 1


# ---------------------------------------------------------------------- dict builders
def goniometric_light(
    distribution: IESProfile | IntensityGrid | np.ndarray | float,
    position: Sequence[float],
    frame: np.ndarray | None = None,
    color: Sequence[float] = (1.0, 1.0, 1.0),
    scale: float = 1.0,
    flux: float | None = None,
    n_theta: int | None = None,
    n_phi: int | None = None,
    clearance: float = 0.0,
) -> dict[str, Any]:
    """Build a ``reroom_goniometric`` emitter dict for ``mi.load_dict``.

    Parameters
    ----------
    distribution:
        An :class:`IESProfile` (resampled with ``to_tabulated(n_theta, n_phi)``),
        an :class:`IntensityGrid`, an ``(n_theta, n_phi)`` node table, or a
        float (isotropic).
    position:
        World position of the light (metres).
    frame:
        3x3 luminaire-to-world rotation (see :func:`luminaire_frame`); default
        identity, i.e. the nadir points down world -Z.
    color, scale:
        Multiply the table: ``I = scale * color * table`` (W/sr).
    flux:
        If given, override ``scale`` so that the emitted power with
        ``color = (1, 1, 1)`` is ``flux`` watts (``scale = flux / table flux``).
    n_theta, n_phi:
        Grid resolution when resampling a profile. By default the coarsest of
        5, 2.5, 1, 0.5 deg steps whose nodes include every angle of the file
        (so that the emitter reproduces the file's bilinear interpolant
        exactly), else 0.5 deg (0.25 deg when the file is finer); ``n_phi`` is
        2 for axially symmetric profiles.
    clearance:
        Nothing within this distance (metres) of the position shadows the light (see
        the module docstring); 0, the default, is a bare point light.

    Returns
    -------
    dict
        ``{"type": "reroom_goniometric", "position": ..., "to_world": ...,
        "intensity": TensorXf, "color": ..., "scale": ...}``.
    """
    mi = register_emitters()
    if isinstance(distribution, IESProfile):
        if n_theta is None:
            n_theta = _grid_size(distribution.vertical_angles, 180.0)
        if n_phi is None:
            n_phi = (
                2
                if distribution.is_axially_symmetric
                else _grid_size(distribution.horizontal_angles, 360.0)
            )
        grid = distribution.to_tabulated(n_theta, n_phi)
    elif isinstance(distribution, IntensityGrid):
        grid = distribution
    elif np.ndim(distribution) == 0:
        value = float(distribution)  # type: ignore[arg-type]
        grid = IntensityGrid(np.array([0.0, 180.0]), np.array([0.0, 360.0]), np.full((2, 2), value))
    else:
        table = np.asarray(distribution, dtype=np.float64)
        grid = IntensityGrid(
            np.linspace(0, 180, table.shape[0]), np.linspace(0, 360, table.shape[1]), table
        )
    if flux is not None:
        table_flux = grid.total_flux()
        if table_flux <= 0:
            raise ValueError("the distribution emits no light; cannot set its flux")
        scale = float(flux) / table_flux
    rot = np.eye(3) if frame is None else np.asarray(frame, dtype=np.float64)
    values = np.ascontiguousarray(grid.values, dtype=np.float32)
    d = {
        "type": GONIOMETRIC,
        "position": [float(x) for x in position],
        "to_world": mi.ScalarTransform4f(_affine(rot).tolist()),
        "intensity": mi.TensorXf(values),
        "color": [float(c) for c in color],
        "scale": float(scale),
    }
    if not (np.isfinite(clearance) and clearance >= 0):
        raise ValueError(f"{GONIOMETRIC}: clearance must be a distance >= 0, got {clearance!r}")
    if clearance > 0:
        d["clearance"] = float(clearance)
    return d


#: Below this peakedness a map is sampled on the opening alone (see
#: :func:`default_sky_sampling`).
SKY_PEAKEDNESS_THRESHOLD = 20.0


def sky_peakedness(
    image: np.ndarray, outward: Sequence[float] | None = None, rotation_deg: float = 0.0
) -> float:
    """How unevenly a lat-long map spreads its light: ``sum_i P_i^2 / W_i``.

    ``P_i`` is pixel ``i``'s share of the map's luminance times its weight and
    ``W_i`` its share of the weight, the weight being the pixel's solid angle times
    ``max(0, d . outward)`` (the light that enters through an opening facing
    ``outward``; the whole sphere without one). 1 for a uniform sky; it is the
    relative second moment that uniform sampling of the opening pays in variance, so
    a small sun of large radiance makes it large.
    """
    img = np.maximum(np.nan_to_num(np.asarray(image, np.float64)[..., :3]), 0.0)
    h, w = img.shape[:2]
    weight = np.repeat(np.sin(np.pi * (np.arange(h) + 0.5) / h)[:, None], w, axis=1)
    if outward is not None:
        weight = weight * np.maximum(_pixel_directions(h, w, rotation_deg) @ outward, 0.0)
    power = (img @ np.array([0.2126, 0.7152, 0.0722])) * weight
    if power.sum() <= 0 or weight.sum() <= 0:
        return 1.0
    seen = weight > 0
    p = power[seen] / power.sum()
    a = weight[seen] / weight.sum()
    return float((p * p / a).sum())


def default_sky_sampling(
    image: np.ndarray, outward: Sequence[float] | None = None, rotation_deg: float = 0.0
) -> float:
    """The share of a portal's light samples drawn from the map's brightness.

    ``0.5 (1 - T / V)`` for a peakedness ``V`` (:func:`sky_peakedness`) above
    ``T`` = :data:`SKY_PEAKEDNESS_THRESHOLD`, else 0. A sky sample helps only if it
    passes the opening, which from a point in a room is a tenth or so of the
    directions the map weights; a share ``s`` thus wins when ``V / (1 - s)`` exceeds
    about ``10 / s``, i.e. for ``V`` above about 20 (measured on a box room lit
    through a 1.2 x 1 m window at 16 spp: the bundled ``courtyard``, ``V`` 7.8, is
    noisier with any share; ``sunset`` (89), ``city`` (5843) and ``sunrise``
    (13186) are 2-5x less noisy in RMSE with 0.25-0.5).
    """
    v = sky_peakedness(image, outward, rotation_deg)
    if v <= SKY_PEAKEDNESS_THRESHOLD:
        return 0.0
    return 0.5 * (1.0 - SKY_PEAKEDNESS_THRESHOLD / v)


def _pixel_directions(height: int, width: int, rotation_deg: float = 0.0) -> np.ndarray:
    """``(H, W, 3)`` world directions of a lat-long map's pixel centres (module convention)."""
    theta = np.pi * (np.arange(height) + 0.5) / height
    u = (np.arange(width) + 0.5) / width
    phi = 2.0 * np.pi * (0.5 - u) + np.radians(rotation_deg)
    st = np.sin(theta)[:, None]
    return np.stack(
        [st * np.cos(phi)[None, :], st * np.sin(phi)[None, :], np.cos(theta)[:, None] + 0 * phi],
        axis=-1,
    )


def portal_emitter(
    hdri: str | Path | np.ndarray,
    scale: float = 1.0,
    rotation_deg: float = 0.0,
    opening: Sequence[Sequence[float]] | None = None,
    sky_sampling: float | None = None,
    view: np.ndarray | None = None,
) -> dict[str, Any]:
    """Build a ``reroom_portal`` emitter dict (to nest under a shape's ``"emitter"`` key).

    ``view`` is a second ``(H', W', 3)`` lat-long map (same convention, any size) that
    the emitter shows instead of ``hdri`` while its parameter ``use_view`` is 1: what a
    camera looking out sees (the photos' own radiance,
    :func:`reroom.invert.window_env.view_map`), while the room is lit by ``hdri``.
    :class:`reroom.render.frames.FrameRenderer` switches it for the pass that gives
    the emitters seen directly.

    ``hdri`` is an EXR path or an ``(H, W, 3)`` lat-long array (see the module
    docstring for the convention); it is clamped to >= 0. ``opening`` is the shape's
    parallelogram, ``(centre, half_u, half_v, inward_normal)`` (metres, world;
    ``centre +- half_u +- half_v`` are its corners): with it, next-event estimation can
    also draw directions from the map (the sky strategy, for a low sun), whose share
    of the light samples is ``sky_sampling`` (default :func:`default_sky_sampling` of
    the map). It must be the shape the emitter is attached to.
    """
    mi = register_emitters()
    data = load_hdri(hdri)
    d: dict[str, Any] = {
        "type": PORTAL,
        "data": mi.TensorXf(data),
        "scale": float(scale),
        "rotation": float(rotation_deg),
    }
    if opening is not None:
        centre, half_u, half_v, inward = (np.asarray(x, np.float64) for x in opening)
        for name, x in (("centre", centre), ("half_u", half_u), ("half_v", half_v)):
            if x.shape != (3,) or not np.all(np.isfinite(x)):
                raise ValueError(f"{PORTAL}: opening {name} must be a finite 3-vector, got {x}")
        if inward.shape != (3,) or not np.all(np.isfinite(inward)) or not inward.any():
            raise ValueError(f"{PORTAL}: inward_normal must be a nonzero 3-vector, got {inward}")
        if np.linalg.norm(np.cross(half_u, half_v)) <= 0:
            raise ValueError(f"{PORTAL}: the opening's half_u and half_v span no area")
        d["outward"] = (-inward / np.linalg.norm(inward)).tolist()
        d["opening_centre"] = centre.tolist()
        d["opening_u"] = half_u.tolist()
        d["opening_v"] = half_v.tolist()
    if sky_sampling is not None:
        d["sky_sampling"] = float(sky_sampling)
    if view is not None:
        d["view_data"] = mi.TensorXf(load_hdri(np.asarray(view, np.float32)))
    return d


def window_portal(
    center: Sequence[float],
    width: float,
    height: float,
    inward_normal: Sequence[float],
    hdri: str | Path | np.ndarray,
    scale: float = 1.0,
    rotation_deg: float = 0.0,
    up: Sequence[float] = (0.0, 0.0, 1.0),
) -> dict[str, Any]:
    """A black ``rectangle`` filling a window opening, carrying a ``reroom_portal`` emitter.

    Parameters
    ----------
    center:
        Centre of the opening (metres, world).
    width, height:
        Size of the opening along the horizontal and ``up`` directions (metres).
    inward_normal:
        Unit vector pointing from the window into the room (the side that
        receives light).
    hdri, scale, rotation_deg:
        Outdoor radiance, see :func:`portal_emitter`.
    up:
        Direction of the opening's ``height`` edge (projected into the window plane).

    Returns
    -------
    dict
        A shape dict: add it to the scene dict under any key.
    """
    mi = register_emitters()
    n = np.asarray(inward_normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    y = np.asarray(up, dtype=np.float64)
    y = y - n * (y @ n)
    if np.linalg.norm(y) < 1e-8:
        raise ValueError("'up' must not be parallel to the window normal")
    y = y / np.linalg.norm(y)
    x = np.cross(y, n)  # right-handed (x, y, n) so the rectangle's +Z normal maps onto n
    linear = np.stack([x * (width / 2.0), y * (height / 2.0), n], axis=1)
    return {
        "type": "rectangle",
        "to_world": mi.ScalarTransform4f(_affine(linear, center).tolist()),
        # Black: a path that reaches the opening ends there, as if it escaped outdoors.
        "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}},
        "emitter": portal_emitter(
            hdri,
            scale,
            rotation_deg,
            opening=(center, x * (width / 2.0), y * (height / 2.0), n),
        ),
    }


def envmap_emitter(
    hdri: str | Path | np.ndarray, scale: float = 1.0, rotation_deg: float = 0.0
) -> dict[str, Any]:
    """Mitsuba's built-in ``envmap`` showing ``hdri`` with the same convention as ``reroom_portal``.

    Mitsuba's envmap is +Y-up with ``u = atan2(x, -z) / (2 pi)``; its
    ``to_world`` here maps that onto the +Z-up convention above. Its rows are
    *nodes* (row 0 exactly at the zenith, the last row at the nadir) whereas
    lat-long pixels are cell centres. The map is therefore resampled to
    ``2 H + 1`` node rows at ``theta = pi j / (2 H)``: these include every pixel
    centre, where the portal's interpolant has its kinks, so Mitsuba's
    bilinear lookup reproduces the portal's radiance exactly (columns already
    agree: both put pixel centres at ``u = (c + 0.5) / W``).

    Load scenes that contain an envmap with ``mi.load_dict(scene, optimize=False)``:
    in Mitsuba 3.9.1 the default optimisation merges meshes that share a BSDF
    into one mesh with an *invalid* bounding box, the scene's bounding box
    becomes invalid, the envmap's bounding sphere collapses to ~1e-4 m and its
    shadow rays stop short of the walls, so light leaks into closed rooms.
    """
    mi = mitsuba()
    data = load_hdri(hdri)
    h = data.shape[0]
    ext = np.concatenate([data[:1], data, data[-1:]], axis=0)  # clamp beyond the poles
    mid = 0.5 * (ext[:-1] + ext[1:])  # even node 2k (theta = pi k / H): between rows k-1, k
    nodes = np.empty((2 * h + 1,) + data.shape[1:], dtype=np.float32)
    nodes[0::2] = mid
    nodes[1::2] = data  # odd node 2k+1 is the centre of row k
    # Mitsuba local (x, y, z) -> world (z, x, y), then the rotation about +Z.
    to_mitsuba = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    return {
        "type": "envmap",
        "bitmap": mi.Bitmap(np.ascontiguousarray(nodes, dtype=np.float32)),
        "scale": float(scale),
        "to_world": mi.ScalarTransform4f(_affine(_rot_z(rotation_deg) @ to_mitsuba).tolist()),
    }


# ---------------------------------------------------------------------- plugin classes
def _props_array(props: Any, name: str) -> np.ndarray | None:
    if name not in props:
        return None
    return np.array(props[name], dtype=np.float64)


def _make_classes(mi: ModuleType) -> tuple[type, type]:
    """Define the plugin classes for the current variant (they subclass its ``mi.Emitter``)."""
    import drjit as dr

    if not mi.is_rgb or mi.variant().startswith("scalar"):
        # Python plugins run once per vectorised call in JIT variants, but once per
        # ray in scalar ones, and the table/HDRI code below assumes JIT arrays.
        from reroom.errors import ReroomError

        raise ReroomError(
            "windows and goniometric point lights are rendered by Python-defined Mitsuba "
            f"emitters, which need the llvm_ad_rgb variant, not {mi.variant()}: install LLVM >= 17 "
            "(`apt-get install libllvm19`, which scripts/setup.sh does when run as root)"
        )

    inv_pi = 1.0 / math.pi
    inv_two_pi = 0.5 / math.pi

    def _zero_wavelengths(si: Any) -> Any:
        return dr.zeros(type(si.wavelengths), dr.width(si.p))

    shadow_end = make_shadow_end(mi)

    class GoniometricEmitter(mi.Emitter):
        """Point light with a tabulated type C intensity distribution (see module docstring)."""

        def __init__(self, props: Any) -> None:
            super().__init__(props)
            m = (
                np.array(props["to_world"].matrix, dtype=np.float64).reshape(4, 4)
                if "to_world" in props
                else np.eye(4)
            )
            lin = m[:3, :3]
            # Only the orientation matters for a point light: drop scale/shear.
            u, _, vt = np.linalg.svd(lin)
            rot = u @ vt
            if np.linalg.det(rot) < 0:
                raise ValueError(f"{GONIOMETRIC}: to_world must not mirror the luminaire frame")
            pos = _props_array(props, "position")
            pos = m[:3, 3] if pos is None else pos
            self.m_position = mi.Point3f(*[float(x) for x in pos])
            self.m_axes = [mi.Vector3f(*[float(x) for x in rot[:, k]]) for k in range(3)]
            self._rot = rot
            self._pos = pos

            if "intensity" in props:
                raw = props["intensity"]
                table = np.array(raw, dtype=np.float64)
            else:
                table = np.array(1.0)
            if table.ndim == 0:
                table = np.full((2, 2), float(table))
            if table.ndim != 2 or table.shape[0] < 2 or table.shape[1] < 2:
                raise ValueError(f"{GONIOMETRIC}: 'intensity' must be a (n_theta, n_phi) table")
            if not np.all(np.isfinite(table)) or np.any(table < 0):
                raise ValueError(f"{GONIOMETRIC}: 'intensity' must be finite and >= 0")
            color = _props_array(props, "color")
            color = np.ones(3) if color is None else np.broadcast_to(color, (3,))
            scale = float(props["scale"]) if "scale" in props else 1.0
            clearance = float(props["clearance"]) if "clearance" in props else 0.0
            if not math.isfinite(clearance) or clearance < 0:
                raise ValueError(f"{GONIOMETRIC}: 'clearance' must be a distance >= 0")
            self.clearance = clearance
            self.m_color = mi.Color3f(*[float(c) for c in color])
            self.m_scale = mi.Float(scale)
            self.m_table = mi.TensorXf(table.astype(np.float32))
            self._build_sampling()
            dr.make_opaque(self.m_position, self.m_color, self.m_scale, self.m_axes)
            self.m_flags = mi.EmitterFlags.DeltaPosition
            # sample_ray() only uses sample3 (direction); the position is a delta.
            self.m_needs_sample_2 = False

        # -- setup -----------------------------------------------------------
        def _build_sampling(self) -> None:
            """Build the cell distribution used by ``sample_ray`` (host side)."""
            table = np.array(self.m_table, dtype=np.float64)
            nt, nph = table.shape
            self.n_theta, self.n_phi = int(nt), int(nph)
            theta = np.linspace(0.0, math.pi, nt)
            dphi = 2.0 * math.pi / (nph - 1)
            cos_t = np.cos(theta)
            solid = (cos_t[:-1] - cos_t[1:])[:, None] * dphi  # (nt-1, 1)
            avg = 0.25 * (table[:-1, :-1] + table[1:, :-1] + table[:-1, 1:] + table[1:, 1:])
            w = (avg * solid).ravel()
            if not np.any(w > 0):
                w = np.broadcast_to(solid, avg.shape).ravel().copy()
            self.m_cell_distr = mi.DiscreteDistribution(mi.Float(w.astype(np.float32)))
            self.m_cos_nodes = mi.Float(cos_t.astype(np.float32))
            self.m_solid = mi.Float(np.broadcast_to(solid, avg.shape).ravel().astype(np.float32))
            self.m_table_flat = mi.Float(table.astype(np.float32).ravel())

        # -- helpers ---------------------------------------------------------
        def _to_local(self, d: Any) -> Any:
            return mi.Vector3f(
                dr.dot(d, self.m_axes[0]), dr.dot(d, self.m_axes[1]), dr.dot(d, self.m_axes[2])
            )

        def _to_world(self, v: Any) -> Any:
            return self.m_axes[0] * v.x + self.m_axes[1] * v.y + self.m_axes[2] * v.z

        def _table(self, d_local: Any, active: Any = True) -> Any:
            """Bilinear table lookup for a unit local direction (theta from -Z)."""
            theta = dr.safe_acos(-d_local.z)
            phi = dr.atan2(d_local.y, d_local.x)
            phi = dr.select(phi < 0, phi + 2.0 * math.pi, phi)
            ft = theta * ((self.n_theta - 1) * inv_pi)
            fp = phi * ((self.n_phi - 1) * inv_two_pi)
            it = dr.minimum(mi.UInt32(dr.maximum(ft, 0.0)), self.n_theta - 2)
            ip = dr.minimum(mi.UInt32(dr.maximum(fp, 0.0)), self.n_phi - 2)
            wt = dr.clip(ft - mi.Float(it), 0.0, 1.0)
            wp = dr.clip(fp - mi.Float(ip), 0.0, 1.0)
            idx = it * self.n_phi + ip
            v00 = dr.gather(mi.Float, self.m_table_flat, idx, active)
            v01 = dr.gather(mi.Float, self.m_table_flat, idx + 1, active)
            v10 = dr.gather(mi.Float, self.m_table_flat, idx + self.n_phi, active)
            v11 = dr.gather(mi.Float, self.m_table_flat, idx + self.n_phi + 1, active)
            v0 = dr.lerp(v00, v01, wp)
            v1 = dr.lerp(v10, v11, wp)
            return dr.lerp(v0, v1, wt)

        def _intensity(self, d_world: Any, active: Any = True) -> Any:
            """Radiant intensity (W/sr, RGB) emitted along the unit world direction."""
            val = self._table(self._to_local(d_world), active) * self.m_scale
            return mi.Spectrum(self.m_color * val)

        def _pdf_local(self, d_local: Any, active: Any = True) -> Any:
            """Solid-angle density of ``sample_ray``'s direction sampling."""
            theta = dr.safe_acos(-d_local.z)
            phi = dr.atan2(d_local.y, d_local.x)
            phi = dr.select(phi < 0, phi + 2.0 * math.pi, phi)
            it = dr.minimum(
                mi.UInt32(dr.maximum(theta * ((self.n_theta - 1) * inv_pi), 0.0)),
                self.n_theta - 2,
            )
            ip = dr.minimum(
                mi.UInt32(dr.maximum(phi * ((self.n_phi - 1) * inv_two_pi), 0.0)),
                self.n_phi - 2,
            )
            cell = it * (self.n_phi - 1) + ip
            pmf = self.m_cell_distr.eval_pmf_normalized(cell, active)
            solid = dr.gather(mi.Float, self.m_solid, cell, active)
            return dr.select(solid > 0, pmf / solid, 0.0)

        # -- Emitter interface -------------------------------------------------
        def sample_direction(self, it: Any, sample: Any, active: Any = True) -> Any:
            ds = dr.zeros(mi.DirectionSample3f)
            ds.p = mi.Point3f(self.m_position)
            ds.n = mi.Normal3f(0.0)
            ds.uv = mi.Point2f(0.0)
            ds.time = it.time
            ds.pdf = mi.Float(1.0)
            ds.delta = mi.Bool(True)
            ds.emitter = mi.EmitterPtr(self)
            d = ds.p - it.p
            dist2 = dr.squared_norm(d)
            inv_dist = dr.rsqrt(dist2)
            ds.d = d * inv_dist
            ds.dist = dr.sqrt(dist2)
            # Light leaves the luminaire along -ds.d.
            spec = self._intensity(-ds.d, active) * dr.square(inv_dist)
            if self.clearance > 0:
                ds.p = shadow_end(it.p, ds.d, ds.dist, self.clearance)
            return ds, dr.select(active, spec, 0.0)

        def pdf_direction(self, it: Any, ds: Any, active: Any = True) -> Any:
            return mi.Float(0.0)  # a delta position has no density w.r.t. solid angle

        def eval_direction(self, it: Any, ds: Any, active: Any = True) -> Any:
            d = ds.p - it.p
            dist2 = dr.squared_norm(d)
            spec = self._intensity(-d * dr.rsqrt(dist2), active) / dist2
            return dr.select(active, spec, 0.0)

        def eval(self, si: Any, active: Any = True) -> Any:
            return mi.Spectrum(0.0)  # rays can never hit a point

        def sample_position(self, time: Any, sample: Any, active: Any = True) -> Any:
            ps = dr.zeros(mi.PositionSample3f)
            ps.p = mi.Point3f(self.m_position)
            ps.time = time
            ps.pdf = mi.Float(1.0)
            ps.delta = mi.Bool(True)
            return ps, mi.Float(1.0)

        def pdf_position(self, ps: Any, active: Any = True) -> Any:
            return mi.Float(0.0)

        def sample_ray(
            self, time: Any, sample1: Any, sample2: Any, sample3: Any, active: Any = True
        ) -> Any:
            # Importance-sample a table cell, then a direction uniform in solid angle in it.
            cell, u_re, pmf = self.m_cell_distr.sample_reuse_pmf(sample3.x, active)
            it = cell // (self.n_phi - 1)
            ip = cell - it * (self.n_phi - 1)
            c0 = dr.gather(mi.Float, self.m_cos_nodes, it, active)
            c1 = dr.gather(mi.Float, self.m_cos_nodes, it + 1, active)
            cos_t = dr.lerp(c0, c1, u_re)
            sin_t = dr.safe_sqrt(1.0 - dr.square(cos_t))
            phi = (mi.Float(ip) + sample3.y) * (2.0 * math.pi / (self.n_phi - 1))
            sp, cp = dr.sincos(phi)
            d_local = mi.Vector3f(sin_t * cp, sin_t * sp, -cos_t)
            solid = dr.gather(mi.Float, self.m_solid, cell, active)
            pdf = dr.select(solid > 0, pmf / solid, 0.0)
            d_world = self._to_world(d_local)
            weight = self._intensity(d_world, active) / dr.maximum(pdf, 1e-30)
            wavelengths = dr.zeros(mi.Color0f, dr.width(sample1)) if hasattr(mi, "Color0f") else 0
            ray = mi.Ray3f(mi.Point3f(self.m_position), d_world, time, wavelengths)
            return ray, dr.select(active & (pdf > 0), weight, 0.0)

        def sample_wavelengths(self, si: Any, sample: Any, active: Any = True) -> Any:
            # RGB only: nothing to sample; the weight is the intensity towards si.wi.
            return _zero_wavelengths(si), dr.select(
                active, self._intensity(dr.normalize(si.wi), active), 0.0
            )

        def bbox(self) -> Any:
            p = mi.ScalarPoint3f(*[float(x) for x in self._pos])
            return mi.ScalarBoundingBox3f(p)

        def traverse(self, callback: Any) -> None:
            callback.put("scale", self.m_scale, mi.ParamFlags.Differentiable)
            callback.put("color", self.m_color, mi.ParamFlags.Differentiable)
            callback.put("position", self.m_position, mi.ParamFlags.NonDifferentiable)
            callback.put("intensity", self.m_table, mi.ParamFlags.NonDifferentiable)

        def parameters_changed(self, keys: Any = None) -> None:
            if not keys or "intensity" in keys:
                self._build_sampling()
            self._pos = np.array(self.m_position, dtype=np.float64).ravel()
            dr.make_opaque(self.m_position, self.m_color, self.m_scale)

        def to_string(self) -> str:
            return (
                f"GoniometricEmitter[position={self._pos.tolist()}, "
                f"table={self.n_theta}x{self.n_phi}, scale={self.m_scale}, color={self.m_color}]"
            )

    class WindowPortalEmitter(mi.Emitter):
        """Area emitter on a window opening showing an outdoor HDRI (see module docstring)."""

        def __init__(self, props: Any) -> None:
            super().__init__(props)
            if "data" in props:
                img = np.array(props["data"], dtype=np.float32)
            elif "bitmap" in props:
                img = np.array(props["bitmap"], dtype=np.float32)
            elif "filename" in props:
                img = load_hdri(str(props["filename"]))
            else:
                raise ValueError(f"{PORTAL}: one of 'filename', 'data' or 'bitmap' is required")
            if img.ndim != 3 or img.shape[2] < 3 or img.shape[0] < 2 or img.shape[1] < 2:
                raise ValueError(
                    f"{PORTAL}: expected an (H >= 2, W >= 2, 3) image, got {img.shape}"
                )
            img = np.maximum(np.nan_to_num(img[..., :3]), 0.0)
            self.height, self.width = int(img.shape[0]), int(img.shape[1])
            # One extra column (a copy of the first) so that u wraps without a modulo.
            padded = np.concatenate([img, img[:, :1]], axis=1)
            self.m_data = mi.Float(np.ascontiguousarray(padded, dtype=np.float32).ravel())
            self.m_scale = mi.Float(float(props["scale"]) if "scale" in props else 1.0)
            rotation = float(props["rotation"]) if "rotation" in props else 0.0
            self.rotation = rotation
            self.m_cos_rot = mi.Float(math.cos(math.radians(rotation)))
            self.m_sin_rot = mi.Float(math.sin(math.radians(rotation)))
            dr.make_opaque(self.m_scale, self.m_cos_rot, self.m_sin_rot)
            self.m_flags = mi.EmitterFlags.Surface
            self._build_sky_sampling(img, props)
            # The camera's view (portal_emitter's ``view``), shown while use_view is 1.
            self.has_view = "view_data" in props
            self.m_use_view = mi.Float(0.0)
            if self.has_view:
                view = np.maximum(np.nan_to_num(np.array(props["view_data"], np.float32)), 0.0)
                if view.ndim != 3 or view.shape[2] < 3 or min(view.shape[:2]) < 2:
                    raise ValueError(f"{PORTAL}: view_data must be (H >= 2, W >= 2, 3)")
                view = view[..., :3]
                self.view_height, self.view_width = int(view.shape[0]), int(view.shape[1])
                vpad = np.concatenate([view, view[:, :1]], axis=1)
                self.m_view = mi.Float(np.ascontiguousarray(vpad, dtype=np.float32).ravel())

        def _build_sky_sampling(self, img: np.ndarray, props: Any) -> None:
            """The second NEE strategy: directions drawn from the map's own brightness.

            Uniform points on the opening find a small bright sun only by chance (one
            sample in hundreds carries all of a sunlit patch's light: fireflies). So a
            share ``sky_sampling`` of the samples picks a pixel with probability
            proportional to its luminance times its solid angle, a uniform point in it,
            and follows that direction to the opening (a miss carries nothing). Both
            strategies' pdfs are summed (a one-sample mixture), so the estimate stays
            unbiased whatever the share; 0 keeps area sampling alone.
            """
            share = float(props["sky_sampling"]) if "sky_sampling" in props else None
            outward = _props_array(props, "outward")
            opening = [_props_array(props, k) for k in ("opening_centre", "opening_u", "opening_v")]
            if outward is None or any(x is None for x in opening):
                # Without the opening's plane and extent a sky sample cannot be placed.
                if share:
                    raise ValueError(
                        f"{PORTAL}: sky_sampling needs 'outward', 'opening_centre', "
                        "'opening_u' and 'opening_v'"
                    )
                share = 0.0
            else:
                centre, half_u, half_v = opening
                outward = outward / np.linalg.norm(outward)
                self.m_centre = mi.Vector3f(*(float(x) for x in centre))
                self.m_inward = mi.Vector3f(*(float(-x) for x in outward))
                self.m_half_u = mi.Vector3f(*(float(x) for x in half_u))
                self.m_half_v = mi.Vector3f(*(float(x) for x in half_v))
                self.m_inv_u2 = mi.Float(1.0 / float(half_u @ half_u))
                self.m_inv_v2 = mi.Float(1.0 / float(half_v @ half_v))
            lum = np.maximum(img @ np.array([0.2126, 0.7152, 0.0722], np.float32), 0.0)
            # The lookup is bilinear between pixel centres, so a pixel's light spills into
            # its neighbours' areas: weight each pixel by the interpolant's integral over
            # its area (weights 1/8, 3/4, 1/8 per axis; rows clamp, columns wrap, as the
            # lookup does). Weighting by the pixel's own value leaves almost half of a
            # one-pixel sun to the uniform strategy (fireflies, and a mean that converges
            # slowly).
            lum = correlate1d(lum, [0.125, 0.75, 0.125], axis=0, mode="nearest")
            lum = correlate1d(lum, [0.125, 0.75, 0.125], axis=1, mode="wrap")
            sin_t = np.sin(np.pi * (np.arange(self.height) + 0.5) / self.height)
            weight = lum * sin_t[:, None]
            if outward is not None:
                # Only directions that leave through the opening can pass it: weight by the
                # cosine at the opening (the light that enters), 0 behind it.
                dirs = _pixel_directions(self.height, self.width, self.rotation)
                weight = weight * np.maximum(dirs @ outward, 0.0)
            if share is None:
                share = default_sky_sampling(img, outward, self.rotation)
            if not (0.0 <= share < 1.0) or not np.isfinite(share):
                raise ValueError(f"{PORTAL}: sky_sampling must be in [0, 1), got {share!r}")
            if weight.sum() <= 0:
                share = 0.0
            self.sky_share = share
            if share > 0:
                self.m_sky = mi.DiscreteDistribution(mi.Float(weight.ravel().astype(np.float32)))
            self.m_share = mi.Float(share)
            dr.make_opaque(self.m_share)

        def _through_opening(self, p: Any, d: Any) -> tuple[Any, Any, Any]:
            """Where the ray ``p + t d`` crosses the opening: point, ``t``, and a hit mask.

            Ray-parallelogram by hand rather than ``Shape.ray_intersect``: a mesh shape
            (the synthetic scenes' window panes) has no per-shape intersection in Mitsuba.
            """
            denom = dr.dot(d, self.m_inward)  # < 0 for a ray leaving the room
            safe = dr.select(dr.abs(denom) > 1e-12, denom, -1e-12)
            t = dr.dot(self.m_centre - p, self.m_inward) / safe
            x = p + t * d
            r = x - self.m_centre
            a = dr.dot(r, self.m_half_u) * self.m_inv_u2
            b = dr.dot(r, self.m_half_v) * self.m_inv_v2
            hit = (denom < 0) & (t > 0) & (dr.abs(a) <= 1.0) & (dr.abs(b) <= 1.0)
            return x, t, hit

        def _sky_pdf(self, d: Any, active: Any = True) -> Any:
            """Solid-angle pdf of the sky strategy for the world direction ``d``."""
            u, v = self._map_uv(d)
            cos_t = dr.clip(d.z, -1.0, 1.0)
            w, h = self.width, self.height
            col = dr.minimum(mi.UInt32(dr.maximum(u * w, 0.0)), w - 1)
            row = dr.minimum(mi.UInt32(dr.maximum(v * h, 0.0)), h - 1)
            pmf = self.m_sky.eval_pmf_normalized(row * w + col, active)
            sin_t = dr.safe_sqrt(1.0 - cos_t * cos_t)
            # (u, v) uniform in a pixel: d omega = 2 pi^2 sin(theta) du dv.
            pdf = pmf * (w * h) / (2.0 * math.pi * math.pi * dr.maximum(sin_t, 1e-12))
            return dr.select(active & (sin_t > 0), pdf, 0.0)

        def _sky_direction(self, sample: Any) -> Any:
            """A world direction drawn by the sky strategy from a ``Point2f`` sample."""
            idx, x_re = self.m_sky.sample_reuse(sample.x)
            w, h = self.width, self.height
            row = idx // w
            col = idx - row * w
            u = (mi.Float(col) + x_re) / w
            v = (mi.Float(row) + sample.y) / h
            phi = 2.0 * math.pi * (0.5 - u)
            theta = math.pi * v
            st, ct = dr.sin(theta), dr.cos(theta)
            xl, yl = st * dr.cos(phi), st * dr.sin(phi)
            # Back to world: the inverse of the rotation in ``_radiance``.
            return mi.Vector3f(
                xl * self.m_cos_rot - yl * self.m_sin_rot,
                xl * self.m_sin_rot + yl * self.m_cos_rot,
                ct,
            )

        # -- helpers ---------------------------------------------------------
        def _map_uv(self, d: Any) -> tuple[Any, Any]:
            """The map coordinates ``(u, v)`` in [0, 1) of the unit world direction ``d``."""
            # Undo the environment's rotation about +Z.
            x = d.x * self.m_cos_rot + d.y * self.m_sin_rot
            y = d.y * self.m_cos_rot - d.x * self.m_sin_rot
            u = 0.5 - dr.atan2(y, x) * inv_two_pi
            u = u - dr.floor(u)
            return u, dr.safe_acos(d.z) * inv_pi

        def _radiance(self, d: Any, active: Any = True) -> Any:
            """Outdoor radiance seen looking along the unit world direction ``d``."""
            u, v = self._map_uv(d)
            light = self._lookup(self.m_data, self.width, self.height, u, v, active)
            if not self.has_view:
                return light
            view = self._lookup(self.m_view, self.view_width, self.view_height, u, v, active)
            return dr.select(self.m_use_view > 0.5, view, light)

        def _lookup(self, data: Any, w: int, h: int, u: Any, v: Any, active: Any) -> Any:
            """Bilinear lookup of a padded lat-long table at ``(u, v)``, times the scale."""
            fx = u * w - 0.5
            fx = dr.select(fx < 0, fx + w, fx)
            x0 = dr.minimum(mi.UInt32(dr.maximum(fx, 0.0)), w - 1)
            wx = dr.clip(fx - mi.Float(x0), 0.0, 1.0)
            fy = dr.clip(v * h - 0.5, 0.0, h - 1.0)
            y0 = dr.minimum(mi.UInt32(fy), h - 2)
            wy = dr.clip(fy - mi.Float(y0), 0.0, 1.0)
            idx = y0 * (w + 1) + x0
            c00 = dr.gather(mi.Color3f, data, idx, active)
            c01 = dr.gather(mi.Color3f, data, idx + 1, active)
            c10 = dr.gather(mi.Color3f, data, idx + (w + 1), active)
            c11 = dr.gather(mi.Color3f, data, idx + (w + 2), active)
            c0 = dr.lerp(c00, c01, wx)
            c1 = dr.lerp(c10, c11, wx)
            return mi.Spectrum(dr.lerp(c0, c1, wy) * self.m_scale)

        # -- Emitter interface -------------------------------------------------
        def eval(self, si: Any, active: Any = True) -> Any:
            # si.wi points from the portal back towards the viewer (local frame);
            # the viewer looks out through the window along -wi.
            front = active & (mi.Frame3f.cos_theta(si.wi) > 0)
            look = -si.to_world(si.wi)
            return dr.select(front, self._radiance(look, front), 0.0)

        def sample_direction(self, it: Any, sample: Any, active: Any = True) -> Any:
            shape = self.get_shape()
            if self.sky_share <= 0:
                ds = shape.sample_direction(it, sample, active)
                # Uniform area sampling; ds.pdf is already in solid angle (d^2 / (|cos| A)).
                active = active & (dr.dot(ds.d, ds.n) < 0) & (ds.pdf > 0)
                ds.emitter = mi.EmitterPtr(self)
                spec = self._radiance(ds.d, active) / dr.select(active, ds.pdf, 1.0)
                return ds, dr.select(active, spec, 0.0)
            share = self.m_share
            use_sky = sample.x < share
            # Each strategy gets its share of [0, 1) stretched back to the whole range.
            x_area = dr.clip((sample.x - share) / (1.0 - share), 0.0, 0.99999994)
            x_sky = dr.clip(sample.x / share, 0.0, 0.99999994)
            ds = shape.sample_direction(it, mi.Point2f(x_area, sample.y), active)
            d_sky = self._sky_direction(mi.Point2f(x_sky, sample.y))
            p_hit, t_hit, hit = self._through_opening(it.p, d_sky)
            ds.p = dr.select(use_sky, p_hit, ds.p)
            ds.n = dr.select(use_sky, self.m_inward, ds.n)
            ds.d = dr.select(use_sky, d_sky, ds.d)
            ds.dist = dr.select(use_sky, t_hit, ds.dist)
            ok = active & dr.select(use_sky, hit, ds.pdf > 0) & (dr.dot(ds.d, ds.n) < 0)
            ds.pdf = self._mixture_pdf(it, ds, ok)
            ds.delta = False
            ds.emitter = mi.EmitterPtr(self)
            ok = ok & (ds.pdf > 0)
            spec = self._radiance(ds.d, ok) / dr.select(ok, ds.pdf, 1.0)
            return ds, dr.select(ok, spec, 0.0)

        def _mixture_pdf(self, it: Any, ds: Any, active: Any) -> Any:
            area = self.get_shape().pdf_direction(it, ds, active)
            if self.sky_share <= 0:
                return area
            share = self.m_share
            return (1.0 - share) * area + share * self._sky_pdf(ds.d, active)

        def pdf_direction(self, it: Any, ds: Any, active: Any = True) -> Any:
            active = active & (dr.dot(ds.d, ds.n) < 0)
            pdf = self._mixture_pdf(it, ds, active)
            return dr.select(active, pdf, 0.0)

        def eval_direction(self, it: Any, ds: Any, active: Any = True) -> Any:
            active = active & (dr.dot(ds.d, ds.n) < 0)
            return dr.select(active, self._radiance(ds.d, active), 0.0)

        def sample_position(self, time: Any, sample: Any, active: Any = True) -> Any:
            ps = self.get_shape().sample_position(time, sample, active)
            weight = dr.select(active & (ps.pdf > 0), dr.rcp(ps.pdf), 0.0)
            return ps, weight

        def pdf_position(self, ps: Any, active: Any = True) -> Any:
            return self.get_shape().pdf_position(ps, active)

        def sample_ray(
            self, time: Any, sample1: Any, sample2: Any, sample3: Any, active: Any = True
        ) -> Any:
            # Uniform point on the opening, cosine-weighted direction into the room.
            ps = self.get_shape().sample_position(time, sample2, active)
            local = mi.warp.square_to_cosine_hemisphere(sample3)
            d = mi.Frame3f(ps.n).to_world(local)
            # Radiance entering along d is what one sees looking out along -d;
            # weight = L cos / (pdf_area * cos / pi) = L pi / pdf_area.
            spec = self._radiance(-d, active) * (math.pi / dr.maximum(ps.pdf, 1e-30))
            wavelengths = dr.zeros(mi.Color0f, dr.width(sample1)) if hasattr(mi, "Color0f") else 0
            ray = mi.Ray3f(ps.p, d, time, wavelengths)
            valid = active & (ps.pdf > 0) & (mi.Frame3f.cos_theta(local) > 0)
            return ray, dr.select(valid, spec, 0.0)

        def sample_wavelengths(self, si: Any, sample: Any, active: Any = True) -> Any:
            # The particle tracer sets si.wi to the world direction towards the sensor.
            wi = dr.normalize(si.wi)
            front = active & (dr.dot(wi, si.n) > 0)
            return _zero_wavelengths(si), dr.select(front, self._radiance(-wi, front), 0.0)

        def bbox(self) -> Any:
            shape = self.get_shape()
            return shape.bbox() if shape is not None else mi.ScalarBoundingBox3f()

        def traverse(self, callback: Any) -> None:
            callback.put("scale", self.m_scale, mi.ParamFlags.Differentiable)
            if self.has_view:
                callback.put("use_view", self.m_use_view, mi.ParamFlags.NonDifferentiable)

        def parameters_changed(self, keys: Any = None) -> None:
            dr.make_opaque(self.m_scale, self.m_use_view)

        def to_string(self) -> str:
            return (
                f"WindowPortalEmitter[hdri={self.width}x{self.height}, "
                f"scale={self.m_scale}, rotation={self.rotation}]"
            )

    return GoniometricEmitter, WindowPortalEmitter
