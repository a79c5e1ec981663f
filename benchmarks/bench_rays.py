"""Throughput of reroom.rays on a room-sized mesh with incoherent rays.

Run as ``.venv/bin/python benchmarks/bench_rays.py [--rays N] [--no-mitsuba]``.

The scene is an 8 x 6 x 3 m box room and twelve boxes of furniture, each
subdivided to give about 200k triangles. Rays start at uniform random points
inside the room and go in uniform random directions: the incoherent workload of
bounce rays, the worst case for a BVH. Closest-hit queries have no length
limit; occlusion queries stop at 2 m, so about half of them are blocked.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import trimesh

from reroom.rays import RayCaster

ROOM = np.array([8.0, 6.0, 3.0])
OCCLUSION_TMAX = 2.0


def subdivided_box(extents: np.ndarray, centre: np.ndarray, levels: int) -> trimesh.Trimesh:
    box = trimesh.creation.box(extents=extents)
    v, f = box.vertices, box.faces
    for _ in range(levels):
        v, f = trimesh.remesh.subdivide(v, f)
    return trimesh.Trimesh(v + centre, f, process=False)


def room_mesh(rng: np.random.Generator) -> trimesh.Trimesh:
    """The room shell (12 * 4^6 triangles) and 12 furniture boxes (12 * 4^5 each)."""
    parts = [subdivided_box(ROOM, ROOM / 2, 6)]
    for _ in range(12):
        size = rng.uniform([0.4, 0.4, 0.4], [2.0, 1.5, 2.0])
        pos = rng.uniform(size / 2, ROOM - size / 2)
        pos[2] = size[2] / 2  # standing on the floor
        parts.append(subdivided_box(size, pos, 5))
    return trimesh.util.concatenate(parts)


def rays(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    o = rng.uniform([0.01, 0.01, 0.01], ROOM - 0.01, (n, 3))
    d = rng.normal(size=(n, 3))
    return o, d / np.linalg.norm(d, axis=1, keepdims=True)


@dataclass
class Timing:
    """Best wall-clock and process CPU seconds of a few runs of one function."""

    wall: float = np.inf
    cpu: float = np.inf


def best_times(fns: dict[str, Callable[[], object]], repeats: int = 3) -> dict[str, Timing]:
    """Best wall and CPU time of each function, running them interleaved.

    Interleaving and taking the minimum keeps a burst of load from other
    processes from landing on one variant only, which matters for speed-up ratios.
    CPU time (all threads of this process) is barely affected by such load, so
    ``cpu(1 thread) / cpu(N threads)`` measures the parallel overhead even when
    the wall-clock speed-up cannot be measured.
    """
    best = {name: Timing() for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            w, c = time.perf_counter(), time.process_time()
            fn()
            best[name].wall = min(best[name].wall, time.perf_counter() - w)
            best[name].cpu = min(best[name].cpu, time.process_time() - c)
    return best


def report(label: str, n: int, t: Timing) -> float:
    rate = n / t.wall
    print(
        f"  {label:<40s} {rate / 1e6:6.2f} Mrays/s ({t.wall:5.2f} s wall)"
        f" {n / t.cpu / 1e6:6.2f} Mrays/CPU-s"
    )
    return rate


def speedup(one: Timing, many: Timing, cpus: int) -> None:
    print(
        f"  {cpus} threads: speed-up {one.wall / many.wall:.2f}x wall-clock; "
        f"CPU time {many.cpu / one.cpu:.2f}x that of 1 thread"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rays", type=int, default=5_000_000)
    parser.add_argument("--no-mitsuba", action="store_true", help="skip the Mitsuba backend")
    args = parser.parse_args()
    n = args.rays
    cpus = os.cpu_count() or 1
    rng = np.random.default_rng(0)

    mesh = room_mesh(rng)
    o, d = rays(rng, n)
    print(f"{platform.processor() or platform.machine()}, {cpus} CPUs")
    print(f"mesh: {len(mesh.faces):,} triangles; {n:,} incoherent rays")
    load = os.getloadavg()[0]
    if load > 0.5:
        print(f"warning: load average {load:.1f} before starting; other work skews the timings")

    start = time.perf_counter()
    single = RayCaster(mesh, threads=1)
    print(f"embree scene build: {time.perf_counter() - start:.2f} s")
    multi = RayCaster(mesh, threads=cpus)

    # The bare embreex call, float32 in and out, as a floor for our wrapper's overhead.
    o32 = (o - single.center).astype(np.float32)
    d32 = d.astype(np.float32)
    scene = single._backend.scene

    print("closest hit:")
    best = best_times(
        {
            "raw": lambda: scene.run(o32, d32, dists=np.full(n, np.inf, np.float32), output=1),
            "one": lambda: single.intersect(o, d),
            "many": lambda: multi.intersect(o, d),
        }
    )
    report("embreex run() alone, 1 thread", n, best["raw"])
    report("RayCaster.intersect, 1 thread", n, best["one"])
    report(f"RayCaster.intersect, {cpus} threads", n, best["many"])
    speedup(best["one"], best["many"], cpus)
    print(f"  wrapper overhead: {best['one'].cpu / best['raw'].cpu - 1:.0%} CPU over raw embreex")

    print(f"occlusion (tmax = {OCCLUSION_TMAX} m):")
    blocked = multi.occluded(o, d, OCCLUSION_TMAX)
    print(f"  {blocked.mean():.0%} of rays blocked")
    best = best_times(
        {
            "one": lambda: single.occluded(o, d, OCCLUSION_TMAX),
            "many": lambda: multi.occluded(o, d, OCCLUSION_TMAX),
        }
    )
    report("RayCaster.occluded, 1 thread", n, best["one"])
    report(f"RayCaster.occluded, {cpus} threads", n, best["many"])
    speedup(best["one"], best["many"], cpus)

    m = min(n, 1_000_000)
    print(f"chunk size ({cpus} threads, closest hit, {m:,} rays):")
    casters = {
        chunk: RayCaster(mesh, threads=cpus, chunk_size=chunk)
        for chunk in (1 << 12, 1 << 14, 1 << 16, 1 << 18)
    }
    best = best_times({c: (lambda r=r: r.intersect(o[:m], d[:m])) for c, r in casters.items()})
    for chunk, timing in best.items():
        report(f"chunk_size={chunk}", m, timing)

    if args.no_mitsuba:
        return
    from reroom.render import mitsuba_info

    info = mitsuba_info()
    if not info.vectorized:
        print(f"mitsuba: skipped ({info.note})")
        return
    print(f"mitsuba {info.mitsuba_version} ({info.variant}, LLVM {info.llvm_version}):")
    start = time.perf_counter()
    mit = RayCaster(mesh, backend="mitsuba")
    mit.intersect(o[:1000], d[:1000])
    mit.occluded(o[:1000], d[:1000], OCCLUSION_TMAX)
    print(f"  scene build + first (JIT-compiling) queries: {time.perf_counter() - start:.2f} s")
    best = best_times(
        {
            "hit": lambda: mit.intersect(o, d),
            "occ": lambda: mit.occluded(o, d, OCCLUSION_TMAX),
        },
        repeats=2,
    )
    report("RayCaster.intersect, mitsuba", n, best["hit"])
    report("RayCaster.occluded, mitsuba", n, best["occ"])


if __name__ == "__main__":
    main()
