"""The edit format shared by the model side, the synthetic-truth side and ``reroom run``.

An edit file is JSON, ``{"format": "reroom-edits", "version": 1, "edits": [OP, ...]}``; a
*named edit set* is a list of OPs applied in order (positions in the scan's mesh frame,
metres, +Z up; colours linear RGB). The operations (see docs/edit.md for the semantics):

* ``{"op": "empty"}``
* ``{"op": "repaint", "target": T, "color": [r, g, b]}`` or
  ``{"op": "repaint", "target": T, "texture": FILE, "metres_per_tile": 1.0}``
* ``{"op": "light", "name": N, "off": true | "scale": s | "color": [r, g, b] | "move_to": [x, y, z]}``
* ``{"op": "add_light", "name": N, "type": "point", "position": P, "intensity": I,
  "color": [r, g, b], "ies": optional}``
* ``{"op": "window", "name": N, "hdri": H, "was": optional H0, "scale": 1.0}``
* ``{"op": "insert", "object": O, "position": P, "rotation_deg": 0, "scale": 1, "color": [r, g, b]}``

:func:`parse_edits` checks what can be checked without a room (types, ranges, files that
must load) and returns normalised copies (defaults filled in); :func:`check_names` checks
the names against a room's lights and materials. Every problem is an :class:`EditError`
whose message starts with the edit file (or ``<edits>``) and the edit's index.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from reroom.errors import ReroomError

__all__ = [
    "as_ops",
    "EDIT_FORMAT",
    "EDIT_VERSION",
    "LABEL_TARGETS",
    "OPS",
    "EditError",
    "check_names",
    "edit_document",
    "load_edits",
    "op_from_shortcut",
    "parse_edits",
]

EDIT_FORMAT = "reroom-edits"
EDIT_VERSION = 1
OPS = ("empty", "repaint", "light", "add_light", "window", "insert")
#: Feature labels a repaint may target besides the model's material clusters.
LABEL_TARGETS = ("wall", "floor", "ceiling", "door", "baseboard")

_KEYS: dict[str, tuple[set[str], set[str]]] = {  # op -> (required, optional) keys
    "empty": (set(), set()),
    "repaint": ({"target"}, {"color", "texture", "metres_per_tile"}),
    "light": ({"name"}, {"off", "scale", "color", "move_to"}),
    "add_light": ({"name", "position", "intensity"}, {"type", "color", "ies", "up"}),
    "window": ({"name", "hdri"}, {"was", "scale"}),
    "insert": ({"object", "position"}, {"rotation_deg", "scale", "color", "name"}),
}


class EditError(ReroomError):
    """An edit (or edit file) that is malformed or names something the room does not have."""


def _where(source: str, i: int | None, op: Mapping[str, Any] | None = None) -> str:
    if i is None:
        return source
    kind = op.get("op") if isinstance(op, Mapping) else None
    return f"{source}: edit {i}" + (f" ({kind})" if isinstance(kind, str) else "")


def _number(
    where: str, op: Mapping[str, Any], key: str, lo: float | None = None, positive: bool = False
) -> float:
    v = op[key]
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise EditError(f"{where}: {key!r} must be a finite number, not {v!r}")
    if positive and v <= 0:
        raise EditError(f"{where}: {key!r} must be > 0, not {v!r}")
    if lo is not None and v < lo:
        raise EditError(f"{where}: {key!r} must be >= {lo}, not {v!r}")
    return float(v)


def _vec3(
    where: str, op: Mapping[str, Any], key: str, lo: float | None = None, hi: float | None = None
) -> list[float]:
    v = op[key]
    ok = isinstance(v, Sequence) and not isinstance(v, str) and len(v) == 3
    if ok:
        ok = all(
            isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x) for x in v
        )
    if not ok:
        raise EditError(f"{where}: {key!r} must be 3 finite numbers, not {v!r}")
    out = [float(x) for x in v]
    if lo is not None and min(out) < lo or hi is not None and max(out) > hi:
        raise EditError(f"{where}: {key!r} must lie in [{lo}, {hi}], not {out}")
    return out


def _string(where: str, op: Mapping[str, Any], key: str) -> str:
    v = op[key]
    if not isinstance(v, str) or not v.strip():
        raise EditError(f"{where}: {key!r} must be a non-empty string, not {v!r}")
    return v


def _resolve(path: str, base: Path | None) -> str:
    """A relative file name resolves against the edit file's folder (bundled names stay)."""
    p = Path(path)
    if base is not None and not p.is_absolute() and (base / p).exists():
        return str(base / p)
    return path


def _check_hdri(where: str, key: str, name: str) -> None:
    from reroom.data import hdri_path
    from reroom.errors import ScanError
    from reroom.io.images import read_exr

    try:
        path = hdri_path(name)
    except FileNotFoundError as exc:
        raise EditError(f"{where}: {key!r}: {exc}") from exc
    try:
        img = read_exr(path)
    except ScanError as exc:
        raise EditError(f"{where}: {key!r}: {exc}") from exc
    if img.ndim != 3 or img.shape[2] < 3 or img.shape[1] != 2 * img.shape[0]:
        raise EditError(f"{where}: {key!r}: {path} is not a 2:1 lat-long RGB image {img.shape}")


def _check_texture(where: str, path: str) -> None:
    p = Path(path)
    if p.suffix.lower() not in (".png", ".jpg", ".jpeg", ".exr"):
        raise EditError(f"{where}: texture {path} must be a .png, .jpg or .exr image")
    if not p.is_file():
        raise EditError(f"{where}: texture {path} is missing")
    try:
        from reroom.io.images import read_exr, read_rgb8

        img = read_exr(p) if p.suffix.lower() == ".exr" else read_rgb8(p)
    except Exception as exc:
        raise EditError(f"{where}: texture {path} does not load ({exc})") from exc
    if img.ndim != 3 or min(img.shape[:2]) < 1:
        raise EditError(f"{where}: texture {path} is not an RGB image")


def _check_op(op: Any, i: int, source: str, base: Path | None) -> dict[str, Any]:
    where = _where(source, i, op if isinstance(op, Mapping) else None)
    if not isinstance(op, Mapping):
        raise EditError(f"{where}: an edit must be a JSON object, not {type(op).__name__}")
    kind = op.get("op")
    if kind not in OPS:
        raise EditError(f"{where}: unknown op {kind!r}; the ops are {list(OPS)}")
    required, optional = _KEYS[kind]
    keys = {k for k in op if k != "op" and not str(k).startswith("_") and k != "comment"}
    missing = required - keys
    if missing:
        raise EditError(f"{where}: missing {sorted(missing)}")
    unknown = keys - required - optional
    if unknown:
        raise EditError(
            f"{where}: unknown keys {sorted(unknown)}; {kind!r} takes {sorted(required | optional)}"
        )
    out: dict[str, Any] = {"op": kind}
    if kind == "repaint":
        out["target"] = _string(where, op, "target")
        if ("color" in op) == ("texture" in op):
            raise EditError(f"{where}: give exactly one of 'color' and 'texture'")
        if "color" in op:
            out["color"] = _vec3(where, op, "color", 0.0, 1.0)
        else:
            out["texture"] = _resolve(_string(where, op, "texture"), base)
            _check_texture(where, out["texture"])
            out["metres_per_tile"] = (
                _number(where, op, "metres_per_tile", positive=True)
                if "metres_per_tile" in op
                else 1.0
            )
    elif kind == "light":
        out["name"] = _string(where, op, "name")
        if not keys & {"off", "scale", "color", "move_to"}:
            raise EditError(f"{where}: give at least one of 'off', 'scale', 'color', 'move_to'")
        if "off" in op:
            if not isinstance(op["off"], bool):
                raise EditError(f"{where}: 'off' must be true or false, not {op['off']!r}")
            out["off"] = op["off"]
        if "scale" in op:
            out["scale"] = _number(where, op, "scale", lo=0.0)
        if "color" in op:
            out["color"] = _vec3(where, op, "color", 0.0)
        if "move_to" in op:
            out["move_to"] = _vec3(where, op, "move_to")
    elif kind == "add_light":
        out["name"] = _string(where, op, "name")
        out["type"] = op.get("type", "point")
        if out["type"] != "point":
            raise EditError(f"{where}: only 'point' lights can be added, not {out['type']!r}")
        out["position"] = _vec3(where, op, "position")
        out["intensity"] = _number(where, op, "intensity", lo=0.0)
        out["color"] = _vec3(where, op, "color", 0.0) if "color" in op else [1.0, 1.0, 1.0]
        out["up"] = _vec3(where, op, "up") if "up" in op else [0.0, 0.0, 1.0]
        if "ies" in op and op["ies"] is not None:
            from reroom.data import ies_path
            from reroom.io.ies import read_ies

            name = _resolve(_string(where, op, "ies"), base)
            try:
                read_ies(ies_path(name))
            except FileNotFoundError as exc:
                raise EditError(f"{where}: 'ies': {exc}") from exc
            except ReroomError as exc:
                raise EditError(f"{where}: 'ies': {exc}") from exc
            out["ies"] = name
    elif kind == "window":
        out["name"] = _string(where, op, "name")
        out["hdri"] = _resolve(_string(where, op, "hdri"), base)
        _check_hdri(where, "hdri", out["hdri"])
        if op.get("was") is not None:
            out["was"] = _resolve(_string(where, op, "was"), base)
            _check_hdri(where, "was", out["was"])
        out["scale"] = _number(where, op, "scale", lo=0.0) if "scale" in op else 1.0
    elif kind == "insert":
        from reroom.edit.furniture import BUNDLED_OBJECTS, DEFAULT_COLORS, object_mesh

        obj = _resolve(_string(where, op, "object"), base)
        try:
            object_mesh(obj)  # loads (and so checks) a mesh file; names the bundled ones
        except ReroomError as exc:
            raise EditError(f"{where}: {exc}") from exc
        out["object"] = obj
        out["position"] = _vec3(where, op, "position")
        out["rotation_deg"] = _number(where, op, "rotation_deg") if "rotation_deg" in op else 0.0
        out["scale"] = _number(where, op, "scale", positive=True) if "scale" in op else 1.0
        default = DEFAULT_COLORS.get(obj, (0.6, 0.6, 0.6)) if obj in BUNDLED_OBJECTS else None
        out["color"] = (
            _vec3(where, op, "color", 0.0, 1.0) if "color" in op else list(default or (0.6,) * 3)
        )
        out["name"] = _string(where, op, "name") if "name" in op else f"{Path(obj).stem}{i}"
    return out


def parse_edits(
    edits: Any, source: str | Path = "<edits>", base_dir: str | Path | None = None
) -> list[dict[str, Any]]:
    """Check and normalise edits: a document, a list of OPs, or one OP.

    Parameters
    ----------
    edits:
        ``{"format": "reroom-edits", "version": 1, "edits": [...]}``, a list of OP
        dicts, or a single OP dict.
    source:
        What to call the edits in error messages (the file they came from).
    base_dir:
        Folder that relative texture, HDRI, IES and mesh file names resolve against
        (the edit file's folder); names that exist relative to the working
        directory also work.

    Returns
    -------
    list of dict
        Normalised copies with every default filled in (``insert`` gets a ``name``).

    Raises
    ------
    EditError
        For an unknown op, a missing or unknown key, a value of the wrong type or
        range, or a file (texture, HDRI, IES, mesh) that is missing or does not load.
    """
    source = str(source)
    base = Path(base_dir) if base_dir is not None else None
    if isinstance(edits, Mapping) and "op" not in edits:
        fmt = edits.get("format")
        if fmt != EDIT_FORMAT:
            raise EditError(f"{source}: 'format' must be {EDIT_FORMAT!r}, not {fmt!r}")
        if edits.get("version") != EDIT_VERSION:
            raise EditError(
                f"{source}: version {edits.get('version')!r} is not supported "
                f"(this reroom reads version {EDIT_VERSION})"
            )
        ops = edits.get("edits")
    elif isinstance(edits, Mapping):
        ops = [edits]
    else:
        ops = edits
    if not isinstance(ops, list | tuple):
        raise EditError(f"{source}: 'edits' must be a list of operations")
    out = [_check_op(op, i, source, base) for i, op in enumerate(ops)]
    names = [o["name"] for o in out if o["op"] == "add_light"]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise EditError(f"{source}: lights added twice: {sorted(dup)}")
    return out


def as_ops(edits: Any) -> tuple[list[dict[str, Any]], str]:
    """Parsed OPs and their source name from a path to an edit file, or anything
    :func:`parse_edits` takes (source ``<edits>``)."""
    if isinstance(edits, str | Path):
        return load_edits(edits), str(edits)
    return parse_edits(edits), "<edits>"


def load_edits(path: str | Path) -> list[dict[str, Any]]:
    """Read and check an edit file (see :func:`parse_edits`).

    Raises
    ------
    EditError
        When the file is missing, is not JSON, or holds bad edits (names the file).
    """
    p = Path(path)
    try:
        doc = json.loads(p.read_text())
    except OSError as exc:
        raise EditError(f"{p}: edit file is missing or unreadable ({exc.strerror})") from exc
    except ValueError as exc:
        raise EditError(f"{p}: edit file is not valid JSON ({exc})") from exc
    return parse_edits(doc, p, p.parent)


def edit_document(edits: Iterable[Mapping[str, Any]]) -> dict[str, Any]:
    """The edit-file document of a list of OPs (to write with ``atomic_write_json``)."""
    return {"format": EDIT_FORMAT, "version": EDIT_VERSION, "edits": [dict(e) for e in edits]}


def check_names(
    edits: Sequence[Mapping[str, Any]],
    lights: Mapping[str, str],
    targets: Iterable[str],
    source: str = "<edits>",
) -> None:
    """Check the names of parsed edits against a room, in order.

    Parameters
    ----------
    lights:
        Light name -> type (``area``, ``window``, ``point``, ``line``) of the room;
        lights added by earlier ``add_light`` edits join it as they come.
    targets:
        Repaint targets the room has (labels and material clusters).

    Raises
    ------
    EditError
        For a light, window or repaint target that does not exist (listing those that
        do), a light added under an existing name, a ``window`` edit on a light that is
        not a window, or ``move_to`` on a window.
    """
    known = dict(lights)
    targets = sorted(set(targets))
    for i, op in enumerate(edits):
        where = _where(source, i, op)
        kind = op["op"]
        if kind == "repaint" and op["target"] not in targets:
            raise EditError(
                f"{where}: no label or material cluster named {op['target']!r}; "
                f"this room has {targets}"
            )
        if kind in ("light", "window") and op["name"] not in known:
            raise EditError(
                f"{where}: no light named {op['name']!r}; this room has {sorted(known)}"
            )
        if kind == "window" and known[op["name"]] != "window":
            windows = sorted(n for n, t in known.items() if t == "window")
            raise EditError(
                f"{where}: {op['name']!r} is a {known[op['name']]} light, not a window; "
                f"the windows are {windows}"
            )
        if kind == "light" and "move_to" in op and known[op["name"]] == "window":
            raise EditError(f"{where}: window {op['name']!r} cannot be moved")
        if kind == "add_light":
            if op["name"] in known:
                raise EditError(f"{where}: a light named {op['name']!r} exists already")
            known[op["name"]] = "point"


def _floats(text: str, n: int, spec: str) -> list[float]:
    try:
        vals = [float(x) for x in text.split(",")]
    except ValueError as exc:
        raise EditError(f"--op {spec!r}: {text!r} is not {n} comma-separated numbers") from exc
    if len(vals) != n:
        raise EditError(f"--op {spec!r}: {text!r} is not {n} comma-separated numbers")
    return vals


def op_from_shortcut(spec: str) -> dict[str, Any]:
    """One OP from a command-line shortcut (``reroom edit --op ...``).

    ``empty``; ``repaint:TARGET=r,g,b`` or ``repaint:TARGET=FILE.png``;
    ``off:NAME``; ``scale:NAME=s``; ``color:NAME=r,g,b``; ``move:NAME=x,y,z``;
    ``window:NAME=HDRI``; ``insert:OBJECT@x,y,z`` (optionally ``@ROTATION_DEG``);
    ``add:NAME@x,y,z=INTENSITY``. The result still goes through :func:`parse_edits`.
    """
    kind, _, rest = spec.partition(":")
    kind = kind.strip()
    if kind == "empty" and not rest:
        return {"op": "empty"}
    name, _, value = rest.partition("=")
    if kind == "repaint" and value:
        if any(value.lower().endswith(s) for s in (".png", ".jpg", ".jpeg", ".exr")):
            return {"op": "repaint", "target": name, "texture": value}
        return {"op": "repaint", "target": name, "color": _floats(value, 3, spec)}
    if kind == "off" and name and not value:
        return {"op": "light", "name": name, "off": True}
    if kind == "scale" and value:
        return {"op": "light", "name": name, "scale": _floats(value, 1, spec)[0]}
    if kind == "color" and value:
        return {"op": "light", "name": name, "color": _floats(value, 3, spec)}
    if kind == "move" and value:
        return {"op": "light", "name": name, "move_to": _floats(value, 3, spec)}
    if kind == "window" and value:
        return {"op": "window", "name": name, "hdri": value}
    if kind == "insert" and "@" in rest:
        parts = rest.split("@")
        op: dict[str, Any] = {
            "op": "insert",
            "object": parts[0],
            "position": _floats(parts[1], 3, spec),
        }
        if len(parts) > 2:
            op["rotation_deg"] = _floats(parts[2], 1, spec)[0]
        return op
    if kind == "add" and "@" in name and value:
        lname, _, pos = name.partition("@")
        return {
            "op": "add_light",
            "name": lname,
            "type": "point",
            "position": _floats(pos, 3, spec),
            "intensity": _floats(value, 1, spec)[0],
        }
    raise EditError(
        f"--op {spec!r} is not a shortcut: use empty, repaint:TARGET=r,g,b|FILE, off:NAME, "
        "scale:NAME=s, color:NAME=r,g,b, move:NAME=x,y,z, window:NAME=HDRI, "
        "insert:OBJECT@x,y,z[@deg], add:NAME@x,y,z=I"
    )
