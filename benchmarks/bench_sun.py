"""The windows' sun search (``reroom.invert.sun.find_sun``) on scans: found or not, and why.

For each scan with ``hdr/``, ``layout/`` and ``lights/`` (a window among them), the search
runs as ``reroom invert`` runs it, on the observed wall, floor and ceiling vertices
(vertex normals, the window's own faces passed through), and prints per window: the best
direction's t statistic and lit/ring contrast with every test off, its edge contrasts,
whether the default tests keep it, the lit receivers, the seconds, and, with
``ground_truth/``, the angle to the HDRI's sun (``evaluate.true_sun``).

    .venv/bin/python benchmarks/bench_sun.py SCAN [SCAN ...]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from reroom.hdr.observe import vertex_normals
from reroom.invert import sun
from reroom.invert.pipeline import CLUSTER_LABELS
from reroom.invert.windows import WindowOpening
from reroom.io.mesh import read_ply
from reroom.rays import RayCaster

LOOSE = {"min_score": -np.inf, "min_contrast": 0.0, "min_edges": 0, "min_edge_contrast": 0.0}


def scan_rows(scan: Path) -> list[str]:
    mesh = read_ply(scan / "hdr" / "hdr_mesh.ply")
    rad = np.asarray(mesh.vertex_attributes["radiance"], float)
    seen = np.asarray(mesh.vertex_attributes["observed"]).astype(bool) & np.isfinite(rad).all(1)
    labels = np.asarray(read_ply(scan / "layout" / "layout_labels.ply").vertex_attributes["label"])
    use = seen & np.isin(labels, list(CLUSTER_LABELS.values()))
    normals = vertex_normals(mesh)
    use &= np.linalg.norm(normals, axis=1) > 0
    from reroom.lights import load_lights

    lightset = load_lights(scan / "lights" / "lights.json")
    ids = np.asarray(lightset.vertex_light_id)
    faces = np.asarray(mesh.faces)
    if len(ids):
        use &= ids < 0  # the lights' own glowing vertices are no receivers
    p, n, r = np.asarray(mesh.vertices)[use], normals[use], rad[use]
    caster = RayCaster(mesh)
    lights = json.loads((scan / "lights" / "lights.json").read_text())["lights"]
    truth = scan / "ground_truth" / "ground_truth.json"
    rows = []
    for k, light in enumerate(lights):
        if light["type"] != "window":
            continue
        g = light
        w = WindowOpening(light["name"], g["centre"], g["half_u"], g["half_v"], g["normal"])
        # The window's own faces do not block its light, as in the pipeline.
        pane = (ids[faces] == k).any(axis=1) if len(ids) else None
        t0 = time.perf_counter()
        kept = sun.find_sun(caster, w, p, n, r, pane_faces=pane)
        dt = time.perf_counter() - t0
        best = sun.find_sun(caster, w, p, n, r, pane_faces=pane, **LOOSE)
        edges, angle = [], ""
        if best is not None:
            front = ((p - w.centre) @ w.normal > 0) & (r @ sun._LUMA > 0)
            pf, nf, yf = p[front], n[front], np.log(r[front] @ sun._LUMA)
            lit = sun._through_opening(caster, w, best.direction, pf, nf, caster.eps, 0.02, pane)
            from scipy.spatial import cKDTree

            ring_reach = max(0.12, 1.5 * float(np.median(cKDTree(pf).query(pf, k=2)[0][:, 1])))
            dist = cKDTree(pf[lit]).query(pf, distance_upper_bound=ring_reach)[0]
            _, u, v = sun._opening_coords(w, best.direction, pf, caster.eps, nf)
            edges = sun._edge_contrasts(u, v, lit, np.isfinite(dist) & ~lit, yf)
        if truth.is_file() and best is not None:
            from reroom.invert.evaluate import true_sun

            gt = json.loads(truth.read_text())
            tw = [x for x in gt["lights"] if x["type"] == "window"]
            ts = true_sun(tw[0], scan / "ground_truth" / "scene") if tw else None
            if ts is not None:
                a = float(np.degrees(np.arccos(np.clip(best.direction @ ts["direction"], -1, 1))))
                angle = f"{a:.2f}"
            else:
                angle = "no true sun"
        rows.append(
            f"| {scan} | {light['name']} | {'**yes**' if kept else 'no'} | "
            + (
                f"{best.score:.1f} | {best.contrast:.2f} | {best.lit} | "
                f"{'/'.join(f'{e:.2f}' for e in edges) or '-'} | {angle} | {dt:.1f} |"
                if best is not None
                else "- | - | - | - | - | {dt:.1f} |"
            )
        )
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("scans", type=Path, nargs="+")
    args = ap.parse_args()
    print(
        "| scan | window | sun kept | best t | lit / ring | lit | edge contrasts | "
        "angle to the true sun (deg) | search s |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for scan in args.scans:
        for row in scan_rows(scan):
            print(row, flush=True)


if __name__ == "__main__":
    main()
