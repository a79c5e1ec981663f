"""Evaluation of ``reroom hdr`` against synthetic ground truth (reads ``ground_truth/``).

Only this module reads the truth; :func:`~reroom.hdr.pipeline.run_hdr` never does.

Measures, for our global solve and both baselines:

* **Exposure ratio error** per frame and channel:
  ``|(t_j / t_r) / (s_j / s_r) - 1|`` with ``t`` estimated, ``s`` the true
  ``frames[j].scale`` and ``r`` our reference frame. Summarised by median, p90
  and max over frames and channels; frames without an exposure are counted.
* **Vertex radiance relative error** ``|L_i / (s_r L*_i) - 1|`` per channel of
  every observed *diffuse* vertex (labels wall, floor, ceiling, door, baseboard),
  pooled over vertices and channels (median, p90). Our radiance is in units of
  the reference frame's scale, hence the ``s_r``. The truth is itself a
  Monte-Carlo estimate: only vertices whose relative ``radiance_stderr`` is below
  ``max_truth_stderr`` in every channel count, and the median relative stderr of
  those is reported alongside.
* **Ratio of sums** per channel, overall and per label, of our radiance over
  ``s_r L*`` on every observed diffuse vertex with a positive truth: the HDR's bias,
  in which the truth's own noise cancels (on `furnished` hardly a vertex has truth
  precise to 2 %, so the per-vertex error above is often empty there).
* **Seam metrics** (:mod:`reroom.hdr.metrics`: the seam metric and the noisier
  boundary seam) on flat *wall* vertices, also for the uncalibrated frames and
  for the true scales (the floor set by shading, misregistration and noise).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from reroom.errors import ScanError
from reroom.hdr.linearize import response_lut
from reroom.hdr.metrics import (
    SeamSamples,
    boundary_pairs,
    boundary_seam,
    flat_vertices,
    loop_gap,
    seam_metric,
)
from reroom.hdr.observe import vertex_normals
from reroom.hdr.pipeline import OUTPUT_FILES
from reroom.hdr.reproject import BestFrame
from reroom.io.atomic import atomic_write_json, nan_to_null
from reroom.io.mesh import read_ply
from reroom.scan import load_scan

__all__ = [
    "DIFFUSE_LABELS",
    "Truth",
    "evaluate_hdr",
    "exposure_errors",
    "load_truth",
    "radiance_errors",
]

DIFFUSE_LABELS = ("wall", "floor", "ceiling", "door", "baseboard")
METHODS = {"ours": "scales", "frame-to-frame": "scales_frame_to_frame"}
METHODS["frame-to-model"] = "scales_frame_to_model"


@dataclass
class Truth:
    """Synthetic ground truth of a scan: per-frame scales and per-vertex radiance."""

    scales: np.ndarray
    radiance: np.ndarray
    stderr: np.ndarray
    label: np.ndarray
    labels: dict[str, int]


def load_truth(scan_dir: str | Path) -> Truth:
    """Read ``ground_truth/ground_truth.json`` and ``vertices.ply`` of a synthetic scan."""
    gt = Path(scan_dir) / "ground_truth"
    path = gt / "ground_truth.json"
    if not path.is_file():
        raise ScanError(path, "is missing: only synthetic scans have ground truth")
    doc = json.loads(path.read_text())
    mesh = read_ply(gt / "vertices.ply")
    attrs = mesh.vertex_attributes
    rad = np.asarray(attrs["radiance"], np.float64)
    err = np.asarray(attrs.get("radiance_stderr", np.zeros_like(rad)), np.float64)
    return Truth(
        scales=np.asarray([f["scale"] for f in doc["frames"]], np.float64),
        radiance=rad,
        stderr=err,
        label=np.asarray(attrs["label"]).astype(np.int64),
        labels=dict(doc.get("labels", {})),
    )


def _summary(values: np.ndarray) -> dict:
    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return {"median": None, "p90": None, "max": None, "n": 0}
    return {
        "median": float(np.median(v)),
        "p90": float(np.percentile(v, 90)),
        "max": float(np.max(v)),
        "n": int(len(v)),
    }


def exposure_errors(scales: np.ndarray, truth: np.ndarray, reference: int) -> dict:
    """Ratio errors ``|(t_j/t_r)/(s_j/s_r) - 1|`` per frame and channel, and a summary."""
    t = np.asarray(scales, np.float64)
    s = np.asarray(truth, np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        err = np.abs((t / t[reference]) / (s / s[reference]) - 1.0)
    missing = int(np.count_nonzero(~np.all(np.isfinite(err), axis=1)))
    return {"per_frame": err, **_summary(err), "frames_without_exposure": missing}


def radiance_errors(
    radiance: np.ndarray,
    observed: np.ndarray,
    truth: Truth,
    reference_scale: np.ndarray,
    mask: np.ndarray,
    max_truth_stderr: float = 0.02,
) -> dict:
    """Relative radiance error per channel on ``mask & observed`` vertices with precise truth."""
    ref = truth.radiance * np.asarray(reference_scale, np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        rel_se = truth.stderr / truth.radiance
    precise = np.all(truth.radiance > 0, axis=1) & np.all(rel_se < max_truth_stderr, axis=1)
    sel = mask & observed & precise
    with np.errstate(invalid="ignore", divide="ignore"):
        err = np.abs(radiance[sel] / ref[sel] - 1.0)
        bias = float(np.median(radiance[sel] / ref[sel])) if sel.any() else None
    out = _summary(err)
    names = {v: k for k, v in truth.labels.items()}
    lab = truth.label[sel]
    out["by_label"] = {
        names.get(int(k), str(k)): float(np.median(err[lab == k])) for k in np.unique(lab)
    }
    # The truth's Monte-Carlo noise (about 13 % a vertex on `furnished`, where almost no
    # vertex passes ``max_truth_stderr``) cancels in sums over many vertices, so the
    # ratio of sums over every observed vertex with a positive truth says how biased the
    # HDR radiance is even where the per-vertex error above has no precise vertex.
    every = (
        mask & observed & np.all(truth.radiance > 0, axis=1) & np.all(np.isfinite(radiance), axis=1)
    )

    def ratio_of_sums(rows: np.ndarray) -> list[float] | None:
        if not rows.any():
            return None
        return [float(x) for x in radiance[rows].sum(axis=0) / ref[rows].sum(axis=0)]

    out["ratio_of_sums"] = ratio_of_sums(every)
    out["ratio_of_sums_by_label"] = {
        names.get(int(k), str(k)): ratio_of_sums(every & (truth.label == k))
        for k in np.unique(truth.label[every])
    }
    out.update(
        ratio_of_sums_vertices=int(np.count_nonzero(every)),
        vertices=int(np.count_nonzero(sel)),
        diffuse_vertices=int(np.count_nonzero(mask)),
        diffuse_observed=int(np.count_nonzero(mask & observed)),
        median_ratio=bias,
        truth_rel_stderr_median=float(np.median(rel_se[sel])) if sel.any() else None,
    )
    return out


def evaluate_hdr(
    scan_dir: str | Path,
    hdr_dir: str | Path,
    *,
    max_truth_stderr: float = 0.02,
    write: bool = True,
) -> dict:
    """Evaluate the outputs of :func:`~reroom.hdr.pipeline.run_hdr` in ``hdr_dir``.

    Writes ``evaluation.json`` and ``report/hdr_exposures_truth.png`` (exposure
    curves with the truth) when ``write`` is set, and returns the same numbers
    (without per-frame arrays).
    """
    scan_dir, hdr_dir = Path(scan_dir), Path(hdr_dir)
    truth = load_truth(scan_dir)
    scan = load_scan(scan_dir, check_images=False)
    doc = json.loads((hdr_dir / OUTPUT_FILES["exposures"]).read_text())
    mesh = read_ply(hdr_dir / OUTPUT_FILES["mesh"])
    radiance = np.asarray(mesh.vertex_attributes["radiance"], np.float64)
    observed = np.asarray(mesh.vertex_attributes["observed"]).astype(bool)
    extras = np.load(hdr_dir / OUTPUT_FILES["extras"])
    reference = int(doc["reference_frame"])
    if reference < 0 or len(truth.scales) != len(scan.frames):
        raise ScanError(scan_dir, "ground truth and HDR outputs do not match (frames)")
    lut = response_lut(doc.get("response", "auto"), scan.meta)
    ids = [truth.labels[name] for name in DIFFUSE_LABELS if name in truth.labels]
    diffuse = np.isin(truth.label, ids)
    edges = np.asarray(scan.mesh.edges_unique)
    flat = extras["flat"] if "flat" in extras else flat_vertices(edges, vertex_normals(scan.mesh))
    walls = flat & (truth.label == truth.labels.get("wall", 0))
    best = BestFrame(
        extras["best_frame"].astype(np.int64), extras["best_value"], extras["best_linear"]
    )
    s_ref = truth.scales[reference]
    samples = SeamSamples.from_npz(extras)
    samples = SeamSamples(
        samples.vertex[walls[samples.vertex]],
        samples.frame[walls[samples.vertex]],
        samples.linear[walls[samples.vertex]],
    )
    pairs = boundary_pairs(edges, best.frame, walls, len(truth.scales))

    def seams(scales: np.ndarray) -> dict:
        return {
            "seam": seam_metric(samples, pairs, scales),
            "loop_seam": seam_metric(samples, pairs, scales, min_gap=loop_gap(len(scales))),
            "boundary_seam": boundary_seam(edges, best, scales, lut, walls),
        }

    results: dict = {"reference_frame": reference, "methods": {}}
    curves: dict[str, np.ndarray] = {}
    for name, key in METHODS.items():
        if key not in extras:
            continue
        scales = extras[key]
        curves[name] = scales
        rad = radiance if name == "ours" else extras[f"radiance_{key[len('scales_') :]}"]
        exp = exposure_errors(scales, truth.scales, reference)
        results["methods"][name] = {
            "exposure_ratio_error": {k: v for k, v in exp.items() if k != "per_frame"},
            "radiance_error": radiance_errors(
                rad, observed, truth, s_ref, diffuse, max_truth_stderr=max_truth_stderr
            ),
            **seams(scales),
        }
    results["uncalibrated"] = seams(np.ones_like(truth.scales))
    results["true_scales"] = seams(truth.scales)
    results["truth"] = {
        "max_truth_stderr": max_truth_stderr,
        "diffuse_labels": list(DIFFUSE_LABELS),
    }
    if write:
        from reroom.hdr.pictures import plot_exposures

        names = {"ours": "ours (global)"}
        plot_exposures(
            hdr_dir / "report" / "hdr_exposures_truth.png",
            {names.get(k, k): v / v[reference] for k, v in curves.items()},
            title="Per-frame scales relative to the reference frame, with the truth",
            truth=truth.scales / truth.scales[reference],
        )
        atomic_write_json(hdr_dir / "evaluation.json", nan_to_null(results))
    return results
