"""Render edited room models: from input frames or new cameras, composites, baked GI.

* :func:`render_edit` renders the edited model from input frames (their intrinsics and
  their recovered exposure ``t_j`` from ``SCAN/hdr/exposures.json``, so the picture sits
  next to the photo: what that camera would have recorded) and/or new cameras, and
  writes ``<name>_<view>.exr`` (linear, model radiance units, *before* the exposure) and
  ``<name>_<view>.png`` (radiance x ``t_j`` through the scan's camera response, as
  :func:`reroom.edit.rerender.rerender_inputs` does) plus ``<name>.json``.
* :func:`composite_insertion` inserts objects into an input photo by differential
  rendering (thesis §7.3): renders with and without the inserted objects at that frame,
  an object mask by ray casting, and :func:`reroom.edit.composite.differential_composite`.
* :func:`bake_edit` bakes per-vertex radiance of the edited model and exports PLY + glb.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from reroom.edit.apply import INSERT_PREFIX, edited_scene
from reroom.edit.edits import EditError, as_ops, edit_document
from reroom.edit.model import DEFAULT_MAX_DEPTH
from reroom.errors import ScanError
from reroom.hdr.exposures import load_exposures
from reroom.io.atomic import atomic_write_json
from reroom.io.images import write_exr, write_rgb8
from reroom.scan import Intrinsics

__all__ = [
    "bake_edit",
    "camera_from_json",
    "composite_insertion",
    "encode_response",
    "object_mask",
    "render_edit",
]


def encode_response(linear: np.ndarray, lut: np.ndarray) -> np.ndarray:
    """Linear camera values (``[0, 1]`` = black to white) to 8-bit levels through ``lut``.

    ``lut`` is the inverse response (level -> linear value, non-decreasing, as
    :func:`reroom.hdr.linearize.response_lut` returns); each value gets the level whose
    linear value is nearest, so ``lut[encode(x)]`` round-trips to within a level.
    """
    x = np.clip(np.asarray(linear, np.float64), 0.0, float(lut[-1]))
    hi = np.clip(np.searchsorted(lut, x), 1, len(lut) - 1)
    lo = hi - 1
    pick = np.where(np.abs(lut[lo] - x) <= np.abs(lut[hi] - x), lo, hi)
    return pick.astype(np.uint8)


def _frame_scale(exposures: dict[str, Any], j: int) -> np.ndarray | None:
    frames = exposures.get("frames", [])
    if j >= len(frames) or frames[j].get("scale") is None:
        return None
    return np.broadcast_to(np.asarray(frames[j]["scale"], float), (3,)).copy()


def _default_exposure(exposures: dict[str, Any]) -> np.ndarray:
    """For a new camera: the median exposure of the input frames (a typical one)."""
    scales = [
        np.broadcast_to(np.asarray(f["scale"], float), (3,))
        for f in exposures.get("frames", [])
        if f.get("scale") is not None
    ]
    return np.median(np.stack(scales), axis=0) if scales else np.ones(3)


def camera_from_json(
    cam: Mapping[str, Any], fallback: Intrinsics | None, source: str, i: int
) -> tuple[str, np.ndarray, Intrinsics]:
    """A new camera from a transforms.json-style dict.

    ``transform_matrix`` (or ``c2w``): 4x4 camera-to-world, OpenGL axes; intrinsics
    ``fl_x, fl_y, cx, cy, w, h`` (missing ones from ``fallback``, the scan's); optional
    ``name`` (default ``cam<i>``).
    """
    from reroom.scan.scan import _parse_intrinsics, validate_pose

    where = f"camera {i}"
    pose = cam.get("transform_matrix", cam.get("c2w"))
    if pose is None:
        raise EditError(f"{source}: {where} has no 'transform_matrix' (4x4 camera-to-world)")
    try:
        c2w = validate_pose(pose, Path(source), where)
        intr = _parse_intrinsics(Path(source), dict(cam), fallback, where)
    except ScanError as exc:
        raise EditError(str(exc)) from exc
    return str(cam.get("name", f"cam{i}")), c2w, intr


def _views(
    scan: Any,
    exposures: dict[str, Any],
    frames: Sequence[int] | None,
    cameras: Sequence[Mapping[str, Any]] | None,
    exposure: Sequence[float] | float | None,
    resolution_scale: float,
) -> list[dict[str, Any]]:
    usable = [j for j in range(len(scan.frames)) if _frame_scale(exposures, j) is not None] or list(
        range(len(scan.frames))
    )
    if frames is None and cameras is None:
        from reroom.edit.rerender import spread_frames

        frames = spread_frames(usable, 4)
    views = []
    for j in frames or []:
        if not 0 <= int(j) < len(scan.frames):
            raise EditError(
                f"{scan.root}: frame {j} does not exist (the scan has {len(scan.frames)} frames)"
            )
        frame = scan.frames[int(j)]
        t = _frame_scale(exposures, int(j))
        if exposure is not None:
            t = np.broadcast_to(np.asarray(exposure, float), (3,)).copy()
        elif t is None:
            t = _default_exposure(exposures)
        views.append(
            {
                "view": f"f{int(j):05d}",
                "kind": "frame",
                "frame": int(j),
                "c2w": frame.c2w,
                "intrinsics": frame.intrinsics,
                "exposure": t,
            }
        )
    fallback = scan.frames[0].intrinsics if scan.frames else None
    for i, cam in enumerate(cameras or []):
        name, c2w, intr = camera_from_json(cam, fallback, "<cameras>", i)
        t = (
            np.broadcast_to(np.asarray(exposure, float), (3,)).copy()
            if exposure is not None
            else np.broadcast_to(
                np.asarray(cam.get("exposure", _default_exposure(exposures)), float), (3,)
            ).copy()
        )
        views.append(
            {
                "view": name,
                "kind": "camera",
                "frame": None,
                "c2w": c2w,
                "intrinsics": intr,
                "exposure": t,
            }
        )
    for v in views:
        if resolution_scale != 1.0:
            v["intrinsics"] = v["intrinsics"].scaled(resolution_scale)
    return views


def render_edit(
    scan_dir: str | Path,
    edits: Any,
    out_dir: str | Path,
    *,
    frames: Sequence[int] | None = None,
    cameras: Sequence[Mapping[str, Any]] | None = None,
    spp: int = 64,
    name: str = "edit",
    invert_dir: str | Path | None = None,
    lights_dir: str | Path | None = None,
    layout_dir: str | Path | None = None,
    work_dir: str | Path | None = None,
    max_depth: int = DEFAULT_MAX_DEPTH,
    exposure: Sequence[float] | float | None = None,
    resolution_scale: float = 1.0,
    seed: int = 0,
    scene: dict[str, Any] | None = None,
    denoise: bool = True,
    progress: Callable[[str, int, int], None] | None = None,
) -> dict[str, Any]:
    """Render the edited model from input frames and/or new cameras.

    Parameters
    ----------
    scan_dir:
        The scan folder.
    edits:
        Edits (document, list of OPs, or one OP); ``[]`` renders the unedited model.
    out_dir:
        Output folder (created).
    frames:
        Input frame indices: each is rendered with that frame's pose, intrinsics and
        exposure ``t_j``. Default (with no ``cameras`` either): 4 frames spread over the capture
        (:func:`reroom.edit.rerender.spread_frames`).
    cameras:
        New cameras, transforms.json style: ``transform_matrix`` (4x4 camera-to-world,
        OpenGL axes), ``fl_x, fl_y, cx, cy, w, h`` (missing ones: the first frame's),
        optional ``name`` and ``exposure`` (default the median of the frames').
    spp:
        Samples per pixel.
    name:
        Prefix of the output files: ``<name>_<view>.exr|png`` (views ``f00012`` for
        frames, the camera's name for cameras) and ``<name>.json``.
    exposure:
        Overrides every view's exposure (a number or per-channel triple).
    resolution_scale:
        Resize every view (e.g. 0.5 for a quick look).
    scene:
        A scene dict from :func:`edited_scene` to render instead of building one.
    denoise:
        Pass each render through OIDN (:func:`reroom.render.denoise.denoise`), guided
        by the first hit's albedo and normal: clean pictures from few samples.
    progress:
        ``progress(stage, done, total)`` after each view.

    Returns
    -------
    dict
        The document written to ``<name>.json``: the edits, spp, and per view its file
        names, frame index or camera, exposure, intrinsics, pose and render seconds.
    """
    from reroom.render.frames import FrameRenderer
    from reroom.scan import load_scan

    scan_dir = Path(scan_dir)
    out = Path(out_dir)
    ops, _ = as_ops(edits)
    scan = load_scan(scan_dir, check_images=False)
    exposures, lut = load_exposures(scan_dir, scan.meta)
    views = _views(scan, exposures, frames, cameras, exposure, resolution_scale)
    t0 = time.perf_counter()
    if scene is None:
        scene = edited_scene(
            scan_dir,
            ops,
            invert_dir=invert_dir,
            lights_dir=lights_dir,
            layout_dir=layout_dir,
            work_dir=work_dir,
            max_depth=max_depth,
        )
    t_scene = time.perf_counter() - t0
    out.mkdir(parents=True, exist_ok=True)
    renderers: dict[Intrinsics, FrameRenderer] = {}
    rendered = []
    for k, v in enumerate(views):
        intr = v["intrinsics"]
        if intr not in renderers:  # one loaded scene (compiled kernels) per camera model
            renderers[intr] = FrameRenderer(scene, intr, spp, denoise=denoise)
        t1 = time.perf_counter()
        img = renderers[intr].render(v["c2w"], seed=seed + (v["frame"] or 0) * 7 + k)
        secs = time.perf_counter() - t1
        exr = write_exr(out / f"{name}_{v['view']}.exr", img)
        png = write_rgb8(out / f"{name}_{v['view']}.png", encode_response(img * v["exposure"], lut))
        rendered.append(
            {
                "view": v["view"],
                "kind": v["kind"],
                "frame": v["frame"],
                "exr": exr.name,
                "png": png.name,
                "exposure": np.asarray(v["exposure"], float).tolist(),
                "intrinsics": intr.to_json(),
                "transform_matrix": np.asarray(v["c2w"], float).tolist(),
                "seconds": round(secs, 3),
            }
        )
        if progress is not None:
            progress("render", k + 1, len(views))
    doc = {
        "format": "reroom-edit-render",
        "version": 1,
        "name": name,
        "scan": str(scan_dir),
        "edits": edit_document(ops),
        "spp": int(spp),
        "denoised": bool(denoise),
        "max_depth": int(max_depth),
        "response": exposures.get("response", "auto"),
        "units": "EXR: linear radiance in the model's units (the HDR mesh's), before exposure; "
        "PNG: radiance x exposure through the scan's camera response",
        "scene_seconds": round(t_scene, 3),
        "views": rendered,
    }
    atomic_write_json(out / f"{name}.json", doc)
    return doc


def _shape_meshes(scene: dict[str, Any]) -> list[tuple[str, Any]]:
    """``(key, trimesh)`` of every PLY shape of a scene dict."""
    from reroom.io.mesh import read_ply

    out = []
    for key, val in scene.items():
        if isinstance(val, dict) and val.get("type") == "ply" and "filename" in val:
            out.append((key, read_ply(val["filename"])))
    return out


def object_mask(
    scene: dict[str, Any], c2w: np.ndarray, intr: Intrinsics, supersample: int = 4
) -> np.ndarray:
    """Coverage ``(H, W)`` in ``[0, 1]`` of the ``insert_*`` shapes seen by a camera.

    Rays through a ``supersample`` x ``supersample`` grid in each pixel (Embree); a ray
    counts when its closest hit among all shapes is an inserted object.
    """
    import trimesh

    from reroom.rays import RayCaster
    from reroom.render.camera import subpixel_positions
    from reroom.scan.camera import Frame

    parts = _shape_meshes(scene)
    if not any(k.startswith(INSERT_PREFIX) for k, _ in parts):
        return np.zeros((intr.height, intr.width))
    meshes = [m for _, m in parts]
    owner = np.concatenate([np.full(len(m.faces), k.startswith(INSERT_PREFIX)) for k, m in parts])
    combined = trimesh.util.concatenate(
        [trimesh.Trimesh(m.vertices, m.faces, process=False) for m in meshes]
    )
    caster = RayCaster(combined)
    s = int(supersample)
    frame = Frame(index=0, c2w=np.asarray(c2w, float), intrinsics=intr, image_path=Path("-"))
    o, d = frame.pixel_rays(subpixel_positions(0, intr.width, 0, intr.height, s))
    hits = caster.intersect(o, d)
    obj = hits.hit & owner[np.maximum(hits.face, 0)]
    return obj.reshape(intr.height, intr.width, s * s).mean(-1)


def _smooth_outside(img: np.ndarray, mask: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian blur of ``img`` over the pixels outside ``mask`` (normalised convolution)."""
    if sigma <= 0:
        return np.asarray(img, np.float64)
    from scipy.ndimage import gaussian_filter

    # Only pixels the objects do not cover at all: an edge pixel's render holds object light.
    w = (np.asarray(mask) <= 0).astype(np.float64)
    num = np.stack(
        [gaussian_filter(img[..., c] * w, sigma, mode="nearest") for c in range(img.shape[-1])],
        -1,
    )
    den = gaussian_filter(w, sigma, mode="nearest")[..., None]
    return np.where(den > 1e-6, num / np.maximum(den, 1e-12), img)


def composite_insertion(
    scan_dir: str | Path,
    edits: Any,
    frame: int,
    out_dir: str | Path,
    *,
    spp: int = 64,
    name: str = "composite",
    mode: str = "ratio",
    invert_dir: str | Path | None = None,
    lights_dir: str | Path | None = None,
    layout_dir: str | Path | None = None,
    work_dir: str | Path | None = None,
    max_depth: int = DEFAULT_MAX_DEPTH,
    seed: int = 0,
    smooth_px: float = 1.5,
) -> dict[str, Any]:
    """Insert the edits' objects into input frame ``frame`` by differential rendering.

    The model is rendered at the frame's camera with the edits (``render_with``) and
    with the same edits minus the inserted objects (``render_without``), with the same
    seed (so their Monte-Carlo noise is correlated and mostly cancels in the ratio);
    the linearised photo, divided by the frame's exposure ``t_j`` into model units, is
    composited by :func:`reroom.edit.composite.differential_composite`: object pixels
    from the render, elsewhere ``photo x with / without`` (``mode="ratio"``) so the
    objects' shadows and reflected light land on the photographed surfaces.

    ``smooth_px`` is the Gaussian sigma (pixels) over which both renders are averaged
    before their ratio is taken, outside the objects' coverage (0: per pixel).

    Writes ``<name>_f<frame>.png`` (through the camera response, like the photo),
    ``<name>_f<frame>.exr`` (linear, model units), ``<name>_f<frame>_mask.png`` and
    ``<name>_f<frame>.json``; returns that document.

    Raises
    ------
    EditError
        When the edits insert no object, or the frame does not exist.
    """
    from reroom.edit.composite import differential_composite
    from reroom.render.frames import FrameRenderer
    from reroom.scan import load_scan

    scan_dir = Path(scan_dir)
    ops, _ = as_ops(edits)
    if not any(op["op"] == "insert" for op in ops):
        raise EditError("<edits>: a composite needs at least one 'insert' edit")
    scan = load_scan(scan_dir, check_images=False)
    if not 0 <= int(frame) < len(scan.frames):
        raise EditError(
            f"{scan_dir}: frame {frame} does not exist (the scan has {len(scan.frames)} frames)"
        )
    exposures, lut = load_exposures(scan_dir, scan.meta)
    fr = scan.frames[int(frame)]
    t = _frame_scale(exposures, int(frame))
    if t is None:
        raise EditError(f"{scan_dir}: frame {frame} has no recovered exposure (exposures.json)")
    kw = dict(
        invert_dir=invert_dir,
        lights_dir=lights_dir,
        layout_dir=layout_dir,
        work_dir=work_dir,
        max_depth=max_depth,
    )
    with_scene = edited_scene(scan_dir, ops, **kw)
    without = {k: v for k, v in with_scene.items() if not k.startswith(INSERT_PREFIX)}
    r_with = FrameRenderer(with_scene, fr.intrinsics, spp).render(fr.c2w, seed=seed)
    r_without = FrameRenderer(without, fr.intrinsics, spp).render(fr.c2w, seed=seed)
    mask = object_mask(with_scene, fr.c2w, fr.intrinsics)
    raw = fr.load_image()
    photo = lut[raw] / t  # model units
    # The background ratio with / without is smoothed over the surfaces (not across the
    # objects): far from them, paths that meet an object at a late bounce make the
    # per-pixel ratio noisy (12-16 % at 64 spp on `furnished`) while its expectation
    # varies slowly; the objects' own pixels come from the unsmoothed render.
    sm_with, sm_without = (
        _smooth_outside(r_with, mask, smooth_px),
        _smooth_outside(r_without, mask, smooth_px),
    )
    background = differential_composite(photo, sm_with, sm_without, np.zeros_like(mask), mode=mode)
    m = mask[..., None]
    comp = np.maximum(m * r_with + (1.0 - m) * background, 0.0)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stem = f"{name}_f{int(frame):05d}"
    write_exr(out / f"{stem}.exr", comp.astype(np.float32))
    png = encode_response(comp * t, lut)
    # Pixels the edit does not change keep the photo's exact 8-bit values.
    same = (mask == 0) & np.all(np.abs(sm_with - sm_without) <= 1e-7, axis=-1)
    png[same] = raw[same]
    write_rgb8(out / f"{stem}.png", png)
    write_rgb8(
        out / f"{stem}_mask.png", np.repeat((mask * 255 + 0.5).astype(np.uint8)[..., None], 3, -1)
    )
    doc = {
        "format": "reroom-edit-composite",
        "version": 1,
        "frame": int(frame),
        "mode": mode,
        "spp": int(spp),
        "edits": edit_document(ops),
        "exposure": t.tolist(),
        "png": f"{stem}.png",
        "exr": f"{stem}.exr",
        "mask": f"{stem}_mask.png",
        "object_pixels": float(mask.sum()),
        "changed_pixels": int((~same).sum()),
    }
    atomic_write_json(out / f"{stem}.json", doc)
    return doc


def bake_edit(
    scan_dir: str | Path,
    edits: Any,
    out_dir: str | Path,
    *,
    spp: int = 64,
    name: str = "baked",
    max_edge: float = 0.20,
    invert_dir: str | Path | None = None,
    lights_dir: str | Path | None = None,
    layout_dir: str | Path | None = None,
    work_dir: str | Path | None = None,
    max_depth: int = DEFAULT_MAX_DEPTH,
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, Any]:
    """Bake the edited model's per-vertex radiance; write ``<name>.ply`` and ``<name>.glb``.

    Every non-emitting PLY surface of the edited scene is joined into one mesh (the
    layout's shell behind the scan too: it fills the scan's holes in a viewer as in a
    render, and bakes dark where the scan hides it); large faces (the shells') are
    subdivided to at most ``max_edge`` metres so the
    vertex colours can show the light's variation. Vertex normals are the surface's
    (the scan mesh and the shell face into the room), so each vertex's baked radiance is
    what a viewer inside the room sees.
    """
    import trimesh

    from reroom.edit.bake import bake_vertex_radiance, export_baked

    ops, _ = as_ops(edits)
    scene = edited_scene(
        scan_dir,
        ops,
        invert_dir=invert_dir,
        lights_dir=lights_dir,
        layout_dir=layout_dir,
        work_dir=work_dir,
        max_depth=max_depth,
    )
    meshes = []
    for key, m in _shape_meshes(scene):
        if "emitter" in scene[key]:
            continue
        # Shapes may list vertices their faces do not use (a label's faces of the shell):
        # they have no normal and nothing to bake.
        m = trimesh.Trimesh(m.vertices, m.faces, process=False)
        m.remove_unreferenced_vertices()
        v, f = np.asarray(m.vertices, float), np.asarray(m.faces)
        if len(f) and trimesh.Trimesh(v, f, process=False).edges_unique_length.max() > max_edge:
            v, f = trimesh.remesh.subdivide_to_size(v, f, max_edge=max_edge)
        meshes.append(trimesh.Trimesh(v, f, process=False))
    mesh = trimesh.util.concatenate(meshes)
    t0 = time.perf_counter()
    baked = bake_vertex_radiance(
        scene, mesh.vertices, mesh.vertex_normals, spp=spp, progress=progress
    )
    files = export_baked(mesh, baked, out_dir, name)
    doc = {
        "format": "reroom-edit-bake",
        "version": 1,
        "edits": edit_document(ops),
        "spp": int(spp),
        "vertices": int(len(mesh.vertices)),
        "seconds": round(time.perf_counter() - t0, 3),
        "files": {k: Path(p).name for k, p in files.items()},
        "median_stderr_over_radiance": float(
            np.median(baked.stderr.mean(1) / np.maximum(baked.radiance.mean(1), 1e-12))
        ),
    }
    atomic_write_json(Path(out_dir) / f"{name}.json", doc)
    return doc
