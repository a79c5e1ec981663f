"""Scene presets: ``box``, ``box_points``, ``furnished``, ``lshape`` and ``tworooms``.

``box`` is an empty 5 x 4 x 2.7 m room with a ceiling panel and a window;
``box_points`` is the same room with two point lights added (for light localization):
a floor lamp (isotropic bulb in a fabric shade) in a corner and a recessed downlight
(no visible fitting, the ``ies_light_1`` profile). ``furnished`` has every light type
(panel, baffled tube, floor lamp, IES downlight, window) and furniture; ``lshape`` and
``tworooms`` test non-rectangular and multi-room layouts.

Each preset is a :class:`SceneSpec`: the parts (geometry + label + material +
emission), the light list with every parameter, the layout, the outdoor
environment, and the waypoints of the scanning walk. Radiometric units are
linear scene-referred RGB; the HDRIs are relative, so each window has a scale.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from reroom.synth.geometry import Part, Piece, box, cylinder, frustum_shell, grid_rect
from reroom.synth.room import Opening, RoomSpec, build_room, room_layout

PRESETS = ("box", "box_points", "furnished", "lshape", "tworooms")

#: Linear diffuse albedos per surface class (measured paint/wood values are in this range).
MATERIALS: dict[str, dict] = {
    "wall": {"type": "diffuse", "albedo": [0.72, 0.68, 0.60]},
    "floor": {"type": "diffuse", "texture": "wood_floor", "albedo": [0.42, 0.28, 0.16]},
    "ceiling": {"type": "diffuse", "albedo": [0.82, 0.82, 0.80]},
    "door": {"type": "diffuse", "albedo": [0.50, 0.52, 0.55]},
    "baseboard": {"type": "diffuse", "albedo": [0.88, 0.88, 0.86]},
    "window": {"type": "diffuse", "albedo": [0.80, 0.80, 0.78]},
    "sofa": {"type": "diffuse", "albedo": [0.20, 0.28, 0.45]},
    "table": {"type": "roughplastic", "albedo": [0.35, 0.22, 0.12], "alpha": 0.3},
    "cabinet": {"type": "roughplastic", "albedo": [0.60, 0.15, 0.12], "alpha": 0.25},
    "chair": {"type": "diffuse", "albedo": [0.30, 0.30, 0.30]},
    "bed": {"type": "diffuse", "albedo": [0.70, 0.65, 0.55]},
    "fixture": {"type": "diffuse", "albedo": [0.85, 0.85, 0.85]},
    # Louvres, housings and shade linings are dark, as in many real fittings: a bright
    # lining would light the room through tiny, intense reflections that a path tracer
    # only finds by chance (fireflies), while the light leaving the fitting would be the
    # same kind of directional distribution either way.
    "louvre": {"type": "diffuse", "albedo": [0.04, 0.04, 0.04]},
    "shade": {"type": "diffuse", "albedo": [0.55, 0.50, 0.40]},
    "shade_lining": {"type": "diffuse", "albedo": [0.04, 0.04, 0.04]},
    "pole": {"type": "diffuse", "albedo": [0.10, 0.10, 0.10]},
    "panel": {"type": "diffuse", "albedo": [0.80, 0.80, 0.80]},
    "portal": {"type": "black"},
}


@dataclass
class SceneSpec:
    """Everything the generator needs to render a room and write its ground truth."""

    name: str
    rooms: list[RoomSpec]
    parts: list[Part]
    lights: list[dict]
    waypoints: np.ndarray
    hdri: str
    mesh_spacing: float
    layout: dict = field(default_factory=dict)

    def part(self, name: str) -> Part:
        for p in self.parts:
            if p.name == name:
                return p
        raise KeyError(name)


def _panel(
    name: str,
    x0: float,
    x1: float,
    y0: float,
    y1: float,
    zc: float,
    h: float,
    radiance: list[float],
) -> tuple[list[Part], dict]:
    """A recessed ceiling panel: emitting face 2 cm below the ceiling plus its rim."""
    z = zc - 0.02
    face = grid_rect([x0, y0, z], [0, 1, 0], [1, 0, 0], y1 - y0, x1 - x0, h)  # faces -z
    rim = box([x0, y0, z], [x1, y1, zc], h, skip=("-z", "+z"))
    parts = [
        Part(name, face, "light", MATERIALS["panel"], emission=list(radiance)),
        Part(f"{name}_rim", rim, "light", MATERIALS["fixture"]),
    ]
    corners = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]])
    light = {
        "name": name,
        "type": "area",
        "part": name,
        "radiance": list(radiance),
        "corners": corners.tolist(),
        "normal": [0.0, 0.0, -1.0],
    }
    return parts, light


def _tube(
    name: str, x0: float, x1: float, y: float, zc: float, h: float, radiance: list[float]
) -> tuple[list[Part], dict]:
    """A fluorescent tube under a ceiling housing, between two baffles that block sideways light."""
    r = 0.016
    zt = zc - 0.10
    tube = cylinder([x0, y, zt], [x1, y, zt], r, sections=16, h=h)
    housing = box([x0 - 0.05, y - 0.08, zc - 0.05], [x1 + 0.05, y + 0.08, zc], h, skip=("+z",))
    baffles = Piece.concat(
        [
            box(
                [x0 - 0.05, y - 0.08, zc - 0.16], [x1 + 0.05, y - 0.07, zc - 0.05], h, skip=("+z",)
            ),
            box(
                [x0 - 0.05, y + 0.07, zc - 0.16], [x1 + 0.05, y + 0.08, zc - 0.05], h, skip=("+z",)
            ),
        ]
    )
    parts = [
        Part(name, tube, "light", MATERIALS["panel"], emission=list(radiance)),
        Part(f"{name}_housing", housing, "furniture", MATERIALS["louvre"]),
        Part(f"{name}_baffles", baffles, "furniture", MATERIALS["louvre"]),
    ]
    light = {
        "name": name,
        "type": "line",
        "part": name,
        "p0": [x0, y, zt],
        "p1": [x1, y, zt],
        "radius": r,
        "radiance": list(radiance),
        "baffles": {"half_gap": 0.07, "bottom_below_ceiling": 0.16},
    }
    return parts, light


def _floor_lamp(
    name: str, x: float, y: float, h: float, power: float, color: list[float]
) -> tuple[list[Part], dict]:
    """A floor lamp: pole, fabric shade open at top and bottom, isotropic bulb inside."""
    pole = cylinder([x, y, 0.0], [x, y, 1.36], 0.015, sections=12, h=h)
    base = cylinder([x, y, 0.0], [x, y, 0.03], 0.15, sections=24, h=h)
    outer, lining = frustum_shell(
        [x, y, 1.36], 0.22, 0.14, 0.28, 0.006, sections=40, rings=5, split=True
    )
    parts = [
        Part(f"{name}_pole", Piece.concat([pole, base]), "furniture", MATERIALS["pole"]),
        Part(f"{name}_shade", outer, "furniture", MATERIALS["shade"]),
        Part(f"{name}_shade_lining", lining, "furniture", MATERIALS["shade_lining"]),
    ]
    light = {
        "name": name,
        "type": "point",
        "position": [x, y, 1.50],
        "up": [0.0, 0.0, 1.0],
        "profile": "isotropic",
        "power": power,
        "color": list(color),
    }
    return parts, light


def _downlight(
    name: str, x: float, y: float, zc: float, profile: str, power: float, color: list[float]
) -> tuple[list[Part], dict]:
    light = {
        "name": name,
        "type": "point",
        "position": [x, y, zc - 0.03],
        "up": [0.0, 0.0, 1.0],
        "profile": profile,
        "power": power,
        "color": list(color),
    }
    return [], light


def _table(x0: float, x1: float, y0: float, y1: float, h: float, name: str = "table") -> list[Part]:
    top = box([x0, y0, 0.72], [x1, y1, 0.76], h)
    legs = [
        box([lx, ly, 0.0], [lx + 0.05, ly + 0.05, 0.72], h, skip=("-z", "+z"))
        for lx in (x0 + 0.05, x1 - 0.10)
        for ly in (y0 + 0.05, y1 - 0.10)
    ]
    return [Part(name, Piece.concat([top, *legs]), "furniture", MATERIALS["table"])]


def _chair(x: float, y: float, facing: float, h: float, name: str) -> list[Part]:
    """A simple chair at (x, y), its back on the side opposite ``facing`` (+1: back at -y)."""
    s = 0.22
    seat = box([x - s, y - s, 0.43], [x + s, y + s, 0.47], h)
    legs = [
        box([x + dx, y + dy, 0.0], [x + dx + 0.04, y + dy + 0.04, 0.43], h, skip=("-z", "+z"))
        for dx in (-s, s - 0.04)
        for dy in (-s, s - 0.04)
    ]
    by = y - s if facing > 0 else y + s - 0.04
    back = box([x - s, by, 0.47], [x + s, by + 0.04, 0.90], h)
    return [Part(name, Piece.concat([seat, *legs, back]), "furniture", MATERIALS["chair"])]


def _sofa(x0: float, x1: float, y0: float, y1: float, h: float) -> list[Part]:
    """A sofa against the wall at x = x0 (back along x0)."""
    seat = box([x0, y0, 0.0], [x1, y1, 0.42], h, skip=("-z",))
    back = box([x0, y0, 0.42], [x0 + 0.22, y1, 0.85], h)
    arms = [box([x0 + 0.22, yy, 0.42], [x1, yy + 0.18, 0.62], h) for yy in (y0, y1 - 0.18)]
    return [Part("sofa", Piece.concat([seat, back, *arms]), "furniture", MATERIALS["sofa"])]


def _assemble(
    name: str,
    rooms: list[RoomSpec],
    extra: list[Part],
    lights: list[dict],
    waypoints: list,
    hdri: str,
    h: float,
    ceiling_holes: dict[str, list],
    window_scale: float,
) -> SceneSpec:
    parts: list[Part] = []
    layout_rooms = []
    for room in rooms:
        rp, portals = build_room(room, h, MATERIALS, ceiling_holes=ceiling_holes.get(room.name, ()))
        parts += rp
        layout_rooms.append(room_layout(room, (0.08, 0.012)))
        for portal in portals:
            c = np.asarray(portal["corners"])
            o, u_end, v_end = c[0], c[1], c[3]
            u = u_end - o
            v = v_end - o
            piece = grid_rect(o, u, v, np.linalg.norm(u), np.linalg.norm(v), 10.0)
            if np.dot(np.cross(u, v), portal["normal"]) < 0:  # face the room
                piece = grid_rect(o, v, u, np.linalg.norm(v), np.linalg.norm(u), 10.0)
            pname = portal["name"]
            parts.append(
                Part(f"{pname}_portal", piece, "window", MATERIALS["portal"], in_scan=False)
            )
            lights.append(
                {
                    "name": pname,
                    "type": "window",
                    "part": f"{pname}_portal",
                    "corners": c.tolist(),
                    "normal": np.asarray(portal["normal"]).tolist(),
                    "hdri": hdri,
                    "scale": window_scale,
                    "rotation_deg": 0.0,
                }
            )
    parts += extra
    layout = {"rooms": layout_rooms, "up": [0.0, 0.0, 1.0], "units": "m"}
    return SceneSpec(name, rooms, parts, lights, np.asarray(waypoints, float), hdri, h, layout)


def build_preset(name: str, hdri: str = "courtyard", mesh_spacing: float = 0.08) -> SceneSpec:
    """Build one of :data:`PRESETS` (see the module docstring for what each holds).

    Parameters
    ----------
    name:
        The preset.
    hdri:
        Outdoor environment seen through the windows: a shipped HDRI name or an
        ``.exr`` path.
    mesh_spacing:
        Maximum edge length of the generated meshes, metres.
    """
    h = mesh_spacing
    warm = [1.0, 0.82, 0.62]
    cool = [0.92, 0.97, 1.0]
    if name in ("box", "box_points"):
        room = RoomSpec(
            np.array([[0, 0], [5, 0], [5, 4], [0, 4]], float),
            0.0,
            2.7,
            [Opening("window", 1, 1.3, 2.7, 0.9, 2.1, 0.2, "window0")],
            "room",
        )
        panel_parts, panel = _panel("ceiling_panel", 2.2, 2.8, 1.7, 2.3, 2.7, h, [6.0, 6.0, 6.0])
        box_parts, box_lights = list(panel_parts), [panel]
        if name == "box_points":
            p, light = _floor_lamp("floor_lamp", 4.45, 3.45, h, 10.0, warm)
            box_parts += p
            box_lights.append(light)
            p, light = _downlight("downlight", 1.2, 1.0, 2.7, "ies_light_1", 8.0, cool)
            box_parts += p
            box_lights.append(light)
        return _assemble(
            name,
            [room],
            box_parts,
            box_lights,
            [[1.3, 1.2], [3.7, 1.2], [3.7, 2.8], [1.3, 2.8]],
            hdri,
            h,
            {"room": [(2.2, 2.8, 1.7, 2.3)]},
            1.0,
        )

    if name == "furnished":
        room = RoomSpec(
            np.array([[0, 0], [6, 0], [6, 4.5], [0, 4.5]], float),
            0.0,
            2.7,
            [
                Opening("window", 0, 3.6, 5.2, 0.85, 2.15, 0.2, "window0"),
                Opening("door", 2, 4.4, 5.3, 0.0, 2.05, 0.03, "door0"),
            ],
            "room",
        )
        extra: list[Part] = []
        lights: list[dict] = []
        p, light = _panel("ceiling_panel", 2.2, 2.8, 1.95, 2.55, 2.7, h, [5.0, 5.0, 5.0])
        extra += p
        lights.append(light)
        p, light = _tube("tube", 3.8, 5.0, 3.4, 2.7, h, [12.0, 12.5, 13.0])
        extra += p
        lights.append(light)
        p, light = _floor_lamp("floor_lamp", 0.55, 0.55, h, 10.0, warm)
        extra += p
        lights.append(light)
        p, light = _downlight("downlight", 5.3, 3.9, 2.7, "ies_light_2", 8.0, cool)
        extra += p
        lights.append(light)
        extra += _table(2.3, 3.7, 1.9, 2.7, h)
        extra += _chair(2.7, 1.5, 1, h, "chair0") + _chair(3.3, 3.1, -1, h, "chair1")
        extra += _sofa(0.08, 1.0, 1.3, 3.3, h)
        extra.append(
            Part(
                "cabinet",
                box([5.5, 1.4, 0.0], [5.95, 2.4, 1.2], h, skip=("-z",)),
                "furniture",
                MATERIALS["cabinet"],
            )
        )
        return _assemble(
            name,
            [room],
            extra,
            lights,
            [[1.6, 1.15], [4.6, 1.15], [4.6, 3.45], [1.6, 3.45]],
            hdri,
            h,
            {"room": [(2.2, 2.8, 1.95, 2.55)]},
            1.0,
        )

    if name == "lshape":
        poly = np.array([[0, 0], [6, 0], [6, 3], [3, 3], [3, 5.5], [0, 5.5]], float)
        room = RoomSpec(
            poly,
            0.0,
            2.6,
            [
                Opening("window", 0, 2.0, 3.4, 0.9, 2.0, 0.2, "window0"),
                Opening("door", 4, 1.0, 1.9, 0.0, 2.05, 0.03, "door0"),
            ],
            "room",
        )
        extra, lights = [], []
        p, light = _panel("ceiling_panel", 4.2, 4.8, 1.2, 1.8, 2.6, h, [5.0, 5.0, 5.0])
        extra += p
        lights.append(light)
        p, light = _tube("tube", 0.9, 2.1, 4.3, 2.6, h, [12.0, 12.5, 13.0])
        extra += p
        lights.append(light)
        extra += _table(0.5, 1.5, 0.4, 1.1, h)
        return _assemble(
            name,
            [room],
            extra,
            lights,
            [[1.0, 1.0], [5.0, 1.0], [5.0, 2.1], [2.1, 2.1], [2.1, 4.6], [1.0, 4.6]],
            hdri,
            h,
            {"room": [(4.2, 4.8, 1.2, 1.8)]},
            1.0,
        )

    if name == "tworooms":
        a = RoomSpec(
            np.array([[0, 0], [4, 0], [4, 4.5], [0, 4.5]], float),
            0.0,
            2.7,
            [
                Opening("window", 0, 1.2, 2.6, 0.9, 2.1, 0.2, "window0"),
                Opening("passage", 1, 1.8, 2.7, 0.0, 2.1, 0.15, "passage0"),
            ],
            "roomA",
        )
        b = RoomSpec(
            np.array([[4.15, 0], [8.15, 0], [8.15, 4.5], [4.15, 4.5]], float),
            0.0,
            2.7,
            [
                Opening("window", 2, 1.0, 2.4, 0.9, 2.1, 0.2, "window1"),
                Opening("door", 1, 3.0, 3.9, 0.0, 2.05, 0.03, "door0"),
                Opening("passage", 3, 1.8, 2.7, 0.0, 2.1, 0.15, "passage0", build_tunnel=False),
            ],
            "roomB",
        )
        extra, lights = [], []
        p, light = _panel("ceiling_panel", 1.7, 2.3, 1.95, 2.55, 2.7, h, [5.0, 5.0, 5.0])
        extra += p
        lights.append(light)
        p, light = _tube("tube", 5.6, 6.8, 2.25, 2.7, h, [12.0, 12.5, 13.0])
        extra += p
        lights.append(light)
        p, light = _floor_lamp("floor_lamp", 7.65, 3.95, h, 10.0, warm)
        extra += p
        lights.append(light)
        extra += _table(0.5, 1.7, 3.2, 4.0, h)
        extra.append(
            Part(
                "bed",
                box([6.2, 0.1, 0.0], [8.05, 1.7, 0.5], h, skip=("-z",)),
                "furniture",
                MATERIALS["bed"],
            )
        )
        wps = [
            [1.2, 1.2],
            [2.9, 1.2],
            [2.9, 2.2],
            [5.3, 2.2],
            [5.3, 1.9],
            [7.0, 1.9],
            [7.0, 3.3],
            [5.3, 3.3],
            [5.3, 2.3],
            [2.9, 2.3],
            [2.9, 3.3],
            [1.2, 3.3],
        ]
        return _assemble(
            name, [a, b], extra, lights, wps, hdri, h, {"roomA": [(1.7, 2.3, 1.95, 2.55)]}, 1.0
        )

    raise ValueError(f"unknown preset {name!r}; choose one of {PRESETS}")
