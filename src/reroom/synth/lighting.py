"""Mitsuba emitters for the light types of a scene description.

* ``area`` (ceiling panels) and ``line`` (fluorescent tubes) are diffuse area
  emitters on their part's mesh;
* ``window`` is a portal emitter on the part filling the window opening, which
  shows the outdoor HDRI (see :mod:`reroom.render.emitters`);
* ``point`` is a tabulated goniometric point light: isotropic, or an IES LM-63
  profile (see :mod:`reroom.render.emitters`).

Point-light ``power`` is the radiant flux in scene units (the emitted intensity
is ``power * shape(w) / integral(shape)``, times ``color`` normalised to mean 1).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


def normalized_color(color: list[float]) -> np.ndarray:
    """RGB colour scaled to mean 1 so that ``power`` keeps its meaning."""
    c = np.asarray(color, float)
    return c / c.mean()


def approximate_power(light: dict, scene_dir: Path) -> float:
    """Rough emitted power of a light (scene units), for choosing NEE sampling weights.

    Mitsuba's path tracer picks *one* emitter per next-event estimate; with the
    default uniform choice, a room with five lights wastes most light samples
    on weak ones and the strong ones become five times noisier. Weighting the
    choice by power is the standard remedy; these estimates only need to be
    within a factor of a few.
    """
    kind = light["type"]
    if kind == "point":
        return float(light["power"])
    if kind == "area":
        c = np.asarray(light["corners"], float)
        area = float(np.linalg.norm(np.cross(c[1] - c[0], c[3] - c[0])))
        return float(np.pi * np.mean(light["radiance"]) * area)
    if kind == "line":
        length = float(np.linalg.norm(np.subtract(light["p1"], light["p0"])))
        # Baffles and the housing hide roughly half of the tube.
        return float(
            0.5 * np.pi * np.mean(light["radiance"]) * 2 * np.pi * light["radius"] * length
        )
    if kind == "window":
        from reroom.render.emitters import load_hdri

        c = np.asarray(light["corners"], float)
        area = float(np.linalg.norm(np.cross(c[1] - c[0], c[3] - c[0])))
        mean_radiance = float(load_hdri(scene_dir / light["hdri_file"], max_width=64).mean())
        return float(np.pi * light.get("scale", 1.0) * mean_radiance * area)
    raise ValueError(f"unknown light type {kind!r}")


def _opening(light: dict) -> tuple | None:
    """A window's parallelogram ``(centre, half_u, half_v, inward normal)`` from its corners."""
    if "corners" not in light or "normal" not in light:
        return None
    c = np.asarray(light["corners"], float)
    return c.mean(0), (c[1] - c[0]) / 2.0, (c[3] - c[0]) / 2.0, np.asarray(light["normal"], float)


def shape_emitter(light: dict, scene_dir: Path, mi: Any) -> dict | None:
    """The emitter dict to attach to a light's part, or ``None`` if it has none."""
    kind = light["type"]
    weight = max(approximate_power(light, scene_dir), 1e-6)
    if kind in ("area", "line"):
        return {
            "type": "area",
            "radiance": {"type": "rgb", "value": list(light["radiance"])},
            "sampling_weight": weight,
        }
    if kind == "window":
        from reroom.render import emitters

        d = emitters.portal_emitter(
            str(scene_dir / light["hdri_file"]),
            scale=float(light.get("scale", 1.0)),
            rotation_deg=float(light.get("rotation_deg", 0.0)),
            opening=_opening(light),
        )
        d["sampling_weight"] = weight
        return d
    return None


def point_emitter(light: dict, scene_dir: Path, mi: Any) -> dict:
    """The emitter dict of a point light (isotropic or IES profile)."""
    from reroom.render import emitters

    color = normalized_color(light.get("color", [1.0, 1.0, 1.0]))
    distribution: Any = 1.0
    if light["profile"] != "isotropic":
        from reroom.io.ies import read_ies

        distribution = read_ies(scene_dir / light["profile_file"])
    up = np.asarray(light.get("up", [0.0, 0.0, 1.0]), float)
    d = emitters.goniometric_light(
        distribution,
        position=light["position"],
        frame=emitters.luminaire_frame(nadir=-up),
        color=color.tolist(),
        flux=float(light["power"]),
    )
    d["sampling_weight"] = max(approximate_power(light, scene_dir), 1e-6)
    return d
