"""``reroom hdr``: radiometric calibration of a scan's auto-exposed frames onto its mesh.

:func:`run_hdr` is the whole stage: linearise (:mod:`~reroom.hdr.linearize`),
match vertices to pixels (:mod:`~reroom.hdr.observe`), solve the global
exposures (:mod:`~reroom.hdr.solve`), reproject a robust radiance per vertex
(:mod:`~reroom.hdr.reproject`), run the two baselines
(:mod:`~reroom.hdr.baselines`), and write the outputs and a short report. It
never reads ``ground_truth/`` (:mod:`~reroom.hdr.evaluate` does).
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from reroom.errors import ReroomError
from reroom.hdr.baselines import frame_to_frame, frame_to_model
from reroom.hdr.linearize import ResponseSpec, resolve_response, response_lut
from reroom.hdr.metrics import flat_vertices, seam_samples
from reroom.hdr.observe import Observations, ObserveOptions, collect_observations, vertex_normals
from reroom.hdr.reproject import (
    BestFrame,
    Radiance,
    VertexGroups,
    best_frame_texture,
    reproject_radiance,
)
from reroom.hdr.solve import ExposureSolution, SolveOptions, solve_exposures, usable_samples
from reroom.hdr.vertex_exr import write_vertex_exr
from reroom.io.atomic import atomic_path, atomic_write_json
from reroom.io.mesh import write_ply
from reroom.rays import RayCaster
from reroom.scan import Scan, load_scan

__all__ = ["HdrOptions", "HdrResult", "run_hdr", "OUTPUT_FILES"]

ProgressFn = Callable[[str, int, int], None]

#: What :func:`run_hdr` writes, relative to its output folder.
OUTPUT_FILES = {
    "mesh": "hdr_mesh.ply",
    "radiance_exr": "hdr_radiance.exr",
    "exposures": "exposures.json",
    "extras": "hdr_extras.npz",
    "report": "report/report.md",
    "exposure_plot": "report/hdr_exposures.png",
    "renders": "report/hdr_before_after.png",
}


@dataclass(frozen=True)
class HdrOptions:
    """Options of :func:`run_hdr`.

    Attributes
    ----------
    response:
        Inverse response: ``"auto"`` (the scan's own, else gamma 2.2), a name
        (``gamma2.2``, ``srgb``, ``linear``, ``gamma<g>``), 256 values or a file
        (:func:`~reroom.hdr.linearize.response_lut`).
    observe:
        Visibility and sample filtering (:class:`~reroom.hdr.observe.ObserveOptions`).
    solve:
        The exposure solve (:class:`~reroom.hdr.solve.SolveOptions`).
    baselines:
        Also run frame-to-frame and frame-to-model (thesis §3.7).
    report:
        Write the report pictures (exposure curves, before/after renders).
    render_size:
        ``(width, height)`` of each render in the report.
    predicted_weights:
        Weight each sample of the radiance median by the hat confidence of the level
        the vertex's first-pass radiance predicts in its frame, clipped samples
        censored (:func:`~reroom.hdr.reproject.reproject_radiance`); False: the
        thesis's weights from the sample's own level.
    """

    response: ResponseSpec = "auto"
    observe: ObserveOptions = field(default_factory=ObserveOptions)
    solve: SolveOptions = field(default_factory=SolveOptions)
    baselines: bool = True
    report: bool = True
    render_size: tuple[int, int] = (480, 360)
    predicted_weights: bool = True


@dataclass
class HdrResult:
    """What :func:`run_hdr` computed and where it wrote it.

    Attributes
    ----------
    out_dir:
        The output folder; ``files`` maps :data:`OUTPUT_FILES` keys to paths written.
    scales:
        ``(F, 3)`` per-frame per-channel scales ``t_j`` (``t_ref = 1``); NaN where
        a frame has no exposure.
    status:
        Per-frame status strings (see :class:`~reroom.hdr.solve.ExposureSolution`).
    radiance, observed, sample_count:
        Per-vertex HDR radiance ``(V, 3)`` (0 where unobserved), flag, count.
    baselines:
        ``{"frame-to-frame": (F, 3), "frame-to-model": (F, 3)}`` scales.
    warnings:
        Everything odd about the input, in words.
    timings:
        Seconds per step.
    """

    out_dir: Path
    files: dict[str, Path]
    scales: np.ndarray
    status: list[str]
    reference: int
    radiance: np.ndarray
    observed: np.ndarray
    sample_count: np.ndarray
    baselines: dict[str, np.ndarray]
    warnings: list[str]
    timings: dict[str, float]
    solver_info: dict[str, Any]


def _noop(stage: str, done: int, total: int) -> None:
    pass


def _json_scales(s: np.ndarray) -> list[float] | None:
    s = np.asarray(s, np.float64)
    return [float(v) for v in s] if np.all(np.isfinite(s)) else None


def run_hdr(
    scan_dir: str | Path,
    out_dir: str | Path,
    options: HdrOptions | None = None,
    progress: ProgressFn | None = None,
) -> HdrResult:
    """Calibrate a scan's frames radiometrically and write an HDR mesh.

    Parameters
    ----------
    scan_dir:
        A scan folder (``transforms.json``, frames, mesh).
    out_dir:
        Output folder (created). Written atomically:

        * ``hdr_mesh.ply`` -- the scan mesh with float per-vertex ``radiance``
          (``radiance_r/g/b``, linear, units of the reference frame's scale),
          ``observed`` (uint8 flag) and ``sample_count``;
        * ``hdr_radiance.exr`` -- the same radiance as an RGBA float image, vertex
          ``i`` at pixel ``(i // 1024, i % 1024)``, A = observed
          (:mod:`reroom.hdr.vertex_exr`);
        * ``exposures.json`` -- per frame: ``scale`` (per channel; null when the
          frame has no exposure), ``status``, sample counts, and the baselines'
          scales; solver information, options, warnings, timings;
        * ``hdr_extras.npz`` -- the naive best-frame texture, the baselines'
          scales and radiances, the flat-vertex mask and the samples of the seam
          metric (for evaluation and pictures);
        * ``report/`` -- ``hdr_exposures.png``, ``hdr_before_after.png``, ``report.md``.
    options:
        :class:`HdrOptions`.
    progress:
        ``progress(stage, done, total)`` callback.

    Returns
    -------
    HdrResult

    Raises
    ------
    ScanError
        If the scan is missing or malformed (see :func:`reroom.scan.load_scan`).
    ReroomError
        For bad options (an unknown response or solver).
    """
    opt = options or HdrOptions()
    progress = progress or _noop
    out = Path(out_dir)
    _check_dir(out)
    notes: list[str] = []
    timings: dict[str, float] = {}

    def note(msg: str) -> None:
        notes.append(msg)
        warnings.warn(msg, stacklevel=3)

    t0 = time.perf_counter()
    scan = load_scan(scan_dir)
    out.mkdir(parents=True, exist_ok=True)
    lut = response_lut(opt.response, scan.meta)
    response_name = resolve_response(opt.response, scan.meta)
    caster = RayCaster(scan.mesh)
    normals = vertex_normals(scan.mesh)
    timings["load"] = time.perf_counter() - t0

    t = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        obs = collect_observations(
            scan.frames, scan.mesh, lut, opt.observe, caster, progress, normals=normals
        )
    notes.extend(str(w.message) for w in caught)
    timings["reproject"] = time.perf_counter() - t

    t = time.perf_counter()
    progress("solve exposures", 0, 1)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sol = solve_exposures(obs, opt.solve)
    notes.extend(str(w.message) for w in caught)
    progress("solve exposures", 1, 1)
    timings["solve"] = time.perf_counter() - t
    _explain_frames(obs, sol, opt.solve, note)

    t = time.perf_counter()
    groups = VertexGroups(obs)
    rad = reproject_radiance(
        obs, sol.scales, groups, level_linear=lut if opt.predicted_weights else None
    )
    best = best_frame_texture(obs, groups)
    timings["radiance"] = time.perf_counter() - t
    n_unobs = int(np.count_nonzero(~rad.observed))
    if n_unobs == len(rad.observed):
        note("no vertex is observed by any calibrated frame: the HDR mesh is empty")
    seen_once = int(np.count_nonzero(rad.sample_count == 1))

    baselines: dict[str, np.ndarray] = {}
    baseline_rad: dict[str, Radiance] = {}
    if opt.baselines:
        t = time.perf_counter()
        progress("baselines", 0, 2)
        baselines["frame-to-frame"], _ = frame_to_frame(obs, opt.solve)
        progress("baselines", 1, 2)
        baselines["frame-to-model"], _ = frame_to_model(obs, opt.solve)
        progress("baselines", 2, 2)
        for name, s in baselines.items():
            baseline_rad[name] = reproject_radiance(obs, s, groups)
        timings["baselines"] = time.perf_counter() - t

    files: dict[str, Path] = {}
    files["mesh"] = write_ply(
        out / OUTPUT_FILES["mesh"],
        trimesh.Trimesh(scan.mesh.vertices, scan.mesh.faces, process=False),
        {
            "radiance": rad.radiance.astype(np.float32),
            "observed": rad.observed.astype(np.uint8),
            "sample_count": rad.sample_count.astype(np.int32),
        },
    )
    files["radiance_exr"] = write_vertex_exr(
        out / OUTPUT_FILES["radiance_exr"], rad.radiance, rad.observed
    )
    edges = np.asarray(scan.mesh.edges_unique)
    flat = flat_vertices(edges, normals)
    # The seam metric compares each vertex with itself in two frames, so texture and
    # shading cancel and every surface can take part (evaluation picks flat walls).
    seam_set = seam_samples(obs, np.ones(obs.n_vertices, bool))
    extras = {
        "best_frame": best.frame.astype(np.int32),
        "best_value": best.value,
        "best_linear": best.linear,
        "flat": flat,
        **seam_set.to_npz(),
        "scales": sol.scales,
        **{f"scales_{_key(k)}": v for k, v in baselines.items()},
        **{f"radiance_{_key(k)}": r.radiance.astype(np.float32) for k, r in baseline_rad.items()},
    }
    with atomic_path(out / OUTPUT_FILES["extras"]) as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, **extras)
    files["extras"] = out / OUTPUT_FILES["extras"]

    if opt.report:
        t = time.perf_counter()
        progress("report", 0, 1)
        files.update(
            _write_report(
                out,
                scan,
                caster,
                lut,
                sol,
                rad,
                best,
                baselines,
                baseline_rad,
                opt,
                notes,
                seam_set,
                flat,
            )
        )
        progress("report", 1, 1)
        timings["report"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - t0

    doc = {
        "format": "reroom-hdr-exposures",
        "version": 1,
        "scan": str(scan.root),
        "response": response_name,
        "reference_frame": sol.reference,
        "units": (
            "scale = t_j of eq. 3.1 per channel: linear pixel value = scale x radiance; "
            "the reference frame has scale 1, so radiance is in its linear pixel units"
        ),
        "frames": [
            {
                "index": j,
                "file": str(Path(f.image_path).relative_to(scan.root))
                if Path(f.image_path).is_relative_to(scan.root)
                else str(f.image_path),
                "scale": _json_scales(sol.scales[j]),
                "status": sol.status[j],
                "samples_solve": int(sol.samples[j]),
                "samples_kept": int(obs.frame_stats["kept"][j]),
                "samples_clean": int(obs.frame_stats.get("clean", obs.frame_stats["kept"])[j]),
                "candidates": int(obs.frame_stats["candidates"][j]),
                "visible": int(obs.frame_stats["visible"][j]),
                **{_key(k): _json_scales(v[j]) for k, v in baselines.items()},
            }
            for j, f in enumerate(scan.frames)
        ],
        "vertices": {
            "total": int(obs.n_vertices),
            "observed": int(obs.n_vertices - n_unobs),
            "unobserved": n_unobs,
            "seen_once": seen_once,
        },
        "samples": int(len(obs)),
        "solver": sol.info,
        "options": _options_json(opt),
        "warnings": notes,
        "timings_s": {k: round(v, 3) for k, v in timings.items()},
    }
    files["exposures"] = atomic_write_json(out / OUTPUT_FILES["exposures"], doc)
    return HdrResult(
        out_dir=out,
        files=files,
        scales=sol.scales,
        status=sol.status,
        reference=sol.reference,
        radiance=rad.radiance,
        observed=rad.observed,
        sample_count=rad.sample_count,
        baselines=baselines,
        warnings=notes,
        timings=timings,
        solver_info=sol.info,
    )


def _key(name: str) -> str:
    return name.replace("-", "_")


def _options_json(opt: HdrOptions) -> dict:
    d = asdict(opt)
    if not isinstance(opt.response, str | Path):
        d["response"] = "user curve (256 values)"
    else:
        d["response"] = str(opt.response)
    return d


def _explain_frames(
    obs: Observations, sol: ExposureSolution, opt: SolveOptions, note: Callable[[str], None]
) -> None:
    """Say why each frame without an exposure has none."""
    usable = usable_samples(obs, opt)
    missing = [j for j in range(obs.n_frames) if not sol.solved[j]]
    reasons: dict[str, list[int]] = {}
    for j in missing:
        s, e = obs.frame_offsets[j], obs.frame_offsets[j + 1]
        err = obs.frame_stats.get("error", [""] * obs.n_frames)[j]
        if err:
            why = "image unreadable"
        elif e == s:
            why = "sees no usable part of the mesh"
        elif not usable[s:e].any():
            vals = obs.value[s:e]
            if np.mean(vals.max(axis=1) > opt.max_level) > 0.5:
                why = "saturated where it sees the mesh"
            else:
                why = "too dark where it sees the mesh"
        else:
            why = "shares no usable vertex with other frames"
        reasons.setdefault(why, []).append(j)
    for why, frames in reasons.items():
        shown = ", ".join(map(str, frames[:10])) + (" ..." if len(frames) > 10 else "")
        note(f"{len(frames)} frame(s) got no exposure ({why}): {shown}")
    if sol.reference > 0 and opt.reference == 0:
        note(f"frame 0 has no exposure; frame {sol.reference} is the reference (scale 1)")


def _write_report(
    out: Path,
    scan: Scan,
    caster: RayCaster,
    lut: np.ndarray,
    sol: ExposureSolution,
    rad: Radiance,
    best: BestFrame,
    baselines: dict[str, np.ndarray],
    baseline_rad: dict[str, Radiance],
    opt: HdrOptions,
    notes: list[str],
    seam_set,
    flat: np.ndarray,
) -> dict[str, Path]:
    from reroom.hdr.report import write_report

    return write_report(
        out,
        scan,
        caster,
        lut,
        sol,
        rad,
        best,
        baselines,
        baseline_rad,
        opt.render_size,
        notes,
        seam_set,
        flat,
    )


def _check_dir(path: Path) -> None:
    if path.exists() and not path.is_dir():
        raise ReroomError(f"{path}: exists and is not a folder")
