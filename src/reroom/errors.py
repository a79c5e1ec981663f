"""Exceptions raised by reroom.

Every error that comes from bad input names the file (or object) at fault and
what is wrong with it, so that the command-line tool can print it as is.
"""

from __future__ import annotations

from pathlib import Path


class ReroomError(Exception):
    """Base class of every error reroom raises on purpose."""


class ScanError(ReroomError):
    """A scan (or a file inside it) is missing, corrupt or inconsistent.

    Parameters
    ----------
    path:
        The file or folder at fault.
    problem:
        What is wrong, as a sentence fragment ("is missing", "has no faces").
    """

    def __init__(self, path: str | Path, problem: str) -> None:
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")
