"""HDR capture: radiometric calibration of auto-exposed frames onto the mesh (thesis ch. 3).

Entry point: :func:`run_hdr` (``reroom hdr SCAN --out DIR``). The steps are
available on their own: :func:`response_lut` / :func:`linearize` (inverse camera
response), :func:`collect_observations` (vertex-to-pixel matching with
visibility), :func:`solve_exposures` (eq. 3.1, global, robust),
:func:`reproject_radiance` (weighted medians, eq. 3.2-3.4), and the baselines
:func:`frame_to_frame` and :func:`frame_to_model`. Evaluation against synthetic
ground truth lives in :mod:`reroom.hdr.evaluate`. See ``docs/hdr.md``.
"""

from reroom.hdr.baselines import frame_to_frame, frame_to_model
from reroom.hdr.linearize import linearize, response_lut
from reroom.hdr.observe import Observations, ObserveOptions, collect_observations
from reroom.hdr.pipeline import OUTPUT_FILES, HdrOptions, HdrResult, run_hdr
from reroom.hdr.reproject import Radiance, best_frame_texture, reproject_radiance
from reroom.hdr.solve import (
    ExposureSolution,
    SolveOptions,
    SolveProblem,
    solve_exposures,
    solve_problem,
)

__all__ = [
    "OUTPUT_FILES",
    "ExposureSolution",
    "HdrOptions",
    "HdrResult",
    "ObserveOptions",
    "Observations",
    "Radiance",
    "SolveOptions",
    "SolveProblem",
    "best_frame_texture",
    "collect_observations",
    "frame_to_frame",
    "frame_to_model",
    "linearize",
    "reproject_radiance",
    "response_lut",
    "run_hdr",
    "solve_exposures",
    "solve_problem",
]
