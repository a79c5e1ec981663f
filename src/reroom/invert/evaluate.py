"""Evaluation of ``reroom invert`` against a synthetic scan's ground truth.

The only code of :mod:`reroom.invert` that reads ``ground_truth/``. What is compared:

* **Cluster albedo**: each solved cluster (wall, floor, ceiling) against the mean true
  albedo of the vertices the truth labels so (``vertices.ply``: ``label``, ``albedo``),
  relative error per channel. The floor's wood texture makes its truth a mean.
* **Per-vertex albedo**: every vertex solved per vertex, ``|rho - rho_true| / rho_true``
  pooled over channels: median and 90th percentile, also for the clustered vertices alone.
* **Light power**: the HDR radiance has a global per-channel scale of its own (the HDR
  stage fixes the scale by a reference frame), so solved intensities are first divided
  by ``k_c = sum(Lbar_c) / sum(L_true_c)`` over the observed clustered vertices. Each
  solved light is matched to the nearest true light of its type. True powers: area
  ``pi L A``; point ``power * color / mean(color)`` (the generator's convention);
  window ``A * integral scale * hdri(d) cos dw`` over the directions entering the
  room; line: the power of the *effective* profile below (tube between baffles).
* **Distributions** (issue #5: relative L2 in the solved basis). The truth is converted
  into the solved light's basis, about the solved axis (point), ``d_perp`` (line) or
  cube map (window), as the light looks from outside its fixture:

  - point (:func:`true_point_profile`): per inclination bin, the solid-angle mean of
    ``I_true(d) V(d)`` with ``I_true`` exactly as the generator's goniometric emitter
    evaluates it and ``V`` a ray cast from the light against the fixture;
  - line (:func:`true_line_profile`): per ``(theta, phi)`` bin of the solved
    :class:`~reroom.invert.basis.LineBasis`, ``2 r L`` per metre times the fraction of
    the tube's projected area (along its length and across its width) from which the
    direction is not blocked by the fixture, ``cos^2(phi)``-weighted over the bin so that
    its power is the power leaving the fixture (light out of a channel's open ends
    included);
  - window (:func:`true_window_cells`): the HDRI (times ``scale``) averaged per cube
    cell over the directions that leave the room through the window. A solved sun
    (:mod:`reroom.invert.sun`) is folded into its cell for that comparison and compared
    with the HDRI's own (:func:`true_sun`: angle, irradiance).

  **The fixture** is every true part within :data:`FIXTURE_RADIUS` (0.3 m) of the light
  except the light's own part and the room's shell (walls, floor, ceiling, reveals,
  doors, baseboards): the shell is what the solve fits as receivers, so light reaching
  it is part of the distribution, while a shade, baffle, housing or lamp pole close to
  the light shapes it. Occluders farther away (furniture) are the scene's business,
  not the light's. ``distribution_relative_l2 = ||I_est / k - I_true|| / ||I_true||``
  over the bins (cells), on the Rec. 709 luminance of the per-channel intensities,
  over all bins and over the bins the solve saw (nonzero transfer to a clustered
  vertex, recomputed here by the pipeline's own transfer functions on the scan mesh,
  since ``scene.json`` does not record it), and over the *well-seen* bins (summed
  transfer at least 1 % of the largest bin's); windows over the cells the window shows.
  Line lights also get ``relative_l2_theta``: estimate and truth each reduced to
  ``theta`` (the power-weighted mean over ``phi``), comparable across ``phi_bins``.
  A point light whose bins were split after the solve (``split_from_bins``,
  :mod:`reroom.invert.fine_profiles`) also gets ``relative_l2_solved_bins``: the
  exported profile's flux per bin of the solve against the truth at those bins.

:func:`run_invert_true_radiance` is an **evaluation-only shortcut**: it runs the
pipeline with the true per-vertex radiance instead of the HDR mesh's, to measure the
solve independently of HDR errors.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from reroom.errors import ScanError
from reroom.invert.basis import CubemapBasis, InclinationBasis, LineBasis
from reroom.invert.export import (
    area_light_power,
    inclination_power,
    line_light_power,
    line_profile_grid,
)
from reroom.invert.fine_profiles import coarsen
from reroom.invert.line_fixture import line_open_fraction
from reroom.invert.sun import fold_sun_into_cells
from reroom.io.mesh import read_ply

__all__ = [
    "FIXTURE_RADIUS",
    "distribution_relative_l2",
    "evaluate_invert",
    "hidden_as_unobserved",
    "lights_from_truth",
    "run_invert_true_radiance",
    "true_line_profile",
    "true_point_intensity",
    "true_point_profile",
    "true_sun",
    "true_window_cells",
    "true_window_power",
]

#: Metres around a light within which true parts count as its fixture (see module notes):
#: the synthetic shade's rim is 0.26 m from its bulb, the tube's baffles 0.1 m from it.
FIXTURE_RADIUS = 0.3
#: Part labels of the room's shell, never part of a fixture: they are the receivers.
_SHELL_LABELS = frozenset({"wall", "floor", "ceiling", "window", "door", "baseboard"})
#: A bin is "well seen" when its transfer, summed over the clustered vertices, is at least
#: this fraction of the largest bin's.
_WELL_SEEN = 0.01
#: Rec. 709 luminance weights: one number per bin from the per-channel intensities.
_LUMA = np.array([0.2126, 0.7152, 0.0722])

_CLUSTER_LABELS = {"wall": 0, "floor": 1, "ceiling": 2}


def _truth(scan: Path) -> tuple[Any, dict, Path]:
    gt = scan / "ground_truth"
    if not (gt / "vertices.ply").is_file():
        raise ScanError(gt / "vertices.ply", "is missing (evaluation needs a synthetic scan)")
    verts = read_ply(gt / "vertices.ply")
    scene = json.loads((gt / "scene" / "scene.json").read_text())
    return verts, scene, gt / "scene"


def _window_texels(
    light: dict, scene_dir: Path
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every texel of a true window's HDRI: direction, solid angle, ``max(0, -d . n_in)``
    and radiance.

    The HDRI is equirectangular with the zenith at the top row, the centre looking along
    +X and ``u = 0.5 - atan2(d_y, d_x) / 2 pi`` (``docs/formats.md``), rotated by
    ``rotation_deg`` about +Z, times ``scale``. A ray from the room leaving along ``d``
    sees ``radiance``; it leaves through the window where ``cos > 0``. Summing over the
    texels integrates the map exactly as the renderer's nearest texel would see it: a
    sun of three texels (``city.exr``) carries 17 % of the map's light, which random
    directions (400k, the quadrature before session 21) hit two or three times.
    """
    from reroom.invert.window_env import latlong_directions, latlong_solid_angles
    from reroom.io.images import read_exr

    img = read_exr(scene_dir / light["hdri_file"])[..., :3]
    h, w = img.shape[:2]
    if w != 2 * h:
        raise ScanError(scene_dir / light["hdri_file"], f"is {w}x{h}, not a 2:1 lat-long map")
    d = latlong_directions(h).reshape(-1, 3)
    rot = np.deg2rad(light.get("rotation_deg", 0.0))
    c, s = np.cos(rot), np.sin(rot)
    d = d @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # turn by +rot about Z
    n_in = np.asarray(light["normal"], float)
    cos = np.maximum(-(d @ n_in), 0.0)
    rad = light.get("scale", 1.0) * np.maximum(img.reshape(-1, 3).astype(np.float64), 0.0)
    return d, latlong_solid_angles(h).ravel(), cos, rad


def true_window_power(light: dict, scene_dir: Path) -> np.ndarray:
    """Flux through a true window: ``A * integral scale * hdri(d) cos dw`` (over the texels,
    :func:`_window_texels`)."""
    corners = np.asarray(light["corners"], float)
    area = np.linalg.norm(corners[1] - corners[0]) * np.linalg.norm(corners[3] - corners[0])
    _, omega, cos, rad = _window_texels(light, Path(scene_dir))
    return area * ((omega * cos)[:, None] * rad).sum(axis=0)


def true_window_cells(light: dict, scene_dir: Path, n: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """The true window's light in the solved cube-map basis.

    Each cell holds the mean true radiance (HDRI times ``scale``) over the part of the
    cell whose directions leave the room through the window (``d . n_in < 0``), weighted
    by solid angle over the HDRI's texels: that is what the cell's basis light stands
    for in the solve, a partly shown cell included.

    Returns
    -------
    cells : ndarray, shape (6 n^2, 3)
        Mean radiance per cell (0 where the window shows nothing).
    shown : ndarray of bool, shape (6 n^2,)
        Cells with at least one texel through the window.
    """
    basis = CubemapBasis(n)
    d, omega, cos, rad = _window_texels(light, Path(scene_dir))
    out = cos > 0
    cell = basis.cell_of(d[out])
    area = np.bincount(cell, omega[out], minlength=basis.size)
    total = np.stack(
        [np.bincount(cell, omega[out] * rad[out, c], minlength=basis.size) for c in range(3)],
        axis=1,
    )
    cells = np.divide(total, area[:, None], out=np.zeros_like(total), where=area[:, None] > 0)
    return cells, area > 0


def true_sun(light: dict, scene_dir: Path, radius_deg: float = 2.0) -> dict[str, Any] | None:
    """The sun of a true window's HDRI, if it has one that shines through the window.

    The brightest texel the window shows and the texels within ``radius_deg`` of it
    brighter than a tenth of it: their irradiance (sum of radiance x solid angle, per
    channel) and luminance-weighted direction, with their share of the window's flux.
    None when that blob is under 2 % of the flux (an overcast sky has no sun).
    """
    d, omega, cos, rad = _window_texels(light, Path(scene_dir))
    lum = rad @ _LUMA
    shown = cos > 0
    if not shown.any():
        return None
    k = int(np.flatnonzero(shown)[np.argmax(lum[shown])])
    blob = shown & (d @ d[k] > np.cos(np.deg2rad(radius_deg))) & (lum > 0.1 * lum[k])
    irradiance = (omega[blob, None] * rad[blob]).sum(axis=0)
    share = float(((omega * cos * lum)[blob]).sum() / max((omega * cos * lum).sum(), 1e-300))
    if share < 0.02:
        return None
    direction = (omega[blob] * lum[blob]) @ d[blob]
    return {
        "direction": (direction / np.linalg.norm(direction)).tolist(),
        "irradiance": irradiance.tolist(),
        "share_of_flux": share,
    }


def _fixture_caster(
    scene_dir: Path, lo: np.ndarray, hi: np.ndarray, exclude: set[str], radius: float
):
    """A ray caster of the true parts that can belong to a fixture (or ``None``).

    Parts whose bounding box comes within ``radius`` of the box ``[lo, hi]`` (the light's
    position or its tube), minus ``exclude`` and the room's shell (:data:`_SHELL_LABELS`).
    """
    from reroom.rays import RayCaster

    scene = json.loads((scene_dir / "scene.json").read_text())
    verts, faces, base = [], [], 0
    for part in scene["parts"]:
        if part["name"] in exclude or part.get("label") in _SHELL_LABELS:
            continue
        m = read_ply(scene_dir / part["file"])
        v = np.asarray(m.vertices, float)
        if len(v) == 0 or len(m.faces) == 0:
            continue
        if (v.min(axis=0) > hi + radius).any() or (v.max(axis=0) < lo - radius).any():
            continue
        verts.append(v)
        faces.append(np.asarray(m.faces, np.int64) + base)
        base += len(v)
    if not verts:
        return None
    # A tiny offset: rays start on the tube's surface or at the bulb, never on a part.
    return RayCaster(np.concatenate(verts), np.concatenate(faces), eps=1e-6)


def true_point_intensity(light: dict, scene_dir: Path):
    """The true point light's radiant intensity as a function of direction.

    Mirrors :func:`reroom.synth.lighting.point_emitter`, which builds
    :func:`reroom.render.emitters.goniometric_light` with ``flux=power``: the same
    table (a 2 x 2 grid of ones when isotropic, else the IES file resampled on the
    emitter's node grid, chosen by the emitter's own ``_grid_size``), the same scale
    ``power / table flux``, the same luminaire frame (nadir ``-up``) and bilinear lookup
    in ``(theta from nadir, phi)``, times ``color / mean(color)``. So the intensity
    integrates to ``power * color / mean(color)`` over the sphere (tested).

    Returns
    -------
    callable
        ``f(directions (N, 3) unit, world) -> (N, 3)`` intensity per channel (W/sr,
        the scene's units).
    """
    from reroom.io.ies import IntensityGrid, _bilinear, read_ies
    from reroom.render.emitters import _grid_size, luminaire_frame
    from reroom.synth.lighting import normalized_color

    color = normalized_color(light.get("color", [1.0, 1.0, 1.0]))
    up = np.asarray(light.get("up", [0.0, 0.0, 1.0]), float)
    frame = luminaire_frame(nadir=-up)
    if light.get("profile", "isotropic") == "isotropic":
        grid = IntensityGrid(np.array([0.0, 180.0]), np.array([0.0, 360.0]), np.ones((2, 2)))
    else:
        prof = read_ies(Path(scene_dir) / light["profile_file"])
        n_theta = _grid_size(prof.vertical_angles, 180.0)
        n_phi = 2 if prof.is_axially_symmetric else _grid_size(prof.horizontal_angles, 360.0)
        grid = prof.to_tabulated(n_theta, n_phi)
    scale = float(light["power"]) / grid.total_flux()

    def intensity(directions: np.ndarray) -> np.ndarray:
        local = np.asarray(directions, float) @ frame  # frame's columns: luminaire axes
        local /= np.linalg.norm(local, axis=1, keepdims=True)
        theta = np.degrees(np.arccos(np.clip(-local[:, 2], -1.0, 1.0)))
        phi = np.mod(np.degrees(np.arctan2(local[:, 1], local[:, 0])), 360.0)
        table = _bilinear(grid.theta_deg, grid.phi_deg, grid.values.T, theta, phi)
        return scale * table[:, None] * color[None, :]

    return intensity


def true_point_profile(
    light: dict,
    scene_dir: str | Path,
    axis: np.ndarray,
    bins: int = 32,
    samples: int = 4096,
    fixture_radius: float = FIXTURE_RADIUS,
    seed: int = 0,
) -> np.ndarray:
    """The true point light's effective intensity profile in the solved inclination basis.

    Per bin of ``theta`` (from ``axis``, the solved light's axis, to the direction from
    the light to the receiver), the solid-angle mean over the bin's band of
    ``I_true(d) V(d)``: ``I_true`` from :func:`true_point_intensity`, ``V`` whether the
    ray from the true position along ``d`` leaves the fixture (no hit within
    ``fixture_radius`` of the true parts named in the module notes).

    Parameters
    ----------
    light : dict
        The true light (``ground_truth/scene/scene.json``).
    scene_dir : path
        ``ground_truth/scene``.
    axis : ndarray, shape (3,)
        The solved light's axis.
    bins : int
    samples : int
        Directions per bin, jittered-stratified in ``cos theta`` and azimuth.
    fixture_radius : float
        0 gives the unoccluded profile.
    seed : int

    Returns
    -------
    ndarray, shape (bins, 3)
        Intensity per channel (W/sr, the scene's units).
    """
    from reroom.invert.point_fixture import inclination_directions

    scene_dir = Path(scene_dir)
    pos = np.asarray(light["position"], float)
    d = inclination_directions(axis, InclinationBasis(bins), samples, seed).reshape(-1, 3)
    value = true_point_intensity(light, scene_dir)(d)
    if fixture_radius > 0:
        caster = _fixture_caster(scene_dir, pos, pos, set(), fixture_radius)
        if caster is not None:
            value[caster.occluded(pos, d, tmax=fixture_radius)] = 0.0
    return value.reshape(bins, -1, 3).mean(axis=1)


def true_line_profile(
    light: dict,
    scene_dir: str | Path,
    d_perp: np.ndarray,
    bins: int = 32,
    samples: int = 1024,
    angles: int = 4,
    fixture_radius: float = FIXTURE_RADIUS,
    seed: int = 0,
    phi_bins: int = 1,
    fold: bool = True,
    phi_angles: int = 64,
) -> np.ndarray:
    """The true tube's effective intensity per metre in the solved ``(theta, phi)`` basis.

    The same integral as the inverse rendering's shape prior
    (:func:`reroom.invert.line_fixture.line_open_fraction`), over the true parts. A
    bare tube of radius ``r`` and radiance ``L`` sends ``2 r L cos(phi)`` per metre
    (projected area times radiance) along a direction at angle ``phi`` from the plane
    perpendicular to it, i.e. ``i = 2 r L`` in the line model ``i(theta, phi) cos(phi)``
    (:class:`reroom.invert.basis.LineBasis`). In a fixture, each direction gets ``2 r
    L`` times the fraction of the tube's projected area (stratified points along its
    length and across its projected width, on the tube's surface facing the direction)
    whose ray leaves the fixture (no hit within ``fixture_radius`` of the fixture's
    parts; the tube's own part excluded). A bin's value is the mean of that over its
    directions weighted by ``cos^2(phi)`` -- the weight of the line's power, so that
    :func:`reroom.invert.export.line_light_power` of the result is the power that
    leaves the fixture -- on both sides of ``d_perp`` (the basis folds them) and, when
    ``fold``, at ``+phi`` and ``-phi``: ``angles`` jittered ``theta`` strata per bin
    times ``phi_angles / phi_bins`` (at least 1) jittered ``phi`` strata, equal in
    ``cos^2`` measure. Light that leaves a baffle channel only obliquely, through its
    open ends, is counted in the large ``|phi|`` bins (with ``phi_bins = 1``, the
    separable model's single ``phi`` bin averages it with the rest).

    Parameters
    ----------
    light : dict
        The true line light (``p0``, ``p1``, ``radius``, ``radiance``, ``part``).
    scene_dir : path
    d_perp : ndarray, shape (3,)
        The solved line's reference direction (made perpendicular to the true line).
    bins, phi_bins, fold
        The solved basis's ``theta`` and ``phi`` bins.
    samples, angles, phi_angles, fixture_radius, seed
        ``samples`` points on the tube per direction; ``fixture_radius = 0``: bare tube.
        ``phi_angles`` was 16 until session 17: light leaving a channel's open ends
        changes fast with ``phi``: in the `furnished` tube's 60-90° bins the largest
        step from one ``theta`` bin to the next (of the bare tube's ``2 r L``) is 0.19
        with 16, 0.06 with 64, 0.04 with 96, for 1.5-1.8 / 5.3-5.5 / 7.7-7.9 s per tube
        (``benchmarks/bench_line_fixture.py``).

    Returns
    -------
    ndarray, shape (bins * phi_bins, 3)
        Intensity per metre of tube, per channel, in :class:`~reroom.invert.basis.LineBasis`
        order (``theta_bin * phi_bins + phi_bin``).
    """
    from reroom.invert.basis import LineBasis

    scene_dir = Path(scene_dir)
    basis = LineBasis(bins, phi_bins, fold)
    p0 = np.asarray(light["p0"], float)
    p1 = np.asarray(light["p1"], float)
    up = np.asarray(d_perp, float)
    r = float(light["radius"])
    rad = np.asarray(light["radiance"], float)
    caster = None
    if fixture_radius > 0:
        lo, hi = np.minimum(p0, p1) - r, np.maximum(p0, p1) + r
        exclude = {light["part"]} if light.get("part") else set()
        caster = _fixture_caster(scene_dir, lo, hi, exclude, fixture_radius)
    frac = np.ones(basis.size)
    if caster is not None:
        frac = line_open_fraction(
            caster.occluded, p0, p1, up, r, basis, fixture_radius,
            samples=samples, angles=angles, phi_angles=phi_angles, seed=seed,
        )  # fmt: skip
    return 2 * r * frac[:, None] * rad[None, :]


def distribution_relative_l2(
    estimate: np.ndarray,
    truth: np.ndarray,
    k: np.ndarray | None = None,
    mask: np.ndarray | None = None,
) -> float | None:
    """``||I_est / k - I_true||_2 / ||I_true||_2`` over the bins (cells), on luminance.

    Parameters
    ----------
    estimate, truth : ndarray, shape (bins, 3)
        Per-channel intensities (radiances for cube cells); the estimate in the HDR
        mesh's units, divided per channel by ``k`` before the Rec. 709 luminance.
    k : ndarray, shape (3,), optional
        The report's ``radiance_scale``.
    mask : ndarray of bool, shape (bins,), optional
        Bins to compare (default all).

    Returns
    -------
    float or None
        None when the truth is zero on the compared bins (or there are none).
    """
    e = np.asarray(estimate, float) / (np.ones(3) if k is None else np.asarray(k, float))
    t = np.asarray(truth, float)
    if mask is not None:
        e, t = e[np.asarray(mask, bool)], t[np.asarray(mask, bool)]
    ye, yt = e @ _LUMA, t @ _LUMA
    den = float(np.linalg.norm(yt))
    return float(np.linalg.norm(ye - yt) / den) if den > 0 else None


def _hdr_mesh_path(scan: Path, out: Path) -> Path:
    """The HDR mesh the inverse rendering in ``out`` solved with.

    ``SCAN/hdr/hdr_mesh.ply``, or where ``out/report.json`` says (``reroom run --out DIR``
    keeps its stages' outputs apart from the scan).
    """
    path = scan / "hdr" / "hdr_mesh.ply"
    if not path.is_file() and (out / "report.json").is_file():
        inputs = json.loads((out / "report.json").read_text()).get("inputs", {})
        path = Path(inputs.get("hdr_mesh", path))
    return path


def _seen_bins(scan: Path, out: Path, est: dict) -> dict[str, np.ndarray]:
    """Per solved point / line light, each bin's transfer summed over the clustered vertices.

    A bin is seen where the sum is nonzero.
    ``scene.json`` does not record them, so they are recomputed with the pipeline's own
    transfer functions and options (``report.json``) on the scan mesh, for the vertices
    ``albedo.ply`` marks ``in_cluster`` (the rows the solve used). Estimation inputs only.
    """
    from reroom.hdr.observe import vertex_normals
    from reroom.invert.direct import (
        DEFAULT_LINE_SEGMENTS,
        line_light_transfer,
        point_light_transfer,
    )
    from reroom.invert.transfer import inset_points
    from reroom.rays import RayCaster

    todo = [e for e in est["lights"] if e["type"] in ("point", "line")]
    if not todo:
        return {}
    mesh = read_ply(_hdr_mesh_path(scan, out))
    in_cluster = np.asarray(read_ply(out / "albedo.ply").vertex_attributes["in_cluster"]) > 0
    report = (
        json.loads((out / "report.json").read_text()) if (out / "report.json").is_file() else {}
    )
    opts = report.get("options", {})
    normals = vertex_normals(mesh)
    recv = np.flatnonzero(in_cluster & (np.linalg.norm(normals, axis=1) > 0))
    n = normals[recv]
    p = inset_points(mesh, recv, n, float(opts.get("receiver_inset", 0.0)))
    caster = RayCaster(mesh)
    seen = {}
    for e in todo:
        g = e["geometry"]
        if e["type"] == "line":
            grid, fold = line_profile_grid(e["distribution"])
            basis = LineBasis(grid.shape[0], grid.shape[1], fold)
        else:
            basis = InclinationBasis(int(e["distribution"]["bins"]))
        if e["type"] == "point":
            f = point_light_transfer(
                caster,
                p,
                n,
                np.asarray(g["position"], float),
                np.asarray(g["axis"], float),
                basis,
                # runs from before the option existed used the transfer's own default
                clearance=float(opts.get("point_clearance", 0.02)),
            )
        else:
            f = line_light_transfer(
                caster,
                p,
                n,
                np.asarray(g["p0"], float),
                np.asarray(g["p1"], float),
                np.asarray(g["d_perp"], float),
                basis,
                segments=int(opts.get("line_segments", DEFAULT_LINE_SEGMENTS)),
                clearance=float(opts.get("line_clearance", 0.03)),
            )
        seen[e["name"]] = f.sum(axis=0)
    return seen


def _light_position(light: dict) -> np.ndarray:
    for key in ("position", "centroid", "centre"):
        if key in light:
            return np.asarray(light[key], float)
    if "p0" in light:
        return (np.asarray(light["p0"], float) + np.asarray(light["p1"], float)) / 2
    return np.asarray(light["corners"], float).mean(axis=0)


def _compare_sun(est: dict, truth: dict | None, k: np.ndarray) -> dict[str, Any]:
    """A window's solved sun against the HDRI's (:func:`true_sun`): angle and irradiance."""
    if truth is None:
        return {"truth": None, "note": "the true sky has no sun through this window"}
    a = np.asarray(est["direction"], float)
    b = np.asarray(truth["direction"], float)
    angle = float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a), -1.0, 1.0))))
    irr = np.asarray(est["irradiance"], float) / k
    t_irr = np.asarray(truth["irradiance"], float)
    return {
        "truth": truth,
        "angle_deg": angle,
        "irradiance": irr.tolist(),
        "irradiance_relative_error": (irr / t_irr - 1).tolist(),
    }


def _compare_distribution(
    e: dict, t: dict, scene_dir: Path, k: np.ndarray, seen: dict[str, np.ndarray]
) -> tuple[dict[str, Any], np.ndarray | None]:
    """The distribution part of a light's report entry, and the truth's effective power.

    Area lights have no distribution (Lambertian by construction): ``relative_l2`` None.
    """
    kind = e["type"]
    if kind == "area":
        return {"basis": None, "relative_l2": None}, None
    dist: dict[str, Any] = {"channel": "Rec. 709 luminance of (r, g, b) / k"}
    if kind == "window":
        n = int(e["distribution"]["n"])
        cells = np.asarray(e["distribution"]["cells"], float)
        sun = e.get("sun")
        if sun is not None:
            # The truth's cells average the HDRI, its sun included: compare like with like.
            cells = fold_sun_into_cells(cells, CubemapBasis(n), sun["direction"], sun["irradiance"])
            dist["sun"] = _compare_sun(sun, true_sun(t, scene_dir), k)
        truth, shown = true_window_cells(t, scene_dir, n=n)
        dist.update(
            basis="cubemap",
            shown_cells=int(shown.sum()),
            relative_l2=distribution_relative_l2(cells, truth, k, shown),
            true_cells=truth.tolist(),
        )
        return dist, None
    g = e["geometry"]
    color = np.asarray(e["color"], float)
    if kind == "point":
        profile = np.asarray(e["distribution"]["profile"], float)
        estimate = profile[:, None] * color[None, :]
        truth = true_point_profile(t, scene_dir, np.asarray(g["axis"], float), len(profile))
        effective = inclination_power(truth)
        dist.update(basis="inclination")
        solved_bins = e["distribution"].get("split_from_bins")
        halvings = len(profile) // solved_bins if solved_bins else 0
        if (
            solved_bins is not None
            and solved_bins < len(profile)
            and solved_bins * halvings == len(profile)
            and halvings & (halvings - 1) == 0  # split in two, some number of times
        ):
            # Solved at fewer bins, then split (reroom.invert.fine_profiles): also compare
            # at the bins of the solve, the thesis's basis, each bin's flux as exported.
            coarse = profile
            while len(coarse) > solved_bins:
                coarse = coarsen(coarse)
            t_coarse = true_point_profile(t, scene_dir, np.asarray(g["axis"], float), solved_bins)
            dist.update(
                solved_bins=int(solved_bins),
                relative_l2_solved_bins=distribution_relative_l2(
                    coarse[:, None] * color[None, :], t_coarse, k
                ),
            )
    else:
        grid, fold = line_profile_grid(e["distribution"])
        bins, phi_bins = grid.shape
        estimate = grid.reshape(-1)[:, None] * color[None, :]
        truth = true_line_profile(
            t, scene_dir, np.asarray(g["d_perp"], float), bins, phi_bins=phi_bins, fold=fold
        )
        length = float(np.linalg.norm(np.subtract(t["p1"], t["p0"])))
        effective = line_light_power(truth, length, phi_bins, fold)
        # Both collapsed to theta alone (each theta bin's power-weighted mean over phi):
        # comparable between runs with different phi bins, the separable one included.
        pw = LineBasis(bins, phi_bins, fold).power_weights().reshape(bins, phi_bins)
        pw = pw / pw.sum(axis=1, keepdims=True)

        def collapse(x: np.ndarray) -> np.ndarray:
            return np.einsum("tp,tpc->tc", pw, x.reshape(bins, phi_bins, 3))

        dist.update(
            basis="line",
            bins=bins,
            phi_bins=phi_bins,
            phi_fold=fold,
            relative_l2_theta=distribution_relative_l2(collapse(estimate), collapse(truth), k),
        )
    dist.update(
        relative_l2=distribution_relative_l2(estimate, truth, k),
        true_profile=truth.tolist(),
        true_effective_power=effective.tolist(),
    )
    weight = seen.get(e["name"])
    if weight is not None:
        dist["seen_bins"] = np.flatnonzero(weight > 0).tolist()
        dist["seen_weight"] = (weight / max(weight.max(), 1e-300)).tolist()
        dist["relative_l2_seen"] = distribution_relative_l2(estimate, truth, k, weight > 0)
        # A bin seen only by a few vertices at grazing angles (a tube seen end-on from
        # beyond its ends) is barely constrained: also compare the well-seen bins alone.
        well = (weight > 0) & (weight >= _WELL_SEEN * weight.max())
        dist["relative_l2_well_seen"] = distribution_relative_l2(estimate, truth, k, well)
    return dist, effective


def evaluate_invert(scan_dir: str | Path, invert_dir: str | Path | None = None) -> dict[str, Any]:
    """Compare ``SCAN/invert/`` (or ``invert_dir``) with the scan's ground truth.

    Returns
    -------
    dict
        ``clusters`` (per cluster: estimate, truth, relative error per channel),
        ``per_vertex`` (median / p90 relative error), ``radiance_scale`` (``k``),
        ``lights`` (per solved light: matched truth, power, relative power error;
        ``distribution_relative_l2`` and ``distribution_relative_l2_seen`` (point, line:
        all bins / bins the solve saw; window: the cells it shows), ``distribution``
        (also ``relative_l2_well_seen``, each bin's relative ``seen_weight`` and, for
        lines, ``relative_l2_theta``; line bins flat in ``LineBasis`` order)
        with the truth in the solved basis and the seen bins; point lights also the
        power leaving the fixture, ``true_effective_power``, and its relative error),
        ``missed_lights`` (true lights with no solved light of their type nearby).
    """
    scan = Path(scan_dir)
    out = Path(invert_dir) if invert_dir is not None else scan / "invert"
    verts, scene, scene_dir = _truth(scan)
    true_label = np.asarray(verts.vertex_attributes["label"]).astype(int)
    true_albedo = np.asarray(verts.vertex_attributes["albedo"], float)
    true_rad = np.asarray(verts.vertex_attributes["radiance"], float)
    est = json.loads((out / "scene.json").read_text())
    amesh = read_ply(out / "albedo.ply")
    a = amesh.vertex_attributes
    albedo = np.asarray(a["albedo"], float)
    solved = np.asarray(a["solved_per_vertex"]).astype(bool)
    in_cluster = np.asarray(a["in_cluster"]).astype(bool)
    report: dict[str, Any] = {"invert_dir": str(out)}

    clusters = {}
    for m in est["materials"]:
        lab = _CLUSTER_LABELS.get(m["name"])
        if lab is None or m["albedo"] is None:
            clusters[m["name"]] = {"estimate": m["albedo"], "truth": None}
            continue
        truth = true_albedo[true_label == lab].mean(axis=0)
        e = np.asarray(m["albedo"], float)
        clusters[m["name"]] = {
            "estimate": e.tolist(),
            "truth": truth.tolist(),
            "relative_error": (e / truth - 1).tolist(),
        }
    report["clusters"] = clusters

    def _stats(mask: np.ndarray) -> dict[str, float] | None:
        ok = mask & (true_albedo > 0.02).all(axis=1) & (albedo >= 0).all(axis=1)
        if not ok.any():
            return None
        rel = np.abs(albedo[ok] / true_albedo[ok] - 1).ravel()
        return {
            "vertices": int(ok.sum()),
            "median": float(np.median(rel)),
            "p90": float(np.percentile(rel, 90)),
        }

    report["per_vertex"] = {"all": _stats(solved), "clustered": _stats(solved & in_cluster)}

    # the HDR radiance's own per-channel scale
    hdr_path = _hdr_mesh_path(scan, out)
    k = np.ones(3)
    if (out / "true_radiance.flag").is_file():
        pass  # solved with the truth's radiance: its scale is 1
    elif not hdr_path.is_file():
        report.setdefault("notes", []).append(
            f"{hdr_path} not found: light powers are in the HDR mesh's units (k = 1), "
            "not comparable with the truth's"
        )
    else:
        lbar = np.asarray(read_ply(hdr_path).vertex_attributes["radiance"], float)
        ok = in_cluster & (true_rad > 1e-4).all(axis=1) & (lbar > 0).all(axis=1)
        if ok.any():
            # A ratio of sums, not a median of ratios: the truth is a Monte-Carlo
            # estimate per vertex, unbiased in the mean but right-skewed, so with few
            # samples per vertex the median ratio overstates k (by 6 % at 64 spp per
            # vertex on `furnished`), which made every light look 6 % too weak.
            k = lbar[ok].sum(axis=0) / true_rad[ok].sum(axis=0)
    report["radiance_scale"] = k.tolist()

    lights = []
    true_lights = [x for x in scene["lights"] if x.get("on", True)]
    matched: set[str] = set()
    seen: dict[str, np.ndarray] | None = None
    for e in est["lights"]:
        cands = [t for t in true_lights if t["type"] == e["type"]]
        entry: dict[str, Any] = {"name": e["name"], "type": e["type"]}
        power = np.asarray(e["power"], float) / k
        entry["power"] = power.tolist()
        if cands:
            pos = _light_position(e["geometry"])
            t = min(cands, key=lambda t: np.linalg.norm(_light_position(t) - pos))
            matched.add(t["name"])
            entry["truth"] = t["name"]
            entry["distance_m"] = float(np.linalg.norm(_light_position(t) - pos))
            if seen is None and e["type"] in ("point", "line"):
                seen = _seen_bins(scan, out, est) if hdr_path.is_file() else {}
            dist, effective = _compare_distribution(e, t, scene_dir, k, seen or {})
            entry["distribution"] = dist
            entry["distribution_relative_l2"] = dist["relative_l2"]
            entry["distribution_relative_l2_seen"] = dist.get("relative_l2_seen")
            if "relative_l2_solved_bins" in dist:
                entry["distribution_relative_l2_solved_bins"] = dist["relative_l2_solved_bins"]
            tp = None
            if t["type"] == "area":
                c = np.asarray(t["corners"], float)
                area = np.linalg.norm(c[1] - c[0]) * np.linalg.norm(c[3] - c[0])
                tp = area_light_power(np.asarray(t["radiance"], float), area)
            elif t["type"] == "point":
                col = np.asarray(t.get("color", [1, 1, 1]), float)
                tp = t["power"] * col / col.mean()
                # What leaves the fixture: the shade's hidden bins are the solve's blind spot.
                entry["true_effective_power"] = effective.tolist()
                entry["effective_power_relative_error"] = (power / effective - 1).tolist()
            elif t["type"] == "window":
                tp = true_window_power(t, scene_dir)
            elif t["type"] == "line":
                tp = effective  # no closed form between baffles: the ray-traced profile's
            if tp is not None:
                entry["true_power"] = np.asarray(tp).tolist()
                entry["power_relative_error"] = (power / tp - 1).tolist()
            else:
                entry["true_power"] = None
                entry["note"] = "no true power for this light type"
        lights.append(entry)
    report["lights"] = lights
    report["missed_lights"] = [t["name"] for t in true_lights if t["name"] not in matched]
    return report


def hidden_as_unobserved(radiance: np.ndarray) -> np.ndarray:
    """The truth's per-vertex radiance with the vertices no probe could see set to NaN.

    The generator probes each vertex from just above it; a vertex hidden inside
    geometry (a wall's bottom row behind a baseboard, the floor under a sofa or a
    table's leg) reads exactly 0 in every channel. No photo sees those vertices either,
    so the HDR mesh leaves them unobserved; counted as observed black, they darkened
    every triangle they belong to and made ``E_ind`` 2-5 % low in the true-radiance
    runs (docs/invert.md, session 13). NaN rows are unobserved for
    :func:`reroom.invert.pipeline.run_invert`'s ``radiance_override``.
    """
    rad = np.array(radiance, dtype=float, copy=True)
    rad[(rad == 0.0).all(axis=1)] = np.nan
    return rad


def run_invert_true_radiance(scan_dir: str | Path, out_dir: str | Path, options=None):
    """EVALUATION-ONLY SHORTCUT: :func:`run_invert` with the true per-vertex radiance.

    The true radiance of ``ground_truth/vertices.ply`` replaces the HDR mesh's (every
    vertex counted as observed but those no probe could see:
    :func:`hidden_as_unobserved`), so the result measures the transfer and the solve
    alone. Never use this for anything but evaluation.
    """
    from reroom.invert.pipeline import run_invert

    verts, _, _ = _truth(Path(scan_dir))
    rad = hidden_as_unobserved(np.asarray(verts.vertex_attributes["radiance"], float))
    result = run_invert(scan_dir, out_dir, options, radiance_override=rad)
    (Path(out_dir) / "true_radiance.flag").write_text(
        "evaluation-only: solved with the ground truth's radiance\n"
    )
    return result


def lights_from_truth(scan_dir: str | Path):
    """EVALUATION-ONLY SHORTCUT: the true lights as a :class:`reroom.lights.LightSet`.

    Every light that is on, with the generator's geometry (area: its part's vertices on
    the scan mesh; window: its rectangle; line: ``p0, p1`` with up as ``d_perp``; point:
    ``position`` and ``up``). Used to measure transfer + solve when light detection
    missed a light; never for estimation.
    """
    from reroom.lights import Light, LightSet

    verts, scene, _ = _truth(Path(scan_dir))
    part = np.asarray(verts.vertex_attributes["part"]).astype(int)
    part_index = {p["name"]: i for i, p in enumerate(scene["parts"])}
    ids = np.full(len(verts.vertices), -1, np.int32)
    lights = []
    for t in scene["lights"]:
        if not t.get("on", True):
            continue
        if t["type"] == "area":
            c = np.asarray(t["corners"], float)
            size = [np.linalg.norm(c[1] - c[0]), np.linalg.norm(c[3] - c[0])]
            geom = {
                "centroid": c.mean(axis=0).tolist(),
                "normal": t["normal"],
                "area": float(size[0] * size[1]),
                "light_index": len(lights),
            }
            if t.get("part") in part_index:
                ids[part == part_index[t["part"]]] = len(lights)
        elif t["type"] == "window":
            c = np.asarray(t["corners"], float)
            geom = {
                "centre": c.mean(axis=0).tolist(),
                "half_u": ((c[1] - c[0]) / 2).tolist(),
                "half_v": ((c[3] - c[0]) / 2).tolist(),
                "normal": t["normal"],
            }
        elif t["type"] == "line":
            geom = {"p0": t["p0"], "p1": t["p1"], "d_perp": [0.0, 0.0, 1.0], "radius": t["radius"]}
        else:
            geom = {"position": t["position"], "axis": t.get("up", [0.0, 0.0, 1.0])}
        lights.append(Light(t["name"], t["type"], "user", geom, {}, "ground truth (evaluation)"))
    return LightSet(lights, [], ids, {}, ["EVALUATION ONLY: lights from the ground truth"], {})
