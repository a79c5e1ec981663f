"""Light detection benchmark: synthetic scans against their ground truth, and a real scan.

Usage::

    python benchmarks/bench_lights.py NAME=SCAN[:HDR_DIR:LAYOUT_DIR] ... [--json out.json]

Each scan needs the outputs of ``reroom hdr`` and ``reroom layout`` (default
``SCAN/hdr`` and ``SCAN/layout``). Prints markdown tables: per true light whether it
was found, its type, position error, IoU (area lights, windows) and endpoint error
(line lights); false lights; the rejected candidates by reason; and the time of
detection with the load average (the machine is shared). Scans without
``ground_truth/`` (real ones) get the list of what was found instead.

The thesis (§5.5) has no numbers to compare with: its lights were thresholded with a
user-chosen value and pruned by a person. The baseline here is that procedure
without the person -- every component above the threshold with more than 50
vertices kept as an area light (``thesis-unpruned`` column).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

from reroom.lights import LightsOptions, detect_lights
from reroom.lights.evaluate import evaluate_lights


def _parse(spec: str) -> tuple[str, Path, Path | None, Path | None]:
    name, rest = spec.split("=", 1)
    parts = rest.split(":")
    scan = Path(parts[0])
    hdr = Path(parts[1]) if len(parts) > 1 and parts[1] else None
    layout = Path(parts[2]) if len(parts) > 2 and parts[2] else None
    return name, scan, hdr, layout


def _unpruned_count(lights) -> int:
    """Candidates the thesis's threshold + 50-vertex rule alone would keep as lights."""
    n = sum(1 for x in lights.lights if x.source == "detected" and "pool" not in x.reason)
    for r in lights.rejected:
        if r.evidence.get("vertices", 0) > 50 and r.kind == "component":
            n += 1
    return n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scans", nargs="+", help="NAME=SCAN[:HDR:LAYOUT]")
    ap.add_argument("--json", type=Path, help="Write all results here.")
    args = ap.parse_args()
    results = {}
    print(
        "| scan | true lights | found | type right | false lights | thesis-unpruned lights | "
        "rejected | time (s) | load (1 min) |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    rows = []
    for spec in args.scans:
        name, scan, hdr, layout = _parse(spec)
        t = time.perf_counter()
        lights = detect_lights(scan, hdr, layout, LightsOptions())
        dt = time.perf_counter() - t
        load = os.getloadavg()[0]
        has_truth = (scan / "ground_truth" / "scene" / "scene.json").is_file()
        ev = evaluate_lights(lights, scan) if has_truth else None
        results[name] = {
            "time_s": dt,
            "load": load,
            "evaluation": ev,
            "lights": [x.to_json() for x in lights.lights],
            "rejected": [r.to_json() for r in lights.rejected],
            "thresholds": lights.thresholds,
        }
        rej = ", ".join(f"{k} {v}" for k, v in (ev or {}).get("rejected", {}).items())
        if ev is None:
            rej = f"{len(lights.rejected)}"
        print(
            f"| {name} | {ev['true_lights'] if ev else '-'} | {ev['found'] if ev else '-'} | "
            f"{ev['type_ok'] if ev else '-'} | "
            f"{len(ev['false_lights']) if ev else f'- (kept {len(lights.lights)})'} | "
            f"{_unpruned_count(lights)} | "
            f"{rej} | {dt:.1f} | {load:.1f} |"
        )
        rows.append((name, ev, lights))
    print()
    print(
        "| scan | true light | type | found as | position error (cm) | IoU | "
        "line endpoints error (cm) |"
    )
    print("|---|---|---|---|---|---|---|")
    for name, ev, _ in rows:
        if ev is None:
            continue
        for r in ev["truth"]:
            found = (
                f"{r['matched']} ({r['matched_type']}, {r['matched_source']})"
                if r["found"]
                else "missed"
            )
            pos = f"{100 * r['position_error_m']:.1f}" if r["found"] else "-"
            iou = f"{r['iou']:.2f}" if "iou" in r else "-"
            line = f"{100 * r['endpoint_error_m']:.1f}" if "endpoint_error_m" in r else "-"
            print(f"| {name} | {r['name']} | {r['type']} | {found} | {pos} | {iou} | {line} |")
    print()
    print("| scan | light | type | source | reason |")
    print("|---|---|---|---|---|")
    for name, ev, lights in rows:
        false = {x["name"] for x in ev["false_lights"]} if ev else None
        for x in lights.lights:
            if false is None or x.name in false:
                tag = "" if false is None else " **(false)**"
                print(f"| {name} | {x.name}{tag} | {x.type} | {x.source} | {x.reason} |")
    print()
    print("Cues of every candidate of at least 50 vertices (kept lights first):")
    print()
    print(
        "| scan | candidate | decision | vertices | edge contrast | clipped | "
        "bright frames / seeing | normal · up |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for name, _, lights in rows:
        items = [(x.name, x.reason, x.evidence) for x in lights.lights if x.source == "detected"]
        items += [(r.name, r.reason, r.evidence) for r in lights.rejected if r.kind == "component"]
        for cand, reason, e in items:
            if e.get("vertices", 0) < 50 or "edge_contrast" not in e:
                continue
            decision = reason.split(" — ")[0].split(", ")[0].split(" (")[0]
            print(
                f"| {name} | {cand} | {decision.strip()} | {e['vertices']} | "
                f"{e['edge_contrast']:.1f} | {e.get('clipped_fraction', float('nan')):.2f} | "
                f"{e.get('frames_bright', '-')} / {e.get('frames_seeing', '-')} | "
                f"{e['normal_up']:+.2f} |"
            )
    if args.json:
        args.json.write_text(json.dumps(results, indent=1, default=str))


if __name__ == "__main__":
    main()
