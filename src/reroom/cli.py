"""The ``reroom`` command-line tool (typer + rich)."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.table import Table

from reroom.errors import ReroomError

app = typer.Typer(
    name="reroom",
    help="Turn a room scan into an editable model of its light and materials, and render edits of it.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
console = Console(stderr=True)


@contextlib.contextmanager
def _errors() -> Iterator[None]:
    """Print expected errors as one readable line and exit 1, instead of a traceback."""
    try:
        yield
    except (ReroomError, FileNotFoundError, ValueError) as exc:
        console.print(f"[bold red]error:[/] {exc}")
        raise typer.Exit(1) from exc


@contextlib.contextmanager
def _progress() -> Iterator:
    """A rich progress display and a ``callback(stage, done, total)`` that drives it."""
    tasks: dict[str, int] = {}
    with Progress(
        TextColumn("[bold]{task.description:<16}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=console,
        transient=False,
    ) as bar:

        def callback(stage: str, done: int, total: int) -> None:
            if stage not in tasks:
                tasks[stage] = bar.add_task(stage, total=total)
            bar.update(tasks[stage], completed=done, total=total)

        yield callback


@app.command()
def doctor() -> None:
    """Print the environment: Mitsuba variant, LLVM, ray engine, threads, versions."""
    from reroom.doctor import check_mitsuba_works, environment_report

    table = Table(title="reroom doctor", show_header=False)
    for k, v in environment_report().items():
        table.add_row(k, v)
    ok, msg = check_mitsuba_works()
    table.add_row("mitsuba check", ("[green]ok[/] " if ok else "[red]FAILED[/] ") + msg)
    Console().print(table)
    if not ok:
        raise typer.Exit(1)


@app.command()
def synth(
    preset: Annotated[str, typer.Argument(help="box | box_points | furnished | lshape | tworooms")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Scan folder to write.")],
    frames: Annotated[int, typer.Option(help="Number of frames.")] = 24,
    width: Annotated[int, typer.Option(help="Frame width in pixels.")] = 160,
    height: Annotated[int, typer.Option(help="Frame height in pixels.")] = 120,
    fov: Annotated[float, typer.Option(help="Vertical field of view, degrees.")] = 60.0,
    spp: Annotated[
        int,
        typer.Option(
            help="Path-tracing samples per pixel (perfect squares use a multi-jittered sampler). "
            "Below 64 the renderer's noise clips at the white level and the frames lose "
            "light, most in their brightest channel (docs/architecture.md)."
        ),
    ] = 64,
    vertex_spp: Annotated[
        int, typer.Option(help="Samples per vertex for the true radiance.")
    ] = 256,
    seed: Annotated[int, typer.Option(help="Random seed (trajectory, noise, sampling).")] = 0,
    hdri: Annotated[
        str, typer.Option(help="Outdoor HDRI behind the windows: a shipped name or an .exr.")
    ] = "courtyard",
    lights: Annotated[
        str | None, typer.Option(help="Comma-separated names of lights left on (default all).")
    ] = None,
    mesh: Annotated[
        str, typer.Option(help="clean | corrupted | fused (TSDF from rendered depth).")
    ] = "clean",
    grid_yaw: Annotated[
        float | None,
        typer.Option(
            help="fused: the voxel grid's turn about the vertical, degrees "
            "(default: synth.scanner.GRID_YAW_DEG, 17)."
        ),
    ] = None,
    noise: Annotated[bool, typer.Option(help="Shot and read noise in the frames.")] = True,
    response: Annotated[
        str, typer.Option(help="Camera response: gamma2.2 | srgb | linear.")
    ] = "gamma2.2",
    save_hdr: Annotated[
        bool, typer.Option(help="Also save the linear frames as EXR in ground_truth/hdr.")
    ] = False,
    sheet: Annotated[bool, typer.Option(help="Write contact_sheet.png of the frames.")] = True,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing scan in --out.")] = False,
) -> None:
    """Generate a synthetic scan with ground truth, path-traced with Mitsuba 3."""
    from reroom.synth.camera_sim import CameraModel
    from reroom.synth.generate import SynthOptions, generate_scan

    with _errors():
        opts = SynthOptions(
            frames=frames,
            width=width,
            height=height,
            fov_y_deg=fov,
            spp=spp,
            vertex_spp=vertex_spp,
            seed=seed,
            hdri=hdri,
            lights=None if lights is None else [s.strip() for s in lights.split(",") if s.strip()],
            mesh=mesh,
            camera=CameraModel(response=response, noise=noise),
            save_hdr=save_hdr,
            **({} if grid_yaw is None else {"grid_yaw_deg": grid_yaw}),
        )
        t = time.perf_counter()
        with _progress() as cb:
            generate_scan(preset, out, opts, progress=cb, overwrite=overwrite)
        console.print(f"[green]wrote[/] {out} ({frames} frames) in {time.perf_counter() - t:.1f} s")
        if sheet:
            _write_sheet(out, out / "contact_sheet.png")


def _write_sheet(scan_dir: Path, path: Path) -> None:
    from reroom.scan import load_scan
    from reroom.viz import contact_sheet

    scan = load_scan(scan_dir)
    step = max(1, len(scan.frames) // 24)
    chosen = scan.frames[::step][:24]
    contact_sheet([f.load_image() for f in chosen], path, labels=[str(f.index) for f in chosen])
    console.print(f"[green]wrote[/] {path}")


@app.command()
def info(
    scan: Annotated[Path, typer.Argument(help="Scan folder (or its transforms.json).")],
) -> None:
    """Load and validate a scan, and summarise it."""
    from reroom.scan import load_scan

    with _errors():
        s = load_scan(scan)
        m = s.mesh
        k = s.frames[0].intrinsics
        table = Table(title=str(s.root), show_header=False)
        table.add_row("frames", str(len(s.frames)))
        table.add_row("image size", f"{k.width} x {k.height} ({k.model}, fx {k.fx:.1f})")
        table.add_row("depth maps", "yes" if s.frames[0].depth_path else "no")
        table.add_row(
            "mesh", f"{s.mesh_path.name}: {len(m.vertices)} vertices, {len(m.faces)} faces"
        )
        lo, hi = m.bounds
        table.add_row("mesh extent (m)", " x ".join(f"{x:.2f}" for x in hi - lo))
        table.add_row("ground truth", "yes" if s.has_ground_truth else "no")
        Console().print(table)


@app.command()
def sheet(
    scan: Annotated[Path, typer.Argument(help="Scan folder.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="PNG to write.")] = Path(
        "contact_sheet.png"
    ),
) -> None:
    """Write a contact sheet of a scan's frames."""
    with _errors():
        _write_sheet(scan, out)


@app.command("import-rgbd")
def import_rgbd(
    folder: Annotated[
        Path, typer.Argument(help="Folder with color/, depth/, pose.txt and intrinsics.json.")
    ],
    out: Annotated[Path, typer.Option("--out", "-o", help="Scan folder to write.")],
    voxel_size: Annotated[float, typer.Option(help="TSDF voxel size, metres.")] = 0.02,
) -> None:
    """Fuse a posed RGB-D sequence into a mesh (TSDF) and write it as a scan."""
    from reroom.importers import import_rgbd_folder

    with _errors(), _progress() as cb:
        import_rgbd_folder(
            folder, out, voxel_size=voxel_size, progress=lambda d, n: cb("fuse frames", d, n)
        )
    console.print(f"[green]wrote[/] {out}")


@app.command()
def hdr(
    scan: Annotated[Path, typer.Argument(help="Scan folder.")],
    out: Annotated[
        Path | None, typer.Option("--out", "-o", help="Output folder (default SCAN/hdr).")
    ] = None,
    response: Annotated[
        str, typer.Option(help="auto | gamma2.2 | srgb | linear | gamma<g> | a file of 256 values.")
    ] = "auto",
    baselines: Annotated[
        bool, typer.Option(help="Also run the frame-to-frame and frame-to-model baselines.")
    ] = True,
    report: Annotated[bool, typer.Option(help="Write the report pictures.")] = True,
) -> None:
    """Radiometric calibration: per-frame exposures and an HDR radiance mesh (thesis ch. 3)."""
    from reroom.hdr.pipeline import HdrOptions, run_hdr

    out = out or scan / "hdr"
    with _errors(), _progress() as cb:
        run_hdr(
            scan,
            out,
            HdrOptions(response=response, baselines=baselines, report=report),
            progress=cb,
        )
    console.print(f"[green]wrote[/] {out}")


@app.command()
def layout(
    scan: Annotated[Path, typer.Argument(help="Scan folder.")],
    out: Annotated[
        Path | None, typer.Option("--out", "-o", help="Output folder (default SCAN/layout).")
    ] = None,
    radiance: Annotated[
        Path | None,
        typer.Option(help="HDR mesh PLY with a radiance attribute (finds bright windows)."),
    ] = None,
    features: Annotated[
        bool, typer.Option(help="Find baseboards, doors and windows from the frames.")
    ] = True,
) -> None:
    """Room layout: Manhattan frame, floor, ceiling, walls, floorplan, labels, features (thesis ch. 4)."""
    from reroom.layout.pipeline import LayoutOptions, run_layout

    out = out or scan / "layout"
    if radiance is None and (scan / "hdr" / "hdr_mesh.ply").is_file():
        radiance = scan / "hdr" / "hdr_mesh.ply"
    with _errors(), _progress() as cb:
        run_layout(scan, out, LayoutOptions(radiance=radiance, features=features), progress=cb)
    console.print(f"[green]wrote[/] {out}")


@app.command()
def lights(
    scan: Annotated[Path, typer.Argument(help="Scan folder.")],
    out: Annotated[
        Path | None, typer.Option("--out", "-o", help="Output folder (default SCAN/lights).")
    ] = None,
    hdr_dir: Annotated[
        Path | None, typer.Option("--hdr", help="Output of `reroom hdr` (default SCAN/hdr).")
    ] = None,
    layout_dir: Annotated[
        Path | None,
        typer.Option("--layout", help="Output of `reroom layout` (default SCAN/layout)."),
    ] = None,
    threshold: Annotated[
        float | None,
        typer.Option(help="Absolute HDR luminance threshold (default: automatic)."),
    ] = None,
    threshold_factor: Annotated[
        float, typer.Option(help="Automatic threshold: this x the median wall/ceiling luminance.")
    ] = 8.0,
    min_vertices: Annotated[int, typer.Option(help="Smallest candidate, vertices.")] = 50,
    consistency: Annotated[
        bool, typer.Option(help="Reject view-dependent candidates (specular highlights).")
    ] = True,
    require_layout: Annotated[
        bool,
        typer.Option(help="Fail without layout.json (--no-require-layout: go on without a room)."),
    ] = True,
    add_point: Annotated[
        list[str] | None, typer.Option(help="Add a point light: x,y,z[,name] (repeatable).")
    ] = None,
    remove: Annotated[list[str] | None, typer.Option(help="Remove a light by name.")] = None,
    move: Annotated[list[str] | None, typer.Option(help="Move a light: NAME=x,y,z.")] = None,
    retype: Annotated[
        list[str] | None, typer.Option(help="Change a light's type: NAME=area|window|line|point.")
    ] = None,
    edit: Annotated[
        Path | None, typer.Option(help="A lights_edit.json of add/remove/move/retype.")
    ] = None,
) -> None:
    """Light detection: area lights, windows, line lights, point lights, with reasons (thesis 5.5)."""
    import numpy as np

    from reroom.lights import (
        LightsOptions,
        apply_edits,
        check_user_lights,
        detect_lights,
        edits_from_options,
        load_edits,
        merge_edits,
        write_lights,
    )

    out = out or scan / "lights"
    opts = LightsOptions(
        threshold=threshold,
        threshold_factor=threshold_factor,
        min_vertices=min_vertices,
        view_consistency=consistency,
        require_layout=require_layout,
    )
    with _errors(), _progress() as cb:
        result = detect_lights(scan, hdr_dir, layout_dir, opts, progress=cb)
        user = edits_from_options(add_point, remove, move, retype)
        edits = merge_edits(load_edits(edit), user) if edit else user
        apply_edits(result, edits, up=np.asarray(result.meta.get("up", [0, 0, 1])))
        check_user_lights(result)
        write_lights(result, out)
    table = Table(title=f"{len(result.lights)} lights, {len(result.rejected)} rejected")
    for col in ("name", "type", "source", "reason"):
        table.add_column(col)
    for light in result.lights:
        table.add_row(light.name, light.type, light.source, light.reason)
    console.print(table)
    for note in result.notes:
        console.print(f"[yellow]note:[/] {note}")
    console.print(f"[green]wrote[/] {out}")


@app.command()
def localize(
    scan: Annotated[
        Path,
        typer.Argument(help="Scan folder (after `reroom hdr`, `reroom layout`, `reroom lights`)."),
    ],
    out: Annotated[
        Path | None, typer.Option("--out", "-o", help="Output folder (default SCAN/localize).")
    ] = None,
    time_limit: Annotated[float, typer.Option(help="Seconds for the search.")] = 900.0,
    into_lights: Annotated[
        bool,
        typer.Option(
            help="Also merge the lights into SCAN/lights/lights.json (for `reroom invert`)."
        ),
    ] = False,
    keep_floating: Annotated[
        bool,
        typer.Option(
            help="Keep a light that nothing in the scan holds (no shade, stand, pendant or "
            "wall near it, not just under the ceiling); dropped by default as a fit of light "
            "the other light models miss."
        ),
    ] = False,
) -> None:
    """Point lights from the direct light on walls and ceiling (thesis ch. 6)."""
    from reroom.localize.scan import (
        ScanLocalizeOptions,
        localize_into_lights,
        localize_scan,
        write_localized_lights,
    )

    out = out or scan / "localize"
    with _errors():
        opts = ScanLocalizeOptions(time_limit=time_limit, drop_floating=not keep_floating)
        res, info = localize_scan(scan, opts)
        path = write_localized_lights(res, info, out)
        merged = localize_into_lights(scan, res, info) if into_lights else None
    for p, i in zip(res.positions, res.intensities, strict=True):
        console.print(f"point light at {p.round(3).tolist()} m, intensity {i:.3g}")
    for f in info["floating"]:
        where = [round(float(c), 3) for c in f["position"]]
        console.print(f"[yellow]dropped[/] a light at {where} m: {f['reason']}")
    console.print(f"albedo {info['albedo']}; stopped: {info['stopped']}")
    console.print(f"[green]wrote[/] {path}")
    if merged is not None:
        for line in merged[1]:
            console.print(f"  {line}")
        console.print(f"[green]updated[/] {merged[0]}")


@app.command()
def invert(
    scan: Annotated[Path, typer.Argument(help="Scan folder (with hdr/, layout/, lights/).")],
    out: Annotated[
        Path | None, typer.Option("--out", "-o", help="Output folder (default SCAN/invert).")
    ] = None,
    method: Annotated[str, typer.Option(help="Solver: joint | alternating.")] = "joint",
    rays: Annotated[int, typer.Option(help="Hemisphere rays per receiving vertex.")] = 512,
    voxel: Annotated[
        float, typer.Option(help="One hemisphere receiver per voxel of this size, m (0: all).")
    ] = 0.1,
    pictures: Annotated[bool, typer.Option(help="Write diagrams and cube-map pictures.")] = True,
    rerender: Annotated[
        int,
        typer.Option(help="Input frames to re-render from the model next to the photos (0: none)."),
    ] = 4,
    refine_points: Annotated[
        bool,
        typer.Option(
            help="Move point lights (up to 0.3 m) to where the solved lighting fits the "
            "photos best; --no-refine-points keeps the positions given."
        ),
    ] = True,
    textures: Annotated[
        bool,
        typer.Option(
            help="Albedo textures of the floor, ceiling and walls from the photos "
            "(invert/textures/; the renders use them)."
        ),
    ] = True,
    texel: Annotated[
        float | None,
        typer.Option(help="Texel size of those textures, m (default: the pixel footprint)."),
    ] = None,
    unobserved_fill: Annotated[
        str,
        typer.Option(
            help="Radiance of the surfaces no photo saw, for the indirect light: bounce (one "
            "bounce of the observed light) | mean (the thesis's eq. 5.9)."
        ),
    ] = "bounce",
    window_view: Annotated[
        Path | None,
        typer.Option(
            help="An HDRI of the view outside the windows (EXR, equirectangular in the "
            "scan's frame, any scale): how the sky's light is spread within each cube cell."
        ),
    ] = None,
    window_view_rotation: Annotated[
        float, typer.Option(help="That HDRI's turn about the up axis, degrees.")
    ] = 0.0,
    settings: Annotated[
        list[str] | None,
        typer.Option(
            "--set",
            help="Any other option, NAME=VALUE (repeatable; VALUE as JSON or a bare word): "
            "a field of InvertOptions or solve.FIELD of SolveOptions, e.g. --set "
            "line_phi_smooth=1e6 --set solve.huber_delta=0.02. Applied after the flags "
            "above. An unknown NAME lists the known ones.",
        ),
    ] = None,
) -> None:
    """Inverse rendering: light intensities and distributions, albedos (thesis ch. 5)."""
    from reroom.invert.overrides import with_overrides
    from reroom.invert.pipeline import UNOBSERVED_FILLS, InvertOptions, run_invert
    from reroom.invert.solve import SolveOptions

    # The photos' colour prior is the joint solver's: the alternating solver goes without
    # it (an explicit --set photo_color=... with it is still refused, by run_invert).
    photo_color = InvertOptions.photo_color if method != "alternating" else 0.0
    opts = InvertOptions(
        rays_per_receiver=rays,
        receiver_voxel=voxel,
        photo_color=photo_color,
        solve=SolveOptions(method=method),  # type: ignore[arg-type]
        pictures=pictures,
        refine_points=refine_points,
        textures=textures,
        texel=texel,
        unobserved_fill=unobserved_fill,
        window_view_hdri=None if window_view is None else str(window_view),
        window_view_rotation_deg=window_view_rotation,
    )
    if window_view is not None and not window_view.is_file():
        console.print(f"[red]error:[/] --window-view: {window_view}: no such file")
        raise typer.Exit(2)
    if unobserved_fill not in UNOBSERVED_FILLS:
        console.print(
            f"[red]error:[/] --unobserved-fill must be one of {', '.join(UNOBSERVED_FILLS)}, "
            f"got {unobserved_fill!r}"
        )
        raise typer.Exit(2)
    try:
        opts = with_overrides(opts, settings or [])
    except ValueError as exc:
        console.print(f"[red]error:[/] --set: {exc}")
        raise typer.Exit(2) from exc
    if texel is not None and not texel > 0:
        console.print(f"[red]error:[/] --texel must be positive, got {texel}")
        raise typer.Exit(2)
    with _errors(), _progress() as cb:
        result = run_invert(scan, out, opts, progress=cb)
    table = Table(title="materials")
    for col in ("cluster", "albedo r", "albedo g", "albedo b"):
        table.add_column(col)
    for name, rho in zip(result.cluster_names, result.solve.albedo, strict=True):
        table.add_row(name, *(f"{x:.3f}" for x in rho))
    console.print(table)
    for note in result.warnings:
        console.print(f"[yellow]note:[/] {note}")
    if rerender > 0:
        from reroom.edit.rerender import rerender_inputs

        with _errors():
            doc = rerender_inputs(scan, result.out_dir, frames=rerender)
        console.print(
            f"re-rendered {len(doc['frames'])} input frames: brightness "
            f"{doc['median_ratio_of_means']:.2f} of the photos, relative L1 "
            f"{doc['median_relative_l1']:.2f} (rerender.png)"
        )
    console.print(f"[green]wrote[/] {result.out_dir}")


@app.command()
def edit(
    scan: Annotated[Path, typer.Argument(help="Scan folder (with invert/, lights/, layout/).")],
    edits: Annotated[
        Path | None, typer.Argument(help="Edit file (reroom-edits JSON); or use --op / --set.")
    ] = None,
    op: Annotated[
        list[str] | None,
        typer.Option(
            "--op",
            help="Edit shortcut, repeatable, applied after the file's: empty, "
            "repaint:TARGET=r,g,b|FILE, off:NAME, scale:NAME=s, color:NAME=r,g,b, "
            "move:NAME=x,y,z, window:NAME=HDRI, insert:OBJECT@x,y,z[@deg], add:NAME@x,y,z=I.",
        ),
    ] = None,
    edit_set: Annotated[
        str | None,
        typer.Option("--set", help="A default edit set (empty, repaint_walls, ...) or 'all'."),
    ] = None,
    frames: Annotated[
        str | None, typer.Option(help="Input frames to render from, e.g. 0,5 (default: 4).")
    ] = None,
    camera: Annotated[
        Path | None,
        typer.Option(help="JSON list of new cameras (transform_matrix, fl_x, ..., name)."),
    ] = None,
    spp: Annotated[int, typer.Option(help="Samples per pixel.")] = 64,
    denoise: Annotated[
        bool, typer.Option(help="Denoise the renders (Open Image Denoise; not the composites).")
    ] = True,
    scale: Annotated[
        float, typer.Option("--scale", help="Resize the rendered views (e.g. 0.5).")
    ] = 1.0,
    out: Annotated[
        Path | None, typer.Option("--out", "-o", help="Output folder (default SCAN/edits/NAME).")
    ] = None,
    name: Annotated[
        str | None, typer.Option(help="Name of the renders (default: the edit file's stem).")
    ] = None,
    composite: Annotated[
        bool, typer.Option(help="Composite inserted objects into the frames' photos.")
    ] = False,
    bake: Annotated[bool, typer.Option(help="Bake the edited model's GI to PLY + glb.")] = False,
    list_sets: Annotated[bool, typer.Option("--list", help="Print the default sets.")] = False,
) -> None:
    """Edit the recovered room (empty, repaint, relight, insert) and render it (thesis §5.7, §7.3)."""
    import json

    from reroom.edit import (
        bake_edit,
        composite_insertion,
        default_edit_sets,
        load_edits,
        parse_edits,
        render_edit,
    )
    from reroom.edit.edits import EditError, op_from_shortcut

    with _errors():
        named: dict[str, list] = {}
        if list_sets or edit_set is not None:
            defaults = default_edit_sets(scan)
            if list_sets:
                print(json.dumps(defaults, indent=2))
                if edit_set is None and edits is None and not op:
                    return
            if edit_set == "all":
                named.update(defaults)
            elif edit_set is not None:
                if edit_set not in defaults:
                    raise EditError(f"no default edit set {edit_set!r}; there are {list(defaults)}")
                named[edit_set] = defaults[edit_set]
        ops: list = load_edits(edits) if edits is not None else []
        ops += parse_edits([op_from_shortcut(s) for s in op or []], "--op")
        if edits is not None or op:
            named[name or (edits.stem if edits is not None else "edit")] = ops
        if not named:
            raise EditError("give an edit file, --op shortcuts or --set (see reroom edit --help)")
        frame_list = [int(x) for x in frames.split(",")] if frames else None
        cams = None
        if camera is not None:
            try:
                cams = json.loads(camera.read_text())
            except (OSError, ValueError) as exc:
                raise EditError(f"{camera}: camera file does not load ({exc})") from exc
            cams = cams.get("frames", cams) if isinstance(cams, dict) else cams
        for set_name, set_ops in named.items():
            dest = out if out is not None and len(named) == 1 else None
            dest = dest or (out / set_name if out is not None else scan / "edits" / set_name)
            with _progress() as cb:
                doc = render_edit(
                    scan,
                    set_ops,
                    dest,
                    frames=frame_list,
                    cameras=cams,
                    spp=spp,
                    denoise=denoise,
                    name=set_name,
                    resolution_scale=scale,
                    progress=cb,
                )
            console.print(f"[green]{set_name}[/]: {len(doc['views'])} views in {dest}")
            if composite:
                if not any(o["op"] == "insert" for o in set_ops):
                    console.print(f"[yellow]note:[/] {set_name}: no inserted object to composite")
                else:
                    for j in frame_list or [
                        v["frame"] for v in doc["views"] if v["frame"] is not None
                    ]:
                        c = composite_insertion(
                            scan, set_ops, j, dest, spp=spp, name=f"{set_name}_composite"
                        )
                        console.print(f"  composite of frame {j}: {c['png']}")
            if bake:
                b = bake_edit(scan, set_ops, dest, spp=spp, name=f"{set_name}_baked")
                console.print(f"  baked {b['vertices']} vertices: {', '.join(b['files'].values())}")


@app.command("run")
def run_command(
    scan: Annotated[Path, typer.Argument(help="Scan folder.")],
    out: Annotated[
        Path | None,
        typer.Option(
            "--out", "-o", help="Run folder (default: the scan folder; else links to the scan)."
        ),
    ] = None,
    edits: Annotated[
        Path | None,
        typer.Option(help="An edit file (reroom-edits JSON) rendered as one more edit set."),
    ] = None,
    force: Annotated[
        list[str] | None,
        typer.Option(
            help="Run this stage even if unchanged (repeatable; hdr, layout, lights, invert, "
            "rerender, edits, report, or all)."
        ),
    ] = None,
    frames_to_render: Annotated[
        int, typer.Option(help="Input frames the re-renders and edit renders are made from.")
    ] = 2,
    spp: Annotated[
        int | None,
        typer.Option(
            help="Samples per pixel of the renders (default: about a million a view, "
            "16 at 160x120, 4 at 640x360)."
        ),
    ] = None,
    denoise: Annotated[
        bool, typer.Option(help="Denoise the re-renders and edit renders (Open Image Denoise).")
    ] = True,
    default_edits: Annotated[
        bool, typer.Option(help="Render the default edit sets (empty, repaint, relight, ...).")
    ] = True,
    evaluate: Annotated[
        bool, typer.Option(help="Ground-truth errors in the report (scans with ground_truth/).")
    ] = True,
    localize: Annotated[
        bool,
        typer.Option(
            help="Localize point lights from the lit walls (thesis ch. 6) and hand them "
            "to the inverse rendering (adds 20-80 s; see docs/localize.md)."
        ),
    ] = True,
    window_view: Annotated[
        Path | None,
        typer.Option(
            help="An HDRI of the view outside the windows, taken at a window (EXR, "
            "equirectangular in the scan's frame, any scale): how the sky's light is "
            "spread within each cube cell, which the frames clip (docs/invert.md)."
        ),
    ] = None,
    window_view_rotation: Annotated[
        float, typer.Option(help="That HDRI's turn about the up axis, degrees.")
    ] = 0.0,
) -> None:
    """Every stage end to end (HDR, layout, lights, invert, renders, edits) and report.html.

    Resumable: a stage whose inputs and options did not change is skipped.
    """
    from reroom.run import STAGES, RunOptions, run_scan

    opts = RunOptions(
        out_dir=out,
        edits_file=edits,
        frames_to_render=frames_to_render,
        spp=spp,
        denoise=denoise,
        default_edits=default_edits,
        evaluate=evaluate,
        localize=localize,
        window_view=window_view,
        window_view_rotation_deg=window_view_rotation,
    )
    t = time.perf_counter()
    with _errors(), _progress() as cb:
        res = run_scan(scan, opts, force=force or [], progress=cb)
    table = Table(title=f"reroom run {scan} ({time.perf_counter() - t:.1f} s)")
    for col in ("stage", "status", "seconds", "why"):
        table.add_column(col)
    done = {r.name: r for r in res.results}
    for name in STAGES:
        r = done.get(name)
        if r is None:
            table.add_row(name, "not reached", "", "")
            continue
        color = {"ran": "green", "skipped": "dim", "failed": "red"}[r.status]
        table.add_row(name, f"[{color}]{r.status}[/]", f"{r.seconds:.1f}", r.reason)
    console.print(table)
    for note in res.notes:
        console.print(f"[yellow]note:[/] {note}")
    if res.report is not None:
        console.print(f"[green]wrote[/] {res.report}")
    if res.failed is not None:
        console.print(
            f"[bold red]error:[/] stage {res.failed.name} failed: {res.failed.reason} "
            "(the stages before it kept their results; run again to resume)"
        )
        raise typer.Exit(1)


def demo_scan_state(scan_dir: Path, frames: int, spp: int) -> str:
    """What ``reroom demo`` does with an earlier scan in ``scan_dir``.

    ``"reuse"`` when it has ``frames`` frames rendered at ``spp`` samples per pixel,
    ``"replace"`` when a scan is there but differs (or its files cannot be read), and
    ``"new"`` when there is none.
    """
    import json

    if not (scan_dir / "transforms.json").exists():
        return "new"
    try:
        n = len(json.loads((scan_dir / "transforms.json").read_text())["frames"])
        gt = json.loads((scan_dir / "ground_truth" / "ground_truth.json").read_text())
        same = n == frames and int(gt["options"]["spp"]) == spp
    except (OSError, ValueError, KeyError, TypeError):
        same = False
    return "reuse" if same else "replace"


@app.command()
def demo(
    out: Annotated[Path, typer.Option("--out", "-o", help="Folder for the demo's outputs.")] = Path(
        "out/demo"
    ),
    frames: Annotated[int, typer.Option(help="Number of frames.")] = 24,
    spp: Annotated[
        int | None,
        typer.Option(help="Samples per pixel of the renders (default: as reroom run)."),
    ] = None,
) -> None:
    """The main job on the embedded default: the `furnished` room, then `reroom run` on it.

    Writes the synthetic scan to OUT/scan (kept between runs: regenerated only when its
    frame count or samples per pixel differ), every stage's outputs and OUT/report.html to
    OUT, and, where a Chromium browser exists, OUT/report.png (the report's top in headless
    Chromium).
    """
    from reroom.synth.generate import SynthOptions

    scan_dir = out / "scan"
    scan_spp = SynthOptions().spp  # the generator's default, as `reroom synth`
    existing = demo_scan_state(scan_dir, frames, scan_spp)
    if existing == "reuse":
        console.print(f"reusing the scan in {scan_dir} ({frames} frames)")
    else:
        synth(
            preset="furnished",
            out=scan_dir,
            frames=frames,
            width=160,
            height=120,
            fov=60.0,
            spp=scan_spp,
            vertex_spp=256,
            seed=0,
            hdri="courtyard",
            lights=None,
            mesh="clean",
            noise=True,
            response="gamma2.2",
            save_hdr=False,
            sheet=True,
            overwrite=existing == "replace",
        )
    run_command(
        scan=scan_dir,
        out=out,
        edits=None,
        force=None,
        frames_to_render=2,
        spp=spp,
        denoise=True,
        default_edits=True,
        evaluate=True,
    )
    from reroom.report import find_chromium, screenshot

    if find_chromium() is not None:
        with _errors():
            shot = screenshot(out / "report.html", out / "report.png", width=1280, height=2400)
        console.print(f"[green]wrote[/] {shot} (the report in headless Chromium)")


def main() -> None:  # pragma: no cover - entry point
    app()


if __name__ == "__main__":  # pragma: no cover
    main()
