"""The decision rules: keep or reject a bright candidate, with a reason in words.

See ``docs/lights.md`` (Method, step 5) for the rules and the measurements behind them.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from reroom.lights.candidates import Component
from reroom.lights.lightset import Light
from reroom.lights.room import RoomModel

if TYPE_CHECKING:
    from reroom.lights.detect import LightsOptions

__all__ = ["ceiling_estimated", "decide", "evidence", "make_light", "radiance_text", "window_light"]


def evidence(comp: Component, aligned: np.ndarray, up: np.ndarray, room: RoomModel) -> dict:
    """The measurements a decision rests on, as JSON-ready evidence (world metres)."""
    a = aligned[comp.vertices]
    c_al = room.to_aligned(comp.centroid)
    return {
        "vertices": int(len(comp.vertices)),
        "area_m2": comp.area,
        "size_m": [comp.size[0], comp.size[1]],
        "centroid": comp.centroid,
        "height_m": float(c_al[2]),
        "top_below_ceiling_m": float(room.ceiling_z - a[:, 2].max()),
        "normal_up": float(comp.normal @ up),
        "flatness": comp.normal_spread,
        "aspect": float(np.sqrt(comp.eigenvalues[1] / max(comp.eigenvalues[0], 1e-12))),
        "mean_radiance": comp.mean_radiance,
        "mean_luminance": comp.mean_luminance,
        "peak_luminance": comp.peak_luminance,
        "edge_contrast": comp.edge_contrast,
    }


def decide(
    comp: Component,
    ev: dict,
    opt: LightsOptions,
    room: RoomModel,
    windows: list[dict],
    threshold: float,
) -> tuple:
    """``("reject", reason, tag)``, ``("window-part", reason, w)`` or ``("keep", reason, type)``."""
    n = ev["vertices"]
    if n < opt.min_vertices:
        return ("reject", f"rejected: {n} vertices < {opt.min_vertices}", "small")
    c_al = room.to_aligned(comp.centroid)
    inside = room.inside(c_al[None, :2], opt.room_margin)[0]
    # With a seen ceiling nothing above it is in the room. An estimated ceiling (none
    # seen: a partial scan, layout.json `"ceiling": "estimated"`) is only a lower bound,
    # the highest wall points observed, and a ceiling light sits at the true ceiling,
    # possibly above it. A bright surface seen above it inside the room's outline shows
    # that the ceiling is at least that high, so there only the floor bounds the height.
    top = np.inf if ceiling_estimated(room) else room.ceiling_z + 0.1
    if not inside or not (room.floor_z - 0.1 <= c_al[2] <= top):
        return (
            "reject",
            f"rejected: outside the room (centroid {np.round(comp.centroid, 2).tolist()})",
            "outside",
        )
    for w, win in enumerate(windows):
        if _near_window(comp.centroid, win, margin=0.1):
            facing = abs(float(comp.normal @ win["normal"])) > 0.8
            if facing:
                return ("window-part", f"part of window {w}: its glass, seen bright", w)
            return (
                "reject",
                f"rejected: in window opening {w} but not facing into the room "
                "(the reveal, lit by daylight)",
                "window reveal",
            )
    if not room.inside(c_al[None, :2], 0.0)[0]:
        depth = float(room.wall_distance(c_al[None, :2])[0])
        return (
            "reject",
            f"rejected: in the wall's thickness, {depth:.2f} m behind its inner face: the lit "
            "reveal of an opening the layout did not report (if it is a window, add it in "
            "lights_edit.json)",
            "wall thickness",
        )
    seen, bright = ev.get("frames_seeing", 0), ev.get("frames_bright", 0)
    near_ceiling = ev["top_below_ceiling_m"] <= opt.ceiling_zone
    if seen >= opt.min_view_frames and bright < opt.min_view_fraction * seen:
        if not (near_ceiling and ev["normal_up"] < -0.5):
            return (
                "reject",
                f"rejected: view-dependent — bright in {bright} of {seen} frames that see it "
                "(a specular highlight)",
                "highlight",
            )
        # A surface at the ceiling facing down would mirror the floor, not a light: the
        # views where it looks dark are views where its fitting (baffles, a housing the
        # mesh does not resolve) hides it.
        ev["view_note"] = (
            f"; bright in only {bright} of {seen} frames, but it faces down at the ceiling, "
            "where a highlight would mirror the dark floor: an emitter partly hidden by its "
            "fitting"
        )
    if ev["normal_up"] > 0.7 and not near_ceiling:
        return (
            "reject",
            f"rejected: upward-facing surface at z = {ev['height_m']:.2f} m (a floor or a "
            "table top lit from above, not an emitter)",
            "lit top",
        )
    if comp.edge_contrast < opt.min_contrast:
        on_ceiling = near_ceiling and ev["normal_up"] < -0.7
        where = "on the ceiling" if on_ceiling else f"at z = {ev['height_m']:.2f} m"
        return (
            "reject",
            f"rejected: soft edge {where} — only {comp.edge_contrast:.1f}x brighter than its "
            f"surroundings (< {opt.min_contrast:g}): a pool of light (from a lamp or daylight), "
            "not an emitter",
            "ceiling pool" if on_ceiling else "pool",
        )
    length, width = comp.size
    if near_ceiling and ev["aspect"] < opt.line_max_aspect and length >= opt.line_min_length:
        return ("keep", f"kept: line light, {length:.2f} m long, {radiance_text(ev)}", "line")
    vertical = abs(ev["normal_up"]) < 0.3 and ev["flatness"] > 0.8
    if vertical and width >= opt.window_min_size:
        wall_d = float(room.wall_distance(room.to_aligned(comp.centroid)[None, :2])[0])
        fill = comp.area / max(length * width, 1e-9)
        if wall_d < 0.3 and fill > 0.7:
            return (
                "keep",
                f"kept: window, {length:.2f} x {width:.2f} m on a wall ({wall_d:.2f} m from it), "
                f"rectangular (fill {fill:.2f}), {radiance_text(ev)}",
                "window",
            )
    if ev["flatness"] > 0.5:
        return (
            "keep",
            f"kept: area light, {length:.2f} x {width:.2f} m, {radiance_text(ev)}",
            "area",
        )
    return (
        "keep",
        f"kept: point light, a compact bright blob {length:.2f} m across, {radiance_text(ev)}",
        "point",
    )


def ceiling_estimated(room: RoomModel) -> bool:
    """Whether the layout estimated the ceiling rather than seeing it (a room with
    ``"ceiling": "estimated"``, ``docs/layout.md`` step 4b): its height is a lower bound."""
    return any(r.get("ceiling") == "estimated" for r in room.rooms)


def radiance_text(ev: dict) -> str:
    """The mean radiance in words, saying when clipping makes it a lower bound."""
    text = f"mean radiance {ev['mean_luminance']:.3g}"
    if ev.get("radiance_is_lower_bound"):
        text += f" (a lower bound: clipped in {100 * ev['clipped_fraction']:.0f} % of its views)"
    return text


def _near_window(p: np.ndarray, win: dict, margin: float) -> bool:
    """Whether world point ``p`` lies in the window's opening box (through the wall's depth)."""
    c, hu, hv, n = (np.asarray(win[k], float) for k in ("centre", "half_u", "half_v", "normal"))
    d = p - c
    u = abs(d @ hu) / max(hu @ hu, 1e-12)
    v = abs(d @ hv) / max(hv @ hv, 1e-12)
    depth = d @ n  # 0 at the outside face, win["depth"] at the inside face
    return (
        u <= 1 + margin / np.linalg.norm(hu)
        and v <= 1 + margin / np.linalg.norm(hv)
        and -margin <= depth <= win["depth"] + margin
    )


def _tube_section_fits(comp: Component) -> bool:
    """Whether the circle fitted to a component's cross-section looks like a tube's: its
    radius within a factor 2 of half the width, its centre within the width of the box's
    middle."""
    half_width = float(comp.extent[1] / 2)
    r, c = comp.section_radius, comp.section_center
    return bool(
        half_width > 0
        and np.isfinite(r)
        and np.all(np.isfinite(c))
        and 0.5 * half_width <= r <= 2.0 * half_width
        and np.linalg.norm(c - comp.center) <= 2.0 * half_width
    )


def _tube_axis_point(comp: Component) -> np.ndarray:
    """The middle of a line light's axis: the centre of its cross-section's circle.

    A scanned tube is seen from below only: the middle of its bounding box then sits a
    few millimetres to a centimetre under the axis (1.1 cm for `furnished`'s 1.6 cm
    tube), which shifts where its fixture cuts its light off by about a bin
    (docs/invert.md, "A shape prior for line lights"). The fitted circle is used when it
    looks like the tube (radius within a factor 2 of half the width, centre within the
    width of the box's middle); otherwise the box's middle.
    """
    if _tube_section_fits(comp):
        return np.asarray(comp.section_center, float)
    return np.asarray(comp.center, float)


def make_light(typ: str, comp: Component, ev: dict, up: np.ndarray, reason: str) -> Light:
    """A detected light of type ``typ`` from a component (geometry per ``docs/lights.md``)."""
    if typ == "line":
        d = comp.axes[0]
        half = d * comp.extent[0] / 2
        # The cross-sections' circles where they agree on a tube (candidates._tube_slices);
        # else half the width (a fused scan's blob of tube and housing: the whole
        # section's circle is the blob's, and measured worse there, docs/lights.md).
        slices = comp.section_from_slices and _tube_section_fits(comp)
        radius = float(comp.section_radius if slices else comp.extent[1] / 2)
        perp = up - (up @ d) * d
        perp /= max(np.linalg.norm(perp), 1e-12)
        middle = _tube_axis_point(comp)
        geometry = {
            "p0": middle - half,
            "p1": middle + half,
            "d_perp": perp,
            "radius": radius,
        }
    elif typ == "window":
        long_axis, short_axis = comp.axes[0], comp.axes[1]
        geometry = {
            "centre": comp.center,
            "half_u": long_axis * comp.extent[0] / 2,
            "half_v": short_axis * comp.extent[1] / 2,
            "normal": comp.normal,
        }
    elif typ == "area":
        geometry = {
            "centroid": comp.centroid,
            "normal": comp.normal,
            "area": comp.area,
            "size": [comp.extent[0], comp.extent[1]],
            "axis_long": comp.axes[0],
            "axis_short": comp.axes[1],
        }
    else:
        geometry = {"position": comp.centroid, "axis": up}
    return Light("", typ, "detected", geometry, ev, reason)


def window_light(k: int, win: dict) -> Light:
    """The window light of layout window ``k`` (``source: layout``)."""
    hu, hv = np.linalg.norm(win["half_u"]), np.linalg.norm(win["half_v"])
    return Light(
        "",
        "window",
        "layout",
        {k2: win[k2] for k2 in ("centre", "half_u", "half_v", "normal")},
        {
            "room": win["room"],
            "wall": win["wall"],
            "depth_m": win["depth"],
            "layout_source": win["layout_source"],
        },
        f"kept: window opening {k} of the layout, {2 * hu:.2f} x {2 * hv:.2f} m "
        "(rectangle on the wall's outside face, normal into the room)",
    )
