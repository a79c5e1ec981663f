"""Point-light localization (thesis chapter 6): how many lights, where, how bright.

Given surfaces with known geometry and the direct light ``B(q)`` measured on them, the
Intensity-Distance Field ``D(p)``, its Limiter field ``L(p)`` and the voting function
``V(p)`` propose candidate light positions, and the refinement algorithm (Algorithms 1-3)
turns them into lights whose rendering matches the measurements.

Layout:

* :mod:`~reroom.localize.measurements`, :mod:`~reroom.localize.solve`,
  :mod:`~reroom.localize.refine`: dimension-free (2D floor plans and 3D scans alike):
  measurements, the shading model ``S(q, p)``, the fits, Algorithms 1-3 and the
  random-restart baseline;
* :mod:`~reroom.localize.scene2d`, :mod:`~reroom.localize.fields`: 2D rooms with exact
  occlusion, and the scene transforms on a pixel grid;
* :mod:`~reroom.localize.bench2d`, :mod:`~reroom.localize.plot`: the thesis's synthetic 2D
  dataset and evaluation (Table 6.1), and pictures of the fields;
* :mod:`~reroom.localize.fields3d`, :mod:`~reroom.localize.scene3d`: the scene transforms on
  a voxel grid, the 3D candidate proposer, and box rooms (Table 6.2);
* :mod:`~reroom.localize.scan`: room-scale localization on a scan (``reroom localize``),
  with the indirect light gathered from the observations and the hand-off to
  ``SCAN/lights/lights.json``.
"""

from reroom.localize.bench2d import (
    THESIS_TABLE_6_1,
    Scene2D,
    SceneResult,
    evaluate_scene,
    make_scene,
    matches_truth,
    random_lights,
    settings_for,
    summarize,
)
from reroom.localize.fields import (
    FieldGrid,
    FieldProposer2D,
    VoteParams,
    find_candidates,
    intensity_distance_field,
    limiter_count_field,
    medial_axis,
    voting_field,
)
from reroom.localize.fields3d import (
    VoxelGrid,
    find_peaks_3d,
    intensity_distance_field_3d,
    limiter_count_3d,
)
from reroom.localize.measurements import (
    LocalizeError,
    Measurements,
    render,
    shading_jacobian,
    shading_matrix,
)
from reroom.localize.plot import plot_fields, plot_fields_3d
from reroom.localize.refine import (
    LocalizeResult,
    RefineParams,
    associate,
    localize_lights,
    random_restarts,
    refine_positions,
    single_round,
)
from reroom.localize.scene2d import (
    Room2D,
    WallSamples,
    box_room,
    render_room,
    sample_walls,
    shot_noise,
    visibility_2d,
)
from reroom.localize.scene3d import (
    FieldProposer3D,
    VoteParams3D,
    box_light_bounds,
    box_measurements,
    box_valid_mask,
)
from reroom.localize.solve import (
    fit_lights,
    fit_lights_lm,
    mean_squared_error,
    prune_lights,
    solve_intensities,
)

__all__ = [
    "THESIS_TABLE_6_1",
    "FieldGrid",
    "FieldProposer2D",
    "FieldProposer3D",
    "LocalizeError",
    "LocalizeResult",
    "Measurements",
    "RefineParams",
    "Room2D",
    "Scene2D",
    "SceneResult",
    "VoteParams",
    "VoteParams3D",
    "VoxelGrid",
    "WallSamples",
    "associate",
    "box_light_bounds",
    "box_measurements",
    "box_room",
    "box_valid_mask",
    "evaluate_scene",
    "find_candidates",
    "find_peaks_3d",
    "fit_lights",
    "fit_lights_lm",
    "intensity_distance_field",
    "intensity_distance_field_3d",
    "limiter_count_3d",
    "limiter_count_field",
    "localize_lights",
    "make_scene",
    "matches_truth",
    "mean_squared_error",
    "medial_axis",
    "plot_fields",
    "plot_fields_3d",
    "prune_lights",
    "random_lights",
    "random_restarts",
    "refine_positions",
    "render",
    "render_room",
    "sample_walls",
    "settings_for",
    "shading_jacobian",
    "shading_matrix",
    "shot_noise",
    "single_round",
    "solve_intensities",
    "summarize",
    "visibility_2d",
    "voting_field",
]
