"""Readers for posed RGB-D captures: pose files, 16-bit depth, intrinsics, the white border."""

from __future__ import annotations

import json
import math
import re
import warnings
from pathlib import Path

import numpy as np

from reroom.errors import ScanError
from reroom.scan.camera import Intrinsics
from reroom.scan.scan import validate_pose

#: Flip between OpenCV and OpenGL camera axes, as a 4x4 (its own inverse).
CV_TO_GL_4 = np.diag([1.0, -1.0, -1.0, 1.0])

_NUMBER_RE = re.compile(r"^\d+$")


# --------------------------------------------------------------------------- poses


def _quat_to_matrix(qx: float, qy: float, qz: float, qw: float) -> np.ndarray:
    """Rotation matrix of a unit Hamilton quaternion ``(x, y, z, w)``."""
    x, y, z, w = qx, qy, qz, qw
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _nearest_rotation(r: np.ndarray) -> np.ndarray:
    u, _, vt = np.linalg.svd(r)
    out = u @ vt
    if np.linalg.det(out) < 0:
        u[:, -1] *= -1
        out = u @ vt
    return out


def read_pose_file(
    path: str | Path, *, quat_tol: float = 1e-3, quat_max_error: float = 0.05
) -> np.ndarray:
    """Read camera-to-world poses, one per frame, as an ``(N, 4, 4)`` float64 array.

    Understood layouts (chosen by the number of values on the first data line;
    every data line must then have the same count):

    * 7 numbers: ``tx ty tz qx qy qz qw`` (quaternion w last, as slambook2);
    * 8 numbers: ``timestamp tx ty tz qx qy qz qw`` (TUM RGB-D; the time is ignored);
    * 12 numbers: a row-major 3x4 ``[R | t]`` (KITTI);
    * 16 numbers: a row-major 4x4 matrix;
    * 4 numbers: a 4x4 matrix over 4 consecutive lines (blank lines may separate poses).

    Blank lines and ``#`` comments are skipped; a missing final newline is fine.
    The poses are returned as they are in the file: this function does not
    change camera axes.

    Raises
    ------
    ScanError
        Naming the file and line, for non-numeric or non-finite values, a line
        with the wrong count, a quaternion far from unit length (more than
        ``quat_max_error``; closer ones are normalised, with a warning beyond
        ``quat_tol``), or a matrix that is not a rigid transform.
    """
    path = Path(path)
    if not path.is_file():
        raise ScanError(path, "pose file is missing")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ScanError(path, f"is not a readable text file ({exc})") from exc

    rows: list[tuple[int, list[float]]] = []
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        tokens = line.replace(",", " ").split()
        try:
            values = [float(t) for t in tokens]
        except ValueError as exc:
            raise ScanError(
                path, f"line {lineno}: not a list of numbers ({raw.strip()!r})"
            ) from exc
        if not all(math.isfinite(v) for v in values):
            raise ScanError(
                path, f"line {lineno}: non-finite value (NaN or inf) in {raw.strip()!r}"
            )
        rows.append((lineno, values))
    if not rows:
        raise ScanError(path, "pose file has no poses")

    count = len(rows[0][1])
    for lineno, values in rows:
        if len(values) != count:
            raise ScanError(
                path,
                f"line {lineno}: {len(values)} numbers, but the first pose line has {count}",
            )

    poses: list[np.ndarray] = []
    if count in (7, 8):
        for lineno, values in rows:
            tx, ty, tz, qx, qy, qz, qw = values[-7:]
            norm = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
            if abs(norm - 1.0) > quat_max_error:
                raise ScanError(
                    path,
                    f"line {lineno}: quaternion (qx qy qz qw) = ({qx}, {qy}, {qz}, {qw}) has "
                    f"length {norm:.4g}, too far from 1 to be a rotation "
                    "(expected tx ty tz qx qy qz qw, quaternion w last)",
                )
            if abs(norm - 1.0) > quat_tol:
                warnings.warn(
                    f"{path}: line {lineno}: quaternion length {norm:.5f}; normalised",
                    RuntimeWarning,
                    stacklevel=2,
                )
            m = np.eye(4)
            m[:3, :3] = _quat_to_matrix(qx / norm, qy / norm, qz / norm, qw / norm)
            m[:3, 3] = (tx, ty, tz)
            poses.append(m)
    elif count in (12, 16):
        for lineno, values in rows:
            m = np.eye(4)
            m[: count // 4] = np.reshape(values, (count // 4, 4))
            poses.append(_checked_matrix(m, path, f"line {lineno}"))
    elif count == 4:
        if len(rows) % 4:
            raise ScanError(
                path,
                f"{len(rows)} lines of 4 numbers: 4x4 matrices need a multiple of 4 lines",
            )
        for k in range(0, len(rows), 4):
            m = np.array([values for _, values in rows[k : k + 4]])
            poses.append(_checked_matrix(m, path, f"lines {rows[k][0]}-{rows[k + 3][0]}"))
    else:
        raise ScanError(
            path,
            f"line {rows[0][0]}: {count} numbers; expected 7 (tx ty tz qx qy qz qw), "
            "8 (TUM: time tx ty tz qx qy qz qw), 12 (3x4), 16 (4x4) or 4 (4x4 over 4 lines)",
        )
    return np.stack(poses)


def _checked_matrix(m: np.ndarray, path: Path, where: str) -> np.ndarray:
    m = validate_pose(m, path, where)
    m = m.copy()
    m[:3, :3] = _nearest_rotation(m[:3, :3])
    return m


# --------------------------------------------------------------------------- depth


def _read_pgm(path: Path) -> np.ndarray:
    """Decode a binary PGM (P5); 16-bit samples are big-endian, as Netpbm specifies."""
    data = path.read_bytes()
    tokens: list[bytes] = []
    pos = 0
    while len(tokens) < 4:
        while pos < len(data) and data[pos : pos + 1].isspace():
            pos += 1
        if pos < len(data) and data[pos : pos + 1] == b"#":
            while pos < len(data) and data[pos : pos + 1] not in (b"\n", b"\r"):
                pos += 1
            continue
        start = pos
        while pos < len(data) and not data[pos : pos + 1].isspace():
            pos += 1
        if start == pos:
            raise ScanError(path, "PGM header is truncated")
        tokens.append(data[start:pos])
    if tokens[0] != b"P5":
        raise ScanError(path, f"is not a binary PGM (magic {tokens[0][:8]!r}, expected b'P5')")
    try:
        w, h, maxval = (int(t) for t in tokens[1:])
    except ValueError as exc:
        raise ScanError(path, f"PGM header is malformed ({exc})") from exc
    if w <= 0 or h <= 0 or not 0 < maxval < 65536:
        raise ScanError(path, f"PGM header has size {w}x{h} and maxval {maxval}")
    pos += 1  # exactly one whitespace byte separates the header from the samples
    dtype = np.dtype(">u2") if maxval > 255 else np.dtype("u1")
    need = w * h * dtype.itemsize
    if len(data) - pos < need:
        raise ScanError(path, f"PGM data is truncated ({len(data) - pos} of {need} bytes)")
    return np.frombuffer(data, dtype=dtype, count=w * h, offset=pos).reshape(h, w)


def read_depth_raw(path: str | Path) -> np.ndarray:
    """Read a depth map's raw integer samples as ``(H, W)`` uint16 (no scaling).

    Supports 16-bit PNG (and anything else Pillow reads as a single 16/32-bit
    integer channel) and binary PGM with ``maxval > 255`` (big-endian samples).
    8-bit images are refused: they cannot hold metric depth.
    """
    path = Path(path)
    if not path.is_file():
        raise ScanError(path, "depth file is missing")
    if path.suffix.lower() in (".pgm", ".pnm"):
        with path.open("rb") as f:
            magic = f.read(2)
        if magic == b"P5":
            arr = _read_pgm(path)
            if arr.dtype != np.dtype(">u2"):
                raise ScanError(path, "is an 8-bit PGM; depth needs 16-bit samples (maxval > 255)")
            return arr.astype(np.uint16)
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            mode = im.mode
            arr = np.asarray(im)
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as exc:
        raise ScanError(path, f"is corrupt or not an image ({exc})") from exc
    if arr.ndim != 2 or mode not in ("I;16", "I;16B", "I;16L", "I"):
        raise ScanError(
            path, f"is not a single-channel 16-bit depth image (mode {mode!r}, shape {arr.shape})"
        )
    if arr.size and (arr.min() < 0 or arr.max() > 65535):
        raise ScanError(path, f"depth samples outside 0..65535 ({arr.min()}..{arr.max()})")
    return arr.astype(np.uint16)


def read_depth(path: str | Path, depth_scale: float = 1000.0) -> np.ndarray:
    """Read a depth map in metres, ``(H, W)`` float32, 0 where there is no measurement.

    ``depth_m = sample / depth_scale`` (1000 for millimetres, 5000 for TUM).
    """
    if not depth_scale > 0:
        raise ValueError(f"depth_scale must be positive, got {depth_scale}")
    return read_depth_raw(path).astype(np.float32) / np.float32(depth_scale)


# --------------------------------------------------------------------------- intrinsics


def read_intrinsics(path: str | Path) -> tuple[Intrinsics, float]:
    """Read an OpenCV-style intrinsics JSON; return ``(intrinsics, depth_scale)``.

    Keys: ``width``, ``height``, ``fx``, ``fy``, ``cx``, ``cy`` (required),
    ``depth_scale`` (default 1000), ``distortion`` (absent, null, or all zero:
    Open3D's fusion has no lens model, so undistort the images first).
    ``cx, cy`` are taken with pixel centres at integer coordinates (OpenCV,
    Open3D, ``X = (u - cx) z / fx``) and shifted by +0.5 to reroom's convention.
    """
    path = Path(path)
    if not path.is_file():
        raise ScanError(path, "intrinsics file is missing")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ScanError(path, f"is not valid JSON ({exc})") from exc
    if not isinstance(data, dict):
        raise ScanError(path, "top level must be a JSON object")

    def number(key: str, positive: bool = False, default: float | None = None) -> float:
        if key not in data:
            if default is not None:
                return default
            raise ScanError(path, f"lacks '{key}'")
        v = data[key]
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise ScanError(path, f"'{key}' must be a finite number, got {v!r}")
        if positive and v <= 0:
            raise ScanError(path, f"'{key}' must be positive, got {v}")
        return float(v)

    w, h = number("width", True), number("height", True)
    if w != int(w) or h != int(h):
        raise ScanError(path, f"image size must be whole pixels, got {w}x{h}")
    dist = data.get("distortion")
    if dist is not None:
        coeffs = list(dist.values()) if isinstance(dist, dict) else dist
        if not isinstance(coeffs, list) or any(
            not isinstance(c, int | float) or c != 0 for c in coeffs
        ):
            raise ScanError(
                path,
                f"has lens distortion {dist!r}; TSDF fusion needs undistorted images "
                "(undistort them first and set 'distortion' to null)",
            )
    intr = Intrinsics(
        width=int(w),
        height=int(h),
        fx=number("fx", True),
        fy=number("fy", True),
        cx=number("cx") + 0.5,
        cy=number("cy") + 0.5,
    )
    return intr, number("depth_scale", True, default=1000.0)


# --------------------------------------------------------------------------- border mask


def white_border_mask(
    image: np.ndarray, *, threshold: int = 250, min_fraction: float = 0.9, pad: int = 2
) -> np.ndarray:
    """Boolean ``(H, W)`` mask of a white frame around the image (True = border).

    Registered Kinect frames (NYU, slambook2) carry a band of pure white where
    the colour camera saw nothing of the warped depth. A side's band is the run
    of rows (or columns) from the edge in which at least ``min_fraction`` of the
    pixels are white (every channel >= ``threshold``), grown by ``pad`` pixels
    to catch the blended seam. Bright content inside the image (a window, a
    lamp) is never masked: only whole edge lines count.
    """
    white = (np.asarray(image)[..., :3] >= threshold).all(axis=-1)
    h, w = white.shape
    mask = np.zeros((h, w), dtype=bool)

    def run(fractions: np.ndarray) -> int:
        n = 0
        for f in fractions:
            if f < min_fraction:
                break
            n += 1
        return n

    rows, cols = white.mean(axis=1), white.mean(axis=0)
    top, bottom = run(rows), run(rows[::-1])
    left, right = run(cols), run(cols[::-1])
    if top:
        mask[: min(h, top + pad)] = True
    if bottom:
        mask[max(0, h - bottom - pad) :] = True
    if left:
        mask[:, : min(w, left + pad)] = True
    if right:
        mask[:, max(0, w - right - pad) :] = True
    return mask
