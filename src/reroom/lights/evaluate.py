"""Light detection against a synthetic scan's ground truth (evaluation only).

This is the only module of :mod:`reroom.lights` that reads ``ground_truth/``. For
every true light that is on, :func:`evaluate_lights` finds the nearest detected
light (any type) and reports whether it was *found* (within a type-dependent
distance), whether the type is right, the position error, the rectangle IoU of
area lights and windows (in the true light's plane), and the endpoint error of
line lights. Detected lights matched to no true light are *false lights*. The
rejected candidates are summarised by their reason.
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from reroom.lights.lightset import Light, LightSet, load_lights

__all__ = ["FOUND_WITHIN", "evaluate_lights", "light_anchor", "rectangle_iou"]

#: A true light is found when a detected light's anchor lies within this distance (m).
FOUND_WITHIN = {"area": 0.3, "window": 0.5, "line": 0.3, "point": 0.5}


def _true_anchor(t: dict) -> np.ndarray:
    if t["type"] in ("area", "window"):
        return np.mean(np.asarray(t["corners"], float), axis=0)
    if t["type"] == "line":
        return (np.asarray(t["p0"], float) + np.asarray(t["p1"], float)) / 2
    return np.asarray(t["position"], float)


def _distance(t: dict, anchor: np.ndarray) -> float:
    """Distance of a detection's anchor from a true light: from its centre, or for a
    line from the nearest point of the segment (a tube found in part still counts)."""
    if t["type"] != "line":
        return float(np.linalg.norm(anchor - _true_anchor(t)))
    p0, p1 = np.asarray(t["p0"], float), np.asarray(t["p1"], float)
    d = p1 - p0
    s = np.clip((anchor - p0) @ d / max(d @ d, 1e-12), 0.0, 1.0)
    return float(np.linalg.norm(anchor - (p0 + s * d)))


def light_anchor(light: Light) -> np.ndarray:
    """A detected light's reference point (:meth:`Light.anchor`)."""
    return light.anchor()


def _detected_corners(light: Light) -> np.ndarray | None:
    """Four corners of a detected area light's or window's rectangle (world)."""
    g = light.geometry
    if light.type == "window":
        c, hu, hv = (np.asarray(g[k], float) for k in ("centre", "half_u", "half_v"))
    elif light.type == "area" and "axis_long" in g:
        c = np.asarray(g["centroid"], float)
        hu = np.asarray(g["axis_long"], float) * g["size"][0] / 2
        hv = np.asarray(g["axis_short"], float) * g["size"][1] / 2
    else:
        return None
    return np.array([c - hu - hv, c + hu - hv, c + hu + hv, c - hu + hv])


def rectangle_iou(true_corners: np.ndarray, corners: np.ndarray) -> float:
    """IoU of two rectangles, measured in the true rectangle's plane.

    The detected corners are projected onto the true rectangle's edge axes and
    replaced by their bounding box there (exact when both are aligned, as Manhattan
    rooms' lights and windows are).
    """
    t = np.asarray(true_corners, float)
    o = t[0]
    u, v = t[1] - t[0], t[3] - t[0]
    lu, lv = np.linalg.norm(u), np.linalg.norm(v)
    u, v = u / lu, v / lv
    q = np.asarray(corners, float) - o
    a = np.array([q @ u, q @ v]).T
    lo, hi = a.min(0), a.max(0)
    ix = max(0.0, min(hi[0], lu) - max(lo[0], 0.0))
    iy = max(0.0, min(hi[1], lv) - max(lo[1], 0.0))
    inter = ix * iy
    union = lu * lv + np.prod(hi - lo) - inter
    return float(inter / union) if union > 0 else 0.0


def _line_errors(t: dict, light: Light) -> dict[str, float]:
    p0, p1 = np.asarray(t["p0"], float), np.asarray(t["p1"], float)
    q0 = np.asarray(light.geometry["p0"], float)
    q1 = np.asarray(light.geometry["p1"], float)
    straight = np.linalg.norm(q0 - p0) + np.linalg.norm(q1 - p1)
    swapped = np.linalg.norm(q0 - p1) + np.linalg.norm(q1 - p0)
    e = (
        [np.linalg.norm(q0 - p0), np.linalg.norm(q1 - p1)]
        if straight <= swapped
        else [np.linalg.norm(q0 - p1), np.linalg.norm(q1 - p0)]
    )
    return {
        "endpoint_error_m": float(np.mean(e)),
        "endpoint_error_max_m": float(np.max(e)),
        "length_error_m": float(np.linalg.norm(q1 - q0) - np.linalg.norm(p1 - p0)),
        "radius_error_m": float(light.geometry["radius"] - t["radius"]),
    }


def evaluate_lights(lights: LightSet | str | Path, scan_dir: str | Path) -> dict[str, Any]:
    """Compare detected lights with ``ground_truth/scene/scene.json``.

    Parameters
    ----------
    lights:
        A :class:`LightSet` or the path of a ``lights.json``.
    scan_dir:
        The synthetic scan (its ``ground_truth/``).

    Returns
    -------
    dict
        ``truth`` (one row per true light that is on: ``name, type, found,
        matched, matched_type, type_ok, position_error_m`` -- from the true
        centre, or for a line from the nearest point of the true segment --, plus ``iou`` for areas
        and windows and the line errors), ``false_lights`` (names, types, reasons),
        ``rejected`` (count per reason kind), ``found`` / ``true_lights`` counts.
    """
    ls = lights if isinstance(lights, LightSet) else load_lights(lights)
    scene_path = Path(scan_dir) / "ground_truth" / "scene" / "scene.json"
    scene = json.loads(scene_path.read_text())
    truth = [t for t in scene.get("lights", []) if t.get("on", True)]
    anchors = [light_anchor(x) for x in ls.lights]
    used: set[int] = set()
    rows = []
    # Greedy: each true light takes the nearest detection not yet taken.
    for t in truth:
        d = [_distance(t, a) if i not in used else np.inf for i, a in enumerate(anchors)]
        i = int(np.argmin(d)) if d else -1
        row: dict[str, Any] = {"name": t["name"], "type": t["type"], "found": False}
        if i >= 0 and d[i] <= FOUND_WITHIN[t["type"]]:
            used.add(i)
            light = ls.lights[i]
            row.update(
                found=True,
                matched=light.name,
                matched_type=light.type,
                matched_source=light.source,
                type_ok=light.type == t["type"],
                position_error_m=float(d[i]),
            )
            corners = _detected_corners(light)
            if t["type"] in ("area", "window") and corners is not None:
                row["iou"] = rectangle_iou(np.asarray(t["corners"], float), corners)
            if t["type"] == "line" and light.type == "line":
                row.update(_line_errors(t, light))
        elif anchors:
            row["nearest_m"] = float(min(_distance(t, a) for a in anchors))
        rows.append(row)
    false = [
        {"name": x.name, "type": x.type, "source": x.source, "reason": x.reason}
        for i, x in enumerate(ls.lights)
        if i not in used
    ]
    kinds = Counter(_reason_kind(r.reason) for r in ls.rejected)
    return {
        "truth": rows,
        "true_lights": len(truth),
        "found": sum(r["found"] for r in rows),
        "type_ok": sum(bool(r.get("type_ok")) for r in rows),
        "false_lights": false,
        "rejected": dict(kinds),
    }


def _reason_kind(reason: str) -> str:
    """A short tag for a rejection reason (for the summary)."""
    for tag in (
        "specks",
        "vertices <",
        "outside the room",
        "window opening",
        "wall's thickness",
        "view-dependent",
        "upward-facing",
        "soft edge",
        "pool on the ceiling",
        "pool on the floor",
        "removed by the user",
    ):
        if tag in reason:
            return tag.replace("vertices <", "too small")
    return "other"
