"""The room's structure: Manhattan frame, floor, ceiling, walls and rooms (thesis §4.2).

:func:`estimate_structure` runs the geometric half of the layout stage on a bare mesh
(no frames needed): frame, planes, wall candidates, rooms and their polygons.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from reroom.layout import floorplan as fp
from reroom.layout.errors import LayoutError
from reroom.layout.manhattan import manhattan_frame
from reroom.layout.meshops import mean_edge_length, vertex_areas, vertex_normals
from reroom.layout.planes import PlaneFit, horizontal_planes
from reroom.layout.wallgrid import rotate
from reroom.layout.walls import FloorGrid, Segment, WallScores, find_wall_segments


@dataclass(frozen=True)
class StructureOptions:
    """Options of :func:`estimate_structure`.

    Attributes
    ----------
    floorplan:
        ``"regions"`` (rooms under the ceiling, outlines snapped to wall lines; handles
        several rooms and non-convex ones) or ``"cycle"`` (the thesis's minimum-cost
        cycle through the wall candidates, one room).
    alpha:
        The cycle's model-complexity penalty per wall (metres of Manhattan distance).
    thin_walls:
        The thin-wall-aware empty-behind test (see :mod:`reroom.layout.walls`).
    max_tilt_deg:
        How far the true up direction may be from the mesh's +Z.
    min_room_area:
        Smallest room, m².
    min_manhattan:
        Smallest fraction of the surface (by area) whose normals lie within 10° of one
        of the six axes; below it the mesh is not a Manhattan room (a sphere: 5 %; the
        cluttered partial real scan slambook2: 22 %; synthetic rooms: 80-89 %).
    min_plane_area:
        Smallest area (m²) of horizontal surface at the floor's (ceiling's) height for it
        to count as the floor (ceiling), and at least a tenth of the other's.
    min_wall_support:
        Smallest fraction of a room outline's length that wall candidates must cover
        (outlines drawn along the ceiling's edge alone are not walls).
    threshold_steps:
        How many times the wall threshold ``N`` is lowered (by ``threshold_decay``)
        when no floorplan is found.
    threshold_decay:
        Factor applied to ``N`` on each retry.
    estimate_ceiling:
        When no ceiling is seen (a partial scan: cameras that hardly look up), estimate
        its height from the highest observed wall points and outline the rooms on the
        floor's coverage instead (:func:`estimate_ceiling`); ``False``: raise
        ``no ceiling found`` as before.
    ceiling_quantile:
        The estimated ceiling is this quantile of the heights of the wall-facing
        vertices (normals horizontal, within 25 degrees of a wall axis): the highest
        observed wall points, robust to a few noise specks.
    min_room_height:
        The estimated ceiling is at least this far above the floor (metres).
    partial_min_wall_support:
        :attr:`min_wall_support` for rooms outlined on the floor's coverage: a partial
        scan sees only some of its walls; the rest of the outline is where the floor's
        coverage ends.
    floor_close:
        Rooms outlined on the floor's coverage: the coverage is closed by this many
        metres first (the floor of a fused scan is speckled with gaps; its ceiling,
        in a complete scan, is not).
    partial_step:
        Rooms outlined on the floor's coverage: where no wall was found, the outline
        follows the coverage in rectilinear steps of at most this size (metres).
    partial_reach:
        Rooms outlined on the floor's coverage: a wall candidate facing the coverage
        from at most this far (metres) extends the room to it
        (:func:`~reroom.layout.floorplan.extend_to_walls`).
    partial_wall_cell:
        Without a seen ceiling, the wall score's grid cell is at least this size
        (metres): a partial scan sees most walls from far away, where a depth camera's
        noise (a Kinect's grows with the square of the range: several centimetres at 5
        m) spreads a wall over several cells of size ``r``.
    camera_margin:
        Rooms outlined on the floor's coverage: the outline is grown to contain every
        camera position given to :func:`estimate_structure` (projected to the floor,
        with this much room around it, metres; see
        :func:`~reroom.layout.floorplan.include_points`). ``None``: not grown.
    """

    floorplan: str = "regions"
    alpha: float = 1.0
    thin_walls: bool = True
    max_tilt_deg: float = 45.0
    min_room_area: float = 1.0
    min_manhattan: float = 0.15
    min_plane_area: float = 0.5
    min_wall_support: float = 0.5
    threshold_steps: int = 3
    threshold_decay: float = 0.6
    estimate_ceiling: bool = True
    ceiling_quantile: float = 0.999
    min_room_height: float = 2.0
    partial_min_wall_support: float = 0.1
    floor_close: float = 0.06
    partial_step: float = 0.5
    partial_reach: float = 3.0
    partial_wall_cell: float = 0.06
    camera_margin: float | None = 0.5


@dataclass
class Room:
    """One room: a counter-clockwise wall polygon in the aligned frame."""

    polygon: np.ndarray
    walls: list[dict]
    segments: list[int] = field(default_factory=list)
    support: float = 1.0
    seen: np.ndarray | None = None
    cameras_added: int = 0

    @property
    def area(self) -> float:
        return fp.polygon_area(self.polygon)


@dataclass
class Structure:
    """What :func:`estimate_structure` found.

    Attributes
    ----------
    rotation:
        ``(3, 3)`` mesh-to-aligned rotation (rows: x, y, up in mesh coordinates).
    r:
        Mesh resolution (mean edge length), metres.
    xyz, normals, areas:
        Vertices and unit normals in the aligned frame, vertex areas.
    normals_flipped:
        Whether the mesh's normals pointed out of the room and were flipped.
    floor, ceiling:
        The planes (aligned heights).
    segments:
        Wall candidates (after NMS and refinement).
    scores:
        The eq. 4.1 grids.
    threshold:
        The ``N`` the segments were found with.
    rooms:
        The rooms, largest first.
    region_labels:
        ``scores.grid``-shaped room index per cell (1-based, 0 = none), for ``regions``.
    notes:
        What was odd, in words.
    ceiling_estimated:
        No ceiling was seen: ``ceiling`` is an estimate (a lower bound: the highest
        observed wall points, see :func:`estimate_ceiling`) and the rooms were outlined
        on the floor's coverage.
    warnings:
        What a later stage should know about the result (the estimated ceiling).
    """

    rotation: np.ndarray
    r: float
    xyz: np.ndarray
    normals: np.ndarray
    areas: np.ndarray
    normals_flipped: bool
    floor: PlaneFit
    ceiling: PlaneFit
    segments: list[Segment]
    scores: WallScores
    threshold: float
    rooms: list[Room]
    region_labels: np.ndarray | None
    notes: list[str] = field(default_factory=list)
    ceiling_estimated: bool = False
    warnings: list[str] = field(default_factory=list)

    @property
    def grid(self) -> FloorGrid:
        return self.scores.grid


def _orient_normals(xyz: np.ndarray, normals: np.ndarray, areas: np.ndarray) -> bool:
    """Whether the normals point out of the room: the lowest horizontal surfaces face down.

    Fused scans orient every normal towards the side the sensor saw, i.e. into the room,
    so the floor faces up; a mesh whose floor faces down has all its normals flipped.
    """
    vert = np.abs(normals[:, 2]) > 0.9
    if vert.sum() < 10:
        return False
    z = xyz[vert, 2]
    low = z < np.quantile(z, 0.2)
    return float(np.sum(areas[vert][low] * normals[vert][low, 2])) < 0


def manhattan_fraction(normals: np.ndarray, areas: np.ndarray, cone_deg: float = 10.0) -> float:
    """Fraction of the surface area whose (aligned) normals lie within ``cone_deg`` of an axis."""
    near = np.abs(normals).max(axis=1) > np.cos(np.radians(cone_deg))
    total = float(areas.sum())
    return float(areas[near].sum() / total) if total > 0 else 0.0


def wall_support(polygon: np.ndarray, segments: list[Segment], tol: float) -> float:
    """Fraction of a polygon's perimeter covered by wall candidates facing into it."""
    seen = wall_coverage(polygon, segments, tol)
    lengths = np.array([w["length"] for w in fp.polygon_walls(polygon)])
    total = float(lengths.sum())
    return float(seen @ lengths) / total if total > 0 else 0.0


def wall_coverage(polygon: np.ndarray, segments: list[Segment], tol: float) -> np.ndarray:
    """Per edge of a polygon, the fraction of its length covered by wall candidates
    facing into it (within ``tol`` of its line)."""
    out = []
    for w in fp.polygon_walls(polygon):
        covered = 0.0
        a = np.asarray(w["start"])
        b = np.asarray(w["end"])
        n = np.asarray(w["inward_normal"])
        length = w["length"]
        ax = 0 if abs(n[0]) > 0.5 else 1
        lo, hi = sorted((a[1 - ax], b[1 - ax]))
        ivs = []
        for s in segments:
            if s.normal @ n < 0.9 or abs(s.offset - a[ax]) > tol:
                continue
            x0, x1 = max(lo, s.lo), min(hi, s.hi)
            if x1 > x0:
                ivs.append((x0, x1))
        ivs.sort()
        end = lo
        for x0, x1 in ivs:
            covered += max(0.0, x1 - max(x0, end))
            end = max(end, x1)
        out.append(covered / length if length > 0 else 0.0)
    return np.array(out)


def tall_surface_cells(
    xyz: np.ndarray,
    normals: np.ndarray,
    floor_z: float,
    ceiling_z: float,
    grid: FloorGrid,
    reach: float = 0.85,
) -> np.ndarray:
    """Cells of the floor grid holding a vertical surface that reaches near the ceiling.

    Walls run from floor to ceiling (above a door there is still wall); furniture
    stops lower. A cell counts when a vertical-facing vertex in it or in one of its 8
    neighbours (the wall score's grid and the vertices may be a cell apart) lies above
    ``floor_z + reach * (ceiling_z - floor_z)``.
    """
    vertical = np.abs(normals[:, 2]) < 0.3
    top = np.full(grid.shape, -np.inf)
    i, j = grid.index(xyz[vertical, :2])
    np.maximum.at(top, (i, j), xyz[vertical, 2])
    tall = top > floor_z + reach * (ceiling_z - floor_z)
    return ndimage.binary_dilation(tall, np.ones((3, 3), bool))


def ceiling_mask(
    st_xyz: np.ndarray, st_normals: np.ndarray, ceiling_z: float, r: float, grid: FloorGrid
) -> np.ndarray:
    """Cells of the floor grid under which a piece of the ceiling was scanned."""
    near = (np.abs(st_xyz[:, 2] - ceiling_z) < max(2.0 * r, 0.04)) & (st_normals[:, 2] < -0.8)
    mask = np.zeros(grid.shape, bool)
    i, j = grid.index(st_xyz[near, :2])
    mask[i, j] = True
    return mask


def floor_mask(
    st_xyz: np.ndarray, st_normals: np.ndarray, floor_z: float, r: float, grid: FloorGrid
) -> np.ndarray:
    """Cells of the floor grid where a piece of the floor was scanned (its coverage)."""
    near = (np.abs(st_xyz[:, 2] - floor_z) < max(2.0 * r, 0.04)) & (st_normals[:, 2] > 0.8)
    mask = np.zeros(grid.shape, bool)
    i, j = grid.index(st_xyz[near, :2])
    mask[i, j] = True
    return mask


def estimate_ceiling(
    xyz: np.ndarray,
    normals: np.ndarray,
    floor_z: float,
    quantile: float = 0.999,
    min_height: float = 2.0,
    min_count: int = 200,
) -> tuple[PlaneFit, str] | None:
    """A ceiling height for a scan whose ceiling was not seen: the highest wall points.

    Walls run from floor to ceiling, so the highest points seen on them (vertices whose
    normals are horizontal and within 25 degrees of a wall axis, above ``floor_z +
    0.5``; the ``quantile`` of their heights, so a few specks of noise do not count) are
    a lower bound of the ceiling under the layout's one-ceiling assumption; it is raised
    to ``floor_z + min_height`` when the walls were seen lower than that. Returns the
    plane (``support`` 0: nothing of it was seen) and a sentence saying how it was made,
    or ``None`` with fewer than ``min_count`` wall points.
    """
    n = np.asarray(normals)
    cos25 = np.cos(np.radians(25.0))
    wallish = (np.abs(n[:, 2]) < 0.3) & (np.abs(n[:, :2]).max(axis=1) > cos25)
    wallish &= xyz[:, 2] > floor_z + 0.5
    if wallish.sum() < min_count:
        return None
    top = float(np.quantile(xyz[wallish, 2], quantile))
    if top < floor_z + min_height:
        how = (
            f"the walls were seen up to {top - floor_z:.2f} m above the floor only; the "
            f"ceiling was put at the smallest room height, {min_height:.2f} m"
        )
        top = floor_z + min_height
    else:
        how = (
            f"estimated at {top - floor_z:.2f} m above the floor from the highest observed "
            f"wall points ({100 * quantile:g}th percentile of {int(wallish.sum())} "
            "wall-facing vertices): a lower bound"
        )
    return PlaneFit(top, 0.0, 0.0), how


def _grid_covering(grid: FloorGrid, xy: np.ndarray, margin: int = 4) -> FloorGrid:
    """``grid`` grown by whole cells (its cells stay where they are) to cover ``xy``
    with ``margin`` cells to spare."""
    c = grid.cell
    lo = np.array([grid.x0, grid.y0])
    hi = lo + c * np.array(grid.shape)
    add_lo = np.maximum(0, np.ceil((lo - (xy.min(axis=0) - margin * c)) / c)).astype(int)
    add_hi = np.maximum(0, np.ceil(((xy.max(axis=0) + margin * c) - hi) / c)).astype(int)
    shape = tuple(int(n) for n in np.array(grid.shape) + add_lo + add_hi)
    lo = lo - c * add_lo
    return FloorGrid(float(lo[0]), float(lo[1]), c, shape)  # type: ignore[arg-type]


def _region_rooms(
    segments: list[Segment],
    grid: FloorGrid,
    cmask: np.ndarray,
    wall_cells: np.ndarray,
    r: float,
    opt: StructureOptions,
    close_cells: int = 1,
    min_support: float | None = None,
    partial_step: float | None = None,
    cameras: np.ndarray | None = None,
) -> tuple[list[Room], np.ndarray]:
    labels, count = fp.room_regions(
        cmask, grid.cell, opt.min_room_area, close_cells=close_cells, walls=wall_cells
    )
    need = opt.min_wall_support if min_support is None else min_support
    regions = [labels == k for k in range(1, count + 1)]
    if partial_step:
        regions = [fp.extend_to_walls(reg, segments, grid, opt.partial_reach) for reg in regions]
        for k, reg in enumerate(regions, start=1):
            labels[reg & (labels == 0)] = k
    # Each camera belongs to the room it stands in, else the nearest one.
    owner = np.zeros(0, int)
    if partial_step and cameras is not None and opt.camera_margin is not None and regions:
        dist = np.stack([ndimage.distance_transform_edt(~reg) for reg in regions])
        i, j = grid.index(cameras)
        owner = np.argmin(dist[:, i, j], axis=0)
    rooms = []
    for k, region in enumerate(regions, start=1):
        cam_x: list[float] = []
        cam_y: list[float] = []
        added = 0
        covered = region
        mine = cameras[owner == k - 1] if len(owner) else np.zeros((0, 2))
        if len(mine) and opt.camera_margin is not None:
            region, cam_x, cam_y, added = fp.include_points(
                region, mine, segments, grid, opt.camera_margin
            )
            labels[region & (labels == 0)] = k
        idx = fp.segments_bounding(segments, region, grid)
        xs, ys = fp.region_lines(segments, idx, merge=max(1.5 * r, 0.04))
        bx, by = fp.boundary_lines(covered, grid, min_len=0.5)
        if partial_step:
            # The floor's coverage of a partial scan ends along slanted lines (the edges
            # of the views, shadows of furniture), which give no straight boundary runs:
            # add its extremes and lines every partial_step in between, so the outline
            # follows the coverage in steps of at most that size. The steps are laid on
            # the coverage before the cameras were added (the cameras' rectangles bring
            # their own sides), so adding them leaves the rest of the outline as it was.
            bx, by = list(bx), list(by)
            for axis, extra in ((0, bx), (1, by)):
                cells = np.flatnonzero(covered.any(axis=1 - axis))
                lo = float(grid.to_coord(axis, cells[0])) - 0.5 * grid.cell
                hi = float(grid.to_coord(axis, cells[-1])) + 0.5 * grid.cell
                n = max(1, int(np.ceil((hi - lo) / partial_step)))
                extra.extend(np.linspace(lo, hi, n + 1).tolist())
        # Boundary runs only stand in for walls the segment search missed.
        far = max(4 * grid.cell, 0.1)
        # The sides of the cameras' rectangles, where no other line is near (a line
        # within `far` stands in for them: a few millimetres apart they would only
        # leave slivers in the outline).
        for lines, extra, cam in ((xs, bx, cam_x), (ys, by, cam_y)):
            for c in cam:
                if all(abs(c - x) > far for x in [*lines, *extra]):
                    extra.append(c)
        xs = np.concatenate([xs, [x for x in bx if len(xs) == 0 or np.abs(xs - x).min() > far]])
        ys = np.concatenate([ys, [y for y in by if len(ys) == 0 or np.abs(ys - y).min() > far]])
        poly = fp.snap_region(region, grid, xs, ys)
        if len(poly) < 4 or fp.polygon_area(poly) < opt.min_room_area:
            continue
        support = wall_support(poly, [segments[i] for i in idx], max(3 * r, 0.08))
        if support < need:
            continue
        rooms.append(Room(poly, fp.polygon_walls(poly), idx, support, cameras_added=added))
    rooms.sort(key=lambda rm: -rm.area)
    return rooms, labels


def estimate_structure(
    vertices: np.ndarray,
    faces: np.ndarray,
    options: StructureOptions | None = None,
    cameras: np.ndarray | None = None,
) -> Structure:
    """Frame, floor, ceiling, walls and rooms of a scanned room mesh.

    ``cameras``: optional ``(N, 3)`` camera positions in the mesh's frame. Only used
    when no ceiling is seen: the partial rooms are grown to contain them (a capture is
    taken from inside the room; see :attr:`StructureOptions.camera_margin`).

    Raises
    ------
    LayoutError
        When no floor, no ceiling, no walls or no closed floorplan is found; the error
        carries what was found so far (``error.partial``).
    """
    opt = options or StructureOptions()
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    normals = vertex_normals(v, f)
    areas = vertex_areas(v, f)
    r = mean_edge_length(v, f)
    if not np.isfinite(r) or r <= 0:
        raise LayoutError("the mesh has no edges of positive length", {})
    rot = manhattan_frame(normals, areas, opt.max_tilt_deg)
    xyz = rotate(v, rot)
    nrm = rotate(normals, rot)
    flipped = _orient_normals(xyz, nrm, areas)
    if flipped:
        nrm = -nrm
    partial: dict = {"rotation": rot, "r": r, "xyz": xyz, "normals": nrm}
    frac = manhattan_fraction(nrm, areas)
    if frac < opt.min_manhattan:
        raise LayoutError(
            f"not a Manhattan-world room: only {100 * frac:.0f} % of the surface faces one of "
            f"three perpendicular axes (looked for at least {100 * opt.min_manhattan:.0f} %: "
            "floor, ceiling and walls)",
            partial,
        )
    floor, ceiling = horizontal_planes(xyz[:, 2], nrm[:, 2], areas, r)
    # A tabletop or a baseboard's top is not a floor: demand a real area of it.
    need = [opt.min_plane_area, opt.min_plane_area]
    if floor is not None and ceiling is not None:
        need = [max(need[0], 0.1 * ceiling.support), max(need[1], 0.1 * floor.support)]
    if floor is not None and floor.support < need[0]:
        floor = None
    if ceiling is not None and ceiling.support < need[1]:
        ceiling = None
    if floor is None:
        raise LayoutError(
            "no floor found: looked for a peak in the heights of upward-facing horizontal "
            f"surfaces (normals within 25 degrees of up) of at least {need[0]:.1f} m²",
            partial,
        )
    partial["floor"] = floor
    notes: list[str] = []
    warnings: list[str] = []
    estimated = None
    if ceiling is None and opt.estimate_ceiling:
        estimated = estimate_ceiling(xyz, nrm, floor.z, opt.ceiling_quantile, opt.min_room_height)
    if ceiling is None and estimated is None:
        # Still look for walls up to the top of the scan, so the error can say what was
        # found and the caller can label it (a partial scan often misses the ceiling).
        top = float(np.quantile(xyz[:, 2], 0.99))
        if top > floor.z + 0.5:
            segs, _, _ = find_wall_segments(
                xyz, nrm, floor.z, top, r, 0.5, opt.thin_walls, FloorGrid.around(xyz[:, :2], r)
            )
            partial["segments"] = segs
        raise LayoutError(
            "no ceiling found: looked for a peak in the heights of downward-facing "
            f"horizontal surfaces above the floor of at least {need[1]:.1f} m² (found the "
            f"floor at z = {floor.z:.3f} m and {len(partial.get('segments', []))} wall "
            "candidates below the top of the scan"
            + ("" if opt.estimate_ceiling else "; estimating it is switched off")
            + ")",
            partial,
        )
    if ceiling is None:
        # A partial scan: the cameras hardly looked up. The rooms are outlined on the
        # floor's coverage under an estimated ceiling (see estimate_ceiling).
        ceiling, how = estimated
        warnings.append(
            f"no ceiling seen: ceiling height {how}; rooms outlined on the floor's coverage "
            "and the wall planes found (a partial room)"
        )
    partial["ceiling"] = ceiling
    wall_cell = r if estimated is None else max(r, opt.partial_wall_cell)
    grid = FloorGrid.around(xyz[:, :2], wall_cell)
    cams = None
    if estimated is not None and cameras is not None and len(cameras):
        cams = rotate(np.asarray(cameras, np.float64).reshape(-1, 3), rot)[:, :2]
        grid = _grid_covering(grid, cams, 4 + int(np.ceil((opt.camera_margin or 0) / wall_cell)))
    scale = 1.0
    segments: list[Segment] = []
    scores = None
    thr = 0.0
    rooms: list[Room] = []
    labels = None
    if estimated is None:
        cmask = ceiling_mask(xyz, nrm, ceiling.z, r, grid)
        close_cells, min_support, step = 1, None, None
    else:
        cmask = floor_mask(xyz, nrm, floor.z, r, grid)
        close_cells = max(1, int(round(opt.floor_close / grid.cell)))
        min_support = opt.partial_min_wall_support
        step = opt.partial_step
    for attempt in range(opt.threshold_steps + 1):
        segments, scores, thr = find_wall_segments(
            xyz, nrm, floor.z, ceiling.z, wall_cell, scale, opt.thin_walls, grid
        )
        if opt.floorplan == "cycle":
            cyc = fp.min_cost_cycle(segments, opt.alpha)
            rooms = (
                [] if cyc is None else [Room(cyc.polygon, fp.polygon_walls(cyc.polygon), cyc.order)]
            )
        elif opt.floorplan == "regions":
            # Cells where a wall stands: a quarter of a seen wall column's score, and
            # vertical surface reaching up to the ceiling there. Without the second test
            # a closed piece of furniture against a wall (a cabinet: front, sides, back,
            # with the wall behind it in a complete mesh) walls off its own footprint
            # and the room outline gets a notch (and a false passage above it).
            walls = scores.raw.max(axis=0) > 0.5 * thr
            walls &= tall_surface_cells(xyz, nrm, floor.z, ceiling.z, grid)
            rooms, labels = _region_rooms(
                segments, grid, cmask, walls, r, opt, close_cells, min_support, step, cams
            )
        else:
            raise ValueError(f"floorplan must be 'regions' or 'cycle', not {opt.floorplan!r}")
        if rooms:
            break
        if attempt < opt.threshold_steps:
            notes.append(f"no floorplan at N = {thr:.1f}; lowering N")
            scale *= opt.threshold_decay
    partial.update(segments=segments, scores=scores)
    if not segments:
        raise LayoutError(
            "no walls found: looked for vertical surfaces facing into the room along lines "
            f"of the floor grid (eq. 4.1 score above N = {thr:.1f}, lowered "
            f"{opt.threshold_steps} times)",
            partial,
        )
    if not rooms:
        need_support = opt.min_wall_support if estimated is None else min_support
        raise LayoutError(
            f"no closed floorplan found: {len(segments)} wall candidates did not close "
            f"around a room (method {opt.floorplan!r}; a room needs walls along at least "
            f"{100 * need_support:.0f} % of its outline"
            + ("" if estimated is None else "; no ceiling seen, rooms sought on the floor")
            + ")",
            partial,
        )
    for room in rooms:
        cand = [segments[i] for i in room.segments] if room.segments else segments
        room.seen = wall_coverage(room.polygon, cand, max(3 * r, 0.08))
        if opt.floorplan == "cycle":
            room.support = wall_support(room.polygon, cand, max(3 * r, 0.08))
    if estimated is not None:
        inside = np.zeros(0 if cams is None else len(cams), bool)
        for room in rooms:
            if cams is not None:
                inside |= fp.points_in_polygon(cams, room.polygon)
        for k, room in enumerate(rooms):
            grown = ""
            if room.cameras_added:
                n = room.cameras_added
                grown = f", grown to contain {n} camera position{'s' if n > 1 else ''}"
            warnings.append(
                f"room{k}: wall candidates cover {100 * room.support:.0f} % of its outline; "
                f"the rest follows the edge of the floor's coverage{grown}"
            )
        if not inside.all():
            warnings.append(
                f"{int((~inside).sum())} of {len(inside)} camera positions lie outside "
                "every room's outline"
            )
    return Structure(
        rot,
        r,
        xyz,
        nrm,
        areas,
        flipped,
        floor,
        ceiling,
        segments,
        scores,
        thr,
        rooms,
        labels,
        notes,
        estimated is not None,
        warnings,
    )
