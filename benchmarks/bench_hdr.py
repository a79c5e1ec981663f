"""How accurate and how fast is ``reroom hdr`` (radiometric calibration, thesis ch. 3)?

Three parts, each printing a markdown table:

``--accuracy``
    A path-traced ``furnished`` scan from ``generate_scan`` (noise on; cached under
    ``--cache``, default ``/tmp/reroom_hdr_cache``): exposure-ratio error per
    frame and channel, per-vertex radiance error on observed diffuse vertices,
    and the seam metric, for ours and both baselines. Targets: median ratio
    error < 1 %, median radiance error < 3 %, both baselines worse on seams.
``--solvers``
    The solver choice: every solver of :mod:`reroom.hdr.solve` (and weighting /
    robustness / subset variants) on the accuracy scan's samples, time and
    accuracy.
``--speed``
    A SPEED benchmark at the 2016 paper's scale (1000 frames of 640x360, a
    ~200k-vertex mesh). Path tracing that takes far too long here, so the frames
    are rendered cheaply instead: a known per-vertex radiance (albedo x a simple
    light falloff) interpolated over the triangles seen through each pixel
    (ray cast), exposed by the simulated auto-exposure camera, 8-bit quantised.
    Not an accuracy benchmark. Times reprojection (both visibility methods) and
    the solve, and prints the ratio to the paper's ~20 min (5 + 15).

Usage (niced; the machine is shared)::

    nice -n 10 python benchmarks/bench_hdr.py --accuracy --solvers
    nice -n 10 python benchmarks/bench_hdr.py --speed
    nice -n 10 python benchmarks/bench_hdr.py --slambook2
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import time
import warnings
from pathlib import Path

import numpy as np

CACHE = Path("/tmp/reroom_hdr_cache")
PAPER_REPROJECT_S = 5 * 60.0
PAPER_SOLVE_S = 15 * 60.0


def _load() -> str:
    try:
        return " ".join(f"{x:.1f}" for x in os.getloadavg())
    except OSError:
        return "?"


# --------------------------------------------------------------------------- speed problem


def make_speed_scan(
    out: Path, n_frames: int = 1000, width: int = 640, height: int = 360, spacing: float = 0.026
) -> Path:
    """A paper-scale scan with cheaply rendered frames (see the module notes)."""
    import tempfile

    import trimesh

    from reroom.rays import RayCaster
    from reroom.scan import Frame, Intrinsics, write_scan
    from reroom.synth.camera_sim import AutoCamera, CameraModel
    from reroom.synth.groundtruth import clean_surface
    from reroom.synth.labels import LABELS
    from reroom.synth.presets import build_preset
    from reroom.synth.scene import write_scene
    from reroom.synth.trajectory import walk_and_look

    if (out / "transforms.json").is_file():
        return out
    rng = np.random.default_rng(7)
    spec = build_preset("furnished", mesh_spacing=spacing)
    with tempfile.TemporaryDirectory() as tmp:
        desc = write_scene(spec, Path(tmp) / "scene")
        clean = clean_surface(desc, Path(tmp) / "scene")
    v, f, n = clean.vertices, clean.faces, clean.normals
    # A plausible, smooth-ish radiance: albedo x (ambient + a few inverse-square lights).
    lights = np.array([[1.0, 1.0, 2.4], [3.5, 2.5, 2.4], [2.0, 3.5, 1.6]])
    power = np.array([1.2, 0.8, 0.5])
    irr = np.full(len(v), 0.08)
    for p, w in zip(lights, power, strict=True):
        d = p - v
        r2 = np.einsum("ij,ij->i", d, d)
        irr += w * np.maximum(np.einsum("ij,ij->i", n, d) / np.sqrt(r2), 0) / r2
    radiance = clean.albedo * irr[:, None]
    radiance[clean.label == LABELS["light"]] = 15.0
    caster = RayCaster(v, f)
    intr = Intrinsics.from_fov(width, height, 60.0)
    poses = walk_and_look(spec.waypoints, n_frames, rng)
    cam = AutoCamera(CameraModel(noise=True), np.random.default_rng(8))
    scales = []

    def frames():
        t0 = time.perf_counter()
        for j, c2w in enumerate(poses):
            fr = Frame(j, Path(), c2w, intr)
            o, d = fr.pixel_rays()
            hits = caster.intersect(o, d)
            tri = f[np.maximum(hits.face, 0)]
            img = np.einsum("ij,ijk->ik", hits.barycentric, radiance[tri])
            img[~hits.hit] = 0.0
            u8, scale, _, _ = cam.capture(img.reshape(height, width, 3))
            scales.append(scale.tolist())
            if j % 100 == 0:
                print(f"  speed scan: frame {j}/{n_frames} ({time.perf_counter() - t0:.0f} s)")
            yield u8

    tmp_out = out.with_name(out.name + ".partial")
    shutil.rmtree(tmp_out, ignore_errors=True)
    mesh = trimesh.Trimesh(v, f, process=False)
    write_scan(tmp_out, mesh, intr, poses, frames(), meta={"reroom": {"response": "gamma2.2"}})
    (tmp_out / "speed_truth.json").write_text(json.dumps({"scale": scales}))
    tmp_out.rename(out)
    return out


def bench_speed(args) -> list[dict]:
    from reroom.hdr import ObserveOptions, collect_observations, reproject_radiance, response_lut
    from reroom.hdr.solve import SolveOptions, solve_exposures
    from reroom.rays import RayCaster
    from reroom.scan import load_scan

    scan_dir = args.cache / f"speed_{args.speed_frames}x640x360"
    t = time.perf_counter()
    make_speed_scan(scan_dir, n_frames=args.speed_frames)
    print(f"speed scan ready ({time.perf_counter() - t:.0f} s)")
    scan = load_scan(scan_dir)
    lut = response_lut("auto", scan.meta)
    truth = np.asarray(json.loads((scan_dir / "speed_truth.json").read_text())["scale"])
    truth = truth / truth[0]
    nv = len(scan.mesh.vertices)
    rows = []
    caster = RayCaster(scan.mesh)
    methods = args.visibility.split(",")
    for vis in methods:
        opts = ObserveOptions(visibility=vis)
        print(f"reprojection, visibility={vis} (load {_load()}) ...", flush=True)
        t, c = time.perf_counter(), time.process_time()
        obs = collect_observations(scan.frames, scan.mesh, lut, opts, caster)
        t_rep, c_rep = time.perf_counter() - t, time.process_time() - c
        t, c = time.perf_counter(), time.process_time()
        sol = solve_exposures(obs, SolveOptions())
        t_sol, c_sol = time.perf_counter() - t, time.process_time() - c
        t = time.perf_counter()
        rad = reproject_radiance(obs, sol.scales)
        t_rad = time.perf_counter() - t
        err = np.abs(sol.scales / truth - 1)
        rows.append(
            {
                "visibility": vis,
                "frames": len(scan.frames),
                "vertices": nv,
                "samples": len(obs),
                "reproject_s": t_rep,
                "solve_s": t_sol,
                "radiance_s": t_rad,
                "observed": int(rad.observed.sum()),
                "cpu_s": c_rep + c_sol,
                "total_s": t_rep + t_sol,
                "ratio_err_median": float(np.nanmedian(err)),
                "paper_over_ours": (PAPER_REPROJECT_S + PAPER_SOLVE_S) / (t_rep + t_sol),
                "memory_MB": obs.nbytes / 1e6,
                "load_after": _load(),
            }
        )
        print(f"  {rows[-1]}", flush=True)
        del obs
    print()
    print(f"### Speed at the paper's scale (cheap frames; {os.cpu_count()} cores, load {_load()})")
    print()
    print(
        "| visibility | frames | vertices | samples | reprojection s | solve s | total s "
        "| CPU s (both cores) | paper (5+15 min) / ours | exposure err (median) | samples MB "
        "| + weighted medians s |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['visibility']} | {r['frames']} | {r['vertices']} | {r['samples']:,} "
            f"| {r['reproject_s']:.1f} | {r['solve_s']:.1f} | {r['total_s']:.1f} "
            f"| {r['cpu_s']:.1f} | {r['paper_over_ours']:.0f}x | {100 * r['ratio_err_median']:.2f} % "
            f"| {r['memory_MB']:.0f} | {r['radiance_s']:.1f} |"
        )
    return rows


# --------------------------------------------------------------------------- accuracy


ACC_OPTS = dict(frames=240, width=160, height=120, spp=64, vertex_spp=4096, seed=0)


def accuracy_scan(cache: Path) -> Path:
    """The path-traced furnished scan (generated once, ~20-40 min niced on 2 cores)."""
    from reroom.synth.generate import SynthOptions, generate_scan

    o = ACC_OPTS
    out = cache / (
        f"furnished_f{o['frames']}_{o['width']}x{o['height']}_spp{o['spp']}_v{o['vertex_spp']}"
    )
    if (out / "transforms.json").is_file() and (out / "ground_truth/ground_truth.json").is_file():
        return out
    print(f"generating {out} (path tracing; this takes a while) ...")
    shutil.rmtree(out, ignore_errors=True)
    generate_scan("furnished", out, SynthOptions(**o))
    return out


def _pct(x) -> str:
    return "-" if x is None else f"{100 * x:.2f}"


def bench_accuracy(args, scan: Path | None = None) -> dict:
    from reroom.hdr import HdrOptions, run_hdr
    from reroom.hdr.evaluate import evaluate_hdr

    scan = scan or accuracy_scan(args.cache)
    scan_name = scan.name
    out = args.cache / f"hdr_{scan_name}"
    t = time.perf_counter()
    res = run_hdr(scan, out, HdrOptions())
    wall = time.perf_counter() - t
    ev = evaluate_hdr(scan, out, max_truth_stderr=args.max_truth_stderr)
    truth_opts = json.loads((scan / "ground_truth/ground_truth.json").read_text())["options"]
    print()
    print(
        f"### Accuracy: {scan_name} ({truth_opts['frames']} frames {truth_opts['width']}x"
        f"{truth_opts['height']}, {truth_opts['spp']} spp, noise on, truth "
        f"{truth_opts['vertex_spp']} spp/vertex)"
    )
    print()
    print(
        "| method | exposure ratio err median % | p90 % | max % | radiance err median % "
        "| p90 % | seam (walls, log) | seam p90 | loop seam | boundary seam |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, m in ev["methods"].items():
        e, r = m["exposure_ratio_error"], m["radiance_error"]
        print(
            f"| {name} | {_pct(e['median'])} | {_pct(e['p90'])} | {_pct(e['max'])} "
            f"| {_pct(r['median'])} | {_pct(r['p90'])} | {m['seam']['seam']:.4f} "
            f"| {m['seam']['p90']:.4f} | {m['loop_seam']['seam']:.4f} "
            f"| {m['boundary_seam']['seam']:.4f} |"
        )
    for name, key in (("uncalibrated", "uncalibrated"), ("true scales", "true_scales")):
        m = ev[key]
        zero = "0 | 0 | 0" if key == "true_scales" else " | | "
        print(
            f"| {name} | {zero} | | | {m['seam']['seam']:.4f} | {m['seam']['p90']:.4f} "
            f"| {m['loop_seam']['seam']:.4f} | {m['boundary_seam']['seam']:.4f} |"
        )
    r = ev["methods"]["ours"]["radiance_error"]
    print()
    if not r["vertices"]:
        print(f"no vertex has truth stderr < {100 * args.max_truth_stderr:.0f} %: truth too noisy")
    else:
        print(
            f"radiance error on {r['vertices']} observed diffuse vertices with truth stderr < "
            f"{100 * ev['truth']['max_truth_stderr']:.0f} % (of {r['diffuse_vertices']} diffuse, "
            f"{r['diffuse_observed']} observed); truth's own median relative stderr there "
            f"{_pct(r['truth_rel_stderr_median'])} %; median ratio ours/truth "
            f"{r['median_ratio']:.4f}; by label: "
            + ", ".join(f"{k} {_pct(v)} %" for k, v in r["by_label"].items())
        )
    if r.get("ratio_of_sums"):
        print(
            f"ratio of sums ours / truth over {r['ratio_of_sums_vertices']} observed diffuse "
            "vertices (r/g/b; the truth's noise cancels): "
            + "/".join(f"{v:.3f}" for v in r["ratio_of_sums"])
            + "; by label: "
            + ", ".join(
                f"{k} " + "/".join(f"{v:.3f}" for v in vals)
                for k, vals in r["ratio_of_sums_by_label"].items()
                if vals
            )
        )
    print(
        f"run_hdr wall time {wall:.1f} s: "
        + ", ".join(f"{k} {v:.1f}" for k, v in res.timings.items())
    )
    ours = ev["methods"]["ours"]
    med_rad = ours["radiance_error"]["median"]
    checks = {
        "median exposure ratio error < 1 %": ours["exposure_ratio_error"]["median"] < 0.01,
        "median radiance error < 3 %": med_rad is not None and med_rad < 0.03,
    }
    for base in ("frame-to-frame", "frame-to-model"):
        for key in ("seam", "loop_seam"):
            theirs = ev["methods"][base][key]["seam"]
            checks[
                f"{base} {key.replace('_', ' ')} worse ({theirs:.4f} vs ours "
                f"{ours[key]['seam']:.4f})"
            ] = theirs > ours[key]["seam"]
    print()
    for k, ok in checks.items():
        print(f"- {'PASS' if ok else 'FAIL'}: {k}")
    if args.save_images:
        args.save_images.mkdir(parents=True, exist_ok=True)
        short = scan_name.split("_")[0]
        for src, dst in (
            ("report/hdr_exposures_truth.png", f"hdr_exposures_{short}.png"),
            ("report/hdr_before_after.png", f"hdr_before_after_{short}.png"),
        ):
            shutil.copyfile(out / src, args.save_images / dst)
    return ev


def bench_solvers(args) -> None:
    """Every solver and a few variants on the accuracy scan's samples."""
    from reroom.hdr import ObserveOptions, collect_observations, response_lut
    from reroom.hdr.evaluate import DIFFUSE_LABELS, exposure_errors, load_truth, radiance_errors
    from reroom.hdr.reproject import VertexGroups, reproject_radiance
    from reroom.hdr.solve import SolveOptions, solve_exposures
    from reroom.scan import load_scan

    scan_dir = accuracy_scan(args.cache)
    scan = load_scan(scan_dir)
    truth = load_truth(scan_dir)
    lut = response_lut("auto", scan.meta)
    diffuse = np.isin(truth.label, [truth.labels[n] for n in DIFFUSE_LABELS])

    def score(scales, obs, groups) -> tuple[dict, dict]:
        e = exposure_errors(scales, truth.scales, 0)
        rad = reproject_radiance(obs, scales, groups)
        r = radiance_errors(rad.radiance, rad.observed, truth, truth.scales[0], diffuse)
        return e, r

    def observe(**kw):
        t = time.perf_counter()
        obs = collect_observations(scan.frames, scan.mesh, lut, ObserveOptions(**kw))
        return obs, time.perf_counter() - t

    rows = []
    if args.observe_variants:
        for kw in [
            {},
            {"visibility": "rays"},
            {"sampling": "nearest"},
            {"sampling": "bilinear"},
            {"gradient_threshold": 0.15},
            {"gradient_threshold": 0.4},
            {"gradient_threshold": np.inf},
            {"gradient_smoothing": 0},
            {"keep_flagged": False},
            {"depth_tolerance": 0.005},
        ]:
            print(f"  observe {kw} ...", flush=True)
            obs, t_obs = observe(**kw)
            groups = VertexGroups(obs)
            sol = solve_exposures(obs, SolveOptions())
            e, r = score(sol.scales, obs, groups)
            label = ", ".join(f"{k}={v}" for k, v in kw.items()) or "default observe options"
            rows.append((f"observe: {label}", len(obs), t_obs, e, r))
    obs, _ = observe()
    groups = VertexGroups(obs)
    # The iterative linear-domain solvers run without IRLS rounds (each round would
    # repeat their iterations); compare them with log-schur without IRLS too.
    plain = dict(robust=False)
    variants = [
        ("log-schur (default: uniform weights, Cauchy IRLS, 30k vertices)", SolveOptions()),
        ("log-schur, Huber IRLS (k = 2)", SolveOptions(loss="huber", robust_k=2.0)),
        ("log-schur, no IRLS", SolveOptions(**plain)),
        ("log-schur, hat weights (eq. 3.3)", SolveOptions(weighting="hat")),
        (
            "log-schur, all vertices, all samples",
            SolveOptions(max_vertices=10**9, max_samples_per_vertex=10**9),
        ),
        ("log-schur, 5k vertices", SolveOptions(max_vertices=5000)),
        ("log-schur, 64 samples/vertex", SolveOptions(max_samples_per_vertex=64)),
        (
            "linear-schur (eq. 3.1, LM from ones), no IRLS",
            SolveOptions(method="linear-schur", **plain),
        ),
        ("linear-schur, Cauchy IRLS", SolveOptions(method="linear-schur")),
        (
            "alternating (eq. 3.1, from ones), 100 iterations/round, Cauchy IRLS",
            SolveOptions(method="alternating", max_iterations=100),
        ),
        (
            "alternating (eq. 3.1, from ones), 100 iterations, no IRLS",
            SolveOptions(method="alternating", max_iterations=100, **plain),
        ),
        (
            "alternating, 1000 iterations, no IRLS",
            SolveOptions(method="alternating", max_iterations=1000, **plain),
        ),
        (
            "scipy least_squares (eq. 3.1, 3k vertices), no IRLS",
            SolveOptions(method="scipy", max_vertices=3000, max_iterations=20, **plain),
        ),
    ]
    for name, opt in variants:
        print(f"  {name} ...", flush=True)
        t = time.perf_counter()
        sol = solve_exposures(obs, opt)
        dt = time.perf_counter() - t
        e, r = score(sol.scales, obs, groups)
        rows.append((name, sol.info.get("samples", 0), dt, e, r))
    from reroom.hdr import baselines

    for name, fn in (
        ("frame-to-frame", lambda o: baselines.frame_to_frame(o)),
        ("frame-to-model (least squares)", lambda o: baselines.frame_to_model(o)),
        (
            "frame-to-model (mean ratio, thesis)",
            lambda o: baselines.frame_to_model(o, estimator="mean-ratio"),
        ),
    ):
        t = time.perf_counter()
        s, _ = fn(obs)
        dt = time.perf_counter() - t
        e, r = score(s, obs, groups)
        rows.append((f"baseline {name}", len(obs), dt, e, r))
    print()
    print(f"### Solvers on the accuracy scan ({len(obs):,} samples; load {_load()})")
    print()
    print("| variant | samples | time s | ratio err median % | p90 % | radiance err median % |")
    print("|---|---|---|---|---|---|")
    for name, n, dt, e, r in rows:
        print(
            f"| {name} | {n:,} | {dt:.2f} | {_pct(e['median'])} | {_pct(e['p90'])} "
            f"| {_pct(r['median'])} |"
        )


def bench_slambook2(args) -> None:
    """Import the real slambook2 RGB-D sequence and calibrate it (before/after pictures)."""
    from reroom.hdr import HdrOptions, run_hdr
    from reroom.importers import import_rgbd_folder

    src = Path("/work/shared/data/real/slambook2_rgbd")
    scan = args.cache / "slambook2_scan"
    if not (scan / "transforms.json").is_file():
        shutil.rmtree(scan, ignore_errors=True)
        import_rgbd_folder(src, scan)
    out = args.cache / "hdr_slambook2"
    t = time.perf_counter()
    res = run_hdr(scan, out, HdrOptions())
    wall = time.perf_counter() - t
    print()
    print(f"### slambook2 ({len(res.scales)} frames, {len(res.radiance)} vertices)")
    print()
    print("| frame | status | t_R | t_G | t_B | frame-to-frame G | frame-to-model G |")
    print("|---|---|---|---|---|---|---|")
    for j, s in enumerate(res.scales):
        f2f = res.baselines["frame-to-frame"][j, 1]
        f2m = res.baselines["frame-to-model"][j, 1]
        print(
            f"| {j} | {res.status[j]} | {s[0]:.4f} | {s[1]:.4f} | {s[2]:.4f} "
            f"| {f2f:.4f} | {f2m:.4f} |"
        )
    print()
    print((out / "report" / "report.md").read_text())
    print(f"observed {int(res.observed.sum())} of {len(res.observed)} vertices; {wall:.1f} s")
    if args.save_images:
        args.save_images.mkdir(parents=True, exist_ok=True)
        for src_name, dst in (
            ("report/hdr_exposures.png", "hdr_exposures_slambook2.png"),
            ("report/hdr_before_after.png", "hdr_before_after_slambook2.png"),
        ):
            shutil.copyfile(out / src_name, args.save_images / dst)


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--accuracy", action="store_true")
    ap.add_argument("--solvers", action="store_true")
    ap.add_argument("--speed", action="store_true")
    ap.add_argument("--slambook2", action="store_true")
    ap.add_argument("--cache", type=Path, default=CACHE)
    ap.add_argument("--speed-frames", type=int, default=1000)
    ap.add_argument("--visibility", default="depth,rays")
    ap.add_argument(
        "--observe-variants", action="store_true", help="with --solvers: visibility/gradient too"
    )
    ap.add_argument("--save-images", type=Path, default=None, help="copy report PNGs here")
    ap.add_argument("--max-truth-stderr", type=float, default=0.02)
    ap.add_argument(
        "--scan", type=Path, action="append", default=[], help="with --accuracy: more scans"
    )
    args = ap.parse_args()
    args.cache.mkdir(parents=True, exist_ok=True)
    warnings.simplefilter("ignore")
    print(f"{os.cpu_count()} cores, load {_load()}")
    if args.accuracy:
        bench_accuracy(args)
        for extra in args.scan:
            bench_accuracy(args, extra)
    if args.solvers:
        bench_solvers(args)
    if args.speed:
        bench_speed(args)
    if args.slambook2:
        bench_slambook2(args)


if __name__ == "__main__":
    main()
