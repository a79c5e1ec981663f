"""What a scan's holes cost its renders: the input frames re-rendered with and without
the surroundings (docs/invert.md, "What the scan does not hold").

Usage::

    python benchmarks/bench_surroundings.py RUN [RUN ...] [--frames 2] [--spp 16]

``RUN`` is a finished ``reroom run`` (``invert/scene.json`` written by session 39's code
or later). For each run this prints the share of the receivers' hemisphere that leaves
the mesh and the radiance the solve gave it (``scene.json`` ``surroundings``), then
renders ``--frames`` input frames (:func:`reroom.edit.rerender.rerender_inputs`, the
code ``reroom run`` uses) twice: from the model as it is, and from the same model with
the surroundings taken out of a copy of its ``scene.json`` (every other file linked).
Per frame: the ratio of the render's mean to the photo's over the photo's well-exposed
pixels, and the relative L1 error there. Needs no ground truth, so it runs on the real
slambook2 scan (``reroom import-rgbd shared/data/real/slambook2_rgbd --out SCAN`` then
``reroom run SCAN --out RUN``).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from reroom.edit.rerender import rerender_inputs


def _without_surroundings(invert: Path, work: Path) -> Path:
    """A copy of ``invert`` (links) whose ``scene.json`` has no surroundings."""
    out = work / "invert_no_surroundings"
    out.mkdir()
    for f in invert.iterdir():
        if f.name != "scene.json":
            (out / f.name).symlink_to(f.resolve())
    scene = json.loads((invert / "scene.json").read_text())
    scene.pop("surroundings", None)
    (out / "scene.json").write_text(json.dumps(scene))
    return out


def _row(label: str, result: dict) -> str:
    cells = [
        f"{f['index']}: {f['ratio_of_means']:.3f} / {f['relative_l1']:.3f}"
        for f in result["frames"]
    ]
    return f"| {label} | " + " | ".join(cells) + " |"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--frames", type=int, default=2)
    ap.add_argument("--spp", type=int, default=16)
    args = ap.parse_args()
    for run in args.runs:
        scene = json.loads((run / "invert" / "scene.json").read_text())
        s = scene.get("surroundings")
        if s is None:
            print(f"{run}: no surroundings record (an invert before session 39)")
            continue
        rad = (
            "none (closed)"
            if s["radiance"] is None
            else "/".join(f"{x:.3f}" for x in s["radiance"])
        )
        print(f"\n{run}: {100 * s['escape_fraction']:.2f} % of the hemisphere escapes "
              f"({s['points']} points x {s['rays_per_point']} rays); radiance {rad}")  # fmt: skip
        if s["radiance"] is None:
            print("nothing is rendered for it: the renders are the same with and without")
            continue
        print("\n| model | frame: render mean / photo mean, relative L1 |\n|---|---|")
        with tempfile.TemporaryDirectory() as tmp:
            work = Path(tmp)
            for label, inv in (
                ("without the surroundings", _without_surroundings(run / "invert", work)),
                ("with them (the default)", run / "invert"),
            ):
                t = time.perf_counter()
                res = rerender_inputs(
                    run, inv, frames=args.frames, spp=args.spp, out_dir=work / label.split()[0]
                )
                print(_row(label, res) + f" ({time.perf_counter() - t:.1f} s)", flush=True)


if __name__ == "__main__":
    main()
