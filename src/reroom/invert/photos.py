"""The scan's photos in the HDR mesh's radiance units: exposures and response.

The HDR stage writes ``hdr/exposures.json``: the camera response it linearised with and
each frame's exposure ``scale`` (linear pixel = scale x radiance). Stages after the
solve that go back to the photos (the window maps of :mod:`reroom.invert.window_env`,
the surface textures of :mod:`reroom.invert.textures`) read both here, so a pixel means
the same radiance to them as to the HDR mesh.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from reroom.errors import ReroomError

__all__ = ["frame_scale", "open_photos", "pixel_grid", "read_frame_scales", "scan_response"]


def read_frame_scales(scan: Path) -> tuple[dict, list[Any]]:
    """``hdr/exposures.json`` and each frame's ``scale`` by frame index (None: no exposure)."""
    from reroom.hdr.exposures import frame_scales, read_exposures

    doc = read_exposures(scan)
    try:
        return doc, frame_scales(doc)
    except (ValueError, KeyError, TypeError) as exc:
        path = scan / "hdr" / "exposures.json"
        raise ReroomError(f"{path}: cannot read the frame exposures ({exc!r})") from exc


def frame_scale(scales: list[Any], index: int) -> np.ndarray | None:
    """Frame ``index``'s per-channel ``scale`` as ``(3,)``, None when it has none usable."""
    scale = scales[index] if index < len(scales) else None
    if scale is None:
        return None
    s = np.broadcast_to(np.asarray(scale, float), (3,))
    if not np.all(np.isfinite(s)) or np.any(s <= 0):
        return None
    return s


def scan_response(doc: dict, meta: dict, note: Callable[[str], None]) -> np.ndarray:
    """The HDR stage's inverse response: the curve it names in ``exposures.json``."""
    from reroom.hdr.linearize import response_lut

    name = doc.get("response")
    if not isinstance(name, str) or name.startswith("user curve"):
        spec = doc.get("options", {}).get("response", "auto")
        if not isinstance(spec, str) or spec.startswith("user curve"):
            note(
                "photos: the HDR stage used a curve given as numbers; linearised "
                "with the scan's own ('auto') instead"
            )
            spec = "auto"
        return response_lut(spec, meta)
    return response_lut(name, meta)


def open_photos(
    scan_dir: str | Path, note: Callable[[str], None]
) -> tuple[Any, list[Any], np.ndarray]:
    """What reading a scan's photos in the HDR mesh's units takes: the scan (frames not
    checked), each frame's exposure ``scale`` (:func:`read_frame_scales`) and the inverse
    response (:func:`scan_response`; ``note`` hears how it was chosen)."""
    from reroom.scan import load_scan

    scan_dir = Path(scan_dir)
    scan = load_scan(scan_dir, check_images=False)
    doc, scales = read_frame_scales(scan_dir)
    return scan, scales, scan_response(doc, scan.meta, note)


def pixel_grid(width: int, height: int, max_rays: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of a regular pixel grid with at most about ``max_rays`` pixels
    (every ``stride``-th pixel both ways): the pixels the photo readers cast."""
    stride = max(1, int(np.ceil(np.sqrt(width * height / max(int(max_rays), 1)))))
    return np.arange(0, height, stride), np.arange(0, width, stride)
