"""Reading the HDR stage's ``hdr/exposures.json``: one place for every later stage.

The inverse rendering (window maps from the photos) and the edit renders both need each
frame's recovered scale ``t_j`` and the inverse response the HDR stage used.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["frame_scales", "load_exposures", "read_exposures"]


def read_exposures(scan_dir: str | Path) -> dict[str, Any]:
    """``SCAN/hdr/exposures.json`` as a dict (a :class:`~reroom.errors.ScanError` names it
    when it is missing or not JSON)."""
    from reroom.io.jsonfile import read_json

    return read_json(Path(scan_dir) / "hdr" / "exposures.json", "run `reroom hdr SCAN` first")


def frame_scales(doc: dict[str, Any]) -> list[Any]:
    """Each frame's ``scale`` by frame index (``None`` where it got no exposure).

    Raises ``KeyError``/``TypeError``/``ValueError`` on a document without a usable
    ``frames`` list; callers name the file.
    """
    frames = doc["frames"]
    scales: list[Any] = [None] * (max((int(f["index"]) for f in frames), default=-1) + 1)
    for f in frames:
        scales[int(f["index"])] = f.get("scale")
    return scales


def load_exposures(scan_dir: str | Path, meta: dict | None) -> tuple[dict[str, Any], np.ndarray]:
    """``hdr/exposures.json`` of a scan and the response LUT it names (errors name the file)."""
    from reroom.hdr.linearize import response_lut

    doc = read_exposures(scan_dir)
    return doc, response_lut(doc.get("response", "auto"), meta)
