"""Triangle-mesh primitives for synthetic rooms, each face with consistent normals.

Planar pieces are regular grids whose lines pass through every opening edge
(so openings cut cells exactly and the mesh stays watertight around them) and
whose spacing is at most ``h`` -- a room built this way has the dense,
fairly even vertex distribution of a scanned mesh, which the per-vertex stages
(HDR, inverse rendering) need.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

Hole = tuple[float, float, float, float]  # (u0, u1, v0, v1) in the rectangle's own coordinates


@dataclass
class Piece:
    """A triangle mesh with per-vertex normals and texture coordinates."""

    vertices: np.ndarray  # (N, 3)
    faces: np.ndarray  # (M, 3)
    normals: np.ndarray  # (N, 3) unit vertex normals
    uv: np.ndarray  # (N, 2)

    @staticmethod
    def concat(pieces: Sequence[Piece]) -> Piece:
        verts, faces, normals, uvs = [], [], [], []
        offset = 0
        for p in pieces:
            verts.append(p.vertices)
            faces.append(p.faces + offset)
            normals.append(p.normals)
            uvs.append(p.uv)
            offset += len(p.vertices)
        return Piece(np.vstack(verts), np.vstack(faces), np.vstack(normals), np.vstack(uvs))

    def transformed(self, matrix: np.ndarray) -> Piece:
        """Apply a 4x4 rigid (or uniformly scaled) transform."""
        r = matrix[:3, :3]
        n = self.normals @ np.linalg.inv(r)
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        return Piece(self.vertices @ r.T + matrix[:3, 3], self.faces.copy(), n, self.uv.copy())


def _breaks(length: float, h: float, cuts: Sequence[float]) -> np.ndarray:
    """Sorted grid coordinates on [0, length]: every cut, then each interval split to <= h."""
    pts = sorted({0.0, float(length), *(float(c) for c in cuts if 0.0 < c < length)})
    out = [pts[0]]
    for a, b in zip(pts[:-1], pts[1:], strict=True):
        if b - a < 1e-9:
            continue
        n = max(1, int(np.ceil((b - a) / h - 1e-9)))
        out.extend(np.linspace(a, b, n + 1)[1:].tolist())
    return np.asarray(out)


def grid_rect(
    origin: Sequence[float],
    u_axis: Sequence[float],
    v_axis: Sequence[float],
    u_len: float,
    v_len: float,
    h: float,
    holes: Sequence[Hole] = (),
    keep: Callable[[float, float], bool] | None = None,
    uv_scale: float = 1.0,
) -> Piece:
    """A planar rectangle ``origin + s u + t v`` (s in [0, u_len], t in [0, v_len]).

    The normal is ``u x v`` (callers choose the axes so that it faces the room).
    Cells whose centre lies in a ``hole`` ``(u0, u1, v0, v1)`` are removed, as are
    cells for which ``keep(s, t)`` (cell centre) is False. Texture coordinates are
    ``(s, t) * uv_scale`` in metres.
    """
    o = np.asarray(origin, float)
    u = np.asarray(u_axis, float) / np.linalg.norm(u_axis)
    v = np.asarray(v_axis, float) / np.linalg.norm(v_axis)
    su = _breaks(u_len, h, [c for hole in holes for c in hole[:2]])
    sv = _breaks(v_len, h, [c for hole in holes for c in hole[2:]])
    ss, tt = np.meshgrid(su, sv, indexing="ij")  # (nu, nv)
    nu, nv = ss.shape
    idx = np.arange(nu * nv).reshape(nu, nv)
    cs = 0.5 * (su[:-1] + su[1:])
    ct = 0.5 * (sv[:-1] + sv[1:])
    cs_g, ct_g = np.meshgrid(cs, ct, indexing="ij")
    mask = np.ones(cs_g.shape, bool)
    for u0, u1, v0, v1 in holes:
        mask &= ~((cs_g > u0) & (cs_g < u1) & (ct_g > v0) & (ct_g < v1))
    if keep is not None:
        mask &= np.vectorize(keep)(cs_g, ct_g).astype(bool)
    a = idx[:-1, :-1][mask]
    b = idx[1:, :-1][mask]
    c = idx[1:, 1:][mask]
    d = idx[:-1, 1:][mask]
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    used = np.unique(faces)
    remap = -np.ones(nu * nv, np.int64)
    remap[used] = np.arange(len(used))
    verts = o + ss.ravel()[used, None] * u + tt.ravel()[used, None] * v
    normal = np.cross(u, v)
    normals = np.broadcast_to(normal, verts.shape).copy()
    uv = np.stack([ss.ravel()[used], tt.ravel()[used]], 1) * uv_scale
    return Piece(verts, remap[faces], normals, uv)


def box(lo: Sequence[float], hi: Sequence[float], h: float, skip: Sequence[str] = ()) -> Piece:
    """An axis-aligned box with outward normals; ``skip`` drops faces ('-z', '+x', ...)."""
    lo = np.asarray(lo, float)
    hi = np.asarray(hi, float)
    dx, dy, dz = hi - lo
    ex, ey, ez = np.eye(3)
    faces = {
        "-z": (lo, ey, ex, dy, dx),
        "+z": (np.array([lo[0], lo[1], hi[2]]), ex, ey, dx, dy),
        "-y": (lo, ex, ez, dx, dz),
        "+y": (np.array([lo[0], hi[1], lo[2]]), ez, ex, dz, dx),
        "-x": (lo, ez, ey, dz, dy),
        "+x": (np.array([hi[0], lo[1], lo[2]]), ey, ez, dy, dz),
    }
    pieces = [
        grid_rect(o, a, b, la, lb, h) for k, (o, a, b, la, lb) in faces.items() if k not in skip
    ]
    return Piece.concat(pieces)


def frustum_shell(
    center: Sequence[float],
    r_bottom: float,
    r_top: float,
    height: float,
    thickness: float,
    sections: int = 48,
    rings: int = 6,
    split: bool = False,
) -> Piece | tuple[Piece, Piece]:
    """A lamp shade: a truncated cone open at both ends, with an outer and an inner wall.

    Both walls carry their own vertices (outer normals point out, inner ones in)
    so that the brightly lit inside and the darker outside each get radiance.
    The two rims close the wall thickness. With ``split`` the result is
    ``(outside and rims, lining)`` so the lining can get its own material.
    """
    c = np.asarray(center, float)
    ang = np.linspace(0, 2 * np.pi, sections, endpoint=False)
    zs = np.linspace(0, height, rings + 1)
    pieces = []
    slope = (r_bottom - r_top) / height
    for sign, dr in ((1, 0.0), (-1, -thickness)):
        radii = r_bottom + dr + (r_top - r_bottom) * zs / height
        pts = []
        nrm = []
        uv = []
        for zi, ri in zip(zs, radii, strict=True):
            for a in ang:
                pts.append(c + [ri * np.cos(a), ri * np.sin(a), zi])
                n = np.array([np.cos(a), np.sin(a), slope]) * sign
                nrm.append(n / np.linalg.norm(n))
                uv.append([a / (2 * np.pi), zi])
        pts = np.array(pts)
        faces = []
        for i in range(rings):
            for j in range(sections):
                a0 = i * sections + j
                a1 = i * sections + (j + 1) % sections
                b0 = a0 + sections
                b1 = a1 + sections
                faces += [[a0, a1, b1], [a0, b1, b0]] if sign > 0 else [[a0, b1, a1], [a0, b0, b1]]
        pieces.append(Piece(pts, np.array(faces), np.array(nrm), np.array(uv)))
    for z, r, nz in ((0.0, r_bottom, -1.0), (height, r_top, 1.0)):
        outer = np.stack(
            [c[0] + r * np.cos(ang), c[1] + r * np.sin(ang), np.full_like(ang, c[2] + z)], 1
        )
        inner = np.stack(
            [
                c[0] + (r - thickness) * np.cos(ang),
                c[1] + (r - thickness) * np.sin(ang),
                np.full_like(ang, c[2] + z),
            ],
            1,
        )
        pts = np.vstack([outer, inner])
        faces = []
        for j in range(sections):
            k = (j + 1) % sections
            tri = [[j, k, sections + k], [j, sections + k, sections + j]]
            faces += tri if nz > 0 else [t[::-1] for t in tri]
        pieces.append(
            Piece(
                pts,
                np.array(faces),
                np.tile([0.0, 0.0, nz], (len(pts), 1)),
                np.zeros((len(pts), 2)),
            )
        )
    if split:
        return Piece.concat([pieces[0], pieces[2], pieces[3]]), pieces[1]
    return Piece.concat(pieces)


def cylinder(
    p0: Sequence[float],
    p1: Sequence[float],
    radius: float,
    sections: int = 24,
    caps: bool = True,
    h: float = 0.1,
) -> Piece:
    """A closed cylinder between ``p0`` and ``p1`` with outward normals (smooth side)."""
    p0 = np.asarray(p0, float)
    p1 = np.asarray(p1, float)
    axis = p1 - p0
    length = float(np.linalg.norm(axis))
    w = axis / length
    a = np.cross(w, [1.0, 0, 0]) if abs(w[0]) < 0.9 else np.cross(w, [0, 1.0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(w, a)
    ang = np.linspace(0, 2 * np.pi, sections, endpoint=False)
    nz = max(1, int(np.ceil(length / h)))
    ts = np.linspace(0, length, nz + 1)
    ring = np.cos(ang)[:, None] * a + np.sin(ang)[:, None] * b  # (S, 3)
    pts = (p0 + ts[:, None, None] * w + radius * ring[None]).reshape(-1, 3)
    nrm = np.broadcast_to(ring[None], (nz + 1, sections, 3)).reshape(-1, 3)
    uv = np.stack(np.meshgrid(ang / (2 * np.pi), ts, indexing="xy"), -1).reshape(-1, 2)
    faces = []
    for i in range(nz):
        for j in range(sections):
            k = (j + 1) % sections
            a0, a1 = i * sections + j, i * sections + k
            faces += [[a0, a1, a1 + sections], [a0, a1 + sections, a0 + sections]]
    pieces = [Piece(pts, np.array(faces), nrm.copy(), uv)]
    if caps:
        for end, sgn in ((p0, -1.0), (p1, 1.0)):
            cpts = np.vstack([end, end + radius * ring])
            # (ring_j, ring_j+1) runs counter-clockwise about w, so this order faces +w
            f = [
                [0, 1 + j, 1 + (j + 1) % sections]
                if sgn > 0
                else [0, 1 + (j + 1) % sections, 1 + j]
                for j in range(sections)
            ]
            pieces.append(
                Piece(cpts, np.array(f), np.tile(sgn * w, (len(cpts), 1)), np.zeros((len(cpts), 2)))
            )
    return Piece.concat(pieces)


@dataclass
class Part:
    """A named piece of the scene with its semantic label, material and optional emission.

    ``material`` is a small dict: ``{"type": "diffuse", "albedo": [r, g, b]}``,
    ``{"type": "diffuse", "texture": "wood_floor.png", "albedo": mean}`` or
    ``{"type": "roughplastic", "albedo": [...], "alpha": 0.15}`` or
    ``{"type": "black"}`` (light-absorbing). ``emission`` is ``None`` or the
    linear RGB radiance of a diffuse area emitter.
    """

    name: str
    piece: Piece
    label: str
    material: dict
    emission: list[float] | None = None
    in_scan: bool = True  # False: rendered but not part of the scanned mesh (e.g. window portals)
    extra: dict = field(default_factory=dict)
