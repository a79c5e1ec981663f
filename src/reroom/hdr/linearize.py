"""Undo the camera's response curve: 8-bit encoded values to linear sensor values.

Every 8-bit level maps to one linear value, so a response is a 256-entry lookup
table (LUT) and linearising a frame is one indexing operation. The LUT is
normalised so that level 255 maps to 1 (the white level).

Where the curve comes from (:func:`response_lut`):

* ``"auto"``: the scan's ``meta["reroom"]["response"]`` when the scan says which
  curve its camera used (synthetic scans do), otherwise gamma 2.2 as in the thesis
  (§3.5: "an inverse gamma correction (gamma = 2.2) ... was sufficient");
* ``"gamma2.2"``, ``"srgb"``, ``"linear"``: the named curve;
* any ``gamma<g>`` (e.g. ``"gamma1.8"``);
* a user curve: a sequence of 256 numbers (linear value of each level), or the
  path of a text/JSON/``.npy`` file holding them.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from reroom.errors import ReroomError

__all__ = ["LUMA", "NAMED_RESPONSES", "linearize", "resolve_response", "response_lut"]

#: Rec. 709 luminance weights of linear RGB.
LUMA = np.array([0.2126, 0.7152, 0.0722])

NAMED_RESPONSES = ("gamma2.2", "srgb", "linear")

#: What a response may be given as: a name, a path, or 256 numbers.
ResponseSpec = str | Path | Sequence[float] | np.ndarray


def _named_lut(name: str) -> np.ndarray:
    v = np.arange(256, dtype=np.float64) / 255.0
    if name == "srgb":
        return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)
    if name == "linear":
        return v
    if name.startswith("gamma"):
        try:
            g = float(name[len("gamma") :])
        except ValueError:
            g = float("nan")
        if not (np.isfinite(g) and 0.1 <= g <= 10.0):
            raise ReroomError(f"response {name!r}: the gamma must be a number in [0.1, 10]")
        return v**g
    raise ReroomError(
        f"unknown response curve {name!r}; use one of {NAMED_RESPONSES}, 'gamma<g>', "
        "'auto', 256 numbers, or a file holding them"
    )


def _check_curve(values: Any, where: str) -> np.ndarray:
    lut = np.asarray(values, dtype=np.float64).ravel()
    if lut.shape != (256,):
        raise ReroomError(f"{where}: a response curve needs 256 values, got {lut.size}")
    if not np.all(np.isfinite(lut)):
        raise ReroomError(f"{where}: response curve has non-finite values")
    if np.any(np.diff(lut) < 0) or lut[-1] <= lut[0]:
        raise ReroomError(f"{where}: response curve must be non-decreasing and not constant")
    # Normalise so that the white level is 1, whatever units the file used.
    return (lut - lut[0]) / (lut[-1] - lut[0])


def resolve_response(spec: ResponseSpec | None, meta: dict | None = None) -> str:
    """Name the curve that ``spec`` stands for (``"auto"`` resolved from ``meta``)."""
    if spec is None or (isinstance(spec, str) and spec == "auto"):
        named = (meta or {}).get("reroom", {}).get("response")
        return named if isinstance(named, str) and named else "gamma2.2"
    if isinstance(spec, str | Path):
        return str(spec)
    return "user curve (256 values)"


def response_lut(spec: ResponseSpec | None = "auto", meta: dict | None = None) -> np.ndarray:
    """The inverse response as a ``(256,)`` float64 LUT: level -> linear value in ``[0, 1]``.

    Parameters
    ----------
    spec:
        ``"auto"``/None, a curve name, ``"gamma<g>"``, 256 numbers, or a file path
        (``.npy``, ``.json`` list, or whitespace/comma separated text).
    meta:
        The scan's ``meta`` (top-level extra keys of ``transforms.json``), for ``"auto"``.

    Raises
    ------
    ReroomError
        For an unknown name, a file that cannot be read, or a curve that is not
        256 finite non-decreasing values.
    """
    if spec is None or isinstance(spec, str) and spec == "auto":
        return _named_lut(resolve_response(spec, meta))
    if isinstance(spec, str) and not Path(spec).is_file():
        looks_like_file = "/" in spec or Path(spec).suffix in (".npy", ".json", ".txt", ".csv")
        if not looks_like_file:
            return _named_lut(spec)
    if isinstance(spec, str | Path):
        path = Path(spec)
        if not path.is_file():
            raise ReroomError(f"{path}: response curve file is missing")
        try:
            if path.suffix == ".npy":
                values = np.load(path)
            elif path.suffix == ".json":
                values = json.loads(path.read_text())
            else:
                values = np.array(path.read_text().replace(",", " ").split(), dtype=np.float64)
        except (ValueError, OSError) as exc:
            raise ReroomError(f"{path}: cannot read a response curve ({exc})") from exc
        return _check_curve(values, str(path))
    return _check_curve(spec, "response")


def linearize(image: np.ndarray, lut: np.ndarray) -> np.ndarray:
    """Linear float32 values of an 8-bit image through an inverse-response ``lut``."""
    image = np.asarray(image)
    if image.dtype != np.uint8:
        raise ValueError(f"expected an 8-bit image, got {image.dtype}")
    return np.asarray(lut, dtype=np.float32)[image]
