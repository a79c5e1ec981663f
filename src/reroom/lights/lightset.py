"""The light description: dataclasses, the ``lights.json`` schema, and user overrides.

A :class:`LightSet` holds the lights of a room (``area``, ``window``, ``line``,
``point``), the candidates that were rejected (each with a reason in words), and a
per-vertex ``light_id`` array (``-1`` = no light) that tells later stages which mesh
vertices belong to which area light or window surface. It is written as
``lights.json`` plus ``lights_vertices.npz`` (:func:`write_lights`) and read back by
:func:`load_lights`. The schema is documented in ``docs/lights.md``.

User overrides (:func:`apply_edits`) add, remove, move and retype lights; they come
from a JSON edit file or the ``reroom lights`` command-line options.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from reroom.errors import ReroomError
from reroom.io.atomic import atomic_path, atomic_write_json

__all__ = [
    "LIGHT_TYPES",
    "LIGHT_SOURCES",
    "Light",
    "Rejected",
    "LightSet",
    "LightsError",
    "apply_edits",
    "edits_from_options",
    "load_edits",
    "merge_edits",
    "load_lights",
    "parse_point",
    "write_lights",
]

LIGHT_TYPES = ("area", "window", "line", "point")
LIGHT_SOURCES = ("detected", "user", "layout", "localize")
FORMAT = "reroom-lights"
VERSION = 1
VERTICES_FILE = "lights_vertices.npz"

#: Geometry keys each light type must carry (world coordinates, metres).
GEOMETRY_KEYS: dict[str, tuple[str, ...]] = {
    "area": ("centroid", "normal", "area"),
    "window": ("centre", "half_u", "half_v", "normal"),
    "line": ("p0", "p1", "d_perp", "radius"),
    "point": ("position", "axis"),
}


class LightsError(ReroomError):
    """Bad light input: a missing stage output, a malformed ``lights.json`` or edit."""


@dataclass
class Light:
    """One light of the room.

    Attributes
    ----------
    name:
        Unique name (``area0``, ``window0``, ``line0``, ``point0``, or the user's).
    type:
        ``area`` | ``window`` | ``line`` | ``point``.
    source:
        ``detected`` | ``user`` | ``layout`` | ``localize``.
    geometry:
        Type-specific, world coordinates (metres): area ``centroid, normal, area``
        (m², plus ``size`` [long, short] in m and ``light_index`` into the per-vertex
        array); window ``centre, half_u, half_v, normal`` (inward); line ``p0, p1,
        d_perp, radius``; point ``position, axis``.
    evidence:
        What the decision rests on (vertex count, mean radiance, view consistency, ...).
    reason:
        The decision in words.
    """

    name: str
    type: str
    source: str
    geometry: dict[str, Any]
    evidence: dict[str, Any] = field(default_factory=dict)
    reason: str = ""

    def anchor(self) -> np.ndarray:
        """Reference point (world): area centroid, window centre, line middle, point position."""
        g = self.geometry
        if self.type == "area":
            return np.asarray(g["centroid"], float)
        if self.type == "window":
            return np.asarray(g["centre"], float)
        if self.type == "line":
            return (np.asarray(g["p0"], float) + np.asarray(g["p1"], float)) / 2
        return np.asarray(g["position"], float)

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict (``name, type, source, reason``, geometry keys, ``evidence``)."""
        return {
            "name": self.name,
            "type": self.type,
            "source": self.source,
            **_jsonable(self.geometry),
            "evidence": _jsonable(self.evidence),
            "reason": self.reason,
        }

    @staticmethod
    def from_json(d: dict[str, Any], where: str = "lights.json") -> Light:
        """Parse and validate one light (raises :class:`LightsError` naming ``where``)."""
        if not isinstance(d, dict):
            raise LightsError(f"{where}: a light must be an object, got {type(d).__name__}")
        name = d.get("name")
        typ = d.get("type")
        if not isinstance(name, str) or not name:
            raise LightsError(f"{where}: a light has no 'name'")
        if typ not in LIGHT_TYPES:
            raise LightsError(f"{where}: light {name!r} has type {typ!r}, not one of {LIGHT_TYPES}")
        source = d.get("source", "user")
        if source not in LIGHT_SOURCES:
            raise LightsError(
                f"{where}: light {name!r} has source {source!r}, not one of {LIGHT_SOURCES}"
            )
        geometry = {
            k: v for k, v in d.items() if k not in ("name", "type", "source", "evidence", "reason")
        }
        _check_geometry(name, typ, geometry, where)
        return Light(name, typ, source, geometry, dict(d.get("evidence", {})), d.get("reason", ""))


@dataclass
class Rejected:
    """A candidate that is not a light, and why."""

    name: str
    kind: str
    reason: str
    evidence: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict (``name, kind, reason, evidence``)."""
        return {
            "name": self.name,
            "kind": self.kind,
            "reason": self.reason,
            "evidence": _jsonable(self.evidence),
        }


@dataclass
class LightSet:
    """The lights of a scan.

    Attributes
    ----------
    lights:
        Accepted lights.
    rejected:
        Rejected candidates with reasons.
    vertex_light_id:
        ``(V,)`` int32 per mesh vertex: index into ``lights`` of the area light or
        window whose surface the vertex belongs to, ``-1`` for none.
    thresholds:
        The thresholds used, with how they were chosen.
    notes:
        Warnings in words (e.g. "no light found").
    meta:
        Inputs and options, for reproduction.
    """

    lights: list[Light] = field(default_factory=list)
    rejected: list[Rejected] = field(default_factory=list)
    vertex_light_id: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    thresholds: dict[str, Any] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    meta: dict[str, Any] = field(default_factory=dict)

    def by_name(self, name: str) -> Light:
        """The light called ``name`` (raises :class:`LightsError` if none)."""
        for light in self.lights:
            if light.name == name:
                return light
        raise LightsError(f"no light named {name!r}; lights are {[x.name for x in self.lights]}")

    def of_type(self, typ: str) -> list[Light]:
        """The lights of one type."""
        return [x for x in self.lights if x.type == typ]

    def area_vertex_index(self) -> np.ndarray:
        """``(V,)`` int32 per-vertex index among the *area* lights only (-1 = none).

        This is what a transfer computation consumes: ``k`` means the vertex emits
        as ``self.of_type("area")[k]``.
        """
        out = np.full(len(self.vertex_light_id), -1, np.int32)
        for k, i in enumerate(i for i, x in enumerate(self.lights) if x.type == "area"):
            out[self.vertex_light_id == i] = k
        return out

    def window_rectangles(self) -> list[dict[str, np.ndarray]]:
        """Every window as ``{name, centre, half_u, half_v, normal}`` (world, metres)."""
        return [
            {
                "name": w.name,
                **{k: np.asarray(w.geometry[k], float) for k in GEOMETRY_KEYS["window"]},
            }
            for w in self.of_type("window")
        ]

    def to_json(self) -> dict[str, Any]:
        """The ``lights.json`` object."""
        return {
            "format": FORMAT,
            "version": VERSION,
            "units": "m",
            "vertices_file": VERTICES_FILE,
            "n_vertices": int(len(self.vertex_light_id)),
            "lights": [x.to_json() for x in self.lights],
            "rejected": [x.to_json() for x in self.rejected],
            "thresholds": _jsonable(self.thresholds),
            "notes": list(self.notes),
            **_jsonable(self.meta),
        }

    def renumber(self) -> None:
        """Set every area light's and window's ``light_index`` to its index in :attr:`lights`.

        Call after removing lights: the per-vertex ids are indices into :attr:`lights`.
        """
        for i, light in enumerate(self.lights):
            if "light_index" in light.geometry:
                light.geometry["light_index"] = i


def write_lights(lights: LightSet, out_dir: str | Path) -> Path:
    """Write ``lights.json`` and ``lights_vertices.npz`` into ``out_dir`` atomically.

    Returns
    -------
    Path
        The ``lights.json`` path.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with atomic_path(out / VERTICES_FILE) as tmp:
        np.savez_compressed(tmp, light_id=np.asarray(lights.vertex_light_id, np.int32))
    return atomic_write_json(out / "lights.json", lights.to_json())


def load_lights(path: str | Path) -> LightSet:
    """Read a light set: ``lights.json`` (or the folder holding it) and its vertex array.

    Raises
    ------
    LightsError
        If the file is missing, not JSON, of another format, or a light is malformed.
    """
    p = Path(path)
    if p.is_dir():
        p = p / "lights.json"
    if not p.is_file():
        raise LightsError(f"{p}: no such file (run `reroom lights SCAN` first)")
    try:
        d = json.loads(p.read_text())
    except json.JSONDecodeError as exc:
        raise LightsError(f"{p}: not valid JSON ({exc})") from exc
    if not isinstance(d, dict) or d.get("format") != FORMAT:
        raise LightsError(f"{p}: not a reroom lights file (format {d.get('format')!r})")
    lights = [Light.from_json(x, str(p)) for x in d.get("lights", [])]
    rejected = [
        Rejected(x["name"], x.get("kind", ""), x.get("reason", ""), x.get("evidence", {}))
        for x in d.get("rejected", [])
    ]
    ids = np.full(int(d.get("n_vertices", 0)), -1, np.int32)
    vfile = p.parent / d.get("vertices_file", VERTICES_FILE)
    if vfile.is_file():
        with np.load(vfile) as z:
            ids = np.asarray(z["light_id"], np.int32)
    elif len(ids) and any(
        x.type in ("area", "window") and "light_index" in x.geometry for x in lights
    ):
        raise LightsError(f"{vfile}: missing (the per-vertex light ids of {p})")
    meta = {
        k: v
        for k, v in d.items()
        if k not in ("format", "version", "units", "vertices_file", "n_vertices", "lights")
        and k not in ("rejected", "thresholds", "notes")
    }
    return LightSet(lights, rejected, ids, d.get("thresholds", {}), list(d.get("notes", [])), meta)


# ---------------------------------------------------------------- user overrides


def parse_point(text: str, where: str = "--add-point") -> tuple[np.ndarray, str | None]:
    """Parse ``"x,y,z"`` or ``"x,y,z,name"`` into a position and an optional name."""
    parts = [s.strip() for s in text.split(",")]
    if len(parts) not in (3, 4):
        raise LightsError(f"{where}: expected x,y,z or x,y,z,name, got {text!r}")
    try:
        xyz = np.array([float(s) for s in parts[:3]])
    except ValueError as exc:
        raise LightsError(f"{where}: coordinates must be numbers, got {text!r}") from exc
    if not np.all(np.isfinite(xyz)):
        raise LightsError(f"{where}: coordinates must be finite, got {text!r}")
    return xyz, (parts[3] if len(parts) == 4 and parts[3] else None)


def _name_and_value(text: str, where: str) -> tuple[str, str]:
    """Split ``"NAME=value"`` (or ``"NAME value"``, ``"NAME:value"``)."""
    for sep in ("=", " ", ":"):
        if sep in text.strip():
            name, value = text.strip().split(sep, 1)
            if name.strip() and value.strip():
                return name.strip(), value.strip()
    raise LightsError(f"{where}: expected NAME=value, got {text!r}")


def edits_from_options(
    add_points: list[str] | None = None,
    remove: list[str] | None = None,
    move: list[str] | None = None,
    retype: list[str] | None = None,
) -> dict[str, Any]:
    """Turn command-line overrides into an edit dict for :func:`apply_edits`.

    Parameters
    ----------
    add_points:
        ``"x,y,z"`` or ``"x,y,z,name"`` each (world coordinates, metres).
    remove:
        Light names.
    move:
        ``"NAME=x,y,z"`` each.
    retype:
        ``"NAME=TYPE"`` each.
    """
    add = []
    for text in add_points or []:
        xyz, name = parse_point(text, "--add-point")
        light: dict[str, Any] = {"type": "point", "position": xyz.tolist()}
        if name:
            light["name"] = name
        add.append(light)
    moves = {}
    for text in move or []:
        name, value = _name_and_value(text, "--move")
        moves[name] = parse_point(value, "--move")[0].tolist()
    retypes = dict(_name_and_value(t, "--retype") for t in retype or [])
    return {"remove": list(remove or []), "move": moves, "retype": retypes, "add": add}


def merge_edits(*edits: dict[str, Any]) -> dict[str, Any]:
    """Concatenate several edit dicts (a file's, then the command line's)."""
    out: dict[str, Any] = {"remove": [], "move": {}, "retype": {}, "add": []}
    for e in edits:
        out["remove"] += list(e.get("remove", []))
        out["move"].update(e.get("move", {}))
        out["retype"].update(e.get("retype", {}))
        out["add"] += list(e.get("add", []))
    return out


def load_edits(path: str | Path) -> dict[str, Any]:
    """Read a ``lights_edit.json`` file (schema in ``docs/lights.md``)."""
    p = Path(path)
    if not p.is_file():
        raise LightsError(f"{p}: no such edit file")
    try:
        d = json.loads(p.read_text())
    except json.JSONDecodeError as exc:
        raise LightsError(f"{p}: not valid JSON ({exc})") from exc
    if not isinstance(d, dict):
        raise LightsError(f"{p}: an edit file must be a JSON object")
    unknown = set(d) - {"add", "remove", "move", "retype"}
    if unknown:
        raise LightsError(f"{p}: unknown keys {sorted(unknown)} (use add, remove, move, retype)")
    return d


def apply_edits(
    lights: LightSet, edits: dict[str, Any], up: np.ndarray | None = None, where: str = "edits"
) -> LightSet:
    """Apply user overrides in place and return ``lights``.

    Parameters
    ----------
    lights:
        The light set to change.
    edits:
        ``{"remove": [name, ...], "move": {name: [x, y, z]}, "retype": {name: type},
        "add": [light objects as in lights.json; ``source`` defaults to ``user``]}``,
        applied in the order remove, add, move, retype (so a light can be replaced
        by one of the same name, and an added light moved or retyped). Moving a light translates all its geometry (a point
        light's position, a line's ends, a window's centre, an area light's
        centroid; an area light's vertices stay where the mesh has them).
    up:
        World up, the default axis of added point lights.
    where:
        Named in error messages (the edit file or "command line").
    """
    up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, float)
    for name in edits.get("remove", []):
        lights.by_name(name)  # raises for an unknown name
        idx = next(i for i, x in enumerate(lights.lights) if x.name == name)
        removed = lights.lights.pop(idx)
        ids = lights.vertex_light_id
        ids[ids == idx] = -1
        ids[ids > idx] -= 1
        lights.rejected.append(
            Rejected(name, removed.type, "removed by the user", {"was": removed.reason})
        )
        lights.renumber()
    taken = {x.name for x in lights.lights}
    for k, d in enumerate(edits.get("add", [])):
        d = dict(d)
        d.setdefault("source", "user")
        d.setdefault("name", _fresh_name(d.get("type", "point"), taken))
        if d.get("type") == "point":
            d.setdefault("axis", up.tolist())
        d.setdefault("reason", "added by the user")
        light = Light.from_json(d, f"{where}: add[{k}]")
        if light.name in taken:
            raise LightsError(f"{where}: add[{k}]: a light named {light.name!r} already exists")
        taken.add(light.name)
        lights.lights.append(light)
    for name, xyz in dict(edits.get("move", {})).items():
        light = lights.by_name(name)
        target = np.asarray(xyz, float)
        if target.shape != (3,) or not np.all(np.isfinite(target)):
            raise LightsError(f"{where}: move {name!r}: expected [x, y, z], got {xyz!r}")
        _move(light, target)
        light.source = "user"
        light.reason += f"; moved by the user to {np.round(target, 3).tolist()}"
    for name, typ in dict(edits.get("retype", {})).items():
        light = lights.by_name(name)
        _retype(light, typ, up, where)
    return lights


def _move(light: Light, target: np.ndarray) -> None:
    g = light.geometry
    anchor_key = {"point": "position", "window": "centre", "area": "centroid"}.get(light.type)
    if light.type == "line":
        p0, p1 = np.asarray(g["p0"], float), np.asarray(g["p1"], float)
        shift = target - (p0 + p1) / 2
        g["p0"], g["p1"] = (p0 + shift).tolist(), (p1 + shift).tolist()
    else:
        g[anchor_key] = target.tolist()


def _retype(light: Light, typ: str, up: np.ndarray, where: str) -> None:
    """Change a light's type, deriving the new geometry from the old one."""
    if typ not in LIGHT_TYPES:
        raise LightsError(f"{where}: retype {light.name!r}: {typ!r} is not one of {LIGHT_TYPES}")
    if typ == light.type:
        return
    g = light.geometry
    centre = {
        "point": lambda: g["position"],
        "area": lambda: g["centroid"],
        "window": lambda: g["centre"],
        "line": lambda: ((np.asarray(g["p0"]) + np.asarray(g["p1"])) / 2).tolist(),
    }[light.type]()
    if typ == "point":
        new = {"position": list(centre), "axis": up.tolist()}
    elif typ == "line" and light.type == "area" and "axis_long" in g:
        half = np.asarray(g["axis_long"], float) * g["size"][0] / 2
        c = np.asarray(centre, float)
        d = half / (np.linalg.norm(half) + 1e-12)
        perp = up - np.dot(up, d) * d
        new = {
            "p0": (c - half).tolist(),
            "p1": (c + half).tolist(),
            "d_perp": (perp / (np.linalg.norm(perp) + 1e-12)).tolist(),
            "radius": float(g["size"][1] / 2),
        }
    elif typ == "area" and light.type in ("window",):
        hu, hv = np.asarray(g["half_u"], float), np.asarray(g["half_v"], float)
        new = {
            "centroid": list(centre),
            "normal": g["normal"],
            "area": float(4 * np.linalg.norm(hu) * np.linalg.norm(hv)),
        }
    elif typ == "window" and light.type == "area" and "axis_long" in g:
        lu = np.asarray(g["axis_long"], float)
        ls = np.asarray(g["axis_short"], float)
        new = {
            "centre": list(centre),
            "half_u": (lu * g["size"][0] / 2).tolist(),
            "half_v": (ls * g["size"][1] / 2).tolist(),
            "normal": g["normal"],
        }
    else:
        raise LightsError(
            f"{where}: retype {light.name!r} from {light.type} to {typ}: the geometry cannot be "
            "derived; remove it and add a new light instead"
        )
    keep = {k: g[k] for k in ("light_index",) if k in g and typ in ("area", "window")}
    light.geometry = {**new, **keep}
    light.reason += f"; retyped by the user from {light.type} to {typ}"
    light.type = typ
    light.source = "user"


def _fresh_name(typ: str, taken: set[str]) -> str:
    i = 0
    while f"{typ}{i}" in taken:
        i += 1
    return f"{typ}{i}"


def _check_geometry(name: str, typ: str, g: dict[str, Any], where: str) -> None:
    for key in GEOMETRY_KEYS[typ]:
        if key not in g:
            raise LightsError(f"{where}: {typ} light {name!r} has no {key!r}")
        value = np.asarray(g[key], dtype=float)
        expected = () if key in ("area", "radius") else (3,)
        if value.shape != expected or not np.all(np.isfinite(value)):
            raise LightsError(
                f"{where}: {typ} light {name!r}: {key!r} must be "
                f"{'a number' if not expected else '[x, y, z]'}, got {g[key]!r}"
            )


def _jsonable(obj: Any) -> Any:
    """Numpy scalars and arrays to plain Python, recursively; floats rounded to 6 digits."""
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, np.bool_ | bool):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, float | np.floating):
        # JSON has no NaN or infinity: an unmeasured value is null.
        return round(float(obj), 6) if np.isfinite(obj) else None
    return obj
