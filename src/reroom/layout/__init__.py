"""Room layout (thesis ch. 4): Manhattan frame, floor, ceiling, walls, floorplan, vertex
labels, baseboards, doors, windows and passages, and an empty-room mesh.

The entry point is :func:`run_layout` (``reroom layout SCAN --out DIR``); the steps are
plain functions on arrays in the submodules.
"""

from reroom.layout.errors import LayoutError
from reroom.layout.features import Baseboard, Opening
from reroom.layout.labels import LAYOUT_LABELS, OTHER
from reroom.layout.pipeline import (
    OUTPUT_FILES,
    LayoutOptions,
    LayoutResult,
    layout_scan,
    run_layout,
)
from reroom.layout.structure import Structure, StructureOptions, estimate_structure

__all__ = [
    "LAYOUT_LABELS",
    "OTHER",
    "OUTPUT_FILES",
    "Baseboard",
    "LayoutError",
    "LayoutOptions",
    "LayoutResult",
    "Opening",
    "Structure",
    "StructureOptions",
    "estimate_structure",
    "layout_scan",
    "run_layout",
]
