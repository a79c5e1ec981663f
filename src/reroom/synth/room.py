"""Rooms from Manhattan floor polygons: walls with openings, floor, ceiling, baseboards.

A room is a counter-clockwise polygon in the xy-plane (metres), extruded from
``floor_z`` to ``ceiling_z``. Openings sit on a polygon edge at arc length
``[s0, s1]`` from the edge's first vertex and height ``[z0, z1]``:

* ``window`` -- a hole through a wall of thickness ``depth``; its reveal
  (jambs, sill, lintel) is labelled ``window`` and an invisible-to-the-scan
  portal rectangle at the outside face emits the outdoor environment;
* ``door`` -- a closed door panel recessed ``depth`` into the wall;
* ``passage`` -- an open doorway through a wall of thickness ``depth`` into
  another room (built once, from the room that lists it).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from reroom.synth.geometry import Part, Piece, grid_rect


@dataclass
class Opening:
    """A window, door or passage in one wall of a room (see the module docstring)."""

    kind: str  # "window" | "door" | "passage"
    edge: int
    s0: float
    s1: float
    z0: float
    z1: float
    depth: float = 0.15
    name: str = ""
    build_tunnel: bool = True  # passages shared by two rooms are built from one side only


@dataclass
class RoomSpec:
    """One room of a floorplan."""

    polygon: np.ndarray  # (K, 2) counter-clockwise
    floor_z: float = 0.0
    ceiling_z: float = 2.7
    openings: list[Opening] = field(default_factory=list)
    name: str = "room"

    def edge(self, i: int) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
        """``(start, unit direction, length, inward normal)`` of polygon edge ``i``."""
        p0 = np.asarray(self.polygon[i], float)
        p1 = np.asarray(self.polygon[(i + 1) % len(self.polygon)], float)
        d = p1 - p0
        length = float(np.linalg.norm(d))
        d /= length
        return p0, d, length, np.array([-d[1], d[0]])


def polygon_area(poly: np.ndarray) -> float:
    """Signed area (positive for counter-clockwise)."""
    x, y = np.asarray(poly, float).T
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def point_in_polygon(x: np.ndarray, y: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Even-odd rule point-in-polygon test, vectorised over points."""
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    inside = np.zeros(np.broadcast(x, y).shape, bool)
    n = len(poly)
    for i in range(n):
        x0, y0 = poly[i]
        x1, y1 = poly[(i + 1) % n]
        crosses = (y0 > y) != (y1 > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            xint = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
        inside ^= crosses & (x < xint)
    return inside


def _z3(p2: np.ndarray, z: float) -> np.ndarray:
    return np.array([p2[0], p2[1], z], float)


def build_room(
    room: RoomSpec,
    h: float,
    materials: dict[str, dict],
    baseboard: tuple[float, float] | None = (0.08, 0.012),
    ceiling_holes: Sequence[tuple[float, float, float, float]] = (),
) -> tuple[list[Part], list[dict]]:
    """Build the parts of one room and the portal descriptions of its windows.

    Parameters
    ----------
    room:
        Polygon, heights and openings.
    h:
        Maximum grid spacing of the meshes (metres).
    materials:
        Material dict per class: ``wall, floor, ceiling, door, baseboard, window``.
    baseboard:
        ``(height, depth)`` of the baseboards, or ``None`` for none.
    ceiling_holes:
        ``(x0, x1, y0, y1)`` rectangles cut out of the ceiling (recessed fixtures).

    Returns
    -------
    parts, portals
        ``portals`` lists ``{"name", "corners" (4x3, counter-clockwise seen from the
        room), "normal" (into the room)}`` for each window.
    """
    if polygon_area(room.polygon) <= 0:
        raise ValueError(f"room {room.name!r}: polygon must be counter-clockwise")
    zf, zc = room.floor_z, room.ceiling_z
    height = zc - zf
    up = np.array([0.0, 0.0, 1.0])
    parts: list[Part] = []
    portals: list[dict] = []
    poly = np.asarray(room.polygon, float)

    for i in range(len(poly)):
        p0, d, length, n_in = room.edge(i)
        d3 = np.array([d[0], d[1], 0.0])
        n3 = np.array([n_in[0], n_in[1], 0.0])
        p1 = p0 + d * length
        # Wall seen from inside: origin at the edge's end, u = -d, so u x z = inward normal.
        ops = [o for o in room.openings if o.edge == i]
        holes = [(length - o.s1, length - o.s0, o.z0 - zf, o.z1 - zf) for o in ops]
        wall = grid_rect(_z3(p1, zf), -d3, up, length, height, h, holes=holes)
        parts.append(Part(f"{room.name}/wall{i}", wall, "wall", materials["wall"]))

        for o in ops:
            a = _z3(p0 + d * o.s0, 0.0)
            b = _z3(p0 + d * o.s1, 0.0)
            w = o.s1 - o.s0
            out = -n3 * o.depth
            if o.kind == "door":
                # Door panel recessed by `depth`, facing the room; jambs and head form its frame.
                panel = grid_rect(b + out + up * o.z0, -d3, up, w, o.z1 - o.z0, h)
                parts.append(
                    Part(f"{room.name}/{o.name or 'door'}", panel, "door", materials["door"])
                )
                frame_label, frame_mat = "door", materials["door"]
            else:
                frame_label = "window" if o.kind == "window" else "wall"
                frame_mat = materials["window"] if o.kind == "window" else materials["wall"]
            if not o.build_tunnel:
                continue
            reveal = [
                # left jamb (at s0) faces +d; right jamb (at s1) faces -d
                grid_rect(a + up * o.z0, up, -n3, o.z1 - o.z0, o.depth, h),
                grid_rect(b + up * o.z0 + out, up, n3, o.z1 - o.z0, o.depth, h),
                # head (top) faces down
                grid_rect(a + up * o.z1, d3, -n3, w, o.depth, h),
            ]
            sill = grid_rect(a + up * o.z0, -n3, d3, o.depth, w, h)  # faces up
            if o.kind == "window":
                reveal.append(sill)
            parts.append(
                Part(
                    f"{room.name}/{o.name or o.kind}_reveal",
                    Piece.concat(reveal),
                    frame_label,
                    frame_mat,
                )
            )
            if o.kind == "passage" and o.z0 <= zf + 1e-9:
                parts.append(
                    Part(
                        f"{room.name}/{o.name or 'passage'}_floor",
                        sill,
                        "floor",
                        materials["floor"],
                    )
                )
            if o.kind == "window":
                corners = np.array(
                    [
                        b + out + up * o.z0,
                        a + out + up * o.z0,
                        a + out + up * o.z1,
                        b + out + up * o.z1,
                    ]
                )
                portals.append(
                    {
                        "name": o.name or f"{room.name}/window{len(portals)}",
                        "corners": corners,
                        "normal": n3,
                    }
                )

        if baseboard is not None:
            bh, bd = baseboard
            skip = sorted(
                (o.s0, o.s1) for o in ops if o.kind in ("door", "passage") and o.z0 <= zf + 1e-9
            )
            segs, start = [], 0.0
            for s0, s1 in skip:
                if s0 > start:
                    segs.append((start, s0))
                start = max(start, s1)
            if start < length:
                segs.append((start, length))
            for k, (s0, s1) in enumerate(segs):
                e = _z3(p0 + d * s1, zf) + n3 * bd
                front = grid_rect(e, -d3, up, s1 - s0, bh, h)
                top = grid_rect(e + up * bh, -d3, -n3, s1 - s0, bd, h)
                ends = [
                    grid_rect(_z3(p0 + d * s0, zf), n3, up, bd, bh, h),  # faces -d
                    grid_rect(_z3(p0 + d * s1, zf), up, n3, bh, bd, h),  # faces +d
                ]
                parts.append(
                    Part(
                        f"{room.name}/baseboard{i}_{k}",
                        Piece.concat([front, top, *ends]),
                        "baseboard",
                        materials["baseboard"],
                    )
                )

    xs = sorted(set(poly[:, 0].tolist()))
    ys = sorted(set(poly[:, 1].tolist()))
    x0, y0 = xs[0], ys[0]
    wx, wy = xs[-1] - x0, ys[-1] - y0

    def inside_xy(s: float, t: float) -> bool:
        return bool(point_in_polygon(np.array(x0 + s), np.array(y0 + t), poly))

    def floor_keep(s: float, t: float) -> bool:
        return inside_xy(s, t)

    floor = grid_rect(
        [x0, y0, zf],
        [1, 0, 0],
        [0, 1, 0],
        wx,
        wy,
        h,
        holes=[
            (x - x0, x - x0, y - y0, y - y0) for x, y in poly
        ],  # zero-size: only adds grid lines
        keep=floor_keep,
    )
    parts.append(Part(f"{room.name}/floor", floor, "floor", materials["floor"]))

    def ceil_keep(s: float, t: float) -> bool:
        x, y = x0 + t, y0 + s
        for hx0, hx1, hy0, hy1 in ceiling_holes:
            if hx0 < x < hx1 and hy0 < y < hy1:
                return False
        return inside_xy(t, s)

    cuts = [(y - y0, y - y0, x - x0, x - x0) for x, y in poly]
    cuts += [(a - y0, b - y0, c - x0, e - x0) for c, e, a, b in ceiling_holes]
    ceiling = grid_rect(
        [x0, y0, zc],
        [0, 1, 0],
        [1, 0, 0],
        wy,
        wx,
        h,
        holes=[(c[0], c[0], c[2], c[2]) for c in cuts] + [(c[1], c[1], c[3], c[3]) for c in cuts],
        keep=ceil_keep,
    )
    parts.append(Part(f"{room.name}/ceiling", ceiling, "ceiling", materials["ceiling"]))
    return parts, portals


def room_layout(room: RoomSpec, baseboard: tuple[float, float] | None) -> dict:
    """The ground-truth layout record of one room (see ``docs/formats.md``)."""
    walls = []
    for i in range(len(room.polygon)):
        p0, d, length, n_in = room.edge(i)
        walls.append(
            {
                "index": i,
                "start": p0.tolist(),
                "end": (p0 + d * length).tolist(),
                "inward_normal": n_in.tolist(),
            }
        )
    return {
        "name": room.name,
        "polygon": np.asarray(room.polygon, float).tolist(),
        "floor_z": room.floor_z,
        "ceiling_z": room.ceiling_z,
        "walls": walls,
        "openings": [
            {
                "kind": o.kind,
                "name": o.name,
                "wall": o.edge,
                "s0": o.s0,
                "s1": o.s1,
                "z0": o.z0,
                "z1": o.z1,
                "depth": o.depth,
            }
            for o in room.openings
        ],
        "baseboard": None if baseboard is None else {"height": baseboard[0], "depth": baseboard[1]},
    }
