"""Albedo textures of the room's planar surfaces (floor, ceiling, walls) from the photos.

The solve gives every observed vertex an albedo (:func:`reroom.invert.solve.per_vertex_albedo`),
so the model's colours have the scan mesh's resolution: 3-8 cm between vertices, which
blurs a wooden floor's planks and their joints into a smooth brown. The photos hold far
more: a 640x360 frame sees a floor 2 m away at about half a centimetre per pixel. This
module turns them into textures on the layout's planes.

* :func:`planar_groups` splits the scan mesh's ``floor``, ``ceiling`` and ``wall`` faces
  (layout labels) into planes of the Manhattan-aligned frame (``layout.json``'s
  ``rotation``): by the aligned axis their normal is closest to, then by their position
  along it (a gap of ``gap`` metres starts a new plane; each wall is its own plane).
  Each plane gets a texture in its two other aligned coordinates, ``texel`` metres
  square.
* :func:`photo_textures` casts every (or every ``stride``-th) pixel ray of every frame
  against the scan mesh, keeps the hits on a grouped face, and turns the pixel into an
  albedo sample: ``pi L / E``, with ``L`` the pixel's radiance (linearised with the HDR
  stage's response and divided by the frame's exposure ``scale``, so in the HDR mesh's
  units; pixels saturated in any channel are skipped) and ``E`` the solved model's
  irradiance at the hit (``E_ind + F . I`` of the receivers, interpolated over the hit
  triangle). That is eq. 5.6 solved per pixel instead of per vertex, so the texture
  and the per-vertex albedo agree where the surface is uniform and the texture keeps
  what lies between the vertices. A texel's albedo is the least-squares answer to
  every sample, each the mean of the texture over its pixel's footprint
  (:mod:`reroom.invert.texture_solve`), on texels half the photos' footprint; or,
  without ``deconvolve`` (or on texels coarser than the pixels), the mean of the
  samples that fall in it, which blurs the pattern by the footprints and the texels.
* Texels no photo saw take the nearest seen texel's albedo within ``fill_radius``
  texels, else the plane's median (the floor under a sofa: nothing tells its pattern).
  The sample count per texel is kept, so a reader knows which texels are measured.

Where the solved lighting is wrong the texture is wrong in the same way as the
per-vertex albedo (both divide the photos by the model's irradiance); what it adds is
resolution. The texel size defaults to the median pixel footprint on the grouped
surfaces (:func:`auto_texel`), clipped to 0.5-5 cm, halved (at least 5 mm) for the
solved texels.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from reroom.errors import ReroomError, ScanError

__all__ = [
    "TEXTURED_LABELS",
    "SurfaceTexture",
    "TexturePlane",
    "auto_texel",
    "face_labels",
    "match_planes",
    "photo_textures",
    "planar_groups",
    "read_texture_planes",
    "read_textures",
    "smoothness_per_plane",
    "write_textures",
]

#: Layout labels that get textures, by name and id (``reroom.layout.labels.LAYOUT_LABELS``).
TEXTURED_LABELS = {"wall": 0, "floor": 1, "ceiling": 2}
_OTHER = 255
#: The two in-plane aligned axes of a plane whose normal is along aligned axis ``a``.
_PLANE_AXES = {0: (1, 2), 1: (0, 2), 2: (0, 1)}


@dataclass(frozen=True)
class TexturePlane:
    """Where a texture lies: a plane of the room and its texel grid (no image).

    The renderer needs only this to map faces onto a texture it passes by file; the
    fields mean what they mean in :class:`SurfaceTexture`, ``height`` x ``width`` texels.
    """

    label: str
    axis: int
    offset: float
    origin: tuple[float, float]
    texel: float
    height: int
    width: int
    rotation: np.ndarray
    name: str = ""

    @property
    def uv_axes(self) -> tuple[int, int]:
        return _PLANE_AXES[self.axis]

    @property
    def shape(self) -> tuple[int, int]:
        return self.height, self.width

    def texture_coords(self, points: np.ndarray) -> np.ndarray:
        """``(N, 2)`` coordinates in ``[0, 1]`` of mesh-frame points on the texture:
        ``u`` along columns, ``v`` along rows (row 0 at ``v = 0``)."""
        a = np.asarray(points, float) @ np.asarray(self.rotation, float).T
        iu, iv = self.uv_axes
        u = (a[:, iu] - self.origin[0]) / (self.width * self.texel)
        v = (a[:, iv] - self.origin[1]) / (self.height * self.texel)
        return np.stack([u, v], axis=1)


@dataclass
class SurfaceTexture:
    """The albedo texture of one plane of the room.

    Attributes
    ----------
    label:
        ``"floor"``, ``"ceiling"`` or ``"wall"``.
    axis:
        The aligned axis (0 x, 1 y, 2 z) the plane's normal is along.
    offset:
        The plane's aligned coordinate along ``axis`` (metres).
    origin:
        Aligned coordinates ``(u0, v0)`` of the texture's corner, along the plane's
        axes :attr:`uv_axes` (``u`` indexes columns, ``v`` rows).
    texel:
        Texel size (metres).
    albedo:
        ``(H, W, 3)`` albedo, every texel filled: the photos' albedo with its local mean
        (a Gaussian of ``calibrate_sigma``) set to the per-vertex albedo's.
    detail:
        ``(H, W, 3)`` the photos' albedo over its local mean (a Gaussian of
        ``detail_sigma``): the pattern alone, 1 where unseen. The empty room multiplies
        it with the plane's mean albedo.
    count:
        ``(H, W)`` photo samples per texel (0 where filled); with the solved texels
        (``photo_textures``' ``deconvolve``), the samples' footprint weight on it.
    rotation:
        ``(3, 3)`` rotation from the mesh's frame to the aligned frame.
    name:
        File stem (``floor_0``, ``wall_2``).
    """

    label: str
    axis: int
    offset: float
    origin: tuple[float, float]
    texel: float
    albedo: np.ndarray
    detail: np.ndarray
    count: np.ndarray
    rotation: np.ndarray
    name: str = ""

    @property
    def plane(self) -> TexturePlane:
        """The texture's plane and texel grid."""
        h, w = int(self.albedo.shape[0]), int(self.albedo.shape[1])
        return TexturePlane(
            self.label, self.axis, self.offset, self.origin, self.texel, h, w,
            self.rotation, self.name,
        )  # fmt: skip

    @property
    def uv_axes(self) -> tuple[int, int]:
        return _PLANE_AXES[self.axis]

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.albedo.shape[0]), int(self.albedo.shape[1])

    @property
    def observed_fraction(self) -> float:
        """Share of the texels (of the plane's bounding rectangle) a photo saw."""
        return float(np.mean(self.count > 0))

    @property
    def mean_albedo(self) -> np.ndarray:
        """``(3,)`` mean albedo over the texels a photo saw (all texels if none)."""
        seen = self.count > 0
        return np.asarray(
            self.albedo[seen].mean(axis=0) if seen.any() else self.albedo.mean(axis=(0, 1)),
            float,
        )

    def texture_coords(self, points: np.ndarray) -> np.ndarray:
        """See :meth:`TexturePlane.texture_coords`."""
        return self.plane.texture_coords(points)


def face_labels(labels: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Label of each face: the label of at least two of its vertices, else 255."""
    fl = np.asarray(labels)[np.asarray(faces)]
    out = np.full(len(fl), _OTHER, np.int64)
    for a, b in ((0, 1), (0, 2), (1, 2)):
        agree = fl[:, a] == fl[:, b]
        out = np.where(agree & (out == _OTHER), fl[:, a], out)
    return out


def _face_geometry(
    vertices: np.ndarray, faces: np.ndarray, rotation: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Aligned unit normals, aligned centroids, areas and aligned corners of the faces."""
    tri = np.asarray(vertices, float)[np.asarray(faces)] @ np.asarray(rotation, float).T
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(cross, axis=1)
    normals = np.divide(cross, length[:, None], out=np.zeros_like(cross), where=length[:, None] > 0)
    return normals, tri.mean(axis=1), 0.5 * length, tri


def planar_groups(
    vertices: np.ndarray,
    faces: np.ndarray,
    labels: np.ndarray,
    rotation: np.ndarray,
    *,
    min_cos: float = 0.95,
    gap: float = 0.15,
    max_distance: float = 0.1,
    min_area: float = 0.25,
) -> tuple[list[dict[str, Any]], np.ndarray]:
    """The planes of the scan mesh's floor, ceiling and wall faces.

    Parameters
    ----------
    vertices, faces:
        The scan mesh.
    labels:
        Per-vertex layout label (``layout_labels.ply``).
    rotation:
        Mesh-to-aligned rotation (``layout.json``).
    min_cos:
        A face joins a plane of axis ``a`` when ``|n_a| >= min_cos``.
    gap:
        Along the axis, faces more than ``gap`` metres from the previous one start a
        new plane.
    max_distance:
        Faces farther than this from their plane's (area-weighted median) position are
        left out of it (a shelf labelled wall).
    min_area:
        Planes with less face area (m^2) are dropped.

    Returns
    -------
    planes, face_plane
        One dict per plane (``label``, ``axis``, ``offset``, ``area``, ``bounds``: the
        aligned ``(u_min, v_min, u_max, v_max)`` of its faces), and each face's plane
        index (-1: none).
    """
    flab = face_labels(labels, faces)
    normals, centres, areas, tri = _face_geometry(vertices, faces, rotation)
    face_plane = np.full(len(flab), -1, np.int64)
    planes: list[dict[str, Any]] = []
    for label, lid in TEXTURED_LABELS.items():
        axes = (2,) if label in ("floor", "ceiling") else (0, 1)
        for axis in axes:
            sel = np.flatnonzero((flab == lid) & (np.abs(normals[:, axis]) >= min_cos))
            if len(sel) == 0:
                continue
            pos = centres[sel, axis]
            order = np.argsort(pos)
            breaks = np.flatnonzero(np.diff(pos[order]) > gap) + 1
            for run in np.split(order, breaks):
                members = sel[run]
                w = areas[members]
                if w.sum() < min_area:
                    continue
                cum = np.cumsum(w[np.argsort(pos[run])])
                median = float(np.sort(pos[run])[np.searchsorted(cum, 0.5 * cum[-1])])
                members = members[np.abs(centres[members, axis] - median) <= max_distance]
                if areas[members].sum() < min_area:
                    continue
                iu, iv = _PLANE_AXES[axis]
                pts = tri[members].reshape(-1, 3)
                face_plane[members] = len(planes)
                planes.append(
                    {
                        "label": label,
                        "axis": axis,
                        "offset": median,
                        "area": float(areas[members].sum()),
                        "bounds": [
                            float(pts[:, iu].min()),
                            float(pts[:, iv].min()),
                            float(pts[:, iu].max()),
                            float(pts[:, iv].max()),
                        ],
                    }
                )
    return planes, face_plane


def match_planes(
    textures: list[TexturePlane] | list[SurfaceTexture],
    vertices: np.ndarray,
    faces: np.ndarray,
    face_label_names: list[str] | np.ndarray,
    *,
    min_cos: float = 0.95,
    max_distance: float = 0.15,
) -> np.ndarray:
    """Which texture each face takes: same label, normal along the texture's axis and
    within ``max_distance`` of its plane (the nearest such); -1 for none.

    Used for the scan mesh's faces and for the empty room's shell, whose walls stand at
    the layout's planes rather than exactly on the scanned ones.
    """
    out = np.full(len(faces), -1, np.int64)
    if not textures or len(faces) == 0:
        return out
    rotation = textures[0].rotation
    normals, centres, _, _ = _face_geometry(vertices, faces, rotation)
    names = np.asarray(face_label_names)
    best = np.full(len(faces), np.inf)
    for k, tex in enumerate(textures):
        dist = np.abs(centres[:, tex.axis] - tex.offset)
        ok = (names == tex.label) & (np.abs(normals[:, tex.axis]) >= min_cos)
        ok &= (dist <= max_distance) & (dist < best)
        out[ok] = k
        best[ok] = dist[ok]
    return out


def _sample_grid(width: int, height: int, max_rays: int) -> tuple[np.ndarray, np.ndarray]:
    from reroom.invert.photos import pixel_grid

    rows, cols = pixel_grid(width, height, max_rays)
    jj, ii = np.meshgrid(cols, rows)
    return ii.ravel(), jj.ravel()


def auto_texel(
    scan, caster, face_plane: np.ndarray, *, grid: int = 24, lo: float = 0.005, hi: float = 0.05
) -> float:
    """The median footprint (metres) of a pixel on the grouped faces, over all frames.

    ``grid x grid`` rays per frame; the footprint of a pixel at distance ``t`` seen at
    ``cos`` to the surface is ``t / (f cos)``, its longer side (``f`` the focal length in
    pixels). Rounded to a millimetre and clipped to ``[lo, hi]``.
    """
    feet = []
    for frame in scan.frames:
        k = frame.intrinsics
        u = (np.arange(grid) + 0.5) * k.width / grid
        v = (np.arange(grid) + 0.5) * k.height / grid
        uu, vv = np.meshgrid(u, v)
        o, d = frame.pixel_rays(np.stack([uu.ravel(), vv.ravel()], axis=1))
        hits = caster.intersect(o, d, tmin=caster.eps)
        ok = hits.hit & (face_plane[np.clip(hits.face, 0, None)] >= 0)
        if not ok.any():
            continue
        cos = np.abs(np.einsum("ij,ij->i", hits.normals[ok], d[ok]))
        f = min(float(k.fx), float(k.fy))
        feet.append(hits.t[ok] / (f * np.maximum(cos, 0.2)))
    if not feet:
        return hi
    return float(np.clip(np.round(np.median(np.concatenate(feet)), 3), lo, hi))


def _smooth(values: np.ndarray, weight: np.ndarray, sigma: float) -> np.ndarray:
    """Normalised convolution: the ``weight``-weighted Gaussian mean of ``values``
    (``(H, W, 3)``) around each texel (NaN where no weight is near)."""
    from scipy import ndimage

    # float32 and 3 sigma: a local mean needs no more, and it halves the cost on the
    # millions of texels of a 640x360 scan's planes.
    weight = weight.astype(np.float32)
    w = ndimage.gaussian_filter(weight, sigma, mode="nearest", truncate=3.0)
    out = np.stack(
        [
            ndimage.gaussian_filter(
                (values[..., c] * weight).astype(np.float32), sigma, mode="nearest", truncate=3.0
            )
            for c in range(values.shape[-1])
        ],
        axis=-1,
    ).astype(np.float64)
    w = w.astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(w[..., None] > 1e-6, out / w[..., None], np.nan)


def _fill(values: np.ndarray, seen: np.ndarray, radius: int) -> np.ndarray:
    """Unseen texels: the nearest seen texel's value within ``radius``, else the median
    of the seen ones."""
    from scipy import ndimage

    out = values.copy()
    if seen.all():
        return out
    dist, (ri, ci) = ndimage.distance_transform_edt(~seen, return_indices=True)
    near = ~seen & (dist <= radius)
    out[near] = out[ri[near], ci[near]]
    far = ~seen & ~near
    out[far] = np.median(out[seen], axis=0)
    return out


def _continue_pattern(detail: np.ndarray, seen: np.ndarray, ratio: float = 1.5) -> np.ndarray:
    """Unseen texels of a striped pattern (a plank floor) continue the stripes.

    Where the pattern changes ``ratio`` times more across one texture axis than along
    the other (mean absolute step between seen neighbours), each unseen texel takes the
    nearest seen texel *along* the stripes, in its row (or column); otherwise, and where
    a row has no seen texel, it stays 1 (the plane's mean). Under a sofa the planks then
    run on instead of leaving a flat patch.
    """
    lum = detail.mean(axis=-1)
    pair_u = seen[:, 1:] & seen[:, :-1]
    pair_v = seen[1:] & seen[:-1]
    if pair_u.sum() < 100 or pair_v.sum() < 100 or seen.all() or not seen.any():
        return detail
    step_u = float(np.abs(np.diff(lum, axis=1))[pair_u].mean())  # along rows
    step_v = float(np.abs(np.diff(lum, axis=0))[pair_v].mean())  # along columns
    if max(step_u, step_v) < ratio * min(step_u, step_v):
        return detail
    along_rows = step_u < step_v  # stripes run along the rows (u)
    d = detail if along_rows else detail.transpose(1, 0, 2)
    m = seen if along_rows else seen.T
    h, w = m.shape
    cols = np.arange(w)
    # index of the nearest seen texel to the left / right in each row
    left = np.maximum.accumulate(np.where(m, cols[None, :], -1), axis=1)
    right = np.minimum.accumulate(np.where(m, cols[None, :], w)[:, ::-1], axis=1)[:, ::-1]
    use_left = (left >= 0) & ((right >= w) | (cols[None, :] - left <= right - cols[None, :]))
    src = np.where(use_left, left, right)
    fill = ~m & (src >= 0) & (src < w)
    rows = np.broadcast_to(np.arange(h)[:, None], (h, w))
    out = d.copy()
    out[fill] = d[rows[fill], src[fill]]
    return out if along_rows else out.transpose(1, 0, 2)


def _finish(
    photo_sum: np.ndarray,
    vertex_sum: np.ndarray,
    count: np.ndarray,
    texel: float,
    calibrate_sigma: float,
    detail_sigma: float,
    fill_radius: int,
    solved: np.ndarray | None = None,
    coverage: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray] | None:
    """``(albedo, detail)`` of one plane from its per-texel sums; None if nothing seen.

    The photos' albedo is ``pi L / E`` per pixel, unbiased but for the pixels it had to
    skip (saturated ones: the brightest); the per-vertex albedo comes from the HDR
    mesh, which recovers those from the other frames' exposures. So the texture takes
    its local mean from the per-vertex albedo (where a texel has one) and only the
    pattern within ``calibrate_sigma`` metres from the photos. The photos' albedo is
    the samples' mean per texel, or ``solved`` (:func:`_solve_planes`) where the
    footprints' ``coverage`` reaches :data:`MIN_COVERAGE`.
    """
    if solved is None:
        seen = count > 0
    else:
        seen = np.asarray(coverage) >= MIN_COVERAGE
    if not seen.any():
        return None
    photo = np.zeros(photo_sum.shape)
    if solved is None:
        photo[seen] = photo_sum[seen] / count[seen][:, None]
    else:
        # A deconvolution rings a little beside sharp steps; albedo is not negative.
        photo[seen] = np.maximum(solved[seen], 0.0)
    has_vertex = (count > 0) & np.isfinite(vertex_sum).all(axis=-1)
    vertex = np.where(has_vertex[..., None], vertex_sum / np.maximum(count, 1)[..., None], 0.0)
    w = seen.astype(np.float64)
    sig = calibrate_sigma / texel
    photo_mean = _smooth(photo, w, sig)
    vertex_mean = _smooth(vertex, has_vertex.astype(np.float64), sig)
    with np.errstate(invalid="ignore", divide="ignore"):
        gain = np.where(photo_mean > 0, vertex_mean / photo_mean, np.nan)
    albedo = np.where(np.isfinite(gain), photo * gain, photo)
    local = _smooth(photo, w, detail_sigma / texel)
    with np.errstate(invalid="ignore", divide="ignore"):
        detail = np.where(local > 0, photo / local, 1.0)
    detail = np.clip(np.where(seen[..., None], detail, 1.0), 0.25, 2.0)
    detail = _continue_pattern(detail, seen)
    return _fill(albedo, seen, fill_radius), detail


#: A texel counts as seen when the samples' footprints put at least this many samples'
#: worth of weight on it (a footprint's weights sum to 1).
MIN_COVERAGE = 0.25


def smoothness_per_plane(
    smooth: float | Mapping[str, float], plane_labels: list[str]
) -> np.ndarray:
    """The texture solve's smoothness of each plane: ``smooth`` itself, or its value for
    the plane's label (1 for a label it does not name).

    Raises
    ------
    ValueError
        A smoothness that is negative or not finite, or a label that no plane can have.
    """
    if isinstance(smooth, Mapping):
        unknown = sorted(set(smooth) - set(TEXTURED_LABELS))
        if unknown:
            raise ValueError(
                f"texture smoothness for unknown label(s) {unknown}; "
                f"textured labels are {sorted(TEXTURED_LABELS)}"
            )
        values = np.array([float(smooth.get(lab, 1.0)) for lab in plane_labels])
    else:
        values = np.full(len(plane_labels), float(smooth))
    if not np.all(np.isfinite(values) & (values >= 0)):
        raise ValueError(f"texture smoothness must be finite and >= 0, got {smooth!r}")
    return values


def _solve_planes(
    footprints: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]],
    shapes: list[tuple[int, int]],
    stats: dict[str, Any],
    smooth: np.ndarray,
    iterations: int,
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Every plane's texels solved from the samples' footprints
    (:func:`reroom.invert.texture_solve.solve_texels`), started from their back
    projection; ``(None, None)`` where the median footprint is under a texel (an
    explicit ``texel`` coarser than the photos' pixels), with the reason in ``stats``."""
    import time

    from reroom.invert.texture_solve import FootprintSamples, median_footprint, solve_texels

    t0 = time.perf_counter()
    plane = np.concatenate([f[0] for f in footprints])
    centre = np.concatenate([f[1] for f in footprints])
    # Samples in texel order (plane, row, column): the solve's gathers and scatters
    # then walk the texels in order instead of frame after frame across the planes.
    order = np.lexsort((centre[:, 0].astype(np.int32), centre[:, 1].astype(np.int32), plane))
    samples = FootprintSamples(
        plane=plane[order],
        centre=centre[order],
        jacobian=np.concatenate([f[2] for f in footprints])[order],
        value=np.concatenate([f[3] for f in footprints])[order],
    )
    del plane, centre, order
    footprint = median_footprint(samples.jacobian)
    if footprint < 1.0:
        # Texels coarser than the pixels: each pixel is about a point on its texel, the
        # footprints blur nothing to undo, and a bilinear fit through point samples of
        # a sharp step rings. The samples' mean per texel is the texture.
        stats["deconvolution"] = {"samples": len(samples), "skipped": round(footprint, 3)}
        return None, None
    solved, coverage, st = solve_texels(samples, shapes, smooth=smooth, iterations=iterations)
    stats["deconvolution"] = {
        "samples": len(samples),
        **st,
        "seconds": round(time.perf_counter() - t0, 2),
    }
    return solved, coverage


def photo_textures(
    scan_dir: str | Path,
    mesh,
    labels: np.ndarray,
    rotation: np.ndarray,
    irradiance: np.ndarray,
    vertex_albedo: np.ndarray | None = None,
    *,
    texel: float | None = None,
    max_rays_per_frame: int = 30_000,
    min_cos: float = 0.2,
    saturation_level: int = 255,
    fill_radius: int = 3,
    calibrate_sigma: float = 0.1,
    detail_sigma: float = 0.3,
    max_plane_distance: float = 0.06,
    footprint: float = 1.0,
    max_texels: int = 16_000_000,
    sharp_irradiance: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
    sharp_at_vertices: np.ndarray | None = None,
    deconvolve: bool = True,
    texels_per_footprint: float = 0.5,
    deconvolve_smooth: float | Mapping[str, float] = 1.0,
    deconvolve_iterations: int = 15,
    caster=None,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[list[SurfaceTexture], dict[str, Any]]:
    """Albedo textures of the scan's floor, ceiling and wall planes from its photos.

    Parameters
    ----------
    scan_dir:
        The scan (``transforms.json``, images, ``hdr/exposures.json``).
    mesh:
        The scan's (HDR) mesh, ``trimesh.Trimesh``.
    labels:
        Per-vertex layout label.
    rotation:
        Mesh-to-aligned rotation (``layout.json``).
    irradiance:
        ``(V, 3)`` the solved model's irradiance per vertex (``E_ind + F . I``); NaN
        where unknown (a sample on a face with such a vertex is skipped).
    vertex_albedo:
        ``(V, 3)`` the per-vertex albedo (NaN or negative where unknown), clipped to
        ``[0, 0.95]`` as the renderer does; the texture's local mean follows it (see
        :func:`_finish`). None: the photos' own.
    texel:
        Texel size (metres); None: :func:`auto_texel` (times ``texels_per_footprint``
        with ``deconvolve``).
    max_rays_per_frame:
        Pixels are taken on a regular grid with at most this many per frame.
    min_cos:
        Pixels seeing their surface more grazing than this are skipped (a grazing pixel
        smears across many texels).
    saturation_level:
        An 8-bit code at or above it in any channel: the pixel is skipped.
    fill_radius:
        Unseen texels within this many texels of a seen one take its albedo.
    calibrate_sigma, detail_sigma:
        Metres: the Gaussians of the local means of ``albedo`` and ``detail``.
    max_plane_distance:
        Hits farther than this from their plane are skipped (a picture frame or a
        board leaning on a wall, labelled wall).
    footprint:
        Pixels: a pixel is used only if the rays through the four points this far from
        its centre (diagonally) hit its plane as well. A pixel across a silhouette or a
        crease mixes two surfaces (the sensor integrates over its area, and the lens and
        demosaicing blur a little more): without this test a chair leaves a dark halo
        on the wall behind it and a table a light one on the floor. 0 turns it off.
    max_texels:
        The texel size grows until all planes together have at most this many.
    sharp_irradiance, sharp_at_vertices:
        The part of ``irradiance`` that changes faster than the mesh's vertices follow
        (a point light's direct light at the edge of its beam or of a shadow), as
        ``sharp_irradiance(points, normals) -> (N, 3)`` and its ``(V, 3)`` values at the
        vertices. Each sample's irradiance is then that function at the sample's hit
        (the face's normal turned to the camera) plus the rest, ``irradiance -
        sharp_at_vertices``, interpolated over the hit triangle; at a vertex it is
        ``irradiance`` as before. Without them the whole irradiance is interpolated, and
        a beam's edge that falls between vertices is drawn into the albedo (a ghost of
        the light that stays when the light is moved or switched off).
    deconvolve:
        Solve each plane's texels as the least-squares answer to every sample, each the
        mean of the texture over its pixel's footprint (:mod:`reroom.invert.texture_solve`),
        instead of averaging the samples that fall in each texel (which blurs the
        pattern by the footprints and the texels). A texel is then seen where the
        footprints cover it (:data:`MIN_COVERAGE`), and ``count`` is that coverage.
    texels_per_footprint:
        With ``deconvolve`` and no ``texel``: the texel is this fraction of the
        median footprint (at least 5 mm).
    deconvolve_smooth, deconvolve_iterations:
        How far the solve's penalty on neighbouring texels' differences spreads a
        texel, in the photos' median footprints (one number for every plane, or one
        per label, ``{"wall": 2.0, ...}``, a label not named taking 1), and its most
        conjugate-gradient steps.
    caster:
        A :class:`reroom.rays.RayCaster` on ``mesh`` (built if not given).
    progress:
        ``progress(done, total)`` over the frames.

    Returns
    -------
    textures, stats
        One :class:`SurfaceTexture` per plane some photo saw, and figures (``texel``,
        frames used and skipped, samples, saturated and grazing pixels, per plane the
        observed fraction, ``notes``).
    """
    from reroom.hdr.linearize import linearize
    from reroom.invert.photos import frame_scale, read_frame_scales, scan_response
    from reroom.rays import RayCaster
    from reroom.scan import load_scan

    scan_dir = Path(scan_dir)
    notes: list[str] = []
    rotation = np.asarray(rotation, float)
    vertices = np.asarray(mesh.vertices, float)
    faces = np.asarray(mesh.faces, np.int64)
    irradiance = np.asarray(irradiance, float)
    if irradiance.shape != (len(vertices), 3):
        raise ValueError(f"irradiance has shape {irradiance.shape}, expected ({len(vertices)}, 3)")
    if (sharp_irradiance is None) != (sharp_at_vertices is None):
        raise ValueError("sharp_irradiance and sharp_at_vertices go together")
    if sharp_at_vertices is not None:
        sharp_at_vertices = np.asarray(sharp_at_vertices, float)
        if sharp_at_vertices.shape != irradiance.shape:
            raise ValueError(
                f"sharp_at_vertices has shape {sharp_at_vertices.shape}, expected "
                f"{irradiance.shape}"
            )
        # The smooth rest, interpolated over a triangle; the sharp part is added per sample.
        irradiance = irradiance - sharp_at_vertices
    planes, face_plane = planar_groups(
        vertices, faces, labels, rotation, max_distance=max_plane_distance
    )
    if vertex_albedo is not None:
        vertex_albedo = np.asarray(vertex_albedo, float)
        if vertex_albedo.shape != (len(vertices), 3):
            raise ValueError(
                f"vertex_albedo has shape {vertex_albedo.shape}, expected ({len(vertices)}, 3)"
            )
        vertex_albedo = np.where(
            np.all(vertex_albedo >= 0, axis=1, keepdims=True),
            np.clip(vertex_albedo, 0, 0.95),
            np.nan,
        )
    stats: dict[str, Any] = {
        "frames": 0,
        "frames_used": 0,
        "frames_no_exposure": 0,
        "frames_unreadable": [],
        "samples": 0,
        "saturated": 0,
        "grazing": 0,
        "no_irradiance": 0,
        "off_plane": 0,
        "edge": 0,
        "planes": [],
        "notes": notes,
    }
    if not planes:
        notes.append("textures: no floor, ceiling or wall plane in the labels")
        return [], stats
    smooth_of_plane = smoothness_per_plane(deconvolve_smooth, [p["label"] for p in planes])
    scan = load_scan(scan_dir, check_images=False)
    doc, scales = read_frame_scales(scan_dir)
    lut = scan_response(doc, scan.meta, notes.append)
    caster = caster if caster is not None else RayCaster(mesh)
    if texel is None:
        # Solved texels can be finer than the photos' pixels (a footprint spans several).
        texel = auto_texel(scan, caster, face_plane)
        if deconvolve:
            texel = max(round(texel * texels_per_footprint, 4), 0.005)
    texel = float(texel)
    if not texel > 0:
        raise ValueError(f"texel must be positive, got {texel}")

    def sizes(t: float) -> list[tuple[int, int]]:
        return [
            (
                int(np.ceil((p["bounds"][3] - p["bounds"][1]) / t)) + 2,
                int(np.ceil((p["bounds"][2] - p["bounds"][0]) / t)) + 2,
            )
            for p in planes
        ]

    while sum(h * w for h, w in sizes(texel)) > max_texels:
        texel *= 1.25
    shapes = sizes(texel)
    origins = [(p["bounds"][0] - texel, p["bounds"][1] - texel) for p in planes]
    starts = np.concatenate([[0], np.cumsum([h * w for h, w in shapes])]).astype(np.int64)
    n_tex = int(starts[-1])
    total = np.zeros((n_tex, 3))
    vertex_total = np.zeros((n_tex, 3))
    count = np.zeros(n_tex, np.int64)
    stats["frames"] = len(scan.frames)
    stats["texel"] = texel

    # Samples are binned a few million at a time: a bincount over every texel per frame
    # would cost more than the rays (300 frames x 4 M texels).
    pending: list[tuple[np.ndarray, np.ndarray, np.ndarray, Any]] = []
    # Every sample's plane, texel position, footprint and albedo, for the solve.
    footprints: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
    n_pending = 0
    flush_at = 4_000_000

    def flush() -> None:
        if not pending:
            return
        flat = np.concatenate([x[0] for x in pending])
        alb = np.concatenate([x[1] for x in pending])
        va = np.concatenate([x[2] for x in pending])
        footprints.extend(x[3] for x in pending if x[3] is not None)
        pending.clear()
        count[:] += np.bincount(flat, minlength=n_tex)
        for c in range(3):
            total[:, c] += np.bincount(flat, weights=alb[:, c], minlength=n_tex)
            # NaN where any sample of the texel lacked a per-vertex albedo
            vertex_total[:, c] += np.bincount(flat, weights=va[:, c], minlength=n_tex)

    plane_offset = np.array([p["offset"] for p in planes])
    plane_axis = np.array([p["axis"] for p in planes], np.int64)
    plane_iu = np.array([_PLANE_AXES[a][0] for a in plane_axis], np.int64)
    plane_iv = np.array([_PLANE_AXES[a][1] for a in plane_axis], np.int64)
    plane_w = np.array([w for _, w in shapes], np.int64)
    plane_h = np.array([h for h, _ in shapes], np.int64)
    plane_u0 = np.array([o[0] for o in origins])
    plane_v0 = np.array([o[1] for o in origins])

    def _plane_seen(h) -> np.ndarray:
        """The plane each ray of ``h`` hit: -1 for none, or a hit farther than
        ``max_plane_distance`` from its plane (a board leaning on the wall)."""
        pl = np.where(h.hit, face_plane[np.where(h.hit, h.face, 0)], -1)
        on = np.flatnonzero(pl >= 0)
        a = h.points[on] @ rotation.T
        k = pl[on]
        far = np.abs(a[np.arange(len(on)), plane_axis[k]] - plane_offset[k]) > max_plane_distance
        pl[on[far]] = -1
        return pl

    def _inside_plane(frame, ii: np.ndarray, jj: np.ndarray, plane: np.ndarray) -> np.ndarray:
        """Whether the pixels' footprints (corners ``footprint`` px away) lie on ``plane``."""
        ok = np.ones(len(ii), bool)
        for dy, dx in ((-1, -1), (-1, 1), (1, -1), (1, 1)):
            uv = np.stack([jj + 0.5 + dx * footprint, ii + 0.5 + dy * footprint], axis=1)
            o, d = frame.pixel_rays(uv)
            ok &= _plane_seen(caster.intersect(o, d, tmin=caster.eps)) == plane
        return ok

    def _uniform_neighbourhood(plane_of: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """Grid pixels whose 8 grid neighbours hit the same plane as they do.

        Those need no corner rays: a surface that covered part of such a pixel's
        footprint yet none of the 9 grid points would have to be narrower than the grid
        step and fall between them. Pixels on the grid's border are not uniform.
        """
        grid = plane_of.reshape(shape)
        out = np.zeros(shape, bool)
        core = grid[1:-1, 1:-1]
        same = core >= 0
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                if dy or dx:
                    h, w = shape
                    same &= grid[1 + dy : h - 1 + dy, 1 + dx : w - 1 + dx] == core
        out[1:-1, 1:-1] = same
        return out.reshape(-1)

    def _footprints(frame, ii: np.ndarray, jj: np.ndarray, a: np.ndarray, plane: np.ndarray):
        """Samples' texel-centre positions and footprints (texels per pixel along the
        image's x and y) on their planes; float32, with each sample's albedo added by
        the caller."""
        k = plane
        iu, iv, ax = plane_iu[k], plane_iv[k], plane_axis[k]
        n = np.arange(len(k))
        centre = np.stack(
            [
                (a[n, iu] - plane_u0[k]) / texel - 0.5,
                (a[n, iv] - plane_v0[k]) / texel - 0.5,
            ],
            axis=1,
        )
        jac = np.empty((len(k), 2, 2))
        for col, (dx, dy) in enumerate(((1.0, 0.0), (0.0, 1.0))):
            o, d = frame.pixel_rays(np.stack([jj + 0.5 + dx, ii + 0.5 + dy], axis=1))
            oa, da = o @ rotation.T, d @ rotation.T
            # The neighbouring pixel's ray met with the sample's own plane (through its
            # hit, along the plane's axis): grazing pixels were dropped, so it meets it.
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (a[n, ax] - oa[n, ax]) / da[n, ax]
            q = oa + t[:, None] * da
            jac[:, 0, col] = (q[n, iu] - a[n, iu]) / texel
            jac[:, 1, col] = (q[n, iv] - a[n, iv]) / texel
        ok = np.isfinite(jac).all(axis=(1, 2))
        jac[~ok] = 0.0  # a point sample where the neighbour misses the plane
        return k.astype(np.int32), centre.astype(np.float32), jac.astype(np.float32)

    def frame_samples(j: int):
        """One frame's ``(flat texel, albedo, vertex albedo)`` and counts, or a skip reason."""
        frame = scan.frames[j]
        scale = frame_scale(scales, j)
        if scale is None:
            return "no_exposure"
        k = frame.intrinsics
        ii, jj = _sample_grid(k.width, k.height, max_rays_per_frame)
        grid_shape = (len(np.unique(ii)), len(np.unique(jj)))
        o, d = frame.pixel_rays(np.stack([jj + 0.5, ii + 0.5], axis=1))
        hits = caster.intersect(o, d, tmin=caster.eps)
        idx = np.flatnonzero(hits.hit)
        idx = idx[face_plane[hits.face[idx]] >= 0]
        if len(idx) == 0:
            return None
        try:
            img = frame.load_image()
        except (ReroomError, OSError, ValueError) as exc:
            return ("unreadable", str(frame.image_path), str(exc))
        f = hits.face[idx]
        cos = np.abs(np.einsum("ij,ij->i", caster.face_normals[f], d[idx]))
        grazing = cos < min_cos
        codes = img[ii[idx], jj[idx]]
        sat = (codes >= saturation_level).any(axis=1)
        bary = hits.barycentric[idx]
        e = np.einsum("nk,nkc->nc", bary, irradiance[faces[f]])
        if sharp_irradiance is not None:
            fn = caster.face_normals[f]
            n_cam = np.where((np.einsum("ij,ij->i", fn, d[idx]) > 0)[:, None], -fn, fn)
            e = e + sharp_irradiance(hits.points[idx], n_cam)
        no_e = ~np.all(np.isfinite(e) & (e > 0), axis=1)
        plane = face_plane[f]
        a = hits.points[idx] @ rotation.T
        rows = np.arange(len(idx))
        plane_of = _plane_seen(hits)  # per grid pixel: -1 where no plane, or off its plane
        off = plane_of[idx] < 0
        keep = ~grazing & ~sat & ~no_e & ~off
        counts = {
            "grazing": int(grazing.sum()),
            "saturated": int((sat & ~grazing).sum()),
            "no_irradiance": int((no_e & ~grazing & ~sat).sum()),
            "off_plane": int((off & ~no_e & ~grazing & ~sat).sum()),
        }
        if footprint > 0 and keep.any():
            # Pixels amid a uniform 3 x 3 block of the grid keep their sample, the others
            # are tested with rays through their footprint's corners.
            uniform = _uniform_neighbourhood(plane_of, grid_shape)[idx]
            test = np.flatnonzero(keep & ~uniform)
            if len(test):
                inner = _inside_plane(frame, ii[idx][test], jj[idx][test], plane[test])
                counts["edge"] = int((~inner).sum())
                keep[test[~inner]] = False
        if not keep.any():
            return counts, None
        f, e, codes, plane, a, bary = (
            f[keep],
            e[keep],
            codes[keep],
            plane[keep],
            a[keep],
            bary[keep],
        )
        rows = rows[: len(f)]
        radiance = linearize(codes, lut).astype(np.float64) / scale
        albedo = np.pi * radiance / e
        foot = None
        if deconvolve:
            foot = (
                *_footprints(frame, ii[idx][keep], jj[idx][keep], a, plane),
                albedo.astype(np.float32),
            )
        if vertex_albedo is not None:
            va = np.einsum("nk,nkc->nc", bary, vertex_albedo[faces[f]])
        else:
            va = albedo
        w = plane_w[plane]
        col = np.clip(
            ((a[rows, plane_iu[plane]] - plane_u0[plane]) / texel).astype(np.int64), 0, w - 1
        )
        row = np.clip(
            ((a[rows, plane_iv[plane]] - plane_v0[plane]) / texel).astype(np.int64),
            0,
            plane_h[plane] - 1,
        )
        return counts, (starts[plane] + row * w + col, albedo, va, foot)

    from concurrent.futures import ThreadPoolExecutor

    # Two frames at a time: Embree, PNG decoding and most numpy calls release the GIL.
    with ThreadPoolExecutor(max_workers=2) as pool:
        for j, out in enumerate(pool.map(frame_samples, range(len(scan.frames)))):
            if progress is not None:
                progress(j, len(scan.frames))
            if out is None:
                continue
            if out == "no_exposure":
                stats["frames_no_exposure"] += 1
                continue
            if out[0] == "unreadable":
                msg = f"textures: skipped frame {out[1]}: cannot read it ({out[2]})"
                warnings.warn(msg, stacklevel=2)
                stats["frames_unreadable"].append(out[1])
                notes.append(msg)
                continue
            counts, samples = out
            stats["frames_used"] += 1
            for key, n in counts.items():
                stats[key] += n
            if samples is None:
                continue
            pending.append(samples)
            n_pending += len(samples[0])
            stats["samples"] += len(samples[0])
            if n_pending >= flush_at:
                flush()
                n_pending = 0
    flush()
    if progress is not None:
        progress(len(scan.frames), len(scan.frames))
    solved = coverage = None
    if deconvolve and footprints:
        solved, coverage = _solve_planes(
            footprints, shapes, stats, smooth_of_plane, deconvolve_iterations
        )
        footprints.clear()

    textures: list[SurfaceTexture] = []
    per_label: dict[str, int] = {}
    for p, plane in enumerate(planes):
        h, w = shapes[p]
        sl = slice(starts[p], starts[p + 1])
        cnt = count[sl].reshape(h, w)
        filled = _finish(
            total[sl].reshape(h, w, 3),
            vertex_total[sl].reshape(h, w, 3),
            cnt,
            texel,
            calibrate_sigma,
            detail_sigma,
            fill_radius,
            None if solved is None else solved[sl].reshape(h, w, 3),
            None if coverage is None else coverage[sl].reshape(h, w),
        )
        if coverage is not None:
            cnt = np.where(coverage[sl] >= MIN_COVERAGE, coverage[sl], 0.0).reshape(h, w)
        entry = {
            "label": plane["label"],
            "axis": plane["axis"],
            "offset": plane["offset"],
            "area_m2": plane["area"],
        }
        if solved is not None:
            entry["smooth"] = float(smooth_of_plane[p])
        if filled is None:
            entry["observed_fraction"] = 0.0
            stats["planes"].append(entry)
            notes.append(
                f"textures: no photo sample on the {plane['label']} plane at "
                f"{'xyz'[plane['axis']]} = {plane['offset']:.2f} m: it keeps its per-vertex albedo"
            )
            continue
        n = per_label.get(plane["label"], 0)
        per_label[plane["label"]] = n + 1
        tex = SurfaceTexture(
            label=plane["label"],
            axis=plane["axis"],
            offset=plane["offset"],
            origin=origins[p],
            texel=texel,
            albedo=filled[0].astype(np.float32),
            detail=filled[1].astype(np.float32),
            count=cnt,
            rotation=rotation,
            name=f"{plane['label']}_{n}",
        )
        entry["name"] = tex.name
        entry["observed_fraction"] = tex.observed_fraction
        entry["above_one"] = float(np.mean((filled[0] > 1.0).any(axis=-1)[cnt > 0]))
        stats["planes"].append(entry)
        textures.append(tex)
    return textures, stats


def write_textures(
    textures: list[SurfaceTexture], out_dir: str | Path, subdir: str = "textures"
) -> list[dict[str, Any]]:
    """Write each texture as ``OUT/textures/<name>.exr`` (linear albedo, clipped to
    ``[0, 1]``), ``<name>_detail.exr`` and ``<name>_count.exr`` (samples per texel); returns the ``scene.json``
    entries (paths relative to ``out_dir``)."""
    from reroom.io.images import write_exr

    out = Path(out_dir) / subdir
    out.mkdir(parents=True, exist_ok=True)
    entries = []
    for tex in textures:
        write_exr(out / f"{tex.name}.exr", np.clip(tex.albedo, 0.0, 1.0))
        write_exr(out / f"{tex.name}_detail.exr", tex.detail)
        write_exr(out / f"{tex.name}_count.exr", tex.count.astype(np.float32))
        h, w = tex.shape
        entries.append(
            {
                "name": tex.name,
                "label": tex.label,
                "file": f"{subdir}/{tex.name}.exr",
                "detail_file": f"{subdir}/{tex.name}_detail.exr",
                "count_file": f"{subdir}/{tex.name}_count.exr",
                "axis": tex.axis,
                "uv_axes": list(tex.uv_axes),
                "offset": tex.offset,
                "origin": [float(x) for x in tex.origin],
                "texel": tex.texel,
                "width": w,
                "height": h,
                "observed_fraction": tex.observed_fraction,
                "mean_albedo": tex.mean_albedo.tolist(),
                "rotation": np.asarray(tex.rotation, float).tolist(),
            }
        )
    return entries


def read_texture_planes(
    entries: list[dict[str, Any]], invert_dir: str | Path
) -> list[TexturePlane]:
    """The planes of ``scene.json``'s ``textures`` entries, reading no image (raises
    :class:`~reroom.errors.ScanError` naming a texture file that is missing)."""
    out = []
    for e in entries:
        path = Path(invert_dir) / e["file"]
        if not path.is_file():
            raise ScanError(path, "texture file is missing")
        out.append(
            TexturePlane(
                label=e["label"],
                axis=int(e["axis"]),
                offset=float(e["offset"]),
                origin=(float(e["origin"][0]), float(e["origin"][1])),
                texel=float(e["texel"]),
                height=int(e["height"]),
                width=int(e["width"]),
                rotation=np.asarray(e["rotation"], float),
                name=e["name"],
            )
        )
    return out


def read_textures(entries: list[dict[str, Any]], invert_dir: str | Path) -> list[SurfaceTexture]:
    """The textures of ``scene.json``'s ``textures`` entries (files relative to
    ``invert_dir``). Raises :class:`~reroom.errors.ScanError` naming a missing or
    mis-sized file."""
    from reroom.io.images import read_exr

    def texture(e: dict[str, Any], albedo, detail, count) -> SurfaceTexture:
        return SurfaceTexture(
            label=e["label"],
            axis=int(e["axis"]),
            offset=float(e["offset"]),
            origin=(float(e["origin"][0]), float(e["origin"][1])),
            texel=float(e["texel"]),
            albedo=albedo,
            detail=detail,
            count=count,
            rotation=np.asarray(e["rotation"], float),
            name=e["name"],
        )

    out = []
    for e in entries:
        path = Path(invert_dir) / e["file"]
        h, w = int(e["height"]), int(e["width"])
        albedo = read_exr(path)[..., :3]
        if albedo.shape[:2] != (h, w):
            raise ScanError(
                path, f"is {albedo.shape[1]}x{albedo.shape[0]}, scene.json says {w}x{h}"
            )
        count_path = Path(invert_dir) / e.get("count_file", "")
        count = (
            read_exr(count_path)[..., 0].astype(np.int64)
            if e.get("count_file") and count_path.is_file()
            else np.ones((h, w), np.int64)
        )
        detail_path = Path(invert_dir) / e.get("detail_file", "")
        detail = (
            read_exr(detail_path)[..., :3]
            if e.get("detail_file") and detail_path.is_file()
            else np.ones_like(albedo)
        )
        out.append(texture(e, albedo, detail, count))
    return out
