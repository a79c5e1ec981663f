"""Per-vertex semantic labels used by the generator's ground truth and by the layout stage."""

from __future__ import annotations

#: Label name -> integer id written in PLY ``label`` properties.
LABELS: dict[str, int] = {
    "wall": 0,
    "floor": 1,
    "ceiling": 2,
    "door": 3,
    "window": 4,
    "baseboard": 5,
    "furniture": 6,
    "light": 7,
}

#: Integer id -> label name.
LABEL_NAMES: dict[int, str] = {v: k for k, v in LABELS.items()}
