"""The recovered room model as a Mitsuba 3 scene dict (thesis §5.7: "rendered with PBRT").

:func:`model_scene` turns what ``reroom invert`` wrote (``SCAN/invert/scene.json`` and
``albedo.ply``) plus the light geometry of ``reroom lights`` into a plain Mitsuba scene
dict, in the spirit of Mitsuba's own Python API: edits are changes to that dict (or to the
model documents before it), and the same path tracer that made the synthetic truth
renders it.

* **Surfaces**: the scan mesh with its per-vertex albedo (``albedo.ply``) through a
  ``mesh_attribute`` texture. Vertices without an albedo (unobserved) take the harmonic
  interpolation of their known neighbours over the mesh (:func:`fill_unknown_albedo`);
  non-physical values (> 1) are clipped to ``max_albedo`` for rendering only
  (``albedo.ply`` keeps them).
* **Area lights**: with an ``outline`` in their geometry (``reroom invert``'s
  ``area_outline``), the part of the faces touching the light's vertices inside it, as
  the transfer integrated it (where those faces reach past its vertices, a millimetre
  in front of the scanned surface, with the light's rim faces behind it as surface);
  without one, the faces of the light's own
  vertices (at least two of three, so the light ends half-way into its rim triangles as
  in the transfer then). Either emits the solved radiance on its front side.
* **Windows**: a black rectangle on the window's opening carrying a ``reroom_portal``
  emitter that shows the window's map ``environment_exr`` (``window_<name>.exr``: the
  solved cube-map cells shaped within each cell by the photos' pixels seen through the
  opening, :mod:`reroom.invert.window_env`; the plain cells are
  ``window_<name>_cells.exr``).
* **Point lights**: ``reroom_goniometric`` with the solved inclination profile about the
  light's axis (``interpolation`` between bin centres, or constant per bin as solved).
* **Line lights**: ``reroom_line`` with the solved profile: ``(theta, phi)`` bins around
  and along the line (``distribution.phi_bins``), or the separable ``theta`` profile of
  files written before the ``phi`` bins.
  Both get the shadow clearance the profile was solved with
  (``distribution.shadow_clearance``): nothing that close to the light shadows it, as in
  the transfer, since the solved profile already holds the fixture's own occlusion.
* **Glowing fittings**: faces of vertices ``albedo.ply`` flags as ``light`` that are not
  an area light's (a tube's own surface) are left out of the light transport: their
  light is in the solved distribution, and their mesh would enclose the emitter. Each
  point or line light within ``GLOW_REACH`` of them gets them as a ``reroom_glow`` entry,
  which the renderer shows glowing with the radiance the solved light implies
  (:mod:`reroom.render.glow`). A line light with a fitted radius whose scanned faces lie
  further out (a fused scan's block, twice the tube's width) glows on the cylinder of
  that radius instead.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from reroom.errors import ReroomError, ScanError
from reroom.io.images import read_exr
from reroom.io.jsonfile import read_json
from reroom.io.mesh import read_ply, write_ply
from reroom.rays.geometry import segment_distance

__all__ = [
    "DEFAULT_MAX_DEPTH",
    "GLOW_REACH",
    "fill_unknown_albedo",
    "model_scene",
    "point_light_table",
]

#: Path depth of the model's renders. The truth renders go to 256 with Russian roulette;
#: depth 8 (the default before session 7) dropped the light of the deeper bounces, which
#: in these rooms (wall 0.66, ceiling 0.8) made every render about 2 % dark (ratio of
#: means to the truth 0.926 -> 0.947 on the fidelity benchmark's input frames). Russian
#: roulette keeps the long paths cheap; a cap stays, as an unbounded path hung with the
#: ``ldsampler`` of before session 45 (docs/benchmarks.md, "Synthetic scan generator").
DEFAULT_MAX_DEPTH = 64

#: Glowing faces within this distance (metres) of a point light or of a line light's
#: segment are that light's visible glow (a bulb, a tube's surface). Tight, as the bright
#: inside of a tube's housing is flagged too but does not glow by itself: with it the
#: glow of the furnished scene's tube spread over twice its width at half its radiance.
GLOW_REACH = {"point": 0.1, "line": 0.05}


def point_light_table(
    profile: np.ndarray, interpolation: str = "linear", n_theta: int = 181
) -> np.ndarray:
    """A ``(n_theta, 2)`` goniometric node table (theta from the nadir) of an axial profile.

    ``profile[k]`` is the intensity of bin ``k`` of theta *from the axis* (``(k + 0.5) pi /
    bins`` at its centre), as ``reroom invert`` solves it; the goniometric emitter's theta
    runs from the nadir, i.e. ``pi -`` that.
    """
    from reroom.render.line_emitter import line_profile_value

    theta_nadir = np.linspace(0.0, np.pi, n_theta)
    values = line_profile_value(np.asarray(profile, float), np.pi - theta_nadir, interpolation)
    return np.stack([values, values], axis=1)


def fill_unknown_albedo(albedo: np.ndarray, faces: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Per-vertex albedo with the unknown vertices filled from their known neighbours.

    Vertices no photo saw (a sofa's back and underside, the wall behind a cabinet) are
    given the harmonic interpolation of the known albedos over the mesh's edges: each
    unknown vertex the mean of its neighbours, the known ones fixed. An unseen side of an
    object so takes its neighbours' colour rather than a room-wide one. (The median of
    every known vertex, the fill before session 20, is a wall's colour: on `furnished` it
    painted the unseen half of the dark-blue sofa off-white. The furnishings' own seen
    vertices were the larger error there, see :mod:`reroom.edit.objects`.) A connected
    part of the mesh with no known vertex takes the median of the known ones.

    Parameters
    ----------
    albedo : ndarray, shape (n, 3)
        Albedo of the known vertices (other rows are ignored).
    faces : ndarray of int, shape (m, 3)
        The mesh's triangles (their edges connect the vertices).
    known : ndarray of bool, shape (n,)
        Which rows of ``albedo`` are known.

    Returns
    -------
    ndarray, shape (n, 3)
        ``albedo`` at the known vertices, the fill elsewhere; within the known values'
        range per channel (a harmonic interpolation has no new extremes).
    """
    import scipy.sparse as sp

    from reroom.layout.meshops import harmonic_fill, vertex_adjacency

    albedo = np.asarray(albedo, np.float64)
    known = np.asarray(known, bool)
    if not known.any():
        return np.full_like(albedo, 0.5)
    # Start every unknown vertex at the median: parts with nothing known keep it.
    start = np.where(known[:, None], albedo, np.median(albedo[known], axis=0))
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    edges = sp.triu(vertex_adjacency(faces, len(albedo))).tocoo()
    return harmonic_fill(start, known, np.stack([edges.row, edges.col], axis=1))


def surroundings_emitter(
    record: dict[str, Any] | None, source: str | Path = "scene.json"
) -> dict[str, Any] | None:
    """The constant environment that stands for what the scan does not hold
    (``scene.json`` ``surroundings``, :mod:`reroom.invert.surroundings`), or None.

    Only rays that leave the mesh through a hole see it; a closed room never does. Its
    share of next-event samples is the escaping share of the hemisphere, so that a room
    with few holes spends few shadow rays on it. A radiance that is not three finite,
    non-negative numbers (a hand-edited ``source``) is left out with a warning naming
    the file.
    """
    if not record or record.get("radiance") is None:
        return None
    try:
        rgb = np.asarray(record["radiance"], float)
    except (TypeError, ValueError):
        rgb = np.full(1, np.nan)
    if rgb.shape != (3,) or not np.all(np.isfinite(rgb)) or np.any(rgb < 0):
        warnings.warn(
            f"{source}: surroundings radiance {record['radiance']!r} is not three finite, "
            "non-negative numbers: rendered without the surroundings",
            stacklevel=2,
        )
        return None
    if not rgb.any():
        return None
    share = float(record.get("escape_fraction", 0.0))
    return {
        "type": "constant",
        "radiance": {"type": "rgb", "value": rgb.tolist()},
        # sampling_weight is relative to the lights' (their solved powers); a room of a few
        # square metres of holes sends about pi L A, A ~ share x 50 m^2 of walls.
        "sampling_weight": float(max(np.pi * rgb.mean() * 50.0 * share, 1e-6)),
    }


def model_scene(
    scan_dir: str | Path,
    invert_dir: str | Path | None = None,
    lights_dir: str | Path | None = None,
    work_dir: str | Path | None = None,
    *,
    max_depth: int = DEFAULT_MAX_DEPTH,
    interpolation: str = "linear",
    max_albedo: float = 0.95,
) -> dict[str, Any]:
    """Build the Mitsuba scene dict of a recovered room model (no sensor).

    Parameters
    ----------
    scan_dir:
        The scan folder.
    invert_dir, lights_dir:
        Outputs of ``reroom invert`` and ``reroom lights`` (default ``SCAN/invert``,
        ``SCAN/lights``).
    work_dir:
        Where the render meshes are written (default ``SCAN/render/model``).
    max_depth:
        Path depth of the ``path`` integrator.
    interpolation:
        Point and line light profiles between bin centres: ``"linear"`` (smoother
        renders) or ``"constant"`` (exactly the solved basis).
    max_albedo:
        Rendering clip of per-vertex albedo.

    Raises
    ------
    ScanError
        When a file of the model is missing or unreadable (names it).
    ReroomError
        When the model has no light.
    """
    from reroom.render import mitsuba
    from reroom.render.emitters import goniometric_light, luminaire_frame, portal_emitter
    from reroom.render.line_emitter import line_light

    mi = mitsuba()
    scan_dir = Path(scan_dir)
    inv = Path(invert_dir) if invert_dir is not None else scan_dir / "invert"
    lit = Path(lights_dir) if lights_dir is not None else scan_dir / "lights"
    work = Path(work_dir) if work_dir is not None else scan_dir / "render" / "model"
    scene_path = inv / "scene.json"
    model = read_json(scene_path, "run `reroom invert SCAN` first")
    albedo_mesh = read_ply(inv / model.get("albedo_file", "albedo.ply"))
    attrs = albedo_mesh.vertex_attributes
    if "albedo" not in attrs:
        raise ScanError(inv / "albedo.ply", "has no albedo_r/g/b vertex properties")
    albedo = np.asarray(attrs["albedo"], np.float64)
    known = np.all(albedo >= 0, axis=1) & np.all(np.isfinite(albedo), axis=1)
    albedo = fill_unknown_albedo(
        np.clip(np.where(known[:, None], albedo, 0.0), 0.0, max_albedo),
        np.asarray(albedo_mesh.faces),
        known,
    )

    vertices = np.asarray(albedo_mesh.vertices)
    faces = np.asarray(albedo_mesh.faces)
    light_id = None
    ids_path = lit / "lights_vertices.npz"
    if ids_path.is_file():
        with np.load(ids_path) as z:
            light_id = np.asarray(z["light_id"])
        if len(light_id) != len(vertices):
            raise ScanError(ids_path, f"has {len(light_id)} ids for {len(vertices)} vertices")

    work.mkdir(parents=True, exist_ok=True)
    scene: dict[str, Any] = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": int(max_depth)},
    }
    emitting = np.zeros(len(faces), bool)
    n_lights = 0
    for k, light in enumerate(model.get("lights", [])):
        kind, geo, name = light["type"], light.get("geometry", {}), light["name"]
        if kind == "area":
            if light_id is None or "light_index" not in geo:
                raise ScanError(ids_path, f"is needed for area light {name!r}")
            members = light_id == int(geo["light_index"])
            sel = members[faces].sum(axis=1) >= 2
            if not sel.any():
                continue
            emitting |= sel
            shape = _area_emitter_shape(vertices, faces, members, sel, geo, albedo)
            path = write_ply(work / f"light_{k:02d}.ply", shape[0], {})
            if shape[1] is not None:
                rim_path = write_ply(work / f"light_{k:02d}_rim.ply", *shape[1])
                scene[f"light_{k:02d}_rim"] = {
                    "type": "ply",
                    "filename": str(rim_path),
                    "bsdf": {
                        "type": "diffuse",
                        "reflectance": {"type": "mesh_attribute", "name": "vertex_albedo_color"},
                    },
                }
            scene[f"light_{k:02d}"] = {
                "type": "ply",
                "filename": str(path),
                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}},
                "emitter": {
                    "type": "area",
                    "radiance": {"type": "rgb", "value": [float(x) for x in light["radiance"]]},
                },
            }
        elif kind == "window":
            exr = inv / light.get("environment_exr", f"window_{name}.exr")
            env = np.maximum(read_exr(exr)[..., :3], 0.0)
            centre = np.asarray(geo["centre"], float)
            hu, hv = np.asarray(geo["half_u"], float), np.asarray(geo["half_v"], float)
            normal = np.asarray(geo["normal"], float)
            m = np.eye(4)
            m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = hu, hv, normal, centre
            if np.linalg.det(m[:3, :3]) < 0:
                m[:3, 0] = -hu
            scene[f"light_{k:02d}"] = {
                "type": "rectangle",
                "to_world": mi.ScalarTransform4f(m.tolist()),
                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}},
                "emitter": portal_emitter(
                    env, opening=(centre, hu, hv, normal), view=read_window_view(inv, light)
                ),
            }
        elif kind == "point":
            dist = light["distribution"]
            axis = np.asarray(geo.get("axis", [0.0, 0.0, 1.0]), float)
            scene[f"light_{k:02d}"] = goniometric_light(
                point_light_table(dist["profile"], interpolation),
                geo["position"],
                frame=luminaire_frame(nadir=-axis),
                color=light.get("color", [1.0, 1.0, 1.0]),
                clearance=float(dist.get("shadow_clearance", 0.0)),
            )
        elif kind == "line":
            from reroom.invert.export import line_profile_grid

            try:
                grid, fold = line_profile_grid(light["distribution"])
            except (KeyError, ValueError) as exc:
                raise ScanError(scene_path, f"line light {name!r}: {exc}") from exc
            scene[f"light_{k:02d}"] = line_light(
                geo["p0"],
                geo["p1"],
                grid[:, 0] if grid.shape[1] == 1 else grid,
                up=geo.get("d_perp", [0.0, 0.0, 1.0]),
                color=light.get("color", [1.0, 1.0, 1.0]),
                interpolation=interpolation,
                phi_fold=fold,
                clearance=float(light["distribution"].get("shadow_clearance", 0.0)),
            )
        else:
            raise ReroomError(f"{scene_path}: light {name!r} has an unknown type {kind!r}")
        # Next-event estimation picks one emitter per sample: by solved power rather than
        # uniformly, so weak lights (a dim downlight) do not take the strong ones' samples.
        power = light.get("power")
        if power is not None and np.all(np.isfinite(power)) and np.mean(power) > 0:
            entry = scene[f"light_{k:02d}"]
            target = entry["emitter"] if "emitter" in entry else entry
            target["sampling_weight"] = float(np.mean(power))
        n_lights += 1
    if n_lights == 0:
        raise ReroomError(f"{scene_path}: the model has no light to render")
    surroundings = surroundings_emitter(model.get("surroundings"), scene_path)
    if surroundings is not None:
        scene["surroundings"] = surroundings

    keep = ~emitting
    if "light" in attrs:
        # Vertices ``reroom invert`` joined to a light's emitter class (a tube's glowing
        # surface, a bulb within 5 cm of a point light): their light is part of the
        # solved distribution, and their mesh would enclose the line or point emitter
        # and block it (the transfer ignores geometry that close to a light), so they
        # are not rendered as surfaces.
        glow = np.asarray(attrs["light"]).astype(bool)
        glow_faces = (glow[faces].sum(axis=1) >= 2) & ~emitting
        keep &= ~glow_faces
        _add_glows(scene, model.get("lights", []), vertices, faces, glow_faces, work)
    room = write_ply(
        work / "room.ply",
        trimesh.Trimesh(vertices, faces[keep], process=False),
        {"albedo": albedo.astype(np.float32)},
    )
    scene["room"] = {
        "type": "ply",
        "filename": str(room),
        "bsdf": {
            "type": "diffuse",
            "reflectance": {"type": "mesh_attribute", "name": "vertex_albedo_color"},
        },
    }
    return scene


#: Metres an area light's outline pieces sit in front of the scanned faces they cut
#: (towards the room), so that the ring of those faces outside the outline, rendered as
#: surface behind them, never hides them. Only where there is such a ring: at grazing
#: views 1 mm moves a panel's edge pixels by several per cent of its radiance.
OUTLINE_LIFT = 1e-3


def _area_emitter_shape(
    vertices: np.ndarray,
    faces: np.ndarray,
    members: np.ndarray,
    sel: np.ndarray,
    geo: dict[str, Any],
    albedo: np.ndarray,
) -> tuple[trimesh.Trimesh, tuple[trimesh.Trimesh, dict[str, np.ndarray]] | None]:
    """An area light's emitting mesh, and the surface ring around it (or None).

    Without an ``outline`` (a clean scan, an older ``scene.json``) the light is its faces
    with at least two light corners, as before. With one (``reroom invert``'s
    ``area_outline``) it is the part of every face touching a light vertex inside the
    outline, as the transfer integrated it. Where some of those faces reach past the
    light's vertices (a fused scan's rim) it is put on its emitting face's plane where
    the light is flat (:func:`reroom.invert.area_region.emitting_face_plane`: the scan
    bends the face's edge towards the ceiling), lifted ``OUTLINE_LIFT`` towards the room,
    and the faces with two light corners that the room leaves out are drawn as surface
    behind it (with the room's albedo); a light that is a piece of its own (a clean
    scan's panel) stays in place.
    """
    from reroom.invert.area_region import (
        area_region,
        clip_to_region,
        emitting_face_plane,
        onto_plane,
    )

    outline = geo.get("outline")
    region = None
    if outline is not None:
        region = area_region(outline, geo.get("normal", [0.0, 0.0, -1.0]))
    touching = members[faces].any(axis=1)
    pv, pf = (None, []) if region is None else clip_to_region(vertices, faces[touching], region)
    if len(pf) == 0:  # no outline, or nothing of the faces inside it: as before
        return trimesh.Trimesh(vertices, faces[sel], process=False), None
    partial = touching & ~members[faces].all(axis=1)
    if not partial.any():
        # A light that is a piece of its own (a clean scan's panel): its faces, in place.
        return trimesh.Trimesh(pv, pf, process=False), None
    # The emitting face is flat, and the scan's faces at its edge bend towards the
    # surface around it: the pieces go onto the face's own plane.
    face = emitting_face_plane(vertices[members], region)
    if face is not None:
        pv = onto_plane(pv, *face, region.normal)
    emitter = trimesh.Trimesh(pv + OUTLINE_LIFT * region.normal, pf, process=False)
    rim_faces = faces[sel & partial]
    if len(rim_faces) == 0:
        return emitter, None
    used, local = np.unique(rim_faces, return_inverse=True)
    rim = trimesh.Trimesh(vertices[used], local.reshape(-1, 3), process=False)
    return emitter, (rim, {"albedo": albedo[used].astype(np.float32)})


#: Sides of the cylinder a line light's glow is drawn on (:func:`_fitted_tube`).
TUBE_SECTIONS = 32

#: Scanned glowing faces whose vertices lie, in the median, further than this many fitted
#: radii from a line light's segment are not the tube's shape (a fused scan's block).
TUBE_WIDER = 1.5


def _fitted_tube(light: dict[str, Any], scanned: np.ndarray) -> trimesh.Trimesh | None:
    """A line light's glowing surface as the cylinder of its fitted radius, when the
    scanned glowing faces' vertices ``scanned`` lie, in the median, more than
    ``TUBE_WIDER`` radii from its segment: the scan does not hold the tube's shape. None
    otherwise (a clean scan's tube lies one radius out and keeps its faces), and for a
    point light or a line without a radius.

    A depth-fused scan holds a tube as a block about twice its width (the issue's
    300-frame fused `furnished`: 7.5 cm wide, the tube 3.2 cm), and a glow drawn on
    that block spread the tube's light over twice its width at half its radiance (a new
    camera that saw the tube: 66 % relative RMSE, 15 % on the cylinder). The line's
    radius (from the photos' stripe or the cross-sections, ``geometry.radius``) is the
    tube's own.
    """
    if light.get("type") != "line":
        return None
    g = light.get("geometry", {})
    radius = float(g.get("radius", 0.0) or 0.0)
    p0, p1 = (
        np.asarray(g.get("p0", [np.nan] * 3), float),
        np.asarray(g.get("p1", [np.nan] * 3), float),
    )
    if not (radius > 0 and np.all(np.isfinite(p0)) and np.all(np.isfinite(p1))):
        return None
    if not np.linalg.norm(p1 - p0) > 2.0 * radius:
        return None
    if not np.median(segment_distance(scanned, p0, p1)) > TUBE_WIDER * radius:
        return None
    return trimesh.creation.cylinder(radius=radius, segment=[p0, p1], sections=TUBE_SECTIONS)


def _add_glows(
    scene: dict[str, Any],
    lights: list[dict[str, Any]],
    vertices: np.ndarray,
    faces: np.ndarray,
    glow_faces: np.ndarray,
    work: Path,
) -> None:
    """Give each point or line light the glowing faces nearest to it (``glow_<k>`` entries)."""
    from reroom.render.glow import glow_entry

    idx = np.flatnonzero(glow_faces)
    if len(idx) == 0:
        return
    centroid = vertices[faces[idx]].mean(axis=1)
    dist, centres = [], []
    for light in lights:
        geo = light.get("geometry", {})
        if light["type"] == "point":
            c = np.asarray(geo["position"], float)
            dist.append(np.linalg.norm(centroid - c, axis=1))
            centres.append(c)
        elif light["type"] == "line":
            a, b = np.asarray(geo["p0"], float), np.asarray(geo["p1"], float)
            dist.append(segment_distance(centroid, a, b))
            centres.append((a + b) / 2.0)
        else:
            dist.append(np.full(len(idx), np.inf))
            centres.append(None)
    if not dist:
        return
    reach = np.array([GLOW_REACH.get(light["type"], 0.0) for light in lights])
    d = np.stack(dist, axis=1)
    nearest = np.argmin(d, axis=1)
    near = d[np.arange(len(idx)), nearest] <= reach[nearest]
    for k, centre in enumerate(centres):
        key = f"light_{k:02d}"
        sel = idx[near & (nearest == k)]
        if centre is None or key not in scene or len(sel) == 0:
            continue
        used, local = np.unique(faces[sel], return_inverse=True)
        shape = trimesh.Trimesh(vertices[used], local.reshape(-1, 3), process=False)
        tube = _fitted_tube(lights[k], shape.vertices)
        if tube is not None:
            shape = tube
        path = write_ply(work / f"glow_{k:02d}.ply", shape, {})
        scene[f"glow_{k:02d}"] = glow_entry(str(path), key, centre)


def read_window_view(invert_dir: Path, light: dict[str, Any]) -> np.ndarray | None:
    """The map a camera looking out of a recovered window is shown (its ``view_exr``,
    relative to ``invert_dir``), or None when it has none. A named file that is missing
    gives a warning naming it, and None: the camera then sees the lighting map."""
    name = light.get("view_exr")
    if not name:
        return None
    path = Path(invert_dir) / name
    if not path.is_file():
        msg = f"window {light.get('name')!r}: {path} is missing; the camera sees the light map"
        warnings.warn(msg, stacklevel=2)
        return None
    return np.maximum(read_exr(path)[..., :3], 0.0)
