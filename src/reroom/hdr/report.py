"""The HDR stage's short report: exposure curves, before/after renders, a summary.

``report/hdr_exposures.png``
    Per-frame scales of our global solve and of the two baselines.
``report/hdr_before_after.png``
    The mesh textured four ways, from a dollhouse view and from inside the room
    (at the mean camera position, looking level along frame 0's heading): naive (each vertex
    coloured by its single best frame, as the camera exposed it -- the seams of
    thesis Fig. 3.1), frame-to-frame, frame-to-model, and ours (the weighted
    median radiance). Each calibrated texture is scaled by one global gain so its
    overall brightness matches the naive one, then clipped; magenta = unobserved.
``report/report.md``
    Counts, warnings, and the ground-truth-free seam metrics
    (:mod:`reroom.hdr.metrics`) of every method on flat surfaces.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from reroom.hdr.metrics import (
    SeamSamples,
    boundary_pairs,
    boundary_seam,
    loop_gap,
    luminance,
    seam_metric,
)
from reroom.hdr.pictures import (
    dollhouse_camera,
    inside_camera,
    plot_exposures,
    render_vertex_colors,
    save_panels,
    to_display,
)
from reroom.hdr.reproject import BestFrame, Radiance
from reroom.hdr.solve import ExposureSolution
from reroom.io.atomic import atomic_write_text
from reroom.rays import RayCaster
from reroom.scan import Scan

__all__ = ["matching_gain", "write_report"]

OURS = "ours (global)"


def matching_gain(reference: np.ndarray, values: np.ndarray, mask: np.ndarray) -> float:
    """The gain ``k`` making ``k * values`` as bright as ``reference`` (median luminance ratio)."""
    ref, val = luminance(reference[mask]), luminance(values[mask])
    ok = (ref > 0) & (val > 0)
    if not np.any(ok):
        return 1.0
    return float(np.median(ref[ok] / val[ok]))


def write_report(
    out: Path,
    scan: Scan,
    caster: RayCaster,
    lut: np.ndarray,
    sol: ExposureSolution,
    rad: Radiance,
    best: BestFrame,
    baselines: dict[str, np.ndarray],
    baseline_rad: dict[str, Radiance],
    size: tuple[int, int],
    notes: list[str],
    seam_set: SeamSamples,
    flat: np.ndarray,
) -> dict[str, Path]:
    """Write ``report/`` (see the module notes) and return the files written."""
    rep = out / "report"
    files: dict[str, Path] = {}
    curves = {OURS: sol.scales, **baselines}
    files["exposure_plot"] = plot_exposures(rep / "hdr_exposures.png", curves)

    naive = best.linear_values()
    has_best = best.frame >= 0
    textures: list[tuple[str, np.ndarray, np.ndarray]] = [
        ("naive (best frame, uncalibrated)", naive, has_best)
    ]
    for name, r in [*((k, baseline_rad[k]) for k in baselines), (OURS, rad)]:
        mask = r.observed & has_best
        gain = matching_gain(naive, r.radiance, mask)
        textures.append((name, r.radiance * gain, r.observed))
    w, h = size
    views = [("dollhouse", *dollhouse_camera(scan.mesh.vertices, w, h))]
    if scan.frames:
        views.append(("inside", *inside_camera(scan.frames, w, h)))
    panels = []
    for view_name, c2w, intr in views:
        row = []
        for name, colors, valid in textures:
            img = render_vertex_colors(caster, to_display(colors, 1.0), c2w, intr, valid=valid)
            row.append((f"{name}: {view_name}", img))
        panels.append(row)
    files["renders"] = save_panels(
        rep / "hdr_before_after.png",
        panels,
        title="Mesh textured from the frames: naive vs calibrated (magenta = unobserved)",
    )

    edges = np.asarray(scan.mesh.edges_unique)
    pairs = boundary_pairs(edges, best.frame, np.ones(len(flat), bool), len(sol.scales))
    seams = {}
    for name, s in {
        "naive (uncalibrated)": np.ones_like(sol.scales),
        OURS: sol.scales,
        **baselines,
    }.items():
        seams[name] = (
            seam_metric(seam_set, pairs, s),
            seam_metric(seam_set, pairs, s, min_gap=loop_gap(len(s))),
            boundary_seam(edges, best, s, lut, flat),
        )

    n_f = len(sol.status)
    solved = int(np.count_nonzero(sol.solved))
    lines = [
        "# HDR calibration report",
        "",
        f"- scan: `{scan.root}`",
        f"- frames: {n_f}, with an exposure: {solved}, reference frame: {sol.reference}",
        f"- vertices: {len(rad.observed)}, observed: {int(rad.observed.sum())}, "
        f"seen once: {int(np.count_nonzero(rad.sample_count == 1))}",
        f"- solver: {sol.info.get('method')} on {sol.info.get('vertices', 0)} vertices, "
        f"{sol.info.get('samples', 0)} samples, {sol.info.get('seconds', 0):.2f} s",
        "",
        "## Seam metrics (no ground truth)",
        "",
        "Log-luminance jump at seams between frames' territories of a best-frame texture",
        "(0.01 = 1 %): *seam* estimates each bordering frame pair's jump over all vertices",
        "both frames see; *loop seam* does so for pairs at least a quarter of the scan apart",
        "(revisits); *boundary seam* measures the jump on the boundary edges themselves",
        "(noisier; flat surfaces only). Definitions in `reroom.hdr.metrics`; lower is better.",
        "",
        "| method | seam | p90 over pairs | frame pairs | loop seam | loop pairs | boundary seam |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, (m, lp, b) in seams.items():
        lines.append(
            f"| {name} | {m['seam']:.4f} | {m['p90']:.4f} | {m['pairs']} "
            f"| {lp['seam']:.4f} | {lp['pairs']} | {b['seam']:.4f} |"
        )
    lines += ["", "## Pictures", "", "![exposures](hdr_exposures.png)", ""]
    lines += ["![before/after](hdr_before_after.png)", ""]
    if notes:
        lines += ["## Warnings", ""] + [f"- {n}" for n in notes] + [""]
    files["report"] = atomic_write_text(rep / "report.md", "\n".join(lines))
    return files
