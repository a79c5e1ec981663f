"""How accurate and how fast is ``reroom layout`` (floorplan and features, thesis ch. 4)?

Parts, each printing a markdown table:

``--accuracy``
    Fused (scanner-like, TSDF from noisy depth) scans of the ``box``, ``furnished``,
    ``lshape`` and ``tworooms`` presets from ``generate_scan`` (cached under ``--cache``,
    default ``/tmp/reroom_layout_cache``), run through :func:`reroom.layout.run_layout`
    and scored by :mod:`reroom.layout.evaluate`. Targets: floorplan IoU >= 0.95, walls
    within 3 cm, floor/ceiling within 2 cm, label accuracy >= 95 % on wall/floor/ceiling
    vertices, every door, window and passage found with no false ones.
``--methods``
    The floorplan choices on the same scans, structure only: the thesis's minimum-cost
    cycle (alpha 1 and 0.5) against our room regions, each with the thesis's
    empty-behind test and with the thin-wall one; and the label tolerance (r vs 2r).
``--speed``
    The paper's floorplan step took ~5 s; ours including the features must stay under
    5 s for a ~200k-vertex mesh and 300 frames on 2 cores. The scan: the furnished
    room's geometry fused from depth maps at 2.8 cm voxels (about 200k vertices) (the generator's own
    scanner model, no path tracing), and its 300 frames reusing the path-traced images
    and poses of the 72-frame accuracy scan cyclically (the layout reads 40 of them).
``--slambook2``
    The real slambook2 RGB-D frames (a partial room), imported with
    :func:`reroom.importers.import_rgbd_folder`: what the layout finds.
``--scans NAME=DIR ...``
    Any scan folders (e.g. the 24-frame 160x120 scans of few, small frames; their
    ``hdr/hdr_mesh.ply`` is used as the bright-window cue when present, as ``reroom
    layout`` does): every opening found (kind, room, wall, extent, the room it opens
    ``into``) and, where the scan has a ground truth, the doors, windows, passages and
    baseboard pieces matched against it.

Usage (niced; the machine is shared)::

    nice -n 10 python benchmarks/bench_layout.py --accuracy --methods
    nice -n 10 python benchmarks/bench_layout.py --speed --slambook2
    python benchmarks/bench_layout.py --scans demo=/tmp/demo tworooms24=/tmp/tw
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import time
from pathlib import Path

import numpy as np

CACHE = Path("/tmp/reroom_layout_cache")
OUT = Path("/tmp/reroom_layout_bench")
PRESETS = {
    # frames, width, height, spp: enough frames for the fused mesh to cover every wall.
    "box": (60, 320, 240, 16),
    "furnished": (72, 320, 240, 16),
    "lshape": (72, 320, 240, 16),
    "tworooms": (96, 320, 240, 16),
}
PAPER_FLOORPLAN_S = 5.0


def _load() -> str:
    try:
        return " ".join(f"{x:.1f}" for x in os.getloadavg())
    except OSError:
        return "?"


def scan_path(preset: str, cache: Path, mesh: str = "fused") -> Path:
    """The cached scan of a preset (``mesh`` fused or clean), generated on first use."""
    from reroom.synth.generate import SynthOptions, generate_scan

    frames, w, h, spp = PRESETS[preset]
    out = cache / f"{preset}_{mesh}_{frames}_{w}x{h}_{spp}"
    if not (out / "transforms.json").exists():
        print(f"generating {out} ...", flush=True)
        opts = SynthOptions(frames=frames, width=w, height=h, spp=spp, vertex_spp=1, mesh=mesh)
        generate_scan(preset, out, opts, overwrite=True)
    return out


# --------------------------------------------------------------------------- accuracy


def accuracy(cache: Path, mesh: str = "fused") -> list[dict]:
    from reroom.layout import run_layout
    from reroom.layout.evaluate import evaluate_scan

    rows = []
    for preset in PRESETS:
        scan = scan_path(preset, cache, mesh)
        out = OUT / f"{preset}_{mesh}"
        t = time.perf_counter()
        res = run_layout(scan, out)
        wall = time.perf_counter() - t
        ev = evaluate_scan(out / "layout.json", scan, out / "layout_labels.ply")
        ev["preset"] = preset
        ev["seconds"] = wall
        ev["timings"] = res.timings
        ev["vertices"] = len(res.labels)
        rows.append(ev)
    print(f"\n### Accuracy ({mesh} meshes; load {_load()})\n")
    print(
        "| preset | vertices | rooms | IoU | walls (cm) mean / max | floor / ceiling (cm) "
        "| labels wall/floor/ceiling | doors | windows | passages | baseboard (height err) "
        "| time (s) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for e in rows:
        f = e["features"]

        def pr(k: str, f=f) -> str:
            x = f[k]
            edges = f", edges {x['edge_error_cm']:.1f} cm" if "edge_error_cm" in x else ""
            return f"{x['matched']}/{x['true']} found, {x['found'] - x['matched']} false{edges}"

        bb = f["baseboard"]
        print(
            f"| {e['preset']} | {e['vertices']} | {e['rooms_found']}/{e['rooms_true']} "
            f"| {e['iou']:.3f} | {e['wall_error_cm']['mean']:.2f} / {e['wall_error_cm']['max']:.2f} "
            f"| {e['floor_error_cm']:.2f} / {e['ceiling_error_cm']:.2f} "
            f"| {100 * e['label_accuracy']:.1f} % "
            f"| {pr('door')} | {pr('window')} | {pr('passage')} "
            f"| {bb['matched']}/{bb['true']} pieces ({bb.get('height_error_cm', float('nan')):.1f} cm) "
            f"| {e['seconds']:.1f} |"
        )
    return rows


def scans(named: list[str]) -> None:
    """The openings of the named scan folders (``NAME=DIR``), against their truth."""
    from reroom.layout import LayoutOptions, run_layout
    from reroom.layout.evaluate import evaluate_scan

    print(f"\n### Openings of the given scans (load {_load()})\n")
    print(
        "| scan | doors | windows | passages | baseboard pieces | openings (room wall kind: s0-s1 x z0-z1 m, into) |"
    )
    print("|---|---|---|---|---|---|")
    for item in named:
        name, _, folder = item.partition("=")
        scan = Path(folder)
        hdr = scan / "hdr" / "hdr_mesh.ply"
        out = OUT / f"scans_{name}"
        run_layout(scan, out, LayoutOptions(radiance=hdr if hdr.is_file() else None))
        doc = json.loads((out / "layout.json").read_text())
        ops = "; ".join(
            f"{r['name']} {o['wall']} {o['kind']}: {o['s0']:.2f}-{o['s1']:.2f} x "
            f"{o['z0']:.2f}-{o['z1']:.2f}" + (f", into {o['into']}" if "into" in o else "")
            for r in doc["rooms"]
            for o in r["openings"]
        )
        cells = ["-"] * 4
        if (scan / "ground_truth").is_dir():
            f = evaluate_scan(out / "layout.json", scan, out / "layout_labels.ply")["features"]
            cells = [
                f"{f[k]['matched']}/{f[k]['true']} ({f[k]['found']} found"
                + (f"; edges {f[k]['edge_error_cm']:.1f} cm" if "edge_error_cm" in f[k] else "")
                + ")"
                for k in ("door", "window", "passage", "baseboard")
            ]
        print(f"| {name} | {' | '.join(cells)} | {ops or 'none'} |")


# --------------------------------------------------------------------------- methods


def methods(cache: Path) -> None:
    from reroom.layout import LayoutOptions, StructureOptions, layout_scan
    from reroom.layout.evaluate import evaluate_layout
    from reroom.scan import load_scan

    variants = {
        "cycle, alpha 1, thesis behind-test": StructureOptions(floorplan="cycle", thin_walls=False),
        "cycle, alpha 1": StructureOptions(floorplan="cycle"),
        "cycle, alpha 0.5": StructureOptions(floorplan="cycle", alpha=0.5),
        "regions, thesis behind-test": StructureOptions(thin_walls=False),
        "regions (default)": StructureOptions(),
    }
    print(f"\n### Floorplan methods (structure only; load {_load()})\n")
    coarse = "tworooms, clean 10 cm mesh"
    print("| method | " + " | ".join([*PRESETS, coarse]) + " |")
    print("|---|" + "---|" * (len(PRESETS) + 1))
    scans = {p: load_scan(scan_path(p, cache)) for p in PRESETS}
    truths = {
        p: json.loads((s.root / "ground_truth" / "ground_truth.json").read_text())["layout"]
        for p, s in scans.items()
    }
    # A coarse mesh (r = 9 cm, so 2r exceeds the 15 cm wall between the rooms): the
    # generator's own geometry at 10 cm spacing, without rendering.
    scans[coarse] = _clean_preset_scan("tworooms", 0.1)
    truths[coarse] = truths["tworooms"]
    for name, so in variants.items():
        cells = []
        for p, scan in scans.items():
            try:
                res = layout_scan(scan, LayoutOptions(structure=so, features=False))
                ev = evaluate_layout(res.layout, truths[p])
                cells.append(
                    f"IoU {ev['iou']:.3f}, {ev['rooms_found']} room(s), "
                    f"walls {ev['wall_error_cm']['max']:.1f} cm"
                    + (f", {ev['walls_missed']} missed" if ev["walls_missed"] else "")
                )
            except Exception as exc:  # noqa: BLE001 - a failed variant is a table entry
                cells.append(f"failed: {str(exc)[:60]}")
        print(f"| {name} | " + " | ".join(cells) + " |")

    from reroom.io.mesh import read_ply

    print(f"\n### Label rules (on wall/floor/ceiling vertices, before features; load {_load()})\n")
    print("| label tolerance | " + " | ".join(PRESETS) + " |")
    print("|---|" + "---|" * len(PRESETS))
    true_labels = {
        p: np.asarray(read_ply(s.root / "ground_truth" / "vertices.ply").vertex_attributes["label"])
        for p, s in scans.items()
        if p != coarse
    }
    for name, kw in {
        "r (thesis), 35°": {"label_tol_scale": 1.0},
        "2r, 35° (default)": {"label_tol_scale": 2.0},
        "3r, 35°": {"label_tol_scale": 3.0},
        "2r, 25°": {"label_tol_scale": 2.0, "label_angle_deg": 25.0},
        "2r, 35°, no closing": {"label_tol_scale": 2.0, "close_steps": 0},
    }.items():
        cells = []
        for p, scan in scans.items():
            if p == coarse:
                continue
            st = layout_scan(scan, LayoutOptions(features=False)).structure
            opt = LayoutOptions(
                features=False,
                label_tol=kw["label_tol_scale"] * st.r,
                label_angle_deg=kw.get("label_angle_deg", 35.0),
                close_steps=kw.get("close_steps", 2),
            )
            res = layout_scan(scan, opt)
            ev = evaluate_layout(res.layout, truths[p], res.labels, true_labels[p])
            cells.append(f"{100 * ev['label_accuracy']:.1f} %")
        print(f"| {name} | " + " | ".join(cells) + " |")


def _clean_preset_scan(preset: str, spacing: float):
    """An in-memory scan (no frames) of a preset's clean geometry, welded."""
    import trimesh

    from reroom.scan import Scan
    from reroom.synth.geometry import Piece
    from reroom.synth.presets import build_preset

    spec = build_preset(preset, mesh_spacing=spacing)
    pc = Piece.concat([p.piece for p in spec.parts if p.in_scan])
    mesh = trimesh.Trimesh(pc.vertices, pc.faces, process=False)
    mesh.merge_vertices()
    return Scan(Path("."), [], mesh, Path("mesh.ply"), {})


# --------------------------------------------------------------------------- speed


def make_speed_scan(cache: Path, n_frames: int = 300, voxel: float = 0.028) -> Path:
    """The speed scan (see the module notes), built once and cached."""
    import trimesh

    from reroom.rays import RayCaster
    from reroom.scan import load_scan, write_scan
    from reroom.synth.groundtruth import clean_surface
    from reroom.synth.scanner import fuse_depth_maps, kinect_noise, render_depth

    out = cache / f"speed_furnished_{n_frames}f_v{voxel:.3f}"
    if (out / "transforms.json").exists():
        return out
    src = load_scan(scan_path("furnished", cache))
    scene_dir = src.root / "ground_truth" / "scene"
    desc = json.loads((scene_dir / "scene.json").read_text())
    clean = clean_surface(desc, scene_dir)
    caster = RayCaster(clean.vertices, clean.faces)
    rng = np.random.default_rng(0)
    frames = [src.frames[i % len(src.frames)] for i in range(n_frames)]
    intr = frames[0].intrinsics
    # Depth from the 72 distinct poses (repeating them adds nothing to the fusion).
    depths = [kinect_noise(render_depth(caster, fr), rng) for fr in src.frames]
    mesh = fuse_depth_maps(depths, src.frames, intr, voxel_size=voxel)
    mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    out.mkdir(parents=True, exist_ok=True)
    images = []
    for i, fr in enumerate(frames):
        link = out / "images" / f"frame_{i:05d}.png"
        link.parent.mkdir(exist_ok=True)
        if not link.exists():
            try:  # a hard link keeps the file inside the scan folder, as write_scan wants
                os.link(fr.image_path, link)
            except OSError:
                shutil.copyfile(fr.image_path, link)
        images.append(link)
    write_scan(out, mesh, intr, [fr.c2w for fr in frames], images, meta=src.meta)
    return out


def speed(cache: Path, repeats: int = 3) -> None:
    from reroom.layout import LayoutOptions, layout_scan
    from reroom.rays import RayCaster
    from reroom.scan import load_scan

    path = make_speed_scan(cache)
    t = time.perf_counter()
    scan = load_scan(path)
    t_load = time.perf_counter() - t
    RayCaster(scan.mesh)  # warm-up: first Embree use loads the library
    best = None
    for _ in range(repeats):
        c0 = time.process_time()
        t = time.perf_counter()
        res = layout_scan(scan, LayoutOptions())
        wall = time.perf_counter() - t
        cpu = time.process_time() - c0
        if best is None or wall < best[0]:
            best = (wall, cpu, res.timings, res.cpu_timings)
    wall, cpu, tim, tcpu = best
    print(
        f"\n### Speed ({len(scan.mesh.vertices)} vertices, {len(scan.frames)} frames; "
        f"load {_load()})\n"
    )
    print("| step | wall clock (s) | CPU (s, all threads) |")
    print("|---|---|---|")
    print(f"| load the scan (PLY + 300 image headers; not part of the step) | {t_load:.2f} | |")
    for k, v in tim.items():
        print(f"| {k} | {v:.2f} | {tcpu.get(k, float('nan')):.2f} |")
    print(f"| **layout, total (best of {repeats})** | **{wall:.2f}** | **{cpu:.2f}** |")
    print(
        f"| ratio to the paper's ~5 s floorplan step | {wall / PAPER_FLOORPLAN_S:.2f} "
        f"| {cpu / PAPER_FLOORPLAN_S:.2f} |"
    )


# --------------------------------------------------------------------------- slambook2


def slambook2(cache: Path) -> None:
    from reroom.importers import import_rgbd_folder
    from reroom.layout import LayoutError, run_layout

    src = Path("/work/shared/data/real/slambook2_rgbd")
    scan = cache / "slambook2"
    if not (scan / "transforms.json").exists():
        import_rgbd_folder(src, scan)
    print("\n### slambook2 (real, partial room)\n")
    try:
        res = run_layout(scan, OUT / "slambook2")
        print(json.dumps({k: res.layout[k] for k in ("floor_z", "ceiling_z", "rooms")}, indent=1))
    except LayoutError as err:
        print(f"LayoutError: {err}")
        from reroom.io.mesh import read_ply

        lab = np.asarray(
            read_ply(OUT / "slambook2" / "layout_labels.ply").vertex_attributes["label"]
        )
        print(
            "labels written:",
            {int(k): int(v) for k, v in zip(*np.unique(lab, return_counts=True), strict=True)},
        )


# --------------------------------------------------------------------------- figures


def figures(cache: Path, out_dir: Path) -> None:
    """The pictures in docs/layout.md, from the accuracy runs (run ``--accuracy`` first)."""
    import shutil as sh

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import trimesh

    from reroom.importers.preview import render_mesh_preview
    from reroom.layout import layout_scan
    from reroom.layout.emptyroom import empty_room_mesh
    from reroom.scan import Intrinsics, load_scan, look_at

    out_dir.mkdir(parents=True, exist_ok=True)
    for preset in PRESETS:
        src = OUT / preset / "floorplan.png"
        if src.exists():
            sh.copyfile(src, out_dir / f"layout_floorplan_{preset}.png")
    # The empty room of the furnished scan, seen from where a frame was taken.
    doc = json.loads((OUT / "furnished" / "layout.json").read_text())
    mesh, lab = empty_room_mesh(doc)
    colours = {
        0: (200, 190, 170),
        1: (140, 100, 60),
        2: (235, 235, 235),
        3: (80, 120, 200),
        4: (120, 200, 255),
        5: (255, 255, 255),
        254: (255, 150, 0),
    }
    v = mesh.vertices[mesh.faces.reshape(-1)]
    fc = np.array([colours.get(int(x), (255, 0, 0)) for x in lab], np.uint8)
    vc = np.column_stack([np.repeat(fc, 3, axis=0), np.full(len(v), 255, np.uint8)])
    flat = trimesh.Trimesh(v, np.arange(len(v)).reshape(-1, 3), vertex_colors=vc, process=False)
    intr = Intrinsics.from_fov(480, 360, 75.0)
    for name, eye, target in (
        ("door", [3.0, 0.5, 1.7], [1.5, 4.5, 1.0]),
        ("window", [3.0, 4.0, 1.7], [4.5, 0.0, 1.2]),
    ):
        render_mesh_preview(
            flat,
            look_at(np.array(eye), np.array(target)),
            intr,
            out_dir / f"layout_empty_room_{name}.png",
            spp=4,
        )
    # The evidence on the furnished room's door wall.
    scan = load_scan(scan_path("furnished", cache))
    res = layout_scan(scan)
    g = res.grids
    k = next(
        i
        for i, o in enumerate(res.layout["rooms"][0]["walls"])
        if any(
            op["kind"] == "door" and op["wall"] == i for op in res.layout["rooms"][0]["openings"]
        )
    )
    n = g.n[k]
    ev = np.divide(g.fv[k], n, out=np.full_like(n, np.nan), where=n > 0)
    eh = np.divide(g.fh[k], n, out=np.full_like(n, np.nan), where=n > 0)
    tot = g.surface[k] + g.shallow[k] + g.deep[k] + g.through[k]
    sh_frac = np.divide(g.shallow[k], tot, out=np.full_like(tot, np.nan), where=tot > 0)
    ext = (0, n.shape[0] * g.cell, 0, n.shape[1] * g.cell)
    fig, axs = plt.subplots(1, 3, figsize=(15, 3.2))
    for ax, img, title in zip(
        axs,
        (ev, eh, sh_frac),
        ("vertical edges F_v / N", "horizontal edges F_h / N", "rays ending 1.5-6 cm behind"),
        strict=True,
    ):
        ax.imshow(
            img.T, origin="lower", extent=ext, aspect="equal", vmax=np.nanpercentile(img, 99.5)
        )
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("s along the wall (m)")
    axs[0].set_ylabel("height (m)")
    fig.tight_layout()
    fig.savefig(out_dir / "layout_wall_evidence.png", dpi=80)
    plt.close(fig)
    print("figures written to", out_dir)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--accuracy", action="store_true")
    ap.add_argument("--methods", action="store_true")
    ap.add_argument("--speed", action="store_true")
    ap.add_argument("--slambook2", action="store_true")
    ap.add_argument("--figures", type=Path, default=None, help="write the docs pictures here")
    ap.add_argument("--cache", type=Path, default=CACHE)
    ap.add_argument("--mesh", default="fused", choices=("fused", "clean"), help="for --accuracy")
    ap.add_argument("--scans", nargs="+", default=[], metavar="NAME=DIR")
    args = ap.parse_args()
    parts = (args.accuracy, args.methods, args.speed, args.slambook2, args.figures, args.scans)
    if not any(parts):
        args.accuracy = True
    if args.scans:
        scans(args.scans)
    if args.accuracy:
        accuracy(args.cache, args.mesh)
    if args.methods:
        methods(args.cache)
    if args.speed:
        speed(args.cache)
    if args.slambook2:
        slambook2(args.cache)
    if args.figures:
        figures(args.cache, args.figures)


if __name__ == "__main__":
    main()
