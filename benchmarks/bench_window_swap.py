"""The window swap's level: the factor that maps the sky a scan was lit by onto a window's
recovered cells, against the true factor.

Usage::

    python benchmarks/bench_window_swap.py RUN [--window window0]

``RUN`` is a finished ``reroom run`` of a synthetic scan (``invert/`` and
``ground_truth/``). A window edit with ``was`` (``reroom.edit.apply.swap_window_environment``)
scales the new HDRI by a per-channel factor found from ``was`` and the recovered cells;
the ideal factor is the run's radiance scale ``k`` times the true window's ``scale``
(the true scene shows its HDRI times ``scale``, the model is ``k`` times the true
scene). This prints, over that ideal, for the solve's cells (``distribution``) and, where
there is one, the render window's (``render_distribution``):

* the ratio of the light entering, ``sum w rec / sum w was`` (what the swap uses, from the
  solve's cells), and
* the least-squares fit ``sum w was rec / sum w was^2`` (what it used until session 36),

with ``w`` the cosine-weighted solid angle of each cell through the opening. It is
evaluation: it reads ``ground_truth/``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("run", type=Path)
    ap.add_argument("--window", default="window0", help="the model's window (scene.json)")
    args = ap.parse_args()

    from reroom.edit.apply import _fibonacci_sphere, environment_cells, swap_window_environment
    from reroom.invert.basis import CubemapBasis
    from reroom.invert.evaluate import evaluate_invert

    path = args.run / "invert" / "scene.json"
    if not path.is_file():
        raise SystemExit(f"{path} is missing: run `reroom run` first")
    light = next(
        (x for x in json.loads(path.read_text())["lights"] if x.get("name") == args.window), None
    )
    if light is None or light.get("type") != "window":
        raise SystemExit(f"{path} has no window named {args.window!r}")
    report = evaluate_invert(args.run)
    entry = next(e for e in report["lights"] if e["name"] == args.window)
    scene_dir = args.run / "ground_truth" / "scene"
    truth = next(
        x for x in json.loads((scene_dir / "scene.json").read_text())["lights"]
        if x["name"] == entry["truth"]
    )  # fmt: skip
    was = scene_dir / truth["hdri_file"]
    ideal = np.asarray(report["radiance_scale"], float) * float(truth.get("scale", 1.0))
    normal = np.asarray(light["geometry"]["normal"], float)
    d = _fibonacci_sphere(200_000)
    print(f"`{args.window}`: the swap's factor over the true one (k x scale = "
          f"{'/'.join(f'{x:.3f}' for x in ideal)}), r/g/b\n")  # fmt: skip
    print("| cells | ratio of the light entering | least squares (before session 36) |")
    print("|---|---|---|")
    for key in ("distribution", "render_distribution"):
        dist = light.get(key)
        if dist is None:
            continue
        basis = CubemapBasis(int(dist["n"]))
        rec = np.maximum(np.asarray(dist["cells"], float), 0.0)
        w = np.bincount(basis.cell_of(d), np.maximum(-(d @ normal), 0.0), minlength=basis.size)
        old = environment_cells(was, basis)
        ratio = (w[:, None] * rec).sum(0) / (w[:, None] * old).sum(0)
        lsq = (w[:, None] * old * rec).sum(0) / (w[:, None] * old * old).sum(0)
        name = f"{key} ({dist['n']}x{dist['n']})"
        print(f"| {name} | {'/'.join(f'{x:.3f}' for x in ratio / ideal)} "
              f"| {'/'.join(f'{x:.3f}' for x in lsq / ideal)} |")  # fmt: skip
    _, used = swap_window_environment(light, "sunset", was=was)
    print(f"\nswap_window_environment(..., was) uses {'/'.join(f'{x:.3f}' for x in used / ideal)}")


if __name__ == "__main__":
    main()
