"""Cheap synthetic scans for the HDR stage's tests and speed benchmark.

Frames are rendered by *projection*, not path tracing: each pixel's ray is cast
at the mesh, the known per-vertex radiance is interpolated over the triangle it
hits, multiplied by the frame's scale (given, or chosen by the simulated
auto-exposure camera of :mod:`reroom.synth.camera_sim`), optionally made noisy,
encoded by the response curve and quantised to 8 bits. The radiance a frame
shows is then *exactly* the per-vertex truth (up to interpolation), which makes
these scans right for exact tests and for timing at any size, and wrong for
judging accuracy on realistic light transport (use ``reroom synth`` for that).

The scan is written in the usual format, with a ``ground_truth/`` folder in the
format of ``docs/formats.md`` (``ground_truth.json`` with per-frame ``scale``;
``vertices.ply`` with ``radiance``, ``radiance_stderr`` = 0 and ``label``), so
:mod:`reroom.hdr.evaluate` reads it like a generated scan's.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import trimesh

from reroom.io.atomic import atomic_write_json
from reroom.io.mesh import write_ply
from reroom.rays import RayCaster
from reroom.scan import Frame, Intrinsics, write_scan
from reroom.synth.camera_sim import AutoCamera, CameraModel, apply_response
from reroom.synth.labels import LABELS

__all__ = ["box_room", "render_projected", "write_projected_scan"]


def render_projected(
    caster: RayCaster,
    radiance: np.ndarray,
    c2w: np.ndarray,
    intrinsics: Intrinsics,
) -> np.ndarray:
    """Linear ``(H, W, 3)`` image of per-vertex ``radiance`` seen from ``c2w`` (0 where no hit)."""
    fr = Frame(0, Path(), np.asarray(c2w, np.float64), intrinsics)
    o, d = fr.pixel_rays()
    hits = caster.intersect(o, d)
    tri = caster.faces[np.maximum(hits.face, 0)]
    img = np.einsum("ij,ijk->ik", hits.barycentric, np.asarray(radiance, np.float64)[tri])
    img[~hits.hit] = 0.0
    return img.reshape(intrinsics.height, intrinsics.width, 3)


def write_projected_scan(
    out: str | Path,
    vertices: np.ndarray,
    faces: np.ndarray,
    radiance: np.ndarray,
    poses: Sequence[np.ndarray],
    intrinsics: Intrinsics,
    *,
    scales: np.ndarray | None = None,
    camera: CameraModel | None = None,
    response: str = "gamma2.2",
    noise_seed: int | None = 0,
    labels: np.ndarray | None = None,
    images_override: dict[int, np.ndarray] | None = None,
    mesh_vertices: np.ndarray | None = None,
    mesh_faces: np.ndarray | None = None,
    progress=None,
) -> Path:
    """Render frames by projection and write a scan with ground truth.

    Parameters
    ----------
    out:
        Scan folder to write.
    vertices, faces, radiance:
        The true surface and its per-vertex linear radiance ``(V, 3)``.
    poses, intrinsics:
        Camera-to-world matrices (OpenGL axes) and shared intrinsics.
    scales:
        ``(F, 3)`` per-frame per-channel scales; default: chosen by the simulated
        auto-exposure camera (``camera``).
    camera:
        The simulated camera model (noise, AE speed); with ``scales`` only its
        noise settings are used.
    response:
        Response curve applied before 8-bit quantisation.
    noise_seed:
        Seed of the sensor noise; ``None`` for no noise at all.
    labels:
        Per-vertex label ids for the ground truth (default: all walls).
    images_override:
        Replace the rendered image of some frames (``{index: uint8 image}``), to
        make bad inputs (black, saturated frames).
    mesh_vertices, mesh_faces:
        The mesh written as the scan's mesh if it differs from the true surface
        (e.g. with holes); it must share the true surface's vertex order.
    """
    out = Path(out)
    caster = RayCaster(vertices, faces)
    model = camera or CameraModel(response=response, noise=noise_seed is not None)
    model = CameraModel(**{**model.to_json(), "response": response})
    rng = np.random.default_rng(noise_seed if noise_seed is not None else 0)
    cam = AutoCamera(model, rng)
    used: list[list[float]] = []
    overrides = images_override or {}

    def frames() -> Iterator[np.ndarray]:
        for j, c2w in enumerate(poses):
            lin = render_projected(caster, radiance, c2w, intrinsics)
            if scales is None:
                img, scale, _, _ = cam.capture(lin)
            else:
                scale = np.asarray(scales[j], np.float64)
                x = lin * scale
                if model.noise:
                    sigma = np.sqrt(np.minimum(x, 1.5) / model.full_well + model.read_noise**2)
                    x = x + rng.standard_normal(x.shape) * sigma
                img = np.clip(np.round(apply_response(x, response) * 255.0), 0, 255).astype(
                    np.uint8
                )
            used.append(np.asarray(scale, np.float64).tolist())
            if progress is not None:
                progress("render frames", j + 1, len(poses))
            yield overrides.get(j, img)

    mv = vertices if mesh_vertices is None else mesh_vertices
    mf = faces if mesh_faces is None else mesh_faces
    mesh = trimesh.Trimesh(mv, mf, process=False)
    write_scan(out, mesh, intrinsics, poses, frames(), meta={"reroom": {"response": response}})
    lab = np.zeros(len(vertices), np.uint8) if labels is None else np.asarray(labels, np.uint8)
    gt = out / "ground_truth"
    write_ply(
        gt / "vertices.ply",
        trimesh.Trimesh(mv, mf, process=False),
        {
            "label": lab,
            "radiance": np.asarray(radiance, np.float64),
            "radiance_stderr": np.zeros((len(vertices), 3)),
        },
    )
    atomic_write_json(
        gt / "ground_truth.json",
        {
            "format": "reroom-ground-truth",
            "version": 1,
            "preset": "projected",
            "frames": [{"index": j, "scale": s} for j, s in enumerate(used)],
            "labels": dict(LABELS),
            "mesh": {"kind": "projected", "vertices": len(mv), "faces": len(mf)},
        },
    )
    return out


def _grid(origin, du, dv, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """A planar grid of triangles spanning ``origin + [0,1] du + [0,1] dv`` (normal du x dv)."""
    du, dv = np.asarray(du, float), np.asarray(dv, float)
    nu = max(1, round(np.linalg.norm(du) / spacing))
    nv = max(1, round(np.linalg.norm(dv) / spacing))
    a, b = np.meshgrid(np.linspace(0, 1, nu + 1), np.linspace(0, 1, nv + 1), indexing="ij")
    verts = np.asarray(origin, float) + a.reshape(-1, 1) * du + b.reshape(-1, 1) * dv
    idx = np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1)
    q0, q1 = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    q2, q3 = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([q0, q1, q2], 1), np.stack([q0, q2, q3], 1)])
    return verts, faces


def _box(lo, hi, spacing: float, inward: bool) -> list[tuple[np.ndarray, np.ndarray]]:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    ex = np.diag(hi - lo)
    out = []
    for axis in range(3):
        u, v = ex[(axis + 1) % 3], ex[(axis + 2) % 3]
        # Face at the low end has outward normal -axis; u x v points along +axis.
        for at_hi in (False, True):
            origin = lo + (ex[axis] if at_hi else 0.0)
            outward_is_uv = at_hi
            if outward_is_uv != inward:
                out.append(_grid(origin, u, v, spacing))
            else:
                out.append(_grid(origin, v, u, spacing))
    return out


def box_room(
    size: tuple[float, float, float] = (4.0, 3.0, 2.5),
    spacing: float = 0.25,
    obstacle: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """A closed box room of planar grids (normals into the room), optionally with a box inside.

    Returns ``(vertices, faces)``; the room spans ``[0, sx] x [0, sy] x [0, sz]``;
    the obstacle is a ``0.6 x 0.6 x 0.8`` m box on the floor with outward normals.
    """
    parts = _box((0, 0, 0), size, spacing, inward=True)
    if obstacle:
        c = (size[0] * 0.55, size[1] * 0.5)
        parts += _box((c[0] - 0.3, c[1] - 0.3, 0.0), (c[0] + 0.3, c[1] + 0.3, 0.8), spacing, False)
    verts, faces, off = [], [], 0
    for v, f in parts:
        verts.append(v)
        faces.append(f + off)
        off += len(v)
    return np.vstack(verts), np.vstack(faces)
