"""Evaluation of ``reroom invert`` against a synthetic scan's ground truth.

The only code of :mod:`reroom.invert` that reads ``ground_truth/``. What is compared:

* **Cluster albedo**: each solved cluster (wall, floor, ceiling) against the mean true
  albedo of the vertices the truth labels so (``vertices.ply``: ``label``, ``albedo``),
  relative error per channel. The floor's wood texture makes its truth a mean.
* **Per-vertex albedo**: every vertex solved per vertex, ``|rho - rho_true| / rho_true``
  pooled over channels: median and 90th percentile, also for the clustered vertices alone.
* **Light power**: the HDR radiance has a global per-channel scale of its own (the HDR
  stage fixes the scale by a reference frame), so solved intensities are first divided
  by ``k_c = median(Lbar_c / L_true_c)`` over the observed clustered vertices. Each
  solved light is matched to the nearest true light of its type. True powers: area
  ``pi L A``; point ``power * color / mean(color)`` (the generator's convention);
  window ``A * integral scale * hdri(d) cos dw`` over the directions entering the
  room. Line lights (between baffles, under a housing) have no closed-form effective
  power and are reported without one.
* **Distributions** (relative L2 in the solved basis) are *not* computed yet: the
  truth's effective distribution (a shaded lamp seen from outside its fixture, a tube
  between baffles) needs a ray-traced conversion that does not exist yet.

:func:`run_invert_true_radiance` is an **evaluation-only shortcut**: it runs the
pipeline with the true per-vertex radiance instead of the HDR mesh's, to measure the
solve independently of HDR errors.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from reroom.errors import ScanError
from reroom.invert.export import area_light_power
from reroom.io.mesh import read_ply

__all__ = [
    "evaluate_invert",
    "lights_from_truth",
    "run_invert_true_radiance",
    "true_window_power",
]

_CLUSTER_LABELS = {"wall": 0, "floor": 1, "ceiling": 2}


def _truth(scan: Path) -> tuple[Any, dict, Path]:
    gt = scan / "ground_truth"
    if not (gt / "vertices.ply").is_file():
        raise ScanError(gt / "vertices.ply", "is missing (evaluation needs a synthetic scan)")
    verts = read_ply(gt / "vertices.ply")
    scene = json.loads((gt / "scene" / "scene.json").read_text())
    return verts, scene, gt / "scene"


def true_window_power(light: dict, scene_dir: Path, samples: int = 400000) -> np.ndarray:
    """Flux through a true window: ``A * integral scale * hdri(d) cos dw`` (seeded samples).

    The HDRI is equirectangular with the zenith at the top row, the centre looking along
    +X and ``u = 0.5 - atan2(d_y, d_x) / 2 pi`` (``docs/formats.md``), rotated by
    ``rotation_deg`` about +Z.
    """
    from reroom.io.images import read_exr

    img = read_exr(scene_dir / light["hdri_file"])[..., :3]
    h, w = img.shape[:2]
    corners = np.asarray(light["corners"], float)
    area = np.linalg.norm(corners[1] - corners[0]) * np.linalg.norm(corners[3] - corners[0])
    n_in = np.asarray(light["normal"], float)
    rng = np.random.default_rng(0)
    d = rng.standard_normal((samples, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    cos = np.maximum(-(d @ n_in), 0.0)  # the ray from the room leaves along d
    rot = np.deg2rad(light.get("rotation_deg", 0.0))
    az = np.arctan2(d[:, 1], d[:, 0]) - rot
    u = np.mod(0.5 - az / (2 * np.pi), 1.0)
    v = np.arccos(np.clip(d[:, 2], -1, 1)) / np.pi
    px = np.minimum((u * w).astype(int), w - 1)
    py = np.minimum((v * h).astype(int), h - 1)
    rad = light.get("scale", 1.0) * img[py, px]
    return area * 4 * np.pi / samples * (cos[:, None] * rad).sum(axis=0)


def _light_position(light: dict) -> np.ndarray:
    for key in ("position", "centroid", "centre"):
        if key in light:
            return np.asarray(light[key], float)
    if "p0" in light:
        return (np.asarray(light["p0"], float) + np.asarray(light["p1"], float)) / 2
    return np.asarray(light["corners"], float).mean(axis=0)


def evaluate_invert(scan_dir: str | Path, invert_dir: str | Path | None = None) -> dict[str, Any]:
    """Compare ``SCAN/invert/`` (or ``invert_dir``) with the scan's ground truth.

    Returns
    -------
    dict
        ``clusters`` (per cluster: estimate, truth, relative error per channel),
        ``per_vertex`` (median / p90 relative error), ``radiance_scale`` (``k``),
        ``lights`` (per solved light: matched truth, power, relative power error),
        ``missed_lights`` (true lights with no solved light of their type nearby).
    """
    scan = Path(scan_dir)
    out = Path(invert_dir) if invert_dir is not None else scan / "invert"
    verts, scene, scene_dir = _truth(scan)
    true_label = np.asarray(verts.vertex_attributes["label"]).astype(int)
    true_albedo = np.asarray(verts.vertex_attributes["albedo"], float)
    true_rad = np.asarray(verts.vertex_attributes["radiance"], float)
    est = json.loads((out / "scene.json").read_text())
    amesh = read_ply(out / "albedo.ply")
    a = amesh.vertex_attributes
    albedo = np.asarray(a["albedo"], float)
    solved = np.asarray(a["solved_per_vertex"]).astype(bool)
    in_cluster = np.asarray(a["in_cluster"]).astype(bool)
    report: dict[str, Any] = {"invert_dir": str(out)}

    clusters = {}
    for m in est["materials"]:
        lab = _CLUSTER_LABELS.get(m["name"])
        if lab is None or m["albedo"] is None:
            clusters[m["name"]] = {"estimate": m["albedo"], "truth": None}
            continue
        truth = true_albedo[true_label == lab].mean(axis=0)
        e = np.asarray(m["albedo"], float)
        clusters[m["name"]] = {
            "estimate": e.tolist(),
            "truth": truth.tolist(),
            "relative_error": (e / truth - 1).tolist(),
        }
    report["clusters"] = clusters

    def _stats(mask: np.ndarray) -> dict[str, float] | None:
        ok = mask & (true_albedo > 0.02).all(axis=1) & (albedo >= 0).all(axis=1)
        if not ok.any():
            return None
        rel = np.abs(albedo[ok] / true_albedo[ok] - 1).ravel()
        return {
            "vertices": int(ok.sum()),
            "median": float(np.median(rel)),
            "p90": float(np.percentile(rel, 90)),
        }

    report["per_vertex"] = {"all": _stats(solved), "clustered": _stats(solved & in_cluster)}

    # the HDR radiance's own per-channel scale
    hdr_path = scan / "hdr" / "hdr_mesh.ply"
    k = np.ones(3)
    if hdr_path.is_file() and not (out / "true_radiance.flag").is_file():
        lbar = np.asarray(read_ply(hdr_path).vertex_attributes["radiance"], float)
        ok = in_cluster & (true_rad > 1e-4).all(axis=1) & (lbar > 0).all(axis=1)
        if ok.any():
            k = np.median(lbar[ok] / true_rad[ok], axis=0)
    report["radiance_scale"] = k.tolist()

    lights = []
    true_lights = [x for x in scene["lights"] if x.get("on", True)]
    matched: set[str] = set()
    for e in est["lights"]:
        cands = [t for t in true_lights if t["type"] == e["type"]]
        entry: dict[str, Any] = {"name": e["name"], "type": e["type"]}
        power = np.asarray(e["power"], float) / k
        entry["power"] = power.tolist()
        if cands:
            pos = _light_position(e["geometry"])
            t = min(cands, key=lambda t: np.linalg.norm(_light_position(t) - pos))
            matched.add(t["name"])
            entry["truth"] = t["name"]
            entry["distance_m"] = float(np.linalg.norm(_light_position(t) - pos))
            tp = None
            if t["type"] == "area":
                c = np.asarray(t["corners"], float)
                area = np.linalg.norm(c[1] - c[0]) * np.linalg.norm(c[3] - c[0])
                tp = area_light_power(np.asarray(t["radiance"], float), area)
            elif t["type"] == "point":
                col = np.asarray(t.get("color", [1, 1, 1]), float)
                tp = t["power"] * col / col.mean()
            elif t["type"] == "window":
                tp = true_window_power(t, scene_dir)
            if tp is not None:
                entry["true_power"] = np.asarray(tp).tolist()
                entry["power_relative_error"] = (power / tp - 1).tolist()
            else:
                entry["true_power"] = None
                entry["note"] = "no closed-form effective power for this light (baffles)"
        lights.append(entry)
    report["lights"] = lights
    report["missed_lights"] = [t["name"] for t in true_lights if t["name"] not in matched]
    return report


def run_invert_true_radiance(scan_dir: str | Path, out_dir: str | Path, options=None):
    """EVALUATION-ONLY SHORTCUT: :func:`run_invert` with the true per-vertex radiance.

    The true radiance of ``ground_truth/vertices.ply`` replaces the HDR mesh's (every
    vertex counted as observed), so the result measures the transfer and the solve
    alone. Never use this for anything but evaluation.
    """
    from reroom.invert.pipeline import run_invert

    verts, _, _ = _truth(Path(scan_dir))
    rad = np.asarray(verts.vertex_attributes["radiance"], float)
    result = run_invert(scan_dir, out_dir, options, radiance_override=rad)
    (Path(out_dir) / "true_radiance.flag").write_text(
        "evaluation-only: solved with the ground truth's radiance\n"
    )
    return result


def lights_from_truth(scan_dir: str | Path):
    """EVALUATION-ONLY SHORTCUT: the true lights as a :class:`reroom.lights.LightSet`.

    Every light that is on, with the generator's geometry (area: its part's vertices on
    the scan mesh; window: its rectangle; line: ``p0, p1`` with up as ``d_perp``; point:
    ``position`` and ``up``). Used to measure transfer + solve when light detection
    missed a light; never for estimation.
    """
    from reroom.lights import Light, LightSet

    verts, scene, _ = _truth(Path(scan_dir))
    part = np.asarray(verts.vertex_attributes["part"]).astype(int)
    part_index = {p["name"]: i for i, p in enumerate(scene["parts"])}
    ids = np.full(len(verts.vertices), -1, np.int32)
    lights = []
    for t in scene["lights"]:
        if not t.get("on", True):
            continue
        if t["type"] == "area":
            c = np.asarray(t["corners"], float)
            size = [np.linalg.norm(c[1] - c[0]), np.linalg.norm(c[3] - c[0])]
            geom = {
                "centroid": c.mean(axis=0).tolist(),
                "normal": t["normal"],
                "area": float(size[0] * size[1]),
                "light_index": len(lights),
            }
            if t.get("part") in part_index:
                ids[part == part_index[t["part"]]] = len(lights)
        elif t["type"] == "window":
            c = np.asarray(t["corners"], float)
            geom = {
                "centre": c.mean(axis=0).tolist(),
                "half_u": ((c[1] - c[0]) / 2).tolist(),
                "half_v": ((c[3] - c[0]) / 2).tolist(),
                "normal": t["normal"],
            }
        elif t["type"] == "line":
            geom = {"p0": t["p0"], "p1": t["p1"], "d_perp": [0.0, 0.0, 1.0], "radius": t["radius"]}
        else:
            geom = {"position": t["position"], "axis": t.get("up", [0.0, 0.0, 1.0])}
        lights.append(Light(t["name"], t["type"], "user", geom, {}, "ground truth (evaluation)"))
    return LightSet(lights, [], ids, {}, ["EVALUATION ONLY: lights from the ground truth"], {})
