"""``reroom run SCAN``: every stage, end to end, resumable, with a report.

The stages, in order, each writing a folder of the *run folder*:

* ``hdr`` -- radiometric calibration (:mod:`reroom.hdr`), ``hdr/``;
* ``layout`` -- room layout (:mod:`reroom.layout`), ``layout/``;
* ``lights`` -- light detection (:mod:`reroom.lights`), ``lights/``;
* ``invert`` -- inverse rendering (:mod:`reroom.invert`), ``invert/``;
* ``rerender`` -- input frames re-rendered from the model, ``rerender/``;
* ``edits`` -- the default edit sets and ``--edits`` rendered (:mod:`reroom.edit`), ``edits/``;
* ``report`` -- ``report.html`` (:mod:`reroom.report`), its record in ``report/``.

The run folder is the scan folder itself, or ``--out DIR``: then ``DIR`` receives
symbolic links to the scan's own files (``transforms.json``, the frames, the mesh,
``ground_truth/``) and every stage writes there, so the scan is never written into.
The stages read each other's outputs from the run folder exactly as the single-stage
commands do.

Resumability is :func:`reroom.runner.run_stages`: each stage's inputs (files) and
options are fingerprinted; a stage whose fingerprint and outputs are unchanged is
skipped. When a stage fails the stages before it keep their results (and their
records, so the next run skips them), the failing stage is named, and the report is
still written with what exists.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from reroom.errors import ReroomError, ScanError
from reroom.io.atomic import atomic_write_json
from reroom.runner import RECORD_NAME, Stage, StageResult, run_stages

__all__ = [
    "STAGES",
    "RESERVED",
    "RunOptions",
    "RunResult",
    "build_stages",
    "load_edit_file",
    "prepare_run_dir",
    "run_scan",
]

ProgressFn = Callable[[str, int, int], None]

#: The stages of a run, in order.
STAGES = ("hdr", "layout", "lights", "invert", "rerender", "edits", "report")

#: A captured view of the windows that a scan folder may hold (docs/formats.md): used
#: as ``RunOptions.window_view`` when none is given.
WINDOW_VIEW_FILE = "window_view.exr"

#: Names in a run folder that belong to the run (never linked from the scan).
RESERVED = frozenset({*STAGES, "report.html", "localize", "render", "run.json", "model_meshes"})


@dataclass
class RunOptions:
    """Options of :func:`run_scan` (the ``reroom run`` flags).

    Attributes
    ----------
    out_dir:
        Run folder (``None``: the scan folder itself).
    edits_file:
        An edit file (``{"format": "reroom-edits", "version": 1, "edits": [...]}``)
        rendered as one more edit set, named after the file.
    frames_to_render:
        Input frames (spread over those with an exposure: the middles of equal stretches) that the re-render and
        the edit renders are made from.
    spp:
        Path-tracing samples per pixel of the re-renders and edit renders; ``None``
        (default): about a million samples a view (:func:`reroom.render.frames.auto_spp`:
        16 at 160 x 120, 4 at 640 x 360), enough once denoised.
    denoise:
        Denoise those renders (OIDN, :func:`reroom.render.denoise.denoise`).
    default_edits:
        Render the default edit sets (``reroom.edit.default_edit_sets``).
    hdr_baselines:
        Also run the HDR stage's frame-to-frame and frame-to-model baselines (their
        exposure curves then appear in the report; off by default: they cost time and
        no later stage uses them).
    invert_rays:
        Hemisphere rays per receiving vertex of the inverse rendering.
    invert_voxel:
        One hemisphere receiver per voxel of this size, metres.
    evaluate:
        Where the scan has ``ground_truth/``, put each stage's errors in the report.
    localize:
        After detecting lights, localize point lights from the lit walls and ceiling
        (``reroom localize --into-lights``, thesis ch. 6) and merge them into
        ``lights.json``, so that lights with no visible emitter (a recessed downlight)
        reach the inverse rendering. On by default (it adds 20-80 s on a small scan):
        without it nothing places point lights that have no visible emitter, and the
        inverse rendering pushes their light into the albedos (the 24-frame demo scan:
        wall +24-28 % and floor +51-79 % without, +3-4 % and +3-10 % with;
        docs/run.md). ``--no-localize`` skips it.
    window_view:
        An HDRI of the view outside the windows, taken at a window (EXR,
        equirectangular in the scan's frame, any overall scale): the inverse rendering
        weights each window cube cell's transfer by its pattern within the cell, and the
        renders spread each solved cell as it does (``InvertOptions.window_view_hdri``,
        docs/invert.md "A captured view of the window"). The frames clip what they see
        through a window and cannot give that pattern; on `furnished` and `box_points`
        the view brings every albedo within 2.2 % and 1.9 % (docs/benchmarks.md,
        sessions 19 and 25). Its content is an input of the invert stage.
        Without it, the scan folder's ``window_view.exr`` is taken when there is one
        (:data:`WINDOW_VIEW_FILE`: a capture app may leave it there).
    window_view_rotation_deg:
        That HDRI's turn about the up axis, degrees.
    """

    out_dir: Path | None = None
    edits_file: Path | None = None
    frames_to_render: int = 2
    spp: int | None = None
    denoise: bool = True
    default_edits: bool = True
    hdr_baselines: bool = False
    invert_rays: int = 512
    invert_voxel: float = 0.1
    evaluate: bool = True
    localize: bool = True
    window_view: Path | None = None
    window_view_rotation_deg: float = 0.0


@dataclass
class RunResult:
    """What :func:`run_scan` did.

    Attributes
    ----------
    run_dir:
        The run folder.
    results:
        One :class:`~reroom.runner.StageResult` per stage reached.
    report:
        Path of ``report.html`` (``None`` if even the report could not be written).
    failed:
        The first failed stage's result, or ``None``.
    seconds:
        Wall-clock seconds of the whole run.
    notes:
        Problems beside the stages' own (the report of a failed run not written).
    """

    run_dir: Path
    results: list[StageResult]
    report: Path | None
    failed: StageResult | None = None
    seconds: float = 0.0
    notes: list[str] = field(default_factory=list)


def prepare_run_dir(scan_dir: str | Path, out_dir: str | Path | None) -> Path:
    """The folder the stages work in: the scan, or ``out_dir`` linked to the scan's files.

    Parameters
    ----------
    scan_dir:
        The scan folder (must hold ``transforms.json``).
    out_dir:
        ``None`` or the scan folder itself: run in place. Otherwise ``out_dir`` is
        created and gets a symbolic link to each top-level entry of the scan except the
        run's own output names (:data:`RESERVED`), so the scan is only read.

    Raises
    ------
    ScanError
        If ``scan_dir`` is not a scan, or ``out_dir`` already holds a different scan
        (a real ``transforms.json`` or an entry of the same name that is not our link).
    """
    scan = Path(scan_dir)
    if not (scan / "transforms.json").is_file():
        raise ScanError(scan / "transforms.json", "is missing: not a scan folder")
    if out_dir is None:
        return scan
    out = Path(out_dir)
    if out.exists() and out.resolve() == scan.resolve():
        return scan
    if out.exists() and not out.is_dir():
        raise ScanError(out, "exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    src_root = scan.resolve()
    for entry in sorted(src_root.iterdir()):
        if entry.name in RESERVED or entry.name.startswith("."):
            continue
        if out.resolve().is_relative_to(entry.resolve()):
            continue  # the run folder is (inside) this entry of the scan: no link loop
        link = out / entry.name
        if link.is_symlink():
            if link.resolve() == entry.resolve():
                continue
            link.unlink()  # ours, pointing at a scan that moved: refresh
        elif link.exists():
            raise ScanError(
                link,
                f"exists and is not a link to {entry}: --out must be a new folder or an "
                "earlier run folder of the same scan",
            )
        os.symlink(entry, link, target_is_directory=entry.is_dir())
    return out


def load_edit_file(path: str | Path) -> tuple[str, list[dict]]:
    """Read and check an edit file; return ``(set name, ops)``, the name being the file's stem.

    The checks are :func:`reroom.edit.load_edits` (format, version, every op and its
    keys; relative texture, HDRI, IES and mesh names resolve against the file's folder).

    Raises
    ------
    ReroomError
        Naming the file: unreadable, not JSON, not an edit file, or a bad edit.
    """
    from reroom.edit import load_edits

    return Path(path).stem, load_edits(path)


def _scan_files(run: Path) -> list[Path]:
    """transforms.json, the mesh and every frame (images, depth) of the scan in ``run``.

    Loading the scan validates it, so a malformed one fails here naming the file.
    """
    from reroom.scan import load_scan

    scan = load_scan(run, check_images=False)
    files = [run / "transforms.json", scan.mesh_path]
    for f in scan.frames:
        files.append(Path(f.image_path))
        if f.depth_path is not None:
            files.append(Path(f.depth_path))
    return files


def _folder_files(folder: Path) -> list[Path]:
    """The files a stage wrote into ``folder`` (not its record), sorted."""
    if not folder.is_dir():
        return [folder]
    return sorted(
        p
        for p in folder.rglob("*")
        if p.is_file() and p.name != RECORD_NAME and "model_meshes" not in p.parts
    )


def render_frames(run: Path, count: int) -> list[int]:
    """``count`` frame indices spread over the frames the HDR stage gave an exposure
    (:func:`reroom.edit.rerender.spread_frames`)."""
    path = run / "hdr" / "exposures.json"
    try:
        doc = json.loads(path.read_text())
    except OSError as exc:
        raise ScanError(path, "is missing: the HDR stage has not run") from exc
    usable = [j for j, f in enumerate(doc.get("frames", [])) if f.get("scale") is not None]
    if not usable:
        raise ScanError(path, "gives no frame an exposure: nothing to render at")
    from reroom.edit.rerender import spread_frames

    # The same choice as reroom.edit.rerender_inputs, so edits and re-renders share frames.
    return spread_frames(usable, count)


def render_spp(run: Path, options: RunOptions) -> int:
    """The re-renders' and edit renders' samples per pixel: ``options.spp``, or by the
    first frame's size (:func:`reroom.render.frames.auto_spp`)."""
    if options.spp is not None:
        return int(options.spp)
    from reroom.render.frames import auto_spp
    from reroom.scan import load_scan

    intr = load_scan(run, check_images=False).frames[0].intrinsics
    return auto_spp(intr.width, intr.height)


def _safe_name(name: str) -> str:
    keep = "".join(c if c.isalnum() or c in "-_." else "_" for c in name).strip("._")
    return keep or "edit"


def _jsonable(obj: Any) -> Any:
    """``obj`` as plain JSON data (arrays as lists, paths and the rest as strings)."""
    return json.loads(
        json.dumps(obj, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))
    )


def build_stages(
    run: Path, options: RunOptions, results: list[StageResult] | None = None
) -> list[Stage]:
    """The stages of a run in ``run`` (see the module docstring), upstream first.

    Parameters
    ----------
    run:
        The run folder (:func:`prepare_run_dir`).
    options:
        :class:`RunOptions`.
    results:
        The results of this run's stages so far, shown in the report (the list is read
        when the report stage runs, so it may still be filled after this call).
    """
    from reroom.hdr.pipeline import OUTPUT_FILES as HDR_FILES
    from reroom.hdr.pipeline import HdrOptions
    from reroom.invert.pipeline import InvertOptions
    from reroom.layout.pipeline import OUTPUT_FILES as LAYOUT_FILES
    from reroom.layout.pipeline import LayoutOptions
    from reroom.lights import LightsOptions

    scan_files = _scan_files(run)
    hdr_dir, layout_dir, lights_dir = run / "hdr", run / "layout", run / "lights"
    invert_dir, rerender_dir, edits_dir = run / "invert", run / "rerender", run / "edits"
    hdr_opt = HdrOptions(baselines=options.hdr_baselines, report=True)
    layout_opt = LayoutOptions(radiance=hdr_dir / HDR_FILES["mesh"])
    lights_opt = LightsOptions()
    view = None if options.window_view is None else Path(options.window_view).resolve()
    invert_opt = InvertOptions(
        rays_per_receiver=options.invert_rays,
        receiver_voxel=options.invert_voxel,
        window_view_hdri=None if view is None else str(view),
        window_view_rotation_deg=options.window_view_rotation_deg,
    )
    hdr_out = [hdr_dir / HDR_FILES[k] for k in ("mesh", "exposures", "extras")]
    layout_out = [layout_dir / LAYOUT_FILES[k] for k in ("layout", "labels")]
    lights_out = [lights_dir / "lights.json", lights_dir / "lights_vertices.npz"]
    invert_out = [invert_dir / "scene.json", invert_dir / "albedo.ply"]

    def run_hdr(cb: ProgressFn) -> None:
        from reroom.hdr.pipeline import run_hdr as _run

        _run(run, hdr_dir, hdr_opt, progress=cb)

    def run_layout(cb: ProgressFn) -> None:
        from reroom.layout.pipeline import run_layout as _run

        _run(run, layout_dir, layout_opt, progress=cb)

    def run_lights(cb: ProgressFn) -> None:
        from reroom.lights import check_user_lights, detect_lights, write_lights

        result = detect_lights(run, hdr_dir, layout_dir, lights_opt, progress=cb)
        check_user_lights(result)
        write_lights(result, lights_dir)
        if options.localize:
            from reroom.localize.scan import (
                ScanLocalizeOptions,
                localize_into_lights,
                localize_scan,
                write_localized_lights,
            )

            cb("localize", 0, 1)
            res, info = localize_scan(run, ScanLocalizeOptions(), progress=cb)
            write_localized_lights(res, info, run / "localize")
            localize_into_lights(run, res, info, lights_dir)
            cb("localize", 1, 1)

    def run_inv(cb: ProgressFn) -> None:
        from reroom.invert.pipeline import run_invert

        run_invert(run, invert_dir, invert_opt, progress=cb)

    def run_rerender(cb: ProgressFn) -> None:
        from reroom.edit.rerender import rerender_inputs

        cb("rerender", 0, 1)
        rerender_inputs(
            run,
            invert_dir,
            lights_dir,
            frames=options.frames_to_render,
            spp=render_spp(run, options),
            out_dir=rerender_dir,
            denoise=options.denoise,
        )
        cb("rerender", 1, 1)

    def run_edits(cb: ProgressFn) -> None:
        sets: dict[str, list[dict]] = {}
        from reroom.edit import default_edit_sets, render_edit

        if options.default_edits:
            sets.update(
                default_edit_sets(
                    run, invert_dir=invert_dir, lights_dir=lights_dir, layout_dir=layout_dir
                )
            )
        if options.edits_file is not None:
            name, ops = load_edit_file(options.edits_file)
            sets[name] = ops
        frames = render_frames(run, options.frames_to_render)
        spp = render_spp(run, options)
        entries = []
        cb("edits", 0, len(sets))
        for k, (name, ops) in enumerate(sets.items()):
            t = time.perf_counter()
            folder = edits_dir / _safe_name(name)
            try:
                info = render_edit(
                    run,
                    ops,
                    folder,
                    frames=frames,
                    spp=spp,
                    denoise=options.denoise,
                    name=_safe_name(name),
                    invert_dir=invert_dir,
                    lights_dir=lights_dir,
                    layout_dir=layout_dir,
                    progress=lambda _s, d, n_views, n=name: cb(f"edit {n}", d, n_views),
                )
            except ReroomError as exc:
                # Name the edit set: the error itself names the op and the file.
                raise ReroomError(f"edit set {name!r}: {exc}") from exc
            entries.append(
                {
                    "name": name,
                    "folder": folder.name,
                    "edits": ops,
                    "frames": frames,
                    "seconds": round(time.perf_counter() - t, 3),
                    "result": _jsonable(info),
                }
            )
            cb("edits", k + 1, len(sets))
        atomic_write_json(
            edits_dir / "edits.json",
            {
                "format": "reroom-run-edits",
                "version": 1,
                "spp": spp,
                "denoised": options.denoise,
                "sets": entries,
            },
        )

    def run_report(cb: ProgressFn) -> None:
        from reroom.report import write_report

        cb("report", 0, 1)
        write_report(run, evaluate=options.evaluate, results=results)
        cb("report", 1, 1)

    def edit_inputs() -> list[Path]:
        files = [*_folder_files(invert_dir), *lights_out, *layout_out]
        files += [layout_dir / LAYOUT_FILES["empty_room"], hdr_dir / HDR_FILES["exposures"]]
        if options.edits_file is not None:
            files.append(Path(options.edits_file))
        return files

    def rerender_inputs() -> list[Path]:
        return [
            *_folder_files(invert_dir),
            *lights_out,
            *scan_files,
            hdr_dir / HDR_FILES["exposures"],
        ]

    edit_options = {
        "frames_to_render": options.frames_to_render,
        "spp": options.spp,
        "denoise": options.denoise,
        "default_edits": options.default_edits,
        # The file's content is an input; its name only names the edit set.
        "edits_file": Path(options.edits_file).stem if options.edits_file else None,
    }
    stages = [
        Stage("hdr", hdr_dir, scan_files, _options(hdr_opt), hdr_out, run_hdr),
        Stage(
            "layout",
            layout_dir,
            [*scan_files, hdr_dir / HDR_FILES["mesh"]],
            # The HDR mesh's path is an input file; in the options it would tie the
            # fingerprint to where the run folder is.
            {**_options(layout_opt), "radiance": "hdr/hdr_mesh.ply"},
            layout_out,
            run_layout,
        ),
        Stage(
            "lights",
            lights_dir,
            [*scan_files, *hdr_out, *layout_out],
            {**_options(lights_opt), "localize": options.localize},
            lights_out,
            run_lights,
        ),
        Stage(
            "invert",
            invert_dir,
            # A captured window view is an input file (its content counts, as the edit
            # file's); in the options only its name, as the HDR mesh's path above.
            [hdr_dir / HDR_FILES["mesh"], *layout_out, *lights_out, *([view] if view else [])],
            {**_options(invert_opt), "window_view_hdri": view.name if view else None},
            invert_out,
            run_inv,
        ),
        Stage(
            "rerender",
            rerender_dir,
            rerender_inputs,
            {"frames": options.frames_to_render, "spp": options.spp, "denoise": options.denoise},
            [rerender_dir / "rerender.json", rerender_dir / "rerender.png"],
            run_rerender,
        ),
        Stage("edits", edits_dir, edit_inputs, edit_options, [edits_dir / "edits.json"], run_edits),
    ]
    # The report depends on everything before it: their records change whenever they run.
    report_inputs = [s.out_dir / RECORD_NAME for s in stages]
    stages.append(
        Stage(
            "report",
            run / "report",
            report_inputs,
            {"evaluate": options.evaluate},
            [run / "report.html"],
            run_report,
        )
    )
    return stages


def _options(opt: Any) -> dict[str, Any]:
    """A dataclass of options as JSON-able data (paths as strings)."""
    return json.loads(json.dumps(asdict(opt), default=str))


def run_scan(
    scan_dir: str | Path,
    options: RunOptions | None = None,
    *,
    force: tuple[str, ...] | list[str] = (),
    progress: ProgressFn | None = None,
) -> RunResult:
    """Run every stage on a scan, skipping those whose inputs did not change.

    Parameters
    ----------
    scan_dir:
        The scan folder.
    options:
        :class:`RunOptions`.
    force:
        Stage names to run even when unchanged (``"all"``: every stage).
    progress:
        ``progress(stage, done, total)``; the run itself reports as ``"run"`` (stages done).

    Returns
    -------
    RunResult
        With ``failed`` set when a stage failed; the report is written in any case
        (it shows what exists and names the failed stage).

    Raises
    ------
    ReroomError
        For bad options (an unknown stage in ``force``, a bad edit file, a window view
        that cannot be read), a scan that is not one, or a run folder that holds another
        scan.
    """
    opt = options or RunOptions()
    cb = progress or (lambda s, d, t: None)
    unknown = sorted(set(force) - set(STAGES) - {"all"})
    if unknown:
        raise ReroomError(
            f"--force: unknown stage {', '.join(unknown)} (stages: {', '.join(STAGES)})"
        )
    if opt.edits_file is not None:
        load_edit_file(opt.edits_file)  # bad edit files fail before any work
    notes: list[str] = []
    given = "--window-view"
    if opt.window_view is None and (Path(scan_dir) / WINDOW_VIEW_FILE).is_file():
        opt = replace(opt, window_view=Path(scan_dir) / WINDOW_VIEW_FILE)
        notes.append(f"the scan's {WINDOW_VIEW_FILE} is the captured view of its windows")
        given = f"the scan's {WINDOW_VIEW_FILE}"
    if opt.window_view is not None:
        _check_window_view(Path(opt.window_view), given)
    t0 = time.perf_counter()
    run = prepare_run_dir(scan_dir, opt.out_dir)
    results: list[StageResult] = []
    done = 0
    # One stage at a time, so the report stage sees the results of those before it.
    for stage in build_stages(run, opt, results):
        cb("run", done, len(STAGES))
        res = run_stages([stage], force=force, progress=cb, root=run)
        results.extend(res)
        done += 1
        cb("run", done, len(STAGES))
        if res and res[-1].status == "failed":
            break
    failed = next((r for r in results if r.status == "failed"), None)
    seconds = time.perf_counter() - t0
    _write_run_json(run, results, seconds)
    report: Path | None = run / "report.html"
    if failed is not None:
        from reroom.report import write_report

        try:
            report = write_report(run, evaluate=opt.evaluate, results=results)
        except Exception as exc:  # the report must not hide the stage's own error
            notes.append(f"the report could not be written either: {exc}")
            report = None
    return RunResult(run, results, report, failed, seconds, notes)


def _check_window_view(path: Path, given: str = "--window-view") -> None:
    """A window view that cannot be read fails before any work, naming the file and
    where it came from, ``given`` (the inverse rendering's own check,
    :func:`reroom.invert.window_env.read_view_hdri`)."""
    from reroom.invert.window_env import read_view_hdri

    try:
        read_view_hdri(path)
    except ScanError as exc:
        raise ReroomError(f"{given}: {exc}") from exc


def _write_run_json(run: Path, results: list[StageResult], seconds: float) -> None:
    """``run.json``: what the last run did per stage (the report's timing table)."""
    atomic_write_json(
        run / "run.json",
        {
            "format": "reroom-run",
            "version": 1,
            "finished": time.strftime("%Y-%m-%dT%H:%M:%S"),
            "seconds": round(seconds, 3),
            "stages": [
                {
                    "name": r.name,
                    "status": r.status,
                    "seconds": round(r.seconds, 3),
                    "reason": r.reason,
                }
                for r in results
            ],
        },
    )
