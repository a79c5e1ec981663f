"""Check a generated scan's ground truth against its own frames.

The frames are predicted from the ground truth alone -- per-vertex radiance,
per-frame exposure x white balance, the response curve -- and compared with
the 8-bit images on diffuse, untextured surfaces. Agreement within noise and
quantisation means the truth is what the frames show; a wrong exposure
convention, response or radiance scale shows up as a bias.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from reroom.io.mesh import read_ply
from reroom.rays import RayCaster
from reroom.scan import Scan, load_scan
from reroom.synth.camera_sim import apply_response, inverse_response
from reroom.synth.labels import LABELS

DIFFUSE_UNTEXTURED = ("wall", "ceiling", "door", "baseboard")


@dataclass
class ConsistencyReport:
    """Agreement between frames and their prediction from the ground truth."""

    samples: int
    ratio_of_means: float  # mean observed / mean predicted linear value (the bias check)
    median_ratio: float  # median of observed / predicted linear value
    median_abs_log_ratio: float
    median_abs_level_diff: float  # in 8-bit levels
    p90_abs_level_diff: float
    frames_used: int

    def to_json(self) -> dict:
        return dict(self.__dict__)


def predict_and_observe(
    scan: Scan,
    labels: tuple[str, ...] = DIFFUSE_UNTEXTURED,
    max_frames: int | None = None,
    min_level: int = 12,
    max_level: int = 243,
    smooth_tol: int = 255,
) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of (observed, predicted) 8-bit values for visible vertices with the given labels.

    A vertex is used in a frame when the camera sees it (ray cast), it projects
    at least 2 pixels inside the image, every pixel of its 3x3 neighbourhood
    sees the same part of the scene (ray cast, so object edges are excluded
    without looking at the noisy pixels), and the observed value is neither
    dark nor saturated. ``smooth_tol`` optionally also requires the observed
    3x3 neighbourhood to vary by at most that many levels.
    """
    gt_dir = scan.ground_truth_dir
    truth = json.loads((gt_dir / "ground_truth.json").read_text())
    gt = read_ply(gt_dir / "vertices.ply")
    attrs = gt.vertex_attributes
    radiance = np.asarray(attrs["radiance"], float)
    label = np.asarray(attrs["label"])
    part = np.asarray(attrs["part"])
    face_part = part[np.asarray(scan.mesh.faces)[:, 0]]
    want = np.isin(label, [LABELS[name] for name in labels])
    response = scan.meta.get("reroom", {}).get("response", "gamma2.2")
    verts = np.asarray(scan.mesh.vertices)
    normals = np.asarray(gt.vertex_normals) if len(verts) else verts
    caster = RayCaster(scan.mesh)
    observed, predicted = [], []
    frames = scan.frames if max_frames is None else scan.frames[:max_frames]
    idx_all = np.flatnonzero(want)
    for frame in frames:
        uv, _, inside = frame.project(verts[idx_all])
        k = frame.intrinsics
        inside &= (
            (uv[:, 0] >= 2) & (uv[:, 0] < k.width - 2) & (uv[:, 1] >= 2) & (uv[:, 1] < k.height - 2)
        )
        idx = idx_all[inside]
        if len(idx) == 0:
            continue
        facing = np.einsum("ij,ij->i", normals[idx], frame.center - verts[idx]) > 0
        idx = idx[facing]
        vis = caster.visible_points(verts[idx], normals[idx], frame.center)
        idx = idx[vis]
        if len(idx) == 0:
            continue
        img = frame.load_image().astype(np.int32)
        o, d = frame.pixel_rays()
        hits = caster.intersect(o, d)
        part_img = np.where(hits.hit, face_part[np.maximum(hits.face, 0)], -1).reshape(
            k.height, k.width
        )
        uvi, _, _ = frame.project(verts[idx])
        col = np.floor(uvi[:, 0]).astype(int)
        row = np.floor(uvi[:, 1]).astype(int)
        offsets = [(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1)]
        patch = np.stack([img[row + dr, col + dc] for dr, dc in offsets], 1)
        same_part = np.all(
            np.stack([part_img[row + dr, col + dc] for dr, dc in offsets], 1) == part[idx][:, None],
            axis=1,
        )
        smooth = same_part & ((patch.max(1) - patch.min(1)).max(1) <= smooth_tol)
        obs = img[row, col]
        scale = np.asarray(truth["frames"][frame.index]["scale"], float)
        pred = np.clip(np.round(255 * apply_response(radiance[idx] * scale, response)), 0, 255)
        ok = smooth & (obs.min(1) >= min_level) & (obs.max(1) <= max_level)
        observed.append(obs[ok])
        predicted.append(pred[ok])
    if not observed:
        return np.zeros((0, 3)), np.zeros((0, 3))
    return np.vstack(observed).astype(float), np.vstack(predicted).astype(float)


def check_consistency(scan_dir: str | Path, **kwargs) -> ConsistencyReport:
    """Compare a generated scan's frames with their prediction from its ground truth."""
    scan = load_scan(scan_dir)
    obs, pred = predict_and_observe(scan, **kwargs)
    response = scan.meta.get("reroom", {}).get("response", "gamma2.2")
    lin_o = inverse_response(obs / 255.0, response)
    lin_p = np.maximum(inverse_response(pred / 255.0, response), 1e-6)
    ratio = lin_o / lin_p
    diff = np.abs(obs - pred)
    return ConsistencyReport(
        samples=int(obs.size),
        # Monte-Carlo estimates are right-skewed at low sample counts, so medians
        # of them read low; the ratio of means is the unbiased comparison.
        ratio_of_means=float(lin_o.mean() / lin_p.mean()) if obs.size else float("nan"),
        median_ratio=float(np.median(ratio)) if obs.size else float("nan"),
        median_abs_log_ratio=float(np.median(np.abs(np.log(np.maximum(ratio, 1e-6)))))
        if obs.size
        else float("nan"),
        median_abs_level_diff=float(np.median(diff)) if obs.size else float("nan"),
        p90_abs_level_diff=float(np.percentile(diff, 90)) if obs.size else float("nan"),
        frames_used=len(scan.frames),
    )
