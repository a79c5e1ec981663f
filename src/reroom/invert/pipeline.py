"""``reroom invert SCAN``: lights and materials of a scanned room (thesis ch. 5).

Reads ``SCAN/hdr/hdr_mesh.ply`` (radiance, observed), ``SCAN/layout/layout_labels.ply``
(per-vertex wall / floor / ceiling / ... labels) and ``SCAN/lights/lights.json`` (which
lights exist and where), computes the hemisphere transfer (indirect light, area lights,
windows in a cube-map basis) on a voxel subsample of the observed vertices (copied to
the others, :mod:`reroom.invert.subsample`) and the point and line light transfers on
every observed vertex, solves eq. 5.7 on the wall, floor and ceiling clusters
(:mod:`reroom.invert.solve`), then every observed vertex's albedo with the solved light,
and writes ``SCAN/invert/`` (:mod:`reroom.invert.export`). Never reads ``ground_truth/``.
"""

from __future__ import annotations

import json
import time
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

from reroom.errors import ReroomError, ScanError
from reroom.invert.area import DEFAULT_AREA_SAMPLES, area_light_transfer
from reroom.invert.area_region import area_region, on_emitting_plane
from reroom.invert.basis import CubemapBasis, InclinationBasis, LineBasis
from reroom.invert.direct import line_light_transfer, point_light_transfer
from reroom.invert.fill import DEFAULT_FILL_ALBEDO, bounce_fill
from reroom.invert.line_fixture import (
    MAX_INSIDE_FRACTION,
    inside_fraction,
    line_open_fraction,
    scan_fixture_caster,
)
from reroom.invert.normals import auto_note, check_normal_radius, receiver_normals
from reroom.invert.portal import DEFAULT_WINDOW_SAMPLES, window_portal_transfer
from reroom.invert.receivers import near_occlusion
from reroom.invert.solve import (
    InverseProblem,
    LightBlock,
    SolveOptions,
    SolveResult,
    footprint_operator,
    per_vertex_albedo,
    solve_lighting,
)
from reroom.invert.subsample import spread_transfer, voxel_receivers
from reroom.invert.surroundings import unseen_surroundings
from reroom.invert.transfer import hemisphere_transfer, inset_points
from reroom.invert.windows import WindowOpening
from reroom.io.mesh import read_ply
from reroom.rays import RayCaster
from reroom.rays.geometry import segment_distance

__all__ = ["InvertOptions", "InvertResult", "run_invert", "CLUSTER_LABELS"]

#: Layout label ids of the clusters solved with the lights (``reroom.synth.labels``).
CLUSTER_LABELS = {"wall": 0, "floor": 1, "ceiling": 2}


@dataclass
class InvertOptions:
    """Options of :func:`run_invert`.

    Parameters
    ----------
    cubemap_n : int
        Cube-map cells per face edge of window light (thesis: 4, 96 cells).
    render_window_cells : int
        After the solve, solve each window again alone on a cube map with this many
        cells per face edge, every other light held at its solved intensities, and use
        that finer map for the renders: the window's ``window_<name>.exr``, the
        textures and the per-vertex albedos (:mod:`reroom.invert.render_window`).
        ``scene.json``'s cells, powers and cluster albedos stay the ``cubemap_n``
        solve's. 0 (or ``cubemap_n``): no refit. The default, 8, on `furnished` (60
        frames, 256 spp, 1024-spp truths): the panel switched off renders at 9.2 / 10.2 %
        from the input / new cameras instead of 10.5 / 10.4 % with no refit, and no edit
        measured got worse by more than 0.2 points (docs/benchmarks.md, "Session 35");
        it costs about 3 s a window.
    render_window_smooth : float
        ``window_smooth`` of that refit.
    render_window_photo_bounds : bool
        Hold each fine cell of that refit at least as bright as the photos through the
        window prove it is (:func:`reroom.invert.window_env.cell_lower_bounds`, as
        ``window_photo_bounds`` does for the solve; joint solver only). The solve and
        ``scene.json``'s figures are not touched; with the alternating solver the refit
        goes on without them (a note). On by default: on `furnished` the
        input frames that look out of the window render at 45.6 % instead of 56.7 %
        (22.7 % instead of 47.2 % clipped as a photo is), and no other view moves by more
        than 0.2 points (docs/benchmarks.md, "Session 36").
    window_smooth : float
        Weight of the smoothness between neighbouring window cells, relative to
        ``solve.smooth_lambda`` (1: the thesis's weak smoothness, as every light).
    bins : int
        Inclination bins of point lights, and ``theta`` bins (around the line) of line
        lights (thesis: 32).
    point_splits : int
        After the solve, split each point light's bins in two this many times, the flux
        of each bin kept and its share between the halves fitted to the receivers with
        everything else held (:mod:`reroom.invert.fine_profiles`): the exported profile
        then has ``bins * 2 ** point_splits`` bins, sharp enough for a downlight's
        scallops, while every power and albedo is the solve's. 0: the solve's bins.
        The default, 2 (128 bins of 1.4 degrees): on `furnished` every edit renders as
        well as or better than with 1 (the moved downlight 10.0 -> 9.9 %, the panel
        switched off 9.0 / 9.9 -> 8.8 / 9.7 % from the input / new cameras;
        docs/benchmarks.md, "Session 37"), for about 0.4 s more.
    point_photo_profile : bool
        After the splits, fit each point light's profile again to the photos' pixels on
        the ``point_photo_clusters`` surfaces it lights, everything else held, each
        group of the solve's bins keeping its flux
        (:mod:`reroom.invert.photo_profiles`): the pixels resolve a beam's edge on a
        wall that the receivers, centimetres apart, do not.
    window_view_height : int
        Rows of ``window_<name>_view.exr``, the lat-long map a camera looking out of a
        window is shown: the photos' own radiance where they saw the outdoors
        unsaturated, the lighting map elsewhere
        (:func:`reroom.invert.window_env.view_map`; the room stays lit by the lighting
        map). 0: none (the camera sees the lighting map, each solved cell's mean shaped
        by the photos).
    point_photo_clusters : str
        The clusters (comma-separated) whose pixels that fit reads, each with its
        cluster albedo, as the solve takes it. A wooden floor's planks differ from that
        mean, and the Huber weights leave the outliers out; the floor holds the beam's
        middle, which no wall sees (on `furnished` the downlight's profile at 128 bins
        came to 8.0 % of the truth with the floor, 11.3 % without, from 13.8 %).
    point_photo_samples : int
        Photo pixels that fit takes per light at most, spread evenly over the bins
        (:func:`reroom.invert.photo_profiles.even_subset`): on the 300-frame 640x360
        scan the downlight had 591k pixels and the fit took 200 s of the 5-minute run.
    surroundings : bool
        Measure how much of the receivers' hemisphere leaves the mesh through holes, and
        the radiance eq. 5.9 gave those directions (:mod:`reroom.invert.surroundings`;
        ``scene.json`` ``surroundings``). Where that share is at least
        ``surroundings_min_escape`` the renders add a constant environment of that
        radiance, so that a scan that does not close (slambook2's unseen ceiling) renders
        with the light the solve assumed instead of losing it through the holes.
    surroundings_min_escape : float
        The escaping share below which a mesh counts as closed (nothing rendered).
    line_phi_bins : int
        ``phi`` bins of line lights (angle out of the plane perpendicular to the line,
        :class:`~reroom.invert.basis.LineBasis`): the profile is ``i(theta, phi)
        cos(phi)``. 1 is the thesis's separable ``i(theta) cos(phi)``, which cannot tell
        light leaving a tube's channel through its open ends (large ``|phi|``) from light
        leaving sideways. 3 (0-30, 30-60, 60-90 degrees) measured best on `furnished`
        against 1, 2, 4, 5, 6 and 8 (docs/invert.md).
    line_phi_fold : bool
        Whether ``phi`` and ``-phi`` (towards either end of the line) share a bin. Folded
        by default: a tube's two ends are alike, and keeping the sign (twice the unknowns,
        half the data each) measured no better on `furnished`.
    line_phi_smooth : float
        Weight of the smoothness between ``phi`` neighbours of a line light, relative to
        that between ``theta`` neighbours (whose weight is ``solve.smooth_lambda``). The
        data hardly separate the ``phi`` bins of one ``theta`` (only the receivers' places
        along the line do), so they are tied far more strongly: 1e5 (``1e5 x 1e-5 = 1`` of a
        bin's data curvature); 1 to 100 left the ``phi`` split noisy (distribution error
        65-73 % on `furnished`), 1e4 gave 28 %. 1e5 (session 15) took the tube 2-5 points
        closer in power and distribution than 1e4 on both `furnished` scans; 1e6 the same
        as 1e5 (docs/invert.md).
    line_clearance : float
        Metres around a line light inside which nothing shadows it
        (:func:`reroom.invert.direct.line_light_transfer`'s ``clearance``), as
        ``point_clearance``: a tube's housing and baffles are then part of its solved
        distribution (the tube as seen from outside its fixture) instead of geometry in
        the shadow rays. With 3 cm (the transfer's own default, and this option's value
        before the ``phi`` bins) the baffles shadow the line in the transfer, so the solve
        recovers the *bare* tube's intensity in every direction some receiver sees past
        them, and its power counted the light the baffles stop (+150 to +200 % against
        what leaves the fixture on `furnished`).
    line_shape_prior : float
        Weight of the line lights' shape prior, relative to the ``theta`` smoothness
        (0: none). A tube is diffuse, so in a fixture its intensity is the bare tube's
        ``i0`` times the fraction of the tube the fixture leaves open in each direction
        (:mod:`reroom.invert.line_fixture`, computed on the scanned mesh within
        ``line_clearance`` of the tube). The solve pulls the profile toward ``i0 *
        open`` with ``i0`` free (``LightBlock.shape``). 1e5 (one bin's data curvature,
        as ``line_phi_smooth``) measured best on `furnished` against 1e3-1e6: the tube's
        distribution error 32 → 6 %, its luminance power +23 → −0.5 % (docs/invert.md,
        "Session 17"). Dropped, with a note, for a tube whose fixture the scan does not
        resolve (:func:`reroom.invert.line_fixture.inside_fraction`).
    line_fixture_samples : int
        Points on the tube per direction when integrating the open fraction.
    point_shape_prior : float
        Weight of the shape prior of a point light that localization placed inside a
        lamp shade (its evidence ``height_from == "pool edge"``), relative to its
        smoothness (0: none): a bulb is about isotropic, so in a shade its profile is
        ``i0 * open(theta)``, ``open`` the part of each inclination band the scanned
        shade leaves open within ``point_clearance`` (:mod:`reroom.invert.point_fixture`).
        Other point lights (a downlight's reflector shapes its light) get none, nor a
        bulb inside a shade the scan closed (rays from it leaving through back faces).
        1e4 measured best against 1e3 and 1e5 on two 60-frame `furnished` scans: the
        floor lamp's distribution error 10.7 / 9.7 % -> 3.2 / 5.4 %, while at 1e5 the
        panel and the window gave up 2-5 points (docs/invert.md, "Session 22").
    line_photo_fixture : bool
        Where the scan does not resolve a tube's fixture, take the tube's axis and radius
        and a trough around it from the photos (:mod:`reroom.invert.line_photos`)
        instead of dropping the shape prior.
    area_outline : bool
        An area light is the part of the mesh around its vertices that lies inside the
        convex outline of those on its emitting face's plane
        (:mod:`reroom.invert.area_region`), in the direct transfer, in the hemisphere
        rays' classes (a rim triangle's hit is light inside the outline, surface
        outside), its power and its rendering; False: the
        barycentric share of its vertices, which on a fused scan reaches half a row of
        triangles past the row of vertices that is already past the panel's edge
        (docs/invert.md, "An area light's outline").
    photo_color : float
        Weight of a prior on each line and area light's colour read from the
        unsaturated edge of its clipped image in the photos
        (:mod:`reroom.invert.emitter_color`; the solve's
        ``LightBlock.color_prior_weight``, relative to the data term); 0: none. An area
        light with a measured colour is solved as colour x scalar. Needs the joint solver.
    rays_per_receiver : int
        Hemisphere rays per receiving vertex.
    receiver_voxel : float
        Metres; one receiver per voxel and normal octant (0: every observed vertex).
    line_segments : int
        Shadow-ray pieces of a line light.
    area_samples : int
        Points sampled on each area light per receiver (its transfer integrates over
        the light's surface: the hemisphere rays' hit count is far too noisy for
        small lights, see :mod:`reroom.invert.area`).
    window_samples : int
        Points sampled on each window opening per receiver
        (:func:`reroom.invert.portal.window_portal_transfer`): the window's transfer
        integrates over the opening. 0 counts the hemisphere rays that leave through it
        instead (the thesis's hemicube, as sampled rays): unbiased but so noisy per cube
        cell that the solve dims the cells seen at grazing angles (regression dilution;
        docs/invert.md, "Windows as portals").
    fixture_margin : float
        Metres: vertices this close to a line light (beyond its radius) or to a point
        light are its glowing fixture, left out of the indirect light. A point light's
        transfer is zero within it, also where the refinement moves the light.
    receiver_inset : float
        Compute every transfer at a point moved into the receiver's own surface by up
        to this fraction of its mean edge length (:func:`reroom.invert.transfer.
        inset_points`), away from seams where shadow rays start in the plane of the
        neighbouring surface. Off (0) by default: measured worse (docs/invert.md).
    point_clearance : float
        Metres around a point light inside which nothing shadows it
        (:func:`reroom.invert.direct.point_light_transfer`'s ``clearance``): its
        fixture (a lamp's shade, a downlight's can) is then part of the solved
        distribution -- the light as seen from outside the fixture, as the thesis's
        generalized point light -- instead of geometry in the shadow rays. A fused scan
        closes a shade's openings and a recess around its bulb; with a 2 cm clearance
        the lamp then lights nothing and its light goes into the albedos (docs/invert.md).
    near_distance : float
        Metres. Clustered receivers whose hemisphere is blocked within this distance
        (seams, contact gaps: :mod:`reroom.invert.receivers`) by more than
        ``near_max_fraction`` are left out of the lighting solve; their transfer at the
        vertex cannot match the radiance the photos show around it. 0: keep all.
    near_max_fraction : float
        See ``near_distance``.
    normal_radius : float
        Metres. Every transfer takes its receivers' normals diffused over about this
        radius of agreeing surface (:func:`reroom.invert.normals.smoothed_vertex_normals`)
        instead of the one-ring normals (0). ``None`` (the default): 0.1 where the
        floor's one-ring normals lean more than 3° in the median, else 0
        (:func:`reroom.invert.normals.receiver_normals`; ``report.json``'s ``normals``
        says which). A fused scan's one-ring normals carry its
        noise (the walls of a 24-frame 160x120 `furnished` scan lean 15° in the
        median), which the solve turns into dim lights and bright albedos. 0.1 took that
        scan's truth run from wall +6/+9/+11 %, floor +21/+28/+36 %, panel −31 % to
        +0/+1/+2 %, +5/+8/+10 %, −7/−9/−11 % (the tube from +5/−11/−18 % to
        +45/+35/+27 %), and a 60-frame one end to end from albedos within 25 % and
        lights 13-34 % off to albedos within 4.1 % and every light but the window within
        10 %; on the issue's 300-frame 320x180 scan, whose floor normals lean 1.4°, it
        made the floor 4 % dark and the lights 3-7 points brighter, hence the auto rule
        (docs/invert.md, "Session 32").
    min_bin_support : float
        A point or line light's bin whose summed transfer over the clustered receivers
        is below this fraction of its best-seen bin's is *poorly seen*: its solved value
        rests on a handful of grazing receivers (a tube's bin straight up, seen only by
        two end-wall vertices, solved to 13x the others). ``scene.json`` keeps the
        solved profile as ``profile_solved`` and gives in ``profile`` (used for power,
        IES files, pictures and rendering) those bins interpolated from the well-seen
        ones.
    textures : bool
        Albedo textures of the floor, ceiling and wall planes from the photos
        (:mod:`reroom.invert.textures`): ``textures/<plane>.exr`` and ``scene.json``'s
        ``textures``, used by the renderer instead of the per-vertex albedo on those
        surfaces. Needs ``layout.json`` and ``hdr/exposures.json``.
    texel : float or None
        Their texel size in metres (None: the median pixel footprint, 0.5-5 cm, halved
        with ``texture_solve``, at least 5 mm).
    texture_solve : bool
        Solve the texels as the least-squares answer to every photo pixel, each the
        mean of the texture over its footprint (:mod:`reroom.invert.texture_solve`),
        instead of averaging the pixels that fall in each texel, which blurs the
        pattern by the photos' footprints and the texels (docs/invert.md).
    texture_smooth : float
        A factor on the three below (2: everything twice as smooth).
    texture_smooth_wall, texture_smooth_floor, texture_smooth_ceiling : float
        How far that solve's penalty on differences between neighbouring texels
        spreads a texel's value on the planes of each label, in the photos' median
        pixel footprints: higher keeps more of the photos' noise and of the model's
        misfit out of flat surfaces, lower keeps more of a pattern's contrast. Walls
        and ceilings are usually paint, floors boards or tiles: on `furnished` walls at
        4 and the floor at 0.5 render every measured view as well as or better than 1
        everywhere (docs/invert.md, "Photo textures"); a patterned wallpaper wants its
        wall lower.
    texture_iterations : int
        The texture solve's most conjugate-gradient steps.
    texture_point_direct : bool
        The textures take the point lights' direct light at each photo sample, read
        between bins as the renderer reads the profile, and interpolate only the rest of
        the model's irradiance between vertices (``photo_textures``' ``sharp_irradiance``).
        False interpolates all of it: the edge of a downlight's beam that falls between
        vertices then stays in the albedo as a ghost when the light is moved.
    window_photos : bool
        Render windows from the photos: ``window_<name>.exr`` shows, within each solved
        cube cell, the detail of the pixels that looked out through the opening, with
        the cell's solved mean kept (:mod:`reroom.invert.window_env`); the plain cells
        stay in ``window_<name>_cells.exr``. False: the cells only.
    window_photo_prior : float
        Weight of the photos' view through each window as a prior on its cube cells,
        relative to the cells' smoothness weight ``lambda_l`` and scaled by the share of
        each cell the photos see cleanly (never saturated;
        :func:`reroom.invert.window_env.cell_means`); 0: none.
    window_photo_bounds : bool
        Hold each window cube cell at least as bright as the photos prove it is
        (:func:`reroom.invert.window_env.cell_lower_bounds`: clipped pixels count at
        their bound, unseen texels at 0; lower bounds of the joint solve). Off by
        default: on `furnished` it lowers the tube by 3-6 points without mending its
        colour (docs/invert.md, session 31).
    window_photo_shapes : bool
        Weight each direction of a window's transfer by the photos' luminance pattern
        within its cube cell (:func:`reroom.invert.window_env.cell_shapes`), so that a
        receiver that sees part of a cell through the opening gets that part's light;
        False: each cell flat, as the basis is.
    window_view_hdri : str or None
        An HDRI of the view outside the windows (an EXR, equirectangular in the scan's
        frame, any overall scale; :class:`reroom.invert.window_env.WindowView`): its
        pattern within each cube cell weights the windows' transfer, as
        ``window_photo_shapes`` does with the photos, and spreads each solved cell in
        the rendering map. Takes precedence over ``window_photo_shapes``.
    window_view_rotation_deg : float
        That HDRI's turn about +Z (degrees).
    window_sun : bool
        Look for a sun shining through each window (a sharp sunlit patch in the HDR
        radiance, :func:`reroom.invert.sun.find_sun`) and solve it as a directional light
        beside the window's cells (:func:`reroom.invert.sun.sun_transfer`); the window's
        rendering map then shows it as a small disc. Nothing changes for a window
        whose patch fails the tests (an overcast sky, a sun behind the building).
    window_sun_footprint : float or None
        Radius (metres) of the disc around each receiver over which the sun's transfer
        averages its visibility, as the HDR radiance averages the pixels around a
        vertex (None: half the receivers' median spacing; 0: the point alone).
    refine_points : bool
        After the first solve, move each point light to where its share of the solved
        lighting fits the photos best (:mod:`reroom.invert.refine_points`), then solve
        again; the new positions are kept only if the objective went down by
        ``refine_min_gain``. A bulb placed from its ceiling pool's edge
        (``evidence["height_from"] == "pool edge"``) keeps its measured place.
    refine_max_shift : float
        Metres a point light may move in that refinement.
    refine_max_receivers : int
        Clustered receivers (a seeded random subset) the refinement fits at most.
    refine_height : bool
        Let the refinement change a light's height too (False: only across the room).
        On `furnished` the height matters for the recessed downlight: refined in 3D it
        goes 3 cm up into its can (power −15/−20/−26 % → −7/−9/−11 %); across the room
        only, it stays put (docs/invert.md).
    albedo_footprint_rings : int
        The per-vertex albedo ``pi L / E`` divides each vertex's HDR radiance by the
        model's irradiance averaged over the vertex and its neighbours within this many
        mesh edges (area-weighted, over vertices that have an irradiance; 0: the point's
        own). The HDR radiance is a mean over the pixels around the vertex's projection,
        a few centimetres of surface; along creases and floor contacts the point's
        irradiance is far below that area's, and the plain ratio came out several times
        too high (session 20: on `furnished` the 90th-percentile per-vertex error of the
        seen furnishings fell from 192 % to 95 % with one ring).
    refine_recess : float
        Metres a refined point light may rise above the ceiling plane (the median height
        of the ceiling's clustered receivers), into a recess. Kept below it, the fit
        took the downlight 27 cm down into the room instead.
    refine_mounted_drop : float
        Metres below the surface above it that a point light ``reroom localize`` found
        held by that surface (``evidence["mounted_on"]``, no fitting in the scan) may go
        in the refinement. A recessed downlight's objective has a cliff at the ceiling
        plane and a second, spurious minimum low in the room: on a regenerated 256-spp
        `furnished` scan the fit took the downlight 0.30 m down (to the search's bound),
        its power −7/−8/−10 % and its profile 36 % off, the window −14/−18/−17 %
        (docs/invert.md, "Session 23"). Negative: no bound.
    refine_min_gain : float
        The refined positions are kept only if the objective falls by at least this
        fraction: on a scan whose lights explain the photos poorly (the demo, whose
        tube and window were not detected) a 0.4 % drop came with the panel's power
        doubling, while real improvements measured 24-25 % (docs/invert.md).
    unobserved_fill : str
        What the indirect light takes for the surfaces no photo saw. ``"bounce"``: one
        bounce of the observed light with reflectance ``fill_albedo``
        (:func:`reroom.invert.fill.bounce_fill`). ``"mean"``: the thesis's eq. 5.9, the
        mean radiance of the rest of each receiver's hemisphere, which gives the hidden
        undersides of the furniture the brightness of the walls and ceiling (albedos
        3-5 % low, lights 4-12 % strong on `furnished`, docs/invert.md "Session 14").
    fill_albedo : float
        See ``unobserved_fill``.
    seed : int
        Seed of the ray sampling and of the solve's vertex subset.
    solve : SolveOptions
        Options of the eq. 5.7 solve.
    pictures : bool
        Write the diagrams and cube-map pictures.
    """

    cubemap_n: int = 4
    window_smooth: float = 1.0
    render_window_cells: int = 8
    render_window_smooth: float = 1000.0
    render_window_photo_bounds: bool = True
    bins: int = 32
    point_splits: int = 2
    point_photo_profile: bool = True
    window_view_height: int = 384
    point_photo_clusters: str = "wall,ceiling,floor"
    point_photo_samples: int = 60_000
    surroundings: bool = True
    surroundings_min_escape: float = 0.01
    line_phi_bins: int = 3
    line_phi_fold: bool = True
    line_phi_smooth: float = 1e5
    line_clearance: float = 0.3
    line_shape_prior: float = 1e5
    line_fixture_samples: int = 64
    line_photo_fixture: bool = True
    area_outline: bool = True
    photo_color: float = 1.0
    point_shape_prior: float = 1e4
    rays_per_receiver: int = 512
    receiver_voxel: float = 0.1
    line_segments: int = 16
    area_samples: int = DEFAULT_AREA_SAMPLES
    window_samples: int = DEFAULT_WINDOW_SAMPLES
    fixture_margin: float = 0.05
    receiver_inset: float = 0.0
    point_clearance: float = 0.3
    near_distance: float = 0.05
    near_max_fraction: float = 0.15
    normal_radius: float | None = None
    min_bin_support: float = 0.01
    textures: bool = True
    texel: float | None = None
    texture_solve: bool = True
    texture_smooth: float = 1.0
    texture_smooth_wall: float = 4.0
    texture_smooth_floor: float = 0.5
    texture_smooth_ceiling: float = 2.0
    texture_iterations: int = 15
    texture_point_direct: bool = True
    window_photos: bool = True
    window_photo_prior: float = 0.0
    window_photo_bounds: bool = False
    window_photo_shapes: bool = False
    window_view_hdri: str | None = None
    window_view_rotation_deg: float = 0.0
    window_sun: bool = True
    window_sun_footprint: float | None = None
    refine_points: bool = True
    refine_max_shift: float = 0.3
    refine_max_receivers: int = 20000
    refine_min_gain: float = 0.02
    refine_height: bool = True
    refine_recess: float = 0.05
    refine_mounted_drop: float = 0.1
    unobserved_fill: str = "bounce"
    fill_albedo: float = DEFAULT_FILL_ALBEDO
    albedo_footprint_rings: int = 1
    seed: int = 0
    solve: SolveOptions = field(default_factory=SolveOptions)
    pictures: bool = True


#: The choices of ``InvertOptions.unobserved_fill``.
UNOBSERVED_FILLS = ("bounce", "mean")


@dataclass
class InvertResult:
    """What :func:`run_invert` computed (also written to ``out_dir``).

    Attributes
    ----------
    solve : SolveResult
        Lights and cluster albedos.
    lights : list of LightBlock
        The solved lights, in column order.
    light_info : list of dict
        Each light's geometry, as read from ``lights.json``.
    cluster_names : list of str
    albedo : ndarray, shape (V, 3)
        Per-vertex albedo (NaN where unknown).
    flags : dict of str to ndarray of bool, shape (V,)
        ``in_cluster``, ``solved_per_vertex``, ``nonphysical``, ``unobserved``,
        ``light`` (a light's own surface).
    cubemap_n, bins : int
    timings : dict of str to float
    warnings : list of str
    out_dir : Path
    problem : InverseProblem or None
        The eq. 5.7 data that was solved (for diagnosis: re-solve it with one input
        swapped, see ``benchmarks/bench_invert_diagnosis.py``).
    problem_vertices : ndarray of int or None
        Mesh vertex index of each row of ``problem``.
    """

    solve: SolveResult
    lights: list[LightBlock]
    light_info: list[dict]
    cluster_names: list[str]
    albedo: np.ndarray
    flags: dict[str, np.ndarray]
    cubemap_n: int
    bins: int
    timings: dict[str, float]
    warnings: list[str]
    out_dir: Path
    problem: InverseProblem | None = None
    problem_vertices: np.ndarray | None = None
    textures: list | None = None
    render_windows: dict = field(default_factory=dict)
    surroundings: dict | None = None


def _require(path: Path, what: str) -> Path:
    if not path.is_file():
        raise ScanError(path, f"is missing ({what})")
    return path


def _load_lights(scan: Path, n_vertices: int, notes: list[str]):
    """The scan's light set, or None with a warning when there is none."""
    from reroom.lights import load_lights

    path = scan / "lights" / "lights.json"
    if not path.is_file():
        notes.append(f"{path} is missing: solving with no lights (run `reroom lights` first)")
        return None
    lights = load_lights(path)
    if len(lights.vertex_light_id) not in (0, n_vertices):
        raise ScanError(
            path,
            f"has {len(lights.vertex_light_id)} per-vertex light ids for a mesh of "
            f"{n_vertices} vertices",
        )
    if not lights.lights:
        notes.append(f"{path} lists no light: albedos explain the radiance by indirect light")
    return lights


def _fixture_vertices(points: np.ndarray, lights: list, margin: float) -> np.ndarray:
    """Vertices on the glowing surface of a line or point light (within ``margin``).

    A line light's glowing surface reaches its tube's radius or, where the detection
    measured it wider (``evidence["size_m"]``: a fused scan's tube and housing, one blob
    brighter than the room), half that width.
    """
    near = np.zeros(len(points), dtype=bool)
    for light in lights:
        g = light.geometry
        if light.type == "line":
            dist = segment_distance(points, g["p0"], g["p1"])
            reach = float(g.get("radius", 0.0))
            size = (light.evidence or {}).get("size_m")
            if isinstance(size, list | tuple) and len(size) >= 2:
                width = float(size[1])
                reach = max(reach, width / 2) if np.isfinite(width) else reach
            near |= dist <= reach + margin
        elif light.type == "point":
            near |= np.linalg.norm(points - np.asarray(g["position"], float), axis=1) <= margin
    return near


def emitter_surfaces(
    light_list: list, vertex_light_id: np.ndarray, n_vertices: int
) -> tuple[list, list, np.ndarray, np.ndarray]:
    """The area lights and windows of a light list, and which vertices are their surfaces.

    Returns ``(areas, windows, area_of, window_of)``: the area lights and the windows in
    list order, and per vertex the index of the area light (window) whose surface it
    is, -1 elsewhere -- the classes :func:`reroom.invert.transfer.hemisphere_transfer`
    takes.
    """
    ids = np.asarray(vertex_light_id)
    areas = [x for x in light_list if x.type == "area"]
    wins = [x for x in light_list if x.type == "window"]
    area_of = np.full(n_vertices, -1, np.int64)
    window_of = np.full(n_vertices, -1, np.int64)
    for k, light in enumerate(areas):
        area_of[ids == light_list.index(light)] = k
    for k, light in enumerate(wins):
        window_of[ids == light_list.index(light)] = k
    return areas, wins, area_of, window_of


#: Tube radius (metres) assumed for a line light whose geometry has none (a T8 tube).
DEFAULT_TUBE_RADIUS = 0.013
#: A light's colour from the photos varying more than this between frames (half its 90 %
#: bootstrap interval, per channel) is not used (reroom.invert.emitter_color): the demo's
#: 16-spp 160x120 frames gave the panel's colour to +-2.4-4.1 % and 5 % off in blue,
#: which the solve then took; 64 spp at 320x180 and 256 spp at 160x120 give 0.1-1.4 %.
MAX_PHOTO_COLOR_SPREAD = 0.02


def _line_open_shape(
    scan: Path, mesh, name: str, geometry: dict, basis: LineBasis, options: InvertOptions,
    notes: list[str], caster: RayCaster | None = None,
) -> tuple[np.ndarray | None, dict, dict]:  # fmt: skip
    """The open fraction of a line light's tube per bin, its info, and its geometry.
    (``caster``: the whole scan's, for the photos' view of the tube, if the caller has one.)

    From the scanned fixture where the scan resolves it. Where it does not (rays from
    the tube leave through back faces: :func:`~reroom.invert.line_fixture.inside_fraction`,
    e.g. a fused scan that closed the baffles' channel around the tube), from the
    photos (:mod:`reroom.invert.line_photos`): the tube's axis and radius from its
    saturated stripes (the returned geometry then has them: the transfer uses that
    axis) and a trough whose cut-off is where the photos lose the tube. ``(None, {...},
    geometry)`` with a note when neither can be had, or the fixture hides the tube
    everywhere: the prior would then pull the profile toward a wrong shape. ``(None,
    {}, geometry)`` when the prior is off.
    """
    if options.line_shape_prior <= 0:
        return None, {}, geometry
    radius = float(geometry.get("radius", DEFAULT_TUBE_RADIUS))
    p0, p1 = np.asarray(geometry["p0"], float), np.asarray(geometry["p1"], float)
    up = np.asarray(geometry["d_perp"], float)
    fixture = scan_fixture_caster(mesh.vertices, mesh.faces, p0, p1, radius, options.line_clearance)
    info: dict[str, Any] = {}
    if fixture is not None:
        inside = inside_fraction(fixture, p0, p1, radius, options.line_clearance)
        if inside > MAX_INSIDE_FRACTION:
            why = (
                f"the scan does not resolve the fixture of line light {name!r} "
                f"({100 * inside:.0f} % of the rays from its tube leave through back faces: "
                "the tube is partly inside the scanned geometry)"
            )
            info["fixture_inside_fraction"] = round(inside, 4)
            found = (
                _photo_trough(scan, mesh, name, geometry, options, notes, caster)
                if options.line_photo_fixture
                else None
            )
            if found is None:
                notes.append(f"{why}: no shape prior")
                return None, info, geometry
            fixture, geometry, photo_info = found
            notes.append(f"{why}: its tube and a trough from the photos instead")
            info["fixture_from_photos"] = photo_info
            radius = float(geometry["radius"])
            p0, p1 = np.asarray(geometry["p0"], float), np.asarray(geometry["p1"], float)
    if fixture is None:
        open_frac = np.ones(basis.size)
    else:
        open_frac = line_open_fraction(
            fixture.occluded, p0, p1, up, radius, basis,
            options.line_clearance, samples=options.line_fixture_samples, seed=options.seed,
        )  # fmt: skip
    info.update({"open_fraction": np.round(open_frac, 4).tolist(), "tube_radius": radius})
    if not np.any(open_frac > 0):
        notes.append(
            f"the scanned fixture of line light {name!r} hides its tube everywhere: no shape prior"
        )
        return None, info, geometry
    return open_frac, info, geometry


def _point_open_shape(
    mesh, light, basis: InclinationBasis, options: InvertOptions, notes: list[str]
) -> tuple[np.ndarray | None, dict]:
    """The open fraction of a shaded bulb per inclination bin, and its info.

    ``(None, {})`` for a point light without a shade's evidence (or with the prior off);
    ``(None, {...})`` with a note when the scan closed the shade around the bulb.
    """
    from reroom.invert.point_fixture import point_inside_fraction, point_open_fraction

    if options.point_shape_prior <= 0 or light.evidence.get("height_from") != "pool edge":
        return None, {}
    pos = np.asarray(light.geometry["position"], float)
    reach = options.point_clearance
    # The shade's faces within reach, as for a tube (a segment of zero length), less the
    # bulb's own: all of whose vertices lie within 2 cm (the tube rule with r = 1 cm).
    caster = scan_fixture_caster(mesh.vertices, mesh.faces, pos, pos, 0.01, reach)
    if caster is None:
        return None, {}
    inside = point_inside_fraction(caster, pos, reach)
    if inside > MAX_INSIDE_FRACTION:
        notes.append(
            f"the scan closed the shade of point light {light.name!r} ({100 * inside:.0f} % of "
            "the rays from its bulb leave through back faces): no shape prior"
        )
        return None, {"fixture_inside_fraction": round(inside, 4)}
    open_frac = point_open_fraction(
        caster.occluded, pos, np.asarray(light.geometry["axis"], float), basis, reach,
        seed=options.seed,
    )  # fmt: skip
    if not np.any(open_frac > 0):
        notes.append(f"the scanned shade of point light {light.name!r} hides it everywhere")
        return None, {}
    return open_frac, {"open_fraction": np.round(open_frac, 4).tolist()}


def _frame_loader(who: str, why: str, notes: list[str]):
    """``load(frame)``: the frame's 8-bit image, or None with a note naming ``who``."""

    def load(frame):
        try:
            return frame.load_image()
        except (ReroomError, OSError, ValueError) as exc:
            notes.append(f"{who}: frame {frame.index} skipped{' ' + why if why else ''} ({exc})")
            return None

    return load


def _photo_color(
    scan: Path, name: str, points: np.ndarray, facing, caster: RayCaster, notes: list[str]
):
    """A light's colour from the photos (:func:`reroom.invert.emitter_color.emitter_color`)
    in the HDR mesh's units; None, with a note, where the photos do not give it."""
    from reroom.invert.emitter_color import emitter_color
    from reroom.invert.photos import frame_scale, read_frame_scales, scan_response
    from reroom.scan import load_scan

    try:
        sc = load_scan(scan, check_images=False)
        doc, scales = read_frame_scales(scan)
        lut = scan_response(doc, sc.meta, notes.append)
    except (ReroomError, OSError, ValueError) as exc:
        notes.append(f"light {name!r}: no colour from the photos ({exc})")
        return None

    load = _frame_loader(f"light {name!r}", "for its colour", notes)
    found = emitter_color(
        sc.frames, load, lambda i: frame_scale(scales, i), lut, caster, points, facing=facing
    )
    return _checked_photo_color(name, found, notes)


def _checked_photo_color(name: str, found, notes: list[str]):
    """``found`` if the solve may use it; None, with a note, when the photos gave no
    colour or one that varies more than ``MAX_PHOTO_COLOR_SPREAD`` between frames."""
    if found is None:
        notes.append(
            f"light {name!r}: the photos show too few unsaturated pixels at the edge of its "
            "clipped image for its colour (a light below saturation, or one no frame sees): "
            "its colour from the solve alone"
        )
    elif float(found.spread.max()) > MAX_PHOTO_COLOR_SPREAD:
        notes.append(
            f"light {name!r}: its colour from the photos ({np.round(found.color, 3).tolist()}) "
            f"varies by +-{100 * found.spread.max():.1f} % between frames (over "
            f"{100 * MAX_PHOTO_COLOR_SPREAD:.0f} %): not used, its colour from the solve alone"
        )
        return None
    return found


def _line_photo_color(scan: Path, mesh, name: str, geometry: dict, notes: list[str]):
    """A tube's colour from the photos, seen past its fixture (a fused scan's block)."""
    from reroom.invert.emitter_color import segment_points
    from reroom.invert.line_photos import caster_without_fixture

    p0, p1 = np.asarray(geometry["p0"], float), np.asarray(geometry["p1"], float)
    others = caster_without_fixture(mesh.vertices, mesh.faces, p0, p1)
    if others is None:
        notes.append(f"light {name!r}: no colour from the photos (the scan is its fixture)")
        return None
    up = np.asarray(geometry["d_perp"], float)
    mid = 0.5 * (p0 + p1)
    return _photo_color(
        scan, name, segment_points(p0, p1), lambda c: float((c - mid) @ up) < 0, others, notes
    )


def _area_photo_color(scan: Path, caster: RayCaster, name: str, g: dict, notes: list[str]):
    """A rectangular light's colour from the photos, seen from its emitting side."""
    from reroom.invert.emitter_color import rectangle_points

    try:
        pts = rectangle_points(g["centroid"], g["axis_long"], g["axis_short"], g["size"])
        centre, normal = np.asarray(g["centroid"], float), np.asarray(g["normal"], float)
    except (KeyError, TypeError, ValueError) as exc:
        notes.append(f"light {name!r}: no colour from the photos (its geometry: {exc!r})")
        return None
    return _photo_color(scan, name, pts, lambda c: float((c - centre) @ normal) > 0, caster, notes)


def _photo_trough(
    scan: Path,
    mesh,
    name: str,
    geometry: dict,
    options: InvertOptions,
    notes: list[str],
    caster: RayCaster | None = None,
) -> tuple[Any, dict, dict] | None:
    """A line light's tube and trough from the photos (None, with a note, when they fail).
    ``caster``: the whole scan's, if the caller has one (else one is built)."""
    from reroom.invert.line_photos import (
        caster_without_fixture,
        fixture_extent,
        observe_tube,
        trough_edges,
        trough_fixture,
        tube_extent,
    )
    from reroom.scan import load_scan

    p0, p1 = np.asarray(geometry["p0"], float), np.asarray(geometry["p1"], float)
    up = np.asarray(geometry["d_perp"], float)
    try:
        frames = load_scan(scan, check_images=False).frames
    except (ReroomError, OSError, ValueError) as exc:
        notes.append(f"line light {name!r}: the photos cannot be read for its fixture ({exc})")
        return None
    others = caster_without_fixture(mesh.vertices, mesh.faces, p0, p1)
    if others is None:
        notes.append(f"line light {name!r}: the scan holds nothing but its fixture")
        return None

    load = _frame_loader(f"line light {name!r}", "", notes)
    tube = observe_tube(frames, load, others, p0, p1, up)
    summary = tube.summary()
    if tube.residual_m is None or tube.radius is None:
        notes.append(
            f"line light {name!r}: too few clean views of its tube for its axis "
            f"({tube.stripe_samples} stripe samples)"
        )
        return None
    # The fused scan may hold only part of the tube bright: its ends from the photos.
    reach = 1.0
    dh = (tube.p1 - tube.p0) / np.linalg.norm(tube.p1 - tube.p0)
    clear = caster_without_fixture(
        mesh.vertices, mesh.faces, tube.p0 - reach * dh, tube.p1 + reach * dh
    )
    along = None
    lit = {s.frame for s in tube.sightings if s.bright}
    if clear is not None and lit:
        along = tube_extent(
            [f for f in frames if f.index in lit], load, clear,
            caster or RayCaster(mesh.vertices, mesh.faces), tube.p0, tube.p1, up, reach=reach,
        )  # fmt: skip
        tube = replace(tube, p0=along.p0, p1=along.p1)
        if any(along.moved_m):  # an end grew by min_move or more (a re-centring moves none)
            # The axis again over the whole tube: a tilt fitted on a part of it would be
            # carried out to the new ends.
            again_others = caster_without_fixture(mesh.vertices, mesh.faces, tube.p0, tube.p1)
            again = (
                observe_tube(frames, load, again_others, tube.p0, tube.p1, up)
                if again_others is not None
                else None
            )
            if again is not None and again.residual_m is not None and again.radius is not None:
                tube = again
                summary = {**tube.summary(), "first_fit": summary}
    radius = float(tube.radius)
    extent = fixture_extent(mesh.vertices, tube.p0, tube.p1, up, radius)
    if extent is None:
        notes.append(f"line light {name!r}: no scanned fixture around its tube for a trough")
        return None
    bottom, top = extent
    trough = trough_edges(tube, bottom, radius) if bottom > radius else None
    if trough is None:
        notes.append(
            f"line light {name!r}: the photos bound no trough around its tube "
            f"(cut-off {summary['cutoff_deg']}, scanned underside {bottom:.3f} m below the axis)"
        )
        return None
    top = max(top, radius + 0.01)
    caster = trough_fixture(tube.p0, tube.p1, up, trough.edges, trough.bottom, top)
    new = dict(geometry)
    new.update(
        {
            "p0": np.round(tube.p0, 6).tolist(),
            "p1": np.round(tube.p1, 6).tolist(),
            "radius": round(radius, 5),
            "axis_from": "photos",
        }
    )
    summary.update(
        {
            "trough_edges_m": [round(e, 4) for e in trough.edges],
            "trough_edges_from": trough.how,
            "trough_bottom_m": round(trough.bottom, 4),
            "trough_bottom_from": trough.bottom_from,
            "trough_top_m": round(top, 4),
            "detected_p0": geometry["p0"],
            "detected_p1": geometry["p1"],
            "detected_radius": geometry.get("radius"),
            **({"extent": along.summary()} if along is not None else {}),
        }
    )
    return caster, new, summary


def _window_photos(
    scan: Path, mesh, caster, openings: list, options: InvertOptions, notes: list[str]
) -> list | None:
    """The photos' view through each window, when an option uses it before the solve.

    None when none of ``window_photo_prior``, ``window_photo_bounds``,
    ``window_photo_shapes`` and ``render_window_photo_bounds`` (with a render window and
    the joint solver) asks for it, or
    (with a note) when the photos cannot be read back (e.g. no ``hdr/exposures.json``).
    """
    wanted = (
        options.window_photo_prior > 0
        or options.window_photo_bounds
        or options.window_photo_shapes
        or (
            options.render_window_photo_bounds
            and options.render_window_cells > 0
            and options.solve.method == "joint"
        )
    )
    if not openings or not wanted:
        return None
    from reroom.invert.window_env import observe_windows

    try:
        photos, stats = observe_windows(scan, mesh, openings, caster=caster)
    except (ReroomError, OSError, ValueError) as exc:
        notes.append(f"window photos: not used before the solve ({exc})")
        return None
    notes.extend(stats["notes"])
    return photos


def _window_view(options: InvertOptions, basis, opening):
    """The :class:`~reroom.invert.window_env.WindowView` of ``window_view_hdri`` for one
    window; :class:`~reroom.errors.ScanError` naming the file if it cannot be read."""
    from reroom.invert.window_env import WindowView

    return WindowView.load(
        str(options.window_view_hdri),
        basis,
        opening.normal,
        options.window_view_rotation_deg,
        seed=options.seed,
    )


def _window_photo_priors(
    photos: list | None, openings: list, basis, options: InvertOptions
) -> list[tuple[np.ndarray | None, np.ndarray | None, dict]]:
    """Per window: the photos' clean view of its cells as a prior ``(values, weights, info)``.

    ``(None, None, {})`` for each window when ``window_photo_prior`` is 0 or there are no
    photos (:func:`_window_photos`).
    """
    none: list[tuple[np.ndarray | None, np.ndarray | None, dict]] = [
        (None, None, {}) for _ in openings
    ]
    if options.window_photo_prior <= 0 or photos is None:
        return none
    from reroom.invert.window_env import cell_means

    out = []
    for ph in photos:
        means, fraction = cell_means(ph, basis)
        weight = options.window_photo_prior * fraction
        info = {
            "photo_prior": {
                "weight": options.window_photo_prior,
                "cells": int(np.count_nonzero(weight > 0)),
                "mean_fraction_seen": round(float(fraction[weight > 0].mean()), 4)
                if np.any(weight > 0)
                else 0.0,
            }
        }
        out.append(
            (np.nan_to_num(means), weight, info) if np.any(weight > 0) else (None, None, info)
        )
    return out


def _light_outline(points: np.ndarray, normal: Any) -> Any:
    """An area light's outline: the hull of its vertices on its emitting face's plane
    (a recessed panel's fused rim left out, :func:`on_emitting_plane`)."""
    return area_region(points[on_emitting_plane(points, normal)], normal)


def _outline_geometry(region, vertex_area: float) -> dict[str, Any]:
    """An area light's geometry entries for its outline (:mod:`reroom.invert.area_region`):
    its corners in 3-D, its projected area (what its power is counted over) and the
    area of its vertices' shares it replaces."""
    corners = region.origin + region.polygon[:, :1] * region.u + region.polygon[:, 1:] * region.v
    return {
        "outline": np.round(corners, 6).tolist(),
        "area": round(region.area, 6),
        "area_of_vertices": round(vertex_area, 6),
    }


def emitter_classes(
    light_list: list, vertex_light_id: np.ndarray, points: np.ndarray, fixture_margin: float
) -> tuple[list, list, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`emitter_surfaces` with the glowing fittings of line and point lights folded in.

    The vertices within ``fixture_margin`` of a line or point light are modelled by that
    light: they must not also count as indirect light, so they join the emitters' class as
    an extra "area light" (index ``len(areas)``) whose transfer column is dropped.

    Returns ``(areas, windows, area_of, window_of, on_light)``; ``on_light`` marks every
    vertex of an emitter's surface or a fitting.
    """
    nv = len(points)
    areas, wins, area_of, window_of = emitter_surfaces(light_list, vertex_light_id, nv)
    fixture = _fixture_vertices(points, light_list, fixture_margin)
    if fixture.any():
        area_of[fixture & (area_of < 0) & (window_of < 0)] = len(areas)
    on_light = (np.asarray(vertex_light_id) >= 0) | fixture
    return areas, wins, area_of, window_of, on_light


def run_invert(
    scan_dir: str | Path,
    out_dir: str | Path | None = None,
    options: InvertOptions | None = None,
    progress: Callable[[str, int, int], None] | None = None,
    *,
    radiance_override: np.ndarray | None = None,
) -> InvertResult:
    """Solve the lights and materials of a scan and write ``SCAN/invert/``.

    Parameters
    ----------
    scan_dir : path
        The scan folder, with ``hdr/``, ``layout/`` and ``lights/`` from earlier stages.
    out_dir : path, optional
        Output folder (default ``SCAN/invert``).
    options : InvertOptions, optional
    progress : callable, optional
        ``progress(stage, done, total)``.
    radiance_override : ndarray, shape (V, 3), optional
        Radiance to use instead of the HDR mesh's, every finite row counted as
        observed (NaN rows: unobserved) (for :func:`reroom.invert.evaluate.run_invert_true_radiance` only).

    Returns
    -------
    InvertResult

    Raises
    ------
    ScanError
        A required input file is missing or inconsistent with the mesh.
    """
    from reroom.invert.export import write_outputs

    options = options or InvertOptions()
    if options.window_photo_bounds and options.solve.method == "alternating":
        raise ValueError("window_photo_bounds needs the joint solver: set solve.method to 'joint'")
    if not np.isfinite(options.photo_color) or options.photo_color < 0:
        raise ValueError(f"photo_color must be >= 0, got {options.photo_color}")
    if options.photo_color > 0 and options.solve.method == "alternating":
        raise ValueError("photo_color needs the joint solver: set solve.method to 'joint'")
    if options.albedo_footprint_rings < 0:
        raise ValueError(
            f"albedo_footprint_rings must be >= 0, got {options.albedo_footprint_rings}"
        )
    if options.unobserved_fill not in UNOBSERVED_FILLS:
        raise ValueError(
            f"unobserved_fill must be one of {UNOBSERVED_FILLS}, got {options.unobserved_fill!r}"
        )
    if not 0.0 < options.fill_albedo <= 1.0:
        raise ValueError(f"fill_albedo must be in (0, 1], got {options.fill_albedo}")
    if options.point_splits < 0:
        raise ValueError(f"point_splits must be >= 0, got {options.point_splits}")
    _photo_clusters(options)  # a misspelt cluster fails here, not after the solve
    if options.point_photo_samples < 100:
        raise ValueError(f"point_photo_samples must be >= 100, got {options.point_photo_samples}")
    if not 0 <= options.surroundings_min_escape <= 1:
        raise ValueError(
            f"surroundings_min_escape must be in [0, 1], got {options.surroundings_min_escape}"
        )
    if options.window_view_height < 0:
        raise ValueError(f"window_view_height must be >= 0, got {options.window_view_height}")
    if options.texture_iterations < 1:
        raise ValueError(f"texture_iterations must be >= 1, got {options.texture_iterations}")
    for name in ("", "_wall", "_floor", "_ceiling"):
        value = getattr(options, f"texture_smooth{name}")
        if not (np.isfinite(value) and value >= 0):
            raise ValueError(f"texture_smooth{name} must be >= 0, got {value}")
    if not (np.isfinite(options.window_smooth) and options.window_smooth >= 0):
        raise ValueError(f"window_smooth must be a finite number >= 0, got {options.window_smooth}")
    if options.render_window_cells < 0:
        raise ValueError(f"render_window_cells must be >= 0, got {options.render_window_cells}")
    if not (np.isfinite(options.render_window_smooth) and options.render_window_smooth >= 0):
        raise ValueError(
            f"render_window_smooth must be a finite number >= 0, got {options.render_window_smooth}"
        )
    check_normal_radius(options.normal_radius)
    scan = Path(scan_dir)
    out = Path(out_dir) if out_dir is not None else scan / "invert"
    notes: list[str] = []
    timings: dict[str, float] = {}
    t0 = time.perf_counter()

    hdr_path = _require(scan / "hdr" / "hdr_mesh.ply", "run `reroom hdr SCAN` first")
    labels_path = _require(scan / "layout" / "layout_labels.ply", "run `reroom layout SCAN` first")
    mesh = read_ply(hdr_path)
    attrs = mesh.vertex_attributes
    if "radiance" not in attrs or "observed" not in attrs:
        raise ScanError(hdr_path, "has no radiance_r/g/b or observed vertex properties")
    radiance = np.asarray(attrs["radiance"], dtype=np.float64)
    observed = np.asarray(attrs["observed"]).astype(bool) & np.isfinite(radiance).all(axis=1)
    nv = len(mesh.vertices)
    if radiance_override is not None:
        radiance = np.asarray(radiance_override, dtype=np.float64).reshape(nv, 3)
        observed = np.isfinite(radiance).all(axis=1)
        radiance = np.where(observed[:, None], radiance, 0.0)
        notes.append("EVALUATION ONLY: solved with the ground truth's radiance")
    labels_mesh = read_ply(labels_path)
    if len(labels_mesh.vertices) != nv or "label" not in labels_mesh.vertex_attributes:
        raise ScanError(labels_path, f"must have a label per vertex of {hdr_path.name} ({nv})")
    labels = np.asarray(labels_mesh.vertex_attributes["label"]).astype(int)
    lightset = _load_lights(scan, nv, notes)
    timings["load"] = time.perf_counter() - t0

    # ------------------------------------------------------------------ lights
    light_list = lightset.lights if lightset is not None else []
    ids = (
        lightset.vertex_light_id
        if lightset is not None and len(lightset.vertex_light_id)
        else np.full(nv, -1, np.int32)
    )
    pts = np.asarray(mesh.vertices, dtype=np.float64)
    areas, wins, area_of, window_of, on_light = emitter_classes(
        light_list, ids, pts, options.fixture_margin
    )
    openings = [
        WindowOpening(
            w.name,
            np.asarray(w.geometry["centre"], float),
            np.asarray(w.geometry["half_u"], float),
            np.asarray(w.geometry["half_v"], float),
            np.asarray(w.geometry["normal"], float),
        )
        for w in wins
    ]
    normals, normal_info = receiver_normals(
        mesh, options.normal_radius, labels == CLUSTER_LABELS["floor"]
    )
    if note := auto_note(options.normal_radius, normal_info):
        notes.append(note)
    has_normal = np.linalg.norm(normals, axis=1) > 0
    receivers = np.flatnonzero(observed & ~on_light & has_normal)
    if len(receivers) == 0:
        raise ScanError(hdr_path, "has no observed vertex to solve for")

    # ------------------------------------------------------------------ transfer
    t = time.perf_counter()
    caster = RayCaster(mesh)
    basis = CubemapBasis(options.cubemap_n)
    if options.receiver_voxel > 0:
        sub = voxel_receivers(pts, normals, receivers, options.receiver_voxel)
    else:
        sub = receivers
    seen_radiance, seen = radiance, observed
    if options.unobserved_fill == "bounce":
        t_fill = time.perf_counter()
        seen_radiance, reached = bounce_fill(
            caster, mesh, radiance, observed, normals, area_of, window_of,
            excluded=on_light, albedo=options.fill_albedo, seed=options.seed + 7,
        )  # fmt: skip
        seen = observed | reached
        timings["unobserved_fill"] = time.perf_counter() - t_fill
        if reached.any():
            notes.append(
                f"{int(reached.sum())} vertices no photo saw lit by one bounce of the observed "
                f"light (reflectance {options.fill_albedo:g}) for the indirect light"
            )
    # Each area light's outline on its plane: the surface it emits from, in every transfer.
    regions = [
        _light_outline(pts[area_of == k], light.geometry.get("normal", [0.0, 0.0, -1.0]))
        if options.area_outline and np.any(area_of == k)
        else None
        for k, light in enumerate(areas)
    ]
    hemi = hemisphere_transfer(
        caster,
        mesh,
        sub,
        normals,
        seen_radiance,
        seen,
        area_of,
        openings,
        basis,
        rays_per_vertex=options.rays_per_receiver,
        seed=options.seed,
        progress=None if progress is None else (lambda d, n: progress("invert transfer", d, n)),
        window_of_vertex=window_of,
        inset=options.receiver_inset,
        area_regions=regions,
    )
    if len(sub) != len(receivers):
        hemi = spread_transfer(hemi, pts, normals, receivers)
    surroundings = None
    if options.surroundings:
        surroundings = unseen_surroundings(
            caster, mesh, openings, hemi, min_escape=options.surroundings_min_escape,
            seed=options.seed + 11,
        )  # fmt: skip
        if surroundings["radiance"] is not None:
            notes.append(
                f"{surroundings['escape_fraction']:.1%} of the receivers' hemisphere leaves the "
                "mesh through holes: rendered as surroundings of the radiance eq. 5.9 gave it "
                f"({', '.join(f'{x:.3g}' for x in surroundings['radiance'])})"
            )
    timings["hemisphere_transfer"] = time.perf_counter() - t - timings.get("unobserved_fill", 0.0)

    t = time.perf_counter()
    blocks: list[LightBlock] = []
    columns: list[np.ndarray] = []
    info: list[dict] = []
    incl = InclinationBasis(options.bins)
    chain = _chain(options.bins)
    line_basis = LineBasis(options.bins, options.line_phi_bins, options.line_phi_fold)
    line_adj, line_adj_w = line_basis.adjacency(options.line_phi_smooth)
    n_recv = normals[receivers] / np.linalg.norm(normals[receivers], axis=1, keepdims=True)
    p_recv = inset_points(mesh, receivers, n_recv, options.receiver_inset)
    for k, light in enumerate(areas):
        color = (
            _area_photo_color(scan, caster, light.name, light.geometry, notes)
            if options.photo_color > 0 and radiance_override is None
            else None
        )
        # With a measured colour the light is colour x scalar, so the prior can hold it.
        blocks.append(
            LightBlock(light.name, "area", 1)
            if color is None
            else LightBlock(
                light.name,
                "area",
                1,
                True,
                color_prior=color.color,
                color_prior_weight=options.photo_color,
            )  # fmt: skip
        )
        geometry = dict(light.geometry)
        region = regions[k]
        if options.area_outline and np.any(area_of == k):
            if region is None:
                notes.append(
                    f"area light {light.name!r}: its vertices span no outline on its plane: "
                    "it ends half-way into its rim triangles"
                )
            else:
                geometry.update(_outline_geometry(region, float(geometry.get("area", 0.0))))
        # Integrated over the light's surface, not counted from the hemisphere rays:
        # those are unbiased but far too noisy for a small light (reroom.invert.area).
        f_area = area_light_transfer(
            caster,
            mesh,
            area_of == k,
            p_recv,
            n_recv,
            options.area_samples,
            seed=options.seed + k,
            region=region,
        )
        columns.append(f_area[:, None])
        info.append(
            {
                "name": light.name,
                "type": "area",
                "geometry": geometry,
                **({} if color is None else {"color_from_photos": color.summary()}),
            }
        )
    photos = _window_photos(scan, mesh, caster, openings, options, notes)
    priors = _window_photo_priors(photos, openings, basis, options)
    for k, light in enumerate(wins):
        prior, prior_weight, prior_info = priors[k]
        direction_weight = None
        if options.window_view_hdri is not None and isinstance(basis, CubemapBasis):
            view = _window_view(options, basis, openings[k])
            prior_info = {
                **prior_info,
                "view": {
                    "hdri": str(options.window_view_hdri),
                    "rotation_deg": options.window_view_rotation_deg,
                },
            }
            direction_weight = view.weight(basis)
        elif options.window_photo_shapes and photos is not None and isinstance(basis, CubemapBasis):
            from reroom.invert.window_env import cell_shapes, fill_gaps, latlong_lookup

            shape, shape_info = cell_shapes(fill_gaps(photos[k]), basis)
            prior_info = {**prior_info, "photo_shapes": shape_info}
            direction_weight = latlong_lookup(shape)
        lower = None
        if options.window_photo_bounds and photos is not None and isinstance(basis, CubemapBasis):
            from reroom.invert.window_env import cell_lower_bounds

            lower = cell_lower_bounds(photos[k], basis)
            prior_info = {
                **prior_info,
                "photo_bounds": {"cells": int(np.count_nonzero(lower.max(axis=1) > 0))},
            }
        pairs = basis.adjacency()
        blocks.append(
            LightBlock(
                light.name,
                "window",
                basis.size,
                False,
                pairs,
                adjacency_weights=np.full(len(pairs), float(options.window_smooth)),
                prior=prior,
                prior_weight=prior_weight,
                lower=lower,
            )
        )
        pane = (window_of[np.asarray(mesh.faces)] == k).any(axis=1)
        if options.window_samples > 0:
            # Integrated over the opening, as the area lights (reroom.invert.portal); the
            # hemisphere rays still decide which directions carry indirect light.
            columns.append(
                window_portal_transfer(
                    caster,
                    openings[k],
                    basis,
                    p_recv,
                    n_recv,
                    options.window_samples,
                    seed=options.seed + 101 + k,
                    pane_faces=pane,
                    direction_weight=direction_weight,
                )
            )
        else:
            columns.append(hemi.distant[:, k, :])
        info.append(
            {"name": light.name, "type": "window", "geometry": light.geometry, **prior_info}
        )
        if options.window_sun and isinstance(basis, CubemapBasis):
            t_sun = time.perf_counter()
            # Searched on the wall, floor and ceiling receivers, the ones the solve fits: a
            # patch on furniture alone could not be solved, and a bright object that
            # happens to line up with the opening is not a sun (on the real slambook2
            # scan a lamp-lit table top did, at t 23).
            on_shell = np.isin(labels[receivers], list(CLUSTER_LABELS.values()))
            _add_window_sun(
                caster, openings[k], light.name, pane, p_recv, n_recv, radiance[receivers],
                observed[receivers] & on_shell, options, blocks, columns, info, notes,
            )  # fmt: skip
            timings["window_sun"] = timings.get("window_sun", 0.0) + time.perf_counter() - t_sun
    for light in light_list:
        g = light.geometry
        if light.type == "point":
            shape, open_info = _point_open_shape(mesh, light, incl, options, notes)
            f = _point_transfer(caster, p_recv, n_recv, g["position"], g["axis"], incl, options)
            blocks.append(
                LightBlock(
                    light.name,
                    "point",
                    incl.size,
                    True,
                    chain,
                    shape=shape,
                    shape_weight=options.point_shape_prior if shape is not None else 0.0,
                )
            )
            info.append(
                {
                    "name": light.name,
                    "type": "point",
                    "geometry": g,
                    "shadow_clearance": options.point_clearance,
                    **open_info,
                }
            )
        elif light.type == "line":
            shape, open_info, g = _line_open_shape(
                scan, mesh, light.name, g, line_basis, options, notes, caster
            )
            light.geometry = g
            color = (
                _line_photo_color(scan, mesh, light.name, g, notes)
                if options.photo_color > 0 and radiance_override is None
                else None
            )
            if color is not None:
                open_info["color_from_photos"] = color.summary()
            f = line_light_transfer(
                caster,
                p_recv,
                n_recv,
                np.asarray(g["p0"], float),
                np.asarray(g["p1"], float),
                np.asarray(g["d_perp"], float),
                line_basis,
                segments=options.line_segments,
                clearance=options.line_clearance,
            )
            blocks.append(
                LightBlock(
                    light.name,
                    "line",
                    line_basis.size,
                    True,
                    line_adj,
                    line_adj_w,
                    shape=shape,
                    shape_weight=options.line_shape_prior if shape is not None else 0.0,
                    color_prior=None if color is None else color.color,
                    color_prior_weight=0.0 if color is None else options.photo_color,
                )
            )
            info.append(
                {
                    "name": light.name,
                    "type": "line",
                    "geometry": g,
                    "shadow_clearance": options.line_clearance,
                    **open_info,
                    "basis": {
                        "theta_bins": line_basis.theta_bins,
                        "phi_bins": line_basis.phi_bins,
                        "phi_fold": line_basis.fold,
                    },
                }
            )
        else:
            continue
        columns.append(f)
    transfer = (
        sp.csr_matrix(np.concatenate(columns, axis=1))
        if columns
        else sp.csr_matrix((len(receivers), 0))
    )
    timings["direct_transfer"] = time.perf_counter() - t

    # ------------------------------------------------------------------ solve
    t = time.perf_counter()
    indirect = hemi.indirect_rescaled()
    names = list(CLUSTER_LABELS)
    cluster_of_label = {v: i for i, v in enumerate(CLUSTER_LABELS.values())}
    rec_labels = labels[receivers]
    in_cluster = np.isin(rec_labels, list(CLUSTER_LABELS.values()))
    rows = np.flatnonzero(in_cluster)
    near = np.zeros(len(receivers), dtype=bool)
    if options.near_distance > 0 and len(rows):
        t_near = time.perf_counter()
        blocked = near_occlusion(
            caster, mesh, receivers[rows], n_recv[rows], options.near_distance, seed=options.seed
        )
        near[rows] = blocked > options.near_max_fraction
        if near.any():
            notes.append(
                f"{int(near.sum())} of {len(rows)} clustered vertices have other geometry "
                f"within {options.near_distance:g} m (seams, contact gaps): left out of the "
                "lighting solve"
            )
        rows = rows[~near[rows]]
        timings["near_filter"] = time.perf_counter() - t_near
    cluster = np.array([cluster_of_label[x] for x in rec_labels[rows]], dtype=int)
    problem = InverseProblem(
        radiance=radiance[receivers[rows]],
        indirect=indirect[rows],
        cluster=cluster,
        cluster_names=names,
        transfer=transfer[rows],
        lights=blocks,
    )
    result = solve_lighting(problem, options.solve, progress)
    timings["solve"] = time.perf_counter() - t
    if options.refine_points and any(b.kind == "point" for b in blocks):
        t = time.perf_counter()
        mounted = _mounted_surfaces(light_list, notes)
        measured = {x.name for x in light_list if x.evidence.get("height_from") == "pool edge"}
        moved = _refine_point_lights(
            caster, pts, p_recv, n_recv, rows, blocks, columns, info, problem, result,
            incl, options, mounted, measured,
        )  # fmt: skip
        if moved:
            transfer = sp.csr_matrix(np.concatenate(columns, axis=1))
            trial = InverseProblem(
                radiance=problem.radiance,
                indirect=problem.indirect,
                cluster=problem.cluster,
                cluster_names=names,
                transfer=transfer[rows],
                lights=blocks,
            )
            second = solve_lighting(trial, options.solve, progress)
            if second.objective < (1.0 - options.refine_min_gain) * result.objective:
                notes.append(
                    "point lights moved to fit the solved lighting: "
                    + ", ".join(f"{info[k]['name']} {d:.2f} m" for k, d, _, _ in moved)
                    + f" (objective {result.objective:.4g} -> {second.objective:.4g})"
                )
                problem, result = trial, second
            else:
                for k, _, old_col, old_geom in moved:
                    columns[k], info[k]["geometry"] = old_col, old_geom
                    info[k].pop("refined_from", None)
                transfer = sp.csr_matrix(np.concatenate(columns, axis=1))
                notes.append(
                    "point-light refinement did not lower the objective by "
                    f"{options.refine_min_gain:.0%} ({result.objective:.4g} -> "
                    f"{second.objective:.4g}): positions kept"
                )
        timings["refine_points"] = time.perf_counter() - t
    if any(b.kind == "sun" for b in blocks):
        result = _sun_from_its_patch(problem, result, options, notes, progress)
    if options.point_splits > 0 and any(b.kind == "point" for b in blocks):
        t = time.perf_counter()
        for _ in range(options.point_splits):
            _split_point_bins(
                caster, p_recv, n_recv, rows, blocks, columns, info, problem, result, options
            )  # fmt: skip
            transfer = sp.csr_matrix(np.concatenate(columns, axis=1))
            problem = replace(problem, transfer=transfer[rows], lights=blocks)
        timings["point_splits"] = time.perf_counter() - t
    if options.point_photo_profile and any(b.kind == "point" for b in blocks):
        t = time.perf_counter()
        _photo_point_profiles(
            scan, mesh, caster, labels, receivers, rows, indirect, transfer, blocks, info,
            result, options, notes, evaluation_radiance=radiance_override is not None,
        )  # fmt: skip
        timings["point_photo_profile"] = time.perf_counter() - t
    # How much data each basis element had: the summed transfer over the clustered
    # receivers (green). Point and line bins that almost no receiver sees are barely
    # constrained by the solve; export fills them from their well-seen neighbours.
    support = np.asarray(abs(transfer[rows]).sum(axis=0)).ravel()
    start = 0
    for block, entry in zip(blocks, info, strict=True):
        entry["support"] = support[start : start + block.size].tolist()
        start += block.size

    # ------------------------------------------------------------------ render windows
    render_windows, render = _render_windows(
        caster, mesh, blocks, wins, openings, window_of, basis, transfer, rows, problem,
        result, p_recv, n_recv, options, notes, timings, photos,
    )  # fmt: skip
    r_transfer, r_blocks, r_result = render

    # ------------------------------------------------------------------ per vertex
    t = time.perf_counter()
    footprint = None
    if options.albedo_footprint_rings > 0:
        footprint = footprint_operator(
            np.asarray(mesh.faces, np.int64),
            receivers,
            nv,
            np.asarray(mesh.vertices, np.float64),
            options.albedo_footprint_rings,
        )
    rec_albedo, nonphys = per_vertex_albedo(
        radiance[receivers], indirect, r_transfer, r_blocks, r_result, footprint=footprint
    )
    albedo = np.full((nv, 3), np.nan)
    albedo[receivers] = rec_albedo
    flags = {
        "in_cluster": np.zeros(nv, bool),
        "solved_per_vertex": np.zeros(nv, bool),
        "nonphysical": np.zeros(nv, bool),
        "unobserved": ~observed,
        "light": on_light,
        "near_geometry": np.zeros(nv, bool),
    }
    flags["near_geometry"][receivers[near]] = True
    used_rows = rows[result.cluster_used[cluster]]
    flags["in_cluster"][receivers[used_rows]] = True
    flags["solved_per_vertex"][receivers] = np.isfinite(rec_albedo).all(axis=1)
    flags["nonphysical"][receivers] = nonphys
    timings["per_vertex"] = time.perf_counter() - t
    notes.extend(result.warnings)
    if nonphys.any():
        notes.append(
            f"{int(nonphys.sum())} vertices ({nonphys.mean():.1%} of the observed) have a "
            "non-physical albedo > 1 (flagged, not clipped)"
        )
    textures = None
    if options.textures:
        t = time.perf_counter()
        textures = _surface_textures(
            scan, mesh, labels, receivers, indirect, r_transfer, r_blocks, r_result, albedo,
            caster, options, notes, radiance_override is not None, progress,
            point_direct=(
                _point_direct(caster, r_blocks, info, r_result, options)
                if options.texture_point_direct
                else None
            ),
            p_recv=p_recv, n_recv=n_recv,
        )  # fmt: skip
        timings["textures"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - t0
    res = InvertResult(
        solve=result,
        lights=blocks,
        light_info=info,
        cluster_names=names,
        albedo=albedo,
        flags=flags,
        cubemap_n=options.cubemap_n,
        bins=options.bins,
        timings=timings,
        warnings=notes,
        out_dir=out,
        problem=problem,
        problem_vertices=receivers[rows],
        textures=textures,
        render_windows=render_windows,
        surroundings=surroundings,
    )
    meta = {
        "scan": str(scan),
        "inputs": {
            "hdr_mesh": str(hdr_path),
            "labels": str(labels_path),
            "lights": str(scan / "lights" / "lights.json"),
        },
        "mesh_vertices": nv,
        "observed": int(observed.sum()),
        "receivers": int(len(receivers)),
        "hemisphere_receivers": int(len(sub)),
        "normals": normal_info,
        "clustered": int(len(rows)),
        "options": _jsonable_options(options),
    }
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        write_outputs(res, mesh, out, meta, pictures=options.pictures)
    return res


def _render_windows(
    caster,
    mesh,
    blocks,
    wins,
    openings,
    window_of,
    basis,
    transfer,
    rows,
    problem,
    result,
    p_recv,
    n_recv,
    options: InvertOptions,
    notes: list[str],
    timings: dict[str, float],
    photos: list | None = None,
):
    """Each window refitted on ``options.render_window_cells`` cells for the renders
    (:mod:`reroom.invert.render_window`); returns them by name, and the render model
    ``(transfer, blocks, result)`` (the solve's own when there is nothing to refit)."""
    from reroom.invert.render_window import refit_window, render_model

    n = int(options.render_window_cells)
    idle = {}, (transfer, blocks, result)
    if n == 0 or n == options.cubemap_n or not any(b.kind == "window" for b in blocks):
        return idle
    why = None
    if not isinstance(basis, CubemapBasis):
        why = "the windows are not solved on a cube map"
    elif options.window_samples <= 0:
        why = "window_samples is 0 (the windows' transfer comes from the hemisphere rays)"
    elif options.window_photo_shapes:
        why = "the windows' transfer is weighted by the photos' pattern"
    if why is not None:
        notes.append(f"render windows: not refitted at {n}x{n} cells ({why})")
        return idle
    t = time.perf_counter()
    fine_basis = CubemapBasis(n)
    faces = np.asarray(mesh.faces)
    index = {w.name: j for j, w in enumerate(wins)}
    fine = {}
    for k, block in enumerate(blocks):
        if block.kind != "window":
            continue
        j = index[block.name]
        # A captured view of the window spreads each fine cell's light as the view does,
        # as it spreads the solve's cells.
        weight = None
        if options.window_view_hdri is not None:
            weight = _window_view(options, fine_basis, openings[j]).weight(fine_basis)
        columns = window_portal_transfer(
            caster,
            openings[j],
            fine_basis,
            p_recv,
            n_recv,
            options.window_samples,
            seed=options.seed + 101 + j,
            pane_faces=(window_of[faces] == j).any(axis=1),
            direction_weight=weight,
        )
        lower = None
        if options.render_window_photo_bounds and options.solve.method != "joint":
            # Bounds are the joint solver's (the photos were not read for them).
            notes.append(
                f"render window {block.name}: the photos' bounds not used (they need the "
                "joint solver)"
            )
        elif options.render_window_photo_bounds and photos is not None:
            from reroom.invert.window_env import cell_lower_bounds

            lower = cell_lower_bounds(photos[j], fine_basis)
        window = refit_window(
            problem, result, blocks, k, columns[rows], fine_basis, basis,
            options.render_window_smooth, options.solve, lower=lower,
        )  # fmt: skip
        fine[block.name] = (window, columns)
        notes.append(
            f"render window {block.name}: refitted alone at {n}x{n} cells a face, the other "
            f"lights held (objective {window.objective_coarse:.4g} at the {options.cubemap_n}"
            f"x{options.cubemap_n} cells -> {window.objective_fine:.4g}); its map, the "
            "textures and the per-vertex albedos use it"
        )
    timings["render_windows"] = time.perf_counter() - t
    return {name: w for name, (w, _) in fine.items()}, render_model(transfer, blocks, result, fine)


def _surface_textures(
    scan: Path,
    mesh,
    labels: np.ndarray,
    receivers: np.ndarray,
    indirect: np.ndarray,
    transfer,
    blocks: list[LightBlock],
    result,
    albedo: np.ndarray,
    caster,
    options: InvertOptions,
    notes: list[str],
    evaluation_radiance: bool,
    progress,
    point_direct=None,
    p_recv: np.ndarray | None = None,
    n_recv: np.ndarray | None = None,
):
    """The photo textures of the floor, ceiling and walls (None, with a note, when the
    scan lacks what they need).

    ``point_direct(points, normals)`` (:func:`_point_direct`), with the receivers' points
    and normals, is the point lights' direct light that the textures evaluate at each
    sample instead of interpolating it between vertices."""
    from reroom.invert.solve import model_irradiance
    from reroom.invert.textures import TEXTURED_LABELS, photo_textures
    from reroom.io.jsonfile import read_json

    if evaluation_radiance:
        notes.append("textures: not made (solved with another radiance than the photos')")
        return None
    layout_path = scan / "layout" / "layout.json"
    if not layout_path.is_file():
        notes.append(f"textures: not made ({layout_path} is missing)")
        return None
    rotation = np.asarray(
        read_json(layout_path, "run `reroom layout SCAN` first").get("rotation", np.eye(3)), float
    )
    irradiance = np.full((len(mesh.vertices), 3), np.nan)
    irradiance[receivers] = model_irradiance(indirect, transfer, blocks, result)
    sharp = None
    if point_direct is not None:
        sharp = np.zeros_like(irradiance)
        sharp[receivers] = point_direct(p_recv, n_recv)
    try:
        textures, stats = photo_textures(
            scan,
            mesh,
            labels,
            rotation,
            irradiance,
            albedo,
            texel=options.texel,
            deconvolve=options.texture_solve,
            deconvolve_smooth={
                label: options.texture_smooth * getattr(options, f"texture_smooth_{label}")
                for label in TEXTURED_LABELS
            },
            deconvolve_iterations=options.texture_iterations,
            sharp_irradiance=None if sharp is None else point_direct,
            sharp_at_vertices=sharp,
            caster=caster,
            progress=None if progress is None else (lambda d, n: progress("invert textures", d, n)),
        )
    except (ReroomError, OSError, ValueError) as exc:
        notes.append(f"textures: not made ({exc})")
        return None
    notes.extend(stats["notes"])
    return textures, stats


def _add_window_sun(
    caster, opening, window_name, pane, p_recv, n_recv, radiance, observed, options,
    blocks, columns, info, notes,
) -> None:  # fmt: skip
    """Look for a sun through one window; if found, add it as a light of its own.

    (:mod:`reroom.invert.sun`.) The sun is a chromatic light of one element, its
    irradiance at normal incidence, named ``<window>_sun``; ``scene.json`` stores it
    inside its window's entry.
    """
    from reroom.invert.sun import find_sun, sun_transfer

    obs = np.flatnonzero(observed)
    est = find_sun(
        caster, opening, p_recv[obs], n_recv[obs], radiance[obs], pane_faces=pane,
        seed=options.seed,
    )  # fmt: skip
    if est is None:
        return
    name = f"{window_name}_sun"
    blocks.append(LightBlock(name, "sun", 1, False))
    footprint = options.window_sun_footprint
    if footprint is None:
        from scipy.spatial import cKDTree

        pts = p_recv[obs]
        footprint = 0.5 * float(np.median(cKDTree(pts).query(pts, k=2)[0][:, 1]))
    columns.append(
        sun_transfer(
            caster, opening, est.direction, p_recv, n_recv, pane_faces=pane, footprint=footprint
        )[:, None]
    )
    info.append(
        {
            "name": name,
            "type": "sun",
            "window": window_name,
            "geometry": {"direction": [float(x) for x in est.direction], "window": window_name},
            "detection": est.as_dict(),
        }
    )
    elevation = float(np.degrees(np.arcsin(np.clip(est.direction[2], -1.0, 1.0))))
    notes.append(
        f"window {window_name}: a sun found along {np.round(est.direction, 3).tolist()} "
        f"(elevation {elevation:.1f} deg; {est.lit} receivers lit, {est.contrast:.1f}x "
        f"brighter than around them, t {est.score:.1f}): solved as its own light"
    )


def _sun_from_its_patch(problem, result, options, notes: list[str], progress=None):
    """The solve again, each sun's irradiance taken from the receivers it lights fully.

    The weights of eq. 5.8 trust the receivers whose light is mostly indirect: a sunlit
    receiver, many times brighter than its indirect light, weighs 0.05-0.15, the unlit
    ones around the patch 1. The solve so takes the sun's level from the patch's edge,
    where a vertex's radiance (a mean over the pixels around it) is part lit and the
    model's transfer is all or nothing, and it came out a third low on the sunny
    `furnished` scan. Here the level is the median, over the receivers the sun lights at
    least half as much as most of its patch, of what the rest of the solved model leaves
    there: ``(pi Lbar / rho - E_ind - others) / F_sun``, per channel. The other lights and
    the albedos are then solved again with the suns fixed at that level (their light
    moved into the fixed term, as ``E_ind``), so that the window's cells do not keep the
    share of the patch's light they had taken. Returns the new result (the suns'
    intensities put back in), or ``result`` when no sun lights enough receivers fully.
    """
    import scipy.sparse as sp

    min_receivers = 20
    transfer = sp.csr_matrix(problem.transfer)
    offsets = np.concatenate([[0], np.cumsum([b.size for b in problem.lights])]).astype(int)
    intens = result.intensity_vector(problem.lights)
    rho = result.albedo[problem.cluster]
    ok = np.isfinite(rho).all(axis=1) & (rho > 0).all(axis=1)
    model = transfer @ intens
    levels: dict[int, np.ndarray] = {}
    for k, block in enumerate(problem.lights):
        if block.kind != "sun":
            continue
        f = np.asarray(transfer[:, offsets[k]].todense()).ravel()
        lit = ok & (f > 0)
        if lit.sum() < min_receivers:
            continue
        full = lit & (f >= 0.5 * np.percentile(f[lit], 90))
        if full.sum() < min_receivers:
            continue
        own = np.outer(f, intens[offsets[k]])
        left = np.pi * problem.radiance / np.where(ok[:, None], rho, 1.0) - problem.indirect
        left = left - (model - own)
        level = np.maximum(np.median(left[full] / f[full, None], axis=0), 0.0)
        levels[k] = level
        solved = np.asarray(result.intensities[block.name], float)[0]
        notes.append(
            f"{block.name}: irradiance {np.round(level, 3).tolist()} from the {int(full.sum())} "
            f"receivers it lights fully (the solve, which weighs them little: "
            f"{np.round(solved, 3).tolist()}); the rest solved again with it fixed"
        )
    if not levels:
        return result
    fixed = problem.indirect.copy()
    for k, level in levels.items():
        fixed += np.outer(np.asarray(transfer[:, offsets[k]].todense()).ravel(), level)
    kept = [k for k in range(len(problem.lights)) if k not in levels]
    cols = np.concatenate([np.arange(offsets[k], offsets[k + 1]) for k in kept]).astype(int)
    again = solve_lighting(
        InverseProblem(
            radiance=problem.radiance,
            indirect=fixed,
            cluster=problem.cluster,
            cluster_names=problem.cluster_names,
            transfer=transfer[:, cols],
            lights=[problem.lights[k] for k in kept],
        ),
        options.solve,
        progress,
    )
    for k, level in levels.items():
        name = problem.lights[k].name
        again.intensities[name] = level[None, :]
        again.light_share[name] = result.light_share.get(name, 0.0)
    return again


def _chain(n: int) -> np.ndarray:
    """``(n - 1, 2)`` neighbouring pairs of ``n`` bins in a row (a profile's smoothness)."""
    return np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)


def _point_direct(caster, blocks, info, result, options):
    """``f(points, normals) -> (N, 3)``: the point lights' direct irradiance as solved,
    read between bins as the renderer reads it (None without point lights)."""
    from reroom.invert.direct import point_light_irradiance

    lights = [
        (info[k]["geometry"], np.nan_to_num(np.asarray(result.intensities[b.name], float)))
        for k, b in enumerate(blocks)
        if b.kind == "point"
    ]
    if not lights:
        return None

    def direct(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        out = np.zeros((len(points), 3))
        for g, intens in lights:
            out += point_light_irradiance(
                caster, points, normals, np.asarray(g["position"], float),
                np.asarray(g["axis"], float), intens, clearance=options.point_clearance,
                fixture=options.fixture_margin,
            )  # fmt: skip
        return out

    return direct


def _point_transfer(caster, p_recv, n_recv, position, axis, basis, options) -> np.ndarray:
    """A point light's transfer at the receivers with the run's clearance and fixture
    margin (the first solve, the refinement and the split all cast it alike)."""
    return point_light_transfer(
        caster, p_recv, n_recv, np.asarray(position, float), np.asarray(axis, float), basis,
        clearance=options.point_clearance, fixture=options.fixture_margin,
    )  # fmt: skip


def _point_blocks(blocks: list[LightBlock]):
    """``(index, block, columns)`` of each point light among ``blocks`` (its columns in
    the stacked transfer matrix)."""
    start = 0
    for k, block in enumerate(blocks):
        cols = slice(start, start + block.size)
        start += block.size
        if block.kind == "point":
            yield k, block, cols


def _split_point_bins(
    caster, p_recv, n_recv, rows, blocks, columns, info, problem, result, options
) -> None:
    """Each point light's profile at twice its bins (:func:`fine_profiles.split_bins`),
    in place: its block, transfer columns and solved intensities; its info keeps the
    bins it was solved at and each halving's shares."""
    from reroom.invert.fine_profiles import split_bins

    used = result.cluster_used[problem.cluster]
    gain = np.nan_to_num(result.albedo[problem.cluster]) / np.pi
    model = gain * (problem.indirect + problem.transfer @ result.intensity_vector(blocks))
    weights = np.where(used[:, None] & np.isfinite(result.weights), result.weights, 0.0)
    for k, block, cols in _point_blocks(blocks):
        g = info[k]["geometry"]
        basis = InclinationBasis(2 * block.size)
        fine = _point_transfer(caster, p_recv, n_recv, g["position"], g["axis"], basis, options)
        coarse = result.intensities[block.name]
        own = gain * (problem.transfer[:, cols] @ coarse)
        target = problem.radiance - model + own
        intens, share = split_bins(coarse, fine[rows], target, gain, weights)
        columns[k] = fine
        blocks[k] = LightBlock(block.name, "point", basis.size, True, _chain(basis.size))
        result.intensities[block.name] = intens
        color = result.colors[block.name]
        result.profiles[block.name] = intens @ color / max(float(color @ color), 1e-300)
        info[k].setdefault("split_from_bins", block.size)
        info[k]["split_shares"] = [*info[k].get("split_shares", []), share.tolist()]
        if "open_fraction" in info[k]:  # the shade prior's, per solved bin: each half
            info[k]["open_fraction"] = np.repeat(info[k]["open_fraction"], 2).tolist()


def _photo_clusters(options: InvertOptions) -> list[int]:
    """The cluster labels ``options.point_photo_clusters`` names (ValueError naming any
    that is not a cluster)."""
    chosen = [c.strip() for c in options.point_photo_clusters.split(",") if c.strip()]
    unknown = [c for c in chosen if c not in CLUSTER_LABELS]
    if unknown:
        raise ValueError(
            f"point_photo_clusters names {unknown}; clusters are {', '.join(CLUSTER_LABELS)}"
        )
    return [CLUSTER_LABELS[c] for c in chosen]


def _photo_point_profiles(
    scan: Path, mesh, caster, labels, receivers, rows, indirect, transfer, blocks, info,
    result, options: InvertOptions, notes: list[str], evaluation_radiance: bool,
) -> None:  # fmt: skip
    """Each point light's profile refitted to the photos' pixels
    (:func:`reroom.invert.photo_profiles.refit_point_profile`), in place: its solved
    intensities and profile; its info gets the fit's figures (``photo_profile``)."""
    from reroom.invert.direct import _point_geometry
    from reroom.invert.photo_profiles import even_subset, photo_samples, refit_point_profile
    from reroom.render.line_emitter import line_profile_value

    if evaluation_radiance:
        notes.append("point photo profiles: not fitted (solved with another radiance)")
        return
    nv = len(mesh.vertices)
    faces = np.asarray(mesh.faces, np.int64)
    wanted = _photo_clusters(options)
    names = list(CLUSTER_LABELS)
    # The clustered receivers the solve fitted: their cluster and albedo.
    rho = np.full((nv, 3), np.nan)
    fitted = receivers[rows]
    lab = labels[fitted]
    for i, name in enumerate(names):
        sel = lab == CLUSTER_LABELS[name]
        if CLUSTER_LABELS[name] in wanted and np.all(np.isfinite(result.albedo[i])):
            rho[fitted[sel]] = result.albedo[i]
    good = np.isfinite(rho).all(axis=1) & (rho > 0).all(axis=1)
    same = (labels[faces] == labels[faces[:, :1]]).all(axis=1)
    face_ok = good[faces].all(axis=1) & same
    if not face_ok.any():
        notes.append("point photo profiles: no clustered face to fit on")
        return
    try:
        samples, stats = photo_samples(scan, mesh, face_ok, caster=caster)
    except (ReroomError, OSError, ValueError) as exc:
        notes.append(f"point photo profiles: not fitted ({exc})")
        return
    notes.extend(stats["notes"])
    if not len(samples):
        notes.append("point photo profiles: no photo pixel on the clustered faces")
        return
    total = np.full((nv, 3), np.nan)
    total[receivers] = np.asarray(indirect) + np.asarray(transfer @ result.intensity_vector(blocks))
    for k, block, cols in _point_blocks(blocks):
        g = info[k]["geometry"]
        own = np.full((nv, 3), np.nan)
        own[receivers] = np.asarray(transfer[:, cols] @ result.intensities[block.name])
        geometry = (
            np.asarray(g["position"], float), np.asarray(g["axis"], float), None,
            options.point_clearance, options.fixture_margin,
        )  # fmt: skip
        # The cheap tests first, over every sample, with the light unoccluded (an upper
        # bound on its light); shadow rays only for the samples that pass them, which
        # gives the same set as testing every sample: an occluded sample gets no light
        # and fails the share test anyway. (On the 300-frame scan most of 6M samples
        # face away from a light or get little of their light from it.)
        value, cos_theta = _point_geometry(
            caster, samples.points, samples.normals, *geometry, occlusion=False
        )
        idx = np.flatnonzero(value > 0)
        value, cos_theta = value[idx], cos_theta[idx]
        rest = samples.interpolate(faces, total - own, idx)
        theta = np.arccos(np.clip(cos_theta, -1.0, 1.0))
        color = np.asarray(result.colors[block.name], float)
        profile = np.asarray(result.profiles[block.name], float)
        light = value * line_profile_value(profile, theta) * float(color.mean())
        target = np.pi * samples.radiance[idx] / samples.interpolate(faces, rho, idx) - rest
        # Samples where this light gives at least a tenth of the modelled light.
        keep = np.isfinite(target).all(axis=1) & (
            light >= 0.1 * (light + np.nan_to_num(rest).mean(axis=1))
        )
        idx, theta, target = idx[keep], theta[keep], target[keep]
        value, _ = _point_geometry(
            caster, samples.points[idx], samples.normals[idx], *geometry, occlusion=True
        )
        lit = value > 0
        idx, value, theta, target = idx[lit], value[lit], theta[lit], target[lit]
        if len(idx) < 100:
            info[k]["photo_profile"] = {"samples": int(len(idx)), "fitted": False}
            notes.append(
                f"point light {block.name!r}: {int(len(idx))} photo pixels it lights; "
                "profile kept as the receivers gave it"
            )
            continue
        group = max(1, block.size // options.bins)
        # A 300-frame 640x360 scan gives a downlight half a million pixels; an even
        # subset by bin keeps every bin's evidence at a fraction of the fit's cost.
        bin_of = np.minimum((theta / np.pi * block.size).astype(np.int64), block.size - 1)
        use = even_subset(bin_of, options.point_photo_samples, seed=options.seed)
        fit = refit_point_profile(profile, color, value[use], theta[use], target[use], group=group)
        result.profiles[block.name] = fit.profile
        result.intensities[block.name] = np.outer(fit.profile, color)
        info[k]["photo_profile"] = {
            "samples": fit.samples,
            "supported_bins": fit.supported_bins,
            "residual_before": round(fit.residual_before, 4),
            "residual_after": round(fit.residual_after, 4),
            "groups": fit.groups.astype(int).tolist(),
            "fitted": True,
        }
        notes.append(
            f"point light {block.name!r}: profile refitted to {fit.samples} photo pixels "
            f"({fit.supported_bins} bins seen; relative residual {fit.residual_before:.3f} "
            f"-> {fit.residual_after:.3f})"
        )


def _mounted_surfaces(light_list, notes: list[str]) -> dict[str, float]:
    """Each point light's ``evidence["mounted_on"]["surface_z"]`` (``reroom localize``).

    ``lights.json`` may be edited by hand: a record that is not a finite height is
    ignored with a note (the light is then refined without the bound).
    """
    out = {}
    for light in light_list:
        record = light.evidence.get("mounted_on")
        if light.type != "point" or record is None:
            continue
        z = record.get("surface_z") if isinstance(record, dict) else None
        try:
            z = float(z)
        except (TypeError, ValueError):
            z = float("nan")
        if np.isfinite(z):
            out[light.name] = z
        else:
            notes.append(
                f"point light {light.name!r}: evidence mounted_on {record!r} has no finite "
                "surface_z; refined without the mount's bound"
            )
    return out


def _refine_point_lights(
    caster,
    pts,
    p_recv,
    n_recv,
    rows,
    blocks,
    columns,
    info,
    problem,
    result,
    incl,
    options,
    mounted=None,
    measured=frozenset(),
) -> list[tuple[int, float, np.ndarray, dict]]:
    """Move each point light to where its share of the first solve fits best.

    (:mod:`reroom.invert.refine_points`). Updates ``columns`` and ``info`` in place for the
    lights that moved; returns ``(block index, metres, old column, old geometry)`` of each.
    ``mounted`` maps a light held by the surface above it to that surface's height: it
    goes at most ``options.refine_mounted_drop`` below it. Lights named in ``measured``
    (placed from their ceiling pool's edge: the rim's centre and the similar triangles,
    to millimetres) stay where they are.
    """
    from reroom.invert.refine_points import refine_point_position

    rho = result.albedo[problem.cluster]  # (n, 3); NaN for clusters left out
    ok = np.isfinite(rho).all(axis=1) & (rho > 0).all(axis=1)
    rho_safe = np.where(ok[:, None], rho, 1.0)
    sizes = [b.size for b in blocks]
    starts = np.concatenate([[0], np.cumsum(sizes)])
    intens = np.concatenate([np.asarray(result.intensities[b.name]) for b in blocks], axis=0)
    model = problem.transfer @ intens  # (n, 3) irradiance from every light
    # Eq. 5.6: Lbar = rho / pi (E_ind + F I), so the radiance residual is rho / pi times
    # the irradiance residual of the light's share.
    weight = np.where(ok[:, None], np.nan_to_num(result.weights) * (rho_safe / np.pi) ** 2, 0.0)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    # A light stays in the room: above the floor the solve fitted, and at most
    # `refine_recess` above its ceiling plane (a downlight sits in a can there: on
    # `furnished` the fit puts it 3 cm up, where the ceiling's receivers no longer face
    # it, as the can's walls hide it from them).
    z = p_recv[rows, 2]
    names = list(CLUSTER_LABELS)
    ceiling = problem.cluster == names.index("ceiling")
    floor = problem.cluster == names.index("floor")
    ceiling_z = float(np.median(z[ceiling])) if ceiling.sum() >= 10 else None
    if ceiling_z is not None:
        # Not clipped to the highest receiver: on a fused mesh that is the ceiling plane
        # itself, and the recess would be lost (the 300-frame `furnished` scan's downlight
        # then fell 0.19 m into the room instead).
        hi[2] = ceiling_z + options.refine_recess
    if floor.sum() >= 10:
        lo[2] = max(lo[2], float(np.median(z[floor])) + 0.01)
    # Each trial position casts a shadow ray per receiver: a seeded subset keeps a
    # 200k-vertex room as cheap as a small one (the fit has 32 unknowns and 3 coordinates).
    use = np.arange(len(rows))
    if len(use) > options.refine_max_receivers:
        rng = np.random.default_rng(options.seed)
        use = np.sort(rng.choice(use, options.refine_max_receivers, replace=False))
    moved = []
    for k, block in enumerate(blocks):
        if block.kind != "point":
            continue
        if block.name in measured:
            info[k]["refinement"] = {"skipped": "placed from its ceiling pool's edge"}
            continue
        cols = slice(int(starts[k]), int(starts[k + 1]))
        own = problem.transfer[:, cols] @ intens[cols]
        target = np.pi * problem.radiance / rho_safe - problem.indirect - (model - own)
        g = info[k]["geometry"]
        color = np.asarray(result.colors.get(block.name, np.ones(3) / np.sqrt(3)), float)
        start = np.asarray(g["position"], float)
        extra = ()
        if (
            options.refine_height
            and ceiling_z is not None
            and options.refine_recess > 0
            and abs(ceiling_z - start[2]) < options.refine_max_shift
        ):
            # A light at the ceiling hangs below it or sits in a can above its plane; the
            # objective has a cliff at the plane (ceiling receivers stop facing the light),
            # which a local search from one side does not cross: start on both sides.
            extra = (np.array([start[0], start[1], ceiling_z + options.refine_recess / 2]),)
        box_lo = lo
        surface_z = (mounted or {}).get(block.name)
        if surface_z is not None and options.refine_mounted_drop >= 0:
            # Localize found nothing in the scan holding the light but the surface above
            # (its mount test): it hangs from that surface, not in mid-air.
            box_lo = lo.copy()
            box_lo[2] = max(lo[2], min(start[2], surface_z - options.refine_mounted_drop))
        ref = refine_point_position(
            caster,
            p_recv[rows[use]],
            n_recv[rows[use]],
            target[use],
            weight[use],
            color,
            start,
            np.asarray(g["axis"], float),
            incl,
            clearance=options.point_clearance,
            fixture=options.fixture_margin,
            max_shift=options.refine_max_shift,
            bounds=(box_lo, hi),
            free=(0, 1, 2) if options.refine_height else (0, 1),
            extra_starts=extra,
        )
        info[k]["refinement"] = {
            "shift_m": ref.shift,
            "cost_start": ref.cost_start,
            "cost_end": ref.cost_end,
            "evaluations": ref.evaluations,
        }
        if box_lo is not lo:
            info[k]["refinement"]["lowest_z"] = float(box_lo[2])
        if ref.shift < 0.005:
            continue
        old_col, old_geom = columns[k], g
        columns[k] = _point_transfer(caster, p_recv, n_recv, ref.position, g["axis"], incl, options)
        info[k]["geometry"] = {**g, "position": ref.position.tolist()}
        info[k]["refined_from"] = list(map(float, g["position"]))
        moved.append((k, ref.shift, old_col, old_geom))
    return moved


def _jsonable_options(options: InvertOptions) -> dict:
    return json.loads(json.dumps(asdict(options), default=str))
