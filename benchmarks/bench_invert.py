"""Benchmark of the eq. 5.7 solve (``reroom.invert.solve``) and of ``reroom invert``.

Part 1 (always): the solvers on synthetic problems with a known answer
(:func:`reroom.invert.synthetic.synthetic_problem`: an area light, a 96-cell window, a
32-bin point light and a 32-bin line light), exact and with 2 % noise and 10 % outlier
vertices: time, iterations, worst relative cluster-albedo error and worst relative L2
error of the seen basis intensities.

Part 2 (``--scan DIR [--true-radiance] [--scan-invert JSON]``): the pipeline on a scan
with hdr/, layout/, lights/ and ground truth (other InvertOptions as JSON), evaluated
by :func:`reroom.invert.evaluate.evaluate_invert` against the issue's targets (albedo within 3 %, power within 5 %, point and line
distributions within 10 % relative L2).

Part 3 (``--speed DIR``): ``reroom invert`` on a scan with hdr/, layout/ and lights/ (no
ground truth needed), e.g. the 208k-vertex paper-scale scan of ``bench_hdr.py --speed``:
wall and CPU time per step, the ray budget, and the ratio to the 2016 paper's 15-30 min
of inverse lighting and to the issue's 60 s target for transfer + solve.

    .venv/bin/python benchmarks/bench_invert.py [--n 20000] [--scan DIR] [--true-radiance]
        [--scan-invert '{"albedo_footprint_rings": 0}']

A window's solved sun (``reroom.invert.sun``) is reported against the HDRI's: the angle
between the two directions and the irradiance error.
    .venv/bin/python benchmarks/bench_invert.py --speed DIR --skip-solvers
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

from reroom.invert.solve import SolveOptions, solve_lighting
from reroom.invert.synthetic import synthetic_problem


def _errors(result, truth) -> tuple[float, float]:
    rho = float(np.nanmax(np.abs(result.albedo / truth.albedo - 1)))
    worst = 0.0
    for name, true in truth.intensities.items():
        seen = truth.seen[name]
        est = result.intensities[name][seen]
        worst = max(worst, float(np.linalg.norm(est - true[seen]) / np.linalg.norm(true[seen])))
    return rho, worst


def solver_table(n: int) -> None:
    cases = [
        ("exact, area+window", dict(lights=("area", "window")), dict(huber_delta=None)),
        ("exact, all four", dict(), dict(huber_delta=None)),
        ("2% noise, 10% outliers, all four", dict(noise=0.02, outlier_fraction=0.1), {}),
    ]
    methods = [
        ("joint (LM, dense normal eq.)", dict(method="joint", inner="lm")),
        ("joint (scipy trf + LSMR)", dict(method="joint", inner="trf")),
        ("alternating (NNLS / closed form)", dict(method="alternating", max_iterations=100)),
    ]
    print(f"### Solvers on synthetic problems, {n} vertices\n")
    print(f"load average before: {os.getloadavg()}\n")
    print(
        "| problem | solver | time (s) | iterations | converged | max albedo err | max light L2 err |"
    )
    print("|---|---|---|---|---|---|---|")
    for label, pkw, okw in cases:
        problem, truth = synthetic_problem(n, seed=1, **pkw)
        for mlabel, mkw in methods:
            opts = SolveOptions(reweight_c=None, max_vertices=None, **okw, **mkw)
            t = time.perf_counter()
            result = solve_lighting(problem, opts)
            dt = time.perf_counter() - t
            rho, light = _errors(result, truth)
            print(
                f"| {label} | {mlabel} | {dt:.2f} | {result.iterations} | {result.converged} "
                f"| {rho:.2e} | {light:.2e} |"
            )
    print(f"\nload average after: {os.getloadavg()}\n")


def huber_table(n: int) -> None:
    problem, truth = synthetic_problem(n, seed=2, noise=0.02, outlier_fraction=0.1)
    print(f"### Huber threshold, {n} vertices, 2% noise, 10% outliers (joint LM)\n")
    print("| huber delta | time (s) | rounds | max albedo err | max light L2 err |")
    print("|---|---|---|---|---|")
    for delta in (None, 0.1, 0.05, 0.02):
        t = time.perf_counter()
        result = solve_lighting(problem, SolveOptions(huber_delta=delta, reweight_c=None))
        rho, light = _errors(result, truth)
        dt = time.perf_counter() - t
        print(f"| {delta} | {dt:.2f} | {len(result.history)} | {rho:.3f} | {light:.3f} |")
    print(f"\nload average: {os.getloadavg()}\n")


def _l2_text(light: dict) -> str:
    """``all / seen`` (and well-seen) relative L2 of a light's distribution, or ``-``."""
    d = light.get("distribution") or {}
    if d.get("relative_l2") is None:
        return "-"
    seen = d.get("relative_l2_seen")
    if d.get("basis") == "cubemap":
        return f"{d['relative_l2']:.1%} ({d['shown_cells']} cells shown)"
    if seen is None:
        return f"{d['relative_l2']:.1%} / ?"
    well = d.get("relative_l2_well_seen")
    well_text = "-" if well is None else f"{well:.1%}"
    return (
        f"{d['relative_l2']:.1%} / {seen:.1%} ({len(d['seen_bins'])} bins seen; "
        f"well-seen bins {well_text})"
    )


def scan_table(scan: str, true_radiance: bool, options: dict | None = None) -> None:
    from reroom.invert.evaluate import evaluate_invert, run_invert_true_radiance
    from reroom.invert.pipeline import InvertOptions, run_invert

    out = os.path.join(scan, "invert_true" if true_radiance else "invert")
    t = time.perf_counter()
    run = run_invert_true_radiance if true_radiance else run_invert
    result = run(scan, out, InvertOptions(**(options or {})))
    dt = time.perf_counter() - t
    ev = evaluate_invert(scan, out)
    kind = "TRUE radiance (evaluation-only)" if true_radiance else "HDR radiance"
    print(f"### `reroom invert` on {scan} ({kind})\n")
    print(f"total {dt:.1f} s, load {os.getloadavg()}; timings {result.timings}\n")
    print("| cluster | relative albedo error (r, g, b) | target |")
    print("|---|---|---|")
    for name, c in ev["clusters"].items():
        err = ", ".join(f"{x:+.1%}" for x in c.get("relative_error", []))
        print(f"| {name} | {err} | 3 % |")
    print(
        "\n| light | truth | power error (r, g, b) | leaving its fitting | target "
        "| distribution rel. L2 all / seen bins | target |"
    )
    print("|---|---|---|---|---|---|---|")
    for light in ev["lights"]:
        err = light.get("power_relative_error")
        text = ", ".join(f"{x:+.1%}" for x in err) if err else light.get("note", "")
        eff = light.get("effective_power_relative_error")  # a point light's, past its shade
        eff_text = ", ".join(f"{x:+.1%}" for x in eff) if eff else "-"
        dist = _l2_text(light)
        target = "10 %" if light["type"] in ("point", "line") else ""
        off = light.get("distance_m")  # from the true light's position or centre
        truth = f"{light.get('truth')}" + (f" ({off:.3f} m off)" if off is not None else "")
        print(f"| {light['name']} | {truth} | {text} | {eff_text} | 5 % | {dist} | {target} |")
    for light in ev["lights"]:
        sun = (light.get("distribution") or {}).get("sun")
        if sun is None:
            continue
        if sun.get("truth") is None:
            print(f"\n{light['name']}: a sun solved, but the true sky has none through it")
            continue
        err = ", ".join(f"{x:+.1%}" for x in sun["irradiance_relative_error"])
        print(
            f"\n{light['name']}'s sun: {sun['angle_deg']:.2f} degrees from the HDRI's, "
            f"irradiance error {err} (the true sun is {sun['truth']['share_of_flux']:.1%} "
            "of the window's flux)"
        )
    print(f"\nper-vertex albedo: {ev['per_vertex']}; missed lights: {ev['missed_lights']}\n")


def speed_table(scan: str, out: str | None = None, options: dict | None = None) -> None:
    """Time ``reroom invert`` on ``scan``: per step, rays, and the ratios to the targets.

    ``options``: InvertOptions other than the defaults (e.g. ``{"window_samples": 0}``).
    The window portals' ray count is an upper bound: receivers behind a window's plane
    or facing away from it cast none.
    """
    import tempfile
    from pathlib import Path

    from reroom.invert.pipeline import InvertOptions, run_invert

    opts = InvertOptions(pictures=False, **(options or {}))
    with tempfile.TemporaryDirectory() as tmp:
        t0, c0 = time.perf_counter(), time.process_time()
        res = run_invert(scan, Path(out) if out else Path(tmp) / "invert", opts)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        import json

        meta = json.loads((res.out_dir / "report.json").read_text())
    tm = res.timings
    n_v = len(res.albedo)
    recv = int(meta.get("receivers", 0))
    hemi = int(meta.get("hemisphere_receivers", 0))
    clustered = int(meta.get("clustered", 0))
    kinds = [b.kind for b in res.lights]
    rays = {
        "hemisphere": hemi * opts.rays_per_receiver,
        "area lights": recv * opts.area_samples * kinds.count("area"),
        "window portals (upper bound)": recv * opts.window_samples * kinds.count("window"),
        "point lights": recv * kinds.count("point"),
        "line lights": recv * opts.line_segments * kinds.count("line"),
        "near filter": clustered * 64,
    }
    # Point-light refinement: one shadow ray per fitted receiver per trial position, and
    # the moved lights' transfer recomputed on every receiver.
    # A light placed from its ceiling pool's edge is not refined (its entry says why).
    refined = [e["refinement"] for e in res.light_info if "evaluations" in e.get("refinement", {})]
    if refined:
        fitted = min(clustered, opts.refine_max_receivers)
        moved = sum(1 for e in res.light_info if "refined_from" in e)
        rays["point-light refinement"] = (
            sum(r["evaluations"] for r in refined) * fitted + moved * recv
        )
    solve_only = tm["solve"] - tm.get("near_filter", 0.0)
    refine = tm.get("refine_points", 0.0)
    transfer_solve = tm["hemisphere_transfer"] + tm["direct_transfer"] + tm["solve"] + refine
    print(f"\n## reroom invert speed: {scan}\n")
    print(
        f"{n_v} vertices, {recv} receivers ({hemi} hemisphere receivers), "
        f"{clustered} clustered; lights: {', '.join(kinds)}; {os.cpu_count()} CPUs, "
        f"load {os.getloadavg()[0]:.1f} at the end\n"
    )
    print("| step | wall s |\n|---|---|")
    for key in ("load", "hemisphere_transfer", "direct_transfer", "near_filter", "per_vertex"):
        if key in tm:
            print(f"| {key} | {tm[key]:.1f} |")
        if key == "direct_transfer" and "window_sun" in tm:
            print(f"| of which the windows' sun search | {tm['window_sun']:.1f} |")
    print(f"| solve (without the near filter) | {solve_only:.1f} |")
    if "refine_points" in tm:
        print(f"| refine_points (search, transfer, second solve) | {refine:.1f} |")
    print(f"| outputs | {wall - tm['total']:.1f} |")
    print(f"| **whole run_invert** | **{wall:.1f}** (CPU {cpu:.1f} s) |")
    print("\n| rays | count |\n|---|---|")
    for key, value in rays.items():
        print(f"| {key} | {value / 1e6:.2f} M |")
    print(f"| total | {sum(rays.values()) / 1e6:.2f} M |")
    print(
        f"\ntransfer + solve: {transfer_solve:.1f} s, {transfer_solve / 60:.2f} of the 60 s "
        f"target; the paper's 15-30 min of inverse lighting / ours: "
        f"{900 / transfer_solve:.0f}-{1800 / transfer_solve:.0f}x"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--n", type=int, default=5000)
    ap.add_argument("--scan", default=None)
    ap.add_argument("--true-radiance", action="store_true")
    ap.add_argument("--speed", default=None, help="scan to time reroom invert on")
    ap.add_argument(
        "--speed-invert",
        default="{}",
        help="InvertOptions as JSON for --speed, e.g. '{\"window_samples\": 0}'",
    )
    ap.add_argument(
        "--scan-invert",
        default="{}",
        help="InvertOptions as JSON for --scan, e.g. '{\"albedo_footprint_rings\": 0}'",
    )
    ap.add_argument("--skip-solvers", action="store_true", help="no part 1")
    args = ap.parse_args()
    if not args.skip_solvers:
        solver_table(args.n)
        huber_table(args.n)
    if args.scan:
        scan_table(args.scan, args.true_radiance, json.loads(args.scan_invert))
    if args.speed:
        speed_table(args.speed, options=json.loads(args.speed_invert))


if __name__ == "__main__":
    main()
