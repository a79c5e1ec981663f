"""The report's sections, one function per stage, each reading that stage's outputs.

Every function takes the run folder and returns HTML (a section body). A stage whose
outputs are missing (it failed or has not run) gets a one-line note instead, so a
partial run still gives a readable report.
"""

from __future__ import annotations

import json
import re
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from reroom.report.html import esc, figure, fmt, swatch, table
from reroom.runner import StageResult, read_record
from reroom.scan import Scan

__all__ = [
    "edits_section",
    "evaluation_section",
    "hdr_section",
    "layout_section",
    "lights_section",
    "materials_section",
    "rerender_section",
    "run_section",
    "scan_section",
]

#: Report images are downscaled to at most this width (the page stays a few MB).
MAX_WIDTH = 960
#: Displayed width (CSS px) of a frame-sized picture and of a larger panel: small frames
#: (the demo's are 160 px wide) are shown enlarged.
THUMB = 280
PANEL = 480


def _missing(what: str, path: Path) -> str:
    return f'<p class="note">No {esc(what)}: {esc(path)} does not exist (the stage did not run or failed).</p>'


def _read_json(path: Path) -> Any:
    return json.loads(path.read_text())


def run_section(run: Path, stages: list[str], results: list[StageResult] | None) -> str:
    """Stage status of the run that wrote the report, and each stage's timing.

    ``seconds (last run)`` is this run's time (0 for a skipped stage); ``seconds
    (result)`` is how long the stage took when it made the result now on disk (from its
    record).
    """
    by_name = {r.name: r for r in results or []}
    rows = []
    total = 0.0
    for name in stages:
        folder = run / "report" if name == "report" else run / name
        rec = read_record(folder)
        r = by_name.get(name)
        if (
            r is None
            and name == "report"
            and results
            and not any(x.status == "failed" for x in results)
        ):
            # The report stage is what is writing this page.
            status, reason, secs = "ran", "this page", None
        elif r is None:
            status, reason, secs = "not reached", "", None
        else:
            status, reason, secs = r.status, r.reason, r.seconds
        cls = {"ran": "ok", "skipped": "skipped", "failed": "failed"}.get(status, "note")
        made = rec.get("seconds") if rec else None
        if made is not None:
            total += float(made)
        rows.append(
            [
                esc(name),
                f'<span class="{cls}">{esc(status)}</span>',
                esc(reason),
                fmt(secs, 3) if secs is not None else "&ndash;",
                fmt(made, 3) if made is not None else "&ndash;",
                esc(rec.get("finished", "")) if rec else "&ndash;",
            ]
        )
    html = table(
        ["stage", "this run", "why", "seconds (this run)", "seconds (result)", "result made"],
        rows,
        raw=True,
    )
    failed = [r for r in results or [] if r.status == "failed"]
    if failed:
        f = failed[0]
        html = (
            f'<p class="failed">Stage {esc(f.name)} failed: {esc(f.reason)}. The stages before '
            "it kept their results; the sections below show what exists.</p>" + html
        )
    html += f"<p>Sum of the stages' times for the results shown: {total:.1f} s.</p>"
    return html


def scan_section(scan: Scan, n_frames: int = 4) -> str:
    """What was scanned: frames, image size, mesh, and a few input frames."""
    from reroom.report.figures import pick_frames

    k = scan.frames[0].intrinsics
    m = scan.mesh
    lo, hi = m.bounds
    rows = [
        ["folder", esc(scan.root)],
        ["frames", fmt(len(scan.frames))],
        ["image size", f"{k.width} &times; {k.height} ({esc(k.model)}, fx {k.fx:.1f})"],
        ["mesh", f"{esc(scan.mesh_path.name)}: {len(m.vertices)} vertices, {len(m.faces)} faces"],
        ["mesh extent (m)", " &times; ".join(f"{x:.2f}" for x in hi - lo)],
        ["ground truth", "yes (errors below)" if scan.has_ground_truth else "no"],
    ]
    figs = "".join(
        figure(scan.frames[j].load_image(), f"input frame {j}", MAX_WIDTH // 2, width=THUMB)
        for j in pick_frames(len(scan.frames), n_frames)
    )
    return table(None, rows, raw=True) + "<h3>Input frames</h3>" + figs


def hdr_section(run: Path, scan: Scan) -> str:
    """Exposures solved, the HDR mesh drawn from input cameras next to the photos."""
    from reroom.report.figures import hdr_views

    hdr = run / "hdr"
    if not (hdr / "exposures.json").is_file():
        return _missing("HDR results", hdr / "exposures.json")
    doc = _read_json(hdr / "exposures.json")
    frames = doc.get("frames", [])
    with_exp = sum(f.get("scale") is not None for f in frames)
    v = doc.get("vertices", {})
    rows = [
        ["response", esc(doc.get("response"))],
        ["reference frame", fmt(doc.get("reference_frame"))],
        ["frames with an exposure", f"{with_exp} of {len(frames)}"],
        ["vertices observed", f"{v.get('observed', '?')} of {v.get('total', '?')}"],
        ["samples", fmt(doc.get("samples"))],
    ]
    html = table(None, rows, raw=True)
    html += "<h3>HDR mesh from input cameras</h3><p>Left the photo, right the HDR mesh's radiance times the frame's solved exposure (no shading; magenta: unobserved).</p>"
    for j, photo, view in hdr_views(scan, hdr, 2):
        html += figure(
            np.concatenate([photo, view], axis=1),
            f"frame {j}: photo | HDR mesh",
            MAX_WIDTH,
            width=2 * THUMB,
        )
    for name, cap in (
        ("hdr_exposures.png", "per-frame exposure scales"),
        (
            "hdr_before_after.png",
            "the mesh textured naively (best frame) and with the HDR radiance",
        ),
    ):
        p = hdr / "report" / name
        if p.is_file():
            html += figure(p, cap, MAX_WIDTH)
    notes = doc.get("warnings") or []
    if notes:
        html += "<h3>Notes</h3><ul>" + "".join(f"<li>{esc(n)}</li>" for n in notes[:12]) + "</ul>"
    return html


def layout_section(run: Path, scan: Scan) -> str:
    """Floorplan, rooms, openings and baseboards, and the vertex labels."""
    from reroom.report.figures import LABEL_COLORS, label_views

    lay = run / "layout"
    if not (lay / "layout.json").is_file():
        return _missing("layout", lay / "layout.json")
    doc = _read_json(lay / "layout.json")
    rows = []
    for r in doc.get("rooms", []):
        kinds = Counter(o.get("kind", "?") for o in r.get("openings", []))
        bb = r.get("baseboard") or {}
        ceiling = r.get("ceiling_z")
        if r.get("ceiling") == "estimated":
            ceiling = f"{fmt(ceiling)} (estimated)"
        rows.append(
            [
                r.get("name"),
                r.get("area"),
                r.get("floor_z"),
                ceiling,
                len(r.get("walls", [])),
                ", ".join(f"{n} {k}" for k, n in sorted(kinds.items())) or "none",
                bb.get("height"),
            ]
        )
    html = ""
    if doc.get("ceiling") == "estimated":
        html += (
            '<p class="note">The ceiling was not seen: its height is estimated (a lower '
            "bound, from the highest wall points observed) and the rooms are partial, "
            "outlined on the floor the scan covered and the walls it found.</p>"
        )
    warnings = doc.get("warnings") or []
    if warnings:
        html += "<h3>Warnings</h3><ul>" + "".join(f"<li>{esc(w)}</li>" for w in warnings) + "</ul>"
    if (lay / "floorplan.png").is_file():
        html += figure(lay / "floorplan.png", "floorplan (top view, aligned frame)", MAX_WIDTH)
    html += table(
        ["room", "area m²", "floor z", "ceiling z", "walls", "openings", "baseboard m"], rows
    )
    counts = doc.get("label_counts") or {}
    if counts:
        html += table(
            ["label", "colour", "vertices"],
            [
                [esc(k), swatch(LABEL_COLORS.get(k, LABEL_COLORS["other"])), fmt(v)]
                for k, v in counts.items()
            ],
            raw=True,
        )
    labels_ply = lay / "layout_labels.ply"
    if labels_ply.is_file():
        ids = doc.get("labels") or {}
        html += "<h3>Vertex labels</h3>"
        for cap, im in label_views(scan, labels_ply, ids):
            html += figure(im, f"labels {cap}", MAX_WIDTH // 2, width=PANEL)
    notes = doc.get("notes") or []
    if notes:
        html += "<ul>" + "".join(f"<li>{esc(n)}</li>" for n in notes[:12]) + "</ul>"
    return html


def _anchor(light: dict) -> list[float] | None:
    for key in ("centroid", "centre", "position"):
        if key in light:
            return [round(float(x), 2) for x in light[key]]
    if "p0" in light and "p1" in light:
        return [
            round((float(a) + float(b)) / 2, 2)
            for a, b in zip(light["p0"], light["p1"], strict=True)
        ]
    return None


def _reason_kind(reason: str) -> str:
    """A rejection reason with its numbers blanked, up to its first clause: a group key."""
    text = reason.removeprefix("rejected:").strip()
    text = re.split(r"[:—(]", text, maxsplit=1)[0]
    return re.sub(r"\d+(\.\d+)?", "n", text).strip(" ,;")[:90] or "other"


def _prior_note(solved: dict) -> str:
    """What shaped a solved point or line light's profile (its shape prior), in words."""
    dist = solved.get("distribution") or {}
    photo = dist.get("fixture_from_photos")
    if photo:  # reroom.invert.line_photos
        off = [1000 * float(x) for x in photo.get("axis_offset_m", [0.0, 0.0])]
        cut = [c for c in photo.get("cutoff_deg", []) if c is not None]
        return (
            f" | invert: the scan closed its fixture, so its axis (moved {off[0]:.0f} mm "
            f"across, {off[1]:.0f} mm up), radius ({1000 * float(photo.get('radius_m', 0)):.1f}"
            f" mm) and a trough (cut-off {', '.join(f'{c:.0f}' for c in cut) or '?'} deg) "
            f"come from {photo.get('stripe_frames', '?')} photos of it"
        )
    if "open_fraction" in dist:
        fixture = "shade" if dist.get("basis") == "inclination" else "fixture"
        return f" | invert: its profile held to what its scanned {fixture} leaves open"
    if "fixture_inside_fraction" in dist:
        return " | invert: the scan closed its fixture: no shape prior"
    return ""


def lights_section(run: Path) -> str:
    """Each light: type, where, how it was decided, its solved power and its diagram."""
    lpath = run / "lights" / "lights.json"
    if not lpath.is_file():
        return _missing("lights", lpath)
    doc = _read_json(lpath)
    inv_path = run / "invert" / "scene.json"
    solved = {}
    if inv_path.is_file():
        solved = {x["name"]: x for x in _read_json(inv_path).get("lights", [])}
    rows = []
    for light in doc.get("lights", []):
        s = solved.get(light["name"], {})
        rows.append(
            [
                esc(light["name"]),
                esc(light["type"]),
                esc(light.get("source", "")),
                fmt(_anchor(light)),
                fmt(s.get("power")) if s else "&ndash;",
                fmt(s.get("share_of_irradiance")) if s else "&ndash;",
                esc(light.get("reason", "") + _prior_note(s)),
            ]
        )
        sun = s.get("sun") if s else None
        if sun:  # a window's sun, found and solved by reroom invert (reroom.invert.sun)
            d = sun.get("direction", [0.0, 0.0, 0.0])
            det = sun.get("detection", {})
            rows.append(
                [
                    esc(sun.get("name", "")),
                    "sun",
                    "invert",
                    "towards " + fmt(d),
                    fmt(sun.get("power")),
                    fmt(sun.get("share_of_irradiance")),
                    esc(
                        f"a sharp sunlit patch seen through {light['name']}: "
                        f"{det.get('lit_receivers', '?')} receivers, "
                        f"{det.get('contrast', '?')}x brighter than around them "
                        f"(t = {det.get('score', '?')})"
                    ),
                ]
            )
    html = table(
        ["light", "type", "source", "position (m)", "power (RGB)", "share of irradiance", "why"],
        rows,
        raw=True,
    )
    html += (
        "<p>Power: the solved emitted power in the HDR mesh's radiance units "
        "(radiance &times; m² &times; sr); positions in the mesh frame.</p>"
    )
    rejected = doc.get("rejected", [])
    if rejected:
        why = Counter(_reason_kind(str(r.get("reason", ""))) for r in rejected)
        html += f"<h3>{len(rejected)} candidates rejected</h3>" + table(
            ["reason", "count"], [[k, n] for k, n in why.most_common(10)]
        )
    inv = run / "invert"
    pics = sorted(inv.glob("gonio_*.png")) + sorted(inv.glob("window_*.png"))
    if pics:
        html += "<h3>Distributions</h3>"
        for p in pics:
            kind = "goniometric diagram" if p.name.startswith("gonio_") else "window environment"
            name = p.stem.split("_", 1)[1]
            html += figure(p, f"{name}: {kind}", MAX_WIDTH // 2)
    return html


def materials_section(run: Path, scan: Scan) -> str:
    """Solved albedo per cluster, and the per-vertex albedo from an input camera."""
    inv = run / "invert"
    if not (inv / "scene.json").is_file():
        return _missing("materials", inv / "scene.json")
    doc = _read_json(inv / "scene.json")
    rows = []
    for m in doc.get("materials", []):
        a = m.get("albedo")
        rows.append(
            [
                esc(m["name"]),
                swatch(a) if a else "",
                *(fmt(x) for x in (a or [None, None, None])),
                "yes" if m.get("solved") else "no",
            ]
        )
    html = table(
        ["cluster", "colour", "albedo R", "albedo G", "albedo B", "solved"], rows, raw=True
    )
    if (inv / "albedo.ply").is_file():
        from reroom.hdr.pictures import render_vertex_colors
        from reroom.io.mesh import read_ply
        from reroom.rays import RayCaster

        mesh = read_ply(inv / "albedo.ply")
        alb = np.asarray(mesh.vertex_attributes["albedo"], np.float64)
        ok = (alb >= 0).all(axis=1)
        j = len(scan.frames) // 2
        f = scan.frames[j]
        view = render_vertex_colors(
            RayCaster(mesh),
            np.clip(np.where(ok[:, None], alb, 0), 0, 1),
            f.c2w,
            f.intrinsics,
            valid=ok,
            cull_backfaces=False,
        )
        html += figure(
            np.concatenate([f.load_image(), view], axis=1),
            f"frame {j}: photo | per-vertex albedo (magenta: not solved)",
            MAX_WIDTH,
            width=2 * THUMB,
        )
    html += _textures_html(inv, doc)
    warns = doc.get("warnings") or []
    if warns:
        html += "<ul>" + "".join(f"<li>{esc(w)}</li>" for w in warns[:12]) + "</ul>"
    return html


def _textures_html(inv: Path, doc: dict) -> str:
    """The photo textures of the planes: a table, and the floor's texture."""
    entries = doc.get("textures") or []
    if not entries:
        return ""
    from reroom.io.images import linear_to_srgb, read_exr

    html = "<p>Albedo textures of the room's planes from the photos (docs/invert.md).</p>"
    html += table(
        ["plane", "texel (cm)", "texels", "seen by a photo"],
        [
            [
                e["name"],
                100 * e["texel"],
                f"{e['width']} x {e['height']}",
                f"{100 * e['observed_fraction']:.0f} %",
            ]
            for e in entries
        ],
    )
    floor = next((e for e in entries if e["label"] == "floor"), None)
    if floor is not None and (inv / floor["file"]).is_file():
        # rows flipped: +y up, as the floor plan
        alb = np.clip(read_exr(inv / floor["file"])[::-1, :, :3], 0.0, 1.0)
        picture = (255 * linear_to_srgb(alb)).round().astype(np.uint8)
        html += figure(picture, f"{floor['name']}: albedo texture", MAX_WIDTH, width=THUMB)
    return html


def rerender_section(run: Path) -> str:
    """Input frames re-rendered from the recovered model, next to the photos."""
    rr = run / "rerender"
    if not (rr / "rerender.json").is_file():
        return _missing("re-renders", rr / "rerender.json")
    doc = _read_json(rr / "rerender.json")
    html = (
        "<p>Each row: the photo, then the model rendered from the same camera times the "
        "frame's solved exposure. Ratio of means 1 = as bright as the photo; relative L1 "
        "includes both images' noise.</p>"
    )
    html += table(
        ["frame", "ratio of means", "relative L1", "pixels"],
        [[f["index"], f["ratio_of_means"], f["relative_l1"], f["pixels"]] for f in doc["frames"]],
    )
    html += (
        f"<p>Median ratio of means {fmt(doc.get('median_ratio_of_means'))}, median relative "
        f"L1 {fmt(doc.get('median_relative_l1'))}, {fmt(doc.get('spp'))} samples per pixel"
        + (", denoised (Open Image Denoise)" if doc.get("denoised") else "")
        + ".</p>"
    )
    if (rr / "rerender.png").is_file():
        html += figure(rr / "rerender.png", "photo | re-render", MAX_WIDTH, width=2 * THUMB)
    return html


def _pictures(folder: Path) -> list[Path]:
    """The PNG pictures an edit render wrote (tone-mapped renders first)."""
    return sorted(p for p in folder.rglob("*.png") if p.is_file())


def _rounded(obj: Any, digits: int = 4) -> Any:
    """``obj`` with its floats rounded for display (``3.3500000000000005`` -> ``3.35``)."""
    if isinstance(obj, float):
        return round(obj, digits)
    if isinstance(obj, list | tuple):
        return [_rounded(x, digits) for x in obj]
    if isinstance(obj, dict):
        return {k: _rounded(v, digits) for k, v in obj.items()}
    return obj


def edits_section(run: Path, scan: Scan) -> str:
    """Every edit set: its operations and its renders, after the photos they start from."""
    ed = run / "edits"
    if not (ed / "edits.json").is_file():
        return _missing("edit renders", ed / "edits.json")
    doc = _read_json(ed / "edits.json")
    html = ""
    if doc.get("spp") is not None:
        html += (
            f"<p>Path-traced at {fmt(doc.get('spp'))} samples per pixel"
            + (", denoised (Open Image Denoise)" if doc.get("denoised") else "")
            + ".</p>"
        )
    frames = sorted({int(j) for e in doc.get("sets", []) for j in e.get("frames", [])})
    frames = [j for j in frames if 0 <= j < len(scan.frames)]
    if frames:
        html += "<h3>The photos the edits are rendered at</h3>"
        html += "".join(
            figure(scan.frames[j].load_image(), f"input frame {j}", MAX_WIDTH // 2, width=PANEL)
            for j in frames
        )
    for entry in doc.get("sets", []):
        html += f"<h3>{esc(entry['name'])}</h3>"
        html += f"<pre>{esc(json.dumps(_rounded(entry.get('edits', []))))}</pre>"
        pics = _pictures(ed / entry["folder"])
        for p in pics:
            cap = f"{entry['name']}: {p.relative_to(ed / entry['folder'])}"
            html += figure(p, cap, MAX_WIDTH // 2, width=PANEL)
        if not pics:
            html += '<p class="note">This edit wrote no picture.</p>'
        html += f"<p>{fmt(entry.get('seconds'))} s, frames {fmt(entry.get('frames'))}.</p>"
    return html or "<p>No edit set.</p>"


def _rel(v: Any) -> str:
    """A relative error as a percentage (lists per channel)."""
    if v is None:
        return "&ndash;"
    if isinstance(v, list | tuple):
        return ", ".join(_rel(x) for x in v)
    return f"{100 * float(v):.1f}%"


def evaluation_section(ev: dict[str, dict[str, Any]]) -> str:
    """Ground-truth errors per stage (from :func:`reroom.report.evaluation.evaluate_run`)."""
    if not ev:
        return "<p>No ground truth for this scan.</p>"
    html = ""
    for stage in ("hdr", "layout", "lights", "invert"):
        res = ev.get(stage)
        if res is None:
            continue
        html += f"<h3>{esc(stage)}</h3>"
        if "error" in res:
            html += f'<p class="failed">evaluation failed: {esc(res["error"])}</p>'
            continue
        html += _EVAL[stage](res)
        html += f'<p class="skipped">evaluated in {res.get("seconds", 0):.1f} s</p>'
    return html


def _eval_hdr(res: dict) -> str:
    rows = []
    for name, m in res.get("methods", {}).items():
        e, r = m.get("exposure_ratio_error", {}), m.get("radiance_error", {})
        rows.append(
            [
                esc(name),
                _rel(e.get("median")),
                _rel(e.get("p90")),
                _rel(e.get("max")),
                _rel(r.get("median")),
                _rel(r.get("p90")),
                fmt(r.get("vertices")),
                esc(_ratios(r.get("ratio_of_sums"))),
            ]
        )
    return (
        table(
            [
                "method",
                "exposure error median",
                "p90",
                "max",
                "radiance error median",
                "p90",
                "vertices",
                "radiance / truth, ratio of sums r/g/b",
            ],
            rows,
            raw=True,
        )
        + "<p>Exposure error: |estimated / true exposure ratio to the reference frame &minus; 1|; "
        "radiance error on diffuse vertices with precise truth (relative standard error "
        f"below {_rel(res.get('truth', {}).get('max_truth_stderr'))}; the truth is itself a "
        "Monte-Carlo estimate); ratio of sums over every observed diffuse vertex, in which "
        "the truth's noise cancels (1 = unbiased).</p>"
    )


def _ratios(values) -> str:
    """``0.989/0.982/0.973``, or a dash."""
    if not values:
        return "–"
    return "/".join(f"{v:.3f}" for v in values)


def _eval_layout(res: dict) -> str:
    we = res.get("wall_error_cm") or {}
    rows = [
        ["rooms found / true", f"{res.get('rooms_found')} / {res.get('rooms_true')}"],
        [
            "walls found / true (missed)",
            f"{res.get('walls_found')} / {res.get('walls_true')} ({res.get('walls_missed')})",
        ],
        ["wall position error, cm (mean / max)", f"{fmt(we.get('mean'))} / {fmt(we.get('max'))}"],
        [
            "floor / ceiling height error, cm",
            f"{fmt(res.get('floor_error_cm'))} / {fmt(res.get('ceiling_error_cm'))}",
        ],
        ["floorplan IoU", fmt(res.get("iou"))],
        ["label accuracy (wall, floor, ceiling)", fmt(res.get("label_accuracy"))],
    ]
    for kind, f in (res.get("features") or {}).items():
        rows.append(
            [
                f"{esc(kind)}: matched / found / true",
                f"{f.get('matched')} / {f.get('found')} / {f.get('true')}",
            ]
        )
    return table(["quantity", "value"], rows, raw=True)


def _eval_lights(res: dict) -> str:
    rows = [
        [
            esc(t["name"]),
            esc(t["type"]),
            "yes" if t.get("found") else "no",
            esc(t.get("matched", "")),
            fmt(t.get("type_ok")),
            fmt(t.get("position_error_m")),
            fmt(t.get("iou")),
        ]
        for t in res.get("truth", [])
    ]
    html = table(
        ["true light", "type", "found", "as", "type right", "position error m", "IoU"],
        rows,
        raw=True,
    )
    false = res.get("false_lights", [])
    html += (
        f"<p>{res.get('found')} of {res.get('true_lights')} true lights found, "
        f"{len(false)} false: {esc(', '.join(f['name'] for f in false)) or 'none'}.</p>"
    )
    return html


def _eval_invert(res: dict) -> str:
    rows = [
        [esc(name), fmt(c.get("estimate")), fmt(c.get("truth")), _rel(c.get("relative_error"))]
        for name, c in (res.get("clusters") or {}).items()
    ]
    html = table(["cluster", "albedo", "true albedo", "relative error"], rows, raw=True)
    pv = (res.get("per_vertex") or {}).get("all") or {}
    if pv:
        html += (
            f"<p>Per-vertex albedo: median relative error {_rel(pv.get('median'))}, "
            f"p90 {_rel(pv.get('p90'))} over {pv.get('vertices')} vertices.</p>"
        )
    rows = [
        [
            esc(x["name"]),
            esc(x["type"]),
            esc(x.get("truth", "")),
            fmt(x.get("distance_m")),
            fmt(x.get("power")),
            fmt(x.get("true_power")),
            _rel(x.get("power_relative_error")),
        ]
        for x in res.get("lights", [])
    ]
    html += table(
        ["light", "type", "truth", "distance m", "power", "true power", "relative error"],
        rows,
        raw=True,
    )
    missed = res.get("missed_lights") or []
    html += f"<p>True lights with no solved light: {esc(', '.join(missed)) or 'none'}.</p>"
    return html


_EVAL = {"hdr": _eval_hdr, "layout": _eval_layout, "lights": _eval_lights, "invert": _eval_invert}
