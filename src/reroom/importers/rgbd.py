"""Import a posed RGB-D sequence (colour + depth + camera-to-world poses) as a reroom scan.

The pipeline:

1. read and validate everything up front (file existence, image sizes, poses),
   so that a bad input fails in seconds with a :class:`~reroom.errors.ScanError`
   naming the file;
2. mask the white registration border (NYU/Kinect style) out of each depth map;
3. fuse the frames with Open3D's voxel-block-grid TSDF (colour included)
   and extract a triangle mesh;
4. clean the mesh (degenerate and duplicated triangles, small islands);
5. estimate the up direction (the cameras' mean "up" axis, refined by the
   mesh's horizontal and vertical surfaces) and rotate the capture's arbitrary
   world so that +Z is up (metres kept; the origin stays where the capture put it);
6. convert poses from OpenCV camera axes to the scan format's OpenGL axes and
   write the scan with :func:`reroom.scan.write_scan`.

Conventions of the inputs
-------------------------
* Poses are camera-to-world in **OpenCV** camera axes (x right, y down, z
  forward), as in TUM, slambook2, ScanNet or Open3D's own datasets.
* Depth maps are registered to the colour images (same size), 16-bit, with
  ``depth_m = value / depth_scale`` and 0 meaning "no measurement".
* :class:`~reroom.scan.Intrinsics` objects use reroom's pixel convention (the
  centre of pixel ``(i, j)`` is ``(j + 0.5, i + 0.5)``). Intrinsics read by
  :func:`read_intrinsics` from an OpenCV-style JSON file (pixel centres at
  integer coordinates, ``X = (u - cx) z / fx``) are shifted by half a pixel.
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from reroom.errors import ScanError
from reroom.importers.alignment import UpEstimate, estimate_up, world_alignment  # noqa: F401
from reroom.importers.capture_io import (  # noqa: F401
    CV_TO_GL_4,
    read_depth,
    read_depth_raw,
    read_intrinsics,
    read_pose_file,
    white_border_mask,
)
from reroom.importers.fusion import (  # noqa: F401
    PoseRefiner,
    TsdfFusion,
    _clean_mesh,
    _o3d,
    canonical_order,
)
from reroom.io.images import image_size, read_rgb8
from reroom.scan.camera import Intrinsics
from reroom.scan.scan import validate_pose, write_scan

#: Default TSDF parameters (metres); see :func:`import_rgbd`.
DEFAULT_VOXEL_SIZE = 0.02
DEFAULT_DEPTH_TRUNC = 6.0

ProgressFn = Callable[[int, int], None]

_NUMBER_RE = re.compile(r"^\d+$")


# --------------------------------------------------------------------------- fusion


@dataclass
class _FrameInput:
    color: Path
    depth: Path


class _DepthMM:
    """A depth map held as uint16 millimetres, handed out in metres on demand.

    ``write_scan`` gathers every depth map before writing; keeping them as
    16-bit integers halves the memory of float32 maps (numpy's ``__array__``
    protocol converts each one only when it is written).
    """

    def __init__(self, depth_m: np.ndarray) -> None:
        mm = np.where(np.isfinite(depth_m) & (depth_m > 0), np.round(depth_m * 1000.0), 0)
        self.mm = np.clip(mm, 0, 65535).astype(np.uint16)

    def __array__(self, dtype: Any = None, copy: bool | None = None) -> np.ndarray:
        out = self.mm.astype(np.float64) / 1000.0
        return out if dtype is None else out.astype(dtype)


def _as_poses(poses: Any) -> tuple[np.ndarray, Path | None]:
    if isinstance(poses, str | Path):
        return read_pose_file(poses), Path(poses)
    arr = np.asarray(poses, dtype=np.float64)
    if arr.ndim != 3 or arr.shape[1:] != (4, 4):
        raise ValueError(f"poses must be (N, 4, 4) camera-to-world matrices, got {arr.shape}")
    return np.stack(
        [validate_pose(m, Path("<poses>"), f"pose {i}") for i, m in enumerate(arr)]
    ), None


def import_rgbd(
    color_paths: Sequence[str | Path],
    depth_paths: Sequence[str | Path],
    intrinsics: Intrinsics | str | Path,
    poses_c2w_cv: np.ndarray | Sequence[np.ndarray] | str | Path,
    out_dir: str | Path,
    *,
    depth_scale: float | None = None,
    voxel_size: float = DEFAULT_VOXEL_SIZE,
    depth_trunc: float = DEFAULT_DEPTH_TRUNC,
    sdf_trunc: float | None = None,
    min_observations: int = 1,
    refine_poses: bool = True,
    mask_white_border: bool = True,
    min_component_fraction: float = 0.002,
    min_component_triangles: int = 50,
    progress: ProgressFn | None = None,
) -> Path:
    """Fuse a posed RGB-D sequence into a mesh and write it, with its frames, as a reroom scan.

    Parameters
    ----------
    color_paths, depth_paths:
        One colour image and one registered depth map (same size) per frame.
    intrinsics:
        Shared pinhole intrinsics (reroom pixel convention), or the path of an
        OpenCV-style intrinsics JSON (see :func:`read_intrinsics`).
    poses_c2w_cv:
        ``(N, 4, 4)`` camera-to-world poses in OpenCV camera axes, or the path
        of a pose file (see :func:`read_pose_file`).
    out_dir:
        The scan folder to write.
    depth_scale:
        Depth sample units per metre; default: the JSON's ``depth_scale``, else 1000.
    voxel_size:
        TSDF voxel edge in metres. 2 cm gives a room in about 10^5 vertices
        and keeps chairs and table edges of Kinect-class depth; 1 cm keeps
        thin chair slats better at about 5 times the vertices and time.
    depth_trunc:
        Depth beyond this (metres) is ignored: Kinect-class depth is
        quantised in steps growing with the square of depth (about 5 cm at
        4 m, 10 cm at 6 m), which fuses into terraced, fronto-parallel sheets.
    sdf_trunc:
        TSDF truncation distance in metres (default ``5 * voxel_size``, 10 cm).
        Surfaces seen at grazing angles (a table top from standing height)
        only get a band ``sdf_trunc * sin(angle)`` thick behind them, and
        marching cubes needs observed voxels on both sides: at 4 voxels the
        table and floor tear into staircase holes, at 5 to 6 far fewer.
    min_observations:
        Keep surface seen by at least this many frames (1 keeps every surface;
        2 or 3 suppresses single-frame outliers in long sequences).
    refine_poses:
        Align each frame's depth to the frames before it with point-to-plane
        ICP (see :class:`PoseRefiner`) before fusing it. Hand-held captures
        with approximate poses (slambook2: moved by 6 to 9 cm and about 1.7
        degrees) fuse into tighter surfaces (there, the share of each frame's
        depth within 2 cm of the mesh rises from 79-84 % to 84-92 %); exact
        poses come back within a few millimetres and 0.1 degree.
        A frame whose alignment fails keeps its given pose.
    mask_white_border:
        Drop depth under the white registration border (:func:`white_border_mask`).
    min_component_fraction, min_component_triangles:
        Connected mesh pieces smaller than ``max(min_component_triangles,
        min_component_fraction * total triangles)`` are removed.
    progress:
        Called as ``progress(done, total)`` after each step (one per frame
        fused, then mesh extraction, clean-up and writing).

    Returns
    -------
    Path of the written ``transforms.json``.

    Raises
    ------
    ScanError
        Naming the file, for missing or unreadable images, depth maps of a
        different size than their colour image, a pose count different from
        the frame count, bad poses, or an empty fusion result.
    """
    if not voxel_size > 0:
        raise ValueError(f"voxel_size must be positive, got {voxel_size}")
    if not depth_trunc > 0:
        raise ValueError(f"depth_trunc must be positive, got {depth_trunc}")
    sdf_trunc = 5.0 * voxel_size if sdf_trunc is None else float(sdf_trunc)
    if not sdf_trunc > voxel_size:
        raise ValueError(f"sdf_trunc ({sdf_trunc}) must exceed voxel_size ({voxel_size})")

    out = Path(out_dir)
    t_start = time.perf_counter()
    if isinstance(intrinsics, str | Path):
        intr, json_scale = read_intrinsics(intrinsics)
        depth_scale = json_scale if depth_scale is None else depth_scale
    else:
        intr = intrinsics
    depth_scale = 1000.0 if depth_scale is None else float(depth_scale)
    if intr.has_distortion:
        raise ValueError("TSDF fusion needs undistorted images (intrinsics have distortion)")

    colors = [Path(p) for p in color_paths]
    depths = [Path(p) for p in depth_paths]
    if len(colors) != len(depths):
        raise ValueError(f"{len(colors)} colour images but {len(depths)} depth maps")
    if not colors:
        raise ValueError("no frames to import")
    poses, pose_src = _as_poses(poses_c2w_cv)
    if len(poses) != len(colors):
        if pose_src is None:
            raise ValueError(f"{len(poses)} poses for {len(colors)} frames")
        raise ScanError(pose_src, f"has {len(poses)} poses for {len(colors)} frames")

    # Validate every file's header before any heavy work.
    frames = [_FrameInput(c, d) for c, d in zip(colors, depths, strict=True)]
    for fr in frames:
        cw, ch = image_size(fr.color)
        if (cw, ch) != (intr.width, intr.height):
            raise ScanError(
                fr.color, f"image is {cw}x{ch} but the intrinsics say {intr.width}x{intr.height}"
            )
        if not fr.depth.is_file():
            raise ScanError(fr.depth, "depth file is missing")
        dw, dh = image_size(fr.depth)
        if (dw, dh) != (cw, ch):
            raise ScanError(
                fr.depth,
                f"depth map is {dw}x{dh} but its colour image {fr.color.name} is {cw}x{ch} "
                "(depth must be registered to colour)",
            )
    n = len(frames)
    total_steps = n + 3
    step = 0

    def tick() -> None:
        nonlocal step
        step += 1
        if progress is not None:
            progress(step, total_steps)

    fusion = TsdfFusion(intr, voxel_size, sdf_trunc, depth_trunc)
    refiner = PoseRefiner(intr, voxel=max(voxel_size, 0.01)) if refine_poses else None
    fused_poses: list[np.ndarray] = []
    kept_depths: list[_DepthMM] = []
    valid_fractions: list[float] = []
    border_pixels = 0
    for fr, pose in zip(frames, poses, strict=True):
        rgb = read_rgb8(fr.color)
        depth = read_depth(fr.depth, depth_scale)
        if depth.shape != rgb.shape[:2]:
            raise ScanError(
                fr.depth,
                f"depth map is {depth.shape[1]}x{depth.shape[0]} but its colour image "
                f"{fr.color.name} is {rgb.shape[1]}x{rgb.shape[0]} (depth must be registered "
                "to colour)",
            )
        if mask_white_border:
            border = white_border_mask(rgb)
            border_pixels += int(np.count_nonzero(border & (depth > 0)))
            depth[border] = 0.0
        valid_fractions.append(float(np.count_nonzero(depth > 0)) / depth.size)
        kept = _DepthMM(depth)
        kept_depths.append(kept)
        if refiner is not None:
            pose = refiner.refine(depth, pose)
        fused_poses.append(pose)
        fusion.integrate(rgb, kept.mm, pose)
        tick()
    poses = np.stack(fused_poses)

    o3d_mesh = fusion.extract_mesh(min_observations)
    n_raw_vertices = len(o3d_mesh.vertices)
    n_blocks = fusion.n_blocks
    del fusion
    tick()
    o3d_mesh = _clean_mesh(o3d_mesh, min_component_fraction, min_component_triangles)
    verts = np.asarray(o3d_mesh.vertices, dtype=np.float64)
    faces = np.asarray(o3d_mesh.triangles, dtype=np.int64)
    if len(faces) == 0:
        raise ScanError(
            depths[0].parent,
            "TSDF fusion produced no surface: check depth_scale, depth_trunc and the poses",
        )
    colors_f = np.asarray(o3d_mesh.vertex_colors, dtype=np.float64)
    vcolor = np.clip(np.round(colors_f * 255.0), 0, 255).astype(np.uint8)
    order, faces = canonical_order(verts, faces)
    verts = verts[order]
    if len(vcolor) == len(order):
        vcolor = vcolor[order]

    # Up direction from the cameras, refined by the mesh's planes.
    tri = verts[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    areas = 0.5 * np.linalg.norm(cross, axis=1)
    normals = cross / np.maximum(2.0 * areas, 1e-30)[:, None]
    up = estimate_up(poses, normals, areas, tri.mean(axis=1))
    forward0 = poses[0, :3, 2]  # the first camera's optical axis (OpenCV +z)
    align = world_alignment(up.up, forward0)

    verts_w = verts @ align[:3, :3].T
    mesh = trimesh.Trimesh(vertices=verts_w, faces=faces, process=False, validate=False)
    mesh.visual = trimesh.visual.ColorVisuals(
        mesh, vertex_colors=np.concatenate([vcolor, np.full((len(vcolor), 1), 255, np.uint8)], 1)
    )
    mesh.vertex_attributes["color"] = vcolor
    poses_gl = [align @ p @ CV_TO_GL_4 for p in poses]
    tick()

    def images() -> Iterator[np.ndarray]:
        for fr in frames:
            yield read_rgb8(fr.color)

    meta = {
        "reroom": {
            "source": "rgbd-import",
            "up_estimated_from": up.source,
            "up": up.to_json(),
            "world_from_capture": align.round(9).tolist(),
            "tsdf": {
                "voxel_size": float(voxel_size),
                "sdf_trunc": float(sdf_trunc),
                "depth_trunc": float(depth_trunc),
                "depth_scale": float(depth_scale),
                "min_observations": int(min_observations),
                "backend": "open3d.t.geometry.VoxelBlockGrid",
                "mask_white_border": bool(mask_white_border),
                "min_component_fraction": float(min_component_fraction),
                "min_component_triangles": int(min_component_triangles),
            },
            "pose_refinement": refiner.report() if refiner is not None else None,
            "stats": {
                "frames": n,
                "raw_vertices": int(n_raw_vertices),
                "voxel_blocks": int(n_blocks),
                "vertices": len(mesh.vertices),
                "faces": len(mesh.faces),
                "valid_depth_fraction": [round(v, 4) for v in valid_fractions],
                "border_depth_pixels_masked": border_pixels,
                "seconds": round(time.perf_counter() - t_start, 3),
            },
            "inputs": {
                "color": [str(p) for p in colors],
                "depth": [str(p) for p in depths],
                **({"poses": str(pose_src)} if pose_src is not None else {}),
            },
        }
    }
    result = write_scan(out, mesh, intr, poses_gl, images(), depths=kept_depths, meta=meta)
    tick()
    return result


# --------------------------------------------------------------------------- folders


def _numeric_key(p: Path) -> tuple[int, int | str]:
    return (0, int(p.stem)) if _NUMBER_RE.match(p.stem) else (1, p.stem)


_COLOR_EXTS = (".png", ".jpg", ".jpeg")
_DEPTH_EXTS = (".pgm", ".png")
_POSE_NAMES = ("pose.txt", "poses.txt", "trajectory.txt", "groundtruth.txt")


def find_rgbd_folder(folder: str | Path) -> tuple[list[Path], list[Path], Path, Path]:
    """Locate the frames of a slambook2-style folder.

    Layout: ``color/N.png``, ``depth/N.pgm`` (or ``.png``), ``pose.txt`` (one
    pose per frame, in frame order) and ``intrinsics.json``. Frames are sorted
    numerically by file stem (``2`` before ``10``); colour and depth pair up by
    stem. Returns ``(color_paths, depth_paths, pose_path, intrinsics_path)``.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ScanError(folder, "RGB-D folder does not exist")
    color_dir, depth_dir = folder / "color", folder / "depth"
    for d in (color_dir, depth_dir):
        if not d.is_dir():
            raise ScanError(d, "is missing (expected color/N.png and depth/N.pgm)")
    colors = sorted(
        (p for p in color_dir.iterdir() if p.suffix.lower() in _COLOR_EXTS), key=_numeric_key
    )
    if not colors:
        raise ScanError(color_dir, "holds no colour images (.png or .jpg)")
    depth_by_stem: dict[str, Path] = {}
    for p in sorted(depth_dir.iterdir()):
        if p.suffix.lower() in _DEPTH_EXTS:
            depth_by_stem.setdefault(p.stem, p)
    depths = []
    for c in colors:
        d = depth_by_stem.pop(c.stem, None)
        if d is None:
            raise ScanError(depth_dir / f"{c.stem}.pgm", f"depth file is missing (for {c.name})")
        depths.append(d)
    if depth_by_stem:
        extra = sorted(depth_by_stem.values(), key=_numeric_key)[0]
        raise ScanError(extra, "depth map has no colour image of the same name")
    pose_path = next((folder / n for n in _POSE_NAMES if (folder / n).is_file()), None)
    if pose_path is None:
        raise ScanError(folder / "pose.txt", "pose file is missing")
    intr_path = folder / "intrinsics.json"
    if not intr_path.is_file():
        raise ScanError(intr_path, "intrinsics file is missing")
    return colors, depths, pose_path, intr_path


def import_rgbd_folder(folder: str | Path, out_dir: str | Path, **kwargs: Any) -> Path:
    """Import a slambook2-style RGB-D folder (see :func:`find_rgbd_folder`) as a scan.

    Keyword arguments go to :func:`import_rgbd`. Returns the ``transforms.json`` path.
    """
    colors, depths, pose_path, intr_path = find_rgbd_folder(folder)
    return import_rgbd(colors, depths, intr_path, pose_path, out_dir, **kwargs)


__all__ = [
    "CV_TO_GL_4",
    "DEFAULT_DEPTH_TRUNC",
    "DEFAULT_VOXEL_SIZE",
    "PoseRefiner",
    "TsdfFusion",
    "UpEstimate",
    "estimate_up",
    "find_rgbd_folder",
    "import_rgbd",
    "import_rgbd_folder",
    "read_depth",
    "read_depth_raw",
    "read_intrinsics",
    "read_pose_file",
    "white_border_mask",
    "world_alignment",
]
