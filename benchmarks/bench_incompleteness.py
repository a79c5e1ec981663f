"""Reflectance estimates vs mesh incompleteness (thesis Fig. 5.9, issue #5).

For each fraction of the mesh deleted and each trial, delete connected chunks of 5 % of
the vertices grown breadth-first from random seeds (never the detected lights' own
vertices: :func:`reroom.invert.incomplete.delete_chunks`), write the subset scan
(:func:`reroom.invert.incomplete.subset_scan`, under ``--work``; the source scan is only
read), run ``reroom invert`` on it (``InvertOptions(pictures=False)``, the same solver
seed every time: the trials differ only in what is deleted) and evaluate it
(:func:`reroom.invert.evaluate.evaluate_invert`). Recorded per run: the wall / floor /
ceiling cluster albedos (RGB), their truth over the vertices left, and each light's
power and relative power error.

``--true-radiance`` solves with the ground truth's per-vertex radiance instead of the
HDR mesh's (:func:`reroom.invert.evaluate.run_invert_true_radiance`, EVALUATION ONLY),
so the curve shows incompleteness alone, without HDR errors.

All trials at fraction 0 delete nothing and give the same mesh; the solve is seeded, so
fraction 0 is run once. Each run's record is a JSON file under ``--work/runs``; a run
whose record exists is skipped, so several processes can share a grid (``--shard i/k``
takes every k-th run) and ``--aggregate`` then reads them all, prints the markdown table,
writes the JSON summary and plots. The interval is the normal 95 % confidence interval of
the mean over the trials, ``mean +- 1.96 sd / sqrt(n)`` (sd with ``ddof=1``), as the
thesis's "95 % confidence intervals" reads; the per-trial points are drawn too.

Usage (niced; the machine is shared)::

    nice -n 10 python benchmarks/bench_incompleteness.py SCAN --work /tmp/h6/inc \\
        --fractions 0,0.1,0.2,0.3,0.5,0.7,0.9 --trials 3 [--shard 0/2] [--true-radiance]
    python benchmarks/bench_incompleteness.py SCAN --work /tmp/h6/inc --aggregate \\
        --png docs/images/invert_incompleteness.png
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np

from reroom.invert.incomplete import delete_chunks, subset_scan

CLUSTERS = ("wall", "floor", "ceiling")
CHANNELS = ("r", "g", "b")


def _tag(fraction: float, trial: int, true_radiance: bool, invert_seed: int = 0) -> str:
    tag = f"{'true_' if true_radiance else ''}f{round(fraction * 100):02d}_t{trial:02d}"
    return tag + (f"_s{invert_seed:02d}" if invert_seed else "")


def run_one(
    scan: Path,
    work: Path,
    fraction: float,
    trial: int,
    seed: int,
    true_rad: bool,
    invert_seed: int = 0,
):
    """Subset, invert and evaluate one trial; return (and write) its record.

    ``invert_seed`` is :class:`InvertOptions`' ``seed`` (ray sampling, solve subset).
    """
    from reroom.invert.evaluate import evaluate_invert, run_invert_true_radiance
    from reroom.invert.pipeline import InvertOptions, run_invert
    from reroom.io.mesh import read_ply
    from reroom.lights import load_lights

    tag = _tag(fraction, trial, true_rad, invert_seed)
    record_path = work / "runs" / f"{tag}.json"
    if record_path.is_file():
        return json.loads(record_path.read_text())
    t0 = time.perf_counter()
    mesh = read_ply(scan / "hdr" / "hdr_mesh.ply")
    ids = load_lights(scan / "lights" / "lights.json").vertex_light_id
    protect = ids >= 0 if len(ids) else None
    rng = np.random.default_rng([seed, round(fraction * 1000), trial])
    keep = delete_chunks(mesh, fraction, rng, protect)
    sub = work / "scans" / tag
    if sub.exists():
        shutil.rmtree(sub)
    info = subset_scan(scan, keep, sub)
    t_sub = time.perf_counter() - t0
    opts = InvertOptions(pictures=False, seed=invert_seed)
    t = time.perf_counter()
    if true_rad:
        run_invert_true_radiance(sub, sub / "invert", opts)
    else:
        run_invert(sub, options=opts)
    t_inv = time.perf_counter() - t
    t = time.perf_counter()
    rep = evaluate_invert(sub)
    t_eval = time.perf_counter() - t
    rec = {
        "fraction": fraction,
        "trial": trial,
        "true_radiance": true_rad,
        "invert_seed": invert_seed,
        "vertices": info["vertices"],
        "faces": info["faces"],
        "vertices_deleted": float(1 - info["vertices"][1] / info["vertices"][0]),
        "faces_deleted": float(1 - info["faces"][1] / info["faces"][0]),
        "clusters": {
            c: {
                "estimate": rep["clusters"].get(c, {}).get("estimate"),
                "truth": rep["clusters"].get(c, {}).get("truth"),
            }
            for c in CLUSTERS
        },
        "lights": {
            e["name"]: {
                "type": e["type"],
                "power": e["power"],
                "true_power": e.get("true_power"),
                "power_relative_error": e.get("power_relative_error"),
            }
            for e in rep["lights"]
        },
        "seconds": {"subset": t_sub, "invert": t_inv, "evaluate": t_eval},
    }
    record_path.parent.mkdir(parents=True, exist_ok=True)
    record_path.write_text(json.dumps(rec, indent=1))
    shutil.rmtree(sub, ignore_errors=True)  # keep only the record (the scans are big)
    return rec


def _interval(x: np.ndarray) -> tuple[float, float, int]:
    """Mean and half-width of the normal 95 % CI of the mean, ignoring NaN."""
    x = x[np.isfinite(x)]
    if not len(x):
        return float("nan"), float("nan"), 0
    if len(x) == 1:
        return float(x[0]), 0.0, 1
    return float(x.mean()), float(1.96 * x.std(ddof=1) / np.sqrt(len(x))), len(x)


def _row(rs: list[dict], mean0: dict, truth0: dict | None) -> dict:
    """Per-cluster and per-light statistics of the records of one fraction."""
    row: dict = {
        "fraction": rs[0]["fraction"],
        "trials": len(rs),
        "vertices_deleted": float(np.mean([r["vertices_deleted"] for r in rs])),
        "faces_deleted": float(np.mean([r["faces_deleted"] for r in rs])),
        "clusters": {},
        "lights": {},
    }
    for c in CLUSTERS:
        est = np.array(
            [
                r["clusters"][c]["estimate"]
                if r["clusters"][c]["estimate"] is not None
                else [np.nan] * 3
                for r in rs
            ],
            float,
        )
        stats = [_interval(est[:, k]) for k in range(3)]
        grey = est.mean(axis=1)  # mean of R, G, B per trial
        g = _interval(grey)
        entry = {
            "mean": [x[0] for x in stats],
            "half_width": [x[1] for x in stats],
            "n": [x[2] for x in stats],
            "rgb_mean": g[0],
            "rgb_half_width": g[1],
            "rgb_sd": float(np.nanstd(grey, ddof=1)) if np.isfinite(grey).sum() > 1 else 0.0,
            "values": est.tolist(),
        }
        if c in mean0:
            entry["relative_change_vs_0"] = (np.array(entry["mean"]) / mean0[c] - 1).tolist()
            entry["rgb_relative_change_vs_0"] = g[0] / float(np.mean(mean0[c])) - 1
        if truth0 is not None and truth0[c] is not None:
            entry["relative_error_vs_truth"] = (
                np.array(entry["mean"]) / np.array(truth0[c]) - 1
            ).tolist()
        row["clusters"][c] = entry
    for name in sorted({n for r in rs for n in r["lights"]}):
        p = np.array([np.mean(r["lights"][name]["power"]) for r in rs if name in r["lights"]])
        m, h, k = _interval(p)
        row["lights"][name] = {"mean_power": m, "half_width": h, "n": k}
    return row


def aggregate(work: Path, true_rad: bool, png: Path | None, out_json: Path) -> dict:
    """Summarise the records: markdown tables, JSON, plot."""
    every = [json.loads(p.read_text()) for p in sorted((work / "runs").glob("*.json"))]
    every = [r for r in every if r["true_radiance"] == true_rad]
    failed = [r for r in every if r.get("failed")]
    every = [r for r in every if not r.get("failed")]
    recs = [r for r in every if not r.get("invert_seed", 0)]
    if not recs:
        raise SystemExit(f"no records under {work / 'runs'}")
    fractions = sorted({r["fraction"] for r in recs})
    base = [r for r in recs if r["fraction"] == 0]
    truth0 = {c: base[0]["clusters"][c]["truth"] for c in CLUSTERS} if base else None
    mean0: dict = {}
    if base:
        r0 = _row(base, {}, truth0)
        mean0 = {c: np.array(r0["clusters"][c]["mean"]) for c in CLUSTERS}
    rows = [_row([r for r in recs if r["fraction"] == f], mean0, truth0) for f in fractions]
    # the noise floor: the full mesh solved with other ray / solve seeds (--noise-floor)
    floor_recs = [r for r in every if r["fraction"] == 0]
    noise = _row(floor_recs, mean0, truth0) if len(floor_recs) > 1 else None
    summary = {
        "true_radiance": true_rad,
        "interval": "normal 95 % CI of the mean: mean +- 1.96 sd / sqrt(n), sd with ddof=1",
        "truth_full_mesh": truth0,
        "rows": rows,
        "noise_floor_full_mesh_seeds": noise,
        "failed": [
            {k: r[k] for k in ("fraction", "trial", "invert_seed", "failed")} for r in failed
        ],
    }
    out_json.parent.mkdir(parents=True, exist_ok=True)
    out_json.write_text(json.dumps(summary, indent=1))

    # ------------------------------------------------------------ markdown tables
    print(
        f"\nIncompleteness ({'true radiance' if true_rad else 'HDR radiance'}): per cluster "
        "the albedo (mean of R, G, B) over the trials ± the 95 % CI half-width of that mean, "
        "(sd across trials), and the relative change of the mean vs the 0 % estimate\n"
    )
    head, sep = "| missing (vertices) | faces gone | trials |", "|---|---|---|"
    for c in CLUSTERS:
        head += f" {c} | change |"
        sep += "---|---|"
    print(head + "\n" + sep)

    def line(label: str, row: dict) -> str:
        out = f"| {label} | {row['faces_deleted']:.1%} | {row['trials']} |"
        for c in CLUSTERS:
            e = row["clusters"][c]
            ch = e.get("rgb_relative_change_vs_0", float("nan"))
            out += (
                f" {e['rgb_mean']:.3f} ± {e['rgb_half_width']:.3f} ({e['rgb_sd']:.3f}) |"
                f" {ch:+.1%} |"
            )
        return out

    for row in rows:
        print(line(f"{row['fraction']:.0%}", row))
    if noise is not None:
        print(line(f"0 %, invert seeds 0-{len(floor_recs) - 1}", noise))
    if truth0:
        print(
            "| truth (full mesh) | | |"
            + "".join(f" {np.mean(truth0[c]):.3f} | |" for c in CLUSTERS)
        )
    for r in failed:
        print(f"- {r['fraction']:.0%} trial {r['trial']}: FAILED ({r['failed']})")
    names = sorted({n for row in rows for n in row["lights"]})
    if names and base:
        print("\nLight power (mean of R, G, B): relative change of the mean vs 0 % ± 95 % CI\n")
        print("| missing | " + " | ".join(names) + " |")
        print("|---|" + "---|" * len(names))
        p0 = rows[0]["lights"]
        for row in rows:
            cells = []
            for n in names:
                e = row["lights"].get(n)
                if e is None or n not in p0 or not np.isfinite(e["mean_power"]):
                    cells.append("-")
                else:
                    m0 = p0[n]["mean_power"]
                    cells.append(f"{e['mean_power'] / m0 - 1:+.1%} ± {e['half_width'] / m0:.1%}")
            print(f"| {row['fraction']:.0%} | " + " | ".join(cells) + " |")

    # ------------------------------------------------------------ plot
    if png is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(1, 3, figsize=(13, 4), sharey=True)
        colors = {"r": "tab:red", "g": "tab:green", "b": "tab:blue"}
        fr = np.array([row["fraction"] for row in rows]) * 100
        for ax, c in zip(axes, CLUSTERS, strict=True):
            for k, ch in enumerate(CHANNELS):
                m = np.array([row["clusters"][c]["mean"][k] for row in rows])
                h = np.array([row["clusters"][c]["half_width"][k] for row in rows])
                ax.errorbar(fr, m, yerr=h, color=colors[ch], marker="o", ms=3, capsize=3)
                for row in rows:
                    v = np.array(row["clusters"][c]["values"])[:, k]
                    ax.scatter(
                        np.full(len(v), row["fraction"] * 100), v, s=6, color=colors[ch], alpha=0.3
                    )
                if truth0 and truth0[c] is not None:
                    ax.axhline(truth0[c][k], color=colors[ch], ls="--", lw=1)
            ax.set_title(c)
            ax.set_xlabel("mesh deleted (% of vertices)")
            ax.grid(alpha=0.3)
        axes[0].set_ylabel("albedo estimate")
        fig.suptitle(
            "Cluster albedo vs mesh incompleteness "
            f"({'true radiance' if true_rad else 'HDR radiance'}): "
            "mean ± 95 % CI of the mean, trials as dots, truth dashed"
        )
        fig.tight_layout()
        png.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(png, dpi=110)
        print(f"\nwrote {png}")
    print(f"wrote {out_json}")
    return summary


def _run_limited(a: argparse.Namespace, f: float, t: int, s: int) -> dict:
    """:func:`run_one` in a subprocess with a time limit; a failure is recorded too."""
    import subprocess

    path = a.work / "runs" / f"{_tag(f, t, a.true_radiance, s)}.json"
    if path.is_file():
        return json.loads(path.read_text())
    cmd = [sys.executable, __file__, str(a.scan), "--work", str(a.work), "--seed", str(a.seed)]
    cmd += ["--one", f"{f},{t},{s}"] + (["--true-radiance"] if a.true_radiance else [])
    try:
        proc = subprocess.run(cmd, timeout=a.run_timeout, capture_output=True, text=True)
        reason = None if proc.returncode == 0 else f"exit {proc.returncode}: {proc.stderr[-300:]}"
    except subprocess.TimeoutExpired:
        reason = f"timeout: not done after {a.run_timeout:.0f} s"
    if reason is None and path.is_file():
        return json.loads(path.read_text())
    rec = {
        "fraction": f,
        "trial": t,
        "true_radiance": a.true_radiance,
        "invert_seed": s,
        "failed": reason or "no record written",
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(rec, indent=1))
    shutil.rmtree(a.work / "scans" / _tag(f, t, a.true_radiance, s), ignore_errors=True)
    return rec


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scan", type=Path)
    ap.add_argument("--work", type=Path, default=Path("/tmp/reroom_incompleteness"))
    ap.add_argument(
        "--fractions",
        default=",".join(f"{x:.2f}" for x in np.arange(0, 0.91, 0.05)),
        help="comma-separated fractions of the vertices to delete",
    )
    ap.add_argument("--trials", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--shard", default="0/1", help="i/k: run every k-th run starting at i")
    ap.add_argument("--true-radiance", action="store_true")
    ap.add_argument(
        "--noise-floor",
        type=int,
        default=0,
        metavar="N",
        help="instead of the grid: the full mesh with invert seeds 1..N (sampling noise)",
    )
    ap.add_argument("--aggregate", action="store_true", help="only summarise the records")
    ap.add_argument(
        "--run-timeout",
        type=float,
        default=300.0,
        help="seconds per run (each in a subprocess; 0: in this process, no limit); a run "
        "past it is recorded as failed: the solve can stall on a mesh that is mostly gone",
    )
    ap.add_argument("--one", default=None, help=argparse.SUPPRESS)  # "fraction,trial,seed"
    ap.add_argument("--png", type=Path, default=None)
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args(argv)
    if a.aggregate:
        aggregate(
            a.work,
            a.true_radiance,
            a.png,
            a.json or a.work / f"summary{'_true' if a.true_radiance else ''}.json",
        )
        return 0
    if a.one is not None:
        f, t, s = a.one.split(",")
        run_one(a.scan, a.work, float(f), int(t), a.seed, a.true_radiance, int(s))
        return 0
    fractions = [float(x) for x in a.fractions.split(",")]
    # trial-major: every fraction gets its first trial before any its second
    grid = [(f, t, 0) for t in range(a.trials) for f in fractions if f > 0 or t == 0]
    if a.noise_floor:
        grid = [(0.0, 0, s) for s in range(1, a.noise_floor + 1)]
    i, k = (int(x) for x in a.shard.split("/"))
    for f, t, s in grid[i::k]:
        t0 = time.perf_counter()
        if a.run_timeout > 0:
            rec = _run_limited(a, f, t, s)
        else:
            rec = run_one(a.scan, a.work, f, t, a.seed, a.true_radiance, s)
        if rec.get("failed"):
            print(f"{_tag(f, t, a.true_radiance, s)}: FAILED ({rec['failed']})", flush=True)
            continue
        est = {c: rec["clusters"][c]["estimate"] for c in CLUSTERS}
        print(
            f"{_tag(f, t, a.true_radiance, s)}: {time.perf_counter() - t0:.0f} s, "
            + ", ".join(
                f"{c} {np.mean(e):.3f}" if e is not None else f"{c} -" for c, e in est.items()
            ),
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
