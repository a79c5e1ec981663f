"""Where the HDR mesh's radiance departs from the true vertex radiance, and in which channel.

Usage::

    python benchmarks/bench_hdr_bias.py SCAN [--truth PLY] [--bin-by PLY]
        [--scales true|solved] [--sampling box3,nearest] [--footprint on,off]
        [--render-frames 5,15 [--render-spp 256] [--clip-spp 16,64,256]]

``SCAN`` is a synthetic scan with ``ground_truth/`` and ``hdr/``. Its frames are
reprojected again here (``collect_observations`` and ``reproject_radiance`` with the
pipeline's defaults, or the ``--sampling`` named, and with the footprint test of edge
samples on, off or both, ``--footprint on,off``), with the frames' *true* scales
(``--scales true``, the default: the reprojection alone) or the ones ``reroom hdr``
solved (``solved``: divided by their per-channel median ratio to the true ones, so
only the frame-to-frame errors stay). Every figure is a ratio of sums, HDR over truth,
per channel, over the vertices of a band of true luminance; emitters (true label
``light``, the window's portal) are left out.

* ``--truth`` is the radiance to compare with (default ``ground_truth/vertices.ply``);
  ``--bin-by`` the radiance that picks the bands. Binning by the same noisy sample that
  is compared with makes the bands regress to the mean (a vertex lands in the top band
  partly because its sample came out high), so pass an independent truth sample of
  the same mesh (e.g. ``reroom synth`` re-run with another seed) to ``--bin-by``.
* Tables: (1) per band, with the share of clean samples clipped (level 255) per
  channel; (2) bands of the vertices that have clean samples against those seen only
  near image or depth edges (flagged samples), with the truth parts of the latter;
  (3) per surface (true label), and (3b) per part of a light's fitting (a tube's
  baffles, a lamp's shade: their samples a pixel from the clipped emitter); (4)
  within 1.5 m of each point or line light against the rest;
  (5) for vertices with no clipped sample, the mean of their samples against their
  median (Monte-Carlo noise of the path-traced frames is skewed, a sensor's is not);
  (6) with ``--render-frames``, those frames path-traced again at ``--render-spp`` by
  the generator's renderer (linear, no camera): the 8-bit frames over the render
  (unclipped pixels, by band of the render; and per surface, over the pixels the render
  expects under half the white level: what the camera simulation and the frames'
  own Monte-Carlo noise do; and a render at the frames' own sample count clipped at
  the white level against the same unclipped: the light a camera loses where the path
  tracer's noise pushes single pixels past white), and the render's pixel at each
  vertex the frame sees (a clean sample) over the vertex truth, per surface: whether
  the truth's probes (a ray from 3 cm along the normal,
  ``reroom.render.frames.probe_radiance``) see the surface as a camera does;
  (7) with ``--clip-spp 16,64``, renders of those views at each sample count clipped at
  the white level against the same unclipped, on the pixels the reference render
  expects under half white: the light the generator's camera loses to the path
  tracer's noise at that sample count (``reroom synth --spp``);
  (8) with ``--cells ceiling,floor``, maps of each surface over 0.5 m cells of the plan:
  HDR over truth, blue over red, and the truth's own relative standard error in blue.
"""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path

import numpy as np

from reroom.hdr.linearize import LUMA, response_lut
from reroom.hdr.observe import (
    EDGE_FLAGS,
    FOREIGN_FOOTPRINT,
    MIXED_FOOTPRINT,
    ObserveOptions,
    collect_observations,
    decode_linear,
    vertex_normals,
)
from reroom.hdr.reproject import VertexGroups, reproject_radiance
from reroom.io.mesh import read_ply
from reroom.rays import RayCaster
from reroom.rays.geometry import segment_distance
from reroom.scan import load_scan

BANDS = [0.0, 0.02, 0.05, 0.1, 0.2, 0.4, 0.8, np.inf]
LABELS = {0: "wall", 1: "floor", 2: "ceiling", 3: "door", 4: "window", 5: "baseboard"}


def _ratio(est: np.ndarray, tru: np.ndarray, sel: np.ndarray) -> str:
    t = tru[sel].sum(0)
    r = est[sel].sum(0) / np.where(t > 0, t, np.nan)
    return " / ".join(f"{x:.3f}" for x in r)


def _band_rows(est, tru, key, sel, extra=None) -> list[str]:
    rows = []
    for a, b in zip(BANDS[:-1], BANDS[1:], strict=True):
        s = sel & (key >= a) & (key < b)
        if s.sum() < 3:
            continue
        cells = [f"{a:g}-{b:g}", str(int(s.sum())), _ratio(est, tru, s)]
        if extra is not None:
            cells.append(extra(s))
        rows.append("| " + " | ".join(cells) + " |")
    return rows


def _distance_to_light(pos: np.ndarray, light: dict) -> np.ndarray:
    """Metres from each point to a true point light, or to a line light's segment."""
    if light["type"] == "point":
        return np.linalg.norm(pos - np.asarray(light["position"], float), axis=1)
    return segment_distance(pos, light["p0"], light["p1"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("scan", type=Path)
    ap.add_argument("--truth", type=Path, help="true vertex radiance PLY to compare with")
    ap.add_argument("--bin-by", type=Path, help="independent true radiance PLY for the bands")
    ap.add_argument("--scales", choices=("true", "solved"), default="true")
    ap.add_argument("--sampling", default="box3", help="comma-separated ObserveOptions.sampling")
    ap.add_argument(
        "--footprint",
        default="on",
        help="comma-separated on/off: ObserveOptions.footprint_test (on,off: both, side by side)",
    )
    ap.add_argument("--render-frames", default="", help="comma-separated frame indices for (6)")
    ap.add_argument("--render-spp", type=int, default=256)
    ap.add_argument(
        "--cells",
        default="",
        help="comma-separated surfaces (e.g. ceiling,floor) for (8): maps over 0.5 m cells",
    )
    ap.add_argument(
        "--clip-spp",
        default="",
        help="comma-separated sample counts for (7): renders clipped at white against unclipped",
    )
    args = ap.parse_args()

    scan_dir = args.scan
    gt_dir = scan_dir / "ground_truth"
    verts = read_ply(gt_dir / "vertices.ply")
    tru = np.asarray(read_ply(args.truth or gt_dir / "vertices.ply").vertex_attributes["radiance"])
    tru = tru.astype(float)
    key = (
        tru
        if args.bin_by is None
        else np.asarray(read_ply(args.bin_by).vertex_attributes["radiance"])
    )
    key = np.asarray(key, float) @ LUMA
    label = np.asarray(verts.vertex_attributes["label"])
    part = np.asarray(verts.vertex_attributes["part"])
    gt = json.loads((gt_dir / "ground_truth.json").read_text())
    scene = json.loads((gt_dir / "scene" / "scene.json").read_text())
    part_names = [p.get("name", str(i)) for i, p in enumerate(scene["parts"])]
    emitter_parts = [i for i, n in enumerate(part_names) if n.endswith("_portal")]
    keep = (label != 7) & ~np.isin(part, emitter_parts)
    t_true = np.array([f["scale"] for f in gt["frames"]], float)
    if args.scales == "true":
        scales = t_true
    else:
        s = np.load(scan_dir / "hdr" / "hdr_extras.npz")["scales"]
        scales = s / np.nanmedian(s / t_true, axis=0)
    wb = np.median([f["white_balance"] for f in gt["frames"]], axis=0)
    print(
        f"`{scan_dir}`: {len(tru)} vertices ({int(keep.sum())} not emitters), "
        f"{len(t_true)} frames at {gt['options']['spp']} spp (median white balance "
        f"{' / '.join(f'{x:.2f}' for x in wb)}), scales: {args.scales}; bands by "
        f"{args.bin_by or 'the compared truth itself (regresses to the mean)'}"
    )

    scan = load_scan(scan_dir)
    lut = response_lut("auto", scan.meta)
    caster = RayCaster(scan.mesh)
    normals = vertex_normals(scan.mesh)
    lights = [x for x in gt["lights"] if x["type"] in ("point", "line")]
    pos = np.asarray(verts.vertices, float)
    runs = [(s, f) for s in args.sampling.split(",") for f in args.footprint.split(",")]
    for sampling, footprint in runs:
        if footprint not in ("on", "off"):
            raise SystemExit(f"--footprint takes on and off, not {footprint!r}")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            obs = collect_observations(
                scan.frames,
                scan.mesh,
                lut,
                ObserveOptions(sampling=sampling, footprint_test=footprint == "on"),
                caster,
                normals=normals,
            )
        rad = reproject_radiance(obs, scales, VertexGroups(obs), level_linear=lut)
        est = rad.radiance
        base = keep & rad.observed
        clean = (obs.flags & EDGE_FLAGS) == 0
        n_clean = np.bincount(obs.vertex[clean], minlength=obs.n_vertices)
        v_clean = obs.vertex[clean]
        clipped = obs.value[clean] == 255

        def clip_share(s: np.ndarray, v_clean=v_clean, clipped=clipped) -> str:
            m = s[v_clean]
            return " / ".join(f"{x:.2f}" for x in clipped[m].mean(0)) if m.any() else "-"

        print(f"\n### sampling `{sampling}`, footprint test {footprint}\n")
        edge = (obs.flags & EDGE_FLAGS) != 0
        print(
            f"{len(obs)} samples, {100 * edge.mean():.1f} % near an edge (footprint-tested), "
            f"{int(np.count_nonzero(obs.flags & MIXED_FOOTPRINT))} partly and "
            f"{int(np.count_nonzero(obs.flags & FOREIGN_FOOTPRINT))} wholly on another surface\n"
        )
        print("(1) per band of true luminance: HDR / truth (r / g / b), clipped clean samples\n")
        print("| band | vertices | HDR / truth | clipped samples |\n|---|---|---|---|")
        print("\n".join(_band_rows(est, tru, key, base, clip_share)))

        print("\n(2) vertices with clean samples, and those seen only near edges\n")
        print("| band | vertices | HDR / truth | which |\n|---|---|---|---|")
        for name, s in (
            ("clean samples", base & (n_clean > 0)),
            ("only near edges", base & (n_clean == 0)),
        ):
            for row in _band_rows(est, tru, key, s & (key >= 0.1)):
                print(row[:-2] + f" | {name} |")
        only = base & (n_clean == 0) & (key >= 0.1)
        names, counts = np.unique(part[only], return_counts=True)
        top = sorted(zip(counts, names, strict=True), reverse=True)[:4]
        print(
            "\nparts of the edge-only vertices above 0.1: "
            + ", ".join(f"{part_names[p]} {c}" for c, p in top)
        )

        print("\n(3) per surface (true label), every band\n")
        print("| surface | vertices | HDR / truth |\n|---|---|---|")
        for k, name in LABELS.items():
            s = base & (label == k)
            if s.sum() >= 3:
                print(f"| {name} | {int(s.sum())} | {_ratio(est, tru, s)} |")

        # (3b) the light fittings' own parts (a tube's baffles, a lamp's shade): thin
        # geometry a pixel from a clipped emitter, whose samples may hold its spill.
        fittings = [
            (i, n)
            for i, n in enumerate(part_names)
            if i not in emitter_parts and any(n.startswith(f"{x['name']}_") for x in gt["lights"])
        ]
        if fittings:
            print("\n(3b) per light-fitting part, every band (clean and edge-only samples)\n")
            print("| part | vertices | seen only near edges | HDR / truth |\n|---|---|---|---|")
            for i, n in fittings:
                s = base & (part == i)
                if s.sum() >= 3:
                    edge_only = int((s & (n_clean == 0)).sum())
                    print(f"| {n} | {int(s.sum())} | {edge_only} | {_ratio(est, tru, s)} |")

        if lights:
            print(
                "\n(4) within 1.5 m of each point light (of a line light's segment), and the rest\n"
            )
            print("| band | vertices | HDR / truth | where |\n|---|---|---|---|")
            near_any = np.zeros(len(pos), bool)
            for light in lights:
                near = _distance_to_light(pos, light) < 1.5
                near_any |= near
                for row in _band_rows(est, tru, key, base & near & (n_clean > 0)):
                    print(row[:-2] + f" | near {light['name']} |")
            for row in _band_rows(est, tru, key, base & ~near_any & (n_clean > 0)):
                print(row[:-2] + " | elsewhere |")

        # (5) the median's bias under skewed noise: unclipped vertices, mean vs median.
        x = decode_linear(obs.linear[clean]) / scales[obs.frame[clean]]
        any_clip = np.bincount(v_clean[clipped.any(1)], minlength=obs.n_vertices) > 0
        order = np.argsort(v_clean, kind="stable")
        vs, xs = v_clean[order], x[order]
        bounds = np.searchsorted(vs, np.arange(obs.n_vertices + 1))
        cnt = np.diff(bounds)
        mean = (
            np.stack([np.bincount(vs, xs[:, c], minlength=obs.n_vertices) for c in range(3)], 1)
            / np.maximum(cnt, 1)[:, None]
        )
        med = np.zeros_like(mean)
        for i in np.flatnonzero(cnt >= 3):
            med[i] = np.median(xs[bounds[i] : bounds[i + 1]], axis=0)
        s5 = base & ~any_clip & (cnt >= 3)
        print(
            "\n(5) vertices with 3+ clean samples and none clipped: plain mean and median of the samples\n"
        )
        print("| band | vertices | mean / truth | median / truth |\n|---|---|---|---|")
        for a, b in zip(BANDS[:-1], BANDS[1:], strict=True):
            s = s5 & (key >= a) & (key < b)
            if s.sum() >= 3:
                print(
                    f"| {a:g}-{b:g} | {int(s.sum())} | {_ratio(mean, tru, s)} | {_ratio(med, tru, s)} |"
                )

        if args.cells:
            err = np.asarray(verts.vertex_attributes["radiance_stderr"], float)
            cell_maps(est, tru, err, pos, label, base, args.cells.split(","))

    if args.render_frames:
        render_check(scan, scan_dir, obs, lut, t_true, tru, est, label, args)
    if args.render_frames and args.clip_spp:
        clip_check(scan, scan_dir, t_true, args)


def cell_maps(est, tru, err, pos, label, base, surfaces: list[str], cell: float = 0.5) -> None:
    """(8) Per ``cell`` x ``cell`` m of each surface's plan (rows from high y down, columns
    from low x): HDR over truth, blue over red, as ratios of sums; and the truth's mean
    relative standard error in blue (where the truth itself is noisy, e.g. light that
    arrives by rare paths)."""
    names = {v: k for k, v in LABELS.items()}
    lo = pos[:, :2].min(axis=0)
    ij = np.floor((pos[:, :2] - lo) / cell).astype(int)
    shape = tuple(ij.max(axis=0) + 1)
    for surface in surfaces:
        sel = base & (label == names[surface])
        e_sum = np.zeros((*shape, 3))
        t_sum = np.zeros((*shape, 3))
        rel = np.zeros(shape)
        n = np.zeros(shape)
        i, j = ij[sel, 0], ij[sel, 1]
        np.add.at(e_sum, (i, j), est[sel])
        np.add.at(t_sum, (i, j), tru[sel])
        np.add.at(rel, (i, j), err[sel, 2] / np.maximum(tru[sel, 2], 1e-9))
        np.add.at(n, (i, j), 1)
        with np.errstate(divide="ignore", invalid="ignore"):
            r = e_sum / t_sum
            tilt = r[..., 2] / r[..., 0]
        print(
            f"\n(8) {surface}, {cell} m cells from ({lo[0]:.1f}, {lo[1]:.1f}): HDR / truth, "
            "blue over red | the truth's relative standard error in blue\n"
        )
        for jj in range(shape[1] - 1, -1, -1):
            left = " ".join(
                f"{x:4.2f}" if n[ii, jj] else "   -" for ii, x in enumerate(tilt[:, jj])
            )
            right = " ".join(
                f"{rel[ii, jj] / n[ii, jj]:4.2f}" if n[ii, jj] else "   -" for ii in range(shape[0])
            )
            print(f"    y {lo[1] + jj * cell:4.1f}  {left}  |  {right}")


def render_check(scan, scan_dir: Path, obs, lut, t_true, tru, est, label, args) -> None:
    """Table (6): the frames against a high-spp render, and the render against the probes."""
    import imageio.v3 as iio

    from reroom.render.camera import subpixel_positions
    from reroom.synth.edits import render_scene

    views = [int(x) for x in args.render_frames.split(",")]
    renders = render_scene(
        scan_dir / "ground_truth" / "scene",
        [(scan.frames[j].c2w, scan.frames[j].intrinsics) for j in views],
        args.render_spp,
        seed=7,
    )
    # The same views at the frames' own sample count, another seed: how much of the light
    # a camera loses when the path tracer's noise pushes single pixels past white.
    frame_spp = int(
        json.loads((scan_dir / "ground_truth" / "ground_truth.json").read_text())["options"]["spp"]
    )
    noisy = render_scene(
        scan_dir / "ground_truth" / "scene",
        [(scan.frames[j].c2w, scan.frames[j].intrinsics) for j in views],
        frame_spp,
        seed=8,
    )
    print(f"\n(6) frames {views} path-traced again at {args.render_spp} spp\n")
    print("| frame | band of the render | pixels | frame / render |\n|---|---|---|---|")
    clean = (obs.flags & EDGE_FLAGS) == 0
    pix_sum: dict[int, np.ndarray] = {}
    tru_sum: dict[int, np.ndarray] = {}
    est_sum: dict[int, np.ndarray] = {}
    frame_sum: dict[int, np.ndarray] = {}
    render_sum: dict[int, np.ndarray] = {}
    noisy_sum: dict[int, np.ndarray] = {}
    clipped_sum: dict[int, np.ndarray] = {}
    caster = RayCaster(scan.mesh)
    faces = np.asarray(scan.mesh.faces)
    for j, render, raw in zip(views, renders, noisy, strict=True):
        frame = scan.frames[j]
        img = iio.imread(frame.image_path)[..., :3]
        x = lut[img] / t_true[j]
        unclipped = (img < 250).all(-1) & (img > 5).all(-1)
        # Picked by the render, not by the frame (which would keep the pixels its noise
        # pulled down): every channel expected well under the white level.
        below_white = (render * t_true[j]).max(-1) < 0.5
        h, w = render.shape[:2]
        hits = caster.intersect(*frame.pixel_rays(subpixel_positions(0, w, 0, h, 1)))
        seen_label = np.where(hits.hit, label[faces[np.maximum(hits.face, 0), 0]], 255)
        seen_label = seen_label.reshape(h, w)
        for k in LABELS:
            s = below_white & (seen_label == k)
            frame_sum[k] = frame_sum.get(k, 0) + x[s].sum(0)
            render_sum[k] = render_sum.get(k, 0) + render[s].sum(0)
            sensor = raw[s] * t_true[j]
            noisy_sum[k] = noisy_sum.get(k, 0) + sensor.sum(0)
            clipped_sum[k] = clipped_sum.get(k, 0) + np.minimum(sensor, 1.0).sum(0)
        lum = render @ LUMA
        for a, b in zip(BANDS[1:-2], BANDS[2:-1], strict=True):
            s = unclipped & (lum >= a) & (lum < b)
            if s.sum() >= 20:
                r = x[s].sum(0) / render[s].sum(0)
                print(
                    f"| {j} | {a:g}-{b:g} | {int(s.sum())} | "
                    + " / ".join(f"{v:.3f}" for v in r)
                    + " |"
                )
        seen = obs.vertex[clean & (obs.frame == j)]
        uv, _, inside = frame.project(np.asarray(scan.mesh.vertices)[seen])
        seen, uv = seen[inside], uv[inside]
        px = render[
            np.clip(uv[:, 1].astype(int), 0, h - 1), np.clip(uv[:, 0].astype(int), 0, w - 1)
        ]
        for k in LABELS:
            s = label[seen] == k
            pix_sum[k] = pix_sum.get(k, 0) + px[s].sum(0)
            tru_sum[k] = tru_sum.get(k, 0) + tru[seen][s].sum(0)
            est_sum[k] = est_sum.get(k, 0) + est[seen][s].sum(0)
    print(
        "\nOver the vertices these frames see in a clean sample:\n\n"
        "| surface | frame / render (expected under half white) | a render at the frames' "
        f"{frame_spp} spp, clipped at white / unclipped (same pixels) "
        "| render pixel / vertex truth | HDR / vertex truth |\n|---|---|---|---|---|"
    )
    for k, name in LABELS.items():
        if np.all(tru_sum.get(k, 0) > 0) and np.all(render_sum.get(k, 0) > 0):
            f = " / ".join(f"{v:.3f}" for v in frame_sum[k] / render_sum[k])
            c = " / ".join(f"{v:.3f}" for v in clipped_sum[k] / noisy_sum[k])
            a = " / ".join(f"{v:.3f}" for v in pix_sum[k] / tru_sum[k])
            b = " / ".join(f"{v:.3f}" for v in est_sum[k] / tru_sum[k])
            print(f"| {name} | {f} | {c} | {a} | {b} |")


def clip_check(scan, scan_dir: Path, t_true: np.ndarray, args) -> None:
    """Table (7): how much light the camera's clip takes from renders of a given spp.

    The views are rendered at ``--render-spp`` (the reference, which picks the pixels it
    expects under half the white level in every channel, in the frame's sensor units) and
    at each ``--clip-spp``; per sample count, the sum of the render clipped at the white
    level over the sum unclipped, on those pixels. Without Monte-Carlo noise it would be 1.
    """
    from reroom.synth.edits import render_scene

    views = [int(x) for x in args.render_frames.split(",")]
    cams = [(scan.frames[j].c2w, scan.frames[j].intrinsics) for j in views]
    scene = scan_dir / "ground_truth" / "scene"
    ref = render_scene(scene, cams, args.render_spp, seed=21)
    print(
        f"\n(7) frames {views}: a render clipped at the white level over the same unclipped, "
        f"on the pixels a {args.render_spp}-spp render expects under half white\n"
    )
    print("| samples per pixel | clipped / unclipped |\n|---|---|")
    for spp in [int(x) for x in args.clip_spp.split(",")]:
        renders = render_scene(scene, cams, spp, seed=22)
        kept = total = 0.0
        for j, r, x in zip(views, ref, renders, strict=True):
            below = (r * t_true[j]).max(-1) < 0.5
            sensor = x[below] * t_true[j]
            kept = kept + np.minimum(sensor, 1.0).sum(0)
            total = total + sensor.sum(0)
        print(f"| {spp} | " + " / ".join(f"{v:.4f}" for v in kept / total) + " |")


if __name__ == "__main__":
    main()
