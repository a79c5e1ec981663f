"""Scene-scale inverse rendering: lights and materials from an HDR mesh (thesis ch. 5).

Transfer (this package's :mod:`~reroom.invert.basis`, :mod:`~reroom.invert.transfer`,
:mod:`~reroom.invert.direct`, :mod:`~reroom.invert.windows`, :mod:`~reroom.invert.portal`,
:mod:`~reroom.invert.subsample`): the incident indirect light at mesh vertices and the
irradiance each basis light would give them; see ``docs/invert.md``.
"""

from reroom.invert.area import DEFAULT_AREA_SAMPLES, area_light_transfer
from reroom.invert.basis import CubemapBasis, InclinationBasis, LineBasis, SHBasis
from reroom.invert.direct import DEFAULT_LINE_SEGMENTS, line_light_transfer, point_light_transfer
from reroom.invert.portal import DEFAULT_WINDOW_SAMPLES, window_portal_transfer
from reroom.invert.subsample import nearest_receivers, spread_transfer, voxel_receivers
from reroom.invert.transfer import (
    DEFAULT_RAYS_PER_VERTEX,
    HemisphereTransfer,
    hemisphere_transfer,
    mean_edge_lengths,
)
from reroom.invert.windows import WindowOpening, rays_through_windows

__all__ = [
    "DEFAULT_AREA_SAMPLES",
    "DEFAULT_LINE_SEGMENTS",
    "DEFAULT_RAYS_PER_VERTEX",
    "DEFAULT_WINDOW_SAMPLES",
    "CubemapBasis",
    "HemisphereTransfer",
    "InclinationBasis",
    "LineBasis",
    "SHBasis",
    "WindowOpening",
    "area_light_transfer",
    "hemisphere_transfer",
    "line_light_transfer",
    "mean_edge_lengths",
    "nearest_receivers",
    "point_light_transfer",
    "rays_through_windows",
    "spread_transfer",
    "voxel_receivers",
    "window_portal_transfer",
]

# Solve (eq. 5.7), pipeline and outputs: see docs/invert.md.
from reroom.invert.pipeline import InvertOptions, InvertResult, run_invert  # noqa: E402
from reroom.invert.solve import (  # noqa: E402
    InverseProblem,
    LightBlock,
    SolveOptions,
    SolveResult,
    per_vertex_albedo,
    solve_lighting,
)

__all__ += [
    "InverseProblem",
    "InvertOptions",
    "InvertResult",
    "LightBlock",
    "SolveOptions",
    "SolveResult",
    "per_vertex_albedo",
    "run_invert",
    "solve_lighting",
]
