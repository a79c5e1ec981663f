"""Per-vertex ground truth of a generated scan: labels, albedo, part ids.

For the clean mesh these come straight from the parts. For a scanner-like mesh
(corrupted or fused), each vertex is mapped to the true surface by a ray cast
along its normal (both directions) against the clean geometry, falling back to
the nearest clean vertex, so the truth refers to the surface the vertex stands
for.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from reroom.synth.labels import LABELS


@dataclass
class CleanSurface:
    """The true scanned surface: every in-scan part concatenated, with per-vertex truth."""

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    uv: np.ndarray
    part: np.ndarray  # (N,) index into desc["parts"]
    label: np.ndarray  # (N,) uint8
    albedo: np.ndarray  # (N, 3) linear diffuse albedo


def _texture_lookup(desc: dict, scene_dir: Path, tex_name: str, uv: np.ndarray) -> np.ndarray:
    """Evaluate a bitmap texture exactly as Mitsuba does (same filter and wrap)."""
    from reroom.render import mitsuba

    mi = mitsuba()
    import drjit as dr

    tex = desc["textures"][tex_name]
    s = 1.0 / tex["metres_per_tile"]
    t = mi.load_dict(
        {
            "type": "bitmap",
            "filename": str(scene_dir / tex["file"]),
            "raw": True,
            "filter_type": "bilinear",
            "wrap_mode": "repeat",
            "to_uv": mi.ScalarTransform4f().scale([s, s, 1.0]),
        }
    )
    si = dr.zeros(mi.SurfaceInteraction3f, len(uv))
    si.uv = mi.Point2f(uv[:, 0].astype(np.float32), uv[:, 1].astype(np.float32))
    val = t.eval(si)
    arr = np.asarray(val, dtype=np.float64)
    return arr.T if arr.shape[0] == 3 and arr.ndim == 2 and arr.shape[1] != 3 else arr


def part_albedo(desc: dict, scene_dir: Path, part: dict, uv: np.ndarray) -> np.ndarray:
    """True diffuse albedo of a part at texture coordinates ``uv``."""
    mat = part["material"]
    if mat["type"] == "black":
        return np.zeros((len(uv), 3))
    if mat.get("texture"):
        return _texture_lookup(desc, scene_dir, mat["texture"], uv)
    return np.tile(np.asarray(mat["albedo"], float), (len(uv), 1))


def clean_surface(desc: dict, scene_dir: str | Path) -> CleanSurface:
    """Concatenate the in-scan parts of a scene description, with their per-vertex truth."""
    from plyfile import PlyData

    scene_dir = Path(scene_dir)
    vs, fs, ns, uvs, pids, labels, albedos = [], [], [], [], [], [], []
    offset = 0
    for i, part in enumerate(desc["parts"]):
        if not part["in_scan"]:
            continue
        ply = PlyData.read(str(scene_dir / part["file"]))
        v = ply["vertex"].data
        xyz = np.stack([v["x"], v["y"], v["z"]], 1).astype(np.float64)
        nrm = np.stack([v["nx"], v["ny"], v["nz"]], 1).astype(np.float64)
        uv = np.stack([v["u"], v["v"]], 1).astype(np.float64)
        f = np.vstack(ply["face"].data["vertex_indices"]).astype(np.int64)
        vs.append(xyz)
        ns.append(nrm)
        uvs.append(uv)
        fs.append(f + offset)
        pids.append(np.full(len(xyz), i, np.int32))
        labels.append(np.full(len(xyz), LABELS[part["label"]], np.uint8))
        albedos.append(part_albedo(desc, scene_dir, part, uv))
        offset += len(xyz)
    return CleanSurface(
        np.vstack(vs),
        np.vstack(fs),
        np.vstack(ns),
        np.vstack(uvs),
        np.concatenate(pids),
        np.concatenate(labels),
        np.vstack(albedos),
    )


def transfer_truth(
    clean: CleanSurface,
    desc: dict,
    scene_dir: str | Path,
    vertices: np.ndarray,
    normals: np.ndarray,
    reach: float = 0.05,
) -> dict[str, Any]:
    """Map per-vertex truth from the clean surface onto another mesh's vertices.

    Each vertex casts rays along ``+-normal`` (up to ``reach`` metres); the
    nearer hit gives the part, label and (texture-interpolated) albedo and the
    point on the true surface. Vertices with no hit take the nearest clean
    vertex's truth. Returns arrays ``part, label, albedo, surface_point,
    distance`` (distance to the true surface) and ``matched_by_ray``.
    """
    from scipy.spatial import cKDTree

    from reroom.rays import RayCaster

    scene_dir = Path(scene_dir)
    caster = RayCaster(clean.vertices, clean.faces)
    v = np.asarray(vertices, float)
    n = np.asarray(normals, float)
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    best_t = np.full(len(v), np.inf)
    best_face = np.full(len(v), -1)
    best_bary = np.zeros((len(v), 2))
    for sign in (1.0, -1.0):
        hits = caster.intersect(v, sign * n, tmin=0.0, tmax=reach)
        better = hits.hit & (hits.t < best_t)
        best_t[better] = hits.t[better]
        best_face[better] = hits.face[better]
        best_bary[better] = hits.uv[better]
    by_ray = best_face >= 0
    out_part = np.empty(len(v), np.int32)
    out_uv = np.zeros((len(v), 2))
    point = np.zeros((len(v), 3))
    tri = clean.faces[best_face[by_ray]]
    u, w = best_bary[by_ray, 0], best_bary[by_ray, 1]
    bw = np.stack([1 - u - w, u, w], 1)
    out_part[by_ray] = clean.part[tri[:, 0]]
    out_uv[by_ray] = np.einsum("nk,nkd->nd", bw, clean.uv[tri])
    point[by_ray] = np.einsum("nk,nkd->nd", bw, clean.vertices[tri])
    if np.any(~by_ray):
        _, idx = cKDTree(clean.vertices).query(v[~by_ray])
        out_part[~by_ray] = clean.part[idx]
        out_uv[~by_ray] = clean.uv[idx]
        point[~by_ray] = clean.vertices[idx]
    label = np.empty(len(v), np.uint8)
    albedo = np.zeros((len(v), 3))
    for pid in np.unique(out_part):
        sel = out_part == pid
        part = desc["parts"][pid]
        label[sel] = LABELS[part["label"]]
        albedo[sel] = part_albedo(desc, scene_dir, part, out_uv[sel])
    return {
        "part": out_part,
        "label": label,
        "albedo": albedo,
        "surface_point": point,
        "distance": np.linalg.norm(point - v, axis=1),
        "matched_by_ray": by_ray,
    }
