"""Denoised renders (``reroom.render.denoise``): how close to a converged render, at what cost.

Three parts; the figures of docs/edit.md, "Denoising":

* **Box room** (always): a closed 4 x 3 x 2.5 m room of albedo (0.7, 0.6, 0.5) lit by a
  ceiling panel 20x brighter than the walls, at 96x72 and 256x192. Relative RMSE against a
  1024-spp render of: the plain render; OIDN on the whole render with the albedo/normal
  guides ("guided, panel in"); and ``FrameRenderer(denoise=True)``, which keeps directly
  seen emission out of the denoiser ("split"). Over all pixels and away from the panel
  (4 pixels around it left out).
* **Cost** (always): one 640x360 frame of the box room at 4 spp: the path tracer alone,
  wrapped in Mitsuba's ``aov`` integrator, the separate ``aov`` pass, the depth-1 pass, and
  OIDN itself (seconds, the second of two runs).
* **A scan's model** (``--scan SCAN --frame J``): input frame J of ``edited_scene(SCAN,
  [])`` (a scan with ``invert/``), relative RMSE against a ``--ref-spp`` render of the same
  model: 16 spp plain, 4 and 16 spp denoised.

Usage::

    python benchmarks/bench_denoise.py [--scan SCAN --frame 75 --ref-spp 256]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh
from scipy import ndimage

from reroom.io.mesh import write_ply
from reroom.render.camera import mitsuba_to_world
from reroom.render.denoise import denoise
from reroom.render.frames import FrameRenderer
from reroom.scan import Intrinsics, look_at

EYE, TARGET = np.array([-1.5, -1.0, 1.4]), np.array([1.5, 1.0, 1.0])


def box_room(tmp: Path) -> dict:
    """The box room's Mitsuba scene dict (meshes written to ``tmp``)."""
    box = trimesh.creation.box(extents=[4.0, 3.0, 2.5])
    box.apply_translation([0.0, 0.0, 1.25])
    box.invert()
    panel = trimesh.Trimesh(
        [[-0.3, -0.3, 2.49], [0.3, -0.3, 2.49], [0.3, 0.3, 2.49], [-0.3, 0.3, 2.49]],
        [[0, 2, 1], [0, 3, 2]],
        process=False,
    )
    white = {"type": "rgb", "value": [0.7, 0.6, 0.5]}
    return {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 8},
        "room": {
            "type": "ply",
            "filename": str(write_ply(tmp / "room.ply", box, {})),
            "face_normals": True,
            "bsdf": {"type": "diffuse", "reflectance": white},
        },
        "panel": {
            "type": "ply",
            "filename": str(write_ply(tmp / "panel.ply", panel, {})),
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 20.0}},
        },
    }


def rel_rmse(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    if mask is not None:
        a, b = a[mask], b[mask]
    return float(np.sqrt(np.mean((a - b) ** 2)) / np.sqrt(np.mean(b**2)))


def _pc(x: float) -> str:
    return f"{100 * x:.1f} %"


def box_accuracy(scene: dict) -> None:
    print(
        "| size | spp | plain | guided, panel in | split (reroom) | plain / split away from the panel |"
    )
    print("|---|---|---|---|---|---|")
    for w, h in ((96, 72), (256, 192)):
        intr = Intrinsics.from_fov(w, h, 70.0)
        c2w = look_at(EYE, TARGET)
        ref = FrameRenderer(scene, intr, 1024).render(c2w, seed=7)
        away = ~ndimage.binary_dilation(ref.max(axis=2) > 5.0, iterations=4)
        for spp in (4, 16, 64):
            r = FrameRenderer(scene, intr, spp, denoise=True)
            mi = r.mi
            r.params["sensor.to_world"] = mitsuba_to_world(c2w)
            r.params.update()
            plain = np.asarray(mi.render(r.scene, spp=spp, seed=1), np.float32)[..., :3]
            aux = np.asarray(mi.render(r.scene, integrator=r._aux, spp=4, seed=1), np.float32)
            guided = denoise(plain, aux[..., -6:-3], aux[..., -3:])
            split = r.render(c2w, seed=1)
            print(
                f"| {w}x{h} | {spp} | {_pc(rel_rmse(plain, ref))} | {_pc(rel_rmse(guided, ref))} "
                f"| {_pc(rel_rmse(split, ref))} | {_pc(rel_rmse(plain, ref, away))} / "
                f"{_pc(rel_rmse(split, ref, away))} |",
                flush=True,
            )


def _timed(fn) -> float:
    fn()
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def box_cost(scene: dict) -> None:
    from reroom.render import mitsuba
    from reroom.render.denoise import AUX_AOVS

    mi = mitsuba()
    intr = Intrinsics.from_fov(640, 360, 70.0)
    c2w = look_at(EYE, TARGET)
    r = FrameRenderer(scene, intr, 4, denoise=True)
    r.params["sensor.to_world"] = mitsuba_to_world(c2w)
    r.params.update()
    wrapped = mi.load_dict({"type": "aov", "aovs": AUX_AOVS, "inner": scene["integrator"]})
    img = np.asarray(mi.render(r.scene, spp=4, seed=0), np.float32)[..., :3]
    aux = np.asarray(mi.render(r.scene, integrator=r._aux, spp=4, seed=0), np.float32)
    rows = [
        ("path tracer, 4 spp", lambda: mi.render(r.scene, spp=4, seed=0)),
        (
            "path tracer inside the aov integrator",
            lambda: mi.render(r.scene, integrator=wrapped, spp=4),
        ),
        ("aov pass alone (albedo, normal)", lambda: mi.render(r.scene, integrator=r._aux, spp=4)),
        (
            "depth-1 pass (emission seen directly)",
            lambda: mi.render(r.scene, integrator=r._direct, spp=4),
        ),
        ("OIDN", lambda: denoise(img, aux[..., -6:-3], aux[..., -3:])),
        ("FrameRenderer(denoise=True).render", lambda: r.render(c2w, seed=0)),
    ]
    print("\n| 640x360, box room | seconds |\n|---|---|")
    for name, fn in rows:
        print(f"| {name} | {_timed(fn):.3f} |", flush=True)


def scan_model(scan: Path, frame: int, ref_spp: int, work: Path) -> None:
    from reroom.edit.apply import edited_scene
    from reroom.scan import load_scan

    f = load_scan(scan, check_images=False).frames[frame]
    scene = edited_scene(scan, [], work_dir=work / "model")
    ref = FrameRenderer(scene, f.intrinsics, ref_spp).render(f.c2w, seed=99)
    ok = np.isfinite(ref).all(axis=2)
    print(f"\n| {scan.name} frame {frame}, against {ref_spp} spp | relative RMSE |\n|---|---|")
    for spp, dn in ((16, False), (4, True), (16, True)):
        img = FrameRenderer(scene, f.intrinsics, spp, denoise=dn).render(f.c2w, seed=1)
        label = f"{spp} spp" + (", denoised" if dn else "")
        print(f"| {label} | {_pc(rel_rmse(img, ref, ok))} |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--scan", type=Path, default=None, help="a scan with invert/")
    ap.add_argument("--frame", type=int, default=0)
    ap.add_argument("--ref-spp", type=int, default=256)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        scene = box_room(Path(tmp))
        box_accuracy(scene)
        box_cost(scene)
        if args.scan is not None:
            scan_model(args.scan, args.frame, args.ref_spp, Path(tmp))


if __name__ == "__main__":
    main()
