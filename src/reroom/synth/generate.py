"""``reroom synth``: generate a synthetic scan with complete ground truth.

Pipeline: preset -> scene files -> Mitsuba scene -> handheld trajectory ->
path-traced linear frames -> simulated auto-exposure camera -> 8-bit frames ->
scan mesh (clean, corrupted or fused from depth) -> per-vertex truth (labels,
albedo, path-traced radiance) -> ``transforms.json`` + ``ground_truth/``.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from reroom.io.atomic import atomic_write_json
from reroom.io.images import write_exr
from reroom.io.mesh import write_ply
from reroom.scan.camera import Frame, Intrinsics
from reroom.scan.scan import write_scan
from reroom.synth.camera_sim import AutoCamera, CameraModel
from reroom.synth.groundtruth import clean_surface, transfer_truth
from reroom.synth.labels import LABELS
from reroom.synth.presets import PRESETS, build_preset
from reroom.synth.scanner import GRID_YAW_DEG
from reroom.synth.scene import mitsuba_scene_dict, write_scene
from reroom.synth.trajectory import walk_and_look

#: progress(stage, done, total)
ProgressFn = Callable[[str, int, int], None]
MESH_KINDS = ("clean", "corrupted", "fused")


@dataclass
class SynthOptions:
    """Options of :func:`generate_scan` (the CLI flags of ``reroom synth``)."""

    frames: int = 24
    width: int = 160
    height: int = 120
    fov_y_deg: float = 60.0
    # 64, not 16: at 16 the path tracer's noise pushes single pixels of bright surfaces
    # past the white level, and the camera's clip then loses 0.5 % of the red and 2.3 %
    # of the blue there, light no real camera loses (docs/architecture.md, "The
    # synthetic generator").
    spp: int = 64
    vertex_spp: int = 256
    max_depth: int = 256
    seed: int = 0
    hdri: str = "courtyard"
    lights: Sequence[str] | None = None  # names of lights left on; None = all
    mesh: str = "clean"
    mesh_spacing: float = 0.08
    camera: CameraModel = field(default_factory=CameraModel)
    save_hdr: bool = False
    voxel_size: float = 0.03
    # The fused mesh's voxel grid, turned this far about the vertical (synth.scanner).
    grid_yaw_deg: float = GRID_YAW_DEG

    def to_json(self) -> dict[str, Any]:
        d = {k: v for k, v in self.__dict__.items() if k != "camera"}
        d["lights"] = None if self.lights is None else list(self.lights)
        d["camera"] = self.camera.to_json()
        return d


def _noop(stage: str, done: int, total: int) -> None:
    pass


def _prepare_out_dir(out: Path, overwrite: bool) -> None:
    """Refuse to mix a new scan with an old one; with ``overwrite``, remove the old one's files."""
    import shutil

    if not out.exists():
        return
    if not out.is_dir():
        raise ValueError(f"{out}: exists and is not a folder")
    if not any(out.iterdir()):
        return
    if not overwrite:
        raise ValueError(f"{out}: folder is not empty (pass --overwrite to replace the scan in it)")
    # transforms.json goes first, so an interrupted run never leaves a folder that
    # looks like a whole scan.
    for name in (
        "transforms.json",
        "images",
        "depth",
        "ground_truth",
        "mesh.ply",
        "contact_sheet.png",
    ):
        p = out / name
        if p.is_dir():
            shutil.rmtree(p)
        elif p.exists():
            p.unlink()


def generate_scan(
    preset: str,
    out_dir: str | Path,
    options: SynthOptions | None = None,
    progress: ProgressFn | None = None,
    overwrite: bool = False,
) -> Path:
    """Generate a synthetic scan of ``preset`` into ``out_dir``; return the folder.

    See :class:`SynthOptions` for the knobs and ``docs/formats.md`` for what is
    written. Deterministic for a given seed and options. ``out_dir`` must be
    absent or empty unless ``overwrite`` is set.
    """
    opt = options or SynthOptions()
    progress = progress or _noop
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; choose one of {PRESETS}")
    if opt.mesh not in MESH_KINDS:
        raise ValueError(f"unknown mesh kind {opt.mesh!r}; choose one of {MESH_KINDS}")
    if opt.frames < 1 or opt.width < 8 or opt.height < 8 or opt.spp < 1:
        raise ValueError("frames must be >= 1, width/height >= 8 and spp >= 1")
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    out = Path(out_dir)
    _prepare_out_dir(out, overwrite)
    gt_dir = out / "ground_truth"
    scene_dir = gt_dir / "scene"
    rng = np.random.default_rng(opt.seed)

    spec = build_preset(preset, hdri=opt.hdri, mesh_spacing=opt.mesh_spacing)
    desc = write_scene(spec, scene_dir, max_depth=opt.max_depth)
    names = [light["name"] for light in desc["lights"]]
    if opt.lights is not None:
        unknown = sorted(set(opt.lights) - set(names))
        if unknown:
            raise ValueError(f"preset {preset!r} has no light(s) {unknown}; its lights are {names}")
        for light in desc["lights"]:
            light["on"] = light["name"] in set(opt.lights)
        atomic_write_json(scene_dir / "scene.json", desc)
    timings["scene"] = time.perf_counter() - t0

    from reroom.render import mitsuba

    mi = mitsuba()
    from reroom.synth.render import FrameRenderer

    intr = Intrinsics.from_fov(opt.width, opt.height, opt.fov_y_deg)
    poses = walk_and_look(spec.waypoints, opt.frames, rng)
    t = time.perf_counter()
    renderer = FrameRenderer(mitsuba_scene_dict(desc, scene_dir), intr, opt.spp)
    cam = AutoCamera(opt.camera, np.random.default_rng(opt.seed + 1))
    images, frame_truth = [], []
    for j, c2w in enumerate(poses):
        radiance = renderer.render(c2w, seed=opt.seed * 100003 + j)
        if not np.all(np.isfinite(radiance)):
            radiance = np.nan_to_num(radiance, nan=0.0, posinf=0.0)
        img, scale, exposure, wb = cam.capture(radiance)
        images.append(img)
        frame_truth.append(
            {
                "index": j,
                "exposure": exposure,
                "white_balance": wb.tolist(),
                "scale": scale.tolist(),
                "saturated_fraction": float(np.mean(img.max(axis=2) >= 255)),
            }
        )
        if opt.save_hdr:
            write_exr(gt_dir / "hdr" / f"frame_{j:05d}.exr", radiance)
        progress("render frames", j + 1, len(poses))
    timings["render_frames"] = time.perf_counter() - t

    # --- the scanned mesh and its per-vertex truth ------------------------------------------
    t = time.perf_counter()
    clean = clean_surface(desc, scene_dir)
    if opt.mesh == "clean":
        mesh = trimesh.Trimesh(clean.vertices, clean.faces, process=False)
        normals = clean.normals
        truth = {
            "part": clean.part,
            "label": clean.label,
            "albedo": clean.albedo,
            "distance": np.zeros(len(clean.vertices)),
        }
    else:
        if opt.mesh == "corrupted":
            from reroom.synth.scanner import corrupt_mesh

            mesh = corrupt_mesh(clean.vertices, clean.faces, rng)
        else:
            mesh = _fused_mesh(clean, poses, intr, opt, progress)
        normals = np.asarray(mesh.vertex_normals)
        truth = transfer_truth(clean, desc, scene_dir, np.asarray(mesh.vertices), normals)
    timings["mesh"] = time.perf_counter() - t

    t = time.perf_counter()
    # Radiance of the true surface point each vertex stands for, seen along the vertex normal.
    probe_points = np.asarray(mesh.vertices) if opt.mesh == "clean" else truth["surface_point"]
    radiance, stderr = _probe_vertices(renderer, probe_points, normals, opt, progress)
    timings["vertex_radiance"] = time.perf_counter() - t

    # --- write --------------------------------------------------------------------------------
    t = time.perf_counter()
    _write_vertex_truth(gt_dir / "vertices.ply", mesh, truth, radiance, stderr)
    scan_mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    meta = {
        "reroom": {
            "source": "reroom synth",
            "preset": preset,
            "response": opt.camera.response,
        }
    }
    # The scan's own mesh carries no truth: estimation stages must not see labels or albedo.
    scan_mesh.vertex_attributes.clear()
    write_scan(out, scan_mesh, intr, poses, images, meta=meta)
    truth_doc = {
        "format": "reroom-ground-truth",
        "version": 1,
        "preset": preset,
        "options": opt.to_json(),
        "mitsuba_variant": mi.variant(),
        "mesh": {
            "kind": opt.mesh,
            "vertices": int(len(mesh.vertices)),
            "faces": int(len(mesh.faces)),
            "vertex_file": "vertices.ply",
            "vertex_radiance_spp": opt.vertex_spp,
        },
        "labels": dict(LABELS),
        "frames": frame_truth,
        "lights": desc["lights"],
        "layout": spec.layout,
        "scene": "scene/scene.json",
        "timings_s": {k: round(v, 3) for k, v in timings.items()},
    }
    timings["write"] = time.perf_counter() - t
    truth_doc["timings_s"]["write"] = round(timings["write"], 3)
    truth_doc["timings_s"]["total"] = round(time.perf_counter() - t0, 3)
    atomic_write_json(gt_dir / "ground_truth.json", truth_doc)
    return out


def _fused_mesh(
    clean: Any,
    poses: Sequence[np.ndarray],
    intr: Intrinsics,
    opt: SynthOptions,
    progress: ProgressFn,
) -> trimesh.Trimesh:
    """The scanner-like mesh: Kinect-noisy depth maps of the clean surface, TSDF-fused."""
    from reroom.rays import RayCaster
    from reroom.synth.scanner import fuse_depth_maps, kinect_noise, render_depth

    caster = RayCaster(clean.vertices, clean.faces)
    frames = [Frame(j, Path(), c2w, intr) for j, c2w in enumerate(poses)]
    depth_rng = np.random.default_rng(opt.seed + 2)
    depths = []
    for j, fr in enumerate(frames):
        depths.append(kinect_noise(render_depth(caster, fr), depth_rng))
        progress("depth maps", j + 1, len(frames))
    return fuse_depth_maps(
        depths,
        frames,
        intr,
        voxel_size=opt.voxel_size,
        progress=lambda d, n: progress("tsdf fusion", d, n),
        grid_yaw_deg=opt.grid_yaw_deg,
    )


def _probe_vertices(
    renderer: Any, points: np.ndarray, normals: np.ndarray, opt: SynthOptions, progress: ProgressFn
) -> tuple[np.ndarray, np.ndarray]:
    """Path-traced radiance (and its standard error) leaving ``points`` along ``normals``."""
    from reroom.synth.render import probe_radiance

    return probe_radiance(
        renderer.scene,
        points,
        normals,
        opt.vertex_spp,
        seed=opt.seed,
        offset=0.004,
        progress=lambda d, n: progress("vertex radiance", d, n),
    )


def _write_vertex_truth(
    path: Path, mesh: trimesh.Trimesh, truth: dict, radiance: np.ndarray, stderr: np.ndarray
) -> None:
    write_ply(
        path,
        trimesh.Trimesh(mesh.vertices, mesh.faces, process=False),
        {
            "label": truth["label"].astype(np.uint8),
            "part": truth["part"].astype(np.int32),
            "albedo": truth["albedo"],
            "radiance": radiance,
            "radiance_stderr": stderr,
            "surface_distance": truth["distance"],
        },
    )


def refuse_scan(
    scan_dir: str | Path,
    out_dir: str | Path,
    grid_yaw_deg: float,
    progress: ProgressFn | None = None,
) -> Path:
    """A fused synthetic scan again, its voxel grid turned ``grid_yaw_deg``; photos kept.

    Copies ``scan_dir`` (made by :func:`generate_scan` with ``mesh="fused"``) to the new
    folder ``out_dir`` and fuses its mesh again from the same noisy depth maps, the grid
    placed otherwise, with the per-vertex truth made afresh; frames, exposures and the
    scene stay. The result is what :func:`generate_scan` makes with that
    ``grid_yaw_deg``, in minutes instead of the frames' rendering: it measures how much
    a figure owes to where the fusion's voxels fell.
    """
    import shutil

    from reroom.render import mitsuba
    from reroom.scan import load_scan

    progress = progress or _noop
    src, out = Path(scan_dir), Path(out_dir)
    gt_path = src / "ground_truth" / "ground_truth.json"
    if not gt_path.is_file():
        raise ValueError(f"{src}: no ground_truth/ground_truth.json (not a synthetic scan)")
    doc = json.loads(gt_path.read_text())
    if doc["mesh"]["kind"] != "fused":
        raise ValueError(f"{src}: its mesh is {doc['mesh']['kind']!r}, not fused")
    if out.exists():
        raise ValueError(f"{out}: exists (refuse_scan writes a new folder)")
    known = set(SynthOptions.__dataclass_fields__) - {"camera"}
    opt = SynthOptions(**{k: v for k, v in doc["options"].items() if k in known})
    opt.grid_yaw_deg = float(grid_yaw_deg)
    scan = load_scan(src, check_images=False)
    intr = scan.frames[0].intrinsics
    poses = [f.c2w for f in scan.frames]
    tmp = out.with_name(out.name + ".partial")
    if tmp.exists():
        shutil.rmtree(tmp)
    shutil.copytree(src, tmp)
    scene_dir = tmp / "ground_truth" / "scene"
    desc = json.loads((scene_dir / "scene.json").read_text())
    clean = clean_surface(desc, scene_dir)
    mesh = _fused_mesh(clean, poses, intr, opt, progress)
    normals = np.asarray(mesh.vertex_normals)
    truth = transfer_truth(clean, desc, scene_dir, np.asarray(mesh.vertices), normals)
    mitsuba()
    from reroom.synth.render import FrameRenderer

    renderer = FrameRenderer(mitsuba_scene_dict(desc, scene_dir), intr, opt.spp)
    radiance, stderr = _probe_vertices(renderer, truth["surface_point"], normals, opt, progress)
    _write_vertex_truth(tmp / "ground_truth" / "vertices.ply", mesh, truth, radiance, stderr)
    write_ply(tmp / "mesh.ply", trimesh.Trimesh(mesh.vertices, mesh.faces, process=False))
    doc["options"]["grid_yaw_deg"] = opt.grid_yaw_deg
    doc["mesh"].update(vertices=int(len(mesh.vertices)), faces=int(len(mesh.faces)))
    doc["refused_from"] = str(src)
    atomic_write_json(tmp / "ground_truth" / "ground_truth.json", doc)
    tmp.rename(out)
    return out
