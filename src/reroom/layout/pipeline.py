"""``reroom layout``: floorplan, labels and architectural features of a scan (thesis ch. 4).

:func:`run_layout` is the whole stage: the room's structure from the mesh
(:mod:`~reroom.layout.structure`), per-vertex labels (:mod:`~reroom.layout.labels`),
image evidence on the walls (:mod:`~reroom.layout.wallgrid`), baseboards, doors,
windows and passages (:mod:`~reroom.layout.features`), and the outputs: ``layout.json``,
the labelled mesh, a floorplan figure and an empty-room mesh. It never reads
``ground_truth/`` (:mod:`~reroom.layout.evaluate` does).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from reroom.layout import features as ft
from reroom.layout.errors import LayoutError
from reroom.layout.labels import (
    CEILING,
    FLOOR,
    LAYOUT_LABELS,
    OTHER,
    WALL,
    assign_walls,
    clean_labels,
    shell_labels,
)
from reroom.layout.meshops import vertex_adjacency
from reroom.layout.structure import Structure, StructureOptions, estimate_structure
from reroom.layout.wallgrid import WallGrids, accumulate_bright, accumulate_frames, select_frames

__all__ = ["LayoutOptions", "LayoutResult", "OUTPUT_FILES", "run_layout", "layout_scan"]

ProgressFn = Callable[[str, int, int], None]

#: What :func:`run_layout` writes, relative to its output folder.
OUTPUT_FILES = {
    "layout": "layout.json",
    "labels": "layout_labels.ply",
    "figure": "floorplan.png",
    "empty_room": "empty_room.ply",
}


@dataclass(frozen=True)
class LayoutOptions:
    """Options of :func:`run_layout`.

    Attributes
    ----------
    structure:
        Frame, planes, walls and floorplan (:class:`~reroom.layout.structure.StructureOptions`).
    label_tol:
        Largest distance of a wall / floor / ceiling vertex from its plane, metres;
        ``None``: twice the mesh resolution ``r`` (the thesis uses ``r``; fused meshes
        are smoothed by that much at corners, by measurement).
    label_angle_deg:
        Largest angle between a vertex normal and its plane's normal.
    close_steps:
        Rings of the morphological closing of the labels along the mesh.
    features:
        Find baseboards, doors, windows and passages (needs the frames).
    max_frames:
        Frames used for the see-through evidence (openings), evenly spread through the
        scan; rays through every other pixel, no image read.
    edge_frames:
        Of those, frames (evenly spread) whose pixels also give the oriented edges
        (doors, baseboards): full resolution, the image read and filtered.
    max_width:
        Frames are downscaled by an integer factor to at most this width.
    wall_cell:
        Cell size of the per-wall grids, metres.
    radiance:
        Optional per-vertex HDR radiance ``(V, 3)`` (or ``(V,)`` luminance) of the scan
        mesh, or the path of a PLY with a ``radiance`` vertex attribute (the HDR stage's
        ``hdr_mesh.ply``): very bright wall regions become windows.
    bright_factor:
        A vertex is bright when its luminance is this many times the walls' median.
    gamma:
        The frames' response, to linearise them for edges (``None``: from the scan's
        metadata, else 2.2).
    figure, empty_room:
        Write the floorplan picture and the empty-room mesh.
    partial_min_seen:
        In a room outlined without a seen ceiling (a partial scan), openings and
        baseboards are kept only on walls whose length is covered by wall candidates at
        least this much: elsewhere the outline is the edge of the floor's coverage.
    """

    structure: StructureOptions = field(default_factory=StructureOptions)
    label_tol: float | None = None
    label_angle_deg: float = 35.0
    close_steps: int = 2
    features: bool = True
    max_frames: int = 120
    edge_frames: int = 40
    max_width: int = 320
    wall_cell: float = 0.02
    radiance: Any = None
    bright_factor: float = 8.0
    gamma: float | None = None
    figure: bool = True
    empty_room: bool = True
    partial_min_seen: float = 0.5


@dataclass
class LayoutResult:
    """What :func:`run_layout` found and wrote.

    Attributes
    ----------
    layout:
        The ``layout.json`` document.
    labels:
        ``(V,)`` uint8 per-vertex labels (:data:`~reroom.layout.labels.LAYOUT_LABELS`).
    room, wall:
        ``(V,)`` per-vertex room index and wall index within it (``-1``: none).
    structure:
        The geometric analysis (:class:`~reroom.layout.structure.Structure`).
    grids:
        The per-wall image evidence (``None`` without features).
    files:
        Paths written, by :data:`OUTPUT_FILES` key.
    timings:
        Wall-clock seconds per step.
    cpu_timings:
        CPU seconds per step (all threads).
    """

    layout: dict
    labels: np.ndarray
    room: np.ndarray
    wall: np.ndarray
    structure: Structure
    grids: WallGrids | None
    files: dict[str, Path]
    timings: dict[str, float]
    cpu_timings: dict[str, float] = field(default_factory=dict)


def _noop(stage: str, done: int, total: int) -> None:
    pass


def _now() -> tuple[float, float]:
    return time.perf_counter(), time.process_time()


def _lap(wall: dict, cpu: dict, name: str, start: tuple[float, float]) -> None:
    """Record a step's wall-clock and CPU seconds (the machine is often shared: CPU
    seconds are what the step costs, wall clock what it took)."""
    wall[name] = time.perf_counter() - start[0]
    cpu[name] = time.process_time() - start[1]


def _gamma(scan_meta: dict, gamma: float | None) -> float:
    if gamma is not None:
        return float(gamma)
    resp = str((scan_meta.get("reroom") or {}).get("response", "gamma2.2"))
    if resp == "linear":
        return 1.0
    if resp.startswith("gamma"):
        try:
            return float(resp[5:])
        except ValueError:
            return 2.2
    return 2.2  # srgb and unknown: close enough for edges


def _luminance(radiance: Any, n_vertices: int) -> np.ndarray | None:
    if radiance is None:
        return None
    if isinstance(radiance, str | Path):
        from reroom.io.mesh import read_ply

        attrs = read_ply(radiance).vertex_attributes
        if "radiance" not in attrs:
            raise LayoutError(f"{radiance}: has no 'radiance' vertex attribute", {})
        radiance = attrs["radiance"]
    r = np.asarray(radiance, np.float64)
    if r.shape[0] != n_vertices:
        raise LayoutError(
            f"radiance has {r.shape[0]} rows but the scan mesh has {n_vertices} vertices", {}
        )
    if r.ndim == 2:
        r = r @ np.array([0.2126, 0.7152, 0.0722])
    return np.nan_to_num(r, nan=0.0)


def _partial_labels(partial: dict, r: float) -> np.ndarray | None:
    """Labels from whatever a failed analysis found (floor, ceiling, wall candidates)."""
    xyz = partial.get("xyz")
    nrm = partial.get("normals")
    if xyz is None or nrm is None:
        return None
    lab = np.full(len(xyz), OTHER, np.uint8)
    tol = 2 * r
    c = np.cos(np.radians(35))
    if "floor" in partial:
        lab[(nrm[:, 2] > c) & (np.abs(xyz[:, 2] - partial["floor"].z) < tol)] = FLOOR
    if "ceiling" in partial:
        lab[(nrm[:, 2] < -c) & (np.abs(xyz[:, 2] - partial["ceiling"].z) < tol)] = CEILING
    for s in partial.get("segments") or []:
        ax = s.axis
        sel = (
            (np.abs(xyz[:, ax] - s.offset) < tol)
            & (nrm[:, :2] @ s.normal > c)
            & (xyz[:, 1 - ax] > s.lo)
            & (xyz[:, 1 - ax] < s.hi)
        )
        lab[sel & (lab == OTHER)] = WALL
    return lab


def layout_scan(
    scan,
    options: LayoutOptions | None = None,
    progress: ProgressFn | None = None,
) -> LayoutResult:
    """:func:`run_layout` on a loaded :class:`~reroom.scan.Scan`, without writing files."""
    opt = options or LayoutOptions()
    progress = progress or _noop
    timings: dict[str, float] = {}
    cpu: dict[str, float] = {}
    mesh = scan.mesh
    v = np.asarray(mesh.vertices, np.float64)
    f = np.asarray(mesh.faces, np.int64)
    lum = _luminance(opt.radiance, len(v))

    t = _now()
    progress("structure", 0, 1)
    # Camera positions: a partial room (no ceiling seen) is grown to contain them.
    cams = np.array([fr.center for fr in scan.frames]) if scan.frames else None
    st = estimate_structure(v, f, opt.structure, cams)
    progress("structure", 1, 1)
    _lap(timings, cpu, "structure", t)

    # --- labels ---------------------------------------------------------------------------
    t = _now()
    walls = [w for room in st.rooms for w in room.walls]
    wall_room = np.concatenate([[k] * len(room.walls) for k, room in enumerate(st.rooms)])
    wall_local = np.concatenate([np.arange(len(room.walls)) for room in st.rooms])
    tol = opt.label_tol if opt.label_tol is not None else 2.0 * st.r
    from reroom.layout.floorplan import rasterize_polygons

    foot_grid = rasterize_polygons([room.polygon for room in st.rooms], st.grid)
    i, j = st.grid.index(st.xyz[:, :2])
    footprint = foot_grid[i, j]
    labels, vwall = shell_labels(
        st.xyz, st.normals, st.floor.z, st.ceiling.z, walls, footprint, tol, opt.label_angle_deg
    )
    adjacency = vertex_adjacency(f, len(v))
    labels = clean_labels(labels, adjacency, opt.close_steps)
    _lap(timings, cpu, "labels", t)

    # --- features -------------------------------------------------------------------------
    grids = None
    openings: list[ft.Opening] = []
    baseboard = None
    if opt.features or lum is not None:
        t = _now()
        grids = WallGrids.empty(walls, opt.wall_cell, st.floor.z, st.ceiling.z)
        # Pixels count for the edges when they see a wall or something set into it
        # (door leaves, trims, baseboards): vertices near a wall plane facing the room.
        fwall, _ = assign_walls(
            st.xyz,
            st.normals,
            walls,
            tol,
            0.5,
            (st.floor.z, st.ceiling.z),
            front=max(tol, 0.05),
            back=0.3,
        )
        fwall[np.isin(labels, (FLOOR, CEILING))] = -1
        w0, w1, w2 = fwall[f[:, 0]], fwall[f[:, 1]], fwall[f[:, 2]]
        face_wall = np.where(w0 == w1, w0, np.where(w1 == w2, w1, w0))
        if opt.features and scan.frames:
            from reroom.rays import RayCaster

            caster = RayCaster(mesh)
            frames = select_frames(scan.frames, opt.max_frames)
            with_edges = select_frames(frames, opt.edge_frames)
            chosen = {id(f) for f in with_edges}
            through_only = [f for f in frames if id(f) not in chosen]
            n_all = len(frames)
            for batch, edges, start in (
                (with_edges, True, 0),
                (through_only, False, len(with_edges)),
            ):
                accumulate_frames(
                    grids,
                    batch,
                    caster,
                    st.rotation,
                    face_wall,
                    opt.max_width,
                    _gamma(scan.meta, opt.gamma),
                    progress=lambda d, n, s0=start: progress("frames", s0 + d, n_all),
                    edges=edges,
                )
        if lum is not None:
            accumulate_bright(grids, st.xyz, lum, fwall, opt.bright_factor)
        _lap(timings, cpu, "evidence", t)

        t = _now()
        holes = [o for k in range(len(walls)) for o in ft.find_holes(grids, k)]
        doors: list[ft.Opening] = []
        if opt.features:
            for k in range(len(walls)):
                doors += ft.combine_doors(ft.find_doors(grids, k), ft.find_recessed_doors(grids, k))
        openings = ft.merge_openings(doors, holes)
        if st.ceiling_estimated:
            # A partial room: where no wall was seen the outline follows the edge of
            # the floor's coverage; rays cross it freely, which is no window or passage,
            # and no baseboard stands there.
            seen = np.concatenate([room.seen for room in st.rooms])
            openings = [o for o in openings if seen[o.wall] >= opt.partial_min_seen]
        openings = ft.join_shared_openings(openings, walls, wall_room)
        ft.measure_depths(openings, st.xyz, st.normals, walls, grids)
        spans = None
        if opt.features:
            height, profile, heights = ft.find_baseboard_height(grids)
            if height is not None:
                baseboard = ft.measure_baseboard(
                    height, grids, st.xyz, st.normals, st.floor.z, profile, heights
                )
                if st.ceiling_estimated:
                    keep = [k for k in baseboard.walls if seen[k] >= opt.partial_min_seen]
                    baseboard = replace(baseboard, walls=keep) if keep else None
            if baseboard is not None:
                spans = baseboard_pieces(baseboard, walls, openings)
        labels = ft.label_features(
            labels, st.xyz, walls, openings, baseboard, st.floor.z, tol, spans
        )
        _lap(timings, cpu, "features", t)

    room = np.where(vwall >= 0, wall_room[np.maximum(vwall, 0)], -1)
    wall_idx = np.where(vwall >= 0, wall_local[np.maximum(vwall, 0)], -1)
    doc = layout_document(st, openings, baseboard, wall_room, wall_local, labels)
    return LayoutResult(doc, labels, room, wall_idx, st, grids, {}, timings, cpu)


def layout_document(
    st: Structure,
    openings: list[ft.Opening],
    baseboard: ft.Baseboard | None,
    wall_room: np.ndarray,
    wall_local: np.ndarray,
    labels: np.ndarray,
) -> dict:
    """The ``layout.json`` document (see ``docs/layout.md``)."""
    rooms = []
    for k, room in enumerate(st.rooms):
        ops = []
        for o in sorted(openings, key=lambda o: (o.wall, o.s0)):
            if wall_room[o.wall] != k:
                continue
            ops.append(
                {
                    "kind": o.kind,
                    "wall": int(wall_local[o.wall]),
                    "s0": round(o.s0, 4),
                    "s1": round(o.s1, 4),
                    "z0": round(o.z0, 4),
                    "z1": round(o.z1, 4),
                    "depth": round(o.depth, 4),
                    "source": o.source,
                    **({"into": f"room{o.into}"} if o.into >= 0 else {}),
                }
            )
        bb = None
        if baseboard is not None:
            pieces = [
                {"wall": int(wall_local[p[0]]), "s0": round(p[1], 4), "s1": round(p[2], 4)}
                for p in baseboard_pieces(
                    baseboard, [w for r in st.rooms for w in r.walls], openings
                )
                if wall_room[p[0]] == k
            ]
            if pieces:
                bb = {
                    "height": round(baseboard.height, 4),
                    "depth": round(baseboard.depth, 4),
                    "pieces": pieces,
                }
        rooms.append(
            {
                "name": f"room{k}",
                "polygon": np.round(room.polygon, 4).tolist(),
                "area": round(room.area, 4),
                "floor_z": round(st.floor.z, 4),
                "ceiling_z": round(st.ceiling.z, 4),
                "ceiling": "estimated" if st.ceiling_estimated else "seen",
                "wall_support": round(room.support, 4),
                "walls": [
                    {
                        "index": w["index"],
                        "start": np.round(w["start"], 4).tolist(),
                        "end": np.round(w["end"], 4).tolist(),
                        "inward_normal": np.round(w["inward_normal"], 6).tolist(),
                        "length": round(w["length"], 4),
                        "seen": round(float(seen), 4),
                    }
                    for w, seen in zip(room.walls, room.seen, strict=True)
                ],
                "openings": ops,
                "baseboard": bb,
            }
        )
    counts = {name: int(np.sum(labels == i)) for name, i in LAYOUT_LABELS.items()}
    return {
        "format": "reroom-layout",
        "version": 1,
        "units": "m",
        "frame": "aligned: x, y = the Manhattan wall axes, z = up; aligned = rotation @ mesh",
        "rotation": np.round(st.rotation, 8).tolist(),
        "up": np.round(st.rotation[2], 8).tolist(),
        "mesh_resolution": round(st.r, 5),
        "normals_flipped": st.normals_flipped,
        "floor_z": round(st.floor.z, 4),
        "ceiling_z": round(st.ceiling.z, 4),
        "ceiling": "estimated" if st.ceiling_estimated else "seen",
        "wall_threshold": round(st.threshold, 3),
        "rooms": rooms,
        "labels": dict(LAYOUT_LABELS),
        "label_counts": counts,
        "notes": list(st.notes),
        "warnings": list(st.warnings),
    }


def baseboard_pieces(
    baseboard: ft.Baseboard, walls: list[dict], openings: list[ft.Opening]
) -> list[tuple[int, float, float]]:
    """``(wall, s0, s1)`` spans of the baseboard: its walls minus doors and passages."""
    out = []
    for k in baseboard.walls:
        length = walls[k]["length"]
        skip = sorted(
            (o.s0, o.s1) for o in openings if o.wall == k and o.kind in ("door", "passage")
        )
        start = 0.0
        for s0, s1 in skip:
            if s0 > start + 0.05:
                out.append((k, start, s0))
            start = max(start, s1)
        if start < length - 0.05:
            out.append((k, start, length))
    return out


def run_layout(
    scan_dir: str | Path,
    out_dir: str | Path,
    options: LayoutOptions | None = None,
    progress: ProgressFn | None = None,
) -> LayoutResult:
    """Recover a scan's room layout and write it.

    Parameters
    ----------
    scan_dir:
        A scan folder (``transforms.json``, frames, mesh).
    out_dir:
        Output folder (created). Written atomically:

        * ``layout.json`` -- rotation into the Manhattan frame, floor and ceiling
          heights, per room its wall polygon, walls, openings (doors, windows,
          passages) and baseboard (see ``docs/layout.md``);
        * ``layout_labels.ply`` -- the scan mesh with per-vertex ``label`` (uint8,
          :data:`~reroom.layout.labels.LAYOUT_LABELS`), ``room`` and ``wall`` (int16,
          -1 where none);
        * ``floorplan.png`` -- top view of the scan with the walls, doors and windows;
        * ``empty_room.ply`` -- the empty room: a closed shell per room with openings,
          plus baseboards, with a per-face ``label`` (aligned frame).
    options:
        :class:`LayoutOptions`.
    progress:
        ``progress(stage, done, total)`` callback.

    Returns
    -------
    LayoutResult

    Raises
    ------
    ScanError
        If the scan is missing or malformed.
    LayoutError
        (a :class:`~reroom.errors.ReroomError`) when the scan does not look like a room:
        no floor, ceiling, walls or closed floorplan. The message says what was looked
        for; the labels that could be made are still written to ``layout_labels.ply``.
    """
    from reroom.io.atomic import atomic_write_json
    from reroom.io.mesh import write_triangle_ply
    from reroom.scan import load_scan

    opt = options or LayoutOptions()
    progress = progress or _noop
    out = Path(out_dir)
    t0 = time.perf_counter()
    progress("load", 0, 1)
    scan = load_scan(scan_dir)
    progress("load", 1, 1)
    t_load = time.perf_counter() - t0
    try:
        res = layout_scan(scan, opt, progress)
    except LayoutError as err:
        lab = _partial_labels(err.partial, float(err.partial.get("r", 0.03)))
        if lab is not None:
            path = write_triangle_ply(
                out / OUTPUT_FILES["labels"], scan.mesh.vertices, scan.mesh.faces, {"label": lab}
            )
            found = ", ".join(
                f"{int(np.sum(lab == i))} {name}"
                for name, i in LAYOUT_LABELS.items()
                if name != "other" and np.any(lab == i)
            )
            raise LayoutError(
                f"{scan.root}: {err}; wrote the labels that could be made "
                f"({found or 'none'}) to {path}",
                err.partial,
            ) from err
        raise LayoutError(f"{scan.root}: {err}", err.partial) from err
    res.timings = {"load": t_load, **res.timings}
    t = time.perf_counter()
    files: dict[str, Path] = {}
    files["labels"] = write_triangle_ply(
        out / OUTPUT_FILES["labels"],
        scan.mesh.vertices,
        scan.mesh.faces,
        {
            "label": res.labels,
            "room": res.room.astype(np.int16),
            "wall": res.wall.astype(np.int16),
        },
    )
    if opt.empty_room:
        from reroom.layout.emptyroom import empty_room_mesh

        em, face_labels = empty_room_mesh(res.layout)
        files["empty_room"] = write_triangle_ply(
            out / OUTPUT_FILES["empty_room"], em.vertices, em.faces, None, {"label": face_labels}
        )
    if opt.figure:
        from reroom.layout.plot import floorplan_figure

        files["figure"] = floorplan_figure(out / OUTPUT_FILES["figure"], res)
    res.timings["write"] = time.perf_counter() - t
    res.timings["total"] = time.perf_counter() - t0
    res.layout["timings_s"] = {k: round(v, 3) for k, v in res.timings.items()}
    res.layout["cpu_s"] = {k: round(v, 3) for k, v in res.cpu_timings.items()}
    res.layout["options"] = _options_json(opt)
    res.layout["scan"] = str(scan.root)
    files["layout"] = atomic_write_json(out / OUTPUT_FILES["layout"], res.layout)
    res.files = files
    return res


def _options_json(opt: LayoutOptions) -> dict:
    d = asdict(opt)
    rad = d.get("radiance")
    d["radiance"] = str(rad) if isinstance(rad, str | Path) else (None if rad is None else "array")
    return d
