"""Atomic file output: write to a temporary file beside the target, then rename.

A crash (or Ctrl-C) while writing leaves at most a stray ``.tmp`` file, never a
half-written result under the final name.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any


@contextlib.contextmanager
def atomic_path(target: str | Path) -> Iterator[Path]:
    """Yield a temporary path; on success rename it onto ``target``.

    The temporary file lives in the target's folder (so the rename is atomic on
    POSIX) and keeps the target's suffix (so writers that infer the format from
    the extension, such as imageio or trimesh, still work).
    """
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(
        prefix=f".{target.stem}.", suffix=f".tmp{target.suffix}", dir=target.parent
    )
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        # mkstemp makes the file private (0600); give it the mode a plain open() would.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        raise


def atomic_write_bytes(target: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``target`` atomically and return the target path."""
    with atomic_path(target) as tmp:
        tmp.write_bytes(data)
    return Path(target)


def atomic_write_text(target: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``target`` atomically and return the target path."""
    return atomic_write_bytes(target, text.encode("utf-8"))


def _json_default(obj: Any) -> Any:
    import numpy as np

    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"cannot serialise {type(obj).__name__} to JSON")


def nan_to_null(obj: Any) -> Any:
    """``obj`` with every float that is not finite (a metric with nothing to measure,
    e.g. a loop seam with no loop pair) replaced by ``None``: JSON has no NaN, and an
    evaluation that cannot compute one figure should still be written."""
    import numpy as np

    if isinstance(obj, dict):
        return {k: nan_to_null(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [nan_to_null(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return nan_to_null(obj.tolist())
    if isinstance(obj, (float, np.floating)):
        return float(obj) if np.isfinite(obj) else None
    return obj


def atomic_write_json(target: str | Path, obj: Any, indent: int | None = 2) -> Path:
    """Serialise ``obj`` as JSON (numpy arrays become lists) and write it atomically."""
    text = json.dumps(obj, indent=indent, default=_json_default, allow_nan=False)
    return atomic_write_text(target, text + "\n")
