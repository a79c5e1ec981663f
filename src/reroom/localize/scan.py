"""Room-scale light localization on a scan (``reroom localize SCAN``), thesis §6.3.1, §6.6.3.

Inputs: ``SCAN/hdr/hdr_mesh.ply`` (per-vertex HDR radiance), ``SCAN/layout/layout_labels.ply``
and ``layout.json`` (labels, room polygons) and, when present, ``SCAN/lights/lights.json``
(area lights, windows and line lights found by ``reroom lights``). Ground truth is never read.

The model of a diffuse receiver ``V`` of surface class ``c`` (wall, ceiling, floor) is

    pi L_V = rho_c (E_ind(V) + A(V) x + sum_k I_k S(V, p_k))

* ``E_ind`` is the irradiance gathered from the *observed* radiance of the other
  surfaces (§6.3.1), by the hemisphere rays of
  :func:`reroom.invert.transfer.hemisphere_transfer` (emitter surfaces excluded);
* ``A x`` is the direct light of the other lights, with unknown non-negative strengths
  ``x``: each area light (its observed radiance is clipped, so it is not trusted), each
  window's cube-map cells, each line light's inclination bins, and one column for the
  light arriving from unobserved directions (holes, a window the layout missed);
* ``S(V, p_k)`` is eq. 6.2 with ray-cast visibility (a bulb inside a lamp shade lights only
  what the shade's openings let through);
* ``rho_c`` is one unknown albedo per class: first the robust minimum of
  ``pi L / E_ind`` over the class (a vertex with no direct light has ``rho = pi L / E_ind``,
  direct light only raises the ratio: §6.6.3's robust minimum, applied to the albedo),
  then the median of ``pi L / (E_ind + A x + S I)`` once lights explain the direct light.

``B = pi L / rho_c - E_ind`` is the direct light the thesis's transforms work on. The
lights are found greedily (discovery on the unexplained illumination, as Algorithm 1): on a
grid of free-space positions inside the layout's rooms, the light that would explain most
of the remaining direct light (``(s . r)_+^2 / |s|^2`` with ray-cast visibility) joins,
then a robust joint nonlinear solve (scipy ``least_squares``, soft-L1) refines every
light's position and intensity and the other lights' strengths. The search stops when the
best new light explains less than ``min_gain`` of the remaining energy or carries less than
``min_power`` of the lights' total intensity; lights whose removal barely raises the cost
are then dropped. Last, a goniometric test (an inclination profile at heights along the
vertical through each light: 32 bins decide, 64 place) catches downlights, which an
isotropic model puts far too low, and a mount test puts a light that sends nothing upwards
and has no fitting in the scan, or that nothing in the scan holds, just under the ceiling
above it (a light inside a shade keeps the search's height); the albedos are
re-estimated with its lights and the test repeated. See
docs/localize.md for what was measured, including why the voting function is not used
here.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares, nnls
from scipy.spatial import cKDTree

from reroom.errors import ReroomError
from reroom.invert.portal import DEFAULT_WINDOW_SAMPLES, window_portal_transfer
from reroom.localize.measurements import shading_jacobian, shading_matrix
from reroom.threads import one_blas_thread

__all__ = [
    "LOCALIZED_REASON",
    "ScanLocalizeOptions",
    "ScanLocalizeResult",
    "localize_into_lights",
    "localize_scan",
    "merge_localized_lights",
    "write_localized_lights",
]

WALL, FLOOR, CEILING = 0, 1, 2
CLASS_NAMES = {WALL: "wall", FLOOR: "floor", CEILING: "ceiling"}
LOCALIZED_REASON = "localized (thesis ch. 6)"


@dataclass(frozen=True)
class ScanLocalizeOptions:
    """Options of :func:`localize_scan`.

    Attributes
    ----------
    classes:
        Surface labels used as measurements of the search (0 wall, 1 floor, 2 ceiling).
        The floor is left out by default: its texture breaks the one-albedo-per-class
        model, and on ``furnished`` it made the lights worse (docs/localize.md).
    profile_classes:
        Surface labels used by the goniometric test (the floor holds a downlight's pool).
    max_measurements:
        Receivers of the search (a seeded random subset of the observed ones).
    profile_measurements:
        Receivers computed in all (a seeded random subset), of which those near a light
        serve its goniometric test.
    score_measurements:
        Receivers used to score the grid positions (a subset, for speed).
    rays_per_vertex:
        Hemisphere rays per receiver for ``E_ind``.
    albedo_percentile:
        Percentile of ``pi L / E_ind`` per class taken as the first albedo estimate.
    grid_step:
        Spacing (metres) of the candidate positions.
    surface_margin:
        Candidates closer than this (metres) to a mesh vertex are dropped (§6.3.6).
    max_lights:
        At most this many point lights.
    min_gain:
        A new light must explain at least this fraction of the unexplained energy.
    discovery:
        How a candidate's share is measured: ``"joint"`` (default) with the other lights
        and the point lights found refitted and soft-L1 weights (:func:`_discovery_gain`),
        ``"fixed"`` (the earlier rule) against the residual with everything else fixed,
        clipped at 30 soft-L1 scales.
    min_power:
        Lights weaker than this fraction of the total intensity are dropped.
    prune_ratio:
        After the search, a light whose removal (and re-solve) raises the robust cost by
        less than this factor is dropped.
    window_cells:
        Cube-map cells per face side of each window's distant light.
    window_samples:
        Points sampled on each window opening per receiver
        (:func:`reroom.invert.portal.window_portal_transfer`), as ``reroom invert``
        does; 0 counts the hemisphere rays that leave through it (so noisy per cell that
        window light the cells cannot fit is left for a false point light near the
        window: docs/localize.md).
    line_bins:
        Inclination bins of each line light's profile.
    profile_bins:
        Inclination bins of the goniometric test's decision, goniometric or isotropic
        (thesis: 32).
    height_bins:
        Inclination bins of the test's height search and of the profile kept (a multiple
        of ``profile_bins``): the rings of a real beam are finer than 32 bins; with 32 the
        height of ``furnished``'s downlight came out 0.5-0.6 m low, with 64 0.2-0.3 m
        (docs/localize.md). Deciding with 64 bins would make isotropic lights look
        goniometric (twice the parameters fit the noise 20 % better).
    profile_radius:
        Receivers within this horizontal distance (metres) of a light serve its test.
    profile_step:
        Height step (metres) of the test's search along the vertical through the light.
    profile_gain:
        The goniometric model replaces the isotropic one when it lowers the robust cost
        of the light's receivers by at least this fraction.
    mount_test:
        Run the mount test after the goniometric test (docs/localize.md): a light whose
        fitted profile sends (almost) nothing upwards needs an opaque body above it; when
        the scan shows none between the light and the ceiling, the ceiling is that body,
        and the light moves to just below it if the data allow.
    mount_up_flux:
        The test applies when at most this fraction of the profile's flux goes upwards.
    mount_radius:
        No mesh vertex may lie within this horizontal distance (metres) of the light's
        vertical, from this far below the light up to the surface above it (a fitting).
    mount_clearance:
        Vertices within this distance (metres) below the surface above are that surface.
    mount_depth:
        The mounted light is searched among the test's heights within this distance
        (metres) below the surface above.
    mount_tolerance:
        ... and taken when its cost is at most this fraction above the best height's.
    mount_shift:
        The mounted light's x, y are refitted within this distance (metres, each axis)
        of the vertical through the light (0: not).
    keep_enclosed:
        A goniometric light inside a fitting the scan shows (vertices other than wall,
        floor and ceiling within ``mount_radius`` of it all around its vertical: a lamp's
        shade; :func:`_enclosed`) keeps the search's height instead of the lowest-cost one.
    enclosed_axis:
        The goniometric test also tries each height inside a fitting (:func:`_enclosed`)
        on the fitting's axis (:func:`_fitting_axis`), keeping the lower cost.
    albedo_rounds:
        Rounds of (albedos from the lights, goniometric test).
    search_albedo_update:
        How the albedos are re-estimated (median of ``(E_ind + A x + S I) / pi L``) during
        the search: ``"bounded"`` (default): after each joint solve, from the previous
        albedos, but kept within a factor ``1 + search_albedo_bound`` of the robust
        minimum; ``"iterated"`` (the earlier rule): the same unbounded; ``"anchored"``:
        one update per discovery from the lights fitted at the robust minimum;
        ``"off"``: the robust minimum throughout. The update has no fixed point (a larger
        ``1 / rho`` is absorbed by larger strengths of the other lights), so iterated it
        drifts: on ``box_points`` the wall albedo went from the robust minimum's 0.71 to
        0.56 (truth 0.667), with or without lights, and the downlight was not discovered
        (docs/localize.md).
    search_albedo_bound:
        See ``search_albedo_update``.
    downward_candidates:
        Score each grid position twice in the discovery: as an isotropic light and as a
        downward one (its upper half shaded by a housing: it lights only what is below
        it). An isotropic stand-in for a downlight lights the ceiling around it, which
        the scan shows dark, so it explains less (docs/localize.md).
    mount_unsupported:
        Also mount a light that sends light upwards when the scan shows nothing that could
        hold it (no vertex other than floor and ceiling near it, ``vertex_labels`` needed)
        and the data allow the mounted position (``mount_tolerance``): a light cannot
        float, so it is in the surface above (docs/localize.md).
    one_fixture_m:
        After the goniometric test, two lights it places closer than this (metres) are
        one fixture: the weaker (by its mean intensity) is dropped and the other refit
        and placed again, its profile now free to send the light of both. Isotropic
        lights above and below an open-topped shade (one for its ceiling pool, one for
        its floor pool) can both pass the pruning and both end at the bulb (issue's
        scan fused at another grid yaw: two lights 1.6 cm apart, the lamp split
        −81 % / −19 %; docs/localize.md).
    drop_floating:
        After the goniometric test (and its mounting), drop a light that nothing in the
        scan can hold: farther than ``mount_depth`` below the surface above it, with no
        vertex but floor and ceiling within ``mount_radius`` of its vertical (no shade,
        stand, pendant or wall; :func:`_floating`), then refit and place the others again.
        On `box` such a light fitted the grazing patch of window light on a wall that
        the window's 96 cells cannot draw (docs/localize.md).
    hold_in_fitting:
        A light the discovery finds inside a fitting the scan shows (:func:`_enclosed`:
        a lamp's shade) starts on the fitting's axis (:func:`_fitting_axis`) and stays
        within ``fitting_slack`` of it across and ``fitting_height`` of its starting
        height in the joint fits. Let loose, it drifted out of the shade while keeping
        the shade's visibility, and was then dropped as floating (docs/localize.md).
    fitting_slack, fitting_height:
        See ``hold_in_fitting`` (metres).
    hold_reach:
        Metres below a light within which a body (a stand's top, a table lamp's base)
        holds it (``drop_floating``).
    soft_scale:
        Scale of the soft-L1 loss, as a fraction of the median ``pi L``.
    time_limit:
        Seconds; the search stops adding lights after this.
    normal_radius:
        Metres; the receivers' normals diffused over about this radius of agreeing
        surface (:func:`reroom.invert.normals.smoothed_vertex_normals`, as
        ``InvertOptions.normal_radius``); 0 takes the one-ring normals; ``None`` (the
        default) decides by the floor's noise as ``InvertOptions.normal_radius`` does.
    seed:
        Seed of the subsets and the hemisphere rays.
    """

    classes: tuple[int, ...] = (WALL, CEILING)
    profile_classes: tuple[int, ...] = (WALL, FLOOR, CEILING)
    max_measurements: int = 3000
    profile_measurements: int = 20000
    score_measurements: int = 1500
    rays_per_vertex: int = 128
    albedo_percentile: float = 5.0
    grid_step: float = 0.2
    surface_margin: float = 0.08
    max_lights: int = 6
    min_gain: float = 0.15
    discovery: str = "joint"
    min_power: float = 0.05
    prune_ratio: float = 1.1
    window_cells: int = 4
    window_samples: int = DEFAULT_WINDOW_SAMPLES
    line_bins: int = 4
    profile_bins: int = 32
    height_bins: int = 64
    profile_radius: float = 1.5
    profile_step: float = 0.05
    profile_gain: float = 0.2
    mount_test: bool = True
    mount_up_flux: float = 0.02
    mount_radius: float = 0.3
    mount_clearance: float = 0.05
    mount_depth: float = 0.1
    mount_tolerance: float = 0.1
    mount_shift: float = 0.2
    keep_enclosed: bool = True
    enclosed_axis: bool = True
    albedo_rounds: int = 2
    search_albedo_update: str = "bounded"
    search_albedo_bound: float = 0.05
    mount_unsupported: bool = True
    one_fixture_m: float = 0.25
    drop_floating: bool = True
    hold_in_fitting: bool = True
    fitting_slack: float = 0.05
    fitting_height: float = 0.15
    hold_reach: float = 0.5
    downward_candidates: bool = False
    soft_scale: float = 0.3
    time_limit: float = 900.0
    normal_radius: float | None = None
    seed: int = 0


@dataclass
class ScanLocalizeResult:
    """What :func:`localize_scan` found.

    Attributes
    ----------
    positions:
        ``(K, 3)`` point-light positions in the scan's frame (metres).
    intensities:
        ``(K,)`` intensities in the scan's radiance units times sr (``pi L / rho`` m^2).
    albedo:
        Albedo per surface class name.
    other_lights:
        Fitted strength of each column of the other lights (name -> value).
    rms:
        Robust-fit residual RMS relative to the median ``pi L``.
    seconds:
        Wall-clock time.
    history:
        One entry per discovery: the candidate, its gain, the lights after the solve.
    goniometric:
        Per light: None (isotropic) or the result of the goniometric test (position,
        inclination profile, mean intensity, costs).
    """

    positions: np.ndarray
    intensities: np.ndarray
    albedo: dict[str, float]
    other_lights: dict[str, float]
    rms: float
    seconds: float
    history: list[dict] = field(default_factory=list)
    goniometric: list[dict | None] = field(default_factory=list)


def _require(path: Path, stage: str, scan: Path) -> Path:
    if not path.is_file():
        raise ReroomError(f"{path}: missing (run `reroom {stage} {scan}` first)")
    return path


@dataclass
class _Problem:
    """Receivers, their observations and the known parts of the model."""

    points: np.ndarray
    normals: np.ndarray
    pil: np.ndarray  # pi * radiance (grey)
    e_ind: np.ndarray  # gathered indirect irradiance
    cls: np.ndarray  # index into classes
    classes: list[int]
    other: np.ndarray  # (n, m) direct light of the other lights per unit strength
    other_names: list[str]
    caster: object
    scale: float

    def subset(self, rows: np.ndarray) -> _Problem:
        """The same problem on some of its receivers."""
        return _Problem(
            self.points[rows], self.normals[rows], self.pil[rows], self.e_ind[rows],
            self.cls[rows], self.classes, self.other[rows], self.other_names, self.caster,
            self.scale,
        )  # fmt: skip

    def visibility(
        self, positions: np.ndarray, down: np.ndarray | None = None
    ) -> np.ndarray | None:
        """Ray-cast visibility; a ``down`` light (its upper half shaded by its housing)
        lights only the receivers below it."""
        if len(positions) == 0:
            return None
        vis = self.caster.visibility_matrix(self.points, self.normals, positions)
        if down is not None and np.any(down):
            vis = vis & ~(down[None, :] & (self.points[:, 2:3] >= positions[None, :, 2]))
        return vis

    def direct(self, u: np.ndarray, x: np.ndarray) -> np.ndarray:
        """``B = pi L / rho - E_ind - A x``: the direct light left for point lights."""
        return u[self.cls] * self.pil - self.e_ind - self.other @ x


def _room_mask(points: np.ndarray, layout: dict, margin_floor: float = 0.1) -> np.ndarray:
    """Points inside a room of the layout (polygon in the aligned frame, between heights)."""
    from matplotlib.path import Path as MPath

    rot = np.asarray(layout.get("rotation", np.eye(3)), float).reshape(3, 3)
    q = points @ rot.T
    inside = np.zeros(len(points), bool)
    for room in layout.get("rooms", []):
        poly = np.asarray(room["polygon"], float)
        inside |= (
            MPath(poly).contains_points(q[:, :2])
            & (q[:, 2] > float(room["floor_z"]) + margin_floor)
            & (q[:, 2] < float(room["ceiling_z"]) - 0.02)
        )
    return inside


def _build_problem(scan: Path, opt: ScanLocalizeOptions, notes: list[str]):
    from reroom.invert.area import area_light_transfer
    from reroom.invert.basis import CubemapBasis, InclinationBasis
    from reroom.invert.direct import line_light_transfer
    from reroom.invert.pipeline import emitter_surfaces
    from reroom.invert.transfer import hemisphere_transfer
    from reroom.invert.windows import WindowOpening
    from reroom.io.mesh import read_ply
    from reroom.lights import load_lights
    from reroom.rays import RayCaster

    hdr = _require(scan / "hdr" / "hdr_mesh.ply", "hdr", scan)
    lab_path = _require(scan / "layout" / "layout_labels.ply", "layout", scan)
    lay_path = _require(scan / "layout" / "layout.json", "layout", scan)
    mesh = read_ply(hdr)
    attrs = mesh.vertex_attributes
    if "radiance" not in attrs:
        raise ReroomError(f"{hdr}: no radiance_r/g/b vertex properties")
    lab = read_ply(lab_path)
    nv = len(mesh.vertices)
    if len(lab.vertices) != nv or "label" not in lab.vertex_attributes:
        raise ReroomError(f"{lab_path}: needs a 'label' for each of the {nv} vertices of {hdr}")
    try:
        layout = json.loads(lay_path.read_text())
    except json.JSONDecodeError as exc:
        raise ReroomError(f"{lay_path}: not valid JSON ({exc})") from exc
    if not layout.get("rooms"):
        raise ReroomError(f"{lay_path}: no room, so no space to search lights in")
    labels = np.asarray(lab.vertex_attributes["label"]).reshape(-1).astype(int)
    rad = np.asarray(attrs["radiance"], np.float64).reshape(nv, 3)
    observed = np.asarray(attrs.get("observed", np.ones(nv)), bool) & np.isfinite(rad).all(axis=1)
    pts = np.asarray(mesh.vertices, np.float64)
    from reroom.invert.normals import auto_note, receiver_normals

    nrm, normal_info = receiver_normals(mesh, opt.normal_radius, labels == FLOOR)
    if note := auto_note(opt.normal_radius, normal_info):
        notes.append(note)

    # Other lights (never point lights: those are what is estimated here).
    lights_path = scan / "lights" / "lights.json"
    light_list, ids = [], np.full(nv, -1, np.int64)
    if lights_path.is_file():
        ls = load_lights(lights_path)
        light_list = ls.lights
        if len(ls.vertex_light_id) == nv:
            ids = np.asarray(ls.vertex_light_id, np.int64)
        elif len(ls.vertex_light_id):
            notes.append(
                f"{lights_path}: {len(ls.vertex_light_id)} per-vertex light ids for a mesh of "
                f"{nv} vertices: ignored (area-light and window surfaces count as lit walls)"
            )
    else:
        notes.append(f"{lights_path} missing: area lights, windows and tubes are not modelled")
    areas, wins, area_of, win_of = emitter_surfaces(light_list, ids, nv)
    lines = [x for x in light_list if x.type == "line"]
    # A tube's glowing surface is modelled by its line light: not indirect light.
    fixture = np.zeros(nv, bool)
    for light in lines:
        g = light.geometry
        p0, p1 = np.asarray(g["p0"], float), np.asarray(g["p1"], float)
        d = p1 - p0
        s = np.clip((pts - p0) @ d / max(float(d @ d), 1e-12), 0.0, 1.0)
        fixture |= np.linalg.norm(pts - (p0 + s[:, None] * d), axis=1) <= g["radius"] + 0.05
    area_of[fixture & (area_of < 0) & (win_of < 0)] = len(areas)

    rng = np.random.default_rng(opt.seed)
    used = sorted(set(opt.classes) | set(opt.profile_classes))
    ok = observed & np.isin(labels, used) & (np.linalg.norm(nrm, axis=1) > 0)
    recv = np.flatnonzero(ok & (ids < 0) & ~fixture)
    n_search = int(np.isin(labels[recv], opt.classes).sum())
    if n_search < 50:
        raise ReroomError(
            f"{hdr}: only {n_search} observed {[CLASS_NAMES.get(c, c) for c in opt.classes]} "
            "vertices, too few to localize"
        )
    if recv.size > opt.profile_measurements:
        recv = np.sort(rng.choice(recv, opt.profile_measurements, replace=False))
    caster = RayCaster(mesh)
    openings = [
        WindowOpening(w.name, *(np.asarray(w.geometry[k], float) for k in ("centre", "half_u", "half_v", "normal")))
        for w in wins
    ]  # fmt: skip
    basis = CubemapBasis(opt.window_cells)
    hemi = hemisphere_transfer(
        caster, mesh, recv, nrm, rad, observed, area_of, openings, basis,
        rays_per_vertex=opt.rays_per_vertex, seed=opt.seed, window_of_vertex=win_of,
    )  # fmt: skip
    p, n = pts[recv], nrm[recv]
    cols, names = [], []
    for k, light in enumerate(areas):
        cols.append(area_light_transfer(caster, mesh, area_of == k, p, n, 256, seed=opt.seed + k))
        names.append(light.name)
    for k, light in enumerate(wins):
        if opt.window_samples > 0:
            pane = (win_of[np.asarray(mesh.faces)] == k).any(axis=1)
            f = window_portal_transfer(
                caster, openings[k], basis, p, n, opt.window_samples,
                seed=opt.seed + 101 + k, pane_faces=pane,
            )  # fmt: skip
        else:
            f = hemi.distant[:, k, :]
        for j in range(basis.size):
            cols.append(f[:, j])
            names.append(f"{light.name}[{j}]")
    incl = InclinationBasis(opt.line_bins)
    for light in lines:
        g = light.geometry
        f = line_light_transfer(caster, p, n, g["p0"], g["p1"], [0.0, 0.0, 1.0], incl)
        for j in range(incl.bins):
            cols.append(f[:, j])
            names.append(f"{light.name}[{j}]")
    cols.append(np.pi * hemi.p_unobserved)
    names.append("unobserved")
    pil = np.pi * rad[recv].mean(axis=1)
    classes = sorted(set(int(c) for c in labels[recv]))
    prob = _Problem(
        p, n, pil, hemi.indirect.mean(axis=1), np.searchsorted(classes, labels[recv]), classes,
        np.stack(cols, axis=1), names, caster, float(np.median(pil)),
    )  # fmt: skip
    return prob, pts, layout, np.asarray(labels[recv]), labels


def _discovery_gain(
    s: np.ndarray, r: np.ndarray, known: np.ndarray, scale: float
) -> tuple[np.ndarray, np.ndarray]:
    """Share of the remaining robust energy each candidate explains, the known lights refitted.

    ``s``: ``(n, M)`` candidates' shading; ``r``: ``(n,)`` residual of the current solution;
    ``known``: ``(n, k)`` columns the joint solve refits with a new light (the other
    lights' active columns and the point lights found). Weights are the soft-L1 loss's
    at ``r`` (``1 / sqrt(1 + (r / scale)^2)``), so outliers (a fixture's bleeding, a sun
    patch's core) weigh as in the joint solve. Each candidate's column and the residual
    are projected off the known columns (orthogonal matching pursuit, not plain matching
    pursuit: without it, the other lights' columns, fitted alone first, absorb part of a
    point light's signal, e.g. a window's 96 cube-map cells a lamp's light near the
    window wall), and the gain is ``(s' . r')_+^2 / (|s'|^2 |r'|^2)``. Returns the gains
    and each candidate's intensity at its best (the start of the joint solve).
    """
    sw = np.sqrt(1.0 / np.sqrt(1.0 + (r / scale) ** 2))
    rw, sw_s = r * sw, s * sw[:, None]
    if known.shape[1]:
        q, _ = np.linalg.qr(known * sw[:, None])
        q = q[:, np.linalg.norm(q, axis=0) > 0]
        rw = rw - q @ (q.T @ rw)
        sw_s = sw_s - q @ (q.T @ sw_s)
    norm2 = (sw_s**2).sum(axis=0) + 1e-300
    num = sw_s.T @ rw
    gain = np.where(num > 0, num**2 / norm2, 0.0) / max(float(rw @ rw), 1e-300)
    return gain, np.maximum(num / norm2, 0.0)


def _nonneg_fit(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Non-negative least squares with equilibrated columns."""
    if a.shape[1] == 0:
        return np.zeros(0)
    cn = np.linalg.norm(a, axis=0)
    cn[cn == 0] = 1.0
    x, _ = nnls(a / cn, b, maxiter=50 * a.shape[1] + 200)
    return x / cn


class _SharedNNLS:
    """Non-negative least squares ``[base f] x ~ b`` for many ``f`` and one ``base``.

    The goniometric test fits every candidate height with the same other lights
    (``base``, ~135 columns) and a new ~32-column transfer ``f``. A QR factorisation of
    the equilibrated ``base`` is made once; for each ``f`` only its part orthogonal to
    ``base`` is factored, and NNLS runs on the small triangular system ``R x ~ Q^T b``
    (the same minimiser: ``|A x - b|^2 = |R x - Q^T b|^2 + const``) instead of the
    ~4000-row one (docs/localize.md, "Session 9": the whole localization of the 300-frame
    scan 55 -> 40 s in ``bench_localize_scan.py``, same positions).
    """

    def __init__(self, base: np.ndarray, b: np.ndarray) -> None:
        self.base, self.b = base, b
        cn = np.linalg.norm(base, axis=0)
        cn[cn == 0] = 1.0
        self.cn = cn
        self.q, self.r = np.linalg.qr(base / cn)
        self.qtb = self.q.T @ b

    def fit(self, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Non-negative coefficients ``[x_base, x_f]`` and the residual ``b - [base f] x``."""
        cf = np.linalg.norm(f, axis=0)
        cf[cf == 0] = 1.0
        ff = f / cf
        f1 = self.q.T @ ff
        f2 = ff - self.q @ f1
        g = self.q.T @ f2  # a second Gram-Schmidt pass keeps f2 orthogonal to base
        f1 += g
        f2 -= self.q @ g
        qf, rf = np.linalg.qr(f2)
        m0, m1 = self.r.shape[1], rf.shape[1]
        r = np.zeros((m0 + m1, m0 + m1))
        r[:m0, :m0] = self.r
        r[:m0, m0:] = f1
        r[m0:, m0:] = rf
        rhs = np.concatenate([self.qtb, qf.T @ self.b])
        x, _ = nnls(r, rhs, maxiter=50 * (m0 + m1) + 200)
        coef = x / np.concatenate([self.cn, cf])
        resid = self.b - self.base @ coef[:m0] - f @ coef[m0:]
        return coef, resid


def _joint_fit(
    prob: _Problem,
    pos: np.ndarray,
    inten: np.ndarray,
    u: np.ndarray,
    x: np.ndarray,
    bounds: tuple[np.ndarray, np.ndarray],
    soft: float,
    down: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Robust joint solve of point-light positions and intensities and other lights' strengths.

    The albedos ``1/u`` stay fixed (they are re-estimated between solves); visibility is
    computed at the starting positions and held fixed, as in §6.5.3.
    """
    k, m, npts = len(pos), prob.other.shape[1], len(prob.pil)
    vis = prob.visibility(pos, down)
    target = prob.direct(u, np.zeros(m))

    def unpack(z):
        return z[: 3 * k].reshape(k, 3), z[3 * k : 4 * k], z[4 * k :]

    def res(z):
        p, i_, xx = unpack(z)
        r = target - prob.other @ xx
        if k:
            r = r - shading_matrix(prob.points, prob.normals, p, vis) @ i_
        return r / prob.scale

    def jac(z):
        p, i_, _ = unpack(z)
        jm = np.zeros((npts, z.size))
        if k:
            s, ds = shading_jacobian(prob.points, prob.normals, p, vis)
            jm[:, : 3 * k] = -(ds * i_[None, :, None]).reshape(npts, 3 * k)
            jm[:, 3 * k : 4 * k] = -s
        jm[:, 4 * k :] = -prob.other
        return jm / prob.scale

    lo, hi = (np.broadcast_to(np.asarray(b, float), (k, 3)).ravel() for b in bounds)
    lb = np.concatenate([lo, np.zeros(k + m)])
    ub = np.concatenate([hi, np.full(k + m, np.inf)])
    z0 = np.clip(np.concatenate([pos.ravel(), inten, x]), lb, np.where(np.isinf(ub), ub, ub - 1e-9))
    sol = least_squares(
        res, z0, jac=jac, bounds=(lb, ub), method="trf", loss="soft_l1", f_scale=soft, max_nfev=100
    )
    p, i_, xx = unpack(sol.x)
    return p.copy(), i_.copy(), xx.copy(), float(np.sqrt(np.mean(sol.fun**2)))


def _update_albedo(prob: _Problem, pos, inten, x, u_prev: np.ndarray, down=None) -> np.ndarray:
    """``u_c = 1 / rho_c``: median of ``(E_ind + A x + S I) / pi L`` over each class."""
    pred = prob.e_ind + prob.other @ x
    if len(pos):
        pred = (
            pred
            + shading_matrix(prob.points, prob.normals, pos, prob.visibility(pos, down)) @ inten
        )
    u = u_prev.copy()
    for j in range(len(prob.classes)):
        sel = (prob.cls == j) & (prob.pil > 0)
        if sel.any():
            u[j] = float(np.median(pred[sel] / prob.pil[sel]))
    return u


def _albedo_from(prob: _Problem, direct: np.ndarray, u_prev: np.ndarray) -> np.ndarray:
    """Albedos given the point lights' direct light: the other lights' strengths by NNLS,
    then :func:`_update_albedo`'s median (with the lights entering as fixed light)."""
    x = _nonneg_fit(prob.other, prob.direct(u_prev, np.zeros(prob.other.shape[1])) - direct)
    pred = prob.e_ind + prob.other @ x + direct
    u = u_prev.copy()
    for j in range(len(prob.classes)):
        sel = (prob.cls == j) & (prob.pil > 0)
        if sel.any():
            u[j] = float(np.median(pred[sel] / prob.pil[sel]))
    return u


def _lights_direct(
    prob: _Problem, pos: np.ndarray, inten: np.ndarray, profiles: list, down=None
) -> np.ndarray:
    """Direct light of the point lights at the receivers: isotropic, or by the inclination
    profile the goniometric test fitted."""
    from reroom.invert.basis import InclinationBasis
    from reroom.invert.direct import point_light_transfer

    out = np.zeros(len(prob.pil))
    for k in range(len(pos)):
        pr = profiles[k] if k < len(profiles) else None
        if pr is None:
            vis = prob.visibility(pos[k : k + 1], None if down is None else down[k : k + 1])
            out += shading_matrix(prob.points, prob.normals, pos[k : k + 1], vis)[:, 0] * inten[k]
        else:
            f = point_light_transfer(
                prob.caster, prob.points, prob.normals, pr["position"], [0.0, 0.0, 1.0],
                InclinationBasis(len(pr["profile"])),
            )  # fmt: skip
            out += f @ np.asarray(pr["profile"])
    return out


def localize_scan(
    scan_dir: str | Path,
    options: ScanLocalizeOptions | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> tuple[ScanLocalizeResult, dict]:
    """Find the point lights of a scanned room from the direct light on its surfaces.

    Parameters
    ----------
    scan_dir:
        Scan folder with ``hdr/`` and ``layout/`` (and ideally ``lights/``) outputs.
    options:
        :class:`ScanLocalizeOptions`.
    progress:
        ``progress(stage, done, total)`` after each discovery.

    Returns
    -------
    result:
        :class:`ScanLocalizeResult`.
    info:
        Inputs and decisions (counts, albedos, stopping reason), JSON-ready.

    Raises
    ------
    ReroomError
        A stage output is missing or malformed, or too few surfaces were observed.
    """
    # Its fits are many small least-squares problems: one BLAS thread is twice as fast
    # there as two (reroom.threads).
    with one_blas_thread():
        return _localize_scan(scan_dir, options, progress)


def _localize_scan(
    scan_dir: str | Path,
    options: ScanLocalizeOptions | None,
    progress: Callable[[str, int, int], None] | None,
) -> tuple[ScanLocalizeResult, dict]:
    opt = options or ScanLocalizeOptions()
    scan = Path(scan_dir)
    t0 = time.perf_counter()
    notes: list[str] = []
    if opt.search_albedo_update not in ("anchored", "iterated", "bounded", "off"):
        raise ValueError(
            f"search_albedo_update {opt.search_albedo_update!r}: bounded, anchored, iterated or off"
        )
    if opt.hold_in_fitting and not (opt.fitting_slack > 0 and opt.fitting_height > 0):
        raise ValueError(
            f"fitting_slack {opt.fitting_slack} and fitting_height {opt.fitting_height} must be "
            "positive (metres) with hold_in_fitting"
        )
    from reroom.invert.normals import check_normal_radius

    check_normal_radius(opt.normal_radius)
    full, verts, layout, labels, vert_labels = _build_problem(scan, opt, notes)
    rng = np.random.default_rng(opt.seed + 1)
    search = np.flatnonzero(np.isin(labels, opt.classes))
    if search.size > opt.max_measurements:
        search = np.sort(rng.choice(search, opt.max_measurements, replace=False))
    prob = full.subset(search)
    t_transfer = time.perf_counter() - t0

    # Candidate positions: free space inside the rooms, away from every surface.
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    axes = [np.arange(lo[c] + opt.grid_step / 2, hi[c], opt.grid_step) for c in range(3)]
    cand = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    dist, _ = cKDTree(verts).query(cand, workers=-1)
    cand = cand[(dist >= opt.surface_margin) & _room_mask(cand, layout)]
    if len(cand) == 0:
        raise ReroomError(f"{scan / 'layout' / 'layout.json'}: no free space inside the rooms")
    sub = np.sort(rng.choice(len(prob.pil), min(opt.score_measurements, len(prob.pil)), False))
    s_grid = shading_matrix(
        prob.points[sub],
        prob.normals[sub],
        cand,
        prob.caster.visibility_matrix(prob.points[sub], prob.normals[sub], cand),
    )
    kind = np.zeros(len(cand), bool)  # True: a downward light (upper half shaded)
    if opt.downward_candidates:
        below = prob.points[sub, 2:3] < cand[None, :, 2]
        s_grid = np.hstack([s_grid, s_grid * below])
        kind = np.r_[kind, np.ones(len(cand), bool)]
        cand = np.vstack([cand, cand])
    s_norm2 = (s_grid**2).sum(axis=0) + 1e-300
    box_lo, box_hi = lo + 0.05, hi - 0.05
    # Per light: the room, or the fitting a light was found in (see below).
    bounds = (np.zeros((0, 3)), np.zeros((0, 3)))
    soft = opt.soft_scale

    # First albedos: the robust minimum of pi L / E_ind; first strengths of the other lights.
    ratio = full.pil / np.maximum(full.e_ind, 1e-12)
    u = np.array(
        [1.0 / max(np.percentile(ratio[full.cls == j], opt.albedo_percentile), 1e-6)
         if np.any(full.cls == j) else 1.0 for j in range(len(full.classes))]
    )  # fmt: skip
    u0 = u.copy()
    x = _nonneg_fit(prob.other, prob.direct(u, np.zeros(prob.other.shape[1])))
    pos, inten, down = np.zeros((0, 3)), np.zeros(0), np.zeros(0, bool)
    history: list[dict] = []
    reason = "max lights"
    rms = float(np.sqrt(np.mean((prob.direct(u, x) / prob.scale) ** 2)))
    for it in range(opt.max_lights):
        if time.perf_counter() - t0 > opt.time_limit:
            reason = "time limit"
            break
        vis = prob.visibility(pos, down)
        r = prob.direct(u, x)
        if len(pos):
            r = r - shading_matrix(prob.points, prob.normals, pos, vis) @ inten
        if opt.discovery == "fixed":
            # Robust: a few huge residuals (fixtures, specular spots) must not pick the light.
            clip = 30.0 * soft * prob.scale
            rs = np.clip(r[sub], -clip, clip)
            num = s_grid.T @ rs
            gain = np.where(num > 0, num**2 / s_norm2, 0.0) / max(float(rs @ rs), 1e-300)
            start = np.maximum(num / s_norm2, 0.0)
        else:
            known = [prob.other[sub][:, x > 0]]
            if len(pos):
                known.append(shading_matrix(prob.points[sub], prob.normals[sub], pos, vis[sub]))
            gain, start = _discovery_gain(s_grid, r[sub], np.hstack(known), soft * prob.scale)
        j = int(np.argmax(gain))
        entry = {"candidate": cand[j].tolist(), "downward": bool(kind[j]), "gain": float(gain[j])}
        if gain[j] < opt.min_gain:
            reason = f"best new light explains {gain[j]:.0%} < {opt.min_gain:.0%}"
            history.append(entry)
            break
        new_pos = np.vstack([pos, cand[j]])
        new_int = np.concatenate([inten, [start[j]]])
        new_down = np.r_[down, kind[j]]
        b_lo, b_hi = box_lo, box_hi
        if opt.hold_in_fitting and vert_labels is not None:
            axis = _fitting_axis(verts, vert_labels, cand[j], opt.mount_radius)
            if axis is not None:
                # Found inside a fitting the scan shows (a lamp's shade): the fit keeps the
                # starting point's visibility (the shade's openings), so a light let
                # loose drifts out of the shade and keeps them (docs/localize.md,
                # session 13). Keep it on the fitting's axis, at about its height.
                new_pos[-1, :2] = axis
                d = np.array([opt.fitting_slack, opt.fitting_slack, opt.fitting_height])
                b_lo = np.maximum(box_lo, new_pos[-1] - d)
                b_hi = np.minimum(box_hi, new_pos[-1] + d)
        new_bounds = (np.vstack([bounds[0], b_lo]), np.vstack([bounds[1], b_hi]))
        new_u, new_x = u, x
        if opt.search_albedo_update == "anchored":
            # One step from the robust minimum: the update has no fixed point (docs).
            new_pos, new_int, new_x, _r = _joint_fit(
                prob, new_pos, new_int, u0, new_x, new_bounds, soft, new_down
            )
            new_u = _update_albedo(prob, new_pos, new_int, new_x, u0, new_down)
            new_pos, new_int, new_x, _r = _joint_fit(
                prob, new_pos, new_int, new_u, new_x, new_bounds, soft, new_down
            )
        else:
            for _ in range(2):
                new_pos, new_int, new_x, _r = _joint_fit(
                    prob, new_pos, new_int, new_u, new_x, new_bounds, soft, new_down
                )
                if opt.search_albedo_update in ("iterated", "bounded"):
                    new_u = _update_albedo(prob, new_pos, new_int, new_x, new_u, new_down)
                if opt.search_albedo_update == "bounded":
                    b = 1.0 + opt.search_albedo_bound
                    new_u = np.clip(new_u, u0 / b, u0 * b)
        new_pos, new_int, new_x, new_rms = _joint_fit(
            prob, new_pos, new_int, new_u, new_x, new_bounds, soft, new_down
        )
        share = new_int[-1] / max(float(new_int.sum()), 1e-300)
        entry.update(positions=new_pos.tolist(), intensities=new_int.tolist(), rms=new_rms)
        history.append(entry)
        if share < opt.min_power:
            reason = f"new light carries {share:.1%} < {opt.min_power:.0%} of the intensity"
            break
        pos, inten, down, u, x, rms = new_pos, new_int, new_down, new_u, new_x, new_rms
        bounds = new_bounds
        if progress is not None:
            progress("localize", it + 1, opt.max_lights)
    keep = inten >= opt.min_power * max(float(inten.sum()), 1e-300)
    pos, inten, down = pos[keep], inten[keep], down[keep]
    bounds = (bounds[0][keep], bounds[1][keep])
    pos, inten, x, down, pruned, bounds = _prune(
        prob, pos, inten, u, x, bounds, soft, opt.prune_ratio, down
    )
    # Albedos of every class (the floor too) from the lights found, then the goniometric
    # test; the test changes what the lights put on the surfaces (an isotropic downlight
    # found low lights the ceiling, the real one does not), so the albedos are estimated
    # again from its lights and the test repeated from the isotropic lights.
    u_search = {c: u[j] for j, c in enumerate(full.classes) if c in opt.classes}
    u_found = u.copy()
    floating: list[dict] = []
    merged: list[dict] = []
    while True:
        u = u_found.copy()
        direct = shading_matrix(full.points, full.normals, pos, full.visibility(pos, down)) @ inten
        profiles: list[dict | None] = [None] * len(pos)
        for _ in range(opt.albedo_rounds):
            u = _albedo_from(full, direct, u)
            profiles = _goniometric_test(
                full, pos, inten, u, (lo, hi), layout, opt, verts, vert_labels, down
            )
            direct = _lights_direct(full, pos, inten, profiles, down)
        placed = pos.copy()
        for k, pr in enumerate(profiles):
            if pr is not None:
                placed[k] = pr["position"]
        held = np.ones(len(pos), bool)
        for k, into in _one_fixture(placed, profiles, inten, opt.one_fixture_m):
            held[k] = False
            merged.append(
                {
                    "position": placed[k].tolist(),
                    "into": placed[into].tolist(),
                    "distance_m": float(np.linalg.norm(placed[k] - placed[into])),
                }
            )
        if held.all() and opt.drop_floating and vert_labels is not None:
            for k, why in _unheld(full.caster, verts, vert_labels, placed, profiles, opt):
                held[k] = False
                floating.append({"position": placed[k].tolist(), "reason": why})
        if held.all():
            break
        # A light that nothing can hold is a fit of light the other models miss (a
        # window's grazing patch on `box`), and one placed at another's fixture is that
        # fixture's: drop it, refit the rest, place them again.
        pos, inten, down = pos[held], inten[held], down[held]
        bounds = (bounds[0][held], bounds[1][held])
        if len(pos):
            pos, inten, x, rms = _joint_fit(prob, pos, inten, u_found, x, bounds, soft, down)
    u = _albedo_from(full, direct, u)
    pos, inten = pos.copy(), inten.copy()
    for k, pr in enumerate(profiles):
        if pr is not None:
            pos[k], inten[k] = pr["position"], pr["mean_intensity"]
    res = ScanLocalizeResult(
        pos,
        inten,
        {CLASS_NAMES.get(c, str(c)): float(1.0 / u[j]) for j, c in enumerate(full.classes)},
        {nm: float(v) for nm, v in zip(prob.other_names, x, strict=True)},
        rms,
        time.perf_counter() - t0,
        history,
        profiles,
    )
    info = {
        "receivers": int(len(prob.pil)),
        "receivers_goniometric_test": int(len(full.pil)),
        "classes": [CLASS_NAMES.get(c, str(c)) for c in opt.classes],
        "candidates": int(len(cand)),
        "albedo": res.albedo,
        "albedo_search": {CLASS_NAMES.get(c, str(c)): float(1 / v) for c, v in u_search.items()},
        "other_lights": res.other_lights,
        "rms_relative": rms,
        "stopped": reason,
        "leave_one_out": pruned,
        "floating": floating,
        "one_fixture": merged,
        "downward": down.tolist(),
        "goniometric": [
            None if pr is None else {k: v for k, v in pr.items() if k != "profile"}
            for pr in profiles
        ],  # fmt: skip
        "transfer_seconds": t_transfer,
        "seconds": res.seconds,
        "notes": notes,
        "options": asdict(opt),
    }
    return res, info


def _one_fixture(placed: np.ndarray, profiles, inten: np.ndarray, within: float):
    """Pairs ``(k, into)``: light ``k`` placed within ``within`` metres of a stronger ``into``.

    Strength is the goniometric profile's mean intensity where the test gave one, else
    the isotropic intensity. Strongest first, so a chain of three keeps one.
    """
    strength = np.array(
        [
            float(pr["mean_intensity"]) if pr is not None else float(i)
            for pr, i in zip(profiles, inten, strict=True)
        ]
    )
    kept: list[int] = []
    out = []
    for k in np.argsort(-strength, kind="stable"):
        near = [j for j in kept if np.linalg.norm(placed[k] - placed[j]) < within]
        if near:
            out.append((int(k), near[0]))
        else:
            kept.append(int(k))
    return out


def _cost(prob: _Problem, pos, inten, u, x, soft: float, down=None) -> float:
    """Soft-L1 cost of the search receivers' residual (the joint solve's objective)."""
    r = prob.direct(u, x)
    if len(pos):
        r = r - shading_matrix(prob.points, prob.normals, pos, prob.visibility(pos, down)) @ inten
    return _soft_cost(r / prob.scale, soft)


def _prune(prob: _Problem, pos, inten, u, x, bounds, soft: float, ratio: float, down=None):
    """Drop lights the data do not need: leave each out (weakest first), re-solve, and drop
    it when the cost grows by less than ``ratio`` (the thesis's real scenes drop weak lights,
    §6.6.3; 2D: :func:`~reroom.localize.solve.prune_lights`). Returns the lights, the other
    lights' strengths, the ``down`` flags, per light tried the cost ratio measured, and the
    kept lights' position bounds (``bounds``: per light, ``(k, 3)`` each)."""
    tried: list[dict] = []
    down = np.zeros(len(pos), bool) if down is None else np.asarray(down, bool)
    while len(pos) > 1:
        # The same solve on both sides: a re-solve alone can lower the cost.
        pos, inten, x, _ = _joint_fit(prob, pos, inten, u, x, bounds, soft, down)
        base = _cost(prob, pos, inten, u, x, soft, down)
        dropped = False
        for i in np.argsort(inten):
            keep = np.arange(len(pos)) != i
            b2 = (bounds[0][keep], bounds[1][keep])
            p2, i2, x2, _ = _joint_fit(prob, pos[keep], inten[keep], u, x, b2, soft, down[keep])
            grow = _cost(prob, p2, i2, u, x2, soft, down[keep]) / max(base, 1e-300)
            tried.append({"position": pos[i].tolist(), "cost_ratio_without": grow})
            if grow < ratio:
                pos, inten, x, down, dropped, bounds = p2, i2, x2, down[keep], True, b2
                tried[-1]["dropped"] = True
                break
        if not dropped:
            break
    return pos, inten, x, down, tried, bounds


def _soft_cost(r: np.ndarray, scale: float) -> float:
    """Soft-L1 cost ``sum 2 (sqrt(1 + (r / scale)^2) - 1)`` (scipy's ``soft_l1``)."""
    z = (r / scale) ** 2
    return float(np.sum(2.0 * (np.sqrt(1.0 + z) - 1.0)))


def _goniometric_test(
    prob: _Problem,
    pos: np.ndarray,
    inten: np.ndarray,
    u: np.ndarray,
    box: tuple[np.ndarray, np.ndarray],
    layout: dict,
    opt: ScanLocalizeOptions,
    verts: np.ndarray | None = None,
    vert_labels: np.ndarray | None = None,
    down: np.ndarray | None = None,
) -> list[dict | None]:
    """Test each light as a goniometric light (intensity by inclination) at other heights.

    An isotropic model of a downlight (a narrow beam from the ceiling) puts it far too
    low: the pool it lights is fitted by a close isotropic light. For each light, the
    receivers within ``profile_radius`` (horizontally) are fitted with the other lights
    fixed, by an inclination profile at heights along the vertical through the light (the
    profile is linear: NNLS), and by the isotropic light at its own position. The light
    becomes goniometric when the best height's soft-L1 cost with ``profile_bins`` bins is
    at least ``profile_gain`` lower than the isotropic one's; its height is then the best
    with ``height_bins`` bins (finer). Then, with ``verts`` (the scan's mesh vertices) and
    ``opt.mount_test``, the mount test (:func:`_mount_test`) may move it up to the
    surface above it. Returns, per light, None (kept isotropic) or the new position, the
    profile, its mean intensity over the sphere, the costs per height and the mount test.
    """
    from reroom.invert.basis import InclinationBasis
    from reroom.invert.direct import point_light_transfer

    out: list[dict | None] = []
    if len(pos) == 0:
        return out
    if opt.height_bins % opt.profile_bins:
        raise ValueError(f"height_bins {opt.height_bins} is not a multiple of {opt.profile_bins}")
    basis = InclinationBasis(opt.height_bins)
    merge = opt.height_bins // opt.profile_bins
    edges = np.linspace(0.0, np.pi, opt.height_bins + 1)
    solid = 2.0 * np.pi * (np.cos(edges[:-1]) - np.cos(edges[1:]))
    target = prob.direct(u, np.zeros(prob.other.shape[1]))
    vis = prob.visibility(pos, down)
    s_all = shading_matrix(prob.points, prob.normals, pos, vis)
    scale = opt.soft_scale * prob.scale
    for k in range(len(pos)):
        near = np.linalg.norm(prob.points[:, :2] - pos[k, :2], axis=1) < opt.profile_radius
        if near.sum() < 20:
            out.append(None)
            continue
        p_n, n_n = prob.points[near], prob.normals[near]
        others = np.delete(s_all[near], k, axis=1)
        base = np.hstack([prob.other[near], others])
        b = target[near]
        shared = _SharedNNLS(base, b)
        iso_cost = _soft_cost(shared.fit(s_all[near, k : k + 1])[1], scale)
        heights = np.arange(box[0][2] + 0.1, box[1][2] - 0.02, opt.profile_step)
        cands = np.column_stack(
            [np.full_like(heights, pos[k, 0]), np.full_like(heights, pos[k, 1]), heights]
        )
        cands = cands[_room_mask(cands, layout, margin_floor=0.1)]

        def fit_at(q, shared=shared, p_n=p_n, n_n=n_n):
            """Soft-L1 cost, transfer and coefficients of a goniometric light at ``q``."""
            f = point_light_transfer(prob.caster, p_n, n_n, q, [0.0, 0.0, 1.0], basis)
            coef, resid = shared.fit(f)
            return _soft_cost(resid, scale), f, coef

        costs, coarse, profiles = [], [], []
        for i, c in enumerate(cands):
            cost, f, coef = fit_at(c)
            axis = None
            if opt.enclosed_axis and verts is not None and vert_labels is not None:
                axis = _fitting_axis(verts, vert_labels, c, opt.mount_radius)
            if axis is not None and np.linalg.norm(axis - c[:2]) > 1e-3:
                # Inside a fitting, its aperture shapes the light: the pool moves by the
                # throw over the aperture's distance (~10x) times any horizontal error,
                # so the fit there is only good on the fitting's axis. Try it too.
                q = np.array([axis[0], axis[1], c[2]])
                on_axis = fit_at(q)
                if on_axis[0] < cost:
                    cands[i] = q
                    cost, f, coef = on_axis
            costs.append(cost)
            profiles.append(coef[-basis.bins :])
            if merge == 1:
                coarse.append(costs[-1])
            else:  # the same bins merged in groups: the decision's profile
                merged = f.reshape(len(f), opt.profile_bins, merge).sum(axis=2)
                coarse.append(_soft_cost(shared.fit(merged)[1], scale))
        if not costs or min(coarse) > (1.0 - opt.profile_gain) * iso_cost:
            out.append(None)
            continue
        costs_a = np.asarray(costs)
        j = int(np.argmin(costs_a))
        mount = None
        if opt.mount_test and verts is not None:

            def evaluate(q, fit_at=fit_at):
                cost, _, coef = fit_at(q)
                return cost, coef[-basis.bins :]

            mount = _mount_test(
                prob.caster, verts, cands, costs_a, profiles[j], j, solid, opt, vert_labels,
                evaluate,
            )  # fmt: skip
            if mount["mounted"]:
                j = mount["index"]
            elif vert_labels is not None and opt.keep_enclosed:
                # A light inside a fitting the scan shows (a shade around it) is where the
                # fitting is: the search's height, not the weakly determined cost curve's.
                if _enclosed(verts, vert_labels, pos[k], opt.mount_radius):
                    j = int(np.argmin(np.abs(cands[:, 2] - pos[k, 2])))
                    mount["enclosed"] = True
        place, profile, cost_j = cands[j], profiles[j], float(costs_a[j])
        if mount is not None and mount["mounted"] and "position" in mount:
            place, profile = np.asarray(mount.pop("position")), mount.pop("profile")
            cost_j = mount["cost_ratio"] * float(costs_a.min())
            mount["position"] = place.tolist()
        out.append({
            "position": place.tolist(),
            "moved_m": float(np.linalg.norm(place - pos[k])),
            "profile": profile.tolist(),
            "mean_intensity": float(profile @ solid / (4.0 * np.pi)),
            "cost_isotropic": iso_cost,
            "cost_goniometric_decision": float(min(coarse)),
            "cost_goniometric": cost_j,
            "heights": cands[:, 2].round(3).tolist(),
            "costs": costs_a.round(2).tolist(),
            "mount": mount,
        })  # fmt: skip
    return out


def _enclosed(verts: np.ndarray, labels: np.ndarray, p: np.ndarray, radius: float) -> bool:
    """Is ``p`` inside a fitting the scan shows (a lamp's shade around the bulb)?

    Vertices other than wall, floor and ceiling within ``radius`` of ``p`` horizontally
    and vertically must surround it: their directions around its vertical cover at least
    6 of 8 sectors (a lamp's pole beside a light found below the shade covers one).
    """
    d = verts - p
    body = (
        (np.linalg.norm(d[:, :2], axis=1) < radius)
        & (np.abs(d[:, 2]) < radius)
        & ~np.isin(labels, (WALL, FLOOR, CEILING))
    )
    if not body.any():
        return False
    sector = np.floor((np.arctan2(d[body, 1], d[body, 0]) + np.pi) / (np.pi / 4)).astype(int) % 8
    return len(np.unique(sector)) >= 6


def _fitting_axis(
    verts: np.ndarray, labels: np.ndarray, p: np.ndarray, radius: float, band: float = 0.1
) -> np.ndarray | None:
    """The x, y of the axis of the fitting around ``p`` (a shade's centre), or None.

    None when ``p`` is not inside a fitting (:func:`_enclosed`). The axis is the centre
    of the circle fitted (algebraically, Kasa) to the fitting's vertices within ``band``
    of ``p``'s height: a circle fit, not their mean, because a scan often shows one side
    of a lamp in a corner only (on the 300-frame `furnished` scan the mean is 3 cm off,
    the circle's centre 0.6 cm).
    """
    if not _enclosed(verts, labels, p, radius):
        return None
    d = verts - p
    ring = (
        (np.linalg.norm(d[:, :2], axis=1) < radius)
        & (np.abs(d[:, 2]) < band)
        & ~np.isin(labels, (WALL, FLOOR, CEILING))
    )
    if ring.sum() < 10:
        return None
    from reroom.lights.pools import fit_circle

    centre, _ = fit_circle(verts[ring, :2])
    if not np.isfinite(centre).all() or np.linalg.norm(centre - p[:2]) > radius:
        return None
    return centre


def _floating(
    caster, verts: np.ndarray, labels: np.ndarray, p: np.ndarray, opt: ScanLocalizeOptions
) -> str | None:
    """Why nothing in the scan can hold a light at ``p`` (None: something can).

    A light hangs from, stands on or is fixed to something: it is held when it sits
    within ``mount_depth`` of the surface above it (a ceiling fitting), or when the scan
    shows anything but floor and ceiling within ``mount_radius`` of its vertical, from
    ``hold_reach`` below the light up to that surface (a lamp's shade or the top of its
    stand, a pendant's shade, a wall for a sconce). A table far below does not hold it.
    """
    hit = caster.intersect(p[None], np.array([[0.0, 0.0, 1.0]]))
    top = float(p[2] + hit.t[0]) if bool(hit.hit[0]) else np.inf
    if top - p[2] <= opt.mount_depth:
        return None
    near = np.linalg.norm(verts[:, :2] - p[:2], axis=1) < opt.mount_radius
    body = near & (verts[:, 2] < top - opt.mount_clearance) & ~np.isin(labels, (FLOOR, CEILING))
    body &= verts[:, 2] > p[2] - opt.hold_reach
    if body.any():
        return None
    return (
        f"floating: {top - p[2]:.2f} m below the surface above, and nothing but floor and "
        f"ceiling within {opt.mount_radius} m of its vertical from {opt.hold_reach} m below "
        "it up (no shade, stand, pendant or wall): dropped"
    )


def _unheld(
    caster, verts: np.ndarray, labels: np.ndarray, placed: np.ndarray, profiles: list, opt
) -> list[tuple[int, str]]:
    """``(index, reason)`` of each placed light that nothing in the scan can hold.

    A light the mount test mounted on the surface above (``profiles[k]["mount"]``) is
    held by that surface. Testing it again with :func:`_floating` would cast upwards
    from its refitted x, y, where a fused ceiling can sit a few millimetres higher: a
    light mounted exactly ``mount_depth`` below the ceiling then read as floating and was
    dropped (session 13: the downlight of session 6's `furnished` scan).
    """
    out = []
    for k, p in enumerate(placed):
        mount = (profiles[k] or {}).get("mount") or {}
        if mount.get("mounted"):
            continue
        why = _floating(caster, verts, labels, np.asarray(p, float), opt)
        if why is not None:
            out.append((k, why))
    return out


def _mount_test(
    caster,
    verts: np.ndarray,
    cands: np.ndarray,
    costs: np.ndarray,
    profile: np.ndarray,
    best: int,
    solid: np.ndarray,
    opt: ScanLocalizeOptions,
    vert_labels: np.ndarray | None = None,
    evaluate: Callable[[np.ndarray], tuple[float, np.ndarray]] | None = None,
) -> dict:
    """Where is the body that shades a light's upper hemisphere?

    The goniometric test finds a downlight's height only weakly (on ``furnished`` the
    costs of heights 0.5 m apart differ by a few %), but two things the scan shows decide
    it. (1) The fitted profile sends at most ``mount_up_flux`` of its flux upwards (the
    ceiling and upper walls show none of its light): light does not stop by itself, so
    an opaque body above the light blocks it. (2) The mesh shows no such body: no vertex
    within ``mount_radius`` of the light's vertical, from ``mount_radius`` below the light
    up to ``mount_clearance`` under the first surface above it (a ray cast upwards; the
    surface must be roughly horizontal, i.e. a ceiling). Then the body is that surface
    itself (a recessed fitting, its housing above the ceiling, unscanned), and the light
    is taken at the best of the tested heights within ``mount_depth`` below it, provided
    its cost is at most ``mount_tolerance`` above the best height's: the data must
    allow it. A pendant's or a shade's mesh, or a light that lights the ceiling, leaves
    the light where the costs put it. ``cands``/``costs``: the tested positions (along
    one vertical) and their costs; ``best``: the index of the lowest cost.

    A light that sends light upwards needs no body above it, but it needs one to hold
    it: with ``vert_labels`` (the scan's layout labels) and ``opt.mount_unsupported``,
    when no vertex other than floor and ceiling lies within ``mount_radius`` of its
    vertical below the surface above (no lamp, no shade, no stand, no wall a sconce could
    hang on), nothing holds the light where the costs put
    it, and it is mounted on the surface above under the same condition on the costs.
    (``box_points``: a wide-beam downlight fitted 0.15 m above the floor sends 12 % of
    its flux up; on the floor lamps the shade is in the scan.)

    With ``evaluate(position) -> (cost, profile)`` (the goniometric test's fit at any
    position) and ``opt.mount_shift``, the mounted light's x, y are refitted too, on a
    0.05 m grid within ``mount_shift`` of the vertical: a light found low is found with
    its x, y off, and the comparison is between the best of both placements.
    """
    half = len(profile) // 2
    total = float(profile @ solid)
    up = float(profile[:half] @ solid[:half]) / total if total > 0 else 1.0
    res: dict = {"upward_flux": up, "mounted": False}
    unsupported = up > opt.mount_up_flux
    if unsupported and (vert_labels is None or not opt.mount_unsupported):
        res["reason"] = "the light sends light upwards: nothing needs to shade it"
        return res
    p = cands[best]
    hit = caster.intersect(p[None], np.array([[0.0, 0.0, 1.0]]))
    if not bool(hit.hit[0]) or abs(float(hit.normals[0, 2])) < 0.7:
        res["reason"] = "no horizontal surface above the light"
        return res
    top = float(p[2] + hit.t[0])
    res["surface_above_z"] = top
    near = np.linalg.norm(verts[:, :2] - p[:2], axis=1) < opt.mount_radius
    body = (
        near & (verts[:, 2] > p[2] - opt.mount_radius) & (verts[:, 2] < top - opt.mount_clearance)
    )
    if unsupported:  # what could hold it, at any height below: not floor or ceiling
        body = near & (verts[:, 2] < top - opt.mount_clearance)
        body &= ~np.isin(vert_labels, (FLOOR, CEILING))
    res["fitting_vertices"] = int(body.sum())
    if body.any():
        res["reason"] = (
            "the light sends light upwards and the scan shows what holds it"
            if unsupported
            else "the scan shows a body above or around the light (a fitting)"
        )
        return res
    band = np.flatnonzero((cands[:, 2] >= top - opt.mount_depth) & (cands[:, 2] < top))
    if band.size == 0:
        res["reason"] = "no tested height just below the surface above"
        return res
    j = int(band[np.argmin(costs[band])])
    cost_top = float(costs[j])
    if evaluate is not None and opt.mount_shift > 0:
        n = int(round(opt.mount_shift / 0.05))
        steps = 0.05 * np.arange(-n, n + 1)
        for dx in steps:
            for dy in steps:
                if dx == 0 and dy == 0:
                    continue
                q = cands[j] + [dx, dy, 0.0]
                c, prof = evaluate(q)
                if c < cost_top:
                    cost_top = c
                    res.update(position=q.tolist(), profile=prof, shift_m=float(np.hypot(dx, dy)))
    ratio = float(cost_top / max(costs[best], 1e-300))
    res["cost_ratio"] = ratio
    if ratio > 1.0 + opt.mount_tolerance:
        res["reason"] = "the data reject a light just below the surface above"
        return res
    why = "nothing holds the light" if unsupported else "no fitting in the scan"
    res.update(mounted=True, index=j, reason=f"{why}: mounted on the surface above")
    return res


def _localized_light(name: str, p: np.ndarray, it: float, info: dict, k: int | None = None):
    """The ``k``-th localized light as a :class:`~reroom.lights.lightset.Light`.

    A light the mount test held by the surface above (``info["goniometric"][k]``) says so
    in ``evidence["mounted_on"]``: ``reroom invert``'s position refinement keeps it near
    that surface.
    """
    from reroom.lights.lightset import Light

    light = Light(
        name=name,
        type="point",
        source="localize",
        geometry={"position": [float(c) for c in p], "axis": [0.0, 0.0, 1.0]},
        evidence={
            "intensity": float(it),
            "intensity_units": "pi * radiance / albedo * m^2 (the scan's radiance units)",
            "albedo": info.get("albedo", {}),
        },
        reason=LOCALIZED_REASON,
    )
    profiles = info.get("goniometric") or []
    mount = (profiles[k] or {}).get("mount") if k is not None and k < len(profiles) else None
    if mount and mount.get("mounted") and "surface_above_z" in mount:
        light.evidence["mounted_on"] = {
            "surface_z": float(mount["surface_above_z"]),
            "reason": str(mount.get("reason", "")),
        }
    return light


#: Evidence of a light placed from its pool's edge that a merge carries over.
_POOL_EDGE_KEYS = (
    "height_from",
    "opening_radius_m",
    "pool_edge_radius_m",
    "edge_sectors",
    "pool",
    "object_top_m",
)


def merge_localized_lights(
    lights, res: ScanLocalizeResult, info: dict, match_distance: float = 0.5
) -> list[str]:
    """Put the localized point lights into a light set (in place).

    A point light already in ``lights`` within ``match_distance`` of a localized one (a
    detected guess, or an earlier localization) is replaced in place (its name and index
    kept, so ``vertex_light_id`` stays valid); the others are appended as ``localizedK``.
    A light whose place ``reroom lights`` measured from its ceiling pool's edge
    (``evidence["height_from"] == "pool edge"``) keeps that place and takes the rest
    from the localization. User-placed point lights are never replaced. Returns what was
    done, in words.
    """
    done = []
    points = [i for i, x in enumerate(lights.lights) if x.type == "point" and x.source != "user"]
    used: set[int] = set()
    taken = {x.name for x in lights.lights}
    k = 0
    for j, (p, it) in enumerate(zip(res.positions, res.intensities, strict=True)):
        best, best_d = None, match_distance
        for i in points:
            d = float(np.linalg.norm(lights.lights[i].anchor() - p))
            if i not in used and d < best_d:
                best, best_d = i, d
        if best is not None:
            old = lights.lights[best]
            # A bulb in an open-topped shade placed from its pool's edge (reroom lights,
            # bulb_from_pool_edge) keeps that place: the edge is pure geometry, while the
            # fit here depends on the mesh's occlusion by the shade, which a fused scan
            # gets wrong (docs/localize.md, "Session 8").
            measured = old.evidence.get("height_from") == "pool edge"
            q = np.asarray(old.anchor(), float) if measured else p
            new = _localized_light(old.name, q, it, info, j)
            new.evidence["replaces"] = {
                "position": old.geometry.get("position"),
                "reason": old.reason,
            }
            if measured:
                for key in _POOL_EDGE_KEYS:
                    if key in old.evidence:
                        new.evidence[key] = old.evidence[key]
                new.evidence["localized_position"] = [float(c) for c in p]
                done.append(
                    f"{old.name}: kept at {np.round(q, 2).tolist()}, its place measured from "
                    f"its pool's edge (localization found it {best_d:.2f} m away, at "
                    f"{np.round(p, 2).tolist()}; {LOCALIZED_REASON})"
                )
            else:
                done.append(
                    f"{old.name}: moved {best_d:.2f} m to {np.round(p, 2).tolist()} "
                    f"({LOCALIZED_REASON})"
                )
            lights.lights[best] = new
            used.add(best)
        else:
            while f"localized{k}" in taken:
                k += 1
            name = f"localized{k}"
            taken.add(name)
            lights.lights.append(_localized_light(name, p, it, info, j))
            done.append(f"{name}: added at {np.round(p, 2).tolist()} ({LOCALIZED_REASON})")
    lights.meta["localize"] = info
    return done


def write_localized_lights(res: ScanLocalizeResult, info: dict, out_dir: str | Path) -> Path:
    """Write the localized lights alone as ``lights.json`` (light-description schema).

    Also writes ``localize.json`` (the run's ``info`` and the discoveries) next to it.
    """
    from reroom.io.atomic import atomic_write_json
    from reroom.lights.lightset import LightSet, write_lights

    ls = LightSet(notes=[], meta={})
    merge_localized_lights(ls, res, info)
    path = write_lights(ls, out_dir)
    report = {"info": info, "history": res.history, "goniometric": res.goniometric}
    atomic_write_json(Path(out_dir) / "localize.json", report)
    return path


def localize_into_lights(
    scan_dir: str | Path,
    res: ScanLocalizeResult,
    info: dict,
    lights_dir: str | Path | None = None,
    match_distance: float = 0.5,
) -> tuple[Path, list[str]]:
    """Merge the localized point lights into ``SCAN/lights/lights.json`` (the hand-off).

    ``reroom invert`` reads point lights from there, so after this it needs no
    user-placed positions. See :func:`merge_localized_lights` for how a detected point
    light at the same place is replaced rather than duplicated.

    Returns
    -------
    path:
        The ``lights.json`` written.
    done:
        What changed, in words.

    Raises
    ------
    reroom.lights.LightsError
        ``lights.json`` is missing or malformed (run ``reroom lights SCAN`` first).
    """
    from reroom.lights.lightset import load_lights, write_lights

    folder = Path(lights_dir) if lights_dir is not None else Path(scan_dir) / "lights"
    lights = load_lights(folder / "lights.json")
    done = merge_localized_lights(lights, res, info, match_distance)
    lights.notes = [n for n in lights.notes if "localiz" not in n] + [
        f"{len(res.positions)} point light(s) from `reroom localize` (thesis ch. 6)"
    ]
    return write_lights(lights, folder), done
