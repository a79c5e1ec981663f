"""The hemisphere transfer's per-ray bookkeeping: parallel against serial, on a real scan.

``reroom invert``'s hemisphere transfer casts its rays in batches and hands each batch to
the numba kernel :func:`reroom.invert._kernels.accumulate`, which classifies every ray and
adds its shares to its receiver's sums. The kernel runs the receivers in parallel
(``prange``), each receiver's rays in order. This script runs ``reroom invert`` on SCAN up
to the solve, records every batch's inputs, then times the kernel as shipped against the
same source compiled without ``parallel`` (``prange`` then runs as ``range``) on those
inputs, and checks that both give the same sums to the bit::

    python benchmarks/bench_hemisphere_bookkeeping.py /tmp/s7/furn300 --work /tmp/hb
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numba as nb
import numpy as np

import reroom.invert._kernels as kernels
import reroom.invert.pipeline as pipeline
from reroom.invert.pipeline import InvertOptions, run_invert


class _Stop(Exception):
    """Raised in place of the solve: the transfers are all this script needs."""


def record_batches(scan: Path, work: Path) -> list[list]:
    """Every ``accumulate`` call's arguments (copied before the call) of one invert run."""
    calls: list[list] = []
    shipped, solve = kernels.accumulate, pipeline.solve_lighting

    def recording(*args):
        calls.append([a.copy() if isinstance(a, np.ndarray) else a for a in args])
        return shipped(*args)

    def stop(*_args, **_kwargs):
        raise _Stop

    kernels.accumulate, pipeline.solve_lighting = recording, stop
    try:
        run_invert(scan, work, InvertOptions(pictures=False, textures=False, refine_points=False))
    except _Stop:
        pass
    finally:
        kernels.accumulate, pipeline.solve_lighting = shipped, solve
    return calls


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scan", type=Path)
    ap.add_argument("--work", type=Path, default=Path("/tmp/reroom_bench_bookkeeping"))
    args = ap.parse_args()
    calls = record_batches(args.scan, args.work)
    if not calls:
        raise SystemExit(f"{args.scan}: the invert run cast no hemisphere rays")
    serial = nb.njit(kernels.accumulate.py_func)

    def copy(call):
        return [a.copy() if isinstance(a, np.ndarray) else a for a in call]

    kernels.accumulate(*copy(calls[0]))  # compile (or load) both before timing
    serial(*copy(calls[0]))
    t_par = t_ser = 0.0
    same = True
    for call in calls:
        a, b = copy(call), copy(call)
        t = time.perf_counter()
        kernels.accumulate(*a)
        t_par += time.perf_counter() - t
        t = time.perf_counter()
        serial(*b)
        t_ser += time.perf_counter() - t
        same &= all(
            np.array_equal(x, y, equal_nan=True)
            for x, y in zip(a, b, strict=True)
            if isinstance(x, np.ndarray)
        )
    rays = sum(len(c[1]) for c in calls)
    print(
        f"{args.scan}: {len(calls)} batches, {rays / 1e6:.1f} M rays, {nb.get_num_threads()} threads"
    )
    print(
        f"serial {t_ser:.2f} s, parallel {t_par:.2f} s: {t_ser / t_par:.2f}x; sums identical: {same}"
    )
    print(f"load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
