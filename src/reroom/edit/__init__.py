"""Stage 5, edits and renders of the recovered room model (thesis §5.7, §7.3).

* :mod:`~reroom.edit.edits`: the edit format (``reroom-edits`` JSON), parsing and checks.
* :mod:`~reroom.edit.apply`: :func:`edited_scene`, the Mitsuba scene dict of the edited model
  (built on :func:`~reroom.edit.model.model_scene`).
* :mod:`~reroom.edit.furniture`: bundled furniture from primitives, and mesh files.
* :mod:`~reroom.edit.render_edits`: :func:`render_edit` (input frames at their exposure, new
  cameras; EXR + PNG), :func:`composite_insertion` (differential rendering into photos),
  :func:`bake_edit` (baked global illumination, PLY + glb).
* :mod:`~reroom.edit.defaults`: :func:`default_edit_sets`, what ``reroom run`` renders.
* Building blocks: :mod:`~reroom.edit.composite` (``differential_composite``),
  :mod:`~reroom.edit.bake` (``bake_vertex_radiance``, ``export_baked``),
  :mod:`~reroom.edit.rerender` (``rerender_inputs``).
"""

from reroom.edit.apply import RoomModel, edited_scene, load_model, swap_window_environment
from reroom.edit.bake import BakedLighting, bake_vertex_radiance, export_baked
from reroom.edit.composite import differential_composite
from reroom.edit.defaults import default_edit_sets
from reroom.edit.edits import EditError, edit_document, load_edits, parse_edits
from reroom.edit.furniture import BUNDLED_OBJECTS, placed_object
from reroom.edit.render_edits import bake_edit, composite_insertion, render_edit

__all__ = [
    "BUNDLED_OBJECTS",
    "BakedLighting",
    "EditError",
    "RoomModel",
    "bake_edit",
    "bake_vertex_radiance",
    "composite_insertion",
    "default_edit_sets",
    "differential_composite",
    "edit_document",
    "edited_scene",
    "export_baked",
    "load_edits",
    "load_model",
    "parse_edits",
    "placed_object",
    "render_edit",
    "swap_window_environment",
]
