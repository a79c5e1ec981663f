"""An area light's outline against the truth: every bright vertex's hull, or those on its face.

Usage::

    python benchmarks/bench_area_outline.py RUN

``RUN`` is a synthetic scan with a lights stage (``lights/lights.json``,
``lights/lights_vertices.npz``) and its ``ground_truth/``; with ``invert/scene.json`` the
outline the solve used is printed too. Per area light (matched to the true area light
nearest its centroid):

* how many vertices the lights stage gave it, and how many
  :func:`reroom.invert.area_region.on_emitting_plane` keeps;
* the convex outline of all of them and of the kept ones: area and extent along the
  outline's own axes, against the truth's rectangle;
* the vertices left out: how far they lie from the kept vertices' plane and how far
  past the true outline (docs/invert.md, "Session 50": a recessed panel's fused rim).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def _extent(region) -> str:
    ab = region.polygon
    span = ab.max(axis=0) - ab.min(axis=0)
    return f"{span[0]:.3f} x {span[1]:.3f} m"


def _past_rectangle(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Distance of each point past a rectangle (its plane's in-plane distance, 0 inside)."""
    o, a, b = corners[0], corners[1] - corners[0], corners[3] - corners[0]
    la, lb = np.linalg.norm(a), np.linalg.norm(b)
    q = points - o
    u, v = q @ (a / la), q @ (b / lb)
    du = np.maximum(np.maximum(-u, u - la), 0.0)
    dv = np.maximum(np.maximum(-v, v - lb), 0.0)
    return np.hypot(du, dv)


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("run", type=Path)
    args = ap.parse_args()

    from reroom.invert.area_region import area_region, on_emitting_plane
    from reroom.io.mesh import read_ply
    from reroom.synth.scene import load_scene_description

    run: Path = args.run
    for need in ("lights/lights.json", "lights/lights_vertices.npz", "mesh.ply",
                 "ground_truth/scene/scene.json"):  # fmt: skip
        if not (run / need).is_file():
            raise SystemExit(f"{run / need}: no such file (a synthetic scan after `reroom lights`)")
    lights = json.loads((run / "lights" / "lights.json").read_text())["lights"]
    with np.load(run / "lights" / "lights_vertices.npz") as z:
        ids = np.asarray(z["light_id"])
    vertices = np.asarray(read_ply(run / "mesh.ply").vertices, float)
    truth = [
        light
        for light in load_scene_description(run / "ground_truth" / "scene")["lights"]
        if light["type"] == "area"
    ]
    solved = {}
    scene = run / "invert" / "scene.json"
    if scene.is_file():
        solved = {x["name"]: x for x in json.loads(scene.read_text())["lights"]}
    for index, light in enumerate(lights):
        if light["type"] != "area":
            continue
        normal = light.get("normal", [0.0, 0.0, -1.0])
        pts = vertices[ids == index]
        keep = on_emitting_plane(pts, normal)
        centre = pts.mean(axis=0)
        true = min(truth, key=lambda t: np.linalg.norm(np.mean(t["corners"], axis=0) - centre))
        corners = np.asarray(true["corners"], float)
        true_region = area_region(corners, normal)
        print(
            f"{light['name']} (truth {true['name']}): {len(pts)} vertices, {int(keep.sum())} on its face"
        )
        print(f"  truth: {true_region.area:.4f} m^2, {_extent(true_region)}")
        for what, sel in (("every vertex", np.ones(len(pts), bool)), ("on its face", keep)):
            r = area_region(pts[sel], normal)
            print(
                f"  hull of {what}: {r.area:.4f} m^2 ({r.area / true_region.area - 1:+.1%}), "
                f"{_extent(r)}"
            )
        if (~keep).any():
            c = pts[keep].mean(axis=0)
            fit = np.linalg.svd(pts[keep] - c, full_matrices=False)[2][-1]
            off = np.abs((pts[~keep] - c) @ fit)
            past = _past_rectangle(pts[~keep], corners)
            print(
                f"  left out: {int((~keep).sum())} vertices, {off.min() * 100:.1f}-"
                f"{off.max() * 100:.1f} cm off the face's plane, up to {past.max() * 100:.1f} cm "
                f"past the true outline (median {np.median(past) * 100:.1f} cm)"
            )
        if light["name"] in solved:
            area = solved[light["name"]]["geometry"].get("area")
            print(f"  invert/scene.json: area {area} m^2")


if __name__ == "__main__":
    main()
