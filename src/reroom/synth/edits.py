"""Edits applied to a synthetic scan's *true* scene, rendered by the same path tracer.

The end-to-end fidelity benchmark (issue #6, item 6) compares a render of the edited
*recovered* model with the truth: the same edit applied to the generator's own scene
description (``ground_truth/scene/scene.json``, see :mod:`reroom.synth.scene`) and
rendered with the same Mitsuba ``path`` integrator that made the scan's frames.

:func:`apply_edits` reads an edit list in the shared ``reroom-edits`` format (the same
operations the model side takes, see ``docs/formats.md``), never touches the scan's
ground truth, and writes a complete, self-contained scene folder: the original meshes,
textures, photometry and HDRIs are copied, changed or new parts get new mesh files, and
the new ``scene.json`` is written last (atomically). :func:`render_scene` renders such a
folder from any cameras as linear radiance.

Truth-side meaning of each operation (positions in the scan's mesh frame, metres, +Z up;
colours linear RGB):

* ``empty`` -- drop every part labelled ``furniture`` *except light fixtures*: the
  generator labels a lamp's pole and shade and a tube's housing and baffles as
  furniture, names them after their light (``floor_lamp_shade``, ``tube_baffles``) and a
  recovered light's distribution already contains their shadowing, so an "empty room
  with the lights still on" keeps them. ``keep_fixtures=False`` drops them as well.
* ``repaint`` -- every part with the target label (or the part of that exact name)
  becomes diffuse with the given albedo, or with a texture (a PNG is sRGB-decoded into a
  linear EXR; the material's ``albedo`` becomes the texture's mean).
* ``light`` -- ``off``; ``scale`` (area/line radiance, point power, window scale);
  ``color`` (multiplies the RGB emission; point lights keep their meaning of ``power``
  as the flux of the mean channel, windows get a tinted copy of their HDRI);
  ``move_to`` (point: new position; area/line: new centre, the emitting part and its
  fixture parts translated; an area light's old recess in the ceiling or wall is closed
  with a patch of that surface).
* ``add_light`` -- a point light (isotropic, or a shipped/user IES profile) of radiant
  intensity ``intensity * color`` per channel (for a profile: at the profile's peak).
* ``window`` -- the window's HDRI replaced (its strength and rotation kept, times the
  op's ``scale``).
* ``insert`` -- a bundled furniture model or a mesh file, built and placed by
  :func:`reroom.edit.furniture.placed_object` as on the model side, footprint centre at
  ``position`` with its base at that height, rotated about +Z and scaled, diffuse with
  ``color``, labelled ``furniture``. Outside every room's floor polygon (from the scan's
  ``ground_truth.json`` layout) it is an error.
"""

from __future__ import annotations

import copy
import json
import shutil
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from reroom.edit.edits import EditError, check_names, load_edits, parse_edits
from reroom.errors import ReroomError, ScanError
from reroom.io.atomic import atomic_write_json
from reroom.synth.geometry import Piece, grid_rect
from reroom.synth.scene import SCENE_JSON, _write_part_ply, load_scene_description

__all__ = [
    "EditError",
    "apply_edits",
    "edit_description",
    "fixture_parts",
    "light_centre",
    "render_scene",
]


# --------------------------------------------------------------------------- helpers


def _read_piece(path: Path) -> Piece:
    """A part mesh (positions, normals, uv) as written by :func:`reroom.synth.scene.write_scene`."""
    from plyfile import PlyData

    try:
        ply = PlyData.read(str(path))
    except (OSError, ValueError) as exc:
        raise ScanError(path, f"part mesh is missing or unreadable ({exc})") from exc
    v = ply["vertex"].data
    names = v.dtype.names or ()
    verts = np.stack([v["x"], v["y"], v["z"]], 1).astype(np.float64)
    if {"nx", "ny", "nz"} <= set(names):
        normals = np.stack([v["nx"], v["ny"], v["nz"]], 1).astype(np.float64)
    else:
        normals = np.zeros_like(verts)
    uv = np.stack([v["u"], v["v"]], 1) if {"u", "v"} <= set(names) else np.zeros((len(v), 2))
    faces = np.vstack(ply["face"].data["vertex_indices"]).astype(np.int64)
    return Piece(verts, faces, normals, uv.astype(np.float64))


def _translation(delta: Sequence[float]) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = np.asarray(delta, float)
    return m


def fixture_parts(desc: dict[str, Any], light: dict[str, Any]) -> list[dict[str, Any]]:
    """The parts that belong to a light's fitting: its emitting part and ``<name>_*`` parts.

    The generator names a fitting's pieces after its light (``ceiling_panel_rim``,
    ``tube_housing``, ``floor_lamp_shade``), whatever their label. Patches that close a
    moved light's old recess (marked ``patch_for``) belong to the room, not the fitting.
    """
    name = light["name"]
    own = light.get("part")
    return [
        p
        for p in desc["parts"]
        if "patch_for" not in p and (p["name"] == own or p["name"].startswith(f"{name}_"))
    ]


def light_centre(light: dict[str, Any]) -> np.ndarray:
    """Position of a light: point position, line midpoint, area/window rectangle centre."""
    kind = light["type"]
    if kind == "point":
        return np.asarray(light["position"], float)
    if kind == "line":
        return 0.5 * (np.asarray(light["p0"], float) + np.asarray(light["p1"], float))
    return np.asarray(light["corners"], float).mean(axis=0)


def _find_light(desc: dict[str, Any], name: Any, op: dict) -> dict[str, Any]:
    for light in desc["lights"]:
        if light["name"] == name:
            return light
    names = [light["name"] for light in desc["lights"]]
    raise EditError(f"no light named {name!r} in the scene (lights: {names})")


class _Editor:
    """Applies operations to a description whose files live in ``out_dir``."""

    def __init__(
        self,
        desc: dict[str, Any],
        out_dir: Path,
        layout: dict[str, Any] | None,
        keep_fixtures: bool,
    ) -> None:
        self.desc = desc
        self.out = out_dir
        self.layout = layout
        self.keep_fixtures = keep_fixtures
        self.counter = 0
        self.index = 0  # of the operation being applied, for error messages

    # -- files --------------------------------------------------------------------
    def _new_name(self, stem: str, suffix: str, folder: str) -> str:
        self.counter += 1
        safe = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in stem)
        return f"{folder}/edit{self.counter:03d}_{safe}{suffix}"

    def _write_piece(self, stem: str, piece: Piece) -> str:
        rel = self._new_name(stem, ".ply", "meshes")
        _write_part_ply(self.out / rel, piece)
        return rel

    # -- operations -----------------------------------------------------------------
    def apply(self, op: dict[str, Any]) -> None:
        """Apply one operation, already checked by :func:`reroom.edit.edits.parse_edits`."""
        try:
            getattr(self, f"op_{op['op']}")(op)
        except EditError as exc:
            raise EditError(f"<edits>: edit {self.index} ({op['op']}): {exc}") from exc
        self.index += 1

    def op_empty(self, op: dict) -> None:
        keep: set[str] = set()
        if self.keep_fixtures:
            for light in self.desc["lights"]:
                keep.update(p["name"] for p in fixture_parts(self.desc, light))
        self.desc["parts"] = [
            p for p in self.desc["parts"] if p["label"] != "furniture" or p["name"] in keep
        ]

    def op_repaint(self, op: dict) -> None:
        target = op["target"]
        parts = [p for p in self.desc["parts"] if p["label"] == target]
        if not parts:
            parts = [p for p in self.desc["parts"] if p["name"] == target]
        if not parts:
            labels = sorted({p["label"] for p in self.desc["parts"]})
            raise EditError(f"no part with label or name {target!r} (labels: {labels})")
        if "texture" in op:
            tex_name, mean = self._add_texture(op)
            material = {"type": "diffuse", "texture": tex_name, "albedo": mean}
        else:
            material = {"type": "diffuse", "albedo": [float(x) for x in op["color"]]}
        for p in parts:
            p["material"] = dict(material)

    def _add_texture(self, op: dict) -> tuple[str, list[float]]:
        from reroom.io.images import read_exr, read_rgb8, write_exr

        src = Path(op["texture"])
        if src.suffix.lower() == ".exr":
            img = np.asarray(read_exr(src), np.float32)[..., :3]
        else:
            # 8-bit textures are sRGB-encoded pictures; Mitsuba reads the EXR as raw albedo.
            x = read_rgb8(src).astype(np.float64) / 255.0
            img = np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
            img = img.astype(np.float32)
        if img.ndim != 3 or img.shape[0] < 1 or img.shape[1] < 1:
            raise ScanError(src, "texture is not a colour image")
        img = np.clip(img, 0.0, 1.0)
        rel = self._new_name(src.stem, ".exr", "textures")
        write_exr(self.out / rel, img)
        tile = float(op.get("metres_per_tile", 1.0))
        name = Path(rel).stem
        self.desc["textures"][name] = {"file": rel, "metres_per_tile": tile}
        return name, img.reshape(-1, 3).mean(axis=0).astype(float).tolist()

    def op_light(self, op: dict) -> None:
        light = _find_light(self.desc, op["name"], op)
        if "off" in op:
            light["on"] = not op["off"]
        if "scale" in op:
            self._scale_light(light, np.full(3, float(op["scale"])))
        if "color" in op:
            self._scale_light(light, np.asarray(op["color"], float))
        if "move_to" in op:
            self._move_light(light, np.asarray(op["move_to"], float), op)

    def _scale_light(self, light: dict, rgb: np.ndarray) -> None:
        kind = light["type"]
        if kind in ("area", "line"):
            light["radiance"] = (np.asarray(light["radiance"], float) * rgb).tolist()
            for p in self.desc["parts"]:
                if p["name"] == light.get("part") and p.get("emission") is not None:
                    p["emission"] = list(light["radiance"])
        elif kind == "point":
            # The renderer normalises the colour to mean 1 and reads `power` as the mean
            # channel's flux: multiply the colour and rescale the power by the mean's change.
            c = np.asarray(light.get("color", [1.0, 1.0, 1.0]), float)
            c_new = c * rgb
            if c_new.mean() <= 0:
                light["power"] = 0.0
            else:
                light["power"] = float(light["power"]) * float(c_new.mean() / c.mean())
                light["color"] = c_new.tolist()
        elif kind == "window":
            if np.allclose(rgb, rgb[0]):
                light["scale"] = float(light.get("scale", 1.0)) * float(rgb[0])
            else:
                self._tint_hdri(light, rgb)
        else:
            raise EditError(f"light {light['name']!r} has an unknown type {kind!r}")

    def _tint_hdri(self, light: dict, rgb: np.ndarray) -> None:
        from reroom.io.images import read_exr, write_exr

        src = self.out / light["hdri_file"]
        img = np.asarray(read_exr(src), np.float32)[..., :3] * rgb.astype(np.float32)
        rel = self._new_name(Path(light["hdri_file"]).stem + "_tinted", ".exr", "hdri")
        write_exr(self.out / rel, img)
        light["hdri_file"] = rel

    def _move_light(self, light: dict, target: np.ndarray, op: dict) -> None:
        kind = light["type"]
        delta = target - light_centre(light)
        if kind == "window":
            raise EditError("a window cannot be moved")
        if kind == "point":
            light["position"] = target.tolist()
        elif kind == "line":
            light["p0"] = (np.asarray(light["p0"], float) + delta).tolist()
            light["p1"] = (np.asarray(light["p1"], float) + delta).tolist()
        elif kind == "area":
            self._close_recess(light)
            light["corners"] = (np.asarray(light["corners"], float) + delta).tolist()
        # A lamp's shade, a tube's housing and a panel's rim go where their light goes.
        for part in fixture_parts(self.desc, light):
            piece = _read_piece(self.out / part["file"]).transformed(_translation(delta))
            part["file"] = self._write_piece(part["name"], piece)

    def _close_recess(self, light: dict) -> None:
        """Cover the opening an area light's recess leaves in its ceiling (or wall).

        The generator cuts a hole in the ceiling where a panel sits; the panel's rim
        lines the hole up to the ceiling plane. The patch is the light's rectangle moved
        back to the depth of the rim's top, facing the room, with the material of the
        surface around it.
        """
        corners = np.asarray(light["corners"], float)
        n = np.asarray(light["normal"], float)
        n = n / np.linalg.norm(n)
        depth = 0.0
        for part in fixture_parts(self.desc, light):
            v = _read_piece(self.out / part["file"]).vertices
            depth = max(depth, float(np.max((corners[0] - v) @ n)))
        o = corners[0] - depth * n
        u, v = corners[1] - corners[0], corners[3] - corners[0]
        lu, lv = float(np.linalg.norm(u)), float(np.linalg.norm(v))
        if np.dot(np.cross(u, v), n) > 0:
            piece = grid_rect(o, u, v, lu, lv, max(lu, lv))
        else:
            piece = grid_rect(o, v, u, lv, lu, max(lu, lv))
        host = "ceiling" if n[2] < -0.5 else "floor" if n[2] > 0.5 else "wall"
        material = next(
            (copy.deepcopy(p["material"]) for p in self.desc["parts"] if p["label"] == host),
            {"type": "diffuse", "albedo": [0.8, 0.8, 0.8]},
        )
        self.desc["parts"].append(
            {
                "name": f"{light['name']}_recess_patch",
                "file": self._write_piece(f"{light['name']}_recess_patch", piece),
                "label": host,
                "material": material,
                "emission": None,
                "in_scan": True,
                "patch_for": light["name"],
            }
        )

    def op_add_light(self, op: dict) -> None:
        color = np.asarray(op["color"], float)
        if not op["intensity"] > 0 or color.mean() <= 0:
            raise EditError("a light added with no intensity or colour emits nothing")
        light: dict[str, Any] = {
            "name": op["name"],
            "type": "point",
            "position": [float(x) for x in op["position"]],
            "up": [float(x) for x in op.get("up", [0.0, 0.0, 1.0])],
            "profile": "isotropic",
            "color": color.tolist(),
            "on": True,
        }
        # Rendered intensity is power * shape / integral(shape) * color / mean(color):
        # choose the power that makes it `intensity * color` (at the profile's peak).
        flux_over_peak = 4.0 * np.pi
        if op.get("ies"):
            from reroom.data import ies_path
            from reroom.io.ies import read_ies

            src = ies_path(str(op["ies"]))
            table = read_ies(src)
            rel = self._new_name(src.stem, ".ies", "ies")
            (self.out / "ies").mkdir(exist_ok=True)
            shutil.copyfile(src, self.out / rel)
            light["profile"] = src.stem
            light["profile_file"] = rel
            flux_over_peak = _ies_flux_over_peak(table)
        light["power"] = float(op["intensity"] * color.mean() * flux_over_peak)
        self.desc["lights"].append(light)

    def op_window(self, op: dict) -> None:
        from reroom.data import hdri_path

        light = _find_light(self.desc, op["name"], op)
        src = hdri_path(str(op["hdri"]))
        rel = f"hdri/{src.name}"
        if not (self.out / rel).exists():
            (self.out / "hdri").mkdir(exist_ok=True)
            shutil.copyfile(src, self.out / rel)
        light["hdri"] = str(op["hdri"])
        light["hdri_file"] = rel
        light["scale"] = float(light.get("scale", 1.0)) * float(op.get("scale", 1.0))

    def op_insert(self, op: dict) -> None:
        pos = np.asarray(op["position"], float)
        self._check_inside(op["object"], pos, op)
        piece = _placed_piece(op)
        base = op.get("name") or f"inserted_{Path(str(op['object'])).stem}"
        name, k = base, 1
        existing = {p["name"] for p in self.desc["parts"]}
        while name in existing:
            k += 1
            name = f"{base}_{k}"
        self.desc["parts"].append(
            {
                "name": name,
                "file": self._write_piece(name, piece),
                "label": "furniture",
                "material": {"type": "diffuse", "albedo": [float(x) for x in op["color"]]},
                "emission": None,
                "in_scan": True,
            }
        )

    def _check_inside(self, obj: Any, pos: np.ndarray, op: dict) -> None:
        if self.layout is None:
            return
        from matplotlib.path import Path as MplPath

        for room in self.layout.get("rooms", []):
            if MplPath(np.asarray(room["polygon"], float)).contains_point(pos[:2]):
                return
        raise EditError(
            f"object {obj!r} at position {pos.tolist()} is outside the room's floor polygon"
        )


def _ies_flux_over_peak(profile: Any) -> float:
    """Flux over peak intensity (steradians) of an IES profile, as the renderer tabulates it."""
    from reroom.render.emitters import goniometric_light

    d = goniometric_light(profile, position=[0.0, 0.0, 0.0], flux=1.0)
    peak = float(np.asarray(d["intensity"], float).max()) * float(d["scale"])
    if not peak > 0:
        raise EditError("the IES profile emits no light")
    return 1.0 / peak


def _placed_piece(op: dict) -> Piece:
    """The placed geometry of an ``insert`` op, built by the model side's own code.

    :func:`reroom.edit.furniture.placed_object` makes the bundled models and loads mesh
    files for the model side too, so both sides insert the very same triangles. Faces
    get their own vertices with the face normal: the bundled boxes share corner
    vertices, and Mitsuba would otherwise interpolate the averaged corner normals across
    each flat face.
    """
    from reroom.edit.furniture import placed_object

    try:
        mesh = placed_object(
            str(op["object"]),
            op["position"],
            rotation_deg=float(op.get("rotation_deg", 0.0)),
            scale=float(op.get("scale", 1.0)),
        )
    except ReroomError as exc:
        raise EditError(f"{exc}") from exc
    tri = np.asarray(mesh.triangles, float).reshape(-1, 3)
    normals = np.repeat(np.asarray(mesh.face_normals, float), 3, axis=0)
    faces = np.arange(len(tri)).reshape(-1, 3)
    return Piece(tri, faces, normals, np.zeros((len(tri), 2)))


# --------------------------------------------------------------------------- API


def edit_description(
    desc: dict[str, Any],
    edits: Any,
    out_dir: str | Path,
    *,
    layout: dict[str, Any] | None = None,
    keep_fixtures: bool = True,
    base_dir: str | Path | None = None,
) -> dict[str, Any]:
    """Apply ``edits`` to a copy of ``desc`` whose files are already in ``out_dir``.

    The edits are checked and normalised by :func:`reroom.edit.edits.parse_edits` (the
    model side's own parser) and their names by :func:`reroom.edit.edits.check_names`
    against this scene's lights and part labels/names. New and changed meshes, textures
    and HDRIs are written into ``out_dir``; ``scene.json`` is not (see
    :func:`apply_edits`). Returns the new description.

    Parameters
    ----------
    edits:
        An edit document, a list of operations or one operation.
    base_dir:
        Folder that relative file names in the edits resolve against.

    Raises
    ------
    EditError
        When an edit is malformed, names a light or target the scene does not have,
        names a file that does not load, or places an object outside every room of
        ``layout``.
    """
    ops = parse_edits(edits, base_dir=base_dir)
    lights = {light["name"]: light["type"] for light in desc["lights"]}
    targets = {p["label"] for p in desc["parts"]} | {p["name"] for p in desc["parts"]}
    check_names(ops, lights, targets)
    editor = _Editor(copy.deepcopy(desc), Path(out_dir), layout, keep_fixtures)
    for op in ops:
        editor.apply(op)
    editor.desc["edits"] = list(desc.get("edits", [])) + ops
    return editor.desc


def apply_edits(
    scene_dir: str | Path,
    edits: Any,
    out_dir: str | Path,
    *,
    layout: dict[str, Any] | None = None,
    keep_fixtures: bool = True,
) -> dict[str, Any]:
    """Write the edited copy of a true scene into ``out_dir`` and return its description.

    Parameters
    ----------
    scene_dir:
        A scene folder (``SCAN/ground_truth/scene``): ``scene.json`` and its files. It is
        only read.
    edits:
        An edit document, a list of operations (``reroom-edits`` format), or the path of
        an edit file (its relative file names resolve against its folder).
    out_dir:
        The new scene folder (created; must not be ``scene_dir``). Its ``scene.json``
        is written last, atomically, so a folder with one is complete. The applied
        (normalised) edits are recorded in it under ``edits``.
    layout:
        Room polygons for the ``insert`` check (``{"rooms": [{"polygon": ...}]}``);
        default: the ``layout`` of ``ground_truth.json`` next to ``scene_dir`` when there
        is one (no check otherwise).
    keep_fixtures:
        Whether ``empty`` keeps the parts of light fittings that are labelled furniture.

    Raises
    ------
    ScanError
        When ``scene_dir`` has no readable ``scene.json`` or ``out_dir`` is ``scene_dir``.
    EditError
        See :func:`edit_description`.
    """
    src = Path(scene_dir)
    out = Path(out_dir)
    if not (src / SCENE_JSON).is_file():
        raise ScanError(src / SCENE_JSON, "is missing: not a ground-truth scene folder")
    if out.resolve() == src.resolve():
        raise ScanError(out, "is the scan's own ground-truth scene; edits go to a new folder")
    base_dir: Path | None = None
    if isinstance(edits, str | Path):
        base_dir = Path(edits).resolve().parent
        edits = load_edits(edits)
    try:
        desc = load_scene_description(src)
    except ValueError as exc:
        raise ScanError(src / SCENE_JSON, f"is not valid JSON ({exc})") from exc
    if layout is None:
        gt = src.parent / "ground_truth.json"
        if gt.is_file():
            layout = json.loads(gt.read_text()).get("layout")
    # A stale scene.json from an earlier run goes first, so an interrupted edit never
    # leaves a folder that looks complete; then a full copy of the scene's files.
    out.mkdir(parents=True, exist_ok=True)
    (out / SCENE_JSON).unlink(missing_ok=True)
    for item in src.iterdir():
        if item.name == SCENE_JSON:
            continue
        if item.is_dir():
            shutil.copytree(item, out / item.name, dirs_exist_ok=True)
        else:
            shutil.copyfile(item, out / item.name)
    new = edit_description(
        desc, edits, out, layout=layout, keep_fixtures=keep_fixtures, base_dir=base_dir
    )
    atomic_write_json(out / SCENE_JSON, new)
    return new


def render_scene(
    scene_dir: str | Path,
    cameras: Sequence[tuple[np.ndarray, Any]],
    spp: int,
    seed: int = 0,
    desc: dict[str, Any] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[np.ndarray]:
    """Path-trace a scene folder from cameras: linear RGB radiance, one ``(H, W, 3)`` each.

    The same translation (:func:`reroom.synth.scene.mitsuba_scene_dict`) and renderer
    (:class:`reroom.render.frames.FrameRenderer`) as the scan's frames.

    Parameters
    ----------
    cameras:
        ``(c2w, intrinsics)`` pairs: camera-to-world in OpenGL axes and a
        :class:`reroom.scan.Intrinsics`.
    spp:
        Samples per pixel.
    seed:
        Base seed; camera ``i`` uses ``seed * 100003 + i`` (two calls with different
        seeds give independent noise).
    desc:
        The description (default: ``scene_dir/scene.json``).
    """
    from reroom.render.frames import FrameRenderer
    from reroom.synth.scene import mitsuba_scene_dict

    scene_dir = Path(scene_dir)
    if desc is None:
        if not (scene_dir / SCENE_JSON).is_file():
            raise ScanError(scene_dir / SCENE_JSON, "is missing: not a scene folder")
        desc = load_scene_description(scene_dir)
    scene = mitsuba_scene_dict(desc, scene_dir)
    renderers: dict[tuple, FrameRenderer] = {}
    out = []
    for i, (c2w, intr) in enumerate(cameras):
        key = (intr.width, intr.height, intr.fx, intr.fy, intr.cx, intr.cy)
        if key not in renderers:
            renderers[key] = FrameRenderer(scene, intr, spp)
        out.append(renderers[key].render(np.asarray(c2w, float), seed=seed * 100003 + i))
        if progress is not None:
            progress(i + 1, len(cameras))
    return out
