"""Stage 5, edits and renders of the recovered room model (thesis §5.7, §7.3).

So far: differential-rendering composites into the input photos
(:mod:`~reroom.edit.composite`) and baked global illumination exported for
interactive viewers (:mod:`~reroom.edit.bake`).
"""

from reroom.edit.bake import BakedLighting, bake_vertex_radiance, export_baked
from reroom.edit.composite import differential_composite

__all__ = ["BakedLighting", "bake_vertex_radiance", "differential_composite", "export_baked"]
