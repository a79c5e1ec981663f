"""Speed and accuracy of reroom.invert's light transfer on synthetic furnished-room scans.

Run as ``.venv/bin/python benchmarks/bench_transfer.py [--small HDR_MESH] [--large HDR_MESH]``.

Inputs are ``hdr_mesh.ply`` files (radiance, observed) of the ``furnished`` preset:
by default ``/tmp/reroom_hdr_cache/hdr_furnished/hdr_mesh.ply`` (26k vertices,
a 240-frame synthetic scan through ``run_hdr``) and
``/tmp/reroom_hdr_cache/hdr_speed/hdr_mesh.ply`` (208k vertices, the paper-scale
speed scan of ``benchmarks/bench_hdr.py``); both are only read. The lights are
the preset's (``build_preset("furnished")``): the ceiling panel as an area light
(the vertices inside its rectangle), the window as an opening, the floor lamp as
a point light and the tube as a line light -- the geometry a user or the light
detection would give; no ground-truth radiance is used.

Tables (markdown):

1. accuracy of E_indirect and of the light fractions vs rays per vertex, against a
   4096-ray reference on 400 random observed vertices (seeded);
2. accuracy of estimating from a vertex subsample (one vertex per voxel and
   normal octant) with more rays each, copied to the others from the nearest
   sampled vertex with a similar normal, against a 2048-ray reference;
3. the line light's error vs its shadow-ray segment count;
4. speed of the hemisphere transfer on every vertex at the default ray count and
   of the point and line light transfers, with rays/s and the load average.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from reroom.hdr.observe import vertex_normals
from reroom.invert import (
    DEFAULT_LINE_SEGMENTS,
    DEFAULT_RAYS_PER_VERTEX,
    CubemapBasis,
    InclinationBasis,
    LineBasis,
    WindowOpening,
    hemisphere_transfer,
    line_light_transfer,
    nearest_receivers,
    point_light_transfer,
    voxel_receivers,
)
from reroom.io.mesh import read_ply
from reroom.rays import RayCaster
from reroom.synth.presets import build_preset

CACHE = Path("/tmp/reroom_hdr_cache")
LUMA = np.array([0.2126, 0.7152, 0.0722])


def load(path: Path):
    mesh = read_ply(path)
    rad = np.asarray(mesh.vertex_attributes["radiance"], dtype=np.float64)
    obs = np.asarray(mesh.vertex_attributes["observed"]).astype(bool)
    return mesh, rad, obs


def preset_lights(mesh) -> tuple[np.ndarray, list[WindowOpening], dict, dict]:
    """Area-light labels, windows, point and line light of the furnished preset."""
    spec = build_preset("furnished")
    lights = {light["name"]: light for light in spec.lights}
    panel = np.asarray(lights["ceiling_panel"]["corners"], dtype=np.float64)
    lo, hi = panel.min(axis=0) - [0.01, 0.01, 0.03], panel.max(axis=0) + [0.01, 0.01, 0.03]
    v = mesh.vertices
    area_of = np.where(np.all((v >= lo) & (v <= hi), axis=1), 0, -1)
    w = lights["window0"]
    windows = [WindowOpening.from_corners("window0", np.asarray(w["corners"]), w["normal"])]
    return area_of, windows, lights["floor_lamp"], lights["tube"]


def _args(mesh, rad, obs, area_of, windows, normals):
    return dict(
        mesh=mesh,
        normals=normals,
        radiance=rad,
        observed=obs,
        area_light_of_vertex=area_of,
        windows=windows,
    )


def accuracy_table(caster, mesh, rad, obs, area_of, windows, normals, n_test=400) -> None:
    rng = np.random.default_rng(0)
    ok = obs & (np.linalg.norm(normals, axis=1) > 0) & (area_of < 0)
    test = np.sort(rng.choice(np.flatnonzero(ok), n_test, replace=False))
    kw = _args(mesh, rad, obs, area_of, windows, normals)
    basis = CubemapBasis(4)
    ref = hemisphere_transfer(
        caster, vertices=test, distant_basis=basis, rays_per_vertex=4096, seed=99, **kw
    )
    e_ref = ref.indirect_rescaled() @ LUMA
    print("\n### E_indirect and light fractions vs rays per vertex (vs 4096 rays)\n")
    print(f"{len(test)} random observed vertices; errors relative to each vertex's reference.\n")
    print(
        "| rays | median rel. err E | p90 rel. err E | RMS abs err p_light | RMS abs err area | seconds |"
    )
    print("|---:|---:|---:|---:|---:|---:|")
    for rays in (16, 32, 64, 128, 256, 512, 1024):
        t0 = time.perf_counter()
        tr = hemisphere_transfer(
            caster, vertices=test, distant_basis=basis, rays_per_vertex=rays, seed=1, **kw
        )
        dt = time.perf_counter() - t0
        rel = np.abs(tr.indirect_rescaled() @ LUMA - e_ref) / np.maximum(e_ref, 1e-12)
        pl = np.sqrt(np.mean((tr.p_light - ref.p_light) ** 2))
        ar = np.sqrt(np.mean((tr.area - ref.area) ** 2))
        print(
            f"| {rays} | {np.median(rel):.2%} | {np.percentile(rel, 90):.2%} | {pl:.4f} | "
            f"{ar:.4f} | {dt:.2f} |"
        )


SMALL_CONFIGS = ((0.0, 64), (0.0, 128), (0.0, 256), (0.05, 256), (0.1, 512), (0.2, 1024))
LARGE_CONFIGS = ((0.0, 128), (0.05, 128), (0.05, 512), (0.1, 512), (0.1, 1024))


def subsample_table(caster, mesh, rad, obs, area_of, windows, normals, configs) -> None:
    """Estimate on a voxel-grid subsample, copy to every vertex from its nearest sample."""
    ok = np.flatnonzero(np.linalg.norm(normals, axis=1) > 0)
    rng = np.random.default_rng(2)
    test = np.sort(rng.choice(ok[obs[ok] & (area_of[ok] < 0)], 2000, replace=False))
    kw = _args(mesh, rad, obs, area_of, windows, normals)
    ref = hemisphere_transfer(
        caster, vertices=test, distant_basis=None, rays_per_vertex=2048, seed=3, **kw
    )
    e_ref = ref.indirect_rescaled() @ LUMA
    print("\n### Subsampled receivers, copied to the nearest sample with a similar normal\n")
    print("Error of E_indirect at 2000 random observed vertices vs a 2048-ray reference there.\n")
    print("| voxel (m) | receivers | share | rays | rays in all | median rel. err | p90 rel. err |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    v = mesh.vertices
    for voxel, rays in configs:
        sub = ok if voxel == 0 else voxel_receivers(v, normals, ok, voxel)
        tr = hemisphere_transfer(
            caster, vertices=sub, distant_basis=None, rays_per_vertex=rays, seed=4, **kw
        )
        e_sub = tr.indirect_rescaled() @ LUMA
        # Nearest sample among those with a similar normal (dot > 0.7), else the nearest.
        pick = nearest_receivers(v, normals, sub, test)
        rel = np.abs(e_sub[pick] - e_ref) / np.maximum(e_ref, 1e-12)
        print(
            f"| {voxel or 'all'} | {len(sub)} | {len(sub) / len(ok):.1%} | {rays} | "
            f"{len(sub) * rays / 1e6:.1f} M | {np.median(rel):.2%} | {np.percentile(rel, 90):.2%} |"
        )


def speed_rows(name, caster, mesh, rad, obs, area_of, windows, normals, lamp, tube) -> list[str]:
    ok = np.flatnonzero(np.linalg.norm(normals, axis=1) > 0)
    kw = _args(mesh, rad, obs, area_of, windows, normals)
    rows = []
    rays = DEFAULT_RAYS_PER_VERTEX
    load0 = os.getloadavg()[0]
    c0, t0 = time.process_time(), time.perf_counter()
    hemisphere_transfer(
        caster, vertices=ok, distant_basis=CubemapBasis(4), rays_per_vertex=rays, **kw
    )
    dt, cpu = time.perf_counter() - t0, time.process_time() - c0
    n = len(ok) * rays
    rows.append(
        f"| {name} | hemisphere, {rays} rays/vertex | {len(ok)} | {n / 1e6:.1f} M | {dt:.2f} | "
        f"{cpu:.2f} | {n / dt / 1e6:.2f} M | {load0:.1f} / {os.getloadavg()[0]:.1f} |"
    )
    p, nrm = mesh.vertices[ok], normals[ok]
    basis = InclinationBasis(32)
    load0 = os.getloadavg()[0]
    c0, t0 = time.process_time(), time.perf_counter()
    f = point_light_transfer(caster, p, nrm, lamp["position"], lamp["up"], basis)
    dt, cpu = time.perf_counter() - t0, time.process_time() - c0
    n = int((f.sum(axis=1) > 0).sum())
    rows.append(
        f"| {name} | point light (shadow rays) | {len(ok)} | {len(ok) / 1e6:.2f} M (max) | "
        f"{dt:.2f} | {cpu:.2f} | {len(ok) / dt / 1e6:.2f} M | "
        f"{load0:.1f} / {os.getloadavg()[0]:.1f} |"
    )
    print(f"{name}: point light reaches {n / len(ok):.1%} of the vertices")
    assert f.shape == (len(ok), 32)
    load0 = os.getloadavg()[0]
    c0, t0 = time.process_time(), time.perf_counter()
    g = line_light_transfer(caster, p, nrm, tube["p0"], tube["p1"], [0, 0, 1], basis)
    dt, cpu = time.perf_counter() - t0, time.process_time() - c0
    print(f"{name}: line light reaches {(g.sum(axis=1) > 0).mean():.1%} of the vertices")
    n = len(ok) * DEFAULT_LINE_SEGMENTS
    rows.append(
        f"| {name} | line light, {DEFAULT_LINE_SEGMENTS} segments | {len(ok)} | {n / 1e6:.1f} M (max) | "
        f"{dt:.2f} | {cpu:.2f} | {n / dt / 1e6:.2f} M | {load0:.1f} / {os.getloadavg()[0]:.1f} |"
    )
    # The same shadow rays, each piece also split at the phi bin edges (LineBasis).
    line2d = LineBasis(32, 3)
    load0 = os.getloadavg()[0]
    c0, t0 = time.process_time(), time.perf_counter()
    g2 = line_light_transfer(caster, p, nrm, tube["p0"], tube["p1"], [0, 0, 1], line2d)
    dt, cpu = time.perf_counter() - t0, time.process_time() - c0
    assert np.allclose(g2.reshape(len(ok), 32, 3).sum(axis=2), g, rtol=1e-9, atol=0)
    rows.append(
        f"| {name} | line light, {DEFAULT_LINE_SEGMENTS} segments, 32 x 3 (theta, phi) bins | "
        f"{len(ok)} | {n / 1e6:.1f} M (max) | {dt:.2f} | {cpu:.2f} | {n / dt / 1e6:.2f} M | "
        f"{load0:.1f} / {os.getloadavg()[0]:.1f} |"
    )
    return rows


def segments_table(caster, mesh, normals, tube) -> None:
    rng = np.random.default_rng(5)
    ok = np.flatnonzero(np.linalg.norm(normals, axis=1) > 0)
    test = np.sort(rng.choice(ok, 3000, replace=False))
    p, n = mesh.vertices[test], normals[test]
    basis = InclinationBasis(32)
    ref = line_light_transfer(caster, p, n, tube["p0"], tube["p1"], [0, 0, 1], basis, 1024).sum(1)
    print("\n### Line light: error vs shadow-ray segments (vs 1024 segments)\n")
    print(
        "Exact per-segment integrals; errors relative to the largest value among 3000 "
        "vertices, and to each lit vertex's own value (lit: above 0.1 % of the largest).\n"
    )
    print(
        "| segments | max err | mean err | lit vertices off by > 1 % | p99 rel. err | max rel. err |"
    )
    print("|---:|---:|---:|---:|---:|---:|")
    lit = ref > 1e-3 * ref.max()
    for s in (4, 8, 16, 32, 64, 128):
        f = line_light_transfer(caster, p, n, tube["p0"], tube["p1"], [0, 0, 1], basis, s).sum(1)
        err = np.abs(f - ref)
        rel = err[lit] / ref[lit]
        print(
            f"| {s} | {err.max() / ref.max():.2%} | {err.mean() / ref.max():.4%} | "
            f"{np.mean(rel > 0.01):.2%} | {np.percentile(rel, 99):.2%} | {rel.max():.1%} |"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--small", type=Path, default=CACHE / "hdr_furnished" / "hdr_mesh.ply")
    ap.add_argument("--large", type=Path, default=CACHE / "hdr_speed" / "hdr_mesh.ply")
    ap.add_argument("--skip-accuracy", action="store_true")
    ap.add_argument(
        "--subsample-large", action="store_true", help="also measure subsampling on the large scan"
    )
    args = ap.parse_args()
    print(f"cpus: {os.cpu_count()}, load average at start: {os.getloadavg()}")

    speed = []
    for name, path in (("furnished", args.small), ("speed (paper scale)", args.large)):
        if not path.is_file():
            print(f"skipping {name}: {path} is missing")
            continue
        mesh, rad, obs = load(path)
        normals = vertex_normals(mesh)
        caster = RayCaster(mesh)
        area_of, windows, lamp, tube = preset_lights(mesh)
        print(
            f"\n## {name}: {path} ({len(mesh.vertices)} vertices, {len(mesh.faces)} faces, "
            f"{obs.mean():.1%} observed, {int((area_of == 0).sum())} area-light vertices)"
        )
        if not args.skip_accuracy and name == "furnished":
            accuracy_table(caster, mesh, rad, obs, area_of, windows, normals)
            subsample_table(caster, mesh, rad, obs, area_of, windows, normals, SMALL_CONFIGS)
            segments_table(caster, mesh, normals, tube)
        if args.subsample_large and name != "furnished":
            subsample_table(caster, mesh, rad, obs, area_of, windows, normals, LARGE_CONFIGS)
        speed += speed_rows(name, caster, mesh, rad, obs, area_of, windows, normals, lamp, tube)

    print("\n### Speed (2 cores; load average 1 min before / after)\n")
    print("| scan | transfer | vertices | rays | seconds | CPU s | rays/s | load |")
    print("|---|---|---:|---:|---:|---:|---:|---|")
    print("\n".join(speed))


if __name__ == "__main__":
    main()
