"""Apply edits to the recovered room model: the Mitsuba scene dict of the edited room.

:func:`edited_scene` starts from :func:`reroom.edit.model.model_scene` (the scan mesh with
its per-vertex albedo, and every recovered light with its distribution) and applies the
edit operations of :mod:`reroom.edit.edits` in order:

* ``empty``: the scan mesh is replaced by the layout's empty-room shell
  (``layout/layout.json`` through :func:`reroom.layout.emptyroom.empty_room_mesh`, in the
  mesh frame), one diffuse material per label where no photo texture covers it (below):
  the solved cluster albedo of wall, floor and ceiling, the median per-vertex albedo of
  door and baseboard vertices. The pane closing
  each window opening is dropped (the window's portal takes its place) and so are the
  panes closing passages (the rooms' shells join). The fittings around point and line
  lights (lamp shades, tube baffles: unlabelled scan geometry near the light) are kept,
  because the recovered distributions were solved with them in place.
* ``repaint``: a colour sets the per-vertex albedo of every vertex of that label
  (``layout/layout_labels.ply``); a texture replaces the faces of that label by a mesh
  with planar texture coordinates (projected on the axis plane closest to each face,
  ``metres_per_tile`` per repeat).
* ``light``: ``off`` removes the emitter (an area light's surface stays, with the albedo of
  the cluster around it; a window's opening turns black); ``scale`` and ``color`` multiply
  the emitted radiance; ``move_to`` moves a point light, the centre of a line light, or an
  area light's emitting faces (the place it left is filled with the surrounding cluster's
  albedo).
* ``add_light``: a ``reroom_goniometric`` point light; ``intensity`` is the radiant
  intensity (model units) of an isotropic light, or the *peak* intensity of an IES
  profile (its brightest direction).
* ``window``: the new HDRI averaged over each cube-map cell of the recovered distant
  light, scaled into model units (see :func:`swap_window_environment`).
* ``insert``: a bundled or loaded object (:mod:`reroom.edit.furniture`), diffuse, which
  must stand inside a room's floor polygon.

Where ``reroom invert`` made photo textures of the floor, ceiling and wall planes
(``scene.json``'s ``textures``, :mod:`reroom.invert.textures`), those surfaces render
with them instead of the per-vertex albedo: the scan mesh's faces of each plane and,
in the empty room, the shell's faces on the same planes (a plane's label, axis and
position within 15 cm), where the empty room takes the plane's pattern at the plane's
mean albedo (the texture's local mean would show what stood there). A repainted label
drops its texture.
"""

from __future__ import annotations

import copy
import hashlib
import json
import warnings
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from reroom.edit.edits import LABEL_TARGETS, EditError, as_ops, check_names
from reroom.edit.model import DEFAULT_MAX_DEPTH, read_window_view
from reroom.edit.objects import object_albedo
from reroom.errors import ReroomError, ScanError
from reroom.io.atomic import atomic_write_json
from reroom.io.jsonfile import read_json
from reroom.io.mesh import read_ply, write_triangle_ply
from reroom.rays.geometry import segment_closest, segment_distance

__all__ = [
    "RoomModel",
    "edited_scene",
    "environment_cells",
    "load_model",
    "swap_window_environment",
    "INSERT_PREFIX",
]

#: Keys of inserted objects in the scene dict (``insert_<name>``): the composite drops them.
INSERT_PREFIX = "insert_"
_LABEL_IDS = {"wall": 0, "floor": 1, "ceiling": 2, "door": 3, "window": 4, "baseboard": 5}
_LABEL_NAMES = {v: k for k, v in _LABEL_IDS.items()}
_OTHER = 255
_PORTAL_PANE = 254
#: Unlabelled scan geometry this close to a point light (or a line light's segment) is its
#: fitting (a shade, a housing, baffles), kept in the empty room; pieces bigger than
#: ``_FIXTURE_MAX`` are furniture that happens to stand near a lamp.
_FIXTURE_NEAR_POINT = 0.35
_FIXTURE_NEAR_LINE = 0.15
_FIXTURE_MAX = 2.0


@dataclass
class RoomModel:
    """The recovered room as the edits see it (loaded by :func:`load_model`).

    Attributes
    ----------
    doc:
        ``invert/scene.json``.
    vertices, faces:
        The scan mesh (from ``albedo.ply``).
    albedo, known:
        Per-vertex albedo as solved (``< 0`` where unknown) and where it is known.
    labels:
        Per-vertex layout label (``layout_labels.ply``) or ``None``.
    layout:
        ``layout.json`` or ``None``; ``rotation`` its mesh-to-aligned rotation.
    """

    scan_dir: Path
    invert_dir: Path
    lights_dir: Path
    layout_dir: Path
    doc: dict[str, Any]
    vertices: np.ndarray
    faces: np.ndarray
    albedo: np.ndarray
    known: np.ndarray
    light_flag: np.ndarray
    labels: np.ndarray | None
    layout: dict[str, Any] | None
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))

    @property
    def lights(self) -> dict[str, dict[str, Any]]:
        """Light name -> its ``scene.json`` entry."""
        return {light["name"]: light for light in self.doc.get("lights", [])}

    @property
    def light_types(self) -> dict[str, str]:
        return {n: light["type"] for n, light in self.lights.items()}

    @property
    def materials(self) -> dict[str, np.ndarray]:
        """Solved material cluster name -> albedo."""
        return {
            m["name"]: np.asarray(m["albedo"], float)
            for m in self.doc.get("materials", [])
            if m.get("albedo") is not None
        }

    @cached_property
    def photo_textures(self) -> list[tuple[Any, Path]]:
        """``(TexturePlane, its EXR path)`` of each photo texture in ``scene.json``."""
        from reroom.invert.textures import read_texture_planes

        entries = self.doc.get("textures") or []
        if not entries:
            return []
        # The renderer reads the images itself: only the planes are needed here.
        textures = read_texture_planes(entries, self.invert_dir)
        return [
            (t, (self.invert_dir / e["file"]).resolve())
            for t, e in zip(textures, entries, strict=True)
        ]

    def texture_detail(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Photo texture ``index``'s detail image and its plane's mean albedo."""
        from reroom.invert.textures import read_textures

        entry = self.doc["textures"][index]
        tex = read_textures([entry], self.invert_dir)[0]
        mean = entry.get("mean_albedo")
        return tex.detail, np.asarray(mean, float) if mean is not None else tex.mean_albedo

    def texture_level(self, index: int) -> np.ndarray:
        """Photo texture ``index``'s plane's mean albedo (read from ``scene.json`` where
        it is recorded, without loading the texture's images)."""
        mean = self.doc["textures"][index].get("mean_albedo")
        return np.asarray(mean, float) if mean is not None else self.texture_detail(index)[1]

    def targets(self) -> list[str]:
        """Repaint targets: the labels this room has, and its material clusters."""
        have = set(self.materials)
        if self.labels is not None:
            present = set(np.unique(self.labels).tolist())
            have |= {t for t in LABEL_TARGETS if _LABEL_IDS[t] in present}
        if self.layout is not None:
            have |= {"wall", "floor", "ceiling"}
            if any(r.get("baseboard") for r in self.layout.get("rooms", [])):
                have.add("baseboard")
            if any(
                o.get("kind") == "door"
                for r in self.layout.get("rooms", [])
                for o in r.get("openings", [])
            ):
                have.add("door")
        return sorted(have)

    def label_albedo(self, label: str) -> np.ndarray:
        """The albedo of a label: its solved cluster, else the median of its vertices."""
        mats = self.materials
        if label in mats:
            return np.clip(mats[label], 0.0, 1.0)
        if self.labels is not None and label in _LABEL_IDS:
            sel = (self.labels == _LABEL_IDS[label]) & self.known
            if sel.sum() >= 3:
                return np.clip(np.median(self.albedo[sel], axis=0), 0.0, 1.0)
        if label in ("window",) and "wall" in mats:
            return np.clip(mats["wall"], 0.0, 1.0)
        return np.clip(np.median(self.albedo[self.known], axis=0), 0.0, 1.0)

    def rooms(self) -> list[tuple[np.ndarray, float, float, str]]:
        """``(polygon_xy, floor_z, ceiling_z, name)`` of each room, in the aligned frame."""
        if self.layout is None:
            return []
        return [
            (np.asarray(r["polygon"], float), float(r["floor_z"]), float(r["ceiling_z"]), r["name"])
            for r in self.layout.get("rooms", [])
        ]

    def to_aligned(self, p: np.ndarray) -> np.ndarray:
        return np.asarray(p, float) @ self.rotation.T

    def to_mesh(self, p: np.ndarray) -> np.ndarray:
        return np.asarray(p, float) @ self.rotation


def load_model(
    scan_dir: str | Path,
    invert_dir: str | Path | None = None,
    lights_dir: str | Path | None = None,
    layout_dir: str | Path | None = None,
) -> RoomModel:
    """Load what the edits need: ``invert/`` (scene.json, albedo.ply) and ``layout/``.

    The layout is optional (without it ``empty``, label repaints and the floor check of
    ``insert`` are unavailable and say so).

    Raises
    ------
    ScanError
        When ``scene.json`` or ``albedo.ply`` is missing or unreadable, or the layout's
        labels do not match the mesh.
    """
    scan_dir = Path(scan_dir)
    inv = Path(invert_dir) if invert_dir is not None else scan_dir / "invert"
    lit = Path(lights_dir) if lights_dir is not None else scan_dir / "lights"
    lay = Path(layout_dir) if layout_dir is not None else scan_dir / "layout"
    doc = read_json(inv / "scene.json", "run `reroom invert SCAN` first")
    mesh = read_ply(inv / doc.get("albedo_file", "albedo.ply"))
    attrs = mesh.vertex_attributes
    if "albedo" not in attrs:
        raise ScanError(inv / "albedo.ply", "has no albedo_r/g/b vertex properties")
    albedo = np.asarray(attrs["albedo"], np.float64)
    known = np.all(albedo >= 0, axis=1) & np.all(np.isfinite(albedo), axis=1)
    light_flag = np.asarray(attrs.get("light", np.zeros(len(albedo))), bool)
    labels = None
    lab_path = lay / "layout_labels.ply"
    if lab_path.is_file():
        lab_mesh = read_ply(lab_path)
        lab = lab_mesh.vertex_attributes.get("label")
        if lab is None:
            raise ScanError(lab_path, "has no 'label' vertex property")
        if len(lab) != len(albedo):
            raise ScanError(lab_path, f"has {len(lab)} labels for {len(albedo)} vertices")
        labels = np.asarray(lab).astype(np.int64)
    layout = None
    rotation = np.eye(3)
    if (lay / "layout.json").is_file():
        layout = read_json(lay / "layout.json", "run `reroom layout SCAN` first")
        rotation = np.asarray(layout.get("rotation", np.eye(3)), float)
    return RoomModel(
        scan_dir,
        inv,
        lit,
        lay,
        doc,
        np.asarray(mesh.vertices, float),
        np.asarray(mesh.faces, np.int64),
        albedo,
        known,
        light_flag,
        labels,
        layout,
        rotation,
    )


# ---------------------------------------------------------------------- helpers
def _fibonacci_sphere(n: int) -> np.ndarray:
    """``n`` nearly uniform unit directions (deterministic)."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = np.pi * (1.0 + 5.0**0.5) * k
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def environment_cells(hdri: str | Path, basis: Any, samples: int = 200_000) -> np.ndarray:
    """``(6 n^2, 3)`` mean radiance of a lat-long HDRI over each cell of a cube-map basis.

    ``hdri`` is a shipped name or an EXR path; the mean is over ``samples`` nearly
    uniform directions (the portal's lat-long convention, no rotation).
    """
    from reroom.data import hdri_path
    from reroom.invert.window_env import map_cell_means
    from reroom.render.emitters import load_hdri

    return map_cell_means(load_hdri(hdri_path(str(hdri))), basis, _fibonacci_sphere(samples))


def swap_window_environment(
    light: dict[str, Any],
    hdri: str | Path,
    was: str | Path | None = None,
    scale: float = 1.0,
    samples: int = 200_000,
) -> tuple[np.ndarray, np.ndarray]:
    """The cube-map cells of a new outdoor HDRI for a recovered window, in model units.

    Each cell of the window's recovered distant light (``distribution.cells``, the
    direction a ray *leaves* the room in) gets the new HDRI's mean radiance over its
    directions (``samples`` directions on the sphere, the portal's lat-long convention,
    no rotation). The cells are weighted by how much the window sees through them,
    ``w_j = integral over the cell of max(0, -d . n_in)`` (the cosine at the opening:
    the light that enters). Units: with ``was`` (the HDRI the scan was lit by), per
    channel the ratio of the light entering, ``s = sum w rec / sum w was``, which maps
    ``was`` onto the recovered cells ``rec``; without it, one factor for all channels so
    that the weighted mean luminance equals the recovered one's (the new sky keeps its
    colour). Times ``scale``. The level is the solve's (its window power, which the
    evaluation checks), not the finer map a render window shows: the single cells of
    either are far less sure than their sum (docs/edit.md).

    Returns
    -------
    cells, factor
        ``(6 n^2, 3)`` new cells and the ``(3,)`` factor applied to the HDRI.
    """
    from reroom.invert.basis import CubemapBasis

    dist = light.get("distribution", {})
    if dist.get("basis") != "cubemap":
        raise ReroomError(f"window {light.get('name')!r} has no cube-map distribution to swap")
    basis = CubemapBasis(int(dist.get("n", 4)))
    rec = np.maximum(np.asarray(dist["cells"], float), 0.0)
    if light.get("sun"):
        # The recovered sun is part of the window's light (reroom.invert.sun): in the
        # cells it stands for its irradiance over its cell, as a sky's sun in `new`.
        from reroom.invert.sun import fold_sun_into_cells

        rec = fold_sun_into_cells(rec, basis, light["sun"]["direction"], light["sun"]["irradiance"])
    d = _fibonacci_sphere(samples)
    cell = basis.cell_of(d)
    count = np.bincount(cell, minlength=basis.size).astype(float)
    normal = np.asarray(light["geometry"]["normal"], float)
    cos_out = np.maximum(-(d @ normal), 0.0)
    w = np.bincount(cell, weights=cos_out, minlength=basis.size)

    new = environment_cells(hdri, basis, samples)
    if w.sum() <= 0:
        w = count  # a degenerate normal: use every direction
    if was is not None:
        # The ratio of the light entering, not a least-squares fit of the cells: that
        # weighs each cell by was^2, so the brightest few cells (the least sure: on
        # `furnished` they are solved at 0.7-1.3 of the truth) set the level, and it
        # came out 8-15 % high; the ratio of sums is the window's power, within 3 %.
        old = environment_cells(was, basis, samples)
        num = (w[:, None] * rec).sum(0)
        den = (w[:, None] * old).sum(0)
        factor = np.where(den > 0, num / np.maximum(den, 1e-30), 0.0)
    else:
        lum = np.array([0.2126, 0.7152, 0.0722])
        den = float((w * (new @ lum)).sum())
        factor = np.full(3, float((w * (rec @ lum)).sum()) / den if den > 0 else 0.0)
    factor = factor * float(scale)
    return new * factor, factor


def _shape_ply(path: Path, vertices: np.ndarray, faces: np.ndarray, **attrs: np.ndarray) -> str:
    write_triangle_ply(path, vertices, faces, {k: v for k, v in attrs.items()})
    return str(path)


def _diffuse(rgb: np.ndarray | list[float], twosided: bool = False) -> dict[str, Any]:
    bsdf = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [float(x) for x in rgb]}}
    return {"type": "twosided", "bsdf": bsdf} if twosided else bsdf


def _planar_uv(tri: np.ndarray) -> np.ndarray:
    """Texture coordinates (metres) of unwelded triangles ``(F, 3, 3)``: each face
    projected on the axis plane closest to it (x-y for floors and ceilings, the wall's
    horizontal axis and z for walls), so the texture keeps its scale on every face."""
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    axis = np.argmax(np.abs(n), axis=1)
    uv = np.empty(tri.shape[:2] + (2,))
    pairs = {0: (1, 2), 1: (0, 2), 2: (0, 1)}
    for a, (i, j) in pairs.items():
        sel = axis == a
        uv[sel, :, 0] = tri[sel][:, :, i]
        uv[sel, :, 1] = tri[sel][:, :, j]
    return uv


def _textured_shape(
    path: Path, vertices: np.ndarray, faces: np.ndarray, texture: str, metres_per_tile: float
) -> dict[str, Any]:
    """A PLY shape of the faces, unwelded, with planar ``u, v`` and a tiled bitmap albedo."""
    tri = np.asarray(vertices, float)[np.asarray(faces)]
    uv = _planar_uv(tri) / float(metres_per_tile)
    v = tri.reshape(-1, 3)
    f = np.arange(len(v)).reshape(-1, 3)
    uv = uv.reshape(-1, 2)
    filename = _shape_ply(path, v, f, u=uv[:, 0], v=uv[:, 1])
    exr = Path(texture).suffix.lower() == ".exr"
    return {
        "type": "ply",
        "filename": filename,
        "face_normals": True,
        "bsdf": {
            "type": "twosided",
            "bsdf": {
                "type": "diffuse",
                "reflectance": {
                    "type": "bitmap",
                    "filename": str(Path(texture).resolve()),
                    # 8-bit images are sRGB-encoded (decoded to linear); EXRs are linear.
                    "raw": bool(exr),
                    "wrap_mode": "repeat",
                },
            },
        },
    }


def _photo_textured_shape(
    path: Path, vertices: np.ndarray, faces: np.ndarray, texture, image: Path, twosided: bool
) -> dict[str, Any]:
    """A PLY shape of the faces, unwelded, with ``u, v`` on a photo texture's plane."""
    tri = np.asarray(vertices, float)[np.asarray(faces)]
    v = tri.reshape(-1, 3)
    uv = texture.texture_coords(v)
    f = np.arange(len(v)).reshape(-1, 3)
    filename = _shape_ply(path, v, f, u=uv[:, 0], v=uv[:, 1])
    bsdf = {
        "type": "diffuse",
        "reflectance": {
            "type": "bitmap",
            "filename": str(image),
            "raw": True,  # linear albedo
            "wrap_mode": "clamp",
        },
    }
    return {
        "type": "ply",
        "filename": filename,
        "face_normals": True,
        "bsdf": {"type": "twosided", "bsdf": bsdf} if twosided else bsdf,
    }


def _label_names(face_label: np.ndarray) -> np.ndarray:
    """Each face's label name (``"other"`` for unlabelled faces)."""
    return np.array([_LABEL_NAMES.get(int(x), "other") for x in face_label], dtype=object)


def _photo_texture_scan(
    scene: dict[str, Any], model: RoomModel, skip: set[str], work: Path
) -> None:
    """Move the scan mesh's faces on a photo-textured plane into textured shapes
    (``texture_<plane>``); labels in ``skip`` (repainted) keep their per-vertex albedo."""
    textures = model.photo_textures
    if not textures or model.labels is None:
        return
    from reroom.invert.textures import match_planes

    room = read_ply(scene["room"]["filename"])
    faces = np.asarray(room.faces)
    vertices = np.asarray(room.vertices)
    names = _label_names(_face_labels(model.labels, faces))
    which = match_planes([t for t, _ in textures], vertices, faces, names)
    which[np.isin(names, sorted(skip))] = -1
    if not (which >= 0).any():
        return
    for k, (tex, image) in enumerate(textures):
        sel = which == k
        if sel.any():
            scene[f"texture_{tex.name}"] = _photo_textured_shape(
                work / f"texture_{tex.name}.ply", vertices, faces[sel], tex, image, False
            )
    path = work / "room_untextured.ply"
    write_triangle_ply(
        path,
        vertices,
        faces[which < 0],
        {"albedo": np.asarray(room.vertex_attributes["albedo"], np.float32)},
    )
    scene["room"]["filename"] = str(path)


def _face_labels(labels: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Label of each face: the label of at least two of its vertices, else 'other' (255)."""
    from reroom.invert.textures import face_labels

    return face_labels(labels, faces)


def _fixture_faces(
    model: RoomModel, emitting: np.ndarray, lights: list[dict[str, Any]] | None = None
) -> np.ndarray:
    """Scan faces that belong to the fittings of ``lights`` (default: every light).

    Unlabelled connected pieces of the scan mesh near a point light or a line light's
    segment, no larger than ``_FIXTURE_MAX`` (a lamp shade and pole, a tube's housing);
    with every light, also the pieces holding vertices ``reroom invert`` marked as a
    light's glowing fitting.
    """
    v = model.vertices
    if lights is None:
        # Each light's fitting on its own (the size limit is per fitting), and the pieces
        # holding glowing-fitting vertices.
        keep = _grown_pieces(model, emitting, model.light_flag, grow=False)
        for light in model.doc.get("lights", []):
            if light["type"] in ("point", "line"):
                keep |= _fixture_faces(model, emitting, [light])
        return keep
    near = np.zeros(len(v), bool)
    for light in lights:
        geo = light.get("geometry", {})
        if light["type"] == "point":
            near |= np.linalg.norm(v - np.asarray(geo["position"], float), axis=1) < (
                _FIXTURE_NEAR_POINT
            )
        elif light["type"] == "line":
            near |= (
                segment_distance(v, np.asarray(geo["p0"], float), np.asarray(geo["p1"], float))
                < _FIXTURE_NEAR_LINE
            )
    return _grown_pieces(model, emitting, near, grow=True)


def _facing_their_light(model: RoomModel, faces: np.ndarray) -> np.ndarray:
    """Which of ``faces`` do not clearly turn their back on the nearest point or line
    light (the point of its segment nearest them): the cosine between the face's normal
    and the way to the light above -0.2. Faces edge-on to it count as facing it (a lamp
    pole under its bulb, whose scanned albedo is the bright wall behind it). All of
    them when the model has no such light."""
    v = model.vertices[faces]
    centre = v.mean(axis=1)
    normal = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    best = np.full(len(faces), np.inf)
    toward = np.zeros_like(centre)
    for light in model.doc.get("lights", []):
        geo = light.get("geometry", {})
        if light["type"] == "point":
            q = np.broadcast_to(np.asarray(geo["position"], float), centre.shape)
        elif light["type"] == "line":
            q = segment_closest(centre, geo["p0"], geo["p1"])
        else:
            continue
        d = np.linalg.norm(q - centre, axis=1)
        closer = d < best
        best[closer] = d[closer]
        toward[closer] = q[closer] - centre[closer]
    if not np.isfinite(best).any():
        return np.ones(len(faces), bool)
    cos = np.einsum("ij,ij->i", normal, toward) / np.maximum(
        np.linalg.norm(normal, axis=1) * np.linalg.norm(toward, axis=1), 1e-300
    )
    return cos > -0.2


def _grown_pieces(
    model: RoomModel, emitting: np.ndarray, near: np.ndarray, grow: bool
) -> np.ndarray:
    """Unlabelled pieces of the scan mesh holding a ``near`` vertex (and, with ``grow``,
    the pieces touching them), no larger than ``_FIXTURE_MAX`` together."""
    v, f = model.vertices, model.faces
    if model.labels is None:
        cand = np.ones(len(f), bool)
    else:
        cand = _face_labels(model.labels, f) == _OTHER
    cand &= ~emitting
    idx = np.flatnonzero(cand)
    if len(idx) == 0:
        return np.zeros(len(f), bool)
    from scipy.spatial import cKDTree

    sub = trimesh.Trimesh(v, f[idx], process=False)
    comps = [
        idx[c]
        for c in trimesh.graph.connected_components(sub.face_adjacency, nodes=np.arange(len(idx)))
    ]
    verts = [np.unique(f[c]) for c in comps]
    picked = [bool(near[vs].any()) for vs in verts]
    # A fitting made of separate pieces (a shade's rims, a box's sides) is grown from the
    # pieces near the light to those touching them (within 1 cm).
    changed = grow and any(picked)
    while changed:
        changed = False
        sel = np.concatenate([vs for vs, p in zip(verts, picked, strict=True) if p])
        tree = cKDTree(v[sel])
        lo, hi = v[sel].min(0), v[sel].max(0)
        for k, vs in enumerate(verts):
            if picked[k]:
                continue
            d, _ = tree.query(v[vs], k=1, distance_upper_bound=0.01)
            if not np.isfinite(d).any():
                continue
            lo2, hi2 = np.minimum(lo, v[vs].min(0)), np.maximum(hi, v[vs].max(0))
            if np.linalg.norm(hi2 - lo2) <= _FIXTURE_MAX:
                picked[k], changed = True, True
                lo, hi = lo2, hi2
    keep = np.zeros(len(f), bool)
    for c, vs, p in zip(comps, verts, picked, strict=True):
        if p and np.linalg.norm(v[vs].max(0) - v[vs].min(0)) <= _FIXTURE_MAX:
            keep[c] = True
    return keep


def _digest(obj: Any) -> str:
    return hashlib.sha1(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:12]


@dataclass
class _LightState:
    off: bool = False
    scale: float = 1.0
    color: np.ndarray = field(default_factory=lambda: np.ones(3))
    move_to: np.ndarray | None = None
    window: dict[str, Any] | None = None


def _inside_room(model: RoomModel, mesh: trimesh.Trimesh, tol: float = 0.02) -> str | None:
    """``None`` if the object's footprint lies in one room's floor polygon, else why not."""
    from reroom.synth.room import point_in_polygon

    rooms = model.rooms()
    pts = model.to_aligned(np.asarray(mesh.vertices))
    if not rooms:
        lo, hi = model.vertices.min(0), model.vertices.max(0)
        ok = np.all(np.asarray(mesh.vertices) >= lo - tol) and np.all(
            np.asarray(mesh.vertices) <= hi + tol
        )
        return None if ok else "outside the scan's bounding box (no layout to check the floor)"
    hull = pts[:, :2]
    try:
        from scipy.spatial import ConvexHull

        hull = hull[ConvexHull(hull).vertices]
    except Exception:  # a flat or degenerate footprint: test every vertex
        pass
    for poly, zf, zc, _name in rooms:
        inside = point_in_polygon(hull[:, 0], hull[:, 1], poly)
        if not inside.all():
            # Points within ``tol`` of an edge count as inside (an object against a wall).
            out = hull[~inside]
            a, b = poly, np.roll(poly, -1, axis=0)
            dmin = np.full(len(out), np.inf)
            for p0, p1 in zip(a, b, strict=True):
                ab = p1 - p0
                t = np.clip(((out - p0) @ ab) / max(float(ab @ ab), 1e-12), 0, 1)
                dmin = np.minimum(dmin, np.linalg.norm(out - (p0 + t[:, None] * ab), axis=1))
            if np.any(dmin > tol):
                continue
        if pts[:, 2].min() < zf - 0.05 or pts[:, 2].max() > zc + tol:
            return f"not between the floor ({zf:.2f} m) and the ceiling ({zc:.2f} m)"
        return None
    names = [r[3] for r in rooms]
    return f"outside the floor polygon of every room ({names})"


# ---------------------------------------------------------------------- the edited scene
def edited_scene(
    scan_dir: str | Path,
    edits: Any,
    *,
    invert_dir: str | Path | None = None,
    lights_dir: str | Path | None = None,
    layout_dir: str | Path | None = None,
    work_dir: str | Path | None = None,
    max_depth: int = DEFAULT_MAX_DEPTH,
    backing: bool = True,
) -> dict[str, Any]:
    """The Mitsuba scene dict (no sensor) of the recovered model with ``edits`` applied.

    Parameters
    ----------
    scan_dir:
        The scan folder.
    edits:
        An edit document, a list of OPs, one OP, or the path of an edit file (see
        :mod:`reroom.edit.edits`); an empty list gives the unedited model.
    invert_dir, lights_dir, layout_dir:
        Stage outputs (default ``SCAN/invert``, ``SCAN/lights``, ``SCAN/layout``).
    work_dir:
        Where the meshes and documents of the edited model go (default
        ``SCAN/render/edits``); each edit list gets its own sub-folder named by a hash
        of the edits, so scene dicts of different edits can coexist.
    max_depth:
        Path depth of the ``path`` integrator.
    backing:
        Put the layout's shell a little behind the scan's walls, floor and ceiling
        (:func:`reroom.layout.emptyroom.backing_shell`), so that the scan's holes show
        a wall, not the background, and send light back as a wall does. Only with a
        layout, and not in the empty room (its shell replaces the scan).

    Returns
    -------
    dict
        Shapes: ``room`` (scan mesh) or ``room_<label>`` (empty shell), ``texture_<plane>``
        / ``room_texture_<plane>`` (photo-textured planes of the scan mesh / the shell),
        ``backing_<label>`` / ``backing_texture_<plane>`` (the shell behind the scan), ``fixtures``,
        ``paint_<target>`` (textured repaints), ``light_NN`` (the model's lights, ``NN``
        their index in ``scene.json``), ``light_NN_patch`` (where an area light was),
        ``added_<name>`` (added lights), ``insert_<name>`` (inserted objects).

    Raises
    ------
    EditError
        For malformed edits, names the room does not have (listing those it has), a
        missing layout where an edit needs it, or an object outside the room.
    ScanError
        When a stage output is missing or unreadable.
    """
    from reroom.edit.model import model_scene

    model = load_model(scan_dir, invert_dir, lights_dir, layout_dir)
    ops, source = as_ops(edits)
    check_names(ops, model.light_types, model.targets(), source)
    scan_dir = Path(scan_dir)
    work_root = Path(work_dir) if work_dir is not None else scan_dir / "render" / "edits"
    work = work_root / _digest({"edits": ops, "model": str(model.invert_dir), "d": max_depth})
    work.mkdir(parents=True, exist_ok=True)

    # Fold the edits, in order, into the final state of each part of the room.
    empty = False
    paint: dict[str, dict[str, Any]] = {}
    states: dict[str, _LightState] = {}
    added: dict[str, dict[str, Any]] = {}
    inserts: list[dict[str, Any]] = []
    for i, op in enumerate(ops):
        kind = op["op"]
        where = f"{source}: edit {i} ({kind})"
        if kind == "empty":
            if model.layout is None:
                raise EditError(
                    f"{where}: needs {model.layout_dir / 'layout.json'}: run `reroom layout`"
                )
            empty = True
        elif kind == "repaint":
            paint[op["target"]] = op
        elif kind == "light":
            if op["name"] in added:
                a = added[op["name"]]
                a["off"] = a.get("off", False) or op.get("off", False)
                a["intensity"] *= op.get("scale", 1.0)
                a["color"] = list(np.asarray(a["color"]) * np.asarray(op.get("color", [1, 1, 1])))
                if "move_to" in op:
                    a["position"] = op["move_to"]
                continue
            st = states.setdefault(op["name"], _LightState())
            st.off = st.off or op.get("off", False)
            st.scale *= op.get("scale", 1.0)
            st.color = st.color * np.asarray(op.get("color", [1.0, 1.0, 1.0]))
            if "move_to" in op:
                st.move_to = np.asarray(op["move_to"], float)
        elif kind == "add_light":
            added[op["name"]] = dict(op)
        elif kind == "window":
            states.setdefault(op["name"], _LightState()).window = op
        elif kind == "insert":
            inserts.append(op)

    # Per-vertex albedo with colour repaints (the model scene reads it from the work doc).
    # The furnishings first get one robust albedo per object (reroom.edit.objects): their
    # per-vertex solve is too bright along creases and contacts, and unseen where hidden.
    albedo = model.albedo.copy()
    if model.labels is not None:
        albedo, _ = object_albedo(
            model.vertices, model.faces, albedo, model.known, model.labels == _OTHER
        )
    textured: dict[str, dict[str, Any]] = {}
    for target, op in paint.items():
        if target in _LABEL_IDS:
            if model.labels is None and not empty:
                raise EditError(
                    f"{source}: repaint {target!r} needs {model.layout_dir / 'layout_labels.ply'}"
                )
            if "color" in op and model.labels is not None:
                albedo[model.labels == _LABEL_IDS[target]] = op["color"]
        if "texture" in op:
            textured[target] = op
    # Light fittings (shades, housings, baffles): the light they reflect is already in
    # the light's solved distribution (it was fitted to what the room receives), and
    # their per-vertex albedo is unreliable (lit from a few centimetres, where the
    # transfer's 1/d^2 is least accurate: the tube's baffles solve to ~0.75 where the
    # truth is 0.04). Rendered with any albedo they add that light a second time, and
    # lit from centimetres they do it as fireflies (0.5 % of the pixels of a 64-spp
    # view, 0.02 % with the tube off). So the fitting faces that face their light (a
    # shade's lining, a housing's inside) are black. The faces turned away from it (a
    # shade's outside) never see its light and keep their albedo: the room lights them,
    # and black they showed as a black shade in every view (session 28).
    emitting = _emitting_faces(model)
    glow = (model.light_flag[model.faces].sum(axis=1) >= 2) & ~emitting
    fittings = _fixture_faces(model, emitting) & ~glow
    fittings[fittings] = _facing_their_light(model, model.faces[fittings])
    on_fitting = np.zeros(len(albedo), bool)
    on_fitting[np.unique(model.faces[fittings])] = True
    albedo[on_fitting] = 0.0
    doc = copy.deepcopy(model.doc)
    write_triangle_ply(
        work / "albedo.ply",
        model.vertices,
        model.faces,
        {"albedo": albedo.astype(np.float32), "light": model.light_flag.astype(np.uint8)},
    )
    doc["albedo_file"] = str((work / "albedo.ply").resolve())
    for light in doc.get("lights", []):
        if light["type"] == "window":
            exr = light.get("environment_exr", f"window_{light['name']}.exr")
            light["environment_exr"] = str((model.invert_dir / exr).resolve())
            if light.get("view_exr"):
                light["view_exr"] = str((model.invert_dir / light["view_exr"]).resolve())
    atomic_write_json(work / "scene.json", doc)
    scene = model_scene(
        scan_dir, work, model.lights_dir, work_dir=work / "meshes", max_depth=max_depth
    )

    # Lights.
    key_of = {light["name"]: f"light_{k:02d}" for k, light in enumerate(doc.get("lights", []))}
    for name, st in states.items():
        _apply_light(scene, key_of[name], model.lights[name], st, model, work)

    for name, a in added.items():
        if a.get("off"):
            continue
        scene[f"added_{name}"] = _added_light(a)

    # A moved point or line light takes its fitting along (a lamp's shade and pole, a
    # tube's housing), as the synthetic-truth side moves a fixture's parts.
    moved_faces = np.zeros(len(model.faces), bool)
    for name, st in states.items():
        light = model.lights[name]
        if st.move_to is None or light["type"] not in ("point", "line"):
            continue
        mask = _fixture_faces(model, emitting, [light]) & ~moved_faces & ~glow
        if not mask.any():
            continue
        moved_faces |= mask
        delta = st.move_to - _light_centre(light)
        _add_moved_fixture(scene, key_of[name], model, mask, delta, albedo, paint, work)

    # Surfaces.
    if empty:
        _empty_room(scene, model, paint, work, fittings & ~moved_faces, albedo)
    else:
        if moved_faces.any():
            _remove_from_room(scene, model.faces[moved_faces], work)
        _texture_scan(scene, model, textured, work)
        _photo_texture_scan(scene, model, set(paint), work)
        if backing and model.layout is not None:
            _back_the_scan(scene, model, paint, work)

    for op in inserts:
        from reroom.edit.furniture import placed_object

        mesh = placed_object(op["object"], op["position"], op["rotation_deg"], op["scale"])
        why = _inside_room(model, mesh)
        if why is not None:
            raise EditError(
                f"{source}: insert {op['name']!r} ({op['object']}) at {op['position']} is {why}"
            )
        path = work / f"insert_{op['name']}.ply"
        scene[f"{INSERT_PREFIX}{op['name']}"] = {
            "type": "ply",
            "filename": _shape_ply(path, np.asarray(mesh.vertices), np.asarray(mesh.faces)),
            "face_normals": True,
            "bsdf": _diffuse(op["color"], twosided=True),
        }
    return scene


def _apply_light(
    scene: dict[str, Any],
    key: str,
    light: dict[str, Any],
    st: _LightState,
    model: RoomModel,
    work: Path,
) -> None:
    """Apply one light's folded edits to its entry of the scene dict."""
    from reroom.render.emitters import portal_emitter

    kind = light["type"]
    if key not in scene:  # an area light with no faces: nothing to edit
        return
    entry = scene[key]
    gain = st.scale * st.color
    if kind == "area":
        path = Path(entry["filename"])
        mesh = read_ply(path)
        label = _light_label(model, light)
        patch_albedo = model.label_albedo(label)
        if st.move_to is not None:
            centre = np.asarray(light["geometry"]["centroid"], float)
            moved = np.asarray(mesh.vertices) + (st.move_to - centre)
            new_path = work / f"{key}_moved.ply"
            entry["filename"] = _shape_ply(new_path, moved, np.asarray(mesh.faces))
            # The scan had the light's faces there: fill the place with its surroundings.
            scene[f"{key}_patch"] = {
                "type": "ply",
                "filename": str(path),
                "bsdf": _diffuse(patch_albedo),
            }
        if st.off:
            entry.pop("emitter", None)
            entry["bsdf"] = _diffuse(patch_albedo)
        else:
            rad = np.asarray(entry["emitter"]["radiance"]["value"], float) * gain
            entry["emitter"]["radiance"]["value"] = rad.tolist()
    elif kind == "window":
        if st.off:
            entry.pop("emitter", None)
            return
        view = None  # a new sky is seen as it is, not as the photos saw the old one
        if st.window is not None:
            from reroom.data import hdri_path
            from reroom.render.emitters import load_hdri

            op = st.window
            _cells, factor = swap_window_environment(
                light, op["hdri"], op.get("was"), op.get("scale", 1.0)
            )
            # The new sky at its own resolution, only scaled into model units: a user who
            # names an HDRI expects its sun's sharp patch, not the recovered light's
            # 96-cell blur (the cells serve only to find the factor).
            env = load_hdri(hdri_path(str(op["hdri"]))) * factor[None, None, :]
        else:
            from reroom.io.images import read_exr

            exr = light.get("environment_exr", f"window_{light['name']}.exr")
            env = np.maximum(read_exr(model.invert_dir / exr)[..., :3], 0.0)
            view = read_window_view(model.invert_dir, light)
        geo = light["geometry"]
        opening = tuple(geo[k] for k in ("centre", "half_u", "half_v", "normal"))
        entry["emitter"] = portal_emitter(
            np.asarray(env * gain, np.float32),
            opening=opening,
            view=None if view is None else np.asarray(view * gain, np.float32),
        )
    elif kind in ("point", "line"):
        if st.off:
            del scene[key]
            return
        entry["scale"] = float(entry.get("scale", 1.0)) * st.scale
        entry["color"] = (np.asarray(entry["color"], float) * st.color).tolist()
        if st.move_to is not None:
            if kind == "point":
                entry["position"] = st.move_to.tolist()
            else:
                p0, p1 = np.asarray(entry["p0"], float), np.asarray(entry["p1"], float)
                shift = st.move_to - (p0 + p1) / 2.0
                entry["p0"], entry["p1"] = (p0 + shift).tolist(), (p1 + shift).tolist()


def _light_label(model: RoomModel, light: dict[str, Any]) -> str:
    """The label around an area light (the cluster its place takes when it is off/moved)."""
    if model.labels is None:
        return "ceiling"
    c = np.asarray(light["geometry"].get("centroid", model.vertices.mean(0)), float)
    d = np.linalg.norm(model.vertices - c, axis=1)
    near = (d < np.sort(d)[min(200, len(d) - 1)]) & (model.labels != _OTHER)
    if not near.any():
        return "ceiling"
    vals, counts = np.unique(model.labels[near], return_counts=True)
    return _LABEL_NAMES.get(int(vals[np.argmax(counts)]), "ceiling")


def _added_light(op: dict[str, Any]) -> dict[str, Any]:
    from reroom.render.emitters import goniometric_light, luminaire_frame

    frame = luminaire_frame(nadir=-np.asarray(op.get("up", [0.0, 0.0, 1.0]), float))
    if op.get("ies"):
        from reroom.data import ies_path
        from reroom.io.ies import read_ies

        profile = read_ies(ies_path(op["ies"]))
        d = goniometric_light(profile, op["position"], frame=frame, color=op["color"])
        # ``intensity`` is the profile's peak intensity (its brightest direction), as the
        # synthetic-truth side reads it (reroom.synth.edits).
        peak = float(np.asarray(d["intensity"], float).max())
        if not peak > 0:
            raise EditError(f"<edits>: IES profile {op['ies']!r} emits no light")
        d["scale"] = float(op["intensity"]) / peak
        return d
    return goniometric_light(
        1.0, op["position"], frame=frame, color=op["color"], scale=float(op["intensity"])
    )


def _light_centre(light: dict[str, Any]) -> np.ndarray:
    g = light["geometry"]
    if light["type"] == "point":
        return np.asarray(g["position"], float)
    if light["type"] == "line":
        return (np.asarray(g["p0"], float) + np.asarray(g["p1"], float)) / 2.0
    return np.asarray(g.get("centroid", g.get("centre")), float)


def _emitting_faces(model: RoomModel) -> np.ndarray:
    """Scan faces of area lights (the rule of ``model_scene``: two of three vertices)."""
    emitting = np.zeros(len(model.faces), bool)
    light_id = _light_ids(model)
    if light_id is None:
        return emitting
    for light in model.doc.get("lights", []):
        if light["type"] == "area" and "light_index" in light.get("geometry", {}):
            members = light_id == int(light["geometry"]["light_index"])
            emitting |= members[model.faces].sum(axis=1) >= 2
    return emitting


def _remove_from_room(
    scene: dict[str, Any], faces: np.ndarray, work: Path, name: str = "room_moved.ply"
) -> None:
    """Rewrite the scan-mesh shape ``room`` without the given faces (vertex triples), as
    ``work/name``."""
    room = read_ply(scene["room"]["filename"])
    rf = np.ascontiguousarray(np.asarray(room.faces, np.int64))
    drop = np.ascontiguousarray(np.asarray(faces, np.int64))
    row = np.dtype((np.void, rf.dtype.itemsize * 3))
    keep = ~np.isin(rf.view(row).ravel(), drop.view(row).ravel())
    path = work / name
    write_triangle_ply(
        path,
        np.asarray(room.vertices),
        rf[keep],
        {"albedo": np.asarray(room.vertex_attributes["albedo"], np.float32)},
    )
    scene["room"]["filename"] = str(path)


def _add_moved_fixture(
    scene: dict[str, Any],
    key: str,
    model: RoomModel,
    mask: np.ndarray,
    delta: np.ndarray,
    albedo: np.ndarray,
    paint: dict[str, dict[str, Any]],
    work: Path,
) -> None:
    """The fitting's faces, moved by ``delta``; a ceiling patch where it was mounted."""
    faces = model.faces[mask]
    used = np.unique(faces)
    remap = np.full(len(model.vertices), -1, np.int64)
    remap[used] = np.arange(len(used))
    ok = np.all(albedo >= 0, axis=1)[:, None]
    alb = np.where(ok, albedo, model.label_albedo("wall"))[used]
    verts = model.vertices[used]
    scene[f"{key}_fixture"] = {
        "type": "ply",
        "filename": _shape_ply(
            work / f"{key}_fixture.ply",
            verts + delta,
            remap[faces],
            albedo=np.clip(alb, 0.0, 0.95).astype(np.float32),
        ),
        "bsdf": {
            "type": "twosided",
            "bsdf": {
                "type": "diffuse",
                "reflectance": {"type": "mesh_attribute", "name": "vertex_albedo_color"},
            },
        },
    }
    # A fitting mounted on the ceiling (a tube's housing) hid the ceiling behind it, which
    # the scan never saw: close that hole with the ceiling's paint.
    a = model.to_aligned(verts)
    for _poly, _zf, zc, _name in model.rooms():
        if abs(a[:, 2].max() - zc) > 0.05:
            continue
        lo, hi = a[:, :2].min(0) - 0.01, a[:, :2].max(0) + 0.01
        z = zc - 0.001
        quad = np.array(
            [[lo[0], lo[1], z], [hi[0], lo[1], z], [hi[0], hi[1], z], [lo[0], hi[1], z]]
        )
        op = paint.get("ceiling")
        rgb = op["color"] if op is not None and "color" in op else model.label_albedo("ceiling")
        scene[f"{key}_fixture_patch"] = {
            "type": "ply",
            "filename": _shape_ply(
                work / f"{key}_fixture_patch.ply",
                model.to_mesh(quad),
                np.array([[0, 2, 1], [0, 3, 2]]),  # facing down, into the room
            ),
            "bsdf": _diffuse(rgb, twosided=True),
        }
        break


def _empty_room(
    scene: dict[str, Any],
    model: RoomModel,
    paint: dict[str, dict[str, Any]],
    work: Path,
    fixtures: np.ndarray,
    albedo: np.ndarray,
) -> None:
    """Replace the scan mesh by the layout's empty shell plus the ``fixtures`` faces
    (light fittings, with per-vertex ``albedo``)."""
    from reroom.layout.emptyroom import empty_room_mesh

    assert model.layout is not None
    shell, face_label = empty_room_mesh(model.layout, in_scan_frame=True)
    face_label = np.asarray(face_label, np.int64)
    keep = face_label != _PORTAL_PANE
    # The pane of each window lies on the recovered window rectangle: the portal replaces it.
    centres = shell.triangles_center
    normals = shell.face_normals
    for light in model.doc.get("lights", []):
        if light["type"] != "window":
            continue
        g = light["geometry"]
        c, hu, hv = (np.asarray(g[k], float) for k in ("centre", "half_u", "half_v"))
        n = np.asarray(g["normal"], float)
        rel = centres - c
        on_plane = np.abs(rel @ n) < 0.03
        parallel = np.abs(normals @ n) > 0.9
        within = (np.abs(rel @ hu) <= (hu @ hu) + 0.05 * np.linalg.norm(hu)) & (
            np.abs(rel @ hv) <= (hv @ hv) + 0.05 * np.linalg.norm(hv)
        )
        keep &= ~(on_plane & parallel & within & (face_label == _LABEL_IDS["window"]))
    del scene["room"]
    _shell_surfaces(scene, model, paint, work, shell, face_label, keep, "room")
    if fixtures.any():
        ok = np.all(albedo >= 0, axis=1)[:, None]
        alb = np.where(ok, albedo, model.label_albedo("wall"))
        scene["fixtures"] = {
            "type": "ply",
            "filename": _shape_ply(
                work / "fixtures.ply",
                model.vertices,
                model.faces[fixtures],
                albedo=np.clip(alb, 0.0, 0.95).astype(np.float32),
            ),
            "bsdf": {
                "type": "diffuse",
                "reflectance": {"type": "mesh_attribute", "name": "vertex_albedo_color"},
            },
        }


#: How far behind the layout's planes the backing shell lies at least (metres): further
#: where a room's scanned walls, floor or ceiling reach further out of their planes (the
#: 99.9th percentile plus 1 cm). The fused scans' lie within 1 cm of their planes (99.9 %
#: of their vertices on the issue's 300-frame scan; a clean scan's on them).
BACKING_GAP = 0.02
#: How much wider the backing's openings are than the layout's, on every side (metres).
BACKING_MARGIN = 0.05


def _back_the_scan(
    scene: dict[str, Any],
    model: RoomModel,
    paint: dict[str, dict[str, Any]],
    work: Path,
) -> None:
    """Add the layout's shell behind the scan (``backing_*`` shapes): it shows, and
    reflects light, only through the scan's holes.

    Only rooms whose ceiling was seen: a room with an estimated ceiling (a real scan
    that never looked up) has a lower bound for a ceiling and an outline grown to hold
    the cameras, not measured surfaces; its holes keep the constant surroundings the
    solve fitted (:func:`reroom.edit.model.surroundings_emitter`).
    """
    from reroom.layout.emptyroom import backing_shell, depth_behind_planes, reveal_points

    assert model.layout is not None
    rooms = [r for r in model.layout.get("rooms", []) if r.get("ceiling", "seen") == "seen"]
    if not rooms:
        return
    portals = [
        tuple(
            np.asarray(light["geometry"][k], float)
            for k in ("centre", "half_u", "half_v", "normal")
        )
        for light in model.doc.get("lights", [])
        if light["type"] == "window"
    ]
    # Each room's shell lies behind every scanned surface of its walls, floor and
    # ceiling: BACKING_GAP, or 1 cm more than the scan's surfaces reach out of the
    # layout's planes where a plane was fitted in front of them (clutter along a wall).
    labels = model.labels if model.labels is not None else np.full(len(model.vertices), -1)
    aligned = model.to_aligned(model.vertices)
    parts = []
    for k, room in enumerate(rooms):
        try:
            gap = max(BACKING_GAP, depth_behind_planes(room, aligned, labels) + 0.01)
            mesh, face_label = backing_shell(
                {**model.layout, "rooms": [room]}, gap, BACKING_MARGIN, portals=portals
            )
            parts.append((mesh, face_label, reveal_points(room, aligned, labels)))
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            # A hand-edited layout.json: the scan still renders, without this room's shell.
            warnings.warn(
                f"{model.layout_dir / 'layout.json'}: room {room.get('name', k)!r} does not "
                f"make a shell ({type(exc).__name__}: {exc}): rendered without its shell "
                "behind the scan",
                stacklevel=3,
            )
    parts = [(m, lab, reveal) for m, lab, reveal in parts if len(m.faces)]
    if not parts:
        return
    # The scan's window reveals give way to the shell's (its planes, the reveals'
    # albedo): a fused scan rounds a reveal over a voxel or two, and where the walk never
    # saw a jamb it holds only that bevel, dark in the window's light. On the issue's
    # `furnished` scan a new camera looking past the unseen jamb renders 43 -> 38 %
    # from the truth with the panel off (docs/benchmarks.md, session 48).
    on_reveal = np.logical_or.reduce([reveal for _, _, reveal in parts])
    reveal_faces = on_reveal[model.faces].all(axis=1)
    if reveal_faces.any():
        _remove_from_room(scene, model.faces[reveal_faces], work, "room_no_reveals.ply")
    shell = trimesh.util.concatenate([m for m, _, _ in parts])
    face_label = np.concatenate([lab for _, lab, _ in parts]).astype(np.int64)
    # Seen only through holes (where no photo looked), the shell's planes show their mean
    # albedo, not their photo texture: the same light, without loading a texture image
    # per plane into every render (on the 640x360 scan 29 MB of them, 3 s of its edits).
    everything = np.ones(len(face_label), bool)
    _shell_surfaces(scene, model, paint, work, shell, face_label, everything, "backing", False)


def _shell_surfaces(
    scene: dict[str, Any],
    model: RoomModel,
    paint: dict[str, dict[str, Any]],
    work: Path,
    shell: trimesh.Trimesh,
    face_label: np.ndarray,
    keep: np.ndarray,
    prefix: str,
    patterned: bool = True,
) -> None:
    """Add the ``keep`` faces of a layout shell (the empty room, or the backing behind the
    scan) as ``PREFIX_<label>`` and ``PREFIX_texture_<plane>`` shapes: photo-textured
    where a plane has a photo texture and is not repainted (without ``patterned``: the
    plane's mean albedo, no image), else the label's albedo or its repaint."""
    sv, sf = np.asarray(shell.vertices, float), np.asarray(shell.faces)
    keep = np.asarray(keep, bool).copy()
    # The shell's faces on a photo-textured plane (floor, ceiling, walls not repainted).
    photo = np.full(len(sf), -1, np.int64)
    if model.photo_textures:
        from reroom.invert.textures import match_planes

        face_names = _label_names(face_label)
        photo = match_planes([t for t, _ in model.photo_textures], sv, sf, face_names)
        photo[~keep | np.isin(face_names, sorted(paint))] = -1
        from reroom.io.images import write_exr

        for k, (tex, _) in enumerate(model.photo_textures):
            sel = photo == k
            if not sel.any():
                continue
            # The shell takes the plane's pattern (detail) at the plane's mean
            # albedo: the texture's own local mean holds what stood there (a sofa's
            # shadow, a rug). The mean, not the cluster's robust albedo, which follows
            # a patterned floor's median (docs/edit.md, "Photo textures").
            if not patterned:
                scene[f"{prefix}_texture_{tex.name}"] = {
                    "type": "ply",
                    "filename": _shape_ply(work / f"{prefix}_texture_{tex.name}.ply", sv, sf[sel]),
                    "face_normals": True,
                    "bsdf": _diffuse(np.clip(model.texture_level(k), 0.0, 0.95), twosided=True),
                }
                continue
            detail, level = model.texture_detail(k)
            image = write_exr(
                work / f"{prefix}_texture_{tex.name}.exr", np.clip(detail * level, 0.0, 0.95)
            )
            scene[f"{prefix}_texture_{tex.name}"] = _photo_textured_shape(
                work / f"{prefix}_texture_{tex.name}.ply", sv, sf[sel], tex, image.resolve(), True
            )
    keep &= photo < 0
    for lab in np.unique(face_label[keep]):
        label = _LABEL_NAMES.get(int(lab), "wall")
        sel = keep & (face_label == lab)
        # A window's reveals take the albedo the scan measured on its reveals (the
        # median of its window-labelled vertices; the wall's where it saw fewer than 3)
        # and no wall's repaint: a reveal is no wall, for the scan's own vertices (a
        # wall repaint recolours wall-labelled vertices only) as for the true room
        # (the issue's `furnished` reveals are 0.80/0.80/0.78 in walls of
        # 0.72/0.68/0.60). Measured in the model's light, the scanned reveals'
        # albedo also carries what that light misses on them (daylight at grazing
        # angles): on the issue's fused scan their median is 0.94/0.89/0.68, and the
        # new camera that meets the shell's jamb renders 4 points closer to the truth
        # with it (docs/benchmarks.md, session 47).
        op = paint.get(label)
        if op is not None and "texture" in op:
            scene[f"{prefix}_{label}"] = _textured_shape(
                work / f"{prefix}_{label}.ply", sv, sf[sel], op["texture"], op["metres_per_tile"]
            )
            continue
        rgb = op["color"] if op is not None else model.label_albedo(label)
        scene[f"{prefix}_{label}"] = {
            "type": "ply",
            "filename": _shape_ply(work / f"{prefix}_{label}.ply", sv, sf[sel]),
            "face_normals": True,
            "bsdf": _diffuse(rgb, twosided=True),
        }


def _light_ids(model: RoomModel) -> np.ndarray | None:
    path = model.lights_dir / "lights_vertices.npz"
    if not path.is_file():
        return None
    with np.load(path) as z:
        return np.asarray(z["light_id"])


def _texture_scan(
    scene: dict[str, Any], model: RoomModel, textured: dict[str, dict[str, Any]], work: Path
) -> None:
    """Move the faces of textured repaint targets out of the scan mesh into textured shapes."""
    if not textured:
        return
    if model.labels is None:
        raise EditError(f"<edits>: texture repaints need {model.layout_dir / 'layout_labels.ply'}")
    room = read_ply(scene["room"]["filename"])
    faces = np.asarray(room.faces)
    flab = _face_labels(model.labels, faces)
    rest = np.ones(len(faces), bool)
    for target, op in textured.items():
        sel = flab == _LABEL_IDS.get(target, -1)
        if not sel.any():
            continue
        rest &= ~sel
        scene[f"paint_{target}"] = _textured_shape(
            work / f"paint_{target}.ply",
            np.asarray(room.vertices),
            faces[sel],
            op["texture"],
            op["metres_per_tile"],
        )
    path = work / "room_rest.ply"
    write_triangle_ply(
        path,
        np.asarray(room.vertices),
        faces[rest],
        {"albedo": np.asarray(room.vertex_attributes["albedo"], np.float32)},
    )
    scene["room"]["filename"] = str(path)
