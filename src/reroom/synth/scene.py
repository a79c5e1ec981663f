"""The ground-truth scene description and its translation into a Mitsuba 3 scene.

A generated scan stores its true scene in ``ground_truth/scene/``:

* ``scene.json`` -- a plain-JSON description: every part (mesh file, semantic
  label, material, emission), every light with all its parameters, textures,
  and the integrator settings (schema in ``docs/formats.md``);
* ``meshes/*.ply`` -- one PLY per part with positions, normals and uv;
* ``textures/*.exr`` -- linear albedo textures; ``ies/*.ies`` -- photometry.

:func:`mitsuba_scene_dict` turns that description into the dict that
``mitsuba.load_dict`` takes. Edits (later stages, and the end-to-end
benchmarks) change ``scene.json`` -- repaint a part, switch a light off, swap
the HDRI -- and re-render with the same path tracer.
"""

from __future__ import annotations

import copy
import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from reroom.data import hdri_path, ies_path
from reroom.io.atomic import atomic_path, atomic_write_json
from reroom.io.images import write_exr
from reroom.synth.geometry import Piece
from reroom.synth.presets import SceneSpec
from reroom.synth.textures import wood_floor

SCENE_JSON = "scene.json"


def _write_part_ply(path: Path, piece: Piece) -> None:
    from plyfile import PlyData, PlyElement

    v = piece.vertices
    vert = np.empty(
        len(v),
        dtype=[(k, "f4") for k in ("x", "y", "z", "nx", "ny", "nz", "u", "v")],
    )
    for i, k in enumerate("xyz"):
        vert[k] = v[:, i]
        vert["n" + k] = piece.normals[:, i]
    vert["u"] = piece.uv[:, 0]
    vert["v"] = piece.uv[:, 1]
    face = np.empty(len(piece.faces), dtype=[("vertex_indices", "i4", (3,))])
    face["vertex_indices"] = piece.faces
    with atomic_path(path) as tmp:
        PlyData([PlyElement.describe(vert, "vertex"), PlyElement.describe(face, "face")]).write(
            str(tmp)
        )


def write_scene(
    spec: SceneSpec, scene_dir: str | Path, max_depth: int = 256, rr_depth: int = 4
) -> dict[str, Any]:
    """Write a preset's parts, textures and photometry; return (and save) ``scene.json``."""
    scene_dir = Path(scene_dir)
    (scene_dir / "meshes").mkdir(parents=True, exist_ok=True)
    textures: dict[str, Any] = {}
    parts = []
    for i, part in enumerate(spec.parts):
        fname = f"meshes/{i:03d}_{part.name.replace('/', '_')}.ply"
        _write_part_ply(scene_dir / fname, part.piece)
        mat = dict(part.material)
        tex = mat.get("texture")
        if tex and tex not in textures:
            if tex != "wood_floor":
                raise ValueError(f"unknown procedural texture {tex!r}")
            img = wood_floor(mean_albedo=tuple(mat["albedo"]))
            write_exr(scene_dir / "textures" / f"{tex}.exr", img)
            textures[tex] = {"file": f"textures/{tex}.exr", "metres_per_tile": 2.0}
        parts.append(
            {
                "name": part.name,
                "file": fname,
                "label": part.label,
                "material": mat,
                "emission": part.emission,
                "in_scan": part.in_scan,
            }
        )
    lights = copy.deepcopy(spec.lights)
    for light in lights:
        if light["type"] == "point" and light["profile"] != "isotropic":
            src = ies_path(light["profile"])
            (scene_dir / "ies").mkdir(exist_ok=True)
            shutil.copyfile(src, scene_dir / "ies" / src.name)
            light["profile_file"] = f"ies/{src.name}"
        if light["type"] == "window":
            src = hdri_path(light["hdri"])
            (scene_dir / "hdri").mkdir(exist_ok=True)
            if not (scene_dir / "hdri" / src.name).exists():
                shutil.copyfile(src, scene_dir / "hdri" / src.name)
            light["hdri_file"] = f"hdri/{src.name}"
        light["on"] = True
    desc = {
        "format": "reroom-scene",
        "version": 1,
        "units": "m",
        "up": [0.0, 0.0, 1.0],
        "parts": parts,
        "lights": lights,
        "textures": textures,
        # Unbounded depth with Russian roulette: a closed room's light keeps bouncing, and
        # truncating paths would make the "true" radiance miss part of the indirect light.
        "integrator": {"type": "path", "max_depth": max_depth, "rr_depth": rr_depth},
    }
    atomic_write_json(scene_dir / SCENE_JSON, desc)
    return desc


def load_scene_description(scene_dir: str | Path) -> dict[str, Any]:
    """Read ``scene.json`` from a ground-truth scene folder."""
    return json.loads((Path(scene_dir) / SCENE_JSON).read_text())


def _bsdf(material: dict, textures: dict, scene_dir: Path, mi: Any) -> dict:
    kind = material["type"]
    if kind == "black":
        return {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}}
    if material.get("texture"):
        tex = textures[material["texture"]]
        s = 1.0 / tex["metres_per_tile"]
        reflectance = {
            "type": "bitmap",
            "filename": str(scene_dir / tex["file"]),
            "raw": True,
            "filter_type": "bilinear",
            "wrap_mode": "repeat",
            "to_uv": mi.ScalarTransform4f().scale([s, s, 1.0]),
        }
    else:
        reflectance = {"type": "rgb", "value": list(material["albedo"])}
    if kind == "diffuse":
        # Two-sided: thin parts (shades, baffles) are seen from both sides.
        return {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": reflectance}}
    if kind == "roughplastic":
        return {
            "type": "roughplastic",
            "distribution": "ggx",
            "alpha": float(material.get("alpha", 0.15)),
            "diffuse_reflectance": reflectance,
        }
    raise ValueError(f"unknown material type {kind!r}")


def mitsuba_scene_dict(
    desc: dict[str, Any],
    scene_dir: str | Path,
    *,
    only_scan_parts: bool = False,
    sensor: dict | None = None,
) -> dict[str, Any]:
    """Translate a scene description into a ``mitsuba.load_dict`` dictionary.

    Lights whose ``"on"`` is false are left out (their geometry stays, unlit).
    ``only_scan_parts`` keeps only geometry the scanner sees (no portals, no
    emitters), for depth rendering.
    """
    from reroom.render import mitsuba
    from reroom.synth import lighting

    mi = mitsuba()
    scene_dir = Path(scene_dir)
    integ = desc.get("integrator", {"type": "path", "max_depth": 8})
    out: dict[str, Any] = {"type": "scene", "integrator": dict(integ)}
    if sensor is not None:
        out["sensor"] = sensor
    lights_by_part = {light.get("part"): light for light in desc["lights"] if light.get("part")}
    for i, part in enumerate(desc["parts"]):
        if only_scan_parts and not part["in_scan"]:
            continue
        shape: dict[str, Any] = {
            "type": "ply",
            "filename": str(scene_dir / part["file"]),
            "face_normals": False,
            "bsdf": _bsdf(part["material"], desc["textures"], scene_dir, mi),
        }
        light = lights_by_part.get(part["name"])
        if not only_scan_parts and light is not None and light.get("on", True):
            emitter = lighting.shape_emitter(light, scene_dir, mi)
            if emitter is not None:
                shape["emitter"] = emitter
        out[f"part{i:03d}"] = shape
    if not only_scan_parts:
        for j, light in enumerate(desc["lights"]):
            if light.get("on", True) and light["type"] == "point":
                out[f"light{j:02d}"] = lighting.point_emitter(light, scene_dir, mi)
    return out
