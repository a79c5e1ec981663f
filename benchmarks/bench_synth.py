"""How fast is the synthetic scan generator?

Runs ``reroom synth`` configurations end to end and prints wall time per stage,
path-tracing throughput (samples per second) and the ratio to the issue's
targets. Usage::

    python benchmarks/bench_synth.py                 # the 24-frame 160x120 furnished target
    python benchmarks/bench_synth.py --large         # also 300 frames at 640x360
    python benchmarks/bench_synth.py --large --large-spp 8 --mesh fused
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

from reroom.render import mitsuba_info
from reroom.synth.generate import SynthOptions, generate_scan
from reroom.synth.validate import check_consistency


def run(preset: str, opts: SynthOptions, label: str, target_s: float | None) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "scan"
        t = time.perf_counter()
        generate_scan(preset, out, opts)
        wall = time.perf_counter() - t
        truth = json.loads((out / "ground_truth" / "ground_truth.json").read_text())
        rep = check_consistency(out, max_frames=min(opts.frames, 24))
    tm = truth["timings_s"]
    frame_samples = opts.frames * opts.width * opts.height * opts.spp
    vert_samples = truth["mesh"]["vertices"] * opts.vertex_spp
    row = {
        "label": label,
        "wall_s": round(wall, 1),
        "render_frames_s": tm["render_frames"],
        "vertex_radiance_s": tm["vertex_radiance"],
        "mesh_s": tm["mesh"],
        "frame_Msamples_per_s": round(frame_samples / tm["render_frames"] / 1e6, 3),
        "vertex_Msamples_per_s": round(vert_samples / max(tm["vertex_radiance"], 1e-9) / 1e6, 3),
        "vertices": truth["mesh"]["vertices"],
        "consistency_ratio_of_means": round(rep.ratio_of_means, 4),
        "consistency_median_abs_log_ratio": round(rep.median_abs_log_ratio, 4),
    }
    if target_s is not None:
        row["target_s"] = target_s
        row["target_over_ours"] = round(target_s / wall, 2)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--large", action="store_true", help="also run a 300-frame 640x360 scan")
    ap.add_argument("--large-spp", type=int, default=4)
    ap.add_argument("--large-frames", type=int, default=300)
    ap.add_argument("--mesh", default="clean", choices=("clean", "corrupted", "fused"))
    ap.add_argument("--skip-small", action="store_true", help="only the --large run")
    args = ap.parse_args()
    info = mitsuba_info()
    print(f"mitsuba {info.mitsuba_version} variant {info.variant}; {os.cpu_count()} cores")
    rows = [
        run(
            "furnished",
            SynthOptions(frames=24, width=160, height=120, spp=spp, vertex_spp=256, mesh=args.mesh),
            f"furnished 24 x 160x120 @{spp}spp, {args.mesh} mesh",
            60.0,
        )
        for spp in (() if args.skip_small else (16, 64))
    ]
    for row in rows:
        print(json.dumps(row), flush=True)
    if args.large:
        rows.append(
            run(
                "furnished",
                SynthOptions(
                    frames=args.large_frames,
                    width=640,
                    height=360,
                    spp=args.large_spp,
                    vertex_spp=256,
                    mesh=args.mesh,
                ),
                f"furnished {args.large_frames} x 640x360 @{args.large_spp}spp, {args.mesh} mesh",
                None,
            )
        )
        print(json.dumps(rows[-1]), flush=True)
    print()
    print(
        "| run | wall (s) | frames (s) | Msamples/s (frames) | vertex radiance (s) | vertices | target (s) | target/ours |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['label']} | {r['wall_s']} | {r['render_frames_s']} | {r['frame_Msamples_per_s']} | "
            f"{r['vertex_radiance_s']} | {r['vertices']} | {r.get('target_s', '-')} | {r.get('target_over_ours', '-')} |"
        )


if __name__ == "__main__":
    main()
