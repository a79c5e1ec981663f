"""Photo textures of the room's planes: cost, and the local mean taken from the per-vertex albedo.

Usage::

    python benchmarks/bench_textures.py SCAN [--windows]

``SCAN`` has ``hdr/``, ``layout/`` and ``invert/`` (a ``reroom invert`` or ``reroom run``
output). The model's irradiance at each vertex is recovered from the solve's own
per-vertex albedo, ``E = pi L / rho`` (``invert/albedo.ply`` and the HDR mesh's
radiance), so no inverse rendering is re-run. Prints, for
:func:`reroom.invert.textures.photo_textures`:

* its wall time, texel, samples and skipped pixels (saturated, grazing), with the local
  mean from the per-vertex albedo (the default) and without it (the photos' own);
* per plane, the ratio of means texture / per-vertex albedo at the plane's vertices, both
  ways: how dark the photos' own textures are (saturated pixels skipped) and that the
  default follows the per-vertex albedo.

``--windows`` also times :func:`reroom.invert.window_env.observe_windows` at 250k and 60k
rays a frame (the default before and since session 10) and counts the lat-long texels
each sees.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from reroom.invert.textures import photo_textures, planar_groups
from reroom.io.mesh import read_ply


def _ratios(textures, mesh, labels, rotation, albedo) -> dict[str, np.ndarray]:
    """Per texture: ratio of means (texture at the plane's vertices) / per-vertex albedo."""
    planes, face_plane = planar_groups(mesh.vertices, mesh.faces, labels, rotation)
    out = {}
    faces = np.asarray(mesh.faces)
    for tex in textures:
        k = next(
            i
            for i, p in enumerate(planes)
            if p["label"] == tex.label and p["axis"] == tex.axis and p["offset"] == tex.offset
        )
        vid = np.unique(faces[face_plane == k])
        vid = vid[np.all(albedo[vid] >= 0, axis=1)]
        uv = tex.texture_coords(np.asarray(mesh.vertices)[vid])
        h, w = tex.shape
        r = np.clip((uv[:, 1] * h).astype(int), 0, h - 1)
        c = np.clip((uv[:, 0] * w).astype(int), 0, w - 1)
        seen = tex.count[r, c] > 0
        out[tex.name] = tex.albedo[r, c][seen].mean(0) / np.clip(albedo[vid][seen], 0, 0.95).mean(0)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("scan", type=Path)
    ap.add_argument("--windows", action="store_true")
    args = ap.parse_args()
    scan = args.scan
    mesh = read_ply(scan / "hdr" / "hdr_mesh.ply")
    radiance = np.asarray(mesh.vertex_attributes["radiance"], float)
    albedo = np.asarray(read_ply(scan / "invert" / "albedo.ply").vertex_attributes["albedo"], float)
    labels = np.asarray(read_ply(scan / "layout" / "layout_labels.ply").vertex_attributes["label"])
    rotation = np.asarray(json.loads((scan / "layout" / "layout.json").read_text())["rotation"])
    known = np.all(albedo > 0, axis=1)
    irradiance = np.where(
        known[:, None], np.pi * radiance / np.where(known[:, None], albedo, 1), np.nan
    )
    vertex = np.where(known[:, None], albedo, np.nan)

    print(f"## {scan}\n")
    print("| local mean from | seconds | texel (cm) | samples | saturated | grazing |")
    print("|---|---|---|---|---|---|")
    results = {}
    for name, va in (("per-vertex albedo (default)", vertex), ("the photos alone", None)):
        t = time.perf_counter()
        textures, stats = photo_textures(scan, mesh, labels, rotation, irradiance, va)
        sec = time.perf_counter() - t
        results[name] = _ratios(textures, mesh, labels, rotation, albedo)
        print(
            f"| {name} | {sec:.1f} | {100 * stats['texel']:.1f} | {stats['samples']} | "
            f"{stats['saturated']} | {stats['grazing']} |"
        )
    print("\nTexture / per-vertex albedo, ratio of means at each plane's vertices (r/g/b):\n")
    print("| plane | " + " | ".join(results) + " |")
    print("|---|" + "---|" * len(results))
    for plane in next(iter(results.values())):
        print(
            f"| {plane} | "
            + " | ".join("/".join(f"{x:.3f}" for x in r[plane]) for r in results.values())
            + " |"
        )

    if args.windows:
        from reroom.invert.window_env import observe_windows
        from reroom.invert.windows import WindowOpening

        doc = json.loads((scan / "invert" / "scene.json").read_text())
        openings = [
            WindowOpening(
                e["name"],
                *(
                    np.asarray(e["geometry"][k], float)
                    for k in ("centre", "half_u", "half_v", "normal")
                ),
            )
            for e in doc["lights"]
            if e["type"] == "window"
        ]
        print(
            "\n| window map, rays a frame | seconds | samples | texels seen unsaturated | seen at all |"
        )
        print("|---|---|---|---|---|")
        for rays in (250_000, 60_000):
            t = time.perf_counter()
            photos, stats = observe_windows(scan, mesh, openings, max_rays_per_frame=rays)
            sec = time.perf_counter() - t
            unsat = sum(int((p.count > 0).sum()) for p in photos)
            seen = sum(int(((p.count > 0) | (p.saturated > 0)).sum()) for p in photos)
            print(f"| {rays} | {sec:.1f} | {sum(stats['samples'])} | {unsat} | {seen} |")


if __name__ == "__main__":
    main()
