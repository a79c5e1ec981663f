"""The albedo the model's renders give the furnishings, against the synthetic truth.

Usage::

    python benchmarks/bench_render_albedo.py SCAN [SCAN ...]

``SCAN`` is a synthetic scan with ``invert/``, ``layout/`` and ``ground_truth/``. The
renderer does not draw ``invert/albedo.ply`` as it is: unseen vertices must get some
albedo, and since session 20 the furnishings (vertices the layout leaves unlabelled) get
one robust albedo per object (:func:`reroom.edit.objects.object_albedo`) before the
remaining unseen vertices are filled over the mesh (:func:`reroom.edit.model.fill_unknown_albedo`).
Per scan this prints, for three ways of making the rendered per-vertex albedo:

* ``median fill``: the per-vertex albedo, every unseen vertex the median of the seen
  ones (the renderer before session 20);
* ``mesh fill``: the unseen vertices interpolated from their neighbours over the mesh;
* ``objects + mesh fill``: the renderer since session 20;

the area-weighted mean albedo over each furnishing (the truth's parts: the vertices'
``part``) over its true mean, and over the whole room (lights and their fixtures left
out: the renderer draws fixtures black), with
the per-vertex relative error of the seen furnishing vertices (median and 90th
percentile). Everything is clipped at 0.95 as the renderer does. Also the seconds that
``object_albedo`` and the fill take.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import trimesh

from reroom.edit.model import fill_unknown_albedo
from reroom.edit.objects import object_albedo
from reroom.io.mesh import read_ply

#: Label of unlabelled (furnishing) vertices in ``layout_labels.ply``.
OTHER = 255
#: True vertex label of furniture in the generator's ``vertices.ply`` (7: light).
TRUE_FURNITURE, TRUE_LIGHT = 6, 7
MAX_ALBEDO = 0.95


def _area_weighted(values: np.ndarray, area: np.ndarray, sel: np.ndarray) -> np.ndarray:
    return (values[sel] * area[sel, None]).sum(axis=0) / area[sel].sum()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("scans", type=Path, nargs="+")
    args = ap.parse_args()
    for scan in args.scans:
        mesh = read_ply(scan / "invert" / "albedo.ply")
        truth = read_ply(scan / "ground_truth" / "vertices.ply").vertex_attributes
        labels = np.asarray(
            read_ply(scan / "layout" / "layout_labels.ply").vertex_attributes["label"]
        ).astype(int)
        scene = json.loads((scan / "ground_truth" / "scene" / "scene.json").read_text())
        part_names = [p["name"] for p in scene["parts"]]
        v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
        est = np.asarray(mesh.vertex_attributes["albedo"], float)
        true_albedo = np.asarray(truth["albedo"], float)
        true_label = np.asarray(truth["label"]).astype(int)
        part = np.asarray(truth["part"]).astype(int)
        area = np.zeros(len(v))
        faces_area = trimesh.Trimesh(v, f, process=False).area_faces
        np.add.at(area, f.ravel(), np.repeat(faces_area / 3.0, 3))
        known = np.all(est >= 0, axis=1) & np.all(np.isfinite(est), axis=1)
        clipped = np.clip(np.where(known[:, None], est, 0.0), 0.0, MAX_ALBEDO)

        t0 = time.perf_counter()
        obj, obj_known = object_albedo(v, f, clipped, known, labels == OTHER)
        t_obj = time.perf_counter() - t0
        t0 = time.perf_counter()
        ours = fill_unknown_albedo(np.clip(obj, 0.0, MAX_ALBEDO), f, obj_known)
        t_fill = time.perf_counter() - t0
        variants = {
            "median fill (before)": np.where(known[:, None], clipped, np.median(clipped[known], 0)),
            "mesh fill": fill_unknown_albedo(clipped, f, known),
            "objects + mesh fill (now)": ours,
        }
        # Light fixtures (the generator names them after their light: tube_baffles,
        # floor_lamp_shade) render black whatever their albedo (reroom.edit.apply).
        lights = tuple(f"{x['name']}_" for x in scene.get("lights", []))
        fixture = np.isin(part, [i for i, n in enumerate(part_names) if n.startswith(lights)])
        furniture = (true_label == TRUE_FURNITURE) & ~fixture
        parts = [
            p
            for p in np.unique(part[furniture])
            if area[furniture & (part == p)].sum() >= 0.5  # skip the fixtures' small parts
        ]
        print(
            f"\n`{scan}`: {len(v)} vertices, {int((labels == OTHER).sum())} unlabelled; "
            f"object_albedo {t_obj:.2f} s, fill {t_fill:.2f} s\n"
        )
        head = " | ".join(part_names[p] for p in parts)
        print(f"| rendered albedo / truth (area-weighted, r/g/b) | {head} | room | "
              "seen furnishing vertices: median / p90 error |")  # fmt: skip
        print("|---" * (len(parts) + 3) + "|")
        room = (true_label != TRUE_LIGHT) & ~fixture
        seen = furniture & known
        for name, alb in variants.items():
            cells = []
            for p in parts:
                sel = furniture & (part == p)
                ratio = _area_weighted(alb, area, sel) / _area_weighted(true_albedo, area, sel)
                cells.append("/".join(f"{x:.2f}" for x in ratio))
            mean = _area_weighted(alb, area, room)
            err = np.abs(alb[seen] / np.maximum(true_albedo[seen], 1e-3) - 1.0).mean(axis=1)
            print(
                f"| {name} | " + " | ".join(cells) + " | "
                + "/".join(f"{x:.3f}" for x in mean)
                + f" | {np.median(err):.2f} / {np.quantile(err, 0.9):.2f} |"
            )  # fmt: skip
        truth_mean = _area_weighted(true_albedo, area, room)
        print("| truth | " + " | ".join("1" for _ in parts) + " | "
              + "/".join(f"{x:.3f}" for x in truth_mean) + " | - |")  # fmt: skip


if __name__ == "__main__":
    main()
