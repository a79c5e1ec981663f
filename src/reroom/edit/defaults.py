"""The default edit sets ``reroom run`` renders: one of each kind of edit, chosen per room.

Every choice is made from the recovered model and the layout (never from ground truth):
which light is strongest (its solved power), which way the room is long (the layout's
floor polygon), where the floor is free (no scan geometry above it).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from reroom.edit.apply import RoomModel, _inside_room, load_model

__all__ = ["WALL_PALETTE", "default_edit_sets"]

#: Candidate wall paints (linear RGB): sage green, terracotta, slate blue, ochre. The
#: default repaint takes the one farthest from the recovered wall albedo, so the change
#: is clearly visible whatever the room's paint.
WALL_PALETTE: tuple[tuple[float, float, float], ...] = (
    (0.30, 0.45, 0.28),
    (0.55, 0.24, 0.14),
    (0.20, 0.30, 0.55),
    (0.70, 0.55, 0.20),
)


def _power(light: dict[str, Any]) -> float:
    p = light.get("power")
    return float(np.mean(p)) if p is not None else 0.0


def _centre(light: dict[str, Any]) -> np.ndarray:
    g = light["geometry"]
    if light["type"] == "point":
        return np.asarray(g["position"], float)
    if light["type"] == "line":
        return (np.asarray(g["p0"], float) + np.asarray(g["p1"], float)) / 2.0
    if light["type"] == "area":
        return np.asarray(g["centroid"], float)
    return np.asarray(g["centre"], float)


def _room_of(model: RoomModel, p_mesh: np.ndarray) -> tuple[np.ndarray, float, float] | None:
    from reroom.synth.room import point_in_polygon

    a = model.to_aligned(p_mesh)
    for poly, zf, zc, _ in model.rooms():
        if point_in_polygon(np.array([a[0]]), np.array([a[1]]), poly)[0]:
            return poly, zf, zc
    rooms = model.rooms()
    return (rooms[0][0], rooms[0][1], rooms[0][2]) if rooms else None


def _moved_position(model: RoomModel, p: np.ndarray, distance: float = 1.0) -> np.ndarray:
    """``p`` moved ``distance`` along its room's longer axis, towards the room's middle
    (so it stays inside); shortened if the room is too small."""
    from reroom.synth.room import point_in_polygon

    room = _room_of(model, p)
    if room is None:  # no layout: the scan's longer horizontal extent
        lo, hi = model.vertices.min(0), model.vertices.max(0)
        axis = np.array([1.0, 0.0, 0.0]) if hi[0] - lo[0] >= hi[1] - lo[1] else np.eye(3)[1]
        centre = (lo + hi) / 2
        sign = 1.0 if (centre - p) @ axis >= 0 else -1.0
        return p + sign * distance * axis
    poly, _, _ = room
    extent = poly.max(0) - poly.min(0)
    axis_a = np.array([1.0, 0.0, 0.0]) if extent[0] >= extent[1] else np.array([0.0, 1.0, 0.0])
    a = model.to_aligned(p)
    centre = np.r_[poly.mean(0), a[2]]
    sign = 1.0 if (centre - a) @ axis_a >= 0 else -1.0
    for d in (distance, 0.75 * distance, 0.5 * distance):
        for s in (sign, -sign):
            q = a + s * d * axis_a
            # Keep 15 cm from the walls: inside the polygon shrunk towards its centre.
            probe = q[:2] + 0.15 * s * axis_a[:2]
            if point_in_polygon(np.array([probe[0]]), np.array([probe[1]]), poly)[0]:
                return model.to_mesh(q)
    return p


def _free_floor_spot(
    model: RoomModel, half: float = 0.22, margin: float = 0.15, step: float = 0.1
) -> np.ndarray | None:
    """A floor point near the middle of the largest room with nothing standing on it.

    Candidates on a ``step`` grid inside the floor polygon, nearest the polygon's
    centroid first; a spot is free when no scan vertex between 3 cm and 1 m above the
    floor lies within the chair's footprint grown by ``margin``.
    """
    from reroom.edit.furniture import placed_object

    rooms = model.rooms()
    if not rooms:
        return None

    def poly_area(poly: np.ndarray) -> float:
        nxt = np.roll(poly, -1, axis=0)
        return abs(float((poly[:, 0] * nxt[:, 1] - nxt[:, 0] * poly[:, 1]).sum())) / 2

    poly, zf, _, _ = max(rooms, key=lambda r: poly_area(r[0]))
    va = model.to_aligned(model.vertices)
    h = va[:, 2] - zf
    standing = va[(h > 0.03) & (h < 1.0)]
    lo, hi = poly.min(0), poly.max(0)
    xs = np.arange(lo[0] + step / 2, hi[0], step)
    ys = np.arange(lo[1] + step / 2, hi[1], step)
    gx, gy = np.meshgrid(xs, ys)
    cand = np.stack([gx.ravel(), gy.ravel()], 1)
    x2 = poly[:, 0] * np.roll(poly[:, 1], -1) - np.roll(poly[:, 0], -1) * poly[:, 1]
    area = x2.sum() / 2
    cx = ((poly[:, 0] + np.roll(poly[:, 0], -1)) * x2).sum() / (6 * area)
    cy = ((poly[:, 1] + np.roll(poly[:, 1], -1)) * x2).sum() / (6 * area)
    order = np.argsort(np.hypot(cand[:, 0] - cx, cand[:, 1] - cy))
    r = half + margin
    for k in order:
        x, y = cand[k]
        near = (np.abs(standing[:, 0] - x) < r) & (np.abs(standing[:, 1] - y) < r)
        if near.any():
            continue
        pos = model.to_mesh(np.array([x, y, zf]))
        if _inside_room(model, placed_object("chair", pos)) is None:
            return pos
    return None


def default_edit_sets(
    scan_dir: str | Path,
    invert_dir: str | Path | None = None,
    lights_dir: str | Path | None = None,
    layout_dir: str | Path | None = None,
) -> dict[str, list[dict[str, Any]]]:
    """The default named edit sets for a recovered room.

    ``empty`` (with a layout), ``repaint_walls`` (the :data:`WALL_PALETTE` colour farthest
    from the wall albedo), ``light_off`` (the strongest non-window light by solved
    power), ``light_moved`` (the strongest point light, else the strongest non-window
    light, moved 1 m along the room's longer axis towards the middle), ``window_sunset``
    (the first window, ``sunset``), ``insert_chair`` (a chair on a free floor spot near
    the middle of the largest room). Sets whose subject the room lacks are left out.
    """
    model = load_model(scan_dir, invert_dir, lights_dir, layout_dir)
    sets: dict[str, list[dict[str, Any]]] = {}
    if model.layout is not None:
        sets["empty"] = [{"op": "empty"}]
    if "wall" in model.targets():
        wall = model.label_albedo("wall")
        far = max(WALL_PALETTE, key=lambda c: float(np.linalg.norm(np.asarray(c) - wall)))
        sets["repaint_walls"] = [{"op": "repaint", "target": "wall", "color": list(far)}]
    lights = [light for light in model.doc.get("lights", []) if light["type"] != "window"]
    if lights:
        strongest = max(lights, key=_power)
        sets["light_off"] = [{"op": "light", "name": strongest["name"], "off": True}]
        points = [light for light in lights if light["type"] == "point"]
        mover = max(points, key=_power) if points else strongest
        p = _centre(mover)
        q = _moved_position(model, p)
        sets["light_moved"] = [
            {"op": "light", "name": mover["name"], "move_to": [float(x) for x in q]}
        ]
    windows = [light for light in model.doc.get("lights", []) if light["type"] == "window"]
    if windows:
        sets["window_sunset"] = [{"op": "window", "name": windows[0]["name"], "hdri": "sunset"}]
    spot = _free_floor_spot(model)
    if spot is not None:
        sets["insert_chair"] = [
            {"op": "insert", "object": "chair", "position": [float(x) for x in spot]}
        ]
    return sets
