"""The empty room as a mesh: a watertight shell per room, plus baseboard boxes.

Each room's shell is its floor, ceiling and walls with the openings cut out. An opening
continues as a tunnel as deep as it was measured (jambs, head, and a sill) and is closed
at its far end: by the door leaf for a door, by a pane for a window or a passage (a
renderer treats the window pane as the portal the daylight comes through, and removes
passage panes -- label ``portal`` -- to join rooms). So every shell is closed: each edge
is shared by exactly two faces.

Watertightness comes from construction, not repair: all surfaces of a room are cut by
the same global lines -- the x and y coordinates of every corner and opening edge, and
every opening's heights -- so neighbouring pieces share their boundary vertices exactly
and welding them closes the shell. Baseboards are separate closed boxes standing on the
floor against the walls.
"""

from __future__ import annotations

import numpy as np
import trimesh

from reroom.layout.labels import BASEBOARD, CEILING, DOOR, FLOOR, WALL, WINDOW

#: Label of the pane closing a passage in the empty-room mesh (remove it to join rooms).
PORTAL = 254


class _Builder:
    def __init__(self) -> None:
        self.tris: list[np.ndarray] = []
        self.labels: list[int] = []

    def quad_grid(
        self,
        origin: np.ndarray,
        u: np.ndarray,
        v: np.ndarray,
        us: np.ndarray,
        vs: np.ndarray,
        label: int,
        keep=None,
    ) -> None:
        """Cells of the grid ``origin + a u + b v`` (``a`` in ``us``, ``b`` in ``vs``); the
        triangles face ``u x v``."""
        for i in range(len(us) - 1):
            for j in range(len(vs) - 1):
                if keep is not None and not keep(
                    0.5 * (us[i] + us[i + 1]), 0.5 * (vs[j] + vs[j + 1])
                ):
                    continue
                p00 = origin + us[i] * u + vs[j] * v
                p10 = origin + us[i + 1] * u + vs[j] * v
                p11 = origin + us[i + 1] * u + vs[j + 1] * v
                p01 = origin + us[i] * u + vs[j + 1] * v
                self.tris.append(np.array([[p00, p10, p11], [p00, p11, p01]]))
                self.labels += [label, label]

    def mesh(self) -> tuple[trimesh.Trimesh, np.ndarray]:
        if not self.tris:
            return trimesh.Trimesh(), np.zeros(0, np.uint8)
        tri = np.concatenate(self.tris)
        lab = np.asarray(self.labels, np.uint8)
        # Weld: identical construction gives identical coordinates; round out float noise.
        pts = tri.reshape(-1, 3)
        key = np.round(pts / 1e-6).astype(np.int64)
        _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
        verts = pts[first]
        faces = np.asarray(inv).reshape(-1, 3)
        m = trimesh.Trimesh(verts, faces, process=False)
        return m, lab


#: Decimals (of a metre) the shell's cut lines and the grown room's openings are rounded
#: to: every cut and every edge it must meet round alike.
CUT_DECIMALS = 6
#: The precision of the shell's cut lines (metres), what :data:`CUT_DECIMALS` rounds to.
CUT_EPS = 10.0**-CUT_DECIMALS


def _cuts(values: list[float], lo: float, hi: float, eps: float = CUT_EPS) -> np.ndarray:
    v = np.unique(np.round(np.clip(np.asarray(values, float), lo, hi), CUT_DECIMALS))
    v = v[(v >= lo - eps) & (v <= hi + eps)]
    out = [v[0]]
    for x in v[1:]:
        if x - out[-1] > eps:
            out.append(x)
    return np.asarray(out)


def room_shell(
    polygon: np.ndarray,
    floor_z: float,
    ceiling_z: float,
    openings: list[dict],
) -> tuple[trimesh.Trimesh, np.ndarray]:
    """A closed shell for one rectilinear room (see the module notes).

    Parameters
    ----------
    polygon:
        ``(K, 2)`` counter-clockwise, axis-aligned polygon.
    openings:
        ``kind`` (door / window / passage), ``wall`` (edge index), ``s0, s1`` (arc length
        from the edge's start), ``z0, z1`` (heights), ``depth`` (tunnel depth, metres),
        optional ``front`` (metres, default 0): how far the tunnel's sides (jambs, head,
        sill) reach in front of the wall, into the room.

    Returns
    -------
    mesh, face_labels
    """
    from reroom.synth.room import point_in_polygon

    poly = np.asarray(polygon, float)
    k = len(poly)
    zf, zc = float(floor_z), float(ceiling_z)
    # Openings clipped into their wall, depth at least a millimetre.
    ops = []
    for o in openings:
        a, b = poly[o["wall"]], poly[(o["wall"] + 1) % k]
        length = float(np.linalg.norm(b - a))
        s0, s1 = max(0.02, o["s0"]), min(length - 0.02, o["s1"])
        z0, z1 = max(zf, o["z0"]), min(zc - 0.02, o["z1"])
        if s1 - s0 < 0.05 or z1 - z0 < 0.05:
            continue
        ops.append(
            {
                **o,
                "s0": s0,
                "s1": s1,
                "z0": z0,
                "z1": z1,
                "depth": max(0.001, abs(o.get("depth", 0.05))),
            }
        )
    xs = list(poly[:, 0])
    ys = list(poly[:, 1])
    zs = [zf, zc]
    for o in ops:
        a, b = poly[o["wall"]], poly[(o["wall"] + 1) % k]
        t = (b - a) / np.linalg.norm(b - a)
        for s in (o["s0"], o["s1"]):
            p = a + t * s
            (xs if abs(t[0]) > 0.5 else ys).append(float(p[0] if abs(t[0]) > 0.5 else p[1]))
        zs += [o["z0"], o["z1"]]
    xc = _cuts(xs, poly[:, 0].min(), poly[:, 0].max())
    yc = _cuts(ys, poly[:, 1].min(), poly[:, 1].max())
    zcut = _cuts(zs, zf, zc)
    bld = _Builder()
    up = np.array([0.0, 0.0, 1.0])

    def inside(x: float, y: float) -> bool:
        return bool(point_in_polygon(np.array(x), np.array(y), poly))

    # Floor faces up (u = x, v = y), ceiling faces down (u = y, v = x).
    bld.quad_grid(
        np.array([0, 0, zf]),
        np.array([1.0, 0, 0]),
        np.array([0, 1.0, 0]),
        xc,
        yc,
        FLOOR,
        keep=lambda x, y: inside(x, y),
    )
    bld.quad_grid(
        np.array([0, 0, zc]),
        np.array([0, 1.0, 0]),
        np.array([1.0, 0, 0]),
        yc,
        xc,
        CEILING,
        keep=lambda y, x: inside(x, y),
    )
    for i in range(k):
        a, b = poly[i], poly[(i + 1) % k]
        length = float(np.linalg.norm(b - a))
        t = (b - a) / length
        n_in = np.array([-t[1], t[0]])
        cuts_along = xc if abs(t[0]) > 0.5 else yc
        coord = a[0] if abs(t[0]) > 0.5 else a[1]
        sign = t[0] if abs(t[0]) > 0.5 else t[1]
        s_cuts = np.sort((cuts_along - coord) * sign)
        # The cuts are rounded to the micrometre (_cuts) and the corners need not be
        # (a shell grown by an uneven gap): compare to that precision, or a corner's
        # strip or an opening's edge is lost (its head and sill with it).
        s_cuts = s_cuts[(s_cuts >= -CUT_EPS) & (s_cuts <= length + CUT_EPS)]
        mine = [o for o in ops if o["wall"] == i]

        def solid(s: float, z: float, mine=mine) -> bool:
            return not any(o["s0"] < s < o["s1"] and o["z0"] < z < o["z1"] for o in mine)

        # Seen from inside: origin at the end, u = -t, v = up gives normal u x v = n_in.
        end3 = np.array([b[0], b[1], 0.0])
        bld.quad_grid(
            end3,
            -np.append(t, 0),
            up,
            np.sort(length - s_cuts),
            zcut,
            WALL,
            keep=lambda u, z, L=length, f=solid: f(L - u, z),
        )
        t3 = np.append(t, 0.0)
        out3 = -np.append(n_in, 0.0)
        a3 = np.array([a[0], a[1], 0.0])
        for o in mine:
            d = o["depth"]
            ss = s_cuts[(s_cuts >= o["s0"] - CUT_EPS) & (s_cuts <= o["s1"] + CUT_EPS)]
            zz = zcut[(zcut >= o["z0"] - CUT_EPS) & (zcut <= o["z1"] + CUT_EPS)]
            dd = np.array([-max(0.0, float(o.get("front", 0.0))), d])
            p0 = a3 + t3 * o["s0"]
            p1 = a3 + t3 * o["s1"]
            back = {"door": DOOR, "window": WINDOW}.get(o["kind"], PORTAL)
            reveal = DOOR if o["kind"] == "door" else (WINDOW if o["kind"] == "window" else WALL)
            # Jambs: at s0 facing +t (u = up, v = out), at s1 facing -t (u = out, v = up).
            bld.quad_grid(p0, up, out3, zz, dd, reveal)
            bld.quad_grid(p1, out3, up, dd, zz, reveal)
            # Head faces down (u = t, v = out); sill faces up (u = out, v = t).
            bld.quad_grid(a3 + up * o["z1"], t3, out3, ss, dd, reveal)
            sill_label = FLOOR if o["z0"] <= zf + CUT_EPS and o["kind"] != "window" else reveal
            bld.quad_grid(a3 + up * o["z0"], out3, t3, dd, ss, sill_label)
            # The far end faces the room (u = -t, v = up) at depth d.
            bld.quad_grid(a3 + out3 * d + t3 * o["s1"], -t3, up, np.sort(o["s1"] - ss), zz, back)
    return bld.mesh()


def baseboard_box(
    start: np.ndarray,
    end: np.ndarray,
    inward: np.ndarray,
    floor_z: float,
    height: float,
    depth: float,
) -> trimesh.Trimesh:
    """A closed box along a wall from ``start`` to ``end`` (xy), ``depth`` into the room."""
    a = np.asarray(start, float)
    b = np.asarray(end, float)
    n = np.asarray(inward, float)
    # Sunk 1 mm into the wall and floor so renderers see no crack.
    lo_pts = [a - 0.001 * n, b - 0.001 * n, b + depth * n, a + depth * n]
    corners = np.array(
        [[p[0], p[1], floor_z - 0.001] for p in lo_pts]
        + [[p[0], p[1], floor_z + height] for p in lo_pts]
    )
    faces = np.array(
        [
            [0, 2, 1],
            [0, 3, 2],
            [4, 5, 6],
            [4, 6, 7],
            [0, 1, 5],
            [0, 5, 4],
            [1, 2, 6],
            [1, 6, 5],
            [2, 3, 7],
            [2, 7, 6],
            [3, 0, 4],
            [3, 4, 7],
        ]
    )
    m = trimesh.Trimesh(corners, faces, process=False)
    if m.volume < 0:
        m.invert()
    return m


def empty_room_mesh(layout: dict, in_scan_frame: bool = True) -> tuple[trimesh.Trimesh, np.ndarray]:
    """The empty-room mesh of a ``layout.json`` document, with a label per face.

    Parameters
    ----------
    layout:
        The document written by :func:`reroom.layout.run_layout`.
    in_scan_frame:
        Return it in the scan's (mesh) coordinates, so it lines up with the scan and its
        cameras; else in the aligned Manhattan frame.

    Returns
    -------
    mesh, face_labels
        One closed shell per room (openings tunnelled and closed by their leaf or pane)
        and one closed box per baseboard piece.
    """
    meshes: list[trimesh.Trimesh] = []
    labels: list[np.ndarray] = []
    for room in layout["rooms"]:
        poly = np.asarray(room["polygon"], float)
        shell, lab = room_shell(poly, room["floor_z"], room["ceiling_z"], room.get("openings", []))
        meshes.append(shell)
        labels.append(lab)
        bb = room.get("baseboard")
        if not bb:
            continue
        k = len(poly)
        for piece in bb["pieces"]:
            i = piece["wall"]
            a, b = poly[i], poly[(i + 1) % k]
            length = float(np.linalg.norm(b - a))
            t = (b - a) / length
            n_in = np.array([-t[1], t[0]])
            s0, s1 = piece["s0"], piece["s1"]
            if s1 >= length - 1e-3:
                # Convex corner ahead (left turn): stop short of the next wall's box;
                # reflex corner (right turn): run on to meet it.
                nxt = poly[(i + 2) % k] - b
                left = t[0] * nxt[1] - t[1] * nxt[0] > 0
                s1 = length - bb["depth"] if left else length + bb["depth"]
            if s1 - s0 < 0.02:
                continue
            box = baseboard_box(
                a + t * s0, a + t * s1, n_in, room["floor_z"], bb["height"], max(bb["depth"], 0.005)
            )
            meshes.append(box)
            labels.append(np.full(len(box.faces), BASEBOARD, np.uint8))
    if not meshes:
        return trimesh.Trimesh(), np.zeros(0, np.uint8)
    mesh = trimesh.util.concatenate(meshes)
    if in_scan_frame:
        rot = np.asarray(layout.get("rotation", np.eye(3)), float)
        mesh = trimesh.Trimesh(np.asarray(mesh.vertices) @ rot, mesh.faces, process=False)
    return mesh, np.concatenate(labels)


def _portal_on_wall(
    o: dict, a: np.ndarray, t: np.ndarray, out: np.ndarray, portals: list[tuple[np.ndarray, ...]]
) -> dict | None:
    """The first of ``portals`` (aligned-frame centre, half axes, normal) that closes
    window opening ``o`` of the wall from ``a`` along ``t`` (outward normal ``out``): its
    span ``s0, s1, z0, z1`` and its plane's depth behind the wall line, or None."""
    t3 = np.append(t, 0.0)
    for centre, hu, hv, normal in portals:
        if abs(float(normal[:2] @ out)) < 0.9:
            continue
        s_c = float((centre[:2] - a) @ t)
        depth = float((centre[:2] - a) @ out)
        if not (o["s0"] - 0.3 <= s_c <= o["s1"] + 0.3 and -0.05 <= depth <= 0.6):
            continue
        half_s = abs(float(hu @ t3)) + abs(float(hv @ t3))
        half_z = abs(float(hu[2])) + abs(float(hv[2]))
        return {
            "s0": s_c - half_s,
            "s1": s_c + half_s,
            "z0": float(centre[2]) - half_z,
            "z1": float(centre[2]) + half_z,
            "depth": depth,
        }
    return None


def _grown_room(
    room: dict, gap: float, margin: float, portals: list[tuple[np.ndarray, ...]] | None = None
) -> dict:
    """``room`` with its walls ``gap`` further out, its floor ``gap`` lower, its ceiling
    ``gap`` higher, each opening ``margin`` wider on every side (a window closed by one of
    ``portals``: that rectangle exactly, its reveals reaching from the room's own wall
    plane to the rectangle's), no baseboard."""
    poly = np.asarray(room["polygon"], float)
    k = len(poly)
    edge = np.roll(poly, -1, axis=0) - poly
    t = edge / np.maximum(np.linalg.norm(edge, axis=1, keepdims=True), 1e-12)
    out = np.stack([t[:, 1], -t[:, 0]], axis=1)  # outward normal of a counter-clockwise edge
    prev = np.roll(out, 1, axis=0)
    # The mitre of the two edges meeting at each corner: on both offset lines at once
    # (n1 + n2) / (1 + n1 . n2) is exact for any two unit normals not facing each other.
    shift = gap * (prev + out) / np.maximum(1.0 + np.sum(prev * out, axis=1), 1e-6)[:, None]
    grown = poly + shift
    openings = []
    for o in room.get("openings", []):
        i = int(o["wall"]) % k
        # The edge's start moved along the edge by shift . t: arc lengths follow it.
        ds = float(shift[i] @ t[i])
        depth = abs(float(o.get("depth", 0.05)))
        # A passage's tunnel ends at the next room's backing (gap short of both walls); a
        # door's leaf stays behind the scanned leaf (its recess plus the gap).
        depth = max(depth - 2 * gap, 0.001) if o["kind"] == "passage" else depth + gap + margin
        portal = None
        if o["kind"] == "window" and portals:
            portal = _portal_on_wall(o, poly[i], t[i], out[i], portals)
        if portal is not None:
            # The reveals meet the portal's edges and end at its plane, where the
            # renderer's window is: no gap between them for a camera to see out through.
            # Rounded as room_shell rounds its cut lines (to the micrometre), or a cut
            # would miss the opening's edge and leave its tunnel out. The reveals start
            # at the layout's wall plane, not the shell's: the scan's own reveal faces
            # give way to them, and a camera looking along the wall past the opening's
            # edge met the shell's wall, dark in the gap behind the scan, where the true
            # jamb is lit by the sky (docs/edit.md, "Holes in the scan").
            openings.append(
                {
                    **o,
                    "s0": round(portal["s0"] - ds, CUT_DECIMALS),
                    "s1": round(portal["s1"] - ds, CUT_DECIMALS),
                    "z0": round(portal["z0"], CUT_DECIMALS),
                    "z1": round(portal["z1"], CUT_DECIMALS),
                    "depth": max(portal["depth"] - gap, 0.001),
                    "front": gap,
                }
            )
            continue
        openings.append(
            {
                **o,
                "s0": round(float(o["s0"]) - ds - margin, CUT_DECIMALS),
                "s1": round(float(o["s1"]) - ds + margin, CUT_DECIMALS),
                "z0": round(float(o["z0"]) - margin, CUT_DECIMALS),
                "z1": round(float(o["z1"]) + margin, CUT_DECIMALS),
                "depth": depth,
            }
        )
    return {
        **room,
        "polygon": grown.tolist(),
        "floor_z": float(room["floor_z"]) - gap,
        "ceiling_z": float(room["ceiling_z"]) + gap,
        "openings": openings,
        "baseboard": None,
    }


def backing_shell(
    layout: dict,
    gap: float = 0.02,
    margin: float = 0.05,
    in_scan_frame: bool = True,
    portals: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] | None = None,
) -> tuple[trimesh.Trimesh, np.ndarray]:
    """The layout's rooms as shells ``gap`` metres behind their walls, floor and ceiling,
    open at the windows' panes: what fills the holes of a scanned mesh when it is rendered.

    A fused scan has holes where no frame looked (behind a cabinet, a corner the walk
    missed). Rendered alone they show the renderer's background from a new camera, and
    they let the light out that the true wall would have sent back. Behind the scan, this
    shell is hidden wherever the scan has a surface and shows through where it has none.

    Parameters
    ----------
    layout:
        The ``layout.json`` document.
    gap:
        How far behind the layout's planes the shell lies; larger than the scanned
        surfaces' spread about their planes, so that it never shows through them (a fused
        scan's walls lie within about a centimetre of their planes).
    margin:
        How much wider than the layout's openings the shell's openings are on every side,
        so that a window's recess or a door's leaf, measured a little small, stays in view.
    in_scan_frame:
        As :func:`empty_room_mesh`.
    portals:
        The renderer's window rectangles (centre, half axes, normal; in the scan frame
        when ``in_scan_frame``, else aligned). A window opening one of them closes
        (same wall, centre within 30 cm of the opening's span) takes that rectangle as
        its opening, without the margin, and its reveals end at the rectangle's plane:
        a point of a reveal next to the portal sees it as the true reveal sees the sky
        beside its pane (with the margin's 5 cm gap it got half the light or less). Its
        reveals start at the room's wall plane, ``gap`` in front of the shell's wall, so
        that they stand where the scan's reveals stood.

    Returns
    -------
    mesh, face_labels
        Walls, floor, ceiling, each window's reveals (jambs, head and sill, so that a
        camera looking past a scan's missing reveal does not see out beside the
        window's portal) without its pane (the shell is open there: the window's light
        comes through), each door's tunnel and leaf (behind the scanned door); no
        passage panes (rooms stay joined); no baseboards.
    """
    rot = np.asarray(layout.get("rotation", np.eye(3)), float)
    aligned = [
        tuple(np.asarray(x, float) @ (rot.T if in_scan_frame else np.eye(3)) for x in p)
        for p in portals or []
    ]
    grown = {
        **layout,
        "rooms": [_grown_room(r, gap, margin, aligned) for r in layout["rooms"]],
    }
    mesh, labels = empty_room_mesh(grown, in_scan_frame=False)
    keep = (labels != PORTAL) & ~_window_panes(grown["rooms"], mesh, labels)
    if not keep.any():
        return trimesh.Trimesh(), np.zeros(0, np.uint8)
    vertices = np.asarray(mesh.vertices)
    if in_scan_frame:
        vertices = vertices @ rot
    sub = trimesh.Trimesh(vertices, np.asarray(mesh.faces)[keep], process=False)
    sub.remove_unreferenced_vertices()
    return sub, labels[keep]


def _window_panes(rooms: list[dict], mesh: trimesh.Trimesh, labels: np.ndarray) -> np.ndarray:
    """Which faces of an (aligned-frame) empty-room mesh are the panes closing its
    windows: the window-labelled faces on the plane at each window's depth, facing the
    room, within its span. The reveals (jambs, head, sill) are window-labelled too."""
    pane = np.zeros(len(labels), bool)
    win = labels == WINDOW
    if not win.any():
        return pane
    centres = mesh.triangles_center
    normals = mesh.face_normals
    for room in rooms:
        poly = np.asarray(room["polygon"], float)
        k = len(poly)
        for o in room.get("openings", []):
            if o["kind"] != "window":
                continue
            a, b = poly[int(o["wall"]) % k], poly[(int(o["wall"]) + 1) % k]
            t = np.append((b - a) / np.linalg.norm(b - a), 0.0)
            out = np.array([t[1], -t[0], 0.0])
            rel = centres - np.append(a, 0.0)
            depth = max(0.001, abs(float(o.get("depth", 0.05))))
            along = rel @ t
            pane |= (
                win
                & (np.abs(rel @ out - depth) < 1e-6)
                & (normals @ out < -0.99)
                & (along > float(o["s0"]) - 1e-6)
                & (along < float(o["s1"]) + 1e-6)
            )
    return pane


def _wall_coordinates(
    poly: np.ndarray, k: int, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float]:
    """Points' arc length along wall ``k`` of a counter-clockwise outline (from corner
    ``k`` to corner ``k + 1``, the room on its left), their depth behind its plane
    (positive away from the room), and the wall's length."""
    a, b = poly[k], poly[(k + 1) % len(poly)]
    length = float(np.linalg.norm(b - a))
    t = (b - a) / max(length, 1e-12)
    rel = np.asarray(points, float)[:, :2] - a
    return rel @ t, rel @ np.array([t[1], -t[0]]), length


def depth_behind_planes(
    room: dict, points: np.ndarray, labels: np.ndarray, quantile: float = 0.999
) -> float:
    """How far a scan's wall, floor and ceiling points lie behind one room's planes.

    Parameters
    ----------
    room:
        A room of ``layout.json`` (aligned frame).
    points:
        ``(N, 3)`` scan vertices in the aligned frame.
    labels:
        ``(N,)`` their layout labels (``WALL``, ``FLOOR``, ``CEILING``; others ignored).
    quantile:
        Which quantile of the distances out to return.

    Returns
    -------
    float
        The ``quantile`` of the distances (metres) of the labelled points out of their
        plane (a wall point: out of the nearest wall line it lies along, 5 cm clear of
        the wall's ends so that the next wall's points at a corner do not count; a floor
        or ceiling point inside the outline: below the floor, above the ceiling); 0 when
        none lies out.
    """
    from reroom.synth.room import point_in_polygon

    pts = np.asarray(points, float)
    lab = np.asarray(labels)
    poly = np.asarray(room["polygon"], float)
    k = len(poly)
    outs = []
    walls = pts[lab == WALL]
    for i in range(k):
        along, out, length = _wall_coordinates(poly, i, walls)
        near = (along > 0.05) & (along < length - 0.05) & (out > -0.3) & (out < 0.5)
        outs.append(out[near])
    for label, sign, level in ((FLOOR, -1.0, room["floor_z"]), (CEILING, 1.0, room["ceiling_z"])):
        sel = pts[lab == label]
        inside = point_in_polygon(sel[:, 0], sel[:, 1], poly) if len(sel) else np.zeros(0, bool)
        outs.append(sign * (sel[inside, 2] - float(level)))
    d = np.concatenate(outs) if outs else np.zeros(0)
    if len(d) == 0:
        return 0.0
    return float(max(np.quantile(d, quantile), 0.0))


def reveal_points(
    room: dict, points: np.ndarray, labels: np.ndarray, near: float = 0.04
) -> np.ndarray:
    """Which of a scan's window-labelled points lie on one room's window reveals.

    A fused scan rounds a reveal's edges over a voxel or two (on the issue's
    3 cm-voxel ``furnished`` scan the jamb the walk never saw is a bevel facing halfway
    between the wall and the jamb, its per-vertex albedo up to 2.7), and the layout's
    shell has the reveal's planes. The points this marks are those a renderer can
    leave to the shell.

    Parameters
    ----------
    room:
        A room of ``layout.json`` (aligned frame).
    points:
        ``(N, 3)`` scan vertices in the aligned frame.
    labels:
        ``(N,)`` their layout labels (only ``WINDOW`` points can be marked).
    near:
        How close (metres) to a reveal's surface a point must lie: a jamb, the sill or
        the head (within the opening's depth), or the wall's plane beside the opening.

    Returns
    -------
    np.ndarray
        ``(N,)`` bool. Points of the opening further than ``near`` from all of those (an
        object standing on the sill, a pane or frame at the far end) are not marked.
    """
    pts = np.asarray(points, float)
    out = np.zeros(len(pts), bool)
    win = np.asarray(labels) == WINDOW
    if not win.any():
        return out
    poly = np.asarray(room.get("polygon", np.zeros((0, 2))), float).reshape(-1, 2)
    for o in room.get("openings", []):
        k = int(o.get("wall", -1))
        if o.get("kind") != "window" or not 0 <= k < len(poly):
            continue
        s, d, _ = _wall_coordinates(poly, k, pts)
        z = pts[:, 2]
        s0, s1, z0, z1 = (float(o[k]) for k in ("s0", "s1", "z0", "z1"))
        depth = max(float(o.get("depth", 0.0)), 0.0)
        box = (
            (s > s0 - near) & (s < s1 + near) & (z > z0 - near) & (z < z1 + near)
            & (d > -near) & (d < depth + near)
        )  # fmt: skip
        to_reveal = np.minimum.reduce(
            [np.abs(s - s0), np.abs(s - s1), np.abs(z - z0), np.abs(z - z1), np.abs(d)]
        )
        out |= win & box & (to_reveal < near)
    return out
