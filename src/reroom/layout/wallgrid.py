"""Per-wall image evidence: oriented edges and see-through rays, binned on wall grids.

Thesis §4.3.1: edges aligned with the Manhattan axes are found in each frame -- the
direction of an axis at a pixel is the direction towards that axis's vanishing point,
known from the frame's pose and the Manhattan frame -- and only pixels that see a wall
(found by ray casting the pixel against the mesh and looking up the wall the hit lies
on) are kept. Each kept pixel adds to its wall's grid cell ``(s, z)``: ``N`` (pixels),
``F_h`` and ``F_v`` (horizontal and vertical edge response).

Our addition: each pixel ray is also followed through the wall planes it crosses. A ray
that ends on the wall plane saw the wall; one that ends a little behind it saw a recess
(a door set into its frame, a window reveal); one that goes on much further, or leaves
the mesh, went through an opening. Those counts find windows and open doorways in meshes
where they are holes, and measure recess depths.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from reroom.rays import RayCaster
from reroom.scan.camera import GL_TO_CV, Frame


@dataclass
class WallGrids:
    """Evidence per wall, each array ``(ns, nz)`` with cell ``(i, j)`` covering
    ``s in [i c, (i+1) c)`` (arc length from the wall's start) and
    ``z in [floor + j c, floor + (j+1) c)``.

    Attributes
    ----------
    walls:
        The walls (``start``, ``end``, ``inward_normal``), all rooms together.
    cell, floor_z, ceiling_z:
        Grid geometry.
    n, fh, fv:
        Pixels that saw the wall surface per cell, their summed horizontal and vertical
        oriented-edge responses.
    surface, shallow, deep, through:
        Rays that crossed the wall plane at the cell and ended on it (within
        ``surface_tol``), a little behind it (up to ``deep_min``: a door set into its
        frame), well behind it (up to ``recess_max``: a window's reveal), or further /
        nowhere (an opening).
    recess_sum:
        Summed depth behind the plane of the ``shallow`` and ``deep`` rays.
    jamb:
        The ``shallow`` rays that ended on a face across the wall plane (its normal
        within 60 degrees of the plane): a window's reveal or sill, a door's jamb. Such
        a ray crossed the plane where the wall is open, however shallow it ended: near
        an opening's edge an oblique ray meets the reveal a few centimetres in.
    bright:
        Count of bright (HDR) vertices per cell, when radiance was given.
    """

    walls: list[dict]
    cell: float
    floor_z: float
    ceiling_z: float
    n: list[np.ndarray] = field(default_factory=list)
    fh: list[np.ndarray] = field(default_factory=list)
    fv: list[np.ndarray] = field(default_factory=list)
    surface: list[np.ndarray] = field(default_factory=list)
    shallow: list[np.ndarray] = field(default_factory=list)
    deep: list[np.ndarray] = field(default_factory=list)
    through: list[np.ndarray] = field(default_factory=list)
    recess_sum: list[np.ndarray] = field(default_factory=list)
    jamb: list[np.ndarray] = field(default_factory=list)
    bright: list[np.ndarray] = field(default_factory=list)

    @staticmethod
    def empty(walls: list[dict], cell: float, floor_z: float, ceiling_z: float) -> WallGrids:
        g = WallGrids(walls, cell, floor_z, ceiling_z)
        nz = max(1, int(np.ceil((ceiling_z - floor_z) / cell)))
        for w in walls:
            length = float(np.linalg.norm(np.subtract(w["end"], w["start"])))
            ns = max(1, int(np.ceil(length / cell)))
            for name in (
                "n",
                "fh",
                "fv",
                "surface",
                "shallow",
                "deep",
                "through",
                "recess_sum",
                "jamb",
                "bright",
            ):
                getattr(g, name).append(np.zeros((ns, nz)))
        return g

    def shape(self, k: int) -> tuple[int, int]:
        return self.n[k].shape

    def _flat_offsets(self) -> np.ndarray:
        sizes = [a.size for a in self.n]
        return np.concatenate([[0], np.cumsum(sizes)])

    def cell_index(
        self, wall: np.ndarray, s: np.ndarray, z: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Flat indices (into all walls' cells) of points ``(s, z)`` on walls ``wall``,
        and a mask of those inside their wall's grid."""
        offs = self._flat_offsets()
        shapes = np.array([a.shape for a in self.n]).reshape(-1, 2)
        i = np.floor(s / self.cell).astype(np.int64)
        j = np.floor((z - self.floor_z) / self.cell).astype(np.int64)
        ns = shapes[wall, 0]
        nz = shapes[wall, 1]
        ok = (i >= 0) & (i < ns) & (j >= 0) & (j < nz)
        flat = offs[wall] + np.where(ok, i * nz + j, 0)
        return flat, ok

    def add(self, name: str, flat: np.ndarray, weights: np.ndarray | None = None) -> None:
        """Add counts (or weights) at flat cell indices to the named grids."""
        offs = self._flat_offsets()
        acc = np.bincount(flat, weights=weights, minlength=int(offs[-1]))
        arrays = getattr(self, name)
        for k, a in enumerate(arrays):
            a += acc[offs[k] : offs[k + 1]].reshape(a.shape)


def wall_frames(walls: list[dict]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per wall: start ``(K, 2)``, unit tangent, inward normal, length."""
    a = np.array([w["start"] for w in walls], float).reshape(-1, 2)
    b = np.array([w["end"] for w in walls], float).reshape(-1, 2)
    length = np.linalg.norm(b - a, axis=1)
    t = (b - a) / length[:, None]
    nin = np.array([w["inward_normal"] for w in walls], float).reshape(-1, 2)
    return a, t, nin, length


def log_luminance(img: np.ndarray, gamma: float = 2.2) -> np.ndarray:
    """Log of the linear luminance of an 8-bit frame, despeckled.

    Each pixel is clamped to the brightest of its four neighbours, which removes
    isolated bright pixels (path-tracing fireflies, hot pixels) at a twentieth of the cost
    of a 3x3 median, before a light Gaussian; differences of log luminance do not depend on the
    frame's exposure, so one edge threshold serves every auto-exposed frame.
    """
    lin = (img.astype(np.float32) / 255.0) ** gamma
    lum = 0.2126 * lin[..., 0] + 0.7152 * lin[..., 1] + 0.0722 * lin[..., 2]
    lum = despeckle(lum)
    lum = ndimage.gaussian_filter(lum, 0.7)
    return np.log(lum + 2e-3)


def despeckle(x: np.ndarray) -> np.ndarray:
    """Clamp each interior pixel to the maximum of its four neighbours."""
    m = np.maximum(np.maximum(x[:-2, 1:-1], x[2:, 1:-1]), np.maximum(x[1:-1, :-2], x[1:-1, 2:]))
    out = x.copy()
    out[1:-1, 1:-1] = np.minimum(x[1:-1, 1:-1], m)
    return out


def rotate(points: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """``points @ rot.T`` for ``(N, 3)`` points, as three matrix-vector products.

    Equal to the matrix product, but numpy hands ``(N, 3) @ (3, 3)`` to a threaded BLAS
    call that cost 10x more wall time on a busy machine (measured: 37 vs 3 ms for 77k
    points with other jobs running).
    """
    p = np.asarray(points)
    return np.stack([p @ r for r in np.asarray(rot)], axis=1)


def downscale(img: np.ndarray, factor: int) -> np.ndarray:
    """Box-average an ``(H, W, ...)`` image by an integer factor."""
    if factor <= 1:
        return img
    h, w = img.shape[0] // factor * factor, img.shape[1] // factor * factor
    x = img[:h, :w].astype(np.float32)
    x = x.reshape(h // factor, factor, w // factor, factor, *img.shape[2:]).mean(axis=(1, 3))
    return x.astype(img.dtype) if img.dtype == np.uint8 else x


def oriented_edges(logl: np.ndarray, vp: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Edge response along a Manhattan axis at pixel positions ``uv``.

    Parameters
    ----------
    logl:
        ``(H, W)`` log luminance.
    vp:
        Homogeneous vanishing point ``(3,)`` of the axis in this image.
    uv:
        ``(P, 2)`` pixel-centre positions of the ``P`` pixels (row-major over ``logl``).

    Returns
    -------
    ``(P,)`` ``max(0, |g . d_perp| - |g . d|)`` with ``g`` the Sobel gradient and ``d``
    the unit direction from the pixel towards the vanishing point: the gradient across
    lines through the vanishing point, minus the gradient along them, so isotropic noise
    averages to about zero and edges in other directions score nothing.
    """
    gy = (ndimage.sobel(logl, axis=0) / 8.0).ravel()
    gx = (ndimage.sobel(logl, axis=1) / 8.0).ravel()
    return _edge(gx, gy, np.asarray(vp, float), np.asarray(uv, float))


def vanishing_points(frame: Frame, axes_mesh: np.ndarray, scale: float) -> np.ndarray:
    """``(3, 3)`` homogeneous vanishing points (rows) of the three axes in a frame's image
    (intrinsics scaled by ``scale``; lens distortion ignored)."""
    k = frame.intrinsics
    kmat = np.array([[k.fx * scale, 0, k.cx * scale], [0, k.fy * scale, k.cy * scale], [0, 0, 1]])
    r_w2c = frame.c2w[:3, :3].T
    return (kmat @ GL_TO_CV @ r_w2c @ axes_mesh.T).T


def select_frames(frames: Sequence[Frame], max_frames: int) -> list[Frame]:
    """At most ``max_frames`` frames, evenly spread through the sequence."""
    if len(frames) <= max_frames:
        return list(frames)
    idx = np.unique(np.round(np.linspace(0, len(frames) - 1, max_frames)).astype(int))
    return [frames[i] for i in idx]


def _camera_rays(frame: Frame, w: int, h: int, factor: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre positions (downscaled image) and unit ray directions in camera axes
    (OpenGL), for ``w x h`` pixels of a frame downscaled by ``factor``."""
    jj, ii = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    uv = np.stack([jj.ravel(), ii.ravel()], axis=1)
    k = frame.intrinsics
    xn, yn = k.undistort((uv[:, 0] * factor - k.cx) / k.fx, (uv[:, 1] * factor - k.cy) / k.fy)
    d = np.stack([xn, -yn, -np.ones_like(xn)], axis=1)
    return uv, d / np.linalg.norm(d, axis=1, keepdims=True)


def accumulate_frames(
    grids: WallGrids,
    frames: Sequence[Frame],
    caster: RayCaster,
    rotation: np.ndarray,
    face_wall: np.ndarray,
    max_width: int = 320,
    gamma: float = 2.2,
    surface_tol: float = 0.015,
    deep_min: float = 0.06,
    recess_max: float = 0.3,
    progress: Callable[[int, int], None] | None = None,
    edges: bool = True,
    through_stride: int | None = None,
) -> None:
    """Add the edge and see-through evidence of ``frames`` to ``grids`` (in place).

    Parameters
    ----------
    caster:
        Ray caster of the scan mesh (mesh coordinates).
    rotation:
        Mesh-to-aligned rotation (rows: the Manhattan axes in mesh coordinates).
    face_wall:
        ``(F,)`` wall index of each face (``-1``: not a wall surface); pixels that hit
        other faces are masked out of the edge counts.
    max_width:
        Frames wider than this are box-downscaled by an integer factor first.
    gamma:
        The frames' response, to linearise them.
    surface_tol, deep_min, recess_max:
        A ray that crossed a wall plane and ended within ``surface_tol`` of it saw the
        wall; up to ``deep_min`` behind it, a shallow recess; up to ``recess_max``, a
        deep one; further, an opening.
    edges:
        Also accumulate the oriented edges (needs the pixels). ``False``: see-through
        evidence only, from every ``through_stride``-th pixel in each direction, without
        reading the image -- what extra frames add cheaply for openings that few frames
        look through.
    through_stride:
        Pixel stride of the see-through rays. ``None``: 2 for frames (after the
        downscale) at least 240 pixels wide, where openings are tens of pixels across
        and a quarter of the rays finds the same openings; 1 for narrower ones, where
        every other pixel leaves the rays too sparse on the walls (the 24-frame 160x120
        ``furnished`` scan's window and door were missed with 2).
    """
    a, t, nin, length = wall_frames(grids.walls)
    zf, zc = grids.floor_z, grids.ceiling_z
    n_walls = len(grids.walls)
    acc: dict[str, list[tuple[np.ndarray, np.ndarray | None]]] = {
        name: []
        for name in (
            "n", "fh", "fv", "surface", "shallow", "deep", "recess_sum", "through", "jamb"
        )
    }  # fmt: skip
    # Each face's normal in the aligned frame: a ray ending on a face across a wall
    # plane (a reveal, sill or jamb) crossed that plane where it is open.
    face_n = rotate(caster.face_normals, rotation)
    ray_cache: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}
    for fi, frame in enumerate(frames):
        k = frame.intrinsics
        factor = max(1, int(np.ceil(k.width / max_width)))
        if edges:
            img = downscale(frame.load_image(), factor)
            h, w = img.shape[:2]
        else:
            h, w = k.height // factor, k.width // factor
        key = (k, w, h, factor)
        if key not in ray_cache:
            ray_cache[key] = _camera_rays(frame, w, h, factor)
        uv, d_cam = ray_cache[key]
        r_mesh = frame.c2w[:3, :3]
        o_al = rotation @ frame.center
        d_al = rotate(d_cam, rotation @ r_mesh)
        # Every other pixel in each direction for the see-through rays on frames 240 px
        # wide or more (or every ``through_stride``-th): openings are tens of pixels
        # across there, and a quarter of the rays cuts this part's cost by four
        # (measured: same openings).
        stride = through_stride or (2 if w >= 240 else 1)
        sub = (
            (np.arange(h)[:, None] % stride == 0) & (np.arange(w)[None, :] % stride == 0)
        ).ravel()
        sub_idx = np.flatnonzero(sub)
        if edges:
            hits = caster.intersect(frame.center, rotate(d_cam, r_mesh))
            t_hit = np.where(hits.hit, hits.t, np.inf)
            t_sub = t_hit[sub_idx]
            f_sub = np.where(hits.hit, hits.face, -1)[sub_idx]
        else:
            hits = caster.intersect(frame.center, rotate(d_cam[sub_idx], r_mesh))
            t_sub = np.where(hits.hit, hits.t, np.inf)
            f_sub = np.where(hits.hit, hits.face, -1)
        d_sub = d_al[sub_idx]

        # --- edges on the wall surfaces the pixels see -------------------------------------
        fw = np.where(hits.hit, face_wall[np.maximum(hits.face, 0)], -1) if edges else None
        seen = np.flatnonzero(fw >= 0) if edges else np.zeros(0, np.int64)
        if len(seen):
            logl = log_luminance(img, gamma)
            gy = (ndimage.sobel(logl, axis=0) / 8.0).ravel()[seen]
            gx = (ndimage.sobel(logl, axis=1) / 8.0).ravel()[seen]
            vps = vanishing_points(frame, rotation, 1.0 / factor)
            kw = fw[seen]
            p = o_al + d_al[seen] * t_hit[seen, None]
            s = np.einsum("ij,ij->i", p[:, :2] - a[kw], t[kw])
            flat, ok = grids.cell_index(kw, s, p[:, 2])
            # The wall's own horizontal axis: y for walls facing +-x, x for walls facing +-y.
            use_y = np.abs(nin[kw, 0]) > 0.5
            eh = np.where(use_y, _edge(gx, gy, vps[1], uv[seen]), _edge(gx, gy, vps[0], uv[seen]))
            ev = _edge(gx, gy, vps[2], uv[seen])
            acc["n"].append((flat[ok], None))
            acc["fh"].append((flat[ok], eh[ok]))
            acc["fv"].append((flat[ok], ev[ok]))

        # --- rays through the wall planes ----------------------------------------------------
        for wk in range(n_walls):
            side = (o_al[:2] - a[wk]) @ nin[wk]  # > 0: camera on the room side
            if side <= 0:
                continue
            toward = d_sub[:, :2] @ nin[wk]  # < 0: heading out through the wall
            idx = np.flatnonzero(toward < -1e-6)
            if not len(idx):
                continue
            tc = -side / toward[idx]
            q = o_al + d_sub[idx] * tc[:, None]
            s = (q[:, :2] - a[wk]) @ t[wk]
            # Depth behind the plane at which the ray ended, measured along the normal.
            gap = (t_sub[idx] - tc) * (-toward[idx])
            keep = (s >= 0) & (s < length[wk]) & (q[:, 2] > zf) & (q[:, 2] < zc)
            keep &= gap >= -surface_tol  # else something in front of the wall hid it
            if not keep.any():
                continue
            flat, ok = grids.cell_index(np.full(int(keep.sum()), wk), s[keep], q[keep, 2])
            g = gap[keep][ok]
            flat = flat[ok]
            on = np.abs(g) <= surface_tol
            rec = (g > surface_tol) & (g <= recess_max)
            acc["surface"].append((flat[on], None))
            acc["shallow"].append((flat[rec & (g <= deep_min)], None))
            fk = f_sub[idx][keep][ok]
            across = (fk >= 0) & (np.abs(face_n[np.maximum(fk, 0), :2] @ nin[wk]) < 0.5)
            acc["jamb"].append((flat[rec & (g <= deep_min) & across], None))
            acc["deep"].append((flat[rec & (g > deep_min)], None))
            acc["recess_sum"].append((flat[rec], g[rec]))
            acc["through"].append((flat[g > recess_max], None))
        if progress is not None:
            progress(fi + 1, len(frames))
    for name, parts in acc.items():
        if not parts:
            continue
        flat = np.concatenate([p[0] for p in parts])
        weights = None if parts[0][1] is None else np.concatenate([p[1] for p in parts])
        grids.add(name, flat, weights)


def _edge(gx: np.ndarray, gy: np.ndarray, vp: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """:func:`oriented_edges` on precomputed gradients of the selected pixels."""
    d = vp[:2][None, :] - vp[2] * uv
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    along = np.abs(gx * d[:, 0] + gy * d[:, 1])
    across = np.abs(-gx * d[:, 1] + gy * d[:, 0])
    return np.maximum(across - along, 0.0)


def accumulate_bright(
    grids: WallGrids,
    xyz: np.ndarray,
    luminance: np.ndarray,
    vertex_wall: np.ndarray,
    factor: float = 8.0,
) -> float:
    """Count, per wall cell, the vertices far brighter than the walls (windows in HDR).

    A vertex is bright when its luminance exceeds ``factor`` times the median luminance of
    the wall vertices. Returns the threshold used.
    """
    on_wall = vertex_wall >= 0
    if not on_wall.any():
        return float("inf")
    ref = float(np.median(luminance[on_wall]))
    thr = factor * max(ref, 1e-12)
    sel = on_wall & (luminance > thr)
    if sel.any():
        a, t, _, _ = wall_frames(grids.walls)
        kw = vertex_wall[sel]
        s = np.einsum("ij,ij->i", xyz[sel, :2] - a[kw], t[kw])
        flat, ok = grids.cell_index(kw, s, xyz[sel, 2])
        grids.add("bright", flat[ok])
    return thr
