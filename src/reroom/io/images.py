"""Reading and writing images: 8-bit sRGB frames, 16-bit depth, float EXR.

Frames are read with Pillow (it reads the header without decoding the pixels,
which lets the scan loader check 1000 frames' sizes cheaply); EXR goes through
the OpenEXR bindings so that float data keeps its full range.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from reroom.errors import ScanError
from reroom.io.atomic import atomic_path


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """The sRGB transfer curve (IEC 61966-2-1) of linear values, clipped to [0, 1] first."""
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def image_size(path: str | Path) -> tuple[int, int]:
    """Return ``(width, height)`` of an image file, reading only its header.

    Raises
    ------
    ScanError
        If the file is missing or is not an image Pillow can identify.
    """
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    if not path.is_file():
        raise ScanError(path, "image file is missing")
    try:
        with Image.open(path) as im:
            return int(im.width), int(im.height)
    except (UnidentifiedImageError, OSError) as exc:
        raise ScanError(path, f"is not a readable image ({exc})") from exc


def read_rgb8(path: str | Path) -> np.ndarray:
    """Read an 8-bit colour image as a ``(H, W, 3)`` uint8 array.

    Grey images are expanded to three channels; an alpha channel is dropped.
    """
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    if not path.is_file():
        raise ScanError(path, "image file is missing")
    try:
        with Image.open(path) as im:
            if im.mode not in ("RGB", "RGBA", "L", "P", "LA"):
                raise ScanError(path, f"has pixel mode {im.mode!r}; expected 8-bit RGB")
            arr = np.asarray(im.convert("RGB"))
    except (UnidentifiedImageError, OSError, SyntaxError) as exc:
        raise ScanError(path, f"is corrupt or not an image ({exc})") from exc
    return arr


def write_rgb8(path: str | Path, image: np.ndarray) -> Path:
    """Write a ``(H, W, 3)`` uint8 image atomically (format from the suffix)."""
    from PIL import Image

    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"expected (H, W, 3) uint8, got {image.shape} {image.dtype}")
    with atomic_path(path) as tmp:
        Image.fromarray(image).save(tmp, format=_pil_format(Path(path)))
    return Path(path)


def read_depth_mm(path: str | Path) -> np.ndarray:
    """Read a 16-bit depth image in millimetres; return metres as float32 (0 = no data)."""
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    if not path.is_file():
        raise ScanError(path, "depth file is missing")
    try:
        with Image.open(path) as im:
            arr = np.asarray(im)
    except (UnidentifiedImageError, OSError, SyntaxError) as exc:
        raise ScanError(path, f"is corrupt or not an image ({exc})") from exc
    if arr.ndim != 2 or arr.dtype not in (np.uint16, np.int32, np.uint32, np.int16):
        raise ScanError(
            path, f"is not a single-channel 16-bit depth image ({arr.dtype}, {arr.shape})"
        )
    return arr.astype(np.float32) / 1000.0


def write_depth_mm(path: str | Path, depth_m: np.ndarray) -> Path:
    """Write depth in metres as a 16-bit PNG in millimetres (non-finite -> 0) atomically."""
    from PIL import Image

    d = np.asarray(depth_m, dtype=np.float64)
    mm = np.where(np.isfinite(d) & (d > 0), np.round(d * 1000.0), 0.0)
    mm = np.clip(mm, 0, 65535).astype(np.uint16)
    with atomic_path(path) as tmp:
        Image.fromarray(mm).save(tmp, format="PNG")
    return Path(path)


def _pil_format(path: Path) -> str:
    suffix = path.suffix.lower()
    return {".png": "PNG", ".jpg": "JPEG", ".jpeg": "JPEG"}.get(suffix, "PNG")


def read_exr(path: str | Path) -> np.ndarray:
    """Read an OpenEXR image as float32 ``(H, W, C)`` (RGB or RGBA channels).

    Negative values from lossy compression are kept; callers clamp if needed.
    """
    import OpenEXR

    path = Path(path)
    if not path.is_file():
        raise ScanError(path, "EXR file is missing")
    try:
        with OpenEXR.File(str(path)) as f:
            channels = f.channels()
            for key in ("RGB", "RGBA"):
                if key in channels:
                    return np.asarray(channels[key].pixels, dtype=np.float32)
            names = [n for n in ("R", "G", "B") if n in channels]
            if len(names) == 3:
                return np.stack(
                    [np.asarray(channels[n].pixels, dtype=np.float32) for n in names], axis=-1
                )
            if len(channels) == 1:
                (only,) = channels.values()
                return np.asarray(only.pixels, dtype=np.float32)[..., None]
    except ScanError:
        raise
    except Exception as exc:  # OpenEXR raises plain exceptions for corrupt files
        raise ScanError(path, f"is not a readable EXR image ({exc})") from exc
    raise ScanError(path, f"has no RGB channels (found {sorted(channels)})")


def write_exr(path: str | Path, image: np.ndarray) -> Path:
    """Write a float ``(H, W, 3)``, ``(H, W, 4)`` (RGBA) or ``(H, W)`` image as a
    ZIP-compressed EXR, atomically."""
    import OpenEXR

    arr = np.ascontiguousarray(np.asarray(image, dtype=np.float32))
    if arr.ndim == 3 and arr.shape[2] == 3:
        channels = {"RGB": arr}
    elif arr.ndim == 3 and arr.shape[2] == 4:
        channels = {"RGBA": arr}
    elif arr.ndim == 2:
        channels = {"Y": arr}
    else:
        raise ValueError(f"expected (H, W, 3), (H, W, 4) or (H, W), got {arr.shape}")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic_path(path) as tmp, OpenEXR.File(header, channels) as f:
        f.write(str(tmp))
    return Path(path)
