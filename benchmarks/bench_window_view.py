"""The window seen directly: each run's window map against the true sky, view by view.

Usage::

    python benchmarks/bench_window_view.py RUN [OTHER_RUN ...] [--window window0]
        [--frames auto] [--oracle-cells 4,8,16]

``RUN`` is a finished ``reroom run`` of a synthetic scan (``invert/`` and
``ground_truth/``); the other runs are runs of the same scan (e.g. the folders of
``bench_invert_sweep.py``). For the views of ``bench_edit_fidelity.py`` (its two new
cameras) and the input frames that see the most of the window (``--frames auto``: the
three with the most pixels through it; or a comma list), every pixel whose ray leaves
the room through the window (the scan mesh hit first, :func:`rays_through_windows`)
looks up

* each run's ``invert/window_<name>.exr`` (what the renderer shows there) over that run's
  radiance scale ``k`` (:func:`reroom.invert.evaluate.evaluate_invert`);
* the truth: the true HDRI times its scale, turned as the true window turns it;
* oracles: the true HDRI averaged over each cell of an ``n x n``-a-face cube map
  (:func:`reroom.invert.evaluate.true_window_cells`), what a perfect solve in that basis
  would show where no photo saw the sky;

and prints the relative RMSE over those pixels (``||ours - truth|| / ||truth||``, all
channels) and the ratio of sums per channel. Nearest texel, one ray per pixel centre.
This separates what a better solve could still win in the view through the window
from what the cells cannot draw (the sky's detail within a cell). It is evaluation: it
reads ``ground_truth/``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def _views(run: Path, frames: str, caster, openings) -> list[tuple[str, object]]:
    """The fidelity benchmark's new cameras and the input frames chosen by ``frames``."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_edit_fidelity import new_cameras

    from reroom.invert.windows import rays_through_windows
    from reroom.scan import load_scan
    from reroom.scan.camera import Frame, Intrinsics

    gt = json.loads((run / "ground_truth" / "ground_truth.json").read_text())
    scan = load_scan(run, check_images=False)
    intr0 = scan.frames[0].intrinsics
    intr = Intrinsics.from_fov(intr0.width, intr0.height, 70.0)
    views = [(n, Frame(-1, Path(n), c2w, intr)) for n, c2w, _ in new_cameras(gt["layout"], intr)]
    if frames == "auto":
        counts = []
        for f in scan.frames:
            w, h = f.intrinsics.width, f.intrinsics.height
            uv = np.stack(np.meshgrid(np.arange(2, w, 4) + 0.5, np.arange(2, h, 4) + 0.5), -1)
            o, d = _rays(f, uv.reshape(-1, 2))
            hits = caster.intersect(o, d)
            counts.append(int((rays_through_windows(o, d, hits.t, openings) >= 0).sum()))
        chosen = [int(j) for j in np.argsort(counts)[::-1][:3] if counts[j] > 0]
    else:
        chosen = [int(x) for x in frames.split(",") if x.strip()]
    bad = [j for j in chosen if not 0 <= j < len(scan.frames)]
    if bad:
        raise SystemExit(f"--frames: no frame {bad} (the scan has {len(scan.frames)})")
    return views + [(f"f{j:05d}", scan.frames[j]) for j in chosen]


def _rays(frame, uv=None) -> tuple[np.ndarray, np.ndarray]:
    o, d = frame.pixel_rays(uv)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    return np.broadcast_to(o, d.shape).copy() if o.ndim == 1 else o, d


def _turn_z(d: np.ndarray, degrees: float) -> np.ndarray:
    """``d`` turned by ``degrees`` about +Z (as :func:`reroom.invert.evaluate` turns the
    HDRI's texel directions by the window's ``rotation_deg``)."""
    r = np.deg2rad(degrees)
    c, s = np.cos(r), np.sin(r)
    return d @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("runs", type=Path, nargs="+")
    ap.add_argument("--window", default="window0", help="the model's window (scene.json)")
    ap.add_argument("--frames", default="auto", help="input frames: auto or a comma list")
    ap.add_argument("--oracle-cells", default="4,8,16", help="n of the true-cell oracles")
    args = ap.parse_args()

    import trimesh

    from reroom.invert.basis import CubemapBasis
    from reroom.invert.evaluate import evaluate_invert, true_window_cells
    from reroom.invert.window_env import _texel_index
    from reroom.invert.windows import WindowOpening, rays_through_windows
    from reroom.io.images import read_exr
    from reroom.rays import RayCaster

    run = args.runs[0]
    for r in args.runs:
        if not (r / "invert" / "scene.json").is_file():
            raise SystemExit(f"{r}/invert/scene.json is missing: run `reroom run` first")
    scene_dir = run / "ground_truth" / "scene"
    if not (scene_dir / "scene.json").is_file():
        raise SystemExit(f"{scene_dir}/scene.json is missing: a synthetic scan's truth is needed")
    true_windows = [
        x for x in json.loads((scene_dir / "scene.json").read_text())["lights"]
        if x["type"] == "window"
    ]  # fmt: skip
    doc = json.loads((run / "invert" / "scene.json").read_text())
    entry = next((x for x in doc["lights"] if x.get("name") == args.window), None)
    if entry is None or entry.get("type") != "window":
        raise SystemExit(f"{run}/invert/scene.json has no window named {args.window!r}")
    g = entry["geometry"]
    opening = WindowOpening(
        args.window, *(np.asarray(g[k], float) for k in ("centre", "half_u", "half_v", "normal"))
    )
    # The true window this one stands for: the nearest centre.
    truth_w = min(
        true_windows,
        key=lambda t: np.linalg.norm(np.mean(t["corners"], axis=0) - opening.centre),
        default=None,
    )
    if truth_w is None:
        raise SystemExit(f"{scene_dir}: the true scene has no window")
    hdri = np.maximum(read_exr(scene_dir / truth_w["hdri_file"])[..., :3].astype(float), 0.0)
    hdri *= float(truth_w.get("scale", 1.0))
    rotation = float(truth_w.get("rotation_deg", 0.0))

    maps = {}
    for r in args.runs:
        e = next(x for x in json.loads((r / "invert" / "scene.json").read_text())["lights"]
                 if x.get("name") == args.window)  # fmt: skip
        k = np.asarray(evaluate_invert(r)["radiance_scale"], float)
        maps[r.name] = read_exr(r / "invert" / e["environment_exr"])[..., :3].astype(float) / k
        if e.get("view_exr"):  # what a camera looking out is shown (the photos' view)
            view = read_exr(r / "invert" / e["view_exr"])[..., :3].astype(float) / k
            maps[f"{r.name} (view)"] = view
    for n in (int(x) for x in args.oracle_cells.split(",") if x.strip()):
        from reroom.invert.export import latlong_from_cubemap

        cells, _ = true_window_cells(truth_w, scene_dir, n=n)
        maps[f"true {n}x{n} cells"] = latlong_from_cubemap(cells, CubemapBasis(n), 256)

    mesh = trimesh.load(run / "mesh.ply", process=False)
    caster = RayCaster(mesh)
    views = _views(run, args.frames, caster, [opening])
    scale = truth_w.get("scale", 1.0)
    print(f"`{args.window}` seen directly (truth: {truth_w['hdri_file']} x {scale})")
    print("relative RMSE over the pixels through the window; ratio of sums r/g/b\n")
    print("| view | pixels | " + " | ".join(maps) + " |")
    print("|---|---|" + "---|" * len(maps))
    for name, frame in views:
        o, d = _rays(frame)
        hits = caster.intersect(o, d)
        through = rays_through_windows(o, d, hits.t, [opening]) == 0
        if not through.any():
            print(f"| {name} | 0 | " + " | ".join("-" for _ in maps) + " |")
            continue
        dd = d[through]
        truth = hdri.reshape(-1, 3)[_texel_index(_turn_z(dd, -rotation), hdri.shape[0])]
        cols = []
        for env in maps.values():
            ours = env.reshape(-1, 3)[_texel_index(dd, env.shape[0])]
            rel = np.sqrt(((ours - truth) ** 2).sum() / max((truth**2).sum(), 1e-300))
            ratio = ours.sum(axis=0) / np.maximum(truth.sum(axis=0), 1e-300)
            cols.append(f"{100 * rel:.0f} % ({'/'.join(f'{x:.2f}' for x in ratio)})")
        print(f"| {name} | {int(through.sum())} | " + " | ".join(cols) + " |")


if __name__ == "__main__":
    main()
