"""The room model light detection needs from ``reroom layout`` (or a stand-in without one).

Coordinates: the layout's aligned frame is ``aligned = rotation @ world``; every
rectangle this module returns is in world coordinates (the scan's).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.path import Path as Polygon

from reroom.io.mesh import read_ply
from reroom.lights.lightset import LightsError

__all__ = [
    "CEILING",
    "FLOOR",
    "OTHER",
    "WALL",
    "RoomModel",
    "load_room_model",
    "room_model_without_layout",
]

#: Layout label ids (``docs/layout.md``).
WALL, FLOOR, CEILING, OTHER = 0, 1, 2, 255


@dataclass
class RoomModel:
    """What detection needs from the layout, in the aligned frame (``aligned = R @ world``).

    Attributes
    ----------
    rotation:
        ``(3, 3)`` world-to-aligned rotation.
    floor_z, ceiling_z:
        Heights (aligned z).
    rooms:
        The layout's rooms (``polygon``, ``walls``, ``openings``, heights).
    labels:
        ``(V,)`` per-vertex layout labels.
    """

    rotation: np.ndarray
    floor_z: float
    ceiling_z: float
    rooms: list[dict]
    labels: np.ndarray

    @property
    def up(self) -> np.ndarray:
        """World up (the aligned z axis in world coordinates)."""
        return self.rotation[2].copy()

    def to_aligned(self, p: np.ndarray) -> np.ndarray:
        """World points to the layout's aligned frame."""
        return np.asarray(p, float) @ self.rotation.T

    def to_world(self, p: np.ndarray) -> np.ndarray:
        """Aligned points (or vectors) to world coordinates."""
        return np.asarray(p, float) @ self.rotation

    def inside(self, xy: np.ndarray, margin: float) -> np.ndarray:
        """``(N,)`` whether aligned ``xy`` points lie in some room (grown by ``margin``)."""
        xy = np.atleast_2d(xy)
        if not self.rooms:  # no layout: nothing is known to be outside
            return np.ones(len(xy), bool)
        ok = np.zeros(len(xy), bool)
        for room in self.rooms:
            ok |= Polygon(np.asarray(room["polygon"], float)).contains_points(xy, radius=margin)
            ok |= Polygon(np.asarray(room["polygon"], float)[::-1]).contains_points(
                xy, radius=margin
            )
        return ok

    def wall_distance(self, xy: np.ndarray) -> np.ndarray:
        """``(N,)`` distance (m) of aligned ``xy`` points to the nearest wall segment."""
        xy = np.atleast_2d(np.asarray(xy, float))
        best = np.full(len(xy), np.inf)
        for room in self.rooms:
            for w in room["walls"]:
                a, b = np.asarray(w["start"], float), np.asarray(w["end"], float)
                ab = b - a
                t = np.clip(((xy - a) @ ab) / max(ab @ ab, 1e-12), 0.0, 1.0)
                best = np.minimum(best, np.linalg.norm(xy - (a + t[:, None] * ab), axis=1))
        return best

    def windows(self) -> list[dict[str, Any]]:
        """Every window opening as a rectangle on the outside face of its wall (world).

        Returns ``{room, wall, centre, half_u, half_v, normal, depth, into}`` dicts; the
        rectangle is where the synthetic generator puts its portal emitter: the
        outer face of the wall, ``depth`` behind the inner face. ``into`` names the room
        of the layout behind the opening (``""`` where it opens outside): such an
        opening lets in no daylight.
        """
        out = []
        for room in self.rooms:
            walls = {w["index"]: w for w in room["walls"]}
            for o in room.get("openings", []):
                if o.get("kind") != "window" or o.get("wall") not in walls:
                    continue
                w = walls[o["wall"]]
                a, b = np.asarray(w["start"], float), np.asarray(w["end"], float)
                t = (b - a) / max(np.linalg.norm(b - a), 1e-12)
                n = np.asarray(w["inward_normal"], float)
                depth = float(o.get("depth", 0.0))
                c2 = a + t * (o["s0"] + o["s1"]) / 2 - n * depth
                centre = np.array([c2[0], c2[1], (o["z0"] + o["z1"]) / 2])
                out.append(
                    {
                        "room": room.get("name", ""),
                        "wall": int(o["wall"]),
                        "centre": self.to_world(centre),
                        "half_u": self.to_world(
                            np.array([t[0], t[1], 0.0]) * (o["s1"] - o["s0"]) / 2
                        ),
                        "half_v": self.to_world(np.array([0.0, 0.0, (o["z1"] - o["z0"]) / 2])),
                        "normal": self.to_world(np.array([n[0], n[1], 0.0])),
                        "depth": depth,
                        "layout_source": o.get("source", ""),
                        "into": o.get("into", ""),
                    }
                )
        return out


def load_room_model(layout_dir: str | Path, n_vertices: int) -> RoomModel:
    """Read ``layout.json`` and ``layout_labels.ply`` (checked against the mesh size)."""
    d = Path(layout_dir)
    lj = d / "layout.json"
    if not lj.is_file():
        raise LightsError(f"{lj}: missing; run `reroom layout SCAN` first")
    try:
        lay = json.loads(lj.read_text())
        rotation = np.asarray(lay["rotation"], float).reshape(3, 3)
        floor_z, ceiling_z = float(lay["floor_z"]), float(lay["ceiling_z"])
        rooms = list(lay["rooms"])
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
        raise LightsError(f"{lj}: not a reroom layout ({exc})") from exc
    lp = d / "layout_labels.ply"
    if not lp.is_file():
        raise LightsError(f"{lp}: missing; run `reroom layout SCAN` first")
    labels = np.asarray(read_ply(lp).vertex_attributes["label"]).astype(np.int64)
    if len(labels) != n_vertices:
        raise LightsError(
            f"{lp}: {len(labels)} vertices, but the HDR mesh has {n_vertices}; "
            "run `reroom layout` again on the same scan"
        )
    return RoomModel(rotation, floor_z, ceiling_z, rooms, labels)


def room_model_without_layout(vertices: np.ndarray) -> RoomModel:
    """A stand-in room when ``reroom layout`` failed: the scan's own axes (+Z up), floor and
    ceiling at the mesh's 1st and 99th height percentiles, no rooms, every label 'other'."""
    z = np.asarray(vertices, float)[:, 2]
    lo, hi = np.percentile(z, [1, 99])
    return RoomModel(np.eye(3), float(lo), float(hi), [], np.full(len(z), OTHER, np.int64))


def lights_outside_room(
    anchors: dict[str, np.ndarray], room: RoomModel, margin: float = 0.3
) -> list[str]:
    """Names and positions, in words, of lights whose anchor lies outside the room.

    ``anchors`` maps light names to world points (a point light's position, a line's
    middle, ...). Outside means beyond every room polygon grown by ``margin`` (walls'
    depth) or more than ``margin`` below the floor or above the ceiling.
    """
    out = []
    for name, p in anchors.items():
        a = room.to_aligned(np.asarray(p, float))
        inside = room.inside(a[None, :2], margin)[0]
        if not inside or not (room.floor_z - margin <= a[2] <= room.ceiling_z + margin):
            out.append(
                f"light {name!r} at {np.round(np.asarray(p, float), 2).tolist()} is outside the room"
            )
    return out
