"""The layout stage's error: what was looked for and not found, with what was found."""

from __future__ import annotations

from typing import Any

from reroom.errors import ReroomError


class LayoutError(ReroomError):
    """The scan does not look like a room: no floor, ceiling, walls or closed floorplan.

    Attributes
    ----------
    partial:
        What was found before the failure (frame, planes, candidates, labels...), so a
        caller can still write the labels that could be made.
    """

    def __init__(self, message: str, partial: dict[str, Any] | None = None) -> None:
        super().__init__(message)
        self.partial = dict(partial or {})
