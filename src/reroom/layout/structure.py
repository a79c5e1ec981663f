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


@dataclass
class Room:
    """One room: a counter-clockwise wall polygon in the aligned frame."""

    polygon: np.ndarray
    walls: list[dict]
    segments: list[int] = field(default_factory=list)

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
    from reroom.layout.floorplan import polygon_walls

    covered = 0.0
    total = 0.0
    for w in polygon_walls(polygon):
        a = np.asarray(w["start"])
        b = np.asarray(w["end"])
        n = np.asarray(w["inward_normal"])
        length = w["length"]
        total += length
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
    return covered / total if total > 0 else 0.0


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


def _region_rooms(
    segments: list[Segment],
    grid: FloorGrid,
    cmask: np.ndarray,
    wall_cells: np.ndarray,
    r: float,
    opt: StructureOptions,
) -> tuple[list[Room], np.ndarray]:
    labels, count = fp.room_regions(cmask, grid.cell, opt.min_room_area, walls=wall_cells)
    rooms = []
    for k in range(1, count + 1):
        region = labels == k
        idx = fp.segments_bounding(segments, region, grid)
        xs, ys = fp.region_lines(segments, idx, merge=max(1.5 * r, 0.04))
        bx, by = fp.boundary_lines(region, grid, min_len=0.5)
        # Boundary runs only stand in for walls the segment search missed.
        far = max(4 * grid.cell, 0.1)
        xs = np.concatenate([xs, [x for x in bx if len(xs) == 0 or np.abs(xs - x).min() > far]])
        ys = np.concatenate([ys, [y for y in by if len(ys) == 0 or np.abs(ys - y).min() > far]])
        poly = fp.snap_region(region, grid, xs, ys)
        if len(poly) < 4 or fp.polygon_area(poly) < opt.min_room_area:
            continue
        if wall_support(poly, [segments[i] for i in idx], max(3 * r, 0.08)) < opt.min_wall_support:
            continue
        rooms.append(Room(poly, fp.polygon_walls(poly), idx))
    rooms.sort(key=lambda rm: -rm.area)
    return rooms, labels


def estimate_structure(
    vertices: np.ndarray, faces: np.ndarray, options: StructureOptions | None = None
) -> Structure:
    """Frame, floor, ceiling, walls and rooms of a scanned room mesh.

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
    if ceiling is None:
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
            "candidates below the top of the scan)",
            partial,
        )
    partial["ceiling"] = ceiling
    grid = FloorGrid.around(xyz[:, :2], r)
    notes: list[str] = []
    scale = 1.0
    segments: list[Segment] = []
    scores = None
    thr = 0.0
    rooms: list[Room] = []
    labels = None
    cmask = ceiling_mask(xyz, nrm, ceiling.z, r, grid)
    for attempt in range(opt.threshold_steps + 1):
        segments, scores, thr = find_wall_segments(
            xyz, nrm, floor.z, ceiling.z, r, scale, opt.thin_walls, grid
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
            rooms, labels = _region_rooms(segments, grid, cmask, walls, r, opt)
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
        raise LayoutError(
            f"no closed floorplan found: {len(segments)} wall candidates did not close "
            f"around a room (method {opt.floorplan!r}; a room needs walls along at least "
            f"{100 * opt.min_wall_support:.0f} % of its outline)",
            partial,
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
    )
