"""The photo textures' solve: how close its steps come to the converged texels, and their cost.

Usage::

    python benchmarks/bench_texture_solve.py RUN [--smooth S] [--work /tmp/reroom_texture_solve]

``RUN`` is a finished ``reroom run`` folder. Its inputs are linked into ``WORK`` (as
``bench_invert_sweep.py`` does) and ``reroom invert`` runs there in this process with
:func:`reroom.invert.texture_solve.solve_texels` wrapped, so the samples it solves are
exactly the pipeline's (every photo pixel on the texture planes, with its footprint).
Those samples are then solved again: 300 preconditioned steps to a residual of 1e-7 as
the reference, and plain and Jacobi-preconditioned conjugate gradients stopped after 5,
10, 15, 20 and 30 steps. Printed per setting: the relative residual, the RMS distance
to the reference over the seen texels (coverage >= ``MIN_COVERAGE``) relative to the
reference's RMS, the 99th percentile of the absolute distance, and the wall time, with
the ratio to 30 plain steps (the solve's first version; docs/benchmarks.md, session 40).
The smoothness is the pipeline's own (one per plane, by its label; session 41) unless
``--smooth`` gives one number for every plane.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_invert_sweep import sweep_dir  # noqa: E402


def pipeline_samples(run: Path, work: Path):
    """The samples, plane shapes and per-plane smoothness ``reroom invert`` solves on
    ``run``'s inputs."""
    import reroom.invert.texture_solve as texture_solve
    from reroom.invert.pipeline import InvertOptions, run_invert

    captured = {}
    solve = texture_solve.solve_texels

    def capture(samples, shapes, *args, **kwargs):
        captured["samples"], captured["shapes"] = samples, list(shapes)
        captured["smooth"] = kwargs.get("smooth", 1.0)
        return solve(samples, shapes, *args, **kwargs)

    texture_solve.solve_texels = capture  # textures.py imports it at call time
    try:
        d = sweep_dir(run, work, "-")
        run_invert(d, d / "invert", InvertOptions())
    finally:
        texture_solve.solve_texels = solve
    if "samples" not in captured:
        raise SystemExit(f"{run}: the invert solved no texture (no textures, or texels too coarse)")
    return captured["samples"], captured["shapes"], captured["smooth"]


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("run", type=Path)
    ap.add_argument("--work", type=Path, default=Path("/tmp/reroom_texture_solve"))
    ap.add_argument("--smooth", type=float, default=None, help="one smoothness for every plane")
    args = ap.parse_args()

    from reroom.invert.texture_solve import solve_texels
    from reroom.invert.textures import MIN_COVERAGE

    samples, shapes, smooth = pipeline_samples(args.run, args.work)
    if args.smooth is not None:
        smooth = args.smooth
    n_tex = sum(h * w for h, w in shapes)
    print(f"{args.run}: {len(samples)} samples, {len(shapes)} planes, {n_tex} texels")
    print(f"smoothness (footprints, per plane): {np.round(np.atleast_1d(smooth), 3).tolist()}")
    t0 = time.perf_counter()
    ref, coverage, st = solve_texels(samples, shapes, smooth=smooth, iterations=300, tol=1e-7)
    print(
        f"reference: {st['iterations']} preconditioned steps, residual "
        f"{st['relative_residual']:.1e}, {time.perf_counter() - t0:.1f} s\n"
    )
    seen = coverage >= MIN_COVERAGE
    scale = float(np.sqrt((ref[seen] ** 2).mean()))
    print(
        "| steps | preconditioned | residual | RMS to reference | p99 abs | seconds | time / 30 plain |"
    )
    print("|---|---|---|---|---|---|---|")
    rows = []
    for precondition in (False, True):
        for steps in (5, 10, 15, 20, 30):
            t0 = time.perf_counter()
            x, _, st = solve_texels(
                samples, shapes, smooth=smooth, iterations=steps, precondition=precondition
            )
            dt = time.perf_counter() - t0
            d = np.abs(x[seen] - ref[seen])
            rows.append((steps, precondition, st["relative_residual"], d, dt))
    base = next(r[4] for r in rows if r[0] == 30 and not r[1])
    for steps, precondition, res, d, dt in rows:
        rms = float(np.sqrt((d**2).mean())) / scale
        print(
            f"| {steps} | {'yes' if precondition else 'no'} | {res:.4f} | {100 * rms:.3f} % "
            f"| {np.percentile(d, 99):.4f} | {dt:.1f} | {dt / base:.2f} |"
        )


if __name__ == "__main__":
    main()
