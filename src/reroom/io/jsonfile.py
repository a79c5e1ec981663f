"""Reading the JSON documents one stage leaves for the next, with errors that name the file."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from reroom.errors import ScanError

__all__ = ["read_json"]


def read_json(path: str | Path, missing: str) -> Any:
    """The parsed content of ``path``.

    Parameters
    ----------
    path:
        A JSON file.
    missing:
        What to tell the user when the file does not exist, e.g. ``"run `reroom hdr
        SCAN` first"``.

    Raises
    ------
    ScanError
        Naming the file: missing or unreadable (with ``missing``), or not valid JSON.
    """
    path = Path(path)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ScanError(path, f"is missing: {missing}") from exc
    except (ValueError, UnicodeDecodeError) as exc:
        raise ScanError(path, f"is not valid JSON ({exc})") from exc
