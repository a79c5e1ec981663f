"""Project mesh vertices into every frame: which pixel sees which vertex (thesis §3.5-3.6).

For each frame, every vertex is projected (:func:`~reroom.hdr._kernels.project_vertices`);
those inside the image, in front of the camera and facing it are *candidates*.
Candidates then pass a visibility test, one of

* ``"rays"`` -- the thesis's test: a ray from the vertex (offset along its normal)
  to the camera centre must hit nothing (:meth:`RayCaster.visible_points`). One
  occlusion ray per candidate.
* ``"depth"`` -- a per-frame depth buffer: closest hits of camera rays through a
  grid of pixels (every ``depth_stride``-th pixel), then a depth test of each
  candidate against the buffer's bilinearly interpolated inverse depth. One
  closest-hit ray per grid pixel, whatever the number of vertices, and depth
  discontinuities come for free.

(``benchmarks/bench_hdr.py`` measures both; ``docs/hdr.md`` has the numbers.)

Visible candidates whose pixel lies near a strong image gradient (Sobel
magnitude of the relative luminance change above ``gradient_threshold`` within
``gradient_radius`` pixels) are *flagged*, as are, with the depth test, those at
depth discontinuities and creases of the buffer: pose and mesh errors move
pixels across such edges (the thesis drops these samples). Flagged samples never
enter the exposure solve or the baselines; in the reprojection a vertex uses
them only when it has no clean sample at all, so that surfaces seen only near
edges (small or busy objects) still get a radiance instead of none.
(``keep_flagged=False`` drops them outright, as the thesis does.)

What is kept is one *sample* per (vertex, frame): the 8-bit pixel value (nearest
pixel, for confidence weights and level tests), its linear value (``sampling``:
that pixel, or an average of its neighbours), the geometric weight ``g_ij`` of
eq. 3.2 and the flags. Samples are stored grouped by frame, compactly (``int32``
vertex and frame, ``uint8`` RGB and flags, ``uint16`` RGB linear codes,
``float32`` weight: 22 bytes each), so a 1000-frame 200k-vertex scan's ~32M
samples take ~0.7 GB.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from reroom.errors import ReroomError
from reroom.hdr import _kernels as K
from reroom.hdr.linearize import LUMA
from reroom.rays import RayCaster
from reroom.rays.geometry import mesh_pieces
from reroom.scan import Frame

__all__ = [
    "CLIPPED",
    "EDGE_FLAGS",
    "FOREIGN_FOOTPRINT",
    "MIXED_FOOTPRINT",
    "NEAR_DEPTH_EDGE",
    "NEAR_IMAGE_EDGE",
    "decode_linear",
    "encode_linear",
    "ObserveOptions",
    "Observations",
    "collect_observations",
    "vertex_normals",
]

#: Sample flag bits (``Observations.flags``): near a strong image gradient ...
NEAR_IMAGE_EDGE = np.uint8(1)
#: ... near a depth discontinuity or crease of the depth buffer ...
NEAR_DEPTH_EDGE = np.uint8(2)
#: ... and a pixel used for the value was clipped (0 or 255), so the value is biased.
CLIPPED = np.uint8(4)
#: Flags that mark a sample as possibly misregistered (not *clean*).
EDGE_FLAGS = np.uint8(NEAR_IMAGE_EDGE | NEAR_DEPTH_EDGE)
#: An edge sample some of whose pixels see another surface than the vertex's (the
#: footprint test, ``ObserveOptions.footprint_test``); its value is the mean of the
#: pixels that do see the vertex's surface ...
MIXED_FOOTPRINT = np.uint8(64)
#: ... or none of them does: the sample shows another surface (thin geometry, or
#: just past an occluding edge) and says nothing about this vertex.
FOREIGN_FOOTPRINT = np.uint8(128)

#: Linear values are stored as ``round(sqrt(x) * 65535)`` in uint16: 6 bytes per
#: sample instead of 24, relative precision better than 0.2 % above 8-bit level 8.
_ENC = 65535.0
_DECODE = (np.arange(65536, dtype=np.float64) / _ENC) ** 2
SAMPLING = {"nearest": 0, "bilinear": 1, "box3": 2}


def encode_linear(x: np.ndarray) -> np.ndarray:
    """Linear values in [0, 1] to the uint16 storage code."""
    return np.round(np.sqrt(np.clip(np.asarray(x, np.float64), 0.0, 1.0)) * _ENC).astype(np.uint16)


def decode_linear(code: np.ndarray) -> np.ndarray:
    """The uint16 storage code back to linear float64 values."""
    return _DECODE[code]


ProgressFn = Callable[[str, int, int], None]


@dataclass(frozen=True)
class ObserveOptions:
    """How vertices are matched to pixels.

    Attributes
    ----------
    visibility:
        ``"depth"`` (depth buffer + depth test) or ``"rays"`` (one occlusion ray
        per candidate vertex, as in the thesis).
    sampling:
        Which pixels give a sample's linear value: ``"nearest"`` (the pixel the
        vertex projects into, as in the thesis), ``"bilinear"`` (the four nearest
        pixel centres) or ``"box3"`` (the mean of the 3x3 pixels around it).
        Averaging neighbouring pixels (linearised first) lowers the per-sample
        noise; measured in ``docs/hdr.md``.
    depth_stride:
        Pixel step of the depth buffer (1 = every pixel); 0 = automatic, a buffer
        about 160 samples wide (stride 4 at 640 pixels, 1 at 160).
    depth_tolerance:
        Relative depth tolerance of the depth test.
    depth_edge_tolerance:
        A depth-buffer sample whose inverse depth has a second difference above
        this fraction of its value is a depth edge or crease
        (:func:`~reroom.hdr._kernels.depth_edges`); vertices there are dropped.
    margin:
        Minimum distance of a sample's pixel position from the image border, pixels.
    min_cos:
        Minimum cosine between a vertex normal and the direction to the camera
        (grazing views smear one pixel over a long strip of surface).
    gradient_threshold:
        Samples near a Sobel gradient of log-luminance above this (per pixel;
        0.25 = a 25 % change per pixel) are dropped. ``inf`` disables the test.
    gradient_noise_factor:
        If positive, in noisy frames the threshold rises to this many times the
        frame's median gradient (its noise level: edges are sparse). Off by
        default: measured worse than a fixed threshold plus the solve's fallback
        to edge samples for frames with few clean ones (``docs/hdr.md``).
    gradient_smoothing:
        Average the luminance over ``(2 s + 1)^2`` pixels before the gradient
        (0 = off), so that pixel noise does not read as edges.
    gradient_radius:
        How near, in pixels (a square window).

    gradient_floor:
        Linear value added to the luminance in the relative gradient's
        denominator, so that noise in near-black pixels is not taken for edges.
    keep_flagged:
        Keep samples near image or depth edges (flagged) for the reprojection of
        vertices that have no other sample; ``False`` drops them.
    footprint_test:
        Cast a ray through the centre of every pixel an edge sample's value is read
        from (one, four or nine, per ``sampling``) and keep, for its value, only the
        pixels that see the vertex's own surface (a hit within
        ``footprint_radius`` pixels' width of the vertex, on a face turned within 60
        degrees of the vertex's normal, of the same connected piece of mesh or in
        the vertex's plane). Near an edge the 3x3 average otherwise mixes in the surface behind: a
        thin black baffle in front of a white ceiling read five times its radiance
        (``docs/hdr.md``). Samples are flagged :data:`MIXED_FOOTPRINT` or
        :data:`FOREIGN_FOOTPRINT`; clean samples are not tested (their pixels are
        away from any image or depth edge).
    footprint_radius:
        How far from the vertex, in pixel widths at the vertex's depth (divided by
        the cosine of the view angle), a pixel's hit may lie and still be the
        vertex's surface.
    """

    visibility: str = "depth"
    sampling: str = "box3"
    depth_stride: int = 0
    depth_tolerance: float = 0.02
    depth_edge_tolerance: float = 0.05
    margin: float = 1.0
    min_cos: float = 0.1
    gradient_threshold: float = 0.25
    gradient_noise_factor: float = 0.0
    gradient_smoothing: int = 1
    gradient_radius: int = 1
    gradient_floor: float = 0.01
    keep_flagged: bool = True
    footprint_test: bool = True
    footprint_radius: float = 3.0


@dataclass
class Observations:
    """Every (vertex, frame) sample kept by :func:`collect_observations`.

    Samples are grouped by frame: frame ``j``'s are ``frame_offsets[j]:frame_offsets[j+1]``.

    Attributes
    ----------
    n_vertices, n_frames:
        Sizes of the problem.
    vertex:
        ``(S,)`` int32 vertex index of each sample.
    frame:
        ``(S,)`` int32 frame index (non-decreasing).
    value:
        ``(S, 3)`` uint8 level of the pixel the vertex projects into, as the camera
        encoded it (for the confidence weights, level tests and naive textures).
    linear:
        ``(S, 3)`` uint16 code of the sample's linear value (per ``sampling``);
        :meth:`linear_values` decodes it.
    geometry:
        ``(S,)`` float32 projected-area weight ``g_ij`` (eq. 3.2).
    flags:
        ``(S,)`` uint8 bits :data:`NEAR_IMAGE_EDGE`, :data:`NEAR_DEPTH_EDGE`,
        :data:`CLIPPED`.
    frame_offsets:
        ``(F + 1,)`` int64.
    frame_stats:
        Per-frame counts: ``candidates`` (in view, facing), ``visible``, ``clean``
        (visible and not flagged), ``kept`` (samples stored), and ``error`` (why a
        frame was skipped, or "").
    """

    n_vertices: int
    n_frames: int
    vertex: np.ndarray
    frame: np.ndarray
    value: np.ndarray
    linear: np.ndarray
    geometry: np.ndarray
    flags: np.ndarray
    frame_offsets: np.ndarray
    frame_stats: dict[str, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.vertex)

    @property
    def nbytes(self) -> int:
        arrays = (self.vertex, self.frame, self.value, self.linear, self.geometry, self.flags)
        return int(sum(a.nbytes for a in arrays))

    @property
    def clean(self) -> np.ndarray:
        """``(S,)`` bool: samples not near an image or depth edge."""
        return (self.flags & EDGE_FLAGS) == 0

    def linear_values(self, index: np.ndarray | slice | None = None) -> np.ndarray:
        """Decoded linear values ``(S, 3)`` float64 (of ``index`` only, if given)."""
        code = self.linear if index is None else self.linear[index]
        return decode_linear(code)

    def samples_per_vertex(self) -> np.ndarray:
        """``(V,)`` number of samples of each vertex."""
        return np.bincount(self.vertex, minlength=self.n_vertices)

    def subset(self, keep: np.ndarray) -> Observations:
        """The samples where the boolean ``keep`` is true (frame grouping preserved)."""
        counts = np.bincount(self.frame[keep], minlength=self.n_frames)
        return Observations(
            self.n_vertices,
            self.n_frames,
            self.vertex[keep],
            self.frame[keep],
            self.value[keep],
            self.linear[keep],
            self.geometry[keep],
            self.flags[keep],
            np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
            self.frame_stats,
        )

    @staticmethod
    def from_arrays(
        n_vertices: int,
        n_frames: int,
        vertex: np.ndarray,
        frame: np.ndarray,
        value: np.ndarray,
        geometry: np.ndarray | None = None,
        flags: np.ndarray | None = None,
        lut: np.ndarray | None = None,
    ) -> Observations:
        """Build observations from unsorted arrays (tests, synthetic problems).

        The linear values are ``lut[value]`` (default: a linear response).
        """
        order = np.argsort(frame, kind="stable")
        frame = np.asarray(frame, np.int32)[order]
        counts = np.bincount(frame, minlength=n_frames)
        g = np.ones(len(order), np.float32) if geometry is None else geometry
        fl = np.zeros(len(order), np.uint8) if flags is None else flags
        lut = np.arange(256) / 255.0 if lut is None else np.asarray(lut, np.float64)
        levels = np.asarray(value, np.uint8).reshape(-1, 3)[order]
        return Observations(
            int(n_vertices),
            int(n_frames),
            np.asarray(vertex, np.int32)[order],
            frame,
            levels,
            encode_linear(lut[levels]),
            np.asarray(g, np.float32)[order],
            np.asarray(fl, np.uint8)[order],
            np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
            {"kept": counts},
        )


def vertex_normals(mesh) -> np.ndarray:
    """Unit area-weighted vertex normals; zero for vertices of no (non-degenerate) face."""
    v = np.asarray(mesh.vertices, dtype=np.float64)
    f = np.asarray(mesh.faces, dtype=np.int64)
    tri = v[f]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # length = 2 * area
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, f[:, k], fn)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


@dataclass(frozen=True)
class VertexChunks:
    """Vertices grouped into small spatial cells with bounding spheres (for frustum culling)."""

    perm: np.ndarray
    offsets: np.ndarray
    centers: np.ndarray
    radii: np.ndarray

    @staticmethod
    def build(verts: np.ndarray, per_chunk: int = 256) -> VertexChunks:
        """Cells of a regular grid sized for about ``per_chunk`` vertices each."""
        v = np.asarray(verts, np.float64)
        if len(v) == 0:
            return VertexChunks(
                np.zeros(0, np.int64), np.zeros(1, np.int64), np.zeros((0, 3)), np.zeros(0)
            )
        lo, hi = v.min(axis=0), v.max(axis=0)
        ext = np.maximum(hi - lo, 1e-9)
        # A surface (not a volume) holds the vertices: cells ~ sqrt(n / per_chunk) per side.
        side = max(1, int(np.sqrt(len(v) / per_chunk)))
        cell = ext.max() / side
        key = np.floor((v - lo) / cell).astype(np.int64)
        dims = key.max(axis=0) + 1
        flat = (key[:, 0] * dims[1] + key[:, 1]) * dims[2] + key[:, 2]
        perm = np.argsort(flat, kind="stable")
        fs = flat[perm]
        starts = np.flatnonzero(np.r_[True, fs[1:] != fs[:-1]])
        offsets = np.r_[starts, len(v)].astype(np.int64)
        counts = np.diff(offsets)
        centers = np.add.reduceat(v[perm], starts, axis=0) / counts[:, None]
        d = np.linalg.norm(v[perm] - np.repeat(centers, counts, axis=0), axis=1)
        radii = np.maximum.reduceat(d, starts) + 1e-9
        return VertexChunks(perm.astype(np.int64), offsets, centers, radii)


@dataclass(frozen=True)
class MeshPieces:
    """The mesh's connected pieces: the label of each vertex's and each face's."""

    vertex: np.ndarray
    face: np.ndarray

    @staticmethod
    def build(mesh) -> MeshPieces:
        """Label the pieces of ``mesh`` (vertices joined by its faces' edges)."""
        f = np.asarray(mesh.faces, np.int64).reshape(-1, 3)
        labels = mesh_pieces(f, len(mesh.vertices))
        return MeshPieces(labels, labels[f[:, 0]] if len(f) else np.zeros(0, np.int64))


def _intrinsics_vector(frame: Frame) -> np.ndarray:
    k = frame.intrinsics
    return np.array([k.fx, k.fy, k.cx, k.cy, k.width, k.height, k.k1, k.k2, k.p1, k.p2], float)


def _world_to_cv(frame: Frame) -> tuple[np.ndarray, np.ndarray]:
    w2c = frame.w2c
    flip = np.diag([1.0, -1.0, -1.0])
    return np.ascontiguousarray(flip @ w2c[:3, :3]), np.ascontiguousarray(flip @ w2c[:3, 3])


def auto_stride(width: int) -> int:
    """Depth-buffer stride giving a buffer about 160 samples wide."""
    return max(1, round(width / 160))


def inverse_depth_buffer(caster: RayCaster, frame: Frame, stride: int) -> np.ndarray:
    """1 / depth of the surface seen through every ``stride``-th pixel centre (0 = nothing)."""
    k = frame.intrinsics
    cols = np.arange(stride / 2.0, k.width, stride)
    rows = np.arange(stride / 2.0, k.height, stride)
    jj, ii = np.meshgrid(cols, rows)
    uv = np.stack([jj.ravel(), ii.ravel()], axis=1)
    o, d = frame.pixel_rays(uv)
    hits = caster.intersect(o, d)
    axis = frame.forward
    depth = hits.t * (d @ axis)
    inv = np.where(hits.hit & (depth > 0), 1.0 / np.where(depth > 0, depth, 1.0), 0.0)
    return inv.reshape(len(rows), len(cols))


def collect_observations(
    frames: list[Frame],
    mesh,
    lut: np.ndarray,
    options: ObserveOptions | None = None,
    caster: RayCaster | None = None,
    progress: ProgressFn | None = None,
    normals: np.ndarray | None = None,
) -> Observations:
    """Match every mesh vertex to the pixel that sees it in every frame.

    Parameters
    ----------
    frames:
        The scan's frames (images decode lazily, one at a time).
    mesh:
        The scan mesh (``trimesh.Trimesh``).
    lut:
        Inverse response LUT (:func:`~reroom.hdr.linearize.response_lut`), used only
        for the gradient test.
    options:
        :class:`ObserveOptions`.
    caster:
        A :class:`RayCaster` of ``mesh`` (built here if not given).
    progress:
        ``progress(stage, done, total)``.
    normals:
        ``(V, 3)`` vertex normals (default: :func:`vertex_normals`).

    Returns
    -------
    Observations
        A frame whose image cannot be decoded is skipped with a warning (its
        ``frame_stats["error"]`` says why).
    """
    opt = options or ObserveOptions()
    if opt.visibility not in ("depth", "rays"):
        raise ReroomError(f"visibility must be 'depth' or 'rays', not {opt.visibility!r}")
    if opt.sampling not in SAMPLING:
        raise ReroomError(f"sampling must be one of {sorted(SAMPLING)}, not {opt.sampling!r}")
    lut64 = np.ascontiguousarray(lut, np.float64)
    if opt.footprint_test and not (np.isfinite(opt.footprint_radius) and opt.footprint_radius > 0):
        raise ReroomError(f"footprint_radius must be > 0 pixels, got {opt.footprint_radius}")
    if opt.depth_stride < 0:
        raise ReroomError(f"depth_stride must be >= 0 (0 = automatic), got {opt.depth_stride}")
    verts = np.ascontiguousarray(np.asarray(mesh.vertices, dtype=np.float64))
    nrm = vertex_normals(mesh) if normals is None else np.asarray(normals, np.float64)
    nrm = np.ascontiguousarray(nrm)
    n_v, n_f = len(verts), len(frames)
    caster = caster or RayCaster(mesh)
    luma_lut = np.ascontiguousarray(np.outer(LUMA, np.asarray(lut, np.float64)), np.float32)

    chunks = VertexChunks.build(verts)
    pieces = MeshPieces.build(mesh) if opt.footprint_test else None
    u = np.empty(n_v, np.float64)
    v = np.empty(n_v, np.float64)
    g = np.empty(n_v, np.float64)
    z = np.empty(n_v, np.float64)
    ok = np.empty(n_v, np.bool_)
    stats = {k: np.zeros(n_f, np.int64) for k in ("candidates", "visible", "clean", "kept")}
    errors = [""] * n_f
    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

    def load(frame: Frame) -> np.ndarray | Exception:
        try:
            return frame.load_image()
        except ReroomError as exc:
            return exc

    # Decode the next frame's image on a thread while this one is processed:
    # PNG decoding releases the GIL, so it overlaps with the ray casting.
    with ThreadPoolExecutor(max_workers=1) as pool:
        pending = pool.submit(load, frames[0]) if n_f else None
        for j, frame in enumerate(frames):
            image = pending.result() if pending is not None else None
            pending = pool.submit(load, frames[j + 1]) if j + 1 < n_f else None
            if isinstance(image, Exception):
                errors[j] = str(image)
                warnings.warn(f"frame {j}: skipped, {image}", stacklevel=2)
                parts.append(_empty_part())
                if progress:
                    progress("reproject", j + 1, n_f)
                continue
            rot, trans = _world_to_cv(frame)
            ok[:] = False
            K.project_vertices(
                verts,
                nrm,
                chunks.perm,
                chunks.offsets,
                chunks.centers,
                chunks.radii,
                rot,
                trans,
                frame.center,
                _intrinsics_vector(frame),
                float(opt.margin),
                float(opt.min_cos),
                1e-6,
                u,
                v,
                g,
                z,
                ok,
            )
            idx = np.flatnonzero(ok)
            stats["candidates"][j] = len(idx)
            flags = np.zeros(len(idx), np.uint8)
            if len(idx):
                if opt.visibility == "rays":
                    vis = caster.visible_points(
                        verts[idx], nrm[idx], frame.center, require_facing=False
                    )
                else:
                    stride = opt.depth_stride or auto_stride(frame.intrinsics.width)
                    inv = inverse_depth_buffer(caster, frame, stride)
                    edges = K.depth_edges(inv, float(opt.depth_edge_tolerance))
                    vis, edge = K.depth_test(
                        inv,
                        edges,
                        stride,
                        u[idx],
                        v[idx],
                        z[idx],
                        float(opt.depth_tolerance),
                    )
                    flags[edge] |= NEAR_DEPTH_EDGE
                stats["visible"][j] = int(np.count_nonzero(vis))
                idx, flags = idx[vis], flags[vis]
            rows = np.floor(v[idx]).astype(np.int64)
            cols = np.floor(u[idx]).astype(np.int64)
            if len(idx) and np.isfinite(opt.gradient_threshold):
                grad = K.relative_gradient(
                    image, luma_lut, np.float32(opt.gradient_floor), int(opt.gradient_smoothing)
                )
                # Edges are sparse, so the median gradient is the frame's noise (and smooth
                # shading): in a noisy frame the fixed threshold would flag everything.
                noise = float(np.median(grad[::4, ::4])) if grad.size else 0.0
                limit = max(opt.gradient_threshold, opt.gradient_noise_factor * noise)
                near = K.max_in_window(grad, rows, cols, int(opt.gradient_radius))
                flags[near > limit] |= NEAR_IMAGE_EDGE
            stats["clean"][j] = int(np.count_nonzero((flags & EDGE_FLAGS) == 0))
            if not opt.keep_flagged:
                keep = (flags & EDGE_FLAGS) == 0
                idx, rows, cols, flags = idx[keep], rows[keep], cols[keep], flags[keep]
            stats["kept"][j] = len(idx)
            lin, clipped = K.sample_pixels(image, lut64, u[idx], v[idx], SAMPLING[opt.sampling])
            flags[clipped] |= CLIPPED
            levels = image[rows, cols]
            if opt.footprint_test:
                edge = np.flatnonzero(flags & EDGE_FLAGS)
                if len(edge):
                    lin[edge], flags[edge] = _footprint_values(
                        caster, frame, image, lut64, verts, nrm, idx[edge], u[idx[edge]],
                        v[idx[edge]], z[idx[edge]], flags[edge], pieces, opt,
                    )  # fmt: skip
                    # The nearest pixel of a mixed sample may show the other surface (a
                    # light, clipped): its level is that of the value kept instead.
                    mixed = edge[(flags[edge] & MIXED_FOOTPRINT) != 0]
                    levels[mixed] = _nearest_levels(lin[mixed], lut64)
            parts.append(
                (
                    idx.astype(np.int32),
                    levels,
                    encode_linear(lin),
                    g[idx].astype(np.float32),
                    flags,
                )
            )
            if progress:
                progress("reproject", j + 1, n_f)

    counts = np.array([len(p[0]) for p in parts], np.int64)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    frame_idx = np.repeat(np.arange(n_f, dtype=np.int32), counts)
    vertex = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0, np.int32)
    value = np.concatenate([p[1] for p in parts]) if parts else np.zeros((0, 3), np.uint8)
    linear = np.concatenate([p[2] for p in parts]) if parts else np.zeros((0, 3), np.uint16)
    geom = np.concatenate([p[3] for p in parts]) if parts else np.zeros(0, np.float32)
    flags = np.concatenate([p[4] for p in parts]) if parts else np.zeros(0, np.uint8)
    stats_out: dict[str, np.ndarray] = dict(stats)
    stats_out["error"] = np.array(errors, dtype=object)
    return Observations(n_v, n_f, vertex, frame_idx, value, linear, geom, flags, offsets, stats_out)


def _nearest_levels(linear: np.ndarray, lut: np.ndarray) -> np.ndarray:
    """The 8-bit level whose linear value (``lut``, non-decreasing) is nearest each value."""
    hi = np.clip(np.searchsorted(lut, linear), 1, len(lut) - 1)
    lower = (linear - lut[hi - 1]) < (lut[hi] - linear)
    return np.where(lower, hi - 1, hi).astype(np.uint8)


def _footprint_pixels(
    u: np.ndarray, v: np.ndarray, width: int, height: int, sampling: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pixels ``(rows, cols)`` each sample's value is read from, ``(S, P)`` each,
    and their weights ``(S, P)`` in that value (as :func:`~reroom.hdr._kernels.sample_pixels`
    reads them; a pixel outside the image has weight 0)."""
    col = np.clip(np.floor(u).astype(np.int64), 0, width - 1)
    row = np.clip(np.floor(v).astype(np.int64), 0, height - 1)
    if sampling == "nearest":
        return row[:, None], col[:, None], np.ones((len(u), 1))
    if sampling == "bilinear":
        gx, gy = u - 0.5, v - 0.5
        x0 = np.clip(np.floor(gx).astype(np.int64), 0, max(width - 2, 0))
        y0 = np.clip(np.floor(gy).astype(np.int64), 0, max(height - 2, 0))
        fx, fy = np.clip(gx - x0, 0, 1), np.clip(gy - y0, 0, 1)
        x1, y1 = np.minimum(x0 + 1, width - 1), np.minimum(y0 + 1, height - 1)
        rows = np.stack([y0, y0, y1, y1], 1)
        cols = np.stack([x0, x1, x0, x1], 1)
        w = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], 1)
        return rows, cols, w
    dr, dc = np.meshgrid(np.arange(-1, 2), np.arange(-1, 2), indexing="ij")
    rows = row[:, None] + dr.ravel()[None, :]
    cols = col[:, None] + dc.ravel()[None, :]
    inside = (rows >= 0) & (rows < height) & (cols >= 0) & (cols < width)
    return np.clip(rows, 0, height - 1), np.clip(cols, 0, width - 1), inside.astype(float)


def _footprint_values(
    caster: RayCaster,
    frame: Frame,
    image: np.ndarray,
    lut: np.ndarray,
    verts: np.ndarray,
    normals: np.ndarray,
    vertex: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    depth: np.ndarray,
    flags: np.ndarray,
    pieces: MeshPieces,
    opt: ObserveOptions,
) -> tuple[np.ndarray, np.ndarray]:
    """The footprint test of ``ObserveOptions.footprint_test`` for some samples of one
    frame: their linear values from the pixels that see their vertex's surface, and
    their flags with :data:`MIXED_FOOTPRINT` / :data:`FOREIGN_FOOTPRINT` set."""
    k = frame.intrinsics
    rows, cols, weight = _footprint_pixels(u, v, k.width, k.height, opt.sampling)
    n, p = rows.shape
    uv = np.stack([cols.ravel() + 0.5, rows.ravel() + 0.5], axis=1)
    origin, direction = frame.pixel_rays(uv)
    hits = caster.intersect(origin, direction)
    x = np.repeat(verts[vertex], p, axis=0)
    nv = np.repeat(normals[vertex], p, axis=0)
    to_cam = frame.center - verts[vertex]
    cos = np.abs(np.sum(to_cam * normals[vertex], axis=1)) / np.linalg.norm(to_cam, axis=1)
    reach = opt.footprint_radius * depth / k.fx / np.maximum(cos, 0.2)
    offset = np.where(hits.hit[:, None], hits.points - x, np.inf)
    turn = np.sum(hits.normals * nv, axis=1)  # NaN where the ray missed
    near = np.linalg.norm(offset, axis=1)
    # A separate piece of mesh close by (a light's emitter inside its housing, a bulb in
    # its shade) is another surface, unless it continues the vertex's plane (a wall
    # meshed in pieces around a window): within a quarter of a pixel of it.
    same_piece = pieces.face[np.where(hits.hit, hits.face, 0)] == np.repeat(
        pieces.vertex[vertex], p
    )
    off_plane = np.abs(np.sum(np.where(hits.hit[:, None], offset, 0.0) * nv, axis=1))
    coplanar = (off_plane <= np.repeat(0.25 * depth / k.fx, p)) & (turn > 0.95)
    owned = hits.hit & (turn > 0.5) & (same_piece | coplanar) & (near <= np.repeat(reach, p))
    owned = owned.reshape(n, p)
    w = weight * owned
    total = w.sum(axis=1)
    values = lut[image[rows, cols]]  # (n, p, 3)
    lin = np.einsum("np,npc->nc", w, values) / np.where(total > 0, total, 1.0)[:, None]
    out = flags.copy()
    mixed = (total > 0) & np.any((weight > 0) & ~owned, axis=1)
    out[mixed] |= MIXED_FOOTPRINT
    out[total <= 0] |= FOREIGN_FOOTPRINT
    whole = np.einsum("np,npc->nc", weight, values) / weight.sum(axis=1)[:, None]
    return np.where((total > 0)[:, None], lin, whole), out


def _empty_part() -> tuple[np.ndarray, ...]:
    return (
        np.zeros(0, np.int32),
        np.zeros((0, 3), np.uint8),
        np.zeros((0, 3), np.uint16),
        np.zeros(0, np.float32),
        np.zeros(0, np.uint8),
    )
