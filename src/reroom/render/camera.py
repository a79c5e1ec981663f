"""Mitsuba sensors that match a scan frame's camera exactly."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from reroom.render.mitsuba_env import mitsuba
from reroom.scan.camera import Intrinsics

#: Mitsuba's perspective camera looks down +z with +y up and +x to the *left*;
#: the scan format's OpenGL camera looks down -z with +x right. This flips x and z.
GL_TO_MITSUBA = np.diag([-1.0, 1.0, -1.0, 1.0])


def mitsuba_to_world(c2w: np.ndarray) -> Any:
    """Mitsuba ``to_world`` transform of a camera given as an OpenGL-axes ``c2w``."""
    mi = mitsuba()
    return mi.ScalarTransform4f((np.asarray(c2w, dtype=np.float64) @ GL_TO_MITSUBA).tolist())


def is_power_of_four(n: int) -> bool:
    """True for 1, 4, 16, 64, 256, ... (the counts :func:`reroom.render.frames.auto_spp` picks)."""
    return n > 0 and n & (n - 1) == 0 and (n.bit_length() - 1) % 2 == 0


def is_perfect_square(n: int) -> bool:
    """True for 1, 4, 9, 16, ... (the sample counts Mitsuba's ``multijitter`` takes as is)."""
    return n > 0 and math.isqrt(n) ** 2 == n


def default_sampler(spp: int) -> str:
    """The Mitsuba sampler a render at ``spp`` samples per pixel gets by default.

    ``multijitter`` (correlated multi-jittered samples, every dimension permuted on its
    own) where ``spp`` is a perfect square, ``independent`` otherwise. Not ``ldsampler``,
    Mitsuba's low-discrepancy sampler, the default until session 45: with more than one
    emitter its estimate is biased (the sample that picks the emitter is, by our reading,
    correlated with the path's later dimensions). In a room of six planes, a point light
    by one corner rendered alone at 0.90 of its brightness beside a second, dark, point
    light (64 and 256 spp; ``multijitter`` and ``independent`` within 0.3 % of 1); a
    recovered model's two point lights rendered alone and summed came to 6.7 % more than
    the two together. ``multijitter`` is as smooth: relative pixel noise 0.147 against
    ``ldsampler``'s 0.157 and ``independent``'s 0.204 on that model at 64 spp
    (docs/benchmarks.md, "Session 45").
    """
    return "multijitter" if is_perfect_square(int(spp)) else "independent"


def perspective_sensor(
    c2w: np.ndarray,
    intr: Intrinsics,
    spp: int,
    seed: int = 0,
    sampler: str | None = None,
    rfilter: str = "box",
    pixel_format: str = "rgb",
) -> dict[str, Any]:
    """A ``perspective`` sensor dict with a frame's pose, field of view and principal point.

    The default sampler is :func:`default_sampler`'s: ``multijitter`` when ``spp`` is a
    perfect square, ``independent`` otherwise.
    Lens distortion is not modelled (Mitsuba's perspective camera is a
    pinhole). Mitsuba's principal-point offsets are fractions of the film with
    the opposite sign of pixel coordinates; the tests check that a world point
    lands on the pixel :meth:`reroom.scan.Frame.project` gives.
    """
    if sampler is None:
        sampler = default_sampler(spp)
    return {
        "type": "perspective",
        "fov": float(intr.fov_y_deg),
        "fov_axis": "y",
        "principal_point_offset_x": float((intr.width / 2.0 - intr.cx) / intr.width),
        "principal_point_offset_y": float((intr.height / 2.0 - intr.cy) / intr.height),
        "near_clip": 0.01,
        "far_clip": 1000.0,
        "to_world": mitsuba_to_world(c2w),
        "film": {
            "type": "hdrfilm",
            "width": int(intr.width),
            "height": int(intr.height),
            "rfilter": {"type": rfilter},
            "pixel_format": pixel_format,
        },
        "sampler": {"type": sampler, "sample_count": int(spp), "seed": int(seed)},
    }


def subpixel_positions(x0: int, x1: int, y0: int, y1: int, supersample: int) -> np.ndarray:
    """``(N, 2)`` image positions of an ``s x s`` grid in every pixel of a box.

    Pixels ``x0 <= x < x1``, ``y0 <= y < y1`` in row-major order, each pixel's ``s * s``
    points together (row-major in the pixel), so a result reshapes to ``(y1 - y0, x1 -
    x0, s * s)``. Pixel ``(x, y)`` covers ``[x, x + 1) x [y, y + 1)``.
    """
    s = int(supersample)
    off = (np.arange(s) + 0.5) / s
    jj, ii = np.meshgrid(np.arange(x0, x1), np.arange(y0, y1))
    return (
        np.stack([jj, ii], -1)[:, :, None, None, :]
        + np.stack(np.meshgrid(off, off, indexing="xy"), -1)[None, None]
    ).reshape(-1, 2)
