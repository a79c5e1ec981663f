"""Glowing fittings seen by the camera (a tube's surface, a bulb), added after the path tracer.

In the recovered model a point or a line light is a delta emitter whose distribution was
fitted to the light the room receives, and the surface that glows around it (the tube of
a fluorescent fitting, a bare bulb) is left out of the rendered scene: its mesh would
enclose the emitter, and its light is already in the solved distribution. A camera that
looks at the fitting must still see it glow, and the photos cannot say how brightly:
auto-exposed for the room, they saw it saturated. So the glow's radiance comes from the
solved light itself.

For a light of radiant intensity ``I(w)`` (W/sr) whose glowing surface shows the visible
projected area ``A_vis(w)`` towards a camera, a uniformly glowing surface that sends that
camera the same light has the radiance ``L(w) = I(w) / A_vis(w)``. A Lambertian tube of
radiance ``L`` and radius ``r`` has ``J = 2 r L`` per unit length, and its visible width is
``2 r``, so the rule gives back ``L`` exactly; a housing that hides part of the tube
lowers ``I`` (in the solved distribution) and ``A_vis`` alike. For a line light the rule
is applied per unit length (``L = J(theta, phi) / w_vis``, ``w_vis`` the visible projected
width, each element's ``cos(phi)`` divided out), as its camera is rarely in the far field.
``w_vis`` is measured on the faces along the line (its side): faces that face along it (a
tube's end caps, when the photos saw them glow) show the same radiance, and add their
light, which the line model cannot hold (it grows as ``sin(phi)`` at the ends).

``A_vis`` is measured by shadow rays: points spread over the glowing faces by area, each
counted with its ``cos`` towards the camera unless something within ``reach`` (the
fitting: housing, baffles, the tube's own far side, the ceiling it hangs from) hides it.
Objects further away (a chair between the camera and the lamp) do not shrink ``A_vis``:
they hide the glow in the picture instead. The picture is then made with ``supersample x
supersample`` rays per pixel: a ray whose closest hit is a glowing face (closer than
anything in the rendered scene) takes that light's radiance, and the pixel becomes
``(1 - coverage) x render + glow``.

Scene dicts carry a glow as a plain entry ``{"type": "reroom_glow", "filename": PLY,
"light": KEY, "origin": [x, y, z]}``: the faces (as scanned), the key of the point or line
emitter entry whose (edited) intensity, colour and position they show, and that light's
centre when the faces were written, so that a moved light takes its glow along. When
the light's entry is gone (switched off) the glow is too. :func:`split_glow` takes these
entries out before ``mi.load_dict``; :class:`reroom.render.frames.FrameRenderer` does
this and composites them.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from reroom.scan.camera import Intrinsics

__all__ = [
    "GLOW",
    "GlowSource",
    "glow_entry",
    "glow_layer",
    "light_intensity",
    "split_glow",
    "visible_projected_area",
]

#: The ``type`` of a glow entry in a scene dict.
GLOW = "reroom_glow"

#: Shadow rays from the glowing faces towards the camera count as hidden when something
#: blocks them within this distance (metres): the fitting around the light.
DEFAULT_REACH = 0.5

#: A line light's glowing face is part of its side (not an end cap) when its normal is
#: within 45 degrees of the plane perpendicular to the line: ``|n . t| <`` this.
SIDE_COS = math.cos(math.radians(45.0))


def glow_entry(filename: str, light: str, origin: np.ndarray) -> dict[str, Any]:
    """A scene-dict entry for the glowing faces in PLY ``filename`` of emitter entry ``light``."""
    return {
        "type": GLOW,
        "filename": str(filename),
        "light": str(light),
        "origin": [float(x) for x in np.asarray(origin, float)],
    }


def split_glow(scene: dict[str, Any]) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
    """``(scene without glow entries, {key: glow entry})``; the input is not modified."""
    glows = {k: v for k, v in scene.items() if isinstance(v, dict) and v.get("type") == GLOW}
    rest = {k: v for k, v in scene.items() if k not in glows}
    return rest, glows


def _light_centre(entry: dict[str, Any]) -> np.ndarray:
    if "p0" in entry:
        return (np.asarray(entry["p0"], float) + np.asarray(entry["p1"], float)) / 2.0
    return np.asarray(entry["position"], float)


def light_intensity(entry: dict[str, Any], directions: np.ndarray) -> np.ndarray:
    """Radiant intensity ``(N, 3)`` of an emitter entry along unit world ``directions``.

    A ``reroom_goniometric`` point light: ``scale x color x table(theta, phi)`` in its
    luminaire frame (bilinear, as the emitter looks it up). A ``reroom_line``: *per unit
    length* and without the element's ``cos(phi)``, i.e. ``scale x color x J(theta,
    phi)`` (W/(sr m)), the radiance-times-width a glowing line shows.
    """
    from reroom.render.emitters import GONIOMETRIC
    from reroom.render.line_emitter import LINE, _perp_up, line_profile_value

    d = np.asarray(directions, float).reshape(-1, 3)
    color = np.broadcast_to(np.asarray(entry.get("color", [1.0, 1.0, 1.0]), float), (3,))
    scale = float(entry.get("scale", 1.0))
    kind = entry.get("type")
    if kind == LINE:
        p0, p1 = np.asarray(entry["p0"], float), np.asarray(entry["p1"], float)
        t, up = _perp_up(p0, p1, np.asarray(entry.get("up", [0.0, 0.0, 1.0]), float))
        prof = np.array(entry["profile"], dtype=np.float64)
        sin_phi = np.clip(d @ t, -1.0, 1.0)
        perp = d - sin_phi[:, None] * t
        norm = np.maximum(np.linalg.norm(perp, axis=1), 1e-12)
        theta = np.arccos(np.clip((perp @ up) / norm, -1.0, 1.0))
        phi = np.arcsin(sin_phi)
        j = line_profile_value(
            prof,
            theta,
            str(entry.get("interpolation", "linear")),
            phi if prof.ndim == 2 and prof.shape[1] > 1 else None,
            bool(entry.get("phi_fold", True)),
        )
        return scale * j[:, None] * color[None, :]
    if kind == GONIOMETRIC:
        m = np.eye(4)
        if "to_world" in entry:
            m = np.array(entry["to_world"].matrix, dtype=np.float64).reshape(4, 4)
        u, _, vt = np.linalg.svd(m[:3, :3])
        local = d @ (u @ vt)  # world -> luminaire frame (rows: local coordinates)
        table = np.array(entry["intensity"], dtype=np.float64)
        if table.ndim == 0:
            table = np.full((2, 2), float(table))
        nt, nph = table.shape
        theta = np.arccos(np.clip(-local[:, 2], -1.0, 1.0))
        phi = np.mod(np.arctan2(local[:, 1], local[:, 0]), 2.0 * np.pi)
        ft, fp = theta * (nt - 1) / np.pi, phi * (nph - 1) / (2.0 * np.pi)
        it = np.minimum(ft.astype(np.int64), nt - 2)
        ip = np.minimum(fp.astype(np.int64), nph - 2)
        wt, wp = np.clip(ft - it, 0.0, 1.0), np.clip(fp - ip, 0.0, 1.0)
        v0 = (1 - wp) * table[it, ip] + wp * table[it, ip + 1]
        v1 = (1 - wp) * table[it + 1, ip] + wp * table[it + 1, ip + 1]
        return scale * ((1 - wt) * v0 + wt * v1)[:, None] * color[None, :]
    raise ValueError(f"a glow needs a point or line emitter entry, not {kind!r}")


@dataclass
class GlowSource:
    """The glowing faces of one light, placed where its (edited) emitter now is."""

    key: str
    entry: dict[str, Any]
    vertices: np.ndarray
    faces: np.ndarray

    @property
    def is_line(self) -> bool:
        return "p0" in self.entry


def glow_sources(scene: dict[str, Any], glows: dict[str, dict[str, Any]]) -> list[GlowSource]:
    """The glows whose light is still in ``scene``, moved along with their light."""
    from reroom.io.mesh import read_ply

    out = []
    for key, g in glows.items():
        entry = scene.get(g["light"])
        if not isinstance(entry, dict):
            continue  # switched off
        mesh = read_ply(g["filename"])
        shift = _light_centre(entry) - np.asarray(g["origin"], float)
        out.append(
            GlowSource(
                key,
                entry,
                np.asarray(mesh.vertices, float) + shift,
                np.asarray(mesh.faces, np.int64),
            )
        )
    return out


def _sample_faces(
    vertices: np.ndarray, faces: np.ndarray, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """``n`` points spread over the faces by area: points, face normals, face ids, area."""
    tri = vertices[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    total = float(area.sum())
    if total <= 0:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, np.int64), 0.0
    normals = cross / np.maximum(2.0 * area, 1e-30)[:, None]
    # Stratified over the cumulative area, so small faces get their share.
    u = (np.arange(n) + rng.random(n)) / n
    face = np.minimum(np.searchsorted(np.cumsum(area) / total, u), len(faces) - 1)
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    p = (
        (1 - s)[:, None] * tri[face, 0]
        + (s * (1 - r2))[:, None] * tri[face, 1]
        + (s * r2)[:, None] * tri[face, 2]
    )
    return p, normals[face], face, total


def visible_projected_area(
    source: GlowSource,
    eye: np.ndarray,
    occluded: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray],
    *,
    samples: int = 4096,
    reach: float = DEFAULT_REACH,
    seed: int = 0,
) -> float:
    """Visible projected area of a glow towards ``eye`` (m^2; per metre for a line light).

    Near-field exact: the glow's solid angle seen from ``eye`` times the squared distance
    to the emitter (to the element of a line light at each point), so that a glow of
    radiance ``I / A`` sends ``eye`` the irradiance ``I / d^2`` the emitter does.

    ``occluded(origins, directions, tmax)`` says which shadow rays are blocked (by the
    rendered scene and the glowing faces themselves). A face counts on either side (the
    scan's winding of a thin glowing piece is not reliable); a face seen from the back
    whose front also faces the camera is hidden by it, which the shadow rays find.
    For a line light each element is divided by its ``cos(phi)`` and the sum by the
    line's length (see the module docstring).
    """
    rng = np.random.default_rng(seed)
    p, n, _, total = _sample_faces(source.vertices, source.faces, samples, rng)
    if total <= 0:
        return 0.0
    to_eye = np.asarray(eye, float)[None, :] - p
    dist = np.linalg.norm(to_eye, axis=1)
    w = to_eye / np.maximum(dist, 1e-12)[:, None]
    cos = np.abs(np.sum(n * w, axis=1))
    side = np.sign(np.sum(n * w, axis=1))
    start = p + 1e-4 * side[:, None] * n
    hidden = occluded(start, w, np.minimum(dist - 1e-3, reach))
    weight = np.where(hidden, 0.0, cos)
    eye = np.asarray(eye, float)
    if source.is_line:
        p0 = np.asarray(source.entry["p0"], float)
        p1 = np.asarray(source.entry["p1"], float)
        length = float(np.linalg.norm(p1 - p0))
        t = (p1 - p0) / length
        cos_phi = np.sqrt(np.maximum(1.0 - (w @ t) ** 2, 0.0))
        # The emitter's element at the sample's place along the line.
        axis = p0 + np.clip((p - p0) @ t, 0.0, length)[:, None] * t
        centre_dist = np.linalg.norm(eye[None, :] - axis, axis=1)
        weight = weight / np.maximum(cos_phi, 0.05) * (centre_dist / np.maximum(dist, 1e-9)) ** 2
        # Only the side sets the radiance: the line model's J cos(phi) per metre is the
        # light of the tube's length, while an end cap's light grows as sin(phi), at the
        # ends (a 1.2 m, 16 mm tube's cap is 5.7 % of its glowing area 70 degrees off).
        # Counting the caps' area here would spread the side's light over them; instead
        # they glow with the side's radiance (glow_layer gives every face of a source the
        # same value), as a uniformly glowing tube does.
        side = np.abs(n @ t) < SIDE_COS
        if side.any():
            weight = np.where(side, weight, 0.0)
        return float(total * weight.mean() / length)
    centre_dist = float(np.linalg.norm(eye - _light_centre(source.entry)))
    return float(total * (weight * (centre_dist / np.maximum(dist, 1e-9)) ** 2).mean())


def glow_layer(
    mi_scene: Any,
    sources: list[GlowSource],
    c2w: np.ndarray,
    intr: Intrinsics,
    *,
    supersample: int = 4,
    reach: float = DEFAULT_REACH,
    samples: int = 4096,
) -> tuple[np.ndarray, np.ndarray]:
    """Glow radiance ``(H, W, 3)`` and coverage ``(H, W)`` of ``sources`` seen by a camera.

    ``mi_scene`` is the loaded Mitsuba scene (everything rendered; the glowing faces are
    not in it), which hides the glows where it is closer.
    """
    import trimesh

    from reroom.rays import RayCaster
    from reroom.render.camera import subpixel_positions
    from reroom.scan.camera import Frame

    h, w = intr.height, intr.width
    glow = np.zeros((h, w, 3))
    cover = np.zeros((h, w))
    sources = [s for s in sources if len(s.faces)]
    if not sources:
        return glow, cover
    owner = np.concatenate([np.full(len(s.faces), k) for k, s in enumerate(sources)])
    merged = trimesh.util.concatenate(
        [trimesh.Trimesh(s.vertices, s.faces, process=False) for s in sources]
    )
    caster = RayCaster(merged)
    frame = Frame(index=0, c2w=np.asarray(c2w, float), intrinsics=intr, image_path=Path("-"))
    eye = frame.center

    def scene_t(o: np.ndarray, d: np.ndarray) -> np.ndarray:
        return _mitsuba_hit_distance(mi_scene, o, d)

    def occluded(o: np.ndarray, d: np.ndarray, tmax: np.ndarray) -> np.ndarray:
        by_glow = caster.occluded(o, d, tmax=tmax, tmin=1e-4)
        return by_glow | (scene_t(o, d) < tmax)

    # Rays only where the glows can show: the box of their faces' images.
    boxes = [b for s in sources if (b := _image_box(s.vertices, s.faces, c2w, intr))]
    if not boxes:
        return glow, cover
    x0, y0 = min(b[0] for b in boxes), min(b[2] for b in boxes)
    x1, y1 = max(b[1] for b in boxes), max(b[3] for b in boxes)
    area = np.array(
        [visible_projected_area(s, eye, occluded, samples=samples, reach=reach) for s in sources]
    )
    s = int(supersample)
    o, d = frame.pixel_rays(subpixel_positions(x0, x1, y0, y1, s))
    hits = caster.intersect(o, d)
    seen = hits.hit & (hits.t < scene_t(o, d))
    value = np.zeros((len(d), 3))
    for k, src in enumerate(sources):
        sel = seen & (owner[np.maximum(hits.face, 0)] == k)
        if not sel.any() or area[k] <= 0:
            seen &= ~sel
            continue
        value[sel] = light_intensity(src.entry, -d[sel]) / area[k]
    shape = (y1 - y0, x1 - x0, s * s)
    glow[y0:y1, x0:x1] = value.reshape(*shape, 3).mean(axis=2)
    cover[y0:y1, x0:x1] = seen.reshape(shape).mean(axis=2)
    return glow, cover


def _image_box(
    points: np.ndarray, faces: np.ndarray, c2w: np.ndarray, intr: Intrinsics, near: float = 1e-3
) -> tuple[int, int, int, int] | None:
    """Pixel box ``(x0, x1, y0, y1)`` holding the image of the triangles ``faces`` of
    ``points``, or ``None`` when none can show.

    The part of each triangle in front of the camera (depth > ``near``) is bounded by its
    vertices there and the points where its edges cross that depth (which project far
    out, so a triangle reaching behind the camera widens the box to the image's border).
    """
    from reroom.scan.camera import GL_TO_CV

    w2c = np.linalg.inv(np.asarray(c2w, float))
    cam = (points @ w2c[:3, :3].T + w2c[:3, 3]) @ GL_TO_CV.T  # OpenCV: +z forward
    front = cam[:, 2] > near
    if not front.any():
        return None
    keep = [cam[front]]
    if not front.all():
        a = faces.reshape(-1)
        b = np.roll(faces, -1, axis=1).reshape(-1)  # the three edges of every face
        cross = front[a] != front[b]
        pa, pb = cam[a[cross]], cam[b[cross]]
        t = (near - pa[:, 2]) / (pb[:, 2] - pa[:, 2])
        keep.append(pa + t[:, None] * (pb - pa))
    pts = np.concatenate(keep)
    x = intr.fx * pts[:, 0] / pts[:, 2] + intr.cx
    y = intr.fy * pts[:, 1] / pts[:, 2] + intr.cy
    # Two pixels of margin for lens distortion.
    x0, x1 = int(np.floor(max(x.min(), -1e6))) - 2, int(np.ceil(min(x.max(), 1e6))) + 2
    y0, y1 = int(np.floor(max(y.min(), -1e6))) - 2, int(np.ceil(min(y.max(), 1e6))) + 2
    x0, y0 = max(x0, 0), max(y0, 0)
    x1, y1 = min(x1, intr.width), min(y1, intr.height)
    if x0 >= x1 or y0 >= y1:
        return None
    return x0, x1, y0, y1


def _mitsuba_hit_distance(mi_scene: Any, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Closest-hit distance of each ray in a loaded Mitsuba scene (``inf`` on a miss)."""
    from reroom.render import mitsuba

    mi = mitsuba()
    out = np.full(len(o), np.inf)
    step = 1 << 21
    for s in range(0, len(o), step):
        oo, dd = o[s : s + step].astype(np.float32), d[s : s + step].astype(np.float32)
        ray = mi.Ray3f(
            mi.Point3f(oo[:, 0], oo[:, 1], oo[:, 2]), mi.Vector3f(dd[:, 0], dd[:, 1], dd[:, 2])
        )
        t = np.array(mi_scene.ray_intersect_preliminary(ray).t, dtype=np.float64)
        out[s : s + len(t)] = np.where(np.isfinite(t), t, np.inf)
    return out
