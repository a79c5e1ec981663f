"""Is a render the sum of its lights? Mitsuba's samplers side by side (session 45).

    python benchmarks/bench_sampler.py [--spp 64] [--run RUN --frame 30]

Two scenes, each rendered with every sampler at the same seeds:

- the six-plane room of ``tests/test_render_sampler.py`` (a lamp by a corner): the lamp
  alone over the lamp beside a dark second light, and two lights alone and summed over
  the two together (both 1 for an unbiased sampler);
- with ``--run``, a finished run's recovered model seen from one input frame, with only
  its point lights on (``reroom.edit.edited_scene`` with every other light off): its
  point lights alone and summed over all of them together, and the relative pixel noise
  of the together render (two seeds).

It prints one table row per sampler, with the seconds it took. ``ldsampler`` was
reroom's default for powers of four until session 45 (docs/edit.md, "The sampler").
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

SAMPLERS = ("ldsampler", "independent", "multijitter", "orthogonal", "stratified")


def plane_room(sampler: str, spp: int) -> tuple[float, float]:
    """(lamp alone / lamp beside a dark light, two lights alone summed / together)."""
    from test_render_sampler import _mean, _point

    from reroom.render.mitsuba_env import mitsuba

    mi = mitsuba()
    lamp, other = _point([3.8, 2.8, 2.3], 1.0), _point([0.6, 2.5, 0.8], 0.5)
    dark = _point([1.0, 1.0, 1.0], 0.0)
    alone = _mean(mi, {"lamp": lamp}, spp, sampler)
    beside_dark = _mean(mi, {"lamp": lamp, "dark": dark}, spp, sampler)
    together = _mean(mi, {"lamp": lamp, "other": other}, spp, sampler)
    return alone / beside_dark, (alone + _mean(mi, {"other": other}, spp, sampler)) / together


def model_points(run: Path, frame: int, sampler: str, spp: int) -> tuple[float, float]:
    """(the model's point lights alone summed / together, relative pixel noise)."""
    from reroom.edit.apply import edited_scene
    from reroom.render.frames import FrameRenderer
    from reroom.scan import load_scan

    scene_doc = json.loads((run / "invert" / "scene.json").read_text())
    names = [light["name"] for light in scene_doc["lights"]]
    points = [light["name"] for light in scene_doc["lights"] if light["type"] == "point"]
    if len(points) < 2:
        raise SystemExit(f"{run}: the model has {len(points)} point lights, need two or more")
    off = [{"op": "light", "name": n, "off": True} for n in names if n not in points]
    work = Path(tempfile.mkdtemp(prefix="reroom_bench_sampler_"))
    scene = edited_scene(run, off, work_dir=work)
    keys = [
        k for k, v in scene.items() if isinstance(v, dict) and v.get("type") == "reroom_goniometric"
    ]
    fr = load_scan(run, check_images=False).frames[frame]

    def render(d: dict, seed: int) -> np.ndarray:
        return FrameRenderer(d, fr.intrinsics, spp, sampler=sampler).render(fr.c2w, seed=seed)

    together = [render(scene, s) for s in (5, 6)]
    parts = sum(
        render({k: v for k, v in scene.items() if k not in keys or k == keep}, 5).mean()
        for keep in keys
    )
    noise = np.sqrt(np.mean((together[0] - together[1]) ** 2) / 2.0) / together[0].mean()
    return float(parts / together[0].mean()), float(noise)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--run", type=Path, default=None, help="a finished `reroom run` folder")
    ap.add_argument("--frame", type=int, default=30)
    args = ap.parse_args()
    from reroom.render.camera import default_sampler

    print(f"default sampler at {args.spp} spp: {default_sampler(args.spp)}\n")
    head = (
        "| sampler | six planes: lamp alone / beside a dark light | two lights summed / together |"
    )
    if args.run:
        head += (
            f" {args.run.name} frame {args.frame}: point lights summed / together | pixel noise |"
        )
    print(head + " seconds |")
    print("|---" * head.count("|") + "|")
    for sampler in SAMPLERS:
        t0 = time.perf_counter()
        dark, pair = plane_room(sampler, args.spp)
        row = f"| `{sampler}` | {dark:.4f} | {pair:.4f} |"
        if args.run:
            parts, noise = model_points(args.run, args.frame, sampler, args.spp)
            row += f" {parts:.4f} | {noise:.3f} |"
        print(row + f" {time.perf_counter() - t0:.0f} |", flush=True)


if __name__ == "__main__":
    main()
