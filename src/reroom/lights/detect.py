"""Automatic light detection on the HDR mesh (thesis §5.5, without the person who pruned).

:func:`detect_lights` reads the HDR stage's radiance mesh and exposures and the layout
stage's room model, and returns a :class:`~reroom.lights.lightset.LightSet`:

1. **Threshold** (automatic): ``threshold_factor`` times the median HDR luminance of
   the observed wall and ceiling vertices (the room's typical lit surface), so the
   threshold follows the exposure units of the HDR stage and the room's brightness.
2. **Candidates**: connected components of the vertices above it (§5.5.1).
3. **Decision**, every candidate kept or rejected with a reason in words, first
   rejection wins, in this order: too few vertices (< ``min_vertices``, the thesis's
   50), outside the room, part of a layout window (its reveal, lit by daylight),
   view-dependent (a specular highlight: bright in few of the frames that see it,
   :mod:`reroom.lights.consistency`), an upward-facing surface below the ceiling
   zone (a floor or table top lit from above), a soft edge (a pool of light, not an
   emitter: low edge contrast). Survivors are typed: *line* (near the ceiling, long
   and thin by PCA, §5.5.4), *window* (vertical, on a wall, rectangular: §5.5.2's
   suggestion), *area* (flat), *point* (a compact, non-flat blob: a bare bulb).
4. **Windows** from the layout's window openings (in a fused scan windows are holes).
5. **Point-light proposals**: a soft pool of light on the ceiling above an object
   (a lamp shade open at the top) proposes a point light inside the object's top;
   its position is a guess and says so. Point lights with no visible emitter and no
   such pool (a recessed downlight) cannot be detected here: the user
   (``--add-point``) or light localization must supply them.

It never reads ``ground_truth/``.
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from reroom.hdr.linearize import LUMA, response_lut
from reroom.hdr.observe import vertex_normals
from reroom.io.mesh import read_ply
from reroom.layout.meshops import vertex_adjacency, vertex_areas
from reroom.lights.candidates import (
    Component,
    bright_components,
    describe_component,
)
from reroom.lights.consistency import (
    clipped_fraction,
    observe_vertices,
    resolved_frames,
    view_consistency,
)
from reroom.lights.decide import decide, evidence, make_light, window_light
from reroom.lights.lightset import Light, LightsError, LightSet, Rejected
from reroom.lights.lines import absorb_pieces, fixture_from_pieces, merge_lines
from reroom.lights.pools import MeshData, find_pools
from reroom.lights.room import (
    CEILING,
    WALL,
    RoomModel,
    lights_outside_room,
    load_room_model,
    room_model_without_layout,
)
from reroom.rays import RayCaster
from reroom.scan import load_scan

__all__ = [
    "LightsOptions",
    "check_user_lights",
    "RoomModel",
    "detect_lights",
    "load_room_model",
    "room_model_without_layout",
]

ProgressFn = Callable[[str, int, int], None]

#: Components smaller than this are summarised as one "specks" entry, not listed.
SPECK = 5


@dataclass
class LightsOptions:
    """Options of :func:`detect_lights` (the ``reroom lights`` flags).

    Attributes
    ----------
    threshold:
        Absolute HDR luminance threshold; ``None`` = automatic
        (``threshold_factor`` x the median wall/ceiling luminance).
    threshold_factor:
        Multiple of the room's typical surface luminance (see ``docs/lights.md``).
    min_vertices:
        A candidate needs this many vertices (thesis: 50).
    min_view_fraction:
        A candidate must look bright in at least this fraction of the frames that
        see it; fewer is a specular highlight.
    min_view_frames:
        The view test needs at least this many frames that see the candidate (with
        fewer, one badly registered frame would decide).
    min_view_pixels:
        Only frames that see a candidate at least this many pixels wide (its
        shorter side) count in the view test; thinner views blur it into its
        surroundings.
    min_contrast:
        Mean luminance of a candidate over that of its surroundings; below it the
        bright region is a pool of light, not an emitter.
    ceiling_zone:
        Height below the ceiling (m) where line lights and ceiling pools are looked for.
    line_max_aspect:
        Line light when ``sqrt(lambda2 / lambda1)`` of the PCA is below this.
    line_min_length:
        ... and it is at least this long (m).
    window_min_size:
        A detected (not layout) window's smaller side, m.
    room_margin:
        How far outside the room polygon (m) a candidate may lie (walls' depth).
    clipped_fraction:
        A vertex whose pixel is at the white level in at least this fraction of the
        frames that see it is bright whatever its HDR radiance (which is then only a
        lower bound: an 8-bit auto-exposed capture cannot measure an emitter).
    min_clip_samples:
        ... and that see it at least this many times. 1 (2 until session 26): on scans
        of few frames most vertices are seen once (95 of the 97 observed vertices of
        the tube of the 24-frame `reroom demo` scan), and the tube, `lshape`'s panel
        and `tworooms`' tube were missed; a single clipped view of a highlight is still
        a candidate that the location, contrast and view tests judge.
    view_consistency:
        Reject candidates bright in few of the frames that see them.
    require_layout:
        Without ``layout.json``, raise (default) or go on without a room model
        (:func:`room_model_without_layout`, with a note): no windows, no room bounds.
    propose_points:
        Look for lit pools on the ceiling and floor; propose point lights inside the
        top of objects under ceiling pools.
    pool_factor:
        A pool is brighter than this multiple of its surface's median luminance. 2: a
        lamp's pool on a ceiling that other lights reach as well is 2.5x its median
        (`box_points`), which 3 missed; a pool only becomes a light with an object
        under it and a measured edge or a note saying its place is a guess.
    pool_min_area:
        Smallest pool considered, m².
    """

    threshold: float | None = None
    threshold_factor: float = 8.0
    min_vertices: int = 50
    min_view_fraction: float = 0.8
    min_view_frames: int = 5
    min_view_pixels: float = 3.0
    min_contrast: float = 2.0
    ceiling_zone: float = 0.5
    line_max_aspect: float = 0.2
    line_min_length: float = 0.3
    window_min_size: float = 0.3
    room_margin: float = 0.3
    clipped_fraction: float = 0.5
    min_clip_samples: int = 1
    view_consistency: bool = True
    propose_points: bool = True
    require_layout: bool = True
    pool_factor: float = 2.0
    pool_min_area: float = 0.05


def _read_scales(path: Path, n_frames: int) -> tuple[np.ndarray, str]:
    """Per-frame scales (NaN rows = no exposure) and the response name from exposures.json."""
    try:
        d = json.loads(path.read_text())
        frames = d["frames"]
    except (json.JSONDecodeError, KeyError, TypeError) as exc:
        raise LightsError(f"{path}: not a reroom exposures file ({exc})") from exc
    if len(frames) != n_frames:
        raise LightsError(f"{path}: {len(frames)} frames, the scan has {n_frames}")
    scales = np.full((n_frames, 3), np.nan)
    for j, f in enumerate(frames):
        if f.get("scale") is not None:
            scales[j] = f["scale"]
    response = d.get("response", "auto")
    option = d.get("options", {}).get("response")
    if response not in ("gamma2.2", "srgb", "linear") and not str(response).startswith("gamma"):
        response = option if option and Path(str(option)).is_file() else "auto"
    return scales, str(response)


def detect_lights(
    scan_dir: str | Path,
    hdr_dir: str | Path | None = None,
    layout_dir: str | Path | None = None,
    options: LightsOptions | None = None,
    progress: ProgressFn | None = None,
) -> LightSet:
    """Find the lights of a scanned room and explain every decision.

    Parameters
    ----------
    scan_dir:
        The scan folder (frames for the view-consistency test).
    hdr_dir:
        Output of ``reroom hdr`` (default ``SCAN/hdr``): ``hdr_mesh.ply``, ``exposures.json``.
    layout_dir:
        Output of ``reroom layout`` (default ``SCAN/layout``): ``layout.json``,
        ``layout_labels.ply``.
    options:
        :class:`LightsOptions`.
    progress:
        ``progress(stage, done, total)``; stages ``load``, ``candidates``,
        ``view consistency``.

    Returns
    -------
    LightSet
        Lights, rejected candidates with reasons, the per-vertex light ids.
        With no light found it is empty, with a note saying why (and a warning).

    Raises
    ------
    LightsError
        If the HDR or layout outputs are missing or do not match the scan.
    """
    opt = options or LightsOptions()
    prog = progress or (lambda s, d, t: None)
    notes: list[str] = []
    scan_dir = Path(scan_dir)
    hdr_dir = Path(hdr_dir) if hdr_dir is not None else scan_dir / "hdr"
    layout_dir = Path(layout_dir) if layout_dir is not None else scan_dir / "layout"
    hdr_mesh = hdr_dir / "hdr_mesh.ply"
    for p in (hdr_mesh, hdr_dir / "exposures.json"):
        if not p.is_file():
            raise LightsError(f"{p}: missing; run `reroom hdr {scan_dir}` first")
    prog("load", 0, 3)
    scan = load_scan(scan_dir)
    mesh = read_ply(hdr_mesh)
    attrs = mesh.vertex_attributes
    if "radiance" not in attrs or "observed" not in attrs:
        raise LightsError(f"{hdr_mesh}: no radiance_r/g/b or observed attribute")
    if len(mesh.vertices) != len(scan.mesh.vertices):
        raise LightsError(
            f"{hdr_mesh}: {len(mesh.vertices)} vertices, the scan mesh has "
            f"{len(scan.mesh.vertices)}; run `reroom hdr` again"
        )
    prog("load", 1, 3)
    if opt.require_layout or (layout_dir / "layout.json").is_file():
        room = load_room_model(layout_dir, len(mesh.vertices))
    else:
        room = room_model_without_layout(mesh.vertices)
        notes.append(
            f"{layout_dir / 'layout.json'} missing: ran without a room layout (no windows, no "
            "room bounds, floor and ceiling = the mesh's lowest and highest points, threshold "
            "relative to all observed vertices)"
        )
        warnings.warn(f"{scan_dir}: {notes[-1]}", stacklevel=2)
    scales, response = _read_scales(hdr_dir / "exposures.json", len(scan.frames))
    prog("load", 2, 3)

    verts = np.asarray(mesh.vertices, float)
    faces = np.asarray(mesh.faces, np.int64)
    radiance = np.asarray(attrs["radiance"], float)
    observed = np.asarray(attrs["observed"]).astype(bool)
    luminance = radiance @ LUMA
    normals = vertex_normals(mesh)
    areas = vertex_areas(verts, faces)
    aligned = room.to_aligned(verts)
    up = room.up

    adjacency = vertex_adjacency(faces, len(verts))
    caster = RayCaster(scan.mesh)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # unreadable frames were reported by `reroom hdr`
        obs = observe_vertices(
            scan.frames, caster, verts, normals, response_lut(response, scan.meta), prog
        )
    n_samples, clip_frac = clipped_fraction(obs)
    threshold, thresholds = _threshold(luminance, observed, room.labels, opt, notes)
    clipped = (n_samples >= opt.min_clip_samples) & (clip_frac >= opt.clipped_fraction)
    _, members = bright_components(adjacency, observed & ((luminance >= threshold) | clipped))
    prog("load", 3, 3)

    edge = np.linalg.norm(verts[faces[:, 1]] - verts[faces[:, 0]], axis=1)
    resolution = float(np.median(edge)) if len(edge) else 0.05
    tree = cKDTree(verts)
    ring = max(2.5 * resolution, 0.05)
    comps: list[Component] = []
    for k, m in enumerate(members):
        comps.append(
            describe_component(m, verts, normals, areas, radiance, luminance, observed, tree, ring)
        )
        prog("candidates", k + 1, len(members))

    consistency = None
    if opt.view_consistency and comps:
        grp = np.full(len(verts), -1, np.int64)
        for k, c in enumerate(comps):
            grp[c.vertices] = k
        resolved = resolved_frames(
            scan.frames,
            np.array([c.centroid for c in comps]),
            np.array([c.extent[1] for c in comps]),
            opt.min_view_pixels,
        )
        consistency = view_consistency(
            obs, grp, len(comps), scales, 0.5 * threshold, resolved=resolved
        )

    windows = room.windows()
    rejected: list[Rejected] = []
    kept: list[tuple[Light, np.ndarray]] = []  # detected lights and their vertices
    window_parts: dict[int, list[np.ndarray]] = {}  # layout window -> vertices of its glass
    specks = 0
    small_near_ceiling: list[tuple[Rejected, Component, dict]] = []
    line_pieces: list[tuple[Rejected, Component, dict]] = []
    piece_opt = replace(opt, min_vertices=SPECK, line_min_length=0.0)

    for k, comp in enumerate(comps):
        if len(comp.vertices) < min(SPECK, opt.min_vertices):
            specks += 1
            continue
        ev = evidence(comp, aligned, up, room)
        ev["clipped_fraction"] = float(np.mean(clip_frac[comp.vertices]))
        ev["radiance_is_lower_bound"] = bool(ev["clipped_fraction"] >= 0.5)
        if consistency is not None:
            ev["frames_seeing"] = int(consistency.frames_seeing[k])
            ev["frames_bright"] = int(consistency.frames_bright[k])
            ev["view_ratio"] = float(consistency.view_ratio[k])
        verdict = decide(comp, ev, opt, room, windows, threshold)
        name = f"candidate{k}"
        if verdict[0] == "reject":
            rejected.append(Rejected(name, "component", verdict[1], ev))
            if verdict[2] == "small" and ev["top_below_ceiling_m"] <= opt.ceiling_zone:
                small_near_ceiling.append((rejected[-1], comp, ev))
                # Would it be a line but for its size (and length)? A piece of a tube.
                if decide(comp, dict(ev), piece_opt, room, windows, threshold)[2] == "line":
                    line_pieces.append((rejected[-1], comp, ev))
        elif verdict[0] == "window-part":
            window_parts.setdefault(verdict[2], []).append(comp.vertices)
            rejected.append(Rejected(name, "component", verdict[1], ev))
        else:
            reason = verdict[1] + ev.get("view_note", "")
            kept.append((make_light(verdict[2], comp, ev, up, reason), comp.vertices))
    if specks:
        rejected.append(
            Rejected(
                "specks",
                "components",
                f"rejected: {specks} specks of fewer than {SPECK} bright vertices "
                f"(< {opt.min_vertices}): isolated glints or noise",
                {"count": specks},
            )
        )

    surfaces = [(x, v) for x, v in kept if x.type in ("area", "window")]
    lines = merge_lines([(x, v) for x, v in kept if x.type == "line"])
    lines = absorb_pieces(lines, small_near_ceiling, up, rejected)
    line_pieces = [p for p in line_pieces if any(p[0] is r for r in rejected)]
    lines += fixture_from_pieces(
        line_pieces, lines, up, rejected, opt.min_vertices, opt.line_min_length
    )
    points = [(x, v) for x, v in kept if x.type == "point"]
    layout_windows = [
        (window_light(w, win), np.concatenate(window_parts.get(w, [np.zeros(0, np.int64)])))
        for w, win in enumerate(windows)
        if not win["into"]
    ]
    rejected += [
        Rejected(
            f"layout_window{w}",
            "window",
            f"rejected: window opening {w} of the layout opens into {win['into']}, not "
            "outside: no daylight comes through it",
            {"room": win["room"], "wall": win["wall"], "into": win["into"]},
        )
        for w, win in enumerate(windows)
        if win["into"]
    ]
    proposals: list[tuple[Light, np.ndarray]] = []
    if opt.propose_points:
        taken = np.zeros(len(verts), bool)
        for _, v in kept:
            taken[v] = True
        md = MeshData(verts, normals, areas, radiance, luminance, observed, tree, ring, aligned)
        proposals, pool_rejects = find_pools(md, taken, adjacency, room, opt, up)
        rejected += pool_rejects
    lights: list[Light] = []
    light_id = np.full(len(verts), -1, np.int32)
    for light, members_k in [*surfaces, *layout_windows, *lines, *points, *proposals]:
        if light.type in ("area", "window"):
            light.geometry["light_index"] = len(lights)
            light_id[members_k] = len(lights)
        lights.append(light)
    _name_lights(lights)

    if not lights:
        why = (
            f"no light found: {len(comps)} candidate(s) above the threshold "
            f"{threshold:.3g}, all rejected (see 'rejected')"
            if comps
            else f"no light found: no vertex is above the threshold {threshold:.3g}"
        )
        notes.append(why)
        warnings.warn(f"{scan_dir}: {why}", stacklevel=2)
    if not any(x.type == "point" for x in lights):
        notes.append(
            "no point light detected: point lights without a visible emitter (a recessed "
            "downlight, a bulb inside a closed shade) must come from the user "
            "(--add-point) or from light localization (`reroom localize`)"
        )
    return LightSet(
        lights,
        rejected,
        light_id,
        thresholds,
        notes,
        {
            "scan": str(scan_dir),
            "hdr": str(hdr_dir),
            "layout": str(layout_dir),
            "up": up.tolist(),
            "options": asdict(opt),
            "mesh_resolution": resolution,
        },
    )


def _threshold(
    luminance: np.ndarray,
    observed: np.ndarray,
    labels: np.ndarray,
    opt: LightsOptions,
    notes: list[str],
) -> tuple[float, dict[str, Any]]:
    """The luminance threshold and how it was chosen."""
    ref_mask = observed & np.isin(labels, (WALL, CEILING))
    what = "median luminance of the observed wall and ceiling vertices"
    if ref_mask.sum() < 100:
        ref_mask = observed
        what = "median luminance of all observed vertices (fewer than 100 wall/ceiling ones)"
        notes.append(f"threshold reference: {what}")
    if not ref_mask.any():
        raise LightsError("the HDR mesh has no observed vertex; nothing to detect lights from")
    ref = float(np.median(luminance[ref_mask]))
    p99 = float(np.percentile(luminance[ref_mask], 99))
    if opt.threshold is not None:
        thr, how = float(opt.threshold), "given by the user"
    else:
        thr, how = opt.threshold_factor * ref, f"{opt.threshold_factor:g} x the reference level"
    if not np.isfinite(thr) or thr <= 0:
        raise LightsError(f"light threshold must be positive, got {thr}")
    return thr, {
        "luminance": thr,
        "how": how,
        "reference": ref,
        "reference_is": what,
        "reference_p99": p99,
        "min_vertices": opt.min_vertices,
        "min_view_fraction": opt.min_view_fraction,
        "min_contrast": opt.min_contrast,
    }


def _name_lights(lights: list[Light]) -> None:
    counts: dict[str, int] = {}
    for light in lights:
        if not light.name:
            i = counts.get(light.type, 0)
            light.name = f"{light.type}{i}"
            counts[light.type] = i + 1


def check_user_lights(lights: LightSet) -> list[str]:
    """Warn about user-given lights outside the room (after :func:`apply_edits`).

    Uses the layout the light set was detected with (``lights.meta["layout"]``); with
    none, nothing is checked. Each problem is added to ``lights.notes``, warned, and
    returned.
    """
    layout = lights.meta.get("layout")
    if not layout or not (Path(layout) / "layout.json").is_file():
        return []
    room = load_room_model(layout, len(lights.vertex_light_id))
    anchors = {x.name: x.anchor() for x in lights.lights if x.source == "user"}
    problems = lights_outside_room(anchors, room)
    for p in problems:
        msg = f"{p} (check its coordinates: world metres, +Z up)"
        lights.notes.append(msg)
        warnings.warn(msg, stacklevel=2)
    return problems
