"""Why do the end-to-end lights come out weak? The experiments behind docs/invert.md.

The figures of docs/invert.md, "Where the ~30 % comes from", and of its "Poorly seen bins"
paragraph come from this script. ``SCAN`` is a synthetic scan with ``hdr/``, ``layout/``
and ``lights/`` (and ``invert/`` for ``--fireflies``). Everything here is evaluation: it
reads ``ground_truth/``, which the estimate never does.

``--reprobe SPP --eval-dir DIR``
    Re-probes the true per-vertex radiance with ``SPP`` samples and writes DIR, a folder
    linking SCAN's files with ``ground_truth/vertices.ply`` replaced. The generator's
    default 64-256 spp per vertex leaves a right-skewed 10-20 % Monte-Carlo error per
    vertex; use DIR as SCAN afterwards.
``--swaps``  (``--invert JSON``: other InvertOptions for every run, e.g. ``near_distance``)
    ``reroom invert`` with one input swapped for the truth's at a time (HDR or true
    radiance, detected or true lights, true radiance where the HDR mesh is observed), then
    the same eq. 5.7 problem re-solved with the receivers' ``Lbar`` or their ``E_ind``
    taken from the truth, or with the window's cube cells fixed to the truth's:
    cluster-albedo and light-power errors per row.
``--truth-run``
    ``reroom invert`` with the true per-vertex radiance and the true lights together: the
    light models' and the solve's own error. With scans that have only some lights on
    (``reroom synth ... --lights tube,window0``) it shows which lights the solve confuses.
    With a window, the same problem is re-solved with its cells fixed to the truth's.
``--window-photos``
    The photos' pixels seen through the window, binned per cube cell: how much of each
    cell they saw, how much was saturated, and what they say about its radiance (the
    unsaturated mean; a lower bound with the saturated samples) against the truth.
``--scales``
    The HDR radiance's scale ``k`` from the evaluation (a ratio of sums over the
    clustered vertices) and from the exposures alone (true over solved frame scales,
    geometric mean over frames).
``--truth-resolves``
    The truth run's problem re-solved with least squares instead of the Huber loss, a
    wider Huber, no eq. 5.8 reweighting and every receiver instead of the subset, then
    without the receivers within 0.5 / 1 / 1.5 m of each point or line light: albedo
    errors, and each light's power over the truth run's.
``--resolves``
    The same re-solves of the scan's own run (HDR radiance, detected lights): each
    light's power over that run's.
``--blurred-truth``
    The truth run on the true radiance as is, then blurred over each vertex's one ring
    (half and all of the ring's mean), as the photos' footprint blurs it.
``--light-swaps``
    ``reroom invert`` with the detected lights, then with one detected light at a time
    replaced by its true counterpart (same type, nearest position; its name kept):
    which light's detection or localization costs the albedos and the other lights.
``--indirect``
    ``E_ind`` from the true radiance (512 hemisphere rays) against the path tracer's
    indirect irradiance ``pi (L - L_direct) / rho``, ``L_direct`` rendered at depth 2;
    and ``E_ind`` from the scan's HDR radiance (divided by its radiance scale ``k``) on
    the receivers both runs share, per channel.
``--subdivide EDGE[,EDGE]``
    ``E_ind`` from the true vertex radiance (true lights, 512 rays, the bounce fill and
    eq. 5.9) on the scan mesh and on the mesh subdivided to each ``EDGE`` metres, the new
    vertices probed as the generator probes its own, against the path tracer's indirect
    light (1024 spp) at 800 receivers per cluster: how much of ``E_ind``'s deficit is the
    radiance read between too few vertices (a clean mesh's 8 cm triangles).
``--bands``
    HDR / true radiance per band of true radiance (relative to the overall ratio of sums),
    binned by ``--bin-by PLY`` (an independent truth sample, so that the truth's own noise
    cannot fake a trend) or by the truth itself.
``--hdr-variants``
    ``--bands`` for HDR meshes re-made with the thesis's weights, the predicted-level
    weights (the default) and nearest-pixel sampling.
``--fireflies FRAME``
    Renders input frame FRAME from the recovered model with every light, then with each
    light off, and counts pixels brighter than 3x their 5x5 median.
``--at-truth``
    The truth run's problem (true radiance, true lights) evaluated at the truth: the data
    cost at the solution and at the true parameters (true cluster albedos, the window's
    true cells, the point and line lights' true profiles, an area light's true power;
    also with the point and line lights' solved shapes at their true power), the same
    problem re-solved with the line lights fixed at their truth (how flat the
    light-albedo valley is), and per cluster the model's direct and indirect irradiance at
    the truth against the path tracer's (depth 2 for direct light), with the floor in
    1 m cells; where the solution's data cost beats the truth's (by cluster and wall
    height), and the clusters by the model's indirect share. Writes ``WORK/at_truth.npz``
    (every receiver's figures). On a fused or corrupted mesh the path tracer probes the
    true surface point each vertex stands for, as the generator does.
``--interpolation``
    Path-traced radiance at random points inside the scan mesh's faces against the
    barycentric interpolation of the truth's vertex radiance, per label: the radiance
    field that ``E_ind``'s rays read between vertices.
``--unobserved``
    What eq. 5.9's fill of the unobserved hemisphere does: ``reroom invert`` with the true
    radiance everywhere the truth has it, and again only where the HDR mesh is observed.
    Prints ``E_ind`` of the second over the first on their common receivers, per cluster;
    the second's problem re-solved on those rows, and again with the first's ``E_ind``
    (albedo errors, and each light's power over the first's on the same rows); and for
    1500 receivers per cluster the hemisphere sums (raw ``E_ind``, observed and unobserved
    fractions) under both masks: how bright the surfaces the HDR mesh misses really are,
    against the mean that eq. 5.9 gives them; last, those surfaces' true radiance against
    one bounce of the observed light with their true albedo (what ``bounce_fill`` assumes).
``--resolve-variants``
    ``reroom invert`` once, then its eq. 5.7 problem re-solved: the counted subset with
    other seeds, every clustered vertex, the subset as solved before session 15 (each
    row counted once; also with ``smooth_lambda`` over the multiplicity), the counted
    subset without its rare rows, and the line's theta or phi smoothness pairs or the
    window's scaled x10 / x100 (the line's up to x1e5), the point lights' x0.1 / x0.01,
    and the window's colours limited to rank 1 or 2. Errors per cluster and light,
    scaled from the run's own evaluation by each variant's albedo and power ratios.
``--indirect-scale S[,S...]``
    The truth run's problem re-solved with ``E_ind`` scaled by each ``S``: which way an
    error in the indirect light moves the albedos and the lights.
``--profile NAME``
    A point or line light's solved profile (the scan's own ``invert/``) against the
    truth in the same basis, bin by bin, and the downward and upward sums per phi bin.
``--shares NAME``
    ``reroom invert`` once, then per inclination bin of light ``NAME`` the receivers it
    lights most: how many, observed over modelled radiance, and every light's (and
    ``E_ind``'s) share of their modelled irradiance. Then the receivers by ``NAME``'s
    share of their light: observed over modelled per channel, and the colour of ``NAME``
    that would close that gap with the rest of the model fixed (does the light's colour
    follow the receivers it lights most?), and where each share band's receivers lie
    (clusters, x/y/z percentiles, distance from the light). With
    ``--shares-true-radiance`` the invert reads the truth's per-vertex radiance instead
    of the HDR mesh (the scan's lights): is a gap the HDR's or the model's?
``--drop-cluster NAME``
    ``reroom invert`` once, then its problem re-solved without cluster ``NAME``'s
    receivers, and with their radiance recoloured to the truth's chroma of that cluster:
    the lights' power errors and the other albedos against the run's.
``--fix-at-truth NAME[,NAME]``
    ``reroom invert`` once, then its problem re-solved with those area, point or line
    lights fixed at their truth (true profile, or an area light's true radiance; moved
    into ``E_ind``): the other lights' power errors and the albedos against the run's,
    and each window's cells (distribution error; the brightest true cells and the cells
    the re-solve moved most, luminance / k). ``--fix-with-true-radiance``: the same on
    the true per-vertex radiance instead of the HDR mesh.
``--fix-window-cells``
    ``reroom invert`` once, then its problem re-solved with some of the window's cells
    fixed at the truth (those the photos see cleanly in part, those any photo sees, those
    none sees, every lit one): the other lights' power errors, and the line light's red
    over blue (its power error ratio).
``--per-light NAME``
    The truth run (true radiance, true lights) split light by light at its receivers:
    each true light path-traced alone (depth 2) and ``E_ind`` against the path tracer's
    indirect light, binned by ``NAME``'s share of the path tracer's light there. Per bin
    and light: its share, the model's irradiance at the true intensities (a point or line
    light's true profile) over the path tracer's (the light model's own error: basis,
    transfer), and the solved over the path tracer's (what the solve made of it); the same
    for the walls by height. With a window, the cube cells that send those receivers most
    light, true against solved. Which term of the model, in which channel, a light's
    solved colour or power absorbs.
``--render-consistency``
    Each solved light rendered alone (every surface white, path depth 2) against the
    solve's own ``F . I`` at 4000 clustered receivers, with the point and line emitters'
    shadow clearance off (the renderer before session 11) and on.

Usage (niced; one ``reroom invert`` is 20-50 s)::

    python benchmarks/bench_invert_diagnosis.py SCAN --reprobe 1024 --eval-dir /tmp/hq
    python benchmarks/bench_invert_diagnosis.py /tmp/hq --swaps --indirect --bands \\
        --bin-by SCAN/ground_truth/vertices.ply --work /tmp/diag
    python benchmarks/bench_invert_diagnosis.py SCAN --fireflies 5 --work /tmp/diag
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import scipy.sparse

from reroom.hdr.linearize import LUMA
from reroom.invert.evaluate import (
    distribution_relative_l2,
    evaluate_invert,
    hidden_as_unobserved,
    lights_from_truth,
)
from reroom.invert.export import light_entries
from reroom.invert.pipeline import InvertOptions, run_invert
from reroom.invert.solve import SolveOptions, solve_lighting
from reroom.io.mesh import read_ply, write_ply

CLUSTERS = {"wall": 0, "floor": 1, "ceiling": 2}


#: Decimals of the percentages printed (``--decimals``).
DECIMALS = [0]


def _pct(v) -> str:
    return "/".join(f"{100 * x:+.{DECIMALS[0]}f}" for x in np.atleast_1d(v)) + " %"


def linked_scan(src: Path, dst: Path, replace: dict[str, Path]) -> Path:
    """``dst`` with a symlink to each of ``src``'s entries, except ``replace``'s (copied).

    ``replace`` maps a relative path (``lights``, ``ground_truth/vertices.ply``) to what
    stands there instead; ``ground_truth`` is linked entry by entry when one of its
    files is replaced.
    """
    if dst.exists():
        shutil.rmtree(dst)
    dst.mkdir(parents=True)
    tops = {Path(k).parts[0] for k in replace}
    for entry in src.iterdir():
        if entry.name not in tops:
            (dst / entry.name).symlink_to(entry.resolve())
    for rel, path in replace.items():
        target = dst / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        if len(Path(rel).parts) > 1:
            for sib in (src / Path(rel).parent).iterdir():
                if sib.name != target.name and not (target.parent / sib.name).exists():
                    (target.parent / sib.name).symlink_to(sib.resolve())
        if path.is_dir():
            shutil.copytree(path, target)
        else:
            shutil.copyfile(path, target)
    return dst


def reprobe(scan: Path, spp: int, eval_dir: Path) -> None:
    """Write ``eval_dir``: ``scan`` with its true vertex radiance re-probed at ``spp``."""
    import trimesh

    from reroom.render.frames import probe_radiance

    scene = _truth_scene(scan)
    gt = read_ply(scan / "ground_truth" / "vertices.ply")
    pts, normals = _probe_points(scan)
    rad, err = probe_radiance(scene, pts, normals, spp, seed=7)
    attrs = dict(gt.vertex_attributes, radiance=rad, radiance_stderr=err)
    tmp = eval_dir.parent / (eval_dir.name + ".vertices.ply")
    write_ply(tmp, trimesh.Trimesh(gt.vertices, gt.faces, process=False), attrs)
    linked_scan(scan, eval_dir, {"ground_truth/vertices.ply": tmp})
    tmp.unlink()
    rel = err[:, 1] / np.maximum(rad[:, 1], 1e-12)
    print(
        f"re-probed {len(rad)} vertices at {spp} spp: median relative stderr {np.median(rel):.3f}"
    )


def _truth(scan: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """True radiance (NaN where no probe could see the vertex), albedo and label."""
    a = read_ply(scan / "ground_truth" / "vertices.ply").vertex_attributes
    return (
        hidden_as_unobserved(np.asarray(a["radiance"], float)),
        np.asarray(a["albedo"], float),
        np.asarray(a["label"]).astype(int),
    )


def _truth_scene(scan: Path, max_depth: int | None = None):
    """The ground truth's Mitsuba scene (``max_depth`` 2: emission and direct light only)."""
    from reroom.render import mitsuba
    from reroom.synth.scene import load_scene_description, mitsuba_scene_dict

    scene_dir = scan / "ground_truth" / "scene"
    desc = load_scene_description(scene_dir)
    if max_depth is not None:
        desc["integrator"] = {"type": "path", "max_depth": max_depth}
    return mitsuba().load_dict(mitsuba_scene_dict(desc, scene_dir))


def _probe_points(scan: Path, rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Where the generator probed the true radiance of the scan mesh's vertices ``rows``.

    Returns ``(points, normals)``: :func:`_on_true_surface` of the vertices, with their
    one-ring normals.
    """
    import trimesh

    mesh = read_ply(scan / "mesh.ply")
    normals = np.asarray(trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).vertex_normals)
    rows = np.arange(len(normals)) if rows is None else np.asarray(rows)
    pts, nrm = np.asarray(mesh.vertices)[rows], normals[rows]
    return _on_true_surface(scan, pts, nrm), nrm


def _on_true_surface(scan: Path, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """The true surface points that points of the scan mesh stand for.

    A clean mesh lies on the true surface: the points themselves. A fused or corrupted
    mesh lies up to centimetres off it, so the generator probes the true surface point
    each vertex stands for (``reroom.synth.groundtruth.transfer_truth``), seen along the
    vertex normal; probing the vertex itself reads 0 wherever the true surface is more
    than the probe's offset behind it.
    """
    from reroom.synth.groundtruth import clean_surface, transfer_truth
    from reroom.synth.scene import load_scene_description

    gt = json.loads((scan / "ground_truth" / "ground_truth.json").read_text())
    if gt.get("mesh", {}).get("kind", "clean") == "clean":
        return np.asarray(points, float)
    scene_dir = scan / "ground_truth" / "scene"
    desc = load_scene_description(scene_dir)
    truth = transfer_truth(clean_surface(desc, scene_dir), desc, scene_dir, points, normals)
    return np.asarray(truth["surface_point"], float)


def _wall_bands(problem, points: np.ndarray) -> list[tuple[float, float, np.ndarray]]:
    """The wall receivers in 0.5 m bands of height above the lowest one, as
    ``(low, high, mask)``; empty without a wall cluster or wall receivers."""
    if "wall" not in problem.cluster_names:
        return []
    wall = problem.cluster == problem.cluster_names.index("wall")
    if not wall.any():
        return []
    z = points[:, 2] - points[wall, 2].min()
    edges = [(0.0, 0.5), (0.5, 1.0), (1.0, 1.5), (1.5, 2.0), (2.0, np.inf)]
    return [(lo, hi, wall & (z >= lo) & (z < hi)) for lo, hi in edges]


def _with_lights_fixed(problem, fixed: dict[int, np.ndarray]):
    """``problem`` with the lights ``fixed`` (block index -> intensities) moved into ``E_ind``."""
    import scipy.sparse as sp

    f = sp.csr_matrix(problem.transfer)
    off = np.concatenate([[0], np.cumsum([b.size for b in problem.lights])]).astype(int)
    e_fix = sum(np.asarray(f[:, off[i] : off[i + 1]] @ v) for i, v in fixed.items())
    keep = np.concatenate(
        [np.arange(off[i], off[i + 1]) for i in range(len(problem.lights)) if i not in fixed]
    ).astype(int)
    return dataclasses.replace(
        problem,
        indirect=problem.indirect + e_fix,
        transfer=f[:, keep],
        lights=[b for i, b in enumerate(problem.lights) if i not in fixed],
    )


def _hdr(scan: Path) -> tuple[np.ndarray, np.ndarray]:
    a = read_ply(scan / "hdr" / "hdr_mesh.ply").vertex_attributes
    rad = np.asarray(a["radiance"], float)
    return rad, np.asarray(a["observed"]).astype(bool) & np.isfinite(rad).all(axis=1)


def _row(label: str, report: dict) -> str:
    cl = report["clusters"]
    cells = [_pct(cl[c]["relative_error"]) for c in CLUSTERS]
    powers = []
    for light in report["lights"]:
        err = light.get("power_relative_error")
        text = f"{light['name']} {_pct(err)}" if err is not None else light["name"]
        eff = light.get("effective_power_relative_error")
        if eff is not None:
            text += f" [leaving the fixture: {_pct(eff)}]"
        l2 = light.get("distribution_relative_l2")
        powers.append(text + (f" (L2 {100 * l2:.0f} %)" if l2 is not None else ""))
    return f"| {label} | " + " | ".join(cells) + " | " + "; ".join(powers) + " |"


#: Extra InvertOptions of every run (``--invert``, e.g. ``{"near_distance": 0}``, added to
#: these). The point lights stay at the solve's bins: the splits to 128 bins and the photo
#: profile reshape each solved bin after the solve (powers and albedos unchanged), but they
#: leave the run's problem with 128-bin columns, and re-solving that (``--resolve-variants``,
#: ``--shares``, ``--fix-*``) is another, freer problem than the one the run solved: on the
#: second walk of `furnished` it moved the tube by 8 points before any variant was applied.
INVERT_EXTRA: dict = {"point_splits": 0, "point_photo_profile": False}


_invert_result_cache: dict[Path, object] = {}


def _invert(scan: Path, out: Path, radiance=None, solve: SolveOptions | None = None):
    res = run_invert(
        scan,
        out,
        InvertOptions(pictures=False, solve=solve or SolveOptions(), **INVERT_EXTRA),
        radiance_override=radiance,
    )
    if radiance is not None:
        # evaluate_invert then takes the radiance's scale as 1 (it is the truth's)
        (out / "true_radiance.flag").write_text("evaluation-only: true radiance\n")
    _invert_result_cache[out] = res
    return res


def _true_window_photos(scan: Path):
    """The photos seen through the truth's first window (its true opening, 128-row map):
    ``(truth light, WindowPhotos, stats, HDR mesh)``, or None without a window."""
    from reroom.invert.window_env import observe_windows
    from reroom.invert.windows import WindowOpening

    gt = json.loads((scan / "ground_truth" / "scene" / "scene.json").read_text())
    wins = [x for x in gt["lights"] if x["type"] == "window" and x.get("on", True)]
    if not wins:
        return None
    t = wins[0]
    c = np.asarray(t["corners"], float)
    opening = WindowOpening(
        t["name"], c.mean(axis=0), (c[1] - c[0]) / 2, (c[3] - c[0]) / 2, np.asarray(t["normal"])
    )
    mesh = read_ply(scan / "hdr" / "hdr_mesh.ply")
    (ph,), stats = observe_windows(scan, mesh, [opening], height=128)
    return t, ph, stats, mesh


def window_photos(scan: Path) -> None:
    """What the photos seen through the (first) window tell about its cube cells.

    Per cell the photos touch: the share of the cell's solid angle they saw, the share of
    their samples that were saturated, the unsaturated samples' mean and the lower bound
    ``sum(a_t max(mean_t, bound_t)) / A_cell`` (unseen texels counted 0), both in the
    truth's units (divided by the HDR radiance's scale ``k``), against the true cell
    (:func:`reroom.invert.evaluate.true_window_cells`). Needs ``hdr/`` and the truth.
    """
    from reroom.invert.basis import CubemapBasis
    from reroom.invert.evaluate import true_window_cells
    from reroom.invert.window_env import (
        cell_lower_bounds,
        latlong_directions,
        latlong_solid_angles,
    )

    found = _true_window_photos(scan)
    if found is None:
        print("no window in the truth")
        return
    t, ph, stats, mesh = found
    true_rad, _, _ = _truth(scan)
    lbar = np.asarray(mesh.vertex_attributes["radiance"], float)
    ok = np.asarray(mesh.vertex_attributes["observed"]).astype(bool)
    ok &= (true_rad > 1e-4).all(axis=1) & (lbar > 0).all(axis=1)
    k = lbar[ok].sum(axis=0) / true_rad[ok].sum(axis=0)
    basis = CubemapBasis(4)
    truth, shown = true_window_cells(t, scan / "ground_truth" / "scene", n=4)
    cell = basis.cell_of(latlong_directions(128).reshape(-1, 3))
    area = latlong_solid_angles(128).ravel()
    mean = ph.mean.reshape(-1, 3) / k
    cnt, sat = ph.count.ravel(), ph.saturated.ravel()
    seen = (cnt > 0) | (sat > 0)
    lum = LUMA
    lower = cell_lower_bounds(ph, basis) / k
    print(
        f"{stats['samples'][0]} samples through the window, {stats['saturated'][0]} saturated; "
        f"k = {np.round(k, 3).tolist()}; {int(shown.sum())} cells shown\n"
    )
    print("| cell | true luminance | share seen | saturated | unsat. mean / true | bound / true |")
    print("|---|---|---|---|---|---|")
    for j in np.flatnonzero(shown):
        m = cell == j
        if not (m & seen).any():
            continue
        a_cell = area[m].sum()
        s = m & seen
        u = m & (cnt > 0)
        lb = lower[j]
        um = (area[u, None] * mean[u]).sum(axis=0) / max(area[u].sum(), 1e-12)
        tl = float(truth[j] @ lum)
        print(
            f"| {j} | {tl:.2f} | {area[s].sum() / a_cell:.2f} | "
            f"{sat[m].sum() / max(cnt[m].sum() + sat[m].sum(), 1):.2f} | "
            f"{(um @ lum) / tl if u.any() else float('nan'):.2f} | {(lb @ lum) / tl:.2f} |"
        )
    bright = shown & (truth @ lum > 1.0)
    unseen = [j for j in np.flatnonzero(bright) if not ((cell == j) & seen).any()]
    print(f"\ncells brighter than 1 (truth): {int(bright.sum())}, seen by no photo: {len(unseen)}")


def _true_lights_scan(scan: Path, work: Path) -> Path:
    """A linked copy of ``scan`` whose ``lights/`` are the truth's (evaluation only)."""
    from reroom.lights import write_lights

    write_lights(lights_from_truth(scan), work / "true_lights")
    return linked_scan(scan, work / "scan_true_lights", {"lights": work / "true_lights"})


def truth_run(scan: Path, work: Path, solve: SolveOptions) -> None:
    """``reroom invert`` with the true radiance *and* the true lights: what is left is
    the light models' and the solve's own error (e.g. two lights confused)."""
    res, src, out = _truth_problem(scan, work, solve)
    print(
        "| run | wall | floor | ceiling | lights (power error, distribution L2) |\n|---|---|---|---|---|"
    )
    print(_row("true radiance, true lights", evaluate_invert(src, out)), flush=True)
    fixed = _window_from_truth(scan, res.problem, np.ones(3))
    if fixed is None:
        return
    # The same problem with the window's cells fixed to the truth's (in E_ind): how much of
    # each other light's error the window's under-determined cells cause.
    again = solve_lighting(fixed, solve)
    print("\nre-solved with the window's cells fixed to the truth's, power / as solved:")
    for b in fixed.lights:
        ratio = again.intensities[b.name].sum(axis=0) / res.solve.intensities[b.name].sum(axis=0)
        print(f"  {b.name}: " + " / ".join(f"{x:.3f}" for x in ratio))


def _truth_problem(scan: Path, work: Path, solve: SolveOptions):
    """The truth run's result (cached) and the linked scan with the true lights."""
    true_rad, _, _ = _truth(scan)
    src = _true_lights_scan(scan, work)
    out = work / "true_radiance_true_lights"
    res = _invert_result_cache.get(out) or _invert(src, out, true_rad, solve)
    return res, src, out


def _true_cluster_albedo(problem, solution, report: dict) -> np.ndarray:
    """The true cluster albedos, back from a solution and its evaluation's relative errors."""
    err = np.array([report["clusters"][c]["relative_error"] for c in problem.cluster_names])
    return solution.albedo / (1.0 + err)


def _true_intensities(
    scan: Path, report: dict, sol, leaving: bool = False, profiles: bool = False
) -> dict:
    """Each light's true intensities in the solve's basis, by name.

    A window's cells from the true HDRI; any other light has its solved shape at its true
    power (the shape error is reported separately): the bulb's power, or with
    ``leaving`` the power leaving its fixture (a lamp's shade keeps part of its bulb's
    light, which the model never sees). With ``profiles`` a point or line light has its
    true profile instead (``evaluate_invert``'s ``true_profile`` times the radiance
    scale ``k``): its shape and power both as the truth's.
    """
    from reroom.invert.evaluate import true_window_cells

    k = np.asarray(report.get("radiance_scale", 1.0), float)

    gt = json.loads((scan / "ground_truth" / "ground_truth.json").read_text())
    out: dict[str, np.ndarray] = {}
    for e in report["lights"]:
        solved = sol.intensities[e["name"]]
        if e["type"] == "window":
            win = next(x for x in gt["lights"] if x["name"] == e["truth"])
            n = int(round(np.sqrt(solved.shape[0] / 6)))
            out[e["name"]], _ = true_window_cells(win, scan / "ground_truth" / "scene", n=n)
        elif profiles and e["type"] in ("point", "line"):
            out[e["name"]] = np.asarray(e["distribution"]["true_profile"], float) * k
        else:
            err = e.get("effective_power_relative_error") if leaving else None
            err = e["power_relative_error"] if err is None else err
            out[e["name"]] = solved / (1.0 + np.asarray(err))
    return out


def at_truth(scan: Path, work: Path, solve: SolveOptions, spp: int = 512) -> None:
    """How the truth run's model fits at the true parameters, and where it misses."""
    import scipy.sparse as sp

    from reroom.invert.solve import indirect_weights
    from reroom.render.frames import probe_radiance

    res, src, out = _truth_problem(scan, work, solve)
    prob, sol, rows = res.problem, res.solve, res.problem_vertices
    report = evaluate_invert(src, out)
    _, true_albedo, label = _truth(scan)
    f = sp.csr_matrix(prob.transfer)
    off = np.concatenate([[0], np.cumsum([b.size for b in prob.lights])]).astype(int)
    shaped = _true_intensities(scan, report, sol)
    true_int = _true_intensities(scan, report, sol, profiles=True)
    rho_true = _true_cluster_albedo(prob, sol, report)
    w = indirect_weights(prob.radiance, prob.indirect, solve.reweight_c or 10.0)
    scale = float(np.median(prob.radiance))
    delta = solve.huber_delta or np.inf

    def irradiance(inten: dict) -> dict[str, np.ndarray]:
        return {
            b.name: np.asarray(f[:, off[i] : off[i + 1]] @ inten[b.name])
            for i, b in enumerate(prob.lights)
        }

    def cost_per_receiver(rho: np.ndarray, inten: dict) -> np.ndarray:
        e = prob.indirect + sum(irradiance(inten).values())
        r = np.abs(np.sqrt(w) * (prob.radiance - rho[prob.cluster] / np.pi * e) / scale)
        return np.where(r <= delta, 0.5 * r * r, delta * (r - 0.5 * delta)).sum(axis=1)

    def cost(rho: np.ndarray, inten: dict) -> float:
        return float(cost_per_receiver(rho, inten).sum())

    print(
        f"\ndata cost (Huber, eq. 5.8 weights): solution {cost(sol.albedo, sol.intensities):.4g}, "
        f"true parameters {cost(rho_true, true_int):.4g} (the point and line lights' "
        f"solved shapes at their true power: {cost(rho_true, shaped):.4g})"
    )
    lines = [i for i, b in enumerate(prob.lights) if b.kind == "line"]
    if lines:
        fixed = _with_lights_fixed(prob, {i: true_int[prob.lights[i].name] for i in lines})
        again = solve_lighting(fixed, solve)
        print(
            f"line lights fixed at their truth, the rest re-solved: objective "
            f"{again.objective:.4g} against {sol.objective:.4g} as solved; albedo error "
            + ", ".join(
                f"{c} {_pct(a)}"
                for c, a in zip(prob.cluster_names, again.albedo / rho_true - 1, strict=True)
            )
        )
    # The path tracer's direct (depth 2) and total radiance at the receivers.
    scene = _truth_scene(scan, max_depth=2)
    pts, nrm = _probe_points(scan, rows)
    direct, _ = probe_radiance(scene, pts, nrm, spp, seed=1)
    rho_v = np.maximum(true_albedo[rows], 1e-3)
    e_dir_true = np.pi * direct / rho_v
    e_ind_true = np.pi * (prob.radiance - direct) / rho_v
    e_dir = sum(irradiance(true_int).values())
    pred = rho_true[prob.cluster] / np.pi * (prob.indirect + e_dir)
    lum = LUMA
    print(
        "\n| cluster | predicted / observed at the truth | E_dir model / path tracer | E_ind model / path tracer |"
    )
    print("|---|---|---|---|")
    for c, name in enumerate(prob.cluster_names):
        m = prob.cluster == c
        print(
            f"| {name} | {_ratio(pred[m], prob.radiance[m])} | {_ratio(e_dir[m], e_dir_true[m])} | "
            f"{_ratio(prob.indirect[m], e_ind_true[m])} |"
        )
    # Where the solution fits better than the truth: the receivers that pull the solve off
    # the true parameters, by cluster and (walls) height band.
    pred_sol = (
        sol.albedo[prob.cluster]
        / np.pi
        * (prob.indirect + sum(irradiance(sol.intensities).values()))
    )
    gain = cost_per_receiver(rho_true, true_int) - cost_per_receiver(sol.albedo, sol.intensities)
    print(
        f"\nwhere the solution's data cost is lower than the truth's (total gain "
        f"{gain.sum():.4g}); predicted / observed (luminance) at the truth and at the solution:\n"
    )
    print("| receivers | count | gain | at the truth | at the solution |\n|---|---|---|---|---|")
    groups = [(name, prob.cluster == c) for c, name in enumerate(prob.cluster_names)]
    groups += [(f"wall, {lo:g}-{hi:g} m up", m) for lo, hi, m in _wall_bands(prob, pts)]
    for name, m in groups:
        if m.any():
            print(
                f"| {name} | {m.sum()} | {gain[m].sum():+.4g} | "
                f"{(pred[m] @ lum).sum() / (prob.radiance[m] @ lum).sum():.3f} | "
                f"{(pred_sol[m] @ lum).sum() / (prob.radiance[m] @ lum).sum():.3f} |"
            )
    # Everything above per receiver, for one-off looks without re-running the probes.
    np.savez_compressed(
        work / "at_truth.npz", rows=rows, points=pts, cluster=prob.cluster,
        radiance=prob.radiance, weight=w, e_dir=e_dir, e_dir_true=e_dir_true,
        e_ind=prob.indirect, e_ind_true=e_ind_true, predicted=pred,
        predicted_solution=pred_sol, huber_delta=delta, scale=scale,
    )  # fmt: skip
    # The same by the indirect share: eq. 5.8's weights favour receivers with some
    # indirect light, and those pin the albedos' scale (rho = pi L / E_ind where the lights
    # send little), so a model error there moves every albedo and light. Binned by the
    # model's share at the truth, not the path tracer's: bins chosen on a noisy estimate
    # read it low where they select it low (on the issue's scan, binned by the path
    # tracer's share, the model's direct light read 1.6 times the path tracer's on the
    # most indirect walls and 0.86 on the least; by the model's share, 0.88 and 1.15).
    share = (prob.indirect @ lum) / np.maximum((prob.indirect + e_dir) @ lum, 1e-300)
    wl = w @ lum
    print(
        "\n| cluster | indirect share (model at the truth) | receivers | share of eq. 5.8's weight | "
        "predicted / observed | E_dir model / path tracer | E_ind model / path tracer |"
    )
    print("|---|---|---|---|---|---|---|")
    edges = [0.0, 0.2, 0.4, 0.6, 0.8, 0.9, 1.01]
    for c, name in enumerate(prob.cluster_names):
        m = prob.cluster == c
        for lo, hi in zip(edges[:-1], edges[1:], strict=True):
            s = m & (share >= lo) & (share < hi)
            if s.sum() < 20:
                continue
            print(
                f"| {name} | {lo:.1f}-{min(hi, 1.0):.1f} | {s.sum()} | "
                f"{wl[s].sum() / max(wl[m].sum(), 1e-300):.2f} | "
                f"{_ratio(pred[s], prob.radiance[s])} | {_ratio(e_dir[s], e_dir_true[s])} | "
                f"{_ratio(prob.indirect[s], e_ind_true[s])} |"
            )
    floor = (
        prob.cluster == prob.cluster_names.index("floor") if "floor" in prob.cluster_names else None
    )
    if floor is None or not floor.any():
        return
    p = pts[floor]
    xe = np.arange(p[:, 0].min(), p[:, 0].max() + 1.0, 1.0)
    ye = np.arange(p[:, 1].min(), p[:, 1].max() + 1.0, 1.0)
    print("\nfloor, 1 m cells (rows: y from the lowest): E_dir model / path tracer (luminance)")
    for j in range(len(ye) - 1):
        cells = []
        for i in range(len(xe) - 1):
            c = (
                (p[:, 0] >= xe[i])
                & (p[:, 0] < xe[i + 1])
                & (p[:, 1] >= ye[j])
                & (p[:, 1] < ye[j + 1])
            )
            a, b = e_dir[floor][c] @ lum, e_dir_true[floor][c] @ lum
            cells.append(f"{a.sum() / b.sum():5.2f}" if c.sum() >= 5 and b.sum() > 0 else "  -  ")
        print(f"  y {ye[j]:4.1f} " + " ".join(cells))


def _ratio(a: np.ndarray, b: np.ndarray) -> str:
    return "/".join(f"{x:.3f}" for x in a.sum(axis=0) / np.maximum(b.sum(axis=0), 1e-300))


def interpolation(scan: Path, spp: int = 2048, points: int = 600) -> None:
    """Path-traced radiance inside faces against the interpolated vertex radiance."""
    import trimesh

    from reroom.render.frames import probe_radiance
    from reroom.synth.labels import LABEL_NAMES

    true_rad, _, label = _truth(scan)
    mesh = read_ply(scan / "mesh.ply")
    v, fc = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    tm = trimesh.Trimesh(v, fc, process=False)
    rng = np.random.default_rng(5)
    emitter = (label[fc] == 7).any(axis=1)  # a light's own faces glow
    p = tm.area_faces * ~emitter
    f = rng.choice(len(fc), points, p=p / p.sum())
    u = rng.random((points, 2))
    u[u.sum(axis=1) > 1] = 1 - u[u.sum(axis=1) > 1]
    bc = np.c_[1 - u.sum(axis=1), u]
    pts = (bc[..., None] * v[fc[f]]).sum(axis=1)
    hidden = np.isnan(true_rad).any(axis=1)  # no probe saw them (inside geometry)
    seen = ~hidden[fc[f]].any(axis=1)
    interp = (bc[..., None] * np.nan_to_num(true_rad)[fc[f]]).sum(axis=1)
    scene = _truth_scene(scan)
    traced, _ = probe_radiance(scene, pts, tm.face_normals[f], spp, seed=9)
    at_vertex, _ = probe_radiance(scene, v[fc[f, 0]], tm.vertex_normals[fc[f, 0]], spp, seed=10)
    ok = ~hidden[fc[f, 0]]
    print(
        f"\nat vertices: path tracer / truth file {_ratio(at_vertex[ok], true_rad[fc[f[ok], 0]])}; "
        f"{hidden.sum()} of {len(hidden)} vertices hidden (radiance exactly 0)"
    )
    print(
        "| label (of the face's first vertex) | points | path tracer / interpolated, hidden "
        "vertices as 0 | points on faces without one | path tracer / interpolated |"
    )
    print("|---|---|---|---|---|")
    lab = label[fc[f, 0]]
    groups = [(LABEL_NAMES.get(int(c), c), lab == c) for c in np.unique(lab)]
    for name, m in groups + [("all", np.ones(points, bool))]:
        s = m & seen
        print(
            f"| {name} | {m.sum()} | {_ratio(traced[m], interp[m])} | {s.sum()} | "
            f"{_ratio(traced[s], interp[s]) if s.any() else '-'} |"
        )


def swaps(scan: Path, work: Path, solve: SolveOptions, rows: int = 4) -> None:
    """Each input of the end-to-end run swapped for the truth's, one at a time.

    ``rows`` < 4 runs only the first ``rows`` variants (and no re-solves).
    """
    true_rad, true_albedo, label = _truth(scan)
    _, observed = _hdr(scan)
    true_lights_scan = _true_lights_scan(scan, work)
    print(
        "| run | wall | floor | ceiling | lights (power error, distribution L2) |\n|---|---|---|---|---|"
    )
    runs = {}
    variants = [
        ("HDR radiance, detected lights", scan, None),
        ("HDR radiance, true lights", true_lights_scan, None),
        ("true radiance, detected lights", scan, true_rad),
        (
            "true radiance where the HDR mesh is observed",
            scan,
            np.where(observed[:, None], true_rad, np.nan),
        ),
    ]
    for name, src, rad in variants[:rows]:
        out = work / name.replace(" ", "_").replace(",", "")
        runs[name] = _invert(src, out, rad, solve)
        print(_row(name, evaluate_invert(src, out)), flush=True)

    if rows < len(variants):
        return
    # The same problem (same receivers), re-solved with one input from the truth.
    hdr = runs["HDR radiance, detected lights"]
    masked = runs["true radiance where the HDR mesh is observed"]
    if not np.array_equal(hdr.problem_vertices, masked.problem_vertices):
        print("(the two runs have different receivers: no re-solves)")
        return
    ph, pt = hdr.problem, masked.problem
    k = ph.radiance.sum(axis=0) / pt.radiance.sum(axis=0)
    # As evaluate_invert: the mean true albedo of every vertex the truth labels so.
    truth_rho = np.stack([true_albedo[label == CLUSTERS[c]].mean(axis=0) for c in ph.cluster_names])
    print(f"\nre-solves of the HDR run's problem (k = {np.round(k, 3).tolist()}), albedo error:\n")
    print("| re-solve | " + " | ".join(ph.cluster_names) + " |\n|---|---|---|---|")
    variants = [
        ("as solved", ph),
        ("Lbar from the truth (x k)", dataclasses.replace(ph, radiance=pt.radiance * k)),
        ("E_ind from the truth (x k)", dataclasses.replace(ph, indirect=pt.indirect * k)),
    ]
    fixed = _window_from_truth(scan, ph, k)
    if fixed is not None:
        variants.append(("window cells fixed to the truth's (x k)", fixed))
    for name, prob in variants:
        r = solve_lighting(prob, solve)
        print(f"| {name} | " + " | ".join(_pct(x) for x in r.albedo / truth_rho - 1) + " |")


def resolves(scan: Path, work: Path, solve: SolveOptions, truth: bool = True) -> None:
    """The truth run's problem (``truth``; else the scan's own run: HDR radiance, detected
    lights) re-solved with the solve's options varied, and without the receivers near
    each point or line light: which part of the solve, or which light's neighbourhood,
    moves the albedos and the lights off the truth."""
    from reroom.lights import load_lights

    if truth:
        res, src, out = _truth_problem(scan, work, solve)
    else:
        src, out = scan, work / "resolves"
        res = _invert_result_cache.get(out) or _invert(src, out, None, solve)
    prob, sol = res.problem, res.solve
    report = evaluate_invert(src, out)
    rho_true = _true_cluster_albedo(prob, sol, report)
    pts = np.asarray(read_ply(scan / "mesh.ply").vertices)[res.problem_vertices]
    run = "truth run" if truth else "run"
    print(_row(run, report))
    print(
        f"\nre-solves: albedo error against the truth; each light's power over the {run}'s"
        "\n\n| re-solve | albedo error | lights |\n|---|---|---|"
    )

    def show(name: str, again) -> None:
        albedo = _albedo_text(prob.cluster_names, again.albedo, rho_true)
        lights = "; ".join(
            f"{n} x" + "/".join(f"{x:.3f}" for x in again.intensities[n].sum(0) / v.sum(0))
            for n, v in sol.intensities.items()
        )
        print(f"| {name} | {albedo} | {lights} |", flush=True)

    for name, change in [
        ("least squares (no Huber)", {"huber_delta": None}),
        ("Huber delta 0.2", {"huber_delta": 0.2}),
        ("no eq. 5.8 reweighting", {"reweight_c": None}),
        ("every receiver (no subset)", {"max_vertices": None}),
    ]:
        show(name, solve_lighting(prob, dataclasses.replace(solve, **change)))
    for light in load_lights(src / "lights" / "lights.json").lights:
        if light.type not in ("point", "line"):
            continue
        near = np.linalg.norm(pts - np.asarray(light.anchor(), float), axis=1)
        for radius in (0.5, 1.0, 1.5):
            keep = np.flatnonzero(near > radius)
            show(
                f"without the {len(pts) - len(keep)} receivers within {radius:g} m of {light.name}",
                solve_lighting(_rows_of(prob, keep), solve),
            )


def blurred_truth(scan: Path, work: Path, solve: SolveOptions) -> None:
    """The truth run with the true radiance blurred over each vertex's one ring (half and
    all of the ring's mean), as the photos' footprint blurs what they see: which way a
    blur of the observations moves each light."""
    true_rad, _, _ = _truth(scan)
    src = _true_lights_scan(scan, work)
    f = np.asarray(read_ply(scan / "mesh.ply").faces)
    n = len(true_rad)
    i = np.concatenate([f[:, 0], f[:, 1], f[:, 2], f[:, 1], f[:, 2], f[:, 0]])
    j = np.concatenate([f[:, 1], f[:, 2], f[:, 0], f[:, 0], f[:, 1], f[:, 2]])
    ring = scipy.sparse.csr_matrix((np.ones(len(i)), (i, j)), shape=(n, n))
    ring.data[:] = 1.0  # an edge shared by two faces counts once
    seen = np.isfinite(true_rad).all(axis=1)
    count = ring @ seen.astype(float)
    mean = (ring @ np.where(seen[:, None], true_rad, 0.0)) / np.maximum(count, 1.0)[:, None]
    mean = np.where((count > 0)[:, None], mean, true_rad)
    print("| truth run, radiance | wall | floor | ceiling | lights |\n|---|---|---|---|---|")
    for name, rad in [
        ("point truth", true_rad),
        ("half the one-ring mean", 0.5 * true_rad + 0.5 * mean),
        ("the one-ring mean", mean),
    ]:
        out = work / ("blurred_" + name.replace(" ", "_"))
        _invert(src, out, np.where(seen[:, None], rad, np.nan), solve)
        print(_row(name, evaluate_invert(src, out)), flush=True)


def radiance_scales(scan: Path) -> None:
    """The HDR radiance's scale ``k`` two ways: the evaluation's ratio of sums over the
    clustered vertices, and from the exposures alone (the geometric mean over frames of
    the true frame scale over the solved one), which no vertex sampling touches."""
    solved = json.loads((scan / "hdr" / "exposures.json").read_text())["frames"]
    truth = json.loads((scan / "ground_truth" / "ground_truth.json").read_text())["frames"]
    ratio = [
        np.asarray(t["scale"], float) / np.asarray(s["scale"], float)
        for s, t in zip(solved, truth, strict=True)
        if s.get("scale") is not None
    ]
    k_exposures = np.exp(np.log(np.asarray(ratio)).mean(axis=0))
    k_vertices = np.asarray(evaluate_invert(scan)["radiance_scale"], float)
    print(
        "\nk from the vertices (the evaluation's) "
        + "/".join(f"{x:.4f}" for x in k_vertices)
        + ", from the exposures "
        + "/".join(f"{x:.4f}" for x in k_exposures)
        + "; vertices over exposures "
        + "/".join(f"{x:.4f}" for x in k_vertices / k_exposures)
    )


def _albedo_text(names, albedo, truth_rho) -> str:
    err = albedo / truth_rho - 1
    return "; ".join(f"{n} {_pct(e)}" for n, e in zip(names, err, strict=True))


def _rows_of(problem, rows: np.ndarray):
    """``problem`` restricted to the receivers ``rows``."""
    return dataclasses.replace(
        problem,
        radiance=problem.radiance[rows],
        indirect=problem.indirect[rows],
        cluster=problem.cluster[rows],
        transfer=problem.transfer[rows],
    )


def unobserved(scan: Path, work: Path, solve: SolveOptions, per_cluster: int = 1500) -> None:
    """The true radiance everywhere the truth has it vs only where the HDR mesh is observed."""
    from reroom.hdr.observe import vertex_normals
    from reroom.invert.pipeline import emitter_classes
    from reroom.invert.transfer import hemisphere_transfer
    from reroom.lights import load_lights
    from reroom.rays import RayCaster

    true_rad, true_albedo, label = _truth(scan)
    _, hdr_observed = _hdr(scan)
    truth_seen = np.isfinite(true_rad).all(axis=1)
    both = hdr_observed & truth_seen
    full = _invert(scan, work / "unobserved_full", true_rad, solve)
    masked = _invert(
        scan, work / "unobserved_masked", np.where(both[:, None], true_rad, np.nan), solve
    )
    pf, pm = full.problem, masked.problem
    truth_rho = np.stack([true_albedo[label == CLUSTERS[c]].mean(axis=0) for c in pf.cluster_names])
    where = {int(v): i for i, v in enumerate(full.problem_vertices)}
    in_full = np.array([int(v) in where for v in masked.problem_vertices])
    im = np.flatnonzero(in_full)
    jf = np.array([where[int(v)] for v in masked.problem_vertices[in_full]], dtype=int)
    print(
        f"\nvertices: {len(label)}; the truth sees {int(truth_seen.sum())}, the HDR mesh "
        f"{int(hdr_observed.sum())}; receivers {len(jf)} in common ({len(pf.radiance)} / "
        f"{len(pm.radiance)})"
    )
    print("\nE_ind, HDR-observed truth / all of the truth, on the common receivers:\n")
    print("| cluster | r / g / b |\n|---|---|")
    for c, name in enumerate(pf.cluster_names):
        sel = pm.cluster[im] == c
        ratio = pm.indirect[im][sel].sum(axis=0) / pf.indirect[jf][sel].sum(axis=0)
        print(f"| {name} | " + " / ".join(f"{x:.3f}" for x in ratio) + " |")

    reference = solve_lighting(_rows_of(pf, jf), solve)
    print("\nre-solves on the common receivers (lights: power / the first row's):\n")
    print("| problem | albedo error | lights |\n|---|---|---|")
    cases = [
        ("all of the truth", _rows_of(pf, jf)),
        ("HDR-observed truth (the fill gives the rest)", _rows_of(pm, im)),
        (
            "HDR-observed truth, E_ind from all of the truth",
            dataclasses.replace(_rows_of(pm, im), indirect=pf.indirect[jf]),
        ),
    ]
    for name, prob in cases:
        r = reference if name == cases[0][0] else solve_lighting(prob, solve)
        lights = "; ".join(
            f"{n} "
            + "/".join(
                f"{x:.3f}" for x in r.intensities[n].sum(0) / reference.intensities[n].sum(0)
            )
            for n in r.intensities
        )
        print(f"| {name} | {_albedo_text(pf.cluster_names, r.albedo, truth_rho)} | {lights} |")

    # The hemisphere sums at a sample of receivers under both masks (512 rays, no windows:
    # their rays count as light, not as observed or unobserved surface).
    mesh = read_ply(scan / "hdr" / "hdr_mesh.ply")
    lights = load_lights(scan / "lights" / "lights.json")
    _, _, area_of, window_of, on_light = emitter_classes(
        lights.lights,
        lights.vertex_light_id,
        np.asarray(mesh.vertices, float),
        InvertOptions(**INVERT_EXTRA).fixture_margin,
    )
    normals = vertex_normals(mesh)
    caster = RayCaster(mesh)
    rad = np.where(truth_seen[:, None], true_rad, 0.0)
    rng = np.random.default_rng(0)
    print(
        "\nhemisphere sums at receivers (green; E_ind raw = over the observed hits, "
        "rescaled = eq. 5.9):\n"
    )
    print(
        "| cluster | mask | E_ind raw | rescaled | observed fraction | unobserved fraction | "
        "radiance per unit of hemisphere, newly unobserved / observed |\n|---|---|---|---|---|---|---|"
    )
    for name, lab in CLUSTERS.items():
        cand = np.flatnonzero(both & (label == lab) & ~on_light)
        if len(cand) == 0:
            continue
        recv = rng.choice(cand, min(per_cluster, len(cand)), replace=False)
        sums = {}
        for mask_name, seen in [("all of the truth", truth_seen), ("HDR-observed", both)]:
            h = hemisphere_transfer(
                caster, mesh, recv, normals, rad * seen[:, None], seen, area_of, [], None,
                rays_per_vertex=512, seed=1, window_of_vertex=window_of,
            )  # fmt: skip
            sums[mask_name] = h
        a, b = sums["all of the truth"], sums["HDR-observed"]
        lost = a.p_observed.sum() - b.p_observed.sum()
        dark = (a.indirect[:, 1].sum() - b.indirect[:, 1].sum()) / max(lost, 1e-12)
        mean = b.indirect[:, 1].sum() / b.p_observed.sum()
        for mask_name, h in sums.items():
            extra = f"{dark:.3g} / {mean:.3g}" if mask_name == "HDR-observed" else ""
            print(
                f"| {name} | {mask_name} | {h.indirect[:, 1].sum():.1f} | "
                f"{h.indirect_rescaled()[:, 1].sum():.1f} | {h.p_observed.mean():.4f} | "
                f"{h.p_unobserved.mean():.4f} | {extra} |"
            )

    # The vertices only the truth sees, against one bounce of the HDR-observed truth's
    # light with their own true albedo (what bounce_fill assumes, with a fixed albedo).
    hidden = np.flatnonzero(
        truth_seen & ~hdr_observed & ~on_light & (np.linalg.norm(normals, axis=1) > 0)
    )
    if len(hidden):
        h = hemisphere_transfer(
            caster, mesh, hidden, normals, rad * both[:, None], both, area_of, [], None,
            rays_per_vertex=256, seed=2, window_of_vertex=window_of,
        )  # fmt: skip
        bounce = true_albedo[hidden] / np.pi * h.indirect_rescaled()
        ratio = true_rad[hidden, 1].sum() / max(bounce[:, 1].sum(), 1e-300)
        print(
            f"\n{len(hidden)} vertices only the truth sees: true radiance / (true albedo / pi "
            f"x E_obs), sum over them (green) {ratio:.3f}; their mean true albedo (green) "
            f"{true_albedo[hidden, 1].mean():.3f}; mean true radiance {true_rad[hidden, 1].mean():.4f} "
            f"against {true_rad[both, 1].mean():.4f} over the HDR-observed vertices"
        )


def indirect_scales(scan: Path, work: Path, solve: SolveOptions, scales: list[float]) -> None:
    """The truth run's problem re-solved with E_ind scaled: which way its error moves things."""
    res, src, out = _truth_problem(scan, work, solve)
    prob, sol = res.problem, res.solve
    report = evaluate_invert(src, out)
    rho_true = _true_cluster_albedo(prob, sol, report)
    true_power = {
        e["name"]: sol.intensities[e["name"]].sum(axis=0)
        / (1.0 + np.asarray(e["power_relative_error"]))
        for e in report["lights"]
    }
    print("\n| E_ind x | albedo error | power error (sum of the solved intensities) |")
    print("|---|---|---|")
    for s in scales:
        r = solve_lighting(dataclasses.replace(prob, indirect=prob.indirect * s), solve)
        lights = "; ".join(
            f"{n} {_pct(r.intensities[n].sum(axis=0) / true_power[n] - 1)}" for n in true_power
        )
        print(f"| {s:g} | {_albedo_text(prob.cluster_names, r.albedo, rho_true)} | {lights} |")


def _window_from_truth(scan: Path, problem, k: np.ndarray):
    """``problem`` with its (first) window's light moved into ``E_ind`` at the true cells.

    The true HDRI averaged per cube cell over the directions through the window
    (:func:`reroom.invert.evaluate.true_window_cells`), times ``k``; None without a window.
    """
    from reroom.invert.evaluate import true_window_cells

    gt = json.loads((scan / "ground_truth" / "ground_truth.json").read_text())
    true_wins = [x for x in gt.get("lights", []) if x["type"] == "window"]
    blocks = [i for i, b in enumerate(problem.lights) if b.kind == "window"]
    if not true_wins or not blocks:
        return None
    wi = blocks[0]
    n = int(round(np.sqrt(problem.lights[wi].size / 6)))
    cells, _ = true_window_cells(true_wins[0], scan / "ground_truth" / "scene", n=n)
    return _with_lights_fixed(problem, {wi: cells * k})


def indirect(scan: Path, work: Path) -> None:
    """``E_ind`` (true radiance, hemisphere rays) against the path tracer's indirect light."""

    from reroom.render.frames import probe_radiance

    true_rad, true_albedo, label = _truth(scan)
    res = _invert(scan, work / "indirect_true_radiance", true_rad)
    scene = _truth_scene(scan, max_depth=2)  # emission + direct light only
    rows = res.problem_vertices
    pts, nrm = _probe_points(scan, rows)
    direct, _ = probe_radiance(scene, pts, nrm, 256, seed=1)
    rho = np.maximum(true_albedo[rows], 1e-3)
    e_true = np.pi * (true_rad[rows] - direct) / rho
    e_ours = res.problem.indirect
    # The same with the scan's own HDR radiance (the pipeline's input), in the truth's
    # units (divided by the evaluation's radiance scale k), on the receivers both share.
    e_hdr = np.full_like(e_ours, np.nan)
    if (scan / "hdr" / "hdr_mesh.ply").is_file():
        out = work / "indirect_hdr_radiance"
        hres = _invert(scan, out, None)
        k = np.asarray(evaluate_invert(scan, out)["radiance_scale"], float)
        at = {int(v): i for i, v in enumerate(hres.problem_vertices)}
        for i, v in enumerate(rows):
            j = at.get(int(v))
            if j is not None:
                e_hdr[i] = hres.problem.indirect[j] / k
    print(
        "\n| cluster | receivers | sum E_ind ours / path tracer: true radiance "
        "| HDR radiance / k (receivers) | indirect share |"
    )
    print("|---|---|---|---|---|")
    for name, lab in CLUSTERS.items():
        m = label[rows] == lab
        share = e_true[m].sum() / (np.pi * true_rad[rows][m] / rho[m]).sum()
        h = m & np.isfinite(e_hdr).all(axis=1)
        hdr = (
            " / ".join(f"{x:.3f}" for x in e_hdr[h].sum(0) / e_true[h].sum(0)) + f" ({h.sum()})"
            if h.any()
            else "-"
        )
        ratio = " / ".join(f"{x:.3f}" for x in e_ours[m].sum(0) / e_true[m].sum(0))
        print(f"| {name} | {m.sum()} | {ratio} | {hdr} | {share:.2f} |")


def subdivided_indirect(
    scan: Path, work: Path, edges: list[float], per_cluster: int = 800, rays: int = 512
) -> None:
    """``E_ind`` from vertex radiance on the scan mesh and on the mesh subdivided to each
    of ``edges`` metres (the new vertices probed as the generator probes its own), against
    the path tracer's indirect light at the same receivers: how much of ``E_ind``'s
    deficit is the radiance field read between too few vertices."""
    import time

    import trimesh

    from reroom.invert.fill import bounce_fill
    from reroom.invert.pipeline import CLUSTER_LABELS, emitter_classes
    from reroom.invert.transfer import hemisphere_transfer
    from reroom.invert.windows import WindowOpening
    from reroom.lights import load_lights
    from reroom.rays import RayCaster
    from reroom.render.frames import probe_radiance

    true_rad, true_albedo, label = _truth(scan)
    mesh = read_ply(scan / "mesh.ply")
    v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces)
    normals = np.asarray(trimesh.Trimesh(v, f, process=False).vertex_normals)
    lights = load_lights(_true_lights_scan(scan, work) / "lights" / "lights.json")
    ids = np.asarray(lights.vertex_light_id)
    margin = InvertOptions().fixture_margin
    _, wins, area_of, window_of, on_light = emitter_classes(lights.lights, ids, v, margin)
    openings = [
        WindowOpening(
            w.name, *(np.asarray(w.geometry[k], float) for k in ("centre", "half_u", "half_v")),
            np.asarray(w.geometry["normal"], float),
        )
        for w in wins
    ]  # fmt: skip
    seen = np.isfinite(true_rad).all(axis=1)
    rng = np.random.default_rng(0)
    recv = np.concatenate(
        [
            rng.choice(c, min(per_cluster, len(c)), replace=False)
            for c in (
                np.flatnonzero(seen & (label == lab) & ~on_light) for lab in CLUSTER_LABELS.values()
            )
            if len(c)
        ]
    )
    scene = _truth_scene(scan)
    at = _on_true_surface(scan, v[recv], normals[recv])
    full, _ = probe_radiance(scene, at, normals[recv], 1024, seed=3)
    direct, _ = probe_radiance(_truth_scene(scan, max_depth=2), at, normals[recv], 1024, seed=4)
    e_traced = np.pi * (full - direct) / np.maximum(true_albedo[recv], 1e-3)

    def e_ind(verts, faces, rad, seen_v, area_v, window_v, on_v, fill: bool) -> np.ndarray:
        m = trimesh.Trimesh(verts, faces, process=False)
        caster = RayCaster(m)
        rad = np.where(seen_v[:, None], rad, 0.0)
        if fill:  # the pipeline's default unobserved fill
            rad, reached = bounce_fill(
                caster, m, rad, seen_v, np.asarray(m.vertex_normals), area_v, window_v,
                excluded=on_v, seed=7,
            )  # fmt: skip
            seen_v = seen_v | reached
        h = hemisphere_transfer(
            caster, m, recv, normals[recv], rad, seen_v, area_v, openings, None,
            rays_per_vertex=rays, seed=1, window_of_vertex=window_v,
        )  # fmt: skip
        return h.indirect_rescaled()

    print(
        f"\nE_ind ({rays} rays, eq. 5.9 after the bounce fill) / the path tracer's indirect "
        f"light (1024 spp) at {len(recv)} receivers, r/g/b sums:\n"
    )
    print("| radiance read from | vertices | wall | floor | ceiling |\n|---|---|---|---|---|")
    rl = label[recv]

    def row(name: str, n: int, e: np.ndarray) -> None:
        cells = [
            "/".join(f"{x:.3f}" for x in e[rl == lab].sum(0) / e_traced[rl == lab].sum(0))
            for lab in CLUSTER_LABELS.values()
        ]
        print(f"| {name} | {n} | " + " | ".join(cells) + " |", flush=True)

    row(
        "the scan mesh's vertices",
        len(v),
        e_ind(v, f, true_rad, seen, area_of, window_of, on_light, True),
    )
    for edge in edges:
        t = time.perf_counter()
        fv, ff, parent = trimesh.remesh.subdivide_to_size(
            v, f, max_edge=edge, max_iter=20, return_index=True
        )
        if not np.allclose(fv[: len(v)], v):
            raise RuntimeError("subdivide_to_size reordered the scan mesh's vertices")
        # Each new vertex takes the light classes of the nearest corner of its parent face.
        owner = np.empty(len(fv), np.int64)
        for k in range(3):
            owner[ff[:, k]] = parent
        corners = f[owner]
        nearest = np.argmin(np.linalg.norm(v[corners] - fv[:, None, :], axis=2), axis=1)
        corner = corners[np.arange(len(fv)), nearest]
        corner[: len(v)] = np.arange(len(v))
        _, _, area_f, window_f, on_f = emitter_classes(lights.lights, ids[corner], fv, margin)
        fn = np.asarray(trimesh.Trimesh(fv, ff, process=False).vertex_normals)
        new = np.arange(len(v), len(fv))
        rad_f = np.concatenate(
            [
                true_rad,
                hidden_as_unobserved(
                    probe_radiance(
                        scene, _on_true_surface(scan, fv[new], fn[new]), fn[new], 256, seed=5
                    )[0]
                ),
            ]
        )
        seen_f = np.isfinite(rad_f).all(axis=1)
        e = e_ind(fv, ff, rad_f, seen_f, area_f, window_f, on_f, True)
        row(f"subdivided to {edge:g} m ({time.perf_counter() - t:.0f} s)", len(fv), e)


def bands(scan: Path, bin_by: Path | None) -> None:
    """HDR / true radiance per band of true radiance (green, clustered observed vertices)."""
    true_rad, _, label = _truth(scan)
    hdr_rad, observed = _hdr(scan)
    key = true_rad if bin_by is None else np.asarray(read_ply(bin_by).vertex_attributes["radiance"])
    m = observed & np.isin(label, list(CLUSTERS.values())) & (true_rad[:, 1] > 1e-3)
    k = hdr_rad[m, 1].sum() / true_rad[m, 1].sum()
    src = "the truth itself" if bin_by is None else str(bin_by)
    print(f"\nHDR / true radiance by band (binned by {src}; overall ratio of sums {k:.3f}):\n")
    print("| true radiance band | vertices | HDR / true, relative |\n|---|---|---|")
    for lo, hi in [(0, 0.02), (0.02, 0.05), (0.05, 0.1), (0.1, 0.2), (0.2, 0.4), (0.4, np.inf)]:
        s = m & (key[:, 1] >= lo) & (key[:, 1] < hi)
        if s.any():
            ratio = hdr_rad[s, 1].sum() / true_rad[s, 1].sum() / k
            print(f"| [{lo}, {hi}) | {s.sum()} | {ratio:.3f} |")


def hdr_variants(scan: Path, work: Path, bin_by: Path | None) -> None:
    """``--bands`` for HDR meshes made with other reprojection choices (docs/hdr.md)."""
    from reroom.hdr.observe import ObserveOptions
    from reroom.hdr.pipeline import HdrOptions, run_hdr

    for label, sampling, predicted in [
        ("thesis weights (own level), 3x3 box", "box3", False),
        ("predicted-level weights, 3x3 box (default)", "box3", True),
        ("predicted-level weights, nearest pixel", "nearest", True),
    ]:
        tag = f"hdr_{sampling}_{'predicted' if predicted else 'own'}"
        opt = HdrOptions(
            baselines=False,
            report=False,
            predicted_weights=predicted,
            observe=ObserveOptions(sampling=sampling),
        )
        run_hdr(scan, work / tag, opt)
        print(f"\n**{label}**")
        bands(linked_scan(scan, work / f"scan_{tag}", {"hdr": work / tag}), bin_by)


def fireflies(scan: Path, frame: int, work: Path, spp: int) -> None:
    """Speckle in a render of the recovered model, with every light and with each one off."""
    import scipy.ndimage as ndi

    from reroom.edit import render_edit
    from reroom.io.images import read_exr

    names = [x["name"] for x in json.loads((scan / "invert" / "scene.json").read_text())["lights"]]
    print(f"\n| render of frame {frame} ({spp} spp) | pixels > 3x their 5x5 median | mean |")
    print("|---|---|---|")
    for label, ops in [("every light", [])] + [
        (f"{n} off", [{"op": "light", "name": n, "off": True}]) for n in names
    ]:
        tag = label.replace(" ", "_")
        render_edit(scan, ops, work / "fireflies" / tag, frames=[frame], spp=spp, name=tag)
        img = read_exr(work / "fireflies" / tag / f"{tag}_f{frame:05d}.exr")[..., :3].mean(axis=2)
        med = ndi.median_filter(img, 5)
        print(f"| {label} | {np.mean(img > 3 * np.maximum(med, 1e-6)):.2%} | {img.mean():.4f} |")


def light_swaps(scan: Path, work: Path) -> None:
    """The detected lights, then each one replaced by its true counterpart in turn."""
    import dataclasses as dc

    from reroom.lights import LightSet, load_lights, write_lights

    detected = load_lights(scan / "lights" / "lights.json")
    truth = lights_from_truth(scan)
    print(
        "| lights | wall | floor | ceiling | lights (power error, distribution L2) |\n"
        "|---|---|---|---|---|"
    )
    out = work / "light_swap_detected"
    _invert(scan, out)
    print(_row("detected", evaluate_invert(scan, out)), flush=True)
    for k, light in enumerate(detected.lights):
        same = [t for t in truth.lights if t.type == light.type]
        if not same:
            continue
        dist = [np.linalg.norm(t.anchor() - light.anchor()) for t in same]
        true_light = same[int(np.argmin(dist))]
        geom = dict(true_light.geometry)
        ids = np.asarray(detected.vertex_light_id).copy()
        if light.type == "area":
            ti = truth.lights.index(true_light)
            ids[ids == k] = -1
            ids[np.asarray(truth.vertex_light_id) == ti] = k
            geom["light_index"] = k
        elif light.type == "window" and "light_index" in light.geometry:
            geom["light_index"] = light.geometry["light_index"]
        lights = list(detected.lights)
        lights[k] = dc.replace(light, geometry=geom, source="user", reason="true (evaluation)")
        swapped = LightSet(lights, [], ids.astype(np.int32), {}, ["EVALUATION ONLY"], {})
        name = f"light_swap_{light.name}"
        write_lights(swapped, work / f"{name}_lights")
        src = linked_scan(scan, work / f"{name}_scan", {"lights": work / f"{name}_lights"})
        _invert(src, work / name)
        label = f"{light.name} true ({float(np.min(dist)):.2f} m off)"
        print(_row(label, evaluate_invert(src, work / name)), flush=True)


def _power_errors(report: dict) -> dict[str, np.ndarray]:
    """Each evaluated light's power error (against what leaves its fitting where known)."""
    return {
        e["name"]: np.asarray(e.get("effective_power_relative_error") or e["power_relative_error"])
        for e in report["lights"]
        if e.get("power_relative_error") is not None
    }


def _powers(res, min_bin_support: float) -> dict[str, np.ndarray]:
    """The powers ``scene.json`` would give each light of an invert result."""
    ents = light_entries(res, None, min_bin_support)
    return {e["name"]: np.asarray(e["power"], float) for e in ents}


def resolve_variants(scan: Path, work: Path, solve: SolveOptions) -> None:
    """The run's eq. 5.7 problem re-solved with the subset and the smoothness varied.

    ``reroom invert`` once (HDR radiance, the scan's lights), then its problem solved
    again: the counted subset with seeds 0-3; the subset as solved before session 15
    (every row counted once), also with ``smooth_lambda`` divided by the sampled rows'
    multiplicity; every clustered vertex; the counted subset without the rows kept as
    rare; and the line and window lights' smoothness pairs scaled (theta or phi pairs of
    the line, all pairs of the window), and each window's colours limited to rank 1 or 2
    (its cells a sum of that many single-colour copies). Errors are the run's own ``evaluate_invert``
    figures times each variant's ratio to the run: albedo ratio per cluster, power ratio
    per light (the powers ``scene.json`` would get, fills of poorly seen bins included).
    """
    import reroom.invert.solve as solve_mod

    out = work / "variants"
    res = _invert(scan, out, None, solve)
    report = evaluate_invert(scan, out)
    prob, base = res.problem, res.solve
    opts = InvertOptions(pictures=False, solve=solve, **INVERT_EXTRA)

    def powers(sol) -> dict[str, np.ndarray]:
        return _powers(dataclasses.replace(res, solve=sol), opts.min_bin_support)

    base_err = {c: np.asarray(v["relative_error"]) for c, v in report["clusters"].items()}
    base_pow = powers(base)
    light_err = _power_errors(report)
    names = [c for c in CLUSTERS if c in prob.cluster_names]
    lights = [b.name for b in prob.lights if b.name in light_err]
    print(
        "| solve | objective | "
        + " | ".join(names + lights)
        + " |\n|"
        + "---|" * (2 + len(names) + len(lights))
    )

    def row(label: str, sol) -> None:
        cells = []
        for c in names:
            k = prob.cluster_names.index(c)
            cells.append(_pct((1 + base_err[c]) * sol.albedo[k] / base.albedo[k] - 1))
        p = powers(sol)
        for n in lights:
            cells.append(_pct((1 + light_err[n]) * p[n] / base_pow[n] - 1))
        print(f"| {label} | {sol.objective:.1f} | " + " | ".join(cells) + " |", flush=True)

    row("the run", base)
    for seed in (1, 2, 3):
        row(f"counted, seed {seed}", solve_lighting(prob, dataclasses.replace(solve, seed=seed)))
    row(
        "every clustered vertex",
        solve_lighting(prob, dataclasses.replace(solve, max_vertices=None)),
    )
    rows_of = solve_mod._solve_rows
    try:
        # The subset as solved before session 15: each row counted once.
        def uncounted(*a):
            r, _ = rows_of(*a)
            return r, np.ones(len(r))

        solve_mod._solve_rows = uncounted
        for seed in (0, 1, 2, 3):
            row(
                f"uncounted, seed {seed}",
                solve_lighting(prob, dataclasses.replace(solve, seed=seed)),
            )
        mult = float(rows_of(prob, np.ones(len(prob.cluster_names), bool), solve)[1].max())
        smooth = dataclasses.replace(solve, smooth_lambda=solve.smooth_lambda / mult)
        row(f"uncounted, smooth_lambda / {mult:.2f}", solve_lighting(prob, smooth))

        def without_rare(*a):
            r, m = rows_of(*a)
            return r[m > 1], m[m > 1]

        if mult > 1:
            solve_mod._solve_rows = without_rare
            row("counted, rare rows left out", solve_lighting(prob, solve))
        else:
            print("| (not subsampled: every row counts once, so no rare rows to leave out) |")
    finally:
        solve_mod._solve_rows = rows_of
    for kind, which in (("line", "theta"), ("line", "phi"), ("window", "all"), ("point", "all")):
        factors = {"point": (0.1, 0.01), "line": (10.0, 100.0, 1e3, 1e4, 1e5)}
        for factor in factors.get(kind, (10.0, 100.0)):
            blocks = []
            for b in prob.lights:
                if b.kind == kind and b.adjacency is not None:
                    w = (
                        np.ones(len(b.adjacency))
                        if b.adjacency_weights is None
                        else np.asarray(b.adjacency_weights, float)
                    )
                    # LineBasis.adjacency: theta pairs weigh 1, phi pairs line_phi_smooth
                    pick = {"theta": w == 1.0, "phi": w != 1.0, "all": np.ones(len(w), bool)}
                    b = dataclasses.replace(
                        b, adjacency_weights=np.where(pick[which], w * factor, w)
                    )
                blocks.append(b)
            sol = solve_lighting(dataclasses.replace(prob, lights=blocks), solve)
            row(f"{kind} smoothness ({which} pairs) x{factor:g}", sol)
    # Each window's colours constrained: its cells as a sum of `rank` monochrome copies
    # (rank 1: one colour for every cell), merged back into the window's cells.
    for rank in (1, 2):
        sol = _solve_window_rank(prob, solve, rank)
        if sol is not None:
            row(f"window colours of rank {rank}", sol)


def _solve_window_rank(prob, solve: SolveOptions, rank: int):
    """``prob`` solved with each window split into ``rank`` monochrome copies of its
    columns (one colour each), the copies summed back into the window's cells."""
    f = scipy.sparse.csc_matrix(prob.transfer)
    off = np.concatenate([[0], np.cumsum([b.size for b in prob.lights])]).astype(int)
    cols, blocks = [], []
    for i, b in enumerate(prob.lights):
        copies = rank if b.kind == "window" else 1
        for k in range(copies):
            cols.append(f[:, off[i] : off[i + 1]])
            blocks.append(
                dataclasses.replace(b, name=f"{b.name}#{k}", monochrome=True)
                if b.kind == "window"
                else b
            )
    if not any(b.kind == "window" for b in prob.lights):
        return None
    split = dataclasses.replace(prob, transfer=scipy.sparse.hstack(cols).tocsr(), lights=blocks)
    sol = solve_lighting(split, solve)
    merged = {}
    for b in prob.lights:
        if b.kind == "window":
            merged[b.name] = sum(sol.intensities[f"{b.name}#{k}"] for k in range(rank))
        else:
            merged[b.name] = sol.intensities[b.name]
    return dataclasses.replace(sol, intensities=merged)


def render_consistency(scan: Path, work: Path, clearance: bool = True, n: int = 4000) -> None:
    """Each solved light rendered alone vs the solve's own transfer, at clustered receivers.

    Every surface white (albedo 1), path depth 2 (direct light only): the probed radiance
    times pi is the irradiance the renderer gives, ``F . I`` the one the solve fitted.
    With ``clearance=False`` the point and line emitters get none (the renderer before
    session 11), so their fixtures shadow them a second time.
    """
    import trimesh

    from reroom.edit.apply import edited_scene
    from reroom.render.emitters import register_emitters
    from reroom.render.frames import probe_radiance
    from reroom.render.glow import split_glow

    res = _invert(scan, work / "consistency")
    prob, pv = res.problem, res.problem_vertices
    mesh = read_ply(scan / "mesh.ply")
    normals = np.asarray(trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).vertex_normals)
    sub = np.random.default_rng(1).choice(len(pv), min(n, len(pv)), replace=False)
    points, nrm, cluster = np.asarray(mesh.vertices)[pv[sub]], normals[pv[sub]], prob.cluster[sub]
    intens = res.solve.intensity_vector(res.lights)
    mi = register_emitters()
    scene, _ = split_glow(
        edited_scene(scan, [], invert_dir=res.out_dir, work_dir=work / "cons_edit")
    )
    lights = [k for k in scene if k.startswith("light_") and not k.endswith("_patch")]
    print(
        f"| light ({'clearance' if clearance else 'no clearance'}) | render / transfer "
        "(sum, r/g/b) | wall | floor | ceiling |\n|---|---|---|---|---|"
    )
    start = 0
    for block in res.lights:
        cols = slice(start, start + block.size)
        start += block.size
        want = np.asarray(prob.transfer[sub][:, cols] @ intens[cols])
        k = next(i for i, x in enumerate(res.light_info) if x["name"] == block.name)
        d = {a: (dict(b) if isinstance(b, dict) else b) for a, b in scene.items()}
        for name in lights:
            if name != f"light_{k:02d}":
                d.pop(name)
        for name, entry in d.items():
            if isinstance(entry, dict) and "bsdf" in entry and not name.startswith("light_"):
                entry["bsdf"] = {"type": "diffuse", "reflectance": {"type": "rgb", "value": 1.0}}
        if not clearance:
            em = d[f"light_{k:02d}"]
            em.pop("clearance", None)
        d["integrator"] = {"type": "path", "max_depth": 2}
        got = np.pi * probe_radiance(mi.load_dict(d), points, nrm, 256, seed=5)[0]
        ratio = got.sum(0) / np.maximum(want.sum(0), 1e-12)
        per = [
            got[cluster == c, 1].sum() / max(want[cluster == c, 1].sum(), 1e-12)
            for c in range(len(prob.cluster_names))
        ]
        print(
            f"| {block.name} ({block.kind}) | {'/'.join(f'{x:.3f}' for x in ratio)} | "
            + " | ".join(f"{x:.3f}" for x in per)
            + " |",
            flush=True,
        )


def profile_bins(scan: Path, name: str) -> None:
    """A point or line light's solved profile against the truth, bin by bin.

    Reads the scan's own ``invert/`` (no solve): per inclination bin (0 = up, 180 =
    down) and phi bin, the solved profile times its colour's luminance over the
    evaluation's luminance scale ``k``, the true profile in the same basis
    (``evaluate_invert``'s ``true_profile``: the light as it leaves its fixture), and
    their ratio where the truth is above 1e-3; then each phi bin's downward and upward
    sums, estimate over truth.
    """
    report = evaluate_invert(scan, scan / "invert")
    scene = json.loads((scan / "invert" / "scene.json").read_text())
    est = next(x for x in scene["lights"] if x["name"] == name)
    ev = next(x for x in report["lights"] if x["name"] == name)
    dist = ev["distribution"]
    lum = LUMA
    k = float(np.asarray(report["radiance_scale"]) @ lum)
    solved = np.asarray(est["distribution"]["profile"], float)
    bins = solved.shape[0]
    solved = solved.reshape(bins, -1) * float(np.asarray(est["color"]) @ lum) / k
    phi = solved.shape[1]
    truth = (np.asarray(dist["true_profile"], float) @ lum).reshape(bins, phi)
    print(
        f"`{name}` ({dist['basis']}, {bins} x {phi} bins; relative L2 "
        f"{100 * dist['relative_l2']:.1f} %), luminance / k, solved | true | ratio:\n"
    )
    head = " | ".join(f"phi {j}" for j in range(phi))
    print(f"| theta | solved: {head} | true: {head} | ratio: {head} |")
    print("|---|" + "---|" * (3 * phi))
    for i in range(bins):
        th = (i + 0.5) * 180.0 / bins
        ratio = [
            f"{solved[i, j] / truth[i, j]:.2f}" if truth[i, j] > 1e-3 else "-" for j in range(phi)
        ]
        print(
            f"| {th:.1f} | "
            + " | ".join(f"{v:.3f}" for v in solved[i])
            + " | "
            + " | ".join(f"{v:.3f}" for v in truth[i])
            + " | "
            + " | ".join(ratio)
            + " |"
        )
    th = (np.arange(bins) + 0.5) * 180.0 / bins
    for label, rows in (("down (theta > 90)", th > 90), ("up (theta < 90)", th < 90)):
        cells = []
        for j in range(phi):
            t = truth[rows, j].sum()
            cells.append(f"phi {j} {solved[rows, j].sum() / t:.2f}" if t > 1e-6 else f"phi {j} -")
        print(f"\n{label}, sum of solved over sum of true per phi bin: " + ", ".join(cells))


def bin_shares(scan: Path, work: Path, name: str, true_radiance: bool = False) -> None:
    """Who lights the receivers of each of a light's bins, in the solved model.

    ``reroom invert`` once (HDR radiance, or with ``true_radiance`` the truth's per-vertex
    radiance; the scan's lights); each clustered receiver is
    given to the inclination bin of light ``name`` that sends it the most (phi bins
    summed). Per bin: the receivers (per cluster), observed over modelled radiance
    (Rec. 709 luminance, sums), and each light's and ``E_ind``'s share of the modelled
    irradiance there. A bin whose receivers get a small share from its own light is
    held by little of the data: a small error of the others moves it a lot.
    """
    if true_radiance:
        res = _invert(scan, work / "shares_true_radiance", radiance=_truth(scan)[0])
    else:
        res = _invert(scan, work / "shares")
    prob, sol = res.problem, res.solve
    intens = sol.intensity_vector(prob.lights)
    offsets = np.concatenate([[0], np.cumsum([b.size for b in prob.lights])])
    names = [b.name for b in prob.lights]
    k = names.index(name)
    parts = {
        b.name: np.asarray(
            prob.transfer[:, offsets[i] : offsets[i + 1]] @ intens[offsets[i] : offsets[i + 1]]
        )
        for i, b in enumerate(prob.lights)
    }
    lum = LUMA
    irr = prob.indirect + sum(parts.values())
    model = sol.albedo[prob.cluster] / np.pi * irr
    own = prob.transfer[:, offsets[k] : offsets[k + 1]]
    own = own.toarray() if hasattr(own, "toarray") else np.asarray(own)
    bins = 32
    per_theta = own.reshape(len(own), bins, -1).sum(2)
    theta_bin = np.where(per_theta.sum(1) > 0, per_theta.argmax(1), -1)
    print(
        f"Receivers by the bin of `{name}` that sends them most; shares of the modelled "
        "irradiance (luminance):\n"
    )
    print(
        "| theta | receivers ("
        + " / ".join(prob.cluster_names)
        + ") | observed / modelled | "
        + " | ".join(names)
        + " | E_ind |"
    )
    print("|---|---|---|" + "---|" * (len(names) + 1))
    for b in range(bins):
        rows = theta_bin == b
        if not rows.any():
            continue
        total = float((irr[rows] @ lum).sum())
        shares = [float((parts[n][rows] @ lum).sum()) / total for n in names]
        shares.append(float((prob.indirect[rows] @ lum).sum()) / total)
        count = np.bincount(prob.cluster[rows], minlength=len(prob.cluster_names))
        ratio = float((prob.radiance[rows] @ lum).sum() / (model[rows] @ lum).sum())
        print(
            f"| {(b + 0.5) * 180 / bins:.1f} | "
            + " / ".join(str(int(c)) for c in count)
            + f" | {ratio:.3f} | "
            + " | ".join(f"{x:.2f}" for x in shares)
            + " |"
        )
    # The light's colour: where it holds a large share, does the model miss in one channel?
    share = (parts[name] @ lum) / np.maximum(irr @ lum, 1e-300)
    print(
        f"\nReceivers by `{name}`'s share of their modelled irradiance (luminance); observed "
        "over modelled radiance per channel (sums), and the light's colour that would close "
        "the gap there with the rest of the model fixed (relative to its solved colour, "
        "normalised to luminance 1):\n"
    )
    print("| share | receivers | observed / modelled r/g/b | colour that fits them r/g/b |")
    print("|---|---|---|---|")
    for lo, hi in ((0.5, 1.01), (0.3, 0.5), (0.1, 0.3), (0.03, 0.1), (0.0, 0.03)):
        rows = (share >= lo) & (share < hi)
        if not rows.any():
            continue
        obs = prob.radiance[rows].sum(0)
        mod = model[rows].sum(0)
        # the light's part of the model there, per channel: rho / pi * its irradiance
        own_part = (sol.albedo[prob.cluster[rows]] / np.pi * parts[name][rows]).sum(0)
        scale = np.where(own_part > 0, 1 + (obs - mod) / np.maximum(own_part, 1e-300), np.nan)
        scale = scale / float(scale @ lum) if np.all(np.isfinite(scale)) else scale
        print(
            f"| {lo:.2f}-{min(hi, 1):.2f} | {int(rows.sum())} | "
            + "/".join(f"{x:.3f}" for x in obs / mod)
            + " | "
            + "/".join(f"{x:.3f}" for x in scale)
            + " |"
        )
    # Where those receivers lie: a share band is a place (a pool, its edge, a corner).
    if res.problem_vertices is None:
        return
    from reroom.io.mesh import read_ply

    xyz = np.asarray(read_ply(scan / "mesh.ply").vertices)[res.problem_vertices]
    info = res.light_info[k]
    anchor = np.asarray(info.get("geometry", {}).get("position", xyz.mean(0)), float)
    print(
        f"\nWhere they lie (the light at {np.round(anchor, 3).tolist()}): per band the "
        "receivers per cluster, the 10th-90th percentiles of x, y, z and the median "
        "distance from the light (metres):\n"
    )
    print("| share | " + " / ".join(prob.cluster_names) + " | x | y | z | distance |")
    print("|---|---|---|---|---|---|")
    for lo, hi in ((0.5, 1.01), (0.3, 0.5), (0.1, 0.3), (0.03, 0.1)):
        rows = (share >= lo) & (share < hi)
        if not rows.any():
            continue
        count = np.bincount(prob.cluster[rows], minlength=len(prob.cluster_names))
        q = np.percentile(xyz[rows], [10, 90], axis=0)
        dist = float(np.median(np.linalg.norm(xyz[rows] - anchor, axis=1)))
        print(
            f"| {lo:.2f}-{min(hi, 1):.2f} | "
            + " / ".join(str(int(c)) for c in count)
            + " | "
            + " | ".join(f"{q[0, a]:.2f}-{q[1, a]:.2f}" for a in range(3))
            + f" | {dist:.2f} |"
        )


def fix_at_truth(
    scan: Path,
    work: Path,
    names: list[str],
    true_radiance: bool = False,
    radiance: np.ndarray | None = None,
) -> None:
    """The run's problem re-solved with some area, point or line lights fixed at their truth.

    ``reroom invert`` once (HDR radiance, the scan's lights); then each named light's
    columns are taken out of the problem and its true profile (``evaluate_invert``'s
    ``true_profile`` times the HDR radiance's scale ``k``: the light as it leaves its
    fixture, in the solve's units) moves into ``E_ind``, and the rest is solved again.
    Printed: every other light's power error and the albedos, scaled from the run's own
    evaluation by the re-solve's ratios, next to the run's. It asks whether an error of
    one light is held by another: if fixing light A leaves B's error as it was, B's error
    is not A's. With ``true_radiance`` the run reads the true per-vertex radiance
    instead of the HDR mesh (the scan's detected lights kept): whether what is left is
    the HDR's or the model's; ``radiance``, a ``(V, 3)`` radiance in the truth's units,
    likewise (e.g. the HDR mesh's with some vertices swapped for the truth's).
    """
    if true_radiance:
        radiance = _truth(scan)[0]
    out = work / ("fix_at_truth" if radiance is None else "fix_at_truth_radiance")
    res = _invert(scan, out, radiance)
    report = evaluate_invert(scan, out)
    prob = res.problem
    k = np.asarray(report["radiance_scale"], float)
    order = [b.name for b in prob.lights]
    errors = _power_errors(report)
    truth_of = {e["name"]: e for e in report["lights"]}
    min_bin_support = InvertOptions(**INVERT_EXTRA).min_bin_support
    base = _powers(res, min_bin_support)
    fixed: dict[int, np.ndarray] = {}
    for name in names:
        i = order.index(name)
        if prob.lights[i].kind == "area":
            # One Lambertian element: its radiance, from the true power pi L A.
            area = float(res.light_info[i]["geometry"].get("area", 0.0))
            true_profile = np.asarray(truth_of[name]["true_power"], float)[None, :]
            true_profile = true_profile / (np.pi * area)
        else:
            true_profile = np.asarray(truth_of[name]["distribution"]["true_profile"], float)
        fixed[i] = true_profile * k
    kept = [j for j in range(len(prob.lights)) if j not in fixed]
    prob2 = _with_lights_fixed(prob, fixed)
    sol2 = solve_lighting(
        prob2, res.solve_options if hasattr(res, "solve_options") else SolveOptions()
    )
    res2 = dataclasses.replace(
        res,
        problem=prob2,
        solve=sol2,
        lights=[res.lights[j] for j in kept],
        light_info=[res.light_info[j] for j in kept],
    )
    after = _powers(res2, min_bin_support)
    print(
        f"`{', '.join(names)}` fixed at the truth, the rest re-solved (objective "
        f"{res.solve.objective:.1f} → {sol2.objective:.1f}):\n"
    )
    print("| | the run | re-solved |\n|---|---|---|")
    for c, cname in enumerate(prob.cluster_names):
        if cname not in CLUSTERS:
            continue
        run_err = np.asarray(report["clusters"][cname]["relative_error"])
        new_err = (1 + run_err) * sol2.albedo[c] / res.solve.albedo[c] - 1
        print(f"| {cname} | {_pct(run_err)} | {_pct(new_err)} |")
    for name in after:
        if name in errors:
            new_err = (1 + errors[name]) * after[name] / base[name] - 1
            print(f"| {name} | {_pct(errors[name])} | {_pct(new_err)} |")
    _window_cells_after(scan, report, res, res2, min_bin_support)


def _with_cells_fixed(problem, block: int, fixed: np.ndarray, values: np.ndarray):
    """``problem`` with the elements ``fixed`` (bool, the block's size) of light ``block``
    held at ``values`` (moved into ``E_ind``), its smoothness pairs and priors kept for
    the rest."""
    import scipy.sparse as sp

    f = sp.csr_matrix(problem.transfer)
    off = np.concatenate([[0], np.cumsum([b.size for b in problem.lights])]).astype(int)
    e_fix = np.asarray(f[:, off[block] + np.flatnonzero(fixed)] @ values[fixed])
    free = np.flatnonzero(~fixed)
    keep = np.concatenate(
        [np.arange(off[block]), off[block] + free, np.arange(off[block + 1], off[-1])]
    )
    b = problem.lights[block]
    renumber = -np.ones(b.size, int)
    renumber[free] = np.arange(len(free))
    adj, wts = b.adjacency, b.adjacency_weights
    if adj is not None:
        both = ~fixed[adj[:, 0]] & ~fixed[adj[:, 1]]
        adj = renumber[adj[both]]
        wts = None if wts is None else np.asarray(wts)[both]
    part = {
        k: None if getattr(b, k) is None else np.asarray(getattr(b, k))[free]
        for k in ("prior", "prior_weight", "lower")
    }
    lights = list(problem.lights)
    lights[block] = dataclasses.replace(
        b, size=len(free), adjacency=adj, adjacency_weights=wts, **part
    )
    return dataclasses.replace(
        problem, indirect=problem.indirect + e_fix, transfer=f[:, keep], lights=lights
    )


def fix_window_cells(scan: Path, work: Path) -> None:
    """The run's problem re-solved with some of the (first) window's cells fixed at the
    truth: those the photos see cleanly in part (>= 8 texels unsaturated and never
    saturated), those any photo sees, those none sees, and every lit cell. Printed: each
    other light's power error (against what leaves its fitting), scaled from the run's
    evaluation by the re-solve's ratio, and the tube's red over blue; which cells a
    light's colour depends on (docs/invert.md, session 31)."""
    from reroom.invert.basis import CubemapBasis
    from reroom.invert.window_env import latlong_directions

    res = _invert(scan, work / "fix_window_cells")
    report = evaluate_invert(scan, work / "fix_window_cells")
    prob = res.problem
    k = np.asarray(report["radiance_scale"], float)
    wi = next(i for i, b in enumerate(prob.lights) if b.kind == "window")
    wname = prob.lights[wi].name
    truth_of = {e["name"]: e for e in report["lights"]}
    true_cells = np.asarray(truth_of[wname]["distribution"]["true_cells"], float) * k
    basis = CubemapBasis(res.cubemap_n)
    _, ph, _, _ = _true_window_photos(scan)
    cell = basis.cell_of(latlong_directions(ph.height).reshape(-1, 3))
    unsat = np.isfinite(ph.mean.reshape(-1, 3)).all(axis=1) & (ph.count.ravel() > 0)
    clean = unsat & (ph.saturated.ravel() == 0)
    seen = (ph.count.ravel() > 0) | (ph.saturated.ravel() > 0)
    n_clean = np.bincount(cell[clean], minlength=basis.size)
    n_seen = np.bincount(cell[seen], minlength=basis.size)
    lit = true_cells @ LUMA > 0
    errors = _power_errors(report)
    min_bin_support = InvertOptions(**INVERT_EXTRA).min_bin_support
    base = _powers(res, min_bin_support)
    others = [n for n in errors if n != wname]
    line = next((b.name for b in prob.lights if b.kind == "line"), None)
    print(f"| `{wname}`'s cells fixed at the truth | cells | " + " | ".join(others), end="")
    print(" | line red / blue |" if line else " |")
    print("|---|---|" + "---|" * (len(others) + (1 if line else 0)))
    variants = {
        "none (the run)": np.zeros(basis.size, bool),
        "seen cleanly in part (>= 8 clean texels)": (n_clean >= 8) & lit,
        "seen by any photo": (n_seen > 0) & lit,
        "seen by no photo": (n_seen == 0) & lit,
        "every lit cell": lit,
    }
    for label, sub in variants.items():
        if sub.any():
            sol = solve_lighting(
                _with_cells_fixed(prob, wi, sub, true_cells),
                res.solve_options if hasattr(res, "solve_options") else SolveOptions(),
            )
            full = np.array(true_cells)
            full[~sub] = sol.intensities[wname]
            sol = dataclasses.replace(sol, intensities={**sol.intensities, wname: full})
            after = _powers(dataclasses.replace(res, solve=sol), min_bin_support)
            err = {n: (1 + errors[n]) * after[n] / base[n] - 1 for n in others}
        else:
            err = {n: errors[n] for n in others}
        row = f"| {label} | {int(sub.sum())} | " + " | ".join(_pct(err[n]) for n in others)
        if line:
            e = 1 + err[line]
            row += f" | {e[0] / e[2]:.2f}"
        print(row + " |", flush=True)


def _window_cells_after(scan: Path, report: dict, res, res2, min_bin_support: float) -> None:
    """Each window's cells, the run's and a re-solve's, against the truth's (luminance / k).

    The distribution error of both, then the cells whose true luminance is largest and
    those the re-solve moved most: where a window's light comes from, as solved. With
    cells finer than the thesis's (``cubemap_n`` a multiple of 4), also the error of both
    summed to the 4 x 4 cells (solid-angle weighted) against the truth's 4 x 4 cells.
    """
    from reroom.invert.evaluate import true_window_cells

    k = np.asarray(report["radiance_scale"], float)
    truth_of = {e["name"]: e for e in report["lights"]}
    ents = {e["name"]: e for e in light_entries(res, None, min_bin_support)}
    ents2 = {e["name"]: e for e in light_entries(res2, None, min_bin_support)}
    for name, e2 in ents2.items():
        if e2["type"] != "window" or name not in truth_of:
            continue
        truth = np.asarray(truth_of[name]["distribution"]["true_cells"], float)
        runs = {
            "the run": np.asarray(ents[name]["distribution"]["cells"], float),
            "re-solved": np.asarray(e2["distribution"]["cells"], float),
        }
        l2 = {
            label: distribution_relative_l2(c, truth, k, truth @ LUMA > 0)
            for label, c in runs.items()
        }
        print(
            f"\n`{name}`'s cells, relative L2 (luminance / k, cells with light): the run "
            f"{100 * l2['the run']:.1f} %, re-solved {100 * l2['re-solved']:.1f} %\n"
        )
        n = int(e2["distribution"]["n"])
        if n > 4 and n % 4 == 0:
            scene_dir = scan / "ground_truth" / "scene"
            gt = json.loads((scene_dir / "scene.json").read_text())
            t_light = next(x for x in gt["lights"] if x["name"] == truth_of[name]["truth"])
            truth4, _ = true_window_cells(t_light, scene_dir, n=4)
            l4 = {
                label: distribution_relative_l2(
                    _cells_summed(c, n, 4), truth4, k, truth4 @ LUMA > 0
                )
                for label, c in runs.items()
            }
            print(
                f"summed to the 4 x 4 cells: the run {100 * l4['the run']:.1f} %, re-solved "
                f"{100 * l4['re-solved']:.1f} %\n"
            )
        lum = {label: (c / k) @ LUMA for label, c in runs.items()}
        t = truth @ LUMA
        moved = np.abs(lum["re-solved"] - lum["the run"])
        rows = list(np.argsort(-t)[:8]) + list(np.argsort(-moved)[:6])
        print("| cell | true | the run | re-solved |\n|---|---|---|---|")
        for j in dict.fromkeys(int(r) for r in rows):
            print(f"| {j} | {t[j]:.2f} | {lum['the run'][j]:.2f} | {lum['re-solved'][j]:.2f} |")


def _cells_summed(cells: np.ndarray, n: int, coarse_n: int) -> np.ndarray:
    """``(6 n^2, 3)`` cube cells summed to ``coarse_n`` cells per face edge: each coarse
    cell the solid-angle weighted mean of the fine cells whose centres fall in it."""
    from reroom.invert.basis import CubemapBasis

    fine, coarse = CubemapBasis(n), CubemapBasis(coarse_n)
    parent = coarse.cell_of(fine.cell_directions())
    area = fine.cell_solid_angles()
    w = np.bincount(parent, area, coarse.size)
    cols = [np.bincount(parent, area * cells[:, j], coarse.size) for j in range(3)]
    return np.stack(cols, 1) / np.maximum(w, 1e-300)[:, None]


def drop_cluster(scan: Path, work: Path, name: str) -> None:
    """The run's problem re-solved without one cluster's receivers, or with its colour moved.

    ``reroom invert`` once (HDR radiance, the scan's lights); then the same eq. 5.7
    problem solved (a) without the receivers of cluster ``name`` and (b) with their
    observed radiance recoloured so that the run's albedo of that cluster gets the
    truth's chroma (its luminance kept). Printed: every light's power error and the other
    albedos, scaled from the run's evaluation by each re-solve's ratios. Does a light's
    colour follow that cluster's albedo error?
    """
    out = work / "drop_cluster"
    res = _invert(scan, out)
    report = evaluate_invert(scan, out)
    prob = res.problem
    c = prob.cluster_names.index(name)
    rows = prob.cluster == c
    min_bin_support = InvertOptions(**INVERT_EXTRA).min_bin_support
    base = _powers(res, min_bin_support)
    errors = _power_errors(report)
    truth = np.asarray(report["clusters"][name]["truth"], float)
    solved = res.solve.albedo[c]
    tilt = (truth / float(truth @ LUMA)) / (solved / float(solved @ LUMA))
    radiance = prob.radiance.copy()
    radiance[rows] *= tilt  # rho is proportional to the radiance: the truth's chroma
    transfer = scipy.sparse.csr_matrix(prob.transfer)
    variants = {
        f"without {name}": dataclasses.replace(
            prob,
            radiance=prob.radiance[~rows],
            indirect=prob.indirect[~rows],
            cluster=prob.cluster[~rows],
            transfer=transfer[~rows],
        ),
        f"{name} recoloured x {'/'.join(f'{x:.4f}' for x in tilt)}": dataclasses.replace(
            prob, radiance=radiance
        ),
    }
    cols = list(variants)
    print(f"\n| | the run | {' | '.join(cols)} |\n|---|---|" + "---|" * len(cols))
    sols = {}
    for label, p in variants.items():
        sol = solve_lighting(p, SolveOptions())
        sols[label] = (
            sol,
            _powers(dataclasses.replace(res, problem=p, solve=sol), min_bin_support),
        )
    for k, cname in enumerate(prob.cluster_names):
        if cname not in CLUSTERS:
            continue
        run_err = np.asarray(report["clusters"][cname]["relative_error"])
        cells = [
            _pct((1 + run_err) * sol.albedo[k] / res.solve.albedo[k] - 1)
            if np.all(np.isfinite(sol.albedo[k]))
            else "-"
            for sol, _ in sols.values()
        ]
        print(f"| {cname} | {_pct(run_err)} | {' | '.join(cells)} |")
    for lname in base:
        if lname in errors:
            cells = [
                _pct((1 + errors[lname]) * pw[lname] / base[lname] - 1) for _, pw in sols.values()
            ]
            print(f"| {lname} | {_pct(errors[lname])} | {' | '.join(cells)} |")


def per_light(scan: Path, work: Path, name: str, spp: int = 256) -> None:
    """The truth run's irradiance light by light at ``name``'s receivers (see the notes)."""
    import copy

    from reroom.render import mitsuba
    from reroom.render.frames import probe_radiance
    from reroom.synth.scene import load_scene_description, mitsuba_scene_dict

    res, src, out = _truth_problem(scan, work, SolveOptions())
    prob, sol, rows = res.problem, res.solve, res.problem_vertices
    report = evaluate_invert(src, out)
    names = [b.name for b in prob.lights]
    if name not in names:
        raise SystemExit(f"--per-light: no true light {name!r} (lights: {', '.join(names)})")
    _, true_albedo, _ = _truth(scan)
    f = scipy.sparse.csr_matrix(prob.transfer)
    off = np.concatenate([[0], np.cumsum([b.size for b in prob.lights])]).astype(int)
    scene_dir = scan / "ground_truth" / "scene"
    true_int = _true_intensities(scan, report, sol, leaving=True, profiles=True)
    model = {
        b.name: np.asarray(f[:, off[i] : off[i + 1]] @ true_int[b.name])
        for i, b in enumerate(prob.lights)
    }
    solved = {
        b.name: np.asarray(f[:, off[i] : off[i + 1]] @ sol.intensities[b.name])
        for i, b in enumerate(prob.lights)
    }
    pts, nrm = _probe_points(scan, rows)
    rho_v = np.maximum(true_albedo[rows], 1e-3)
    desc0 = load_scene_description(scene_dir)
    mi = mitsuba()
    traced: dict[str, np.ndarray] = {}
    for key in [*names, "direct", "all"]:
        desc = copy.deepcopy(desc0)
        if key in names:
            for light in desc["lights"]:
                light["on"] = light["name"] == key
        if key != "all":
            desc["integrator"] = {"type": "path", "max_depth": 2}
        radiance, _ = probe_radiance(
            mi.load_dict(mitsuba_scene_dict(desc, scene_dir)), pts, nrm, spp, seed=1
        )
        traced[key] = np.pi * radiance / rho_v
    traced_ind = traced["all"] - traced["direct"]
    lum = LUMA
    share = (traced[name] @ lum) / np.maximum(traced["all"] @ lum, 1e-300)

    def ratio(a: np.ndarray, b: np.ndarray) -> str:
        if float(b.sum(0) @ lum) <= 1e-9 * float(traced["all"].sum(0) @ lum):
            return "-"  # the light sends these receivers nothing, in truth
        return "/".join(f"{x:.3f}" for x in a.sum(0) / np.maximum(b.sum(0), 1e-300))

    print(
        f"\nReceivers by `{name}`'s share of the path tracer's irradiance (luminance); per "
        "light its share there, the model at the true intensities / path tracer and the "
        "solved / path tracer (r/g/b sums):\n"
    )
    print(
        "| share of `"
        + name
        + "` | receivers | light | its share | model at truth / traced | solved / traced |"
    )
    print("|---|---|---|---|---|---|")
    bands = [(0.3, 1.01), (0.1, 0.3), (0.03, 0.1), (0.0, 0.03)]
    for lo, hi in bands:
        sel = (share >= lo) & (share < hi)
        if not sel.any():
            continue
        total = float((traced["all"][sel] @ lum).sum())
        for n in names:
            sh = float((traced[n][sel] @ lum).sum()) / total
            print(
                f"| {lo:.2f}-{min(hi, 1):.2f} | {int(sel.sum())} | {n} | {sh:.3f} | "
                f"{ratio(model[n][sel], traced[n][sel])} | {ratio(solved[n][sel], traced[n][sel])} |"
            )
        sh = float((traced_ind[sel] @ lum).sum()) / total
        print(
            f"| {lo:.2f}-{min(hi, 1):.2f} | {int(sel.sum())} | E_ind | {sh:.3f} | "
            f"{ratio(prob.indirect[sel], traced_ind[sel])} | (fixed) |"
        )
    bands = _wall_bands(prob, pts)
    if bands:
        # The walls by height: where `--at-truth` finds the solution beating the truth.
        print(
            "\nThe walls by height above their lowest receiver; per light its share, the "
            "model at the true intensities / path tracer and the solved / path tracer:\n"
        )
        print(
            "| wall, m up | receivers | light | its share | model at truth / traced | solved / traced |"
        )
        print("|---|---|---|---|---|---|")
        for lo, hi, sel in bands:
            if not sel.any():
                continue
            total = float((traced["all"][sel] @ lum).sum())
            for n in names:
                print(
                    f"| {lo:g}-{hi:g} | {int(sel.sum())} | {n} | "
                    f"{float((traced[n][sel] @ lum).sum()) / total:.3f} | "
                    f"{ratio(model[n][sel], traced[n][sel])} | {ratio(solved[n][sel], traced[n][sel])} |"
                )
            print(
                f"| {lo:g}-{hi:g} | {int(sel.sum())} | E_ind | "
                f"{float((traced_ind[sel] @ lum).sum()) / total:.3f} | "
                f"{ratio(prob.indirect[sel], traced_ind[sel])} | (fixed) |"
            )
    for i, b in enumerate(prob.lights):
        if b.kind != "window":
            continue
        sel = (share >= 0.1) & (share < 0.3)
        if not sel.any():
            continue
        weight = np.asarray(f[:, off[i] : off[i + 1]][np.flatnonzero(sel)].sum(axis=0)).ravel()
        t, s = true_int[b.name], sol.intensities[b.name]
        sent = weight[:, None] * t
        order = np.argsort(-(sent @ lum))[:8]
        print(
            f"\n`{b.name}`'s cells that send the 0.10-0.30 band most light (fraction of the "
            "window's light there, true and solved r/g/b):\n"
        )
        print("| cell | fraction | true | solved | solved / true |\n|---|---|---|---|---|")
        for c in order:
            print(
                f"| {c} | {float(sent[c] @ lum) / float(sent.sum(0) @ lum):.3f} | "
                + " | ".join("/".join(f"{x:.3f}" for x in v) for v in (t[c], s[c]))
                + " | "
                + "/".join(f"{x:.2f}" for x in s[c] / np.maximum(t[c], 1e-12))
                + " |"
            )


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("scan", type=Path)
    ap.add_argument("--work", type=Path, default=Path("/tmp/reroom_invert_diagnosis"))
    ap.add_argument("--reprobe", type=int, default=0, help="samples per vertex")
    ap.add_argument("--eval-dir", type=Path, help="where --reprobe writes the linked scan")
    ap.add_argument("--swaps", action="store_true")
    ap.add_argument("--solve", default="{}", help="SolveOptions as JSON for --swaps")
    ap.add_argument(
        "--invert", default="{}", help="InvertOptions as JSON, e.g. '{\"near_distance\": 0}'"
    )
    ap.add_argument(
        "--truth-run", action="store_true", help="invert with true radiance and true lights"
    )
    ap.add_argument(
        "--truth-resolves", action="store_true", help="the truth run re-solved, options varied"
    )
    ap.add_argument(
        "--resolves", action="store_true", help="--truth-resolves on the scan's own run"
    )
    ap.add_argument(
        "--blurred-truth", action="store_true", help="the truth run on a one-ring-blurred truth"
    )
    ap.add_argument(
        "--scales", action="store_true", help="k from the vertices and from the exposures"
    )
    ap.add_argument("--light-swaps", action="store_true")
    ap.add_argument(
        "--window-photos", action="store_true", help="what the photos through the window show"
    )
    ap.add_argument("--indirect", action="store_true")
    ap.add_argument("--at-truth", action="store_true", help="the truth run's model at the truth")
    ap.add_argument(
        "--interpolation", action="store_true", help="radiance inside faces vs interpolated"
    )
    ap.add_argument(
        "--subdivide", default="", help="comma-separated edge lengths (m): E_ind between vertices"
    )
    ap.add_argument("--bands", action="store_true")
    ap.add_argument("--bin-by", type=Path, help="independent truth PLY for --bands")
    ap.add_argument(
        "--hdr-variants", action="store_true", help="--bands for other HDR reprojection choices"
    )
    ap.add_argument("--rows", type=int, default=4, help="--swaps: only the first N variants")
    ap.add_argument(
        "--render-consistency",
        action="store_true",
        help="each light rendered alone vs the solve's transfer (with and without clearance)",
    )
    ap.add_argument(
        "--unobserved", action="store_true", help="what eq. 5.9's fill of unseen surfaces does"
    )
    ap.add_argument(
        "--indirect-scale", default="", help="comma-separated E_ind scales for the truth run"
    )
    ap.add_argument(
        "--resolve-variants",
        action="store_true",
        help="the run's problem re-solved with the subset and the smoothness varied",
    )
    ap.add_argument("--decimals", type=int, default=0, help="decimals of the printed %%")
    ap.add_argument("--fireflies", type=int, default=None, help="input frame to render")
    ap.add_argument("--profile", default="", help="a light's solved profile against the truth")
    ap.add_argument("--shares", default="", help="who lights the receivers of a light's bins")
    ap.add_argument(
        "--shares-true-radiance", action="store_true", help="--shares on the truth's radiance"
    )
    ap.add_argument(
        "--per-light", default="", help="the truth run light by light at a light's receivers"
    )
    ap.add_argument("--drop-cluster", default="", help="re-solve without a cluster's receivers")
    ap.add_argument(
        "--fix-at-truth",
        default="",
        help="comma-separated area, point or line lights fixed at the truth",
    )
    ap.add_argument(
        "--fix-with-true-radiance",
        action="store_true",
        help="--fix-at-truth on the true per-vertex radiance instead of the HDR mesh",
    )
    ap.add_argument(
        "--fix-window-cells",
        action="store_true",
        help="re-solve with the window's cells fixed at the truth, by what the photos see",
    )
    ap.add_argument("--spp", type=int, default=64, help="samples per pixel for --fireflies")
    args = ap.parse_args()
    DECIMALS[0] = args.decimals
    args.work.mkdir(parents=True, exist_ok=True)
    INVERT_EXTRA.update(json.loads(args.invert))
    if args.reprobe:
        if args.eval_dir is None:
            ap.error("--reprobe needs --eval-dir")
        reprobe(args.scan, args.reprobe, args.eval_dir)
    if args.swaps:
        swaps(args.scan, args.work, SolveOptions(**json.loads(args.solve)), args.rows)
    if args.truth_run:
        truth_run(args.scan, args.work, SolveOptions(**json.loads(args.solve)))
    if args.scales:
        radiance_scales(args.scan)
    if args.truth_resolves:
        resolves(args.scan, args.work, SolveOptions(**json.loads(args.solve)), truth=True)
    if args.resolves:
        resolves(args.scan, args.work, SolveOptions(**json.loads(args.solve)), truth=False)
    if args.blurred_truth:
        blurred_truth(args.scan, args.work, SolveOptions(**json.loads(args.solve)))
    if args.at_truth:
        at_truth(args.scan, args.work, SolveOptions(**json.loads(args.solve)))
    if args.indirect_scale:
        scales = [float(x) for x in args.indirect_scale.split(",")]
        indirect_scales(args.scan, args.work, SolveOptions(**json.loads(args.solve)), scales)
    if args.unobserved:
        unobserved(args.scan, args.work, SolveOptions(**json.loads(args.solve)))
    if args.interpolation:
        interpolation(args.scan)
    if args.light_swaps:
        light_swaps(args.scan, args.work)
    if args.resolve_variants:
        resolve_variants(args.scan, args.work, SolveOptions(**json.loads(args.solve)))
    if args.render_consistency:
        render_consistency(args.scan, args.work, clearance=False)
        render_consistency(args.scan, args.work, clearance=True)
    if args.window_photos:
        window_photos(args.scan)
    if args.indirect:
        indirect(args.scan, args.work)
    if args.subdivide:
        subdivided_indirect(args.scan, args.work, [float(x) for x in args.subdivide.split(",")])
    if args.bands:
        bands(args.scan, args.bin_by)
    if args.hdr_variants:
        hdr_variants(args.scan, args.work, args.bin_by)
    if args.fireflies is not None:
        fireflies(args.scan, args.fireflies, args.work, args.spp)
    if args.profile:
        profile_bins(args.scan, args.profile)
    if args.shares:
        bin_shares(args.scan, args.work, args.shares, args.shares_true_radiance)
    if args.per_light:
        per_light(args.scan, args.work, args.per_light)
    if args.drop_cluster:
        drop_cluster(args.scan, args.work, args.drop_cluster)
    if args.fix_window_cells:
        fix_window_cells(args.scan, args.work)
    if args.fix_at_truth:
        fix_at_truth(
            args.scan, args.work, args.fix_at_truth.split(","), args.fix_with_true_radiance
        )


if __name__ == "__main__":
    main()
