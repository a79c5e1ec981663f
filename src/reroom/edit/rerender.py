"""Re-render input frames from the recovered model, next to the photos (issue #5 output).

Each chosen frame is rendered with its own camera, multiplied by the frame's exposure
scale ``t_j`` from ``SCAN/hdr/exposures.json`` (so it is what the camera would have
recorded of the model), and set beside the linearised photo. The figures say how well
the model explains the captured appearance: the ratio of mean brightness and the
relative L1 difference over pixels that are neither black nor clipped. Both images
carry noise (the photo sensor and Monte-Carlo noise; the render Monte-Carlo noise), so
L1 has a floor well above zero; the ratio of means does not.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from reroom.errors import ScanError
from reroom.io.atomic import atomic_write_json
from reroom.io.images import write_rgb8

__all__ = ["rerender_inputs", "spread_frames"]


def spread_frames(usable: list[int], count: int) -> list[int]:
    """``count`` of the frame indices ``usable``, one from the middle of each of ``count``
    equal stretches of the capture.

    Not the first and the last frame: a capture that walks round the room ends where it
    started (the synthetic scans' orbit does), so those two show the same view; the
    middles of the stretches look at different parts of the room on a loop and on a
    sweep alike.

    Raises
    ------
    ValueError
        ``usable`` is empty (no frame to render at).
    """
    if len(usable) == 0:
        raise ValueError("no usable frame to pick from (none has an exposure)")
    n = max(1, min(int(count), len(usable)))
    return [usable[int((k + 0.5) * len(usable) / n)] for k in range(n)]


def _encode(linear: np.ndarray, gamma: float = 2.2) -> np.ndarray:
    return (np.clip(linear, 0.0, 1.0) ** (1.0 / gamma) * 255.0 + 0.5).astype(np.uint8)


def rerender_inputs(
    scan_dir: str | Path,
    invert_dir: str | Path | None = None,
    lights_dir: str | Path | None = None,
    frames: int = 4,
    spp: int = 16,
    unit_scale: np.ndarray | float = 1.0,
    out_dir: str | Path | None = None,
    denoise: bool = True,
) -> dict[str, Any]:
    """Render ``frames`` input frames (:func:`spread_frames`) from the model; write a comparison.

    Parameters
    ----------
    unit_scale:
        Factor from the model's radiance units to the HDR mesh's (1 for a model solved on
        the HDR mesh; the reference frame's true scale for one solved on the synthetic
        truth's radiance, an evaluation-only case).
    out_dir:
        Where ``rerender.png`` (photo | render, one frame a row) and ``rerender.json``
        go (default: the invert folder).
    denoise:
        Denoise the renders (:func:`reroom.render.denoise.denoise`).

    Returns
    -------
    dict
        Per frame: ``index``, ``ratio_of_means``, ``relative_l1``, ``pixels``; and the
        medians.
    """
    from reroom.edit.apply import edited_scene
    from reroom.hdr.exposures import load_exposures
    from reroom.render.frames import FrameRenderer
    from reroom.scan import load_scan

    scan_dir = Path(scan_dir)
    inv = Path(invert_dir) if invert_dir is not None else scan_dir / "invert"
    out = Path(out_dir) if out_dir is not None else inv
    scan = load_scan(scan_dir)
    exposures, lut = load_exposures(scan_dir, scan.meta)
    # The unedited model exactly as the edits render it (fittings, glowing surfaces).
    scene = edited_scene(
        scan_dir, [], invert_dir=inv, lights_dir=lights_dir, work_dir=out / "model_meshes"
    )
    usable = [
        j
        for j, f in enumerate(exposures["frames"])
        if f.get("scale") is not None and j < len(scan.frames)
    ]
    if not usable:
        raise ScanError(
            scan_dir / "hdr" / "exposures.json", "gives no frame an exposure: nothing to render at"
        )
    pick = spread_frames(usable, frames)
    renderer: FrameRenderer | None = None
    rows, per_frame = [], []
    scale = np.broadcast_to(np.asarray(unit_scale, float), (3,))
    for j in pick:
        frame = scan.frames[j]
        if renderer is None:
            renderer = FrameRenderer(scene, frame.intrinsics, spp, denoise=denoise)
        t = np.asarray(exposures["frames"][j]["scale"], float)
        pred = renderer.render(frame.c2w, seed=j) * t * scale
        raw = frame.load_image()
        photo = lut[raw]
        ok = (raw.max(axis=-1) < 250) & (raw.max(axis=-1) > 5)
        denom = float(photo[ok].sum())
        per_frame.append(
            {
                "index": int(j),
                "ratio_of_means": float(pred[ok].sum() / denom) if denom > 0 else None,
                "relative_l1": float(np.abs(pred - photo)[ok].sum() / denom) if denom else None,
                "pixels": int(ok.sum()),
            }
        )
        rows.append(np.concatenate([raw, _encode(pred)], axis=1))
    out.mkdir(parents=True, exist_ok=True)
    write_rgb8(out / "rerender.png", np.concatenate(rows, axis=0))

    def med(key: str) -> float | None:
        vals = [f[key] for f in per_frame if f[key] is not None]
        return float(np.median(vals)) if vals else None

    doc = {
        "frames": per_frame,
        "median_ratio_of_means": med("ratio_of_means"),
        "median_relative_l1": med("relative_l1"),
        "spp": spp,
        "denoised": bool(denoise),
        "unit_scale": scale.tolist(),
        "picture": "rerender.png",
    }
    atomic_write_json(out / "rerender.json", doc)
    return doc
