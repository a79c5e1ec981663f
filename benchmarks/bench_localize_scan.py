"""Room-scale light localization on synthetic scans: errors of the point lights found.

For each scan folder given (made by ``reroom synth``, with ``reroom hdr``, ``reroom layout``
and ``reroom lights`` run), runs :func:`reroom.localize.scan.localize_scan` and compares
with ``ground_truth/ground_truth.json`` (read here only, never by the estimation):

* each true point light that is on: the distance to the nearest light found (metres, and
  % of the room's size = the diagonal of the mesh's bounding box), matched one-to-one;
* extra lights (found, not matched within 5% of the room's size): their share of the
  intensity of the matched lights (the found estimate of the true point lights' power;
  with no true point light: of all lights found);
* wall-clock seconds.

    .venv/bin/python benchmarks/bench_localize_scan.py /tmp/h3/furnished /tmp/h3/box
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from reroom.io.mesh import read_ply
from reroom.localize.scan import ScanLocalizeOptions, localize_scan

TARGET = 0.05


def evaluate(scan: Path, res) -> dict:
    """Match the found lights with the true point lights of ``scan``."""
    truth = json.loads((scan / "ground_truth" / "ground_truth.json").read_text())
    true = [x for x in truth["lights"] if x["type"] == "point" and x.get("on", True)]
    tp = np.array([x["position"] for x in true], float).reshape(-1, 3)
    verts = np.asarray(read_ply(scan / "hdr" / "hdr_mesh.ply").vertices)
    size = float(np.linalg.norm(verts.max(axis=0) - verts.min(axis=0)))
    fp = res.positions
    rows, matched = [], set()
    if len(tp) and len(fp):
        d = np.linalg.norm(tp[:, None] - fp[None], axis=-1)
        ti, fi = linear_sum_assignment(d)
        pairs = dict(zip(ti.tolist(), fi.tolist(), strict=True))
    else:
        pairs = {}
    for t, light in enumerate(true):
        f = pairs.get(t)
        err = float(np.linalg.norm(tp[t] - fp[f])) if f is not None else float("inf")
        if f is not None and err <= TARGET * size:
            matched.add(f)
        rows.append({"light": light["name"], "true": tp[t].tolist(),
                     "found": None if f is None else fp[f].round(3).tolist(),
                     "error_m": err, "error_pct": 100 * err / size})  # fmt: skip
    ref = sum(res.intensities[f] for f in matched) or float(res.intensities.sum()) or 1.0
    extra = [
        {"found": fp[f].round(3).tolist(), "share": float(res.intensities[f] / ref)}
        for f in range(len(fp))
        if f not in matched
    ]
    ok = all(r["error_pct"] <= 100 * TARGET for r in rows) and all(
        e["share"] <= TARGET for e in extra
    )
    return {"size_m": size, "lights": rows, "extra": extra, "target_met": ok}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scans", nargs="+", type=Path)
    ap.add_argument(
        "--classes", default="0,2", help="surface labels used (0 wall, 1 floor, 2 ceiling)"
    )
    ap.add_argument("--window-cells", type=int, default=4, help="cube-map cells per face side")
    ap.add_argument("--min-gain", type=float, default=0.15, help="discovery stopping threshold")
    ap.add_argument(
        "--discovery",
        default="joint",
        choices=("joint", "fixed"),
        help="discovery score: other lights refitted, robust weights (joint) or fixed",
    )
    ap.add_argument(
        "--search-albedo-update",
        default="bounded",
        choices=("bounded", "iterated", "anchored", "off"),
        help="albedo update during the search (off: the robust minimum throughout)",
    )
    ap.add_argument(
        "--search-albedo-bound", type=float, default=0.05, help="bound of the bounded update"
    )
    ap.add_argument(
        "--downward-candidates", action="store_true", help="also score downward candidates"
    )
    ap.add_argument(
        "--no-mount-unsupported",
        action="store_true",
        help="mount only lights that send nothing upwards (the earlier rule)",
    )
    ap.add_argument(
        "--mount-shift", type=float, default=0.2, help="x, y refit of a mounted light (m)"
    )
    ap.add_argument(
        "--no-keep-enclosed",
        action="store_true",
        help="a light inside a fitting takes the lowest-cost height too",
    )
    ap.add_argument(
        "--no-enclosed-axis",
        action="store_true",
        help="heights inside a fitting are not also tried on its axis",
    )
    ap.add_argument(
        "--profile-gain", type=float, default=0.2, help="goniometric test threshold (1: off)"
    )
    ap.add_argument(
        "--height-bins", type=int, default=64, help="bins of the goniometric height search"
    )
    ap.add_argument(
        "--no-mount-test", action="store_true", help="keep the goniometric test's best height"
    )
    ap.add_argument(
        "--keep-floating", action="store_true", help="keep lights nothing in the scan holds"
    )
    ap.add_argument(
        "--window-samples", type=int, default=None, help="portal samples (0: hemisphere rays)"
    )
    ap.add_argument("--json", type=Path, help="also write the results here")
    args = ap.parse_args()
    opt = ScanLocalizeOptions(
        classes=tuple(int(c) for c in args.classes.split(",")),
        window_cells=args.window_cells,
        min_gain=args.min_gain,
        discovery=args.discovery,
        search_albedo_update=args.search_albedo_update,
        search_albedo_bound=args.search_albedo_bound,
        downward_candidates=args.downward_candidates,
        mount_unsupported=not args.no_mount_unsupported,
        mount_shift=args.mount_shift,
        keep_enclosed=not args.no_keep_enclosed,
        enclosed_axis=not args.no_enclosed_axis,
        profile_gain=args.profile_gain,
        height_bins=args.height_bins,
        mount_test=not args.no_mount_test,
        drop_floating=not args.keep_floating,
    )
    if args.window_samples is not None:
        opt = dataclasses.replace(opt, window_samples=args.window_samples)
    out = []
    for scan in args.scans:
        res, info = localize_scan(scan, opt)
        ev = evaluate(scan, res)
        ev.update(
            scan=str(scan),
            seconds=res.seconds,
            albedo=info["albedo"],
            stopped=info["stopped"],
            gains=[h["gain"] for h in res.history],
            leave_one_out=info["leave_one_out"],
            goniometric=info["goniometric"],
            floating=info["floating"],
        )
        out.append(ev)
        print(f"\n## {scan} (room size {ev['size_m']:.2f} m, {res.seconds:.0f} s, "
              f"albedo {', '.join(f'{k} {v:.2f}' for k, v in info['albedo'].items())}; "
              f"stopped: {info['stopped']})")  # fmt: skip
        print("| true light | true position | found | error m | error % of size |")
        print("|---|---|---|---|---|")
        for r in ev["lights"]:
            print(f"| {r['light']} | {r['true']} | {r['found']} | {r['error_m']:.2f} | "
                  f"{r['error_pct']:.1f} |")  # fmt: skip
        for e in ev["extra"]:
            print(f"extra light at {e['found']}: {100 * e['share']:.1f}% of the matched power")
        if not ev["lights"] and not ev["extra"]:
            print("no true point light, none found")
        gains = ", ".join(f"{h['gain']:.2f}" for h in res.history)
        print(f"discovery gains (stop below {opt.min_gain}): {gains}")
        loo = ", ".join(
            f"{t['cost_ratio_without']:.2f}" + (" (dropped)" if t.get("dropped") else "")
            for t in info["leave_one_out"]
        )
        print(f"cost ratio without each light (drop below {opt.prune_ratio}): {loo or '-'}")
        for f in info["floating"]:
            print(f"light at {np.round(f['position'], 3).tolist()}: {f['reason']}")
        for k, g in enumerate(res.goniometric):
            if g is not None:
                print(f"light {k}: goniometric, moved {g['moved_m']:.2f} m (soft-L1 cost "
                      f"{g['cost_goniometric']:.0f} vs {g['cost_isotropic']:.0f} isotropic)")  # fmt: skip
                m = g.get("mount")
                if m is not None:
                    print(f"  mount test: upward flux {100 * m['upward_flux']:.1f}%, "
                          f"{m.get('fitting_vertices', '-')} fitting vertices, cost ratio "
                          f"{m.get('cost_ratio', float('nan')):.3f}: {m['reason']}"
                          + (", x, y refitted" if "shift_m" in m else "")
                          + ("; inside the fitting: search height kept" if m.get("enclosed") else ""))  # fmt: skip
        print(f"target met: {ev['target_met']}   (load {os.getloadavg()[0]:.1f})")
    if args.json:
        args.json.write_text(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
