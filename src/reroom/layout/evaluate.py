"""Evaluation of a recovered layout against a synthetic scan's ground truth.

This is the only module of :mod:`reroom.layout` that reads ``ground_truth/``.
Everything is compared in the scan's own (mesh) coordinates: the estimate's aligned
coordinates are mapped back through its ``rotation``.

Metrics
-------
* ``wall_error_cm``: per true wall, the mean distance of the matching estimated wall's
  two ends (clipped to their common extent) from the true wall line; a true wall with
  no estimated wall of the same facing within 0.3 m is *missed*.
* ``floor_error_cm``, ``ceiling_error_cm``: height differences at each room's centroid.
* ``iou``: floorplan IoU of the union of the room polygons, rasterised at 1 cm; per
  room, the IoU with the best-overlapping estimated room.
* ``label_accuracy``: on vertices whose true label is wall, floor or ceiling, the
  fraction with the same estimated label (and per class).
* openings (``door``, ``window``, ``passage``) and ``baseboard`` pieces: rectangles on a
  true wall's plane, matched one-to-one when IoU >= 0.5 (same kind): precision, recall.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from reroom.layout.features import rect_iou
from reroom.layout.labels import CEILING, FLOOR, WALL

_KINDS = ("door", "window", "passage")


def _to_world(rot: np.ndarray, xy: np.ndarray, z: float) -> np.ndarray:
    """Aligned ``(N, 2)`` points at height ``z`` to world (mesh) ``(N, 2)``."""
    p = np.column_stack([xy, np.full(len(xy), z)])
    return (p @ rot)[:, :2]  # rot rows are the axes: world = rot.T @ aligned


def _height_at(rot: np.ndarray, z_aligned: float, xy_world: np.ndarray) -> float:
    """World height of the aligned plane ``z = z_aligned`` above world point ``xy``."""
    up = rot[2]
    return float((z_aligned - up[0] * xy_world[0] - up[1] * xy_world[1]) / up[2])


def _world_walls(layout: dict) -> list[dict]:
    """The estimate's walls in world coordinates, with room and local index."""
    rot = np.asarray(layout.get("rotation", np.eye(3)), float)
    out = []
    for ri, room in enumerate(layout["rooms"]):
        for w in room["walls"]:
            a, b = _to_world(rot, np.array([w["start"], w["end"]], float), room["floor_z"])
            n = np.asarray(w["inward_normal"], float)
            n_w = (np.array([n[0], n[1], 0.0]) @ rot)[:2]
            out.append({"room": ri, "index": w["index"], "start": a, "end": b, "normal": n_w})
    return out


def _gt_walls(truth_layout: dict) -> list[dict]:
    out = []
    for ri, room in enumerate(truth_layout["rooms"]):
        for w in room["walls"]:
            out.append(
                {
                    "room": ri,
                    "index": w["index"],
                    "start": np.asarray(w["start"], float),
                    "end": np.asarray(w["end"], float),
                    "normal": np.asarray(w["inward_normal"], float),
                }
            )
    return out


def _match_wall(gt: dict, est: list[dict], max_dist: float = 0.3) -> tuple[int, float]:
    """Index of the estimated wall matching a true wall and its distance (cm-free, metres)."""
    a, b = gt["start"], gt["end"]
    length = float(np.linalg.norm(b - a))
    t = (b - a) / length
    best, best_key = -1, None
    dist_best = np.inf
    for k, e in enumerate(est):
        if e["normal"] @ gt["normal"] < 0.9:
            continue
        sa, sb = sorted([(e["start"] - a) @ t, (e["end"] - a) @ t])
        lo, hi = max(sa, 0.0), min(sb, length)
        if hi - lo <= 0.05 * length:
            continue
        # Points of the estimated wall at the ends of the common extent.
        ee = e["end"] - e["start"]
        pts = [e["start"] + ee * ((s - ((e["start"] - a) @ t)) / (ee @ t)) for s in (lo, hi)]
        d = float(np.mean([abs((p - a) @ gt["normal"]) for p in pts]))
        if d > max_dist:
            continue
        key = (-(hi - lo) / length > -0.5, d)  # prefer large overlap, then small distance
        if best_key is None or key < best_key:
            best, best_key, dist_best = k, key, d
    return best, dist_best


def _rasterize(polys: list[np.ndarray], lo: np.ndarray, shape: tuple[int, int], cell: float):
    from reroom.synth.room import point_in_polygon

    xs = lo[0] + (np.arange(shape[0]) + 0.5) * cell
    ys = lo[1] + (np.arange(shape[1]) + 0.5) * cell
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    m = np.zeros(shape, bool)
    for p in polys:
        m |= point_in_polygon(gx, gy, np.asarray(p, float))
    return m


def floorplan_iou(
    est_polys: list[np.ndarray], gt_polys: list[np.ndarray], cell: float = 0.01
) -> tuple[float, list[float]]:
    """IoU of the unions, and per true room the IoU with its best estimated room."""
    pts = np.vstack([np.asarray(p, float) for p in [*est_polys, *gt_polys]])
    lo = pts.min(axis=0) - 2 * cell
    shape = tuple(int(v) for v in np.ceil((pts.max(axis=0) + 2 * cell - lo) / cell))
    est = [_rasterize([p], lo, shape, cell) for p in est_polys]
    gt = [_rasterize([p], lo, shape, cell) for p in gt_polys]
    eu = np.any(est, axis=0) if est else np.zeros(shape, bool)
    gu = np.any(gt, axis=0)
    union = np.logical_or(eu, gu).sum()
    iou = float(np.logical_and(eu, gu).sum() / union) if union else 0.0
    per = []
    for g in gt:
        best = 0.0
        for e in est:
            u = np.logical_or(e, g).sum()
            best = max(best, float(np.logical_and(e, g).sum() / u) if u else 0.0)
        per.append(best)
    return iou, per


def _gt_baseboard_pieces(room: dict) -> list[tuple[int, float, float, float, float]]:
    """True baseboard rectangles ``(wall, s0, s1, z0, z1)`` of a room (as the generator
    builds them: every wall, minus door and passage spans that reach the floor)."""
    bb = room.get("baseboard")
    if not bb:
        return []
    zf = room["floor_z"]
    out = []
    for w in room["walls"]:
        length = float(np.linalg.norm(np.subtract(w["end"], w["start"])))
        skip = sorted(
            (o["s0"], o["s1"])
            for o in room["openings"]
            if o["wall"] == w["index"] and o["kind"] in ("door", "passage") and o["z0"] <= zf + 1e-9
        )
        start = 0.0
        for s0, s1 in skip:
            if s0 > start:
                out.append((w["index"], start, s0, zf, zf + bb["height"]))
            start = max(start, s1)
        if start < length:
            out.append((w["index"], start, length, zf, zf + bb["height"]))
    return out


def _project_rect(est_wall: dict, gt_wall: dict, s0: float, s1: float) -> tuple[float, float]:
    """An interval ``[s0, s1]`` along an estimated wall, as arc length on a true wall."""
    a, b = gt_wall["start"], gt_wall["end"]
    t = (b - a) / np.linalg.norm(b - a)
    ee = est_wall["end"] - est_wall["start"]
    te = ee / np.linalg.norm(ee)
    p0 = est_wall["start"] + te * s0
    p1 = est_wall["start"] + te * s1
    u0, u1 = (p0 - a) @ t, (p1 - a) @ t
    return (min(u0, u1), max(u0, u1))


def _pr(matches: int, n_est: int, n_gt: int) -> dict[str, Any]:
    return {
        "true": n_gt,
        "found": n_est,
        "matched": matches,
        "precision": matches / n_est if n_est else (1.0 if n_gt == 0 else 0.0),
        "recall": matches / n_gt if n_gt else 1.0,
    }


def _greedy_match(
    est: list[tuple], gt: list[tuple], min_iou: float
) -> tuple[int, list[float], list[float]]:
    """One-to-one matches of rectangles ``(gt_wall_key, u0, u1, v0, v1)`` by IoU: their
    number, and per match the IoU and the mean distance of the four edges (metres)."""
    pairs = []
    for i, e in enumerate(est):
        for j, g in enumerate(gt):
            if e[0] != g[0]:
                continue
            iou = rect_iou(e[1:], g[1:])
            if iou >= min_iou:
                pairs.append((iou, i, j))
    used_e, used_g = set(), set()
    ious: list[float] = []
    edges: list[float] = []
    for iou, i, j in sorted(pairs, reverse=True):
        if i in used_e or j in used_g:
            continue
        used_e.add(i)
        used_g.add(j)
        ious.append(float(iou))
        edges.append(float(np.mean(np.abs(np.subtract(est[i][1:], gt[j][1:])))))
    return len(ious), ious, edges


def evaluate_layout(
    layout: dict,
    truth: dict,
    labels: np.ndarray | None = None,
    true_labels: np.ndarray | None = None,
    min_iou: float = 0.5,
) -> dict[str, Any]:
    """Compare a layout (the ``layout.json`` document) with a ground-truth layout.

    Parameters
    ----------
    layout:
        The estimate, as written by :func:`reroom.layout.run_layout`.
    truth:
        ``ground_truth.json``'s ``layout``.
    labels, true_labels:
        Optional per-vertex estimated and true label ids of the same mesh.
    min_iou:
        Rectangle IoU for a feature to count as found.
    """
    rot = np.asarray(layout.get("rotation", np.eye(3)), float)
    est_walls = _world_walls(layout)
    gt_walls = _gt_walls(truth)
    wall_err = []
    missed = 0
    gt_to_est: dict[tuple[int, int], int] = {}
    for g in gt_walls:
        k, d = _match_wall(g, est_walls)
        if k < 0:
            missed += 1
            continue
        gt_to_est[(g["room"], g["index"])] = k
        wall_err.append(100.0 * d)

    est_polys = [
        _to_world(rot, np.asarray(r["polygon"], float), r["floor_z"]) for r in layout["rooms"]
    ]
    gt_polys = [np.asarray(r["polygon"], float) for r in truth["rooms"]]
    iou, per_room = floorplan_iou(est_polys, gt_polys)

    floor_err, ceil_err = [], []
    for r in truth["rooms"]:
        c = np.asarray(r["polygon"], float).mean(axis=0)
        # The estimated room over this centroid (else the first).
        er = layout["rooms"][0] if layout["rooms"] else None
        from reroom.synth.room import point_in_polygon

        for k, p in enumerate(est_polys):
            if point_in_polygon(np.array(c[0]), np.array(c[1]), p):
                er = layout["rooms"][k]
                break
        if er is None:
            continue
        floor_err.append(100.0 * abs(_height_at(rot, er["floor_z"], c) - r["floor_z"]))
        ceil_err.append(100.0 * abs(_height_at(rot, er["ceiling_z"], c) - r["ceiling_z"]))

    # --- openings and baseboards: rectangles on the true walls' planes ---------------------
    gt_rects: dict[str, list[tuple]] = {k: [] for k in (*_KINDS, "baseboard")}
    for ri, r in enumerate(truth["rooms"]):
        for o in r["openings"]:
            gt_rects[o["kind"]].append(((ri, o["wall"]), o["s0"], o["s1"], o["z0"], o["z1"]))
        for w, s0, s1, z0, z1 in _gt_baseboard_pieces(r):
            gt_rects["baseboard"].append(((ri, w), s0, s1, z0, z1))
    est_index = {(e["room"], e["index"]): k for k, e in enumerate(est_walls)}
    est_to_gt: dict[int, list[tuple[int, int]]] = {}
    for key, k in gt_to_est.items():
        est_to_gt.setdefault(k, []).append(key)

    def on_gt(ri: int, wall: int, s0: float, s1: float, z0: float, z1: float) -> list[tuple]:
        k = est_index.get((ri, wall))
        out = []
        for gkey in est_to_gt.get(k, []) if k is not None else []:
            gw = next(g for g in gt_walls if (g["room"], g["index"]) == gkey)
            u0, u1 = _project_rect(est_walls[k], gw, s0, s1)
            c = 0.5 * (gw["start"] + gw["end"])
            zf = _height_at(rot, 0.0, c)
            out.append((gkey, u0, u1, z0 + zf, z1 + zf))
        return out

    est_rects: dict[str, list[tuple]] = {k: [] for k in (*_KINDS, "baseboard")}
    n_est: dict[str, int] = {k: 0 for k in (*_KINDS, "baseboard")}
    for ri, r in enumerate(layout["rooms"]):
        for o in r.get("openings", []):
            n_est[o["kind"]] = n_est.get(o["kind"], 0) + 1
            # An estimate on a wall that matches no true wall cannot be right.
            est_rects.setdefault(o["kind"], []).extend(
                on_gt(ri, o["wall"], o["s0"], o["s1"], o["z0"], o["z1"])[:1]
            )
        bb = r.get("baseboard")
        if bb:
            for piece in bb.get("pieces", []):
                n_est["baseboard"] += 1
                est_rects["baseboard"].extend(
                    on_gt(
                        ri,
                        piece["wall"],
                        piece["s0"],
                        piece["s1"],
                        r["floor_z"],
                        r["floor_z"] + bb["height"],
                    )[:1]
                )
    features = {}
    for k in (*_KINDS, "baseboard"):
        n, ious, edges = _greedy_match(est_rects.get(k, []), gt_rects[k], min_iou)
        features[k] = _pr(n, n_est.get(k, 0), len(gt_rects[k]))
        if n:
            # How well the matched rectangles sit: their IoU, and how far their edges are
            # from the truth's (mean of the four, then over the matches).
            features[k]["mean_iou"] = float(np.mean(ious))
            features[k]["edge_error_cm"] = 100.0 * float(np.mean(edges))
    bb_true = [r["baseboard"] for r in truth["rooms"] if r.get("baseboard")]
    bb_est = [r["baseboard"] for r in layout["rooms"] if r.get("baseboard")]
    if bb_true and bb_est:
        features["baseboard"]["height_error_cm"] = 100.0 * abs(
            bb_est[0]["height"] - bb_true[0]["height"]
        )
        features["baseboard"]["depth_error_cm"] = 100.0 * abs(
            bb_est[0]["depth"] - bb_true[0]["depth"]
        )

    out: dict[str, Any] = {
        "rooms_true": len(truth["rooms"]),
        "rooms_found": len(layout["rooms"]),
        "walls_true": len(gt_walls),
        "walls_found": len(est_walls),
        "walls_missed": missed,
        "wall_error_cm": {
            "mean": float(np.mean(wall_err)) if wall_err else None,
            "max": float(np.max(wall_err)) if wall_err else None,
        },
        "floor_error_cm": float(np.max(floor_err)) if floor_err else None,
        "ceiling_error_cm": float(np.max(ceil_err)) if ceil_err else None,
        "iou": iou,
        "iou_per_room": per_room,
        "features": features,
    }
    if labels is not None and true_labels is not None:
        lab = np.asarray(labels)
        tru = np.asarray(true_labels)
        shell = np.isin(tru, (WALL, FLOOR, CEILING))
        out["label_accuracy"] = float(np.mean(lab[shell] == tru[shell])) if shell.any() else None
        out["label_accuracy_per_class"] = {
            name: float(np.mean(lab[tru == c] == c)) if np.any(tru == c) else None
            for name, c in (("wall", WALL), ("floor", FLOOR), ("ceiling", CEILING))
        }
    return out


def evaluate_scan(
    layout_json: str | Path, scan_dir: str | Path, labels_ply: str | Path | None = None
) -> dict:
    """:func:`evaluate_layout` from files: a ``layout.json``, a synthetic scan folder
    (its ``ground_truth/``), and optionally the labelled mesh written with the layout."""
    from reroom.io.mesh import read_ply

    layout = json.loads(Path(layout_json).read_text())
    gt_dir = Path(scan_dir) / "ground_truth"
    truth = json.loads((gt_dir / "ground_truth.json").read_text())
    labels = true_labels = None
    if labels_ply is not None:
        labels = np.asarray(read_ply(labels_ply).vertex_attributes["label"])
        true_labels = np.asarray(read_ply(gt_dir / "vertices.ply").vertex_attributes["label"])
    return evaluate_layout(layout, truth["layout"], labels, true_labels)
