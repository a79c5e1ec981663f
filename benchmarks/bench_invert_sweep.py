"""What does an inverse-rendering option do on a finished run? ``reroom invert --set`` swept.

For each setting (``NAME=VALUE``, several joined by commas), links a finished ``reroom
run`` folder's inputs (scan, HDR, layout, lights) into ``WORK/<tag>``, runs ``reroom
invert`` there with those ``--set`` overrides, and prints the run's own evaluation
(``bench_run.evaluate``: cluster albedos, each light's power, power leaving its fitting,
distribution error) under a header with the setting and the invert's wall time::

    python benchmarks/bench_invert_sweep.py RUN line_shape_prior=1e4 line_shape_prior=1e5 \\
        "line_shape_prior=1e5,line_phi_smooth=1e4" [--work /tmp/reroom_sweep]

It also prints the objective of eq. 5.7. ``place.NAME=X:Y:Z`` in a setting puts point light
``NAME`` there (in a copy of the run's lights), e.g. the downlight at its true place with
the refinement off: ``"place.localized0=5.3:3.9:2.67,refine_points=false"``.

``RUN`` must hold a ground truth (a synthetic scan run with ``bench_run.py --scan``).
Everything here is evaluation; the estimate never reads ``ground_truth/``.

``--capture-window-view PATH [--capture-scale S]`` first plays the photographer who takes
an HDRI at the window: it writes the scene's true window HDRI, times ``S`` (any overall
scale: only the pattern is used), to ``PATH``, an input that a sweep entry then names
(docs/invert.md, session 19)::

    python benchmarks/bench_invert_sweep.py RUN - window_view_hdri=/tmp/view.exr \
        --capture-window-view /tmp/view.exr
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_run import evaluate  # noqa: E402

#: What ``reroom invert`` reads from a run folder (``depth``: an RGB-D import's frames).
INPUTS = (
    "depth",
    "ground_truth",
    "hdr",
    "images",
    "layout",
    "lights",
    "mesh.ply",
    "transforms.json",
)


def sweep_dir(run: Path, work: Path, setting: str) -> Path:
    """A fresh folder linking ``run``'s inputs, named after the setting."""
    tag = re.sub(r"[^A-Za-z0-9]+", "_", setting).strip("_") or "defaults"
    d = work / f"{run.name}_{tag}"
    if d.exists():
        shutil.rmtree(d)
    d.mkdir(parents=True)
    for name in INPUTS:
        if (run / name).exists():
            (d / name).symlink_to((run / name).resolve())
    return d


def place_lights(d: Path, places: list[str]) -> None:
    """Put point lights where ``place.NAME=X:Y:Z`` says, in a copy of ``d``'s lights (an
    evaluation: what the solve makes of a light at a chosen place; pair it with
    ``refine_points=false`` to keep it there)."""
    link = d / "lights"
    src = link.resolve()
    link.unlink()
    shutil.copytree(src, link)
    doc = json.loads((link / "lights.json").read_text())
    by_name = {light["name"]: light for light in doc["lights"]}
    for p in places:
        name, _, xyz = p[len("place.") :].partition("=")
        if name not in by_name or "position" not in by_name[name]:
            raise SystemExit(f"{p}: no point light {name!r} in {src / 'lights.json'}")
        by_name[name]["position"] = [float(v) for v in xyz.split(":")]
    (link / "lights.json").write_text(json.dumps(doc))


def capture_window_view(run: Path, path: Path, scale: float) -> float:
    """Write the run's first true window HDRI, times ``scale``, to ``path``; its rotation."""
    import json

    import numpy as np

    from reroom.io.images import read_exr, write_exr

    gt = json.loads((run / "ground_truth" / "ground_truth.json").read_text())
    light = next(x for x in gt["lights"] if x["type"] == "window")
    scene = run / "ground_truth" / "scene"
    img = read_exr(scene / light["hdri_file"])[..., :3] * float(light.get("scale", 1.0))
    write_exr(path, (scale * img).astype(np.float32))
    return float(light.get("rotation_deg", 0.0))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("run", type=Path, help="a finished `reroom run` folder with ground truth")
    ap.add_argument("settings", nargs="+", help="NAME=VALUE[,NAME=VALUE...]; '-' = defaults")
    ap.add_argument("--work", type=Path, default=Path("/tmp/reroom_sweep"))
    ap.add_argument("--capture-window-view", type=Path, default=None, metavar="PATH")
    ap.add_argument("--capture-scale", type=float, default=0.37)
    args = ap.parse_args()
    if args.capture_window_view is not None:
        rot = capture_window_view(args.run, args.capture_window_view, args.capture_scale)
        print(
            f"wrote {args.capture_window_view} (the true window HDRI x {args.capture_scale}; "
            f"rotation {rot} deg: pass window_view_rotation_deg={rot} if not 0)"
        )
    reroom = Path(sys.executable).with_name("reroom")
    for setting in args.settings:
        pairs = [] if setting == "-" else [p for p in setting.split(",") if p]
        d = sweep_dir(args.run, args.work, setting)
        places = [p for p in pairs if p.startswith("place.")]
        if places:
            place_lights(d, places)
        cmd = [str(reroom), "invert", str(d)]
        for p in pairs:
            if p not in places:
                cmd += ["--set", p]
        t = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True)
        wall = time.perf_counter() - t
        print(f"== {setting} (reroom invert {wall:.1f} s, rc {proc.returncode})", flush=True)
        if proc.returncode != 0:
            print(proc.stderr[-2000:])
            continue
        report = json.loads((d / "invert" / "report.json").read_text())
        print(f"objective of eq. 5.7: {report['objective']:.1f}")
        evaluate(d, d / "invert")


if __name__ == "__main__":
    main()
