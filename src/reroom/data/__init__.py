"""Data shipped with reroom: CC0 outdoor HDRIs and sample IES photometry (with licences)."""

from __future__ import annotations

from pathlib import Path

DATA_DIR = Path(__file__).resolve().parent


def hdri_path(name: str) -> Path:
    """Path of a shipped HDRI by name (``city``, ``courtyard``, ``forest``, ``interior``,
    ``night``, ``studio``, ``sunrise``, ``sunset``) or of a user's ``.exr`` file."""
    p = Path(name)
    if p.suffix.lower() == ".exr":
        return p
    cand = DATA_DIR / "hdri" / f"{name}.exr"
    if not cand.is_file():
        names = sorted(f.stem for f in (DATA_DIR / "hdri").glob("*.exr"))
        raise FileNotFoundError(
            f"no shipped HDRI named {name!r}; choose one of {names} or give an .exr path"
        )
    return cand


def ies_path(name: str) -> Path:
    """Path of a shipped IES file by stem (``ies_light_1``, ``ies_light_2``, ``ASA_15M_R2``) or a user path."""
    p = Path(name)
    if p.suffix.lower() == ".ies":
        return p
    cand = DATA_DIR / "ies" / f"{name}.ies"
    if not cand.is_file():
        names = sorted(f.stem for f in (DATA_DIR / "ies").glob("*.ies"))
        raise FileNotFoundError(
            f"no shipped IES profile named {name!r}; choose one of {names} or give an .ies path"
        )
    return cand
