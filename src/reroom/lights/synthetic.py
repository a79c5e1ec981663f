"""A small projected scan with a specular highlight, for light detection's tests and benchmark.

A 4 x 3 x 2.5 m box room with a ceiling panel (a diffuse emitter, the same radiance
from every direction) and a glossy table whose top reflects it: each pixel that sees
the top gets, besides its diffuse radiance, a Gaussian lobe around the mirror
direction of the panel (width ``lobe_deg``). The camera path lingers on the mirror
side of the table, as a person scanning a desk does, so that the HDR stage's
per-vertex median makes the highlight look like a light; only the frames seen one
by one show that it is bright from some directions and not others.

Frames are rendered by projection (like :mod:`reroom.hdr.synthetic`, with a
view-dependent term added) with fixed per-frame exposures, noise and 8-bit gamma 2.2.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from reroom.io.atomic import atomic_write_json
from reroom.rays import RayCaster
from reroom.scan import Frame, Intrinsics, look_at, write_scan
from reroom.synth.camera_sim import apply_response
from reroom.synth.geometry import Piece, box, grid_rect

__all__ = ["HIGHLIGHT_SCENE", "highlight_scan"]

#: Where things are (metres), for tests and evaluation.
HIGHLIGHT_SCENE = {
    "room": (4.0, 3.0, 2.5),
    "panel": {"lo": (0.7, 1.2), "hi": (1.3, 1.8), "z": 2.48, "radiance": 20.0},
    "table": {"lo": (2.0, 1.0), "hi": (3.2, 2.0), "z": 0.75},
}


def _room(h: float) -> tuple[Piece, np.ndarray, np.ndarray]:
    """The room's pieces, per-vertex diffuse radiance and a 'table top' flag."""
    sx, sy, sz = HIGHLIGHT_SCENE["room"]
    ex, ey, ez = np.eye(3)
    shell = [
        (grid_rect([0, 0, 0], ex, ey, sx, sy, h), 0.20),  # floor, normal +z
        (grid_rect([0, 0, sz], ey, ex, sy, sx, h), 0.25),  # ceiling, -z
        (grid_rect([0, 0, 0], ez, ex, sz, sx, h), 0.30),  # wall y = 0, +y
        (grid_rect([0, sy, 0], ex, ez, sx, sz, h), 0.30),  # wall y = sy, -y
        (grid_rect([0, 0, 0], ey, ez, sy, sz, h), 0.30),  # wall x = 0, +x
        (grid_rect([sx, 0, 0], ez, ey, sz, sy, h), 0.30),  # wall x = sx, -x
    ]
    p = HIGHLIGHT_SCENE["panel"]
    (x0, y0), (x1, y1) = p["lo"], p["hi"]
    panel = grid_rect([x0, y0, p["z"]], ey, ex, y1 - y0, x1 - x0, h / 2)
    t = HIGHLIGHT_SCENE["table"]
    (tx0, ty0), (tx1, ty1) = t["lo"], t["hi"]
    table = box([tx0, ty0, 0.0], [tx1, ty1, t["z"]], h / 2, skip=("-z",))
    pieces = [s for s, _ in shell] + [panel, table]
    levels = [r for _, r in shell] + [p["radiance"], 0.05]
    mesh = Piece.concat(pieces)
    radiance = np.concatenate(
        [np.full(len(s.vertices), r) for s, r in zip(pieces, levels, strict=True)]
    )
    tv = table.vertices
    top = np.concatenate(
        [np.zeros(len(mesh.vertices) - len(tv), bool), np.abs(tv[:, 2] - t["z"]) < 1e-6]
    )
    return mesh, np.repeat(radiance[:, None], 3, axis=1), top


def _poses(n_frames: int) -> list[np.ndarray]:
    """Most frames from the mirror side of the table, some from elsewhere, some of the panel."""
    t = HIGHLIGHT_SCENE["table"]
    centre = np.array([(t["lo"][0] + t["hi"][0]) / 2, (t["lo"][1] + t["hi"][1]) / 2, t["z"]])
    panel = HIGHLIGHT_SCENE["panel"]
    pc = np.array([(panel["lo"][0] + panel["hi"][0]) / 2, (panel["lo"][1] + panel["hi"][1]) / 2])
    poses = []
    n_mirror = n_frames // 2
    n_other = n_frames // 4
    n_panel = n_frames - n_mirror - n_other
    for k in range(n_mirror):  # the mirror side: +x of the table, looking back at it
        a = np.deg2rad(-35 + 70 * k / max(n_mirror - 1, 1))
        eye = centre + np.array([0.95 * np.cos(a), 0.95 * np.sin(a), 0.0])
        eye[2] = 1.55
        poses.append(look_at(eye, centre + [0.0, 0.0, 0.05 * np.sin(3 * k)]))
    for k in range(n_other):  # the other sides
        a = np.deg2rad(110 + 140 * k / max(n_other - 1, 1))
        eye = centre + np.array([1.1 * np.cos(a), 1.1 * np.sin(a), 0.0])
        eye[2] = 1.6
        poses.append(look_at(eye, centre))
    for k in range(n_panel):  # looking up at the panel from around the room
        a = 2 * np.pi * k / n_panel
        eye = np.array([2.0 + 1.2 * np.cos(a), 1.5 + 0.8 * np.sin(a), 1.5])
        poses.append(look_at(eye, np.array([pc[0], pc[1], 2.3])))
    return poses


def highlight_scan(
    out: str | Path,
    n_frames: int = 24,
    width: int = 96,
    height: int = 72,
    spacing: float = 0.1,
    lobe_deg: float = 25.0,
    peak: float = 10.0,
    seed: int = 0,
) -> Path:
    """Write the highlight scan (frames, mesh, ``ground_truth/highlight.json``).

    Parameters
    ----------
    out:
        Scan folder.
    n_frames, width, height:
        Frames and their size.
    spacing:
        Mesh edge length of the room (the panel and table are twice as fine).
    lobe_deg:
        Standard deviation of the highlight lobe around the mirror direction, degrees.
    peak:
        Radiance added at the lobe's centre (the panel's radiance times the
        table's specular reflectance).
    seed:
        Seed of the sensor noise and the exposures.
    """
    out = Path(out)
    piece, radiance, top = _room(spacing)
    caster = RayCaster(piece.vertices, piece.faces)
    f = 0.5 * height / np.tan(np.deg2rad(30.0))
    intr = Intrinsics(width, height, f, f, width / 2, height / 2)
    rng = np.random.default_rng(seed)
    poses = _poses(n_frames)
    scales = np.exp(rng.normal(0.0, 0.25, n_frames))
    panel = HIGHLIGHT_SCENE["panel"]
    pc = np.array(
        [(panel["lo"][0] + panel["hi"][0]) / 2, (panel["lo"][1] + panel["hi"][1]) / 2, panel["z"]]
    )
    tz = HIGHLIGHT_SCENE["table"]["z"]
    sigma = np.deg2rad(lobe_deg)

    def frames():
        for j, c2w in enumerate(poses):
            fr = Frame(j, Path(), c2w, intr)
            o, d = fr.pixel_rays()
            hits = caster.intersect(o, d)
            tri = caster.faces[np.maximum(hits.face, 0)]
            lin = np.einsum("ij,ijk->ik", hits.barycentric, radiance[tri])
            on_top = hits.hit & top[tri].all(axis=1)
            p = hits.points[on_top]
            # Mirror direction of the panel centre about the table's normal (+z).
            inc = p - pc
            inc /= np.linalg.norm(inc, axis=1, keepdims=True)
            refl = inc * [1.0, 1.0, -1.0]
            view = -d[on_top]
            ang = np.arccos(np.clip(np.sum(refl * view, axis=1), -1.0, 1.0))
            lin[on_top] += peak * np.exp(-0.5 * (ang / sigma) ** 2)[:, None]
            lin[~hits.hit] = 0.0
            x = lin * scales[j]
            x = x + rng.standard_normal(x.shape) * np.sqrt(np.minimum(x, 1.5) / 4000 + 1e-6)
            img = np.clip(np.round(apply_response(x, "gamma2.2") * 255), 0, 255).astype(np.uint8)
            yield img.reshape(height, width, 3)

    mesh = trimesh.Trimesh(piece.vertices, piece.faces, process=False)
    write_scan(out, mesh, intr, poses, frames(), meta={"reroom": {"response": "gamma2.2"}})
    atomic_write_json(
        out / "ground_truth" / "highlight.json",
        {
            "scene": HIGHLIGHT_SCENE,
            "table_top_z": tz,
            "lobe_deg": lobe_deg,
            "peak": peak,
            "scales": scales.tolist(),
        },
    )
    return out
