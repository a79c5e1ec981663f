"""Light detection (thesis §5.5): area lights, windows, line lights and point lights.

``detect_lights(scan_dir, hdr_dir, layout_dir, options, progress)`` finds the lights of a
scanned room on the HDR mesh, keeps or rejects every bright candidate with a reason in
words, and returns a :class:`LightSet`; ``write_lights`` writes ``lights.json`` and
``lights_vertices.npz``, ``load_lights`` reads them back; ``apply_edits`` applies user
overrides. See ``docs/lights.md``.
"""

from reroom.lights.detect import LightsOptions, check_user_lights, detect_lights
from reroom.lights.lightset import (
    Light,
    LightsError,
    LightSet,
    Rejected,
    apply_edits,
    edits_from_options,
    load_edits,
    load_lights,
    merge_edits,
    parse_point,
    write_lights,
)

__all__ = [
    "Light",
    "LightSet",
    "LightsError",
    "LightsOptions",
    "Rejected",
    "apply_edits",
    "check_user_lights",
    "detect_lights",
    "edits_from_options",
    "load_edits",
    "load_lights",
    "merge_edits",
    "parse_point",
    "write_lights",
]
