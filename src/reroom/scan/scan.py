"""The scan: a folder with ``transforms.json``, frames, and a triangle mesh.

:func:`load_scan` validates everything up front (pose rigidity, image headers
and sizes, the mesh) and raises :class:`~reroom.errors.ScanError` naming the
file and the problem; pixels are decoded lazily by :meth:`Frame.load_image`, so
a 1000-frame scan loads in seconds and a few hundred MB.
:func:`write_scan` writes the same format atomically (``transforms.json`` is
written last, so a folder without it is never mistaken for a whole scan).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from reroom.errors import ScanError
from reroom.io.atomic import atomic_write_json
from reroom.io.images import image_size, write_depth_mm, write_rgb8
from reroom.io.mesh import read_ply, write_ply
from reroom.scan.camera import Frame, Intrinsics

TRANSFORMS = "transforms.json"
_INTRINSIC_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h")
_CAMERA_MODELS = ("PINHOLE", "OPENCV")


@dataclass
class Scan:
    """A loaded, validated scan.

    Attributes
    ----------
    root:
        The scan folder.
    frames:
        Posed frames in file order; images load lazily.
    mesh:
        The scanned triangle mesh (world coordinates, metres, +Z up).
    mesh_path:
        Where the mesh came from.
    meta:
        Any other top-level keys of ``transforms.json`` (e.g. ``reroom`` metadata
        such as the camera response the generator used).
    """

    root: Path
    frames: list[Frame]
    mesh: trimesh.Trimesh
    mesh_path: Path
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def ground_truth_dir(self) -> Path:
        """``root/ground_truth`` -- read by evaluation code only, never by estimation."""
        return self.root / "ground_truth"

    @property
    def has_ground_truth(self) -> bool:
        return (self.ground_truth_dir / "ground_truth.json").is_file()

    def __len__(self) -> int:
        return len(self.frames)

    def __repr__(self) -> str:
        return (
            f"Scan({str(self.root)!r}, {len(self.frames)} frames, "
            f"{len(self.mesh.vertices)} vertices, {len(self.mesh.faces)} faces)"
        )


def _require_number(src: Path, obj: dict, key: str, where: str, positive: bool = False) -> float:
    if key not in obj:
        raise ScanError(src, f"{where} lacks '{key}'")
    value = obj[key]
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ScanError(src, f"{where}: '{key}' must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ScanError(src, f"{where}: '{key}' is not finite ({value})")
    if positive and value <= 0:
        raise ScanError(src, f"{where}: '{key}' must be positive, got {value}")
    return float(value)


def _parse_intrinsics(src: Path, obj: dict, fallback: Intrinsics | None, where: str) -> Intrinsics:
    present = [k for k in _INTRINSIC_KEYS if k in obj]
    if not present and fallback is not None and "camera_model" not in obj:
        return fallback
    if not present and fallback is None:
        raise ScanError(
            src,
            f"{where} has no intrinsics and there are no global ones (fl_x, fl_y, cx, cy, w, h)",
        )
    base = fallback.to_json() if fallback is not None else {}
    merged = {
        **base,
        **{
            k: v
            for k, v in obj.items()
            if k in (*_INTRINSIC_KEYS, "camera_model", "k1", "k2", "p1", "p2")
        },
    }
    model = merged.get("camera_model", "PINHOLE")
    if model not in _CAMERA_MODELS:
        raise ScanError(src, f"{where}: camera_model {model!r} is not one of {_CAMERA_MODELS}")
    w = _require_number(src, merged, "w", where, positive=True)
    h = _require_number(src, merged, "h", where, positive=True)
    if w != int(w) or h != int(h):
        raise ScanError(src, f"{where}: image size must be whole pixels, got {w}x{h}")
    dist = {
        k: _require_number(src, merged, k, where) if k in merged else 0.0
        for k in ("k1", "k2", "p1", "p2")
    }
    return Intrinsics(
        width=int(w),
        height=int(h),
        fx=_require_number(src, merged, "fl_x", where, positive=True),
        fy=_require_number(src, merged, "fl_y", where, positive=True),
        cx=_require_number(src, merged, "cx", where),
        cy=_require_number(src, merged, "cy", where),
        model=model,
        **dist,
    )


def validate_pose(matrix: Any, src: Path, where: str, tol: float = 1e-3) -> np.ndarray:
    """Check that ``matrix`` is a finite rigid 4x4 transform and return it as float64.

    Raises :class:`ScanError` for a wrong shape, non-finite entries, a last row
    other than ``[0, 0, 0, 1]``, or a rotation block that is not orthonormal with
    determinant +1 (scale, shear or reflection).
    """
    try:
        m = np.asarray(matrix, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ScanError(src, f"{where}: transform_matrix is not numeric ({exc})") from exc
    if m.shape != (4, 4):
        raise ScanError(src, f"{where}: transform_matrix must be 4x4, got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise ScanError(src, f"{where}: transform_matrix has non-finite entries (NaN or inf)")
    if not np.allclose(m[3], [0, 0, 0, 1], atol=1e-6):
        raise ScanError(
            src, f"{where}: transform_matrix last row is {m[3].tolist()}, not [0, 0, 0, 1]"
        )
    r = m[:3, :3]
    err = float(np.abs(r.T @ r - np.eye(3)).max())
    det = float(np.linalg.det(r))
    if err > tol or det < 0:
        raise ScanError(
            src,
            f"{where}: transform_matrix is not rigid (|R^T R - I| = {err:.2g}, det R = {det:.4g}); "
            "poses must be rotations plus translations, without scale, shear or mirroring",
        )
    return m


def load_scan(path: str | Path, *, check_images: bool = True) -> Scan:
    """Load and validate a scan folder (or its ``transforms.json``).

    Parameters
    ----------
    path:
        The scan folder, or the path of its ``transforms.json``.
    check_images:
        Read every image's header to check that it exists, is an image, and has
        the size the intrinsics give (cheap: no pixels are decoded).

    Raises
    ------
    ScanError
        Naming the file and the problem, for a missing or malformed
        ``transforms.json``, missing/corrupt/wrong-size images or depth maps,
        non-finite or non-rigid poses, and a missing, empty or non-triangle mesh.
    """
    path = Path(path)
    src = path if path.suffix == ".json" else path / TRANSFORMS
    root = src.parent
    if not root.exists():
        raise ScanError(root, "scan folder does not exist")
    if not src.is_file():
        raise ScanError(src, "is missing: a scan folder must hold a transforms.json")
    try:
        data = json.loads(src.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ScanError(src, f"is not valid JSON ({exc})") from exc
    if not isinstance(data, dict):
        raise ScanError(src, "top level must be a JSON object")

    frames_json = data.get("frames")
    if not isinstance(frames_json, list) or not frames_json:
        raise ScanError(src, "has no 'frames' list (a scan needs at least one frame)")

    global_intr = None
    if any(k in data for k in _INTRINSIC_KEYS):
        global_intr = _parse_intrinsics(src, data, None, "global intrinsics")

    frames: list[Frame] = []
    for i, fj in enumerate(frames_json):
        where = f"frame {i}"
        if not isinstance(fj, dict):
            raise ScanError(src, f"{where} is not an object")
        if "file_path" not in fj:
            raise ScanError(src, f"{where} lacks 'file_path'")
        if "transform_matrix" not in fj:
            raise ScanError(src, f"{where} lacks 'transform_matrix'")
        intr = _parse_intrinsics(src, fj, global_intr, where)
        c2w = validate_pose(fj["transform_matrix"], src, where)
        img_path = root / fj["file_path"]
        depth_path = root / fj["depth_file_path"] if fj.get("depth_file_path") else None
        if check_images:
            w, h = image_size(img_path)
            if (w, h) != (intr.width, intr.height):
                raise ScanError(
                    img_path, f"image is {w}x{h} but the intrinsics say {intr.width}x{intr.height}"
                )
            if depth_path is not None:
                dw, dh = image_size(depth_path)
                if (dw, dh) != (w, h):
                    raise ScanError(depth_path, f"depth map is {dw}x{dh} but its image is {w}x{h}")
        extra = {
            k: v
            for k, v in fj.items()
            if k
            not in (
                "file_path",
                "transform_matrix",
                "depth_file_path",
                *_INTRINSIC_KEYS,
                "camera_model",
                "k1",
                "k2",
                "p1",
                "p2",
            )
        }
        frames.append(Frame(i, img_path, c2w, intr, depth_path, extra))

    mesh_rel = data.get("ply_file_path")
    if not mesh_rel:
        raise ScanError(src, "lacks 'ply_file_path' naming the scan's triangle mesh")
    mesh_path = root / mesh_rel
    mesh = read_ply(mesh_path)

    known = {"frames", "ply_file_path", "camera_model", *_INTRINSIC_KEYS, "k1", "k2", "p1", "p2"}
    meta = {k: v for k, v in data.items() if k not in known}
    return Scan(root=root, frames=frames, mesh=mesh, mesh_path=mesh_path, meta=meta)


def write_scan(
    out_dir: str | Path,
    mesh: trimesh.Trimesh,
    intrinsics: Intrinsics,
    poses: Sequence[np.ndarray],
    images: Iterable[np.ndarray | Path],
    depths: Iterable[np.ndarray] | None = None,
    meta: dict[str, Any] | None = None,
    image_ext: str = ".png",
) -> Path:
    """Write a scan folder: frames, optional depth maps, the mesh, then ``transforms.json``.

    Parameters
    ----------
    out_dir:
        Destination folder (created; existing files of the same names are replaced).
    mesh:
        The triangle mesh; its ``vertex_attributes`` are written as PLY properties.
    intrinsics:
        Shared intrinsics of all frames.
    poses:
        Camera-to-world 4x4 matrices, OpenGL camera axes.
    images:
        ``(H, W, 3)`` uint8 arrays (written as PNG) or paths of existing image
        files inside ``out_dir``.
    depths:
        Optional depth maps in metres, one per frame (16-bit PNG in millimetres).
    meta:
        Extra top-level keys for ``transforms.json``.

    Returns
    -------
    Path of the written ``transforms.json``.
    """
    out = Path(out_dir)
    (out / "images").mkdir(parents=True, exist_ok=True)
    depth_list = list(depths) if depths is not None else None
    frames_json = []
    for i, (pose, img) in enumerate(zip(poses, images, strict=True)):
        pose = validate_pose(pose, out / TRANSFORMS, f"frame {i}")
        if isinstance(img, Path | str):
            rel = Path(img).resolve().relative_to(out.resolve()).as_posix()
        else:
            rel = f"images/frame_{i:05d}{image_ext}"
            write_rgb8(out / rel, img)
        fj: dict[str, Any] = {"file_path": rel, "transform_matrix": pose.tolist()}
        if depth_list is not None:
            (out / "depth").mkdir(exist_ok=True)
            drel = f"depth/frame_{i:05d}.png"
            write_depth_mm(out / drel, depth_list[i])
            fj["depth_file_path"] = drel
        frames_json.append(fj)
    write_ply(out / "mesh.ply", mesh)
    doc: dict[str, Any] = {**intrinsics.to_json(), "ply_file_path": "mesh.ply"}
    if meta:
        doc.update(meta)
    doc["frames"] = frames_json
    return atomic_write_json(out / TRANSFORMS, doc)
