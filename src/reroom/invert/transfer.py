"""Light transport at mesh vertices: incident indirect light and basis-light transfer.

Thesis ch. 5 (eq. 5.1-5.12). For a diffuse vertex ``V`` of reflectance ``rho``,

    L_V = rho / pi * (E_indirect(V) + sum_l F_l(V) . I_l)

where ``E_indirect = integral L(w) cos dw`` over the hemisphere directions that hit
observed, non-emitting surfaces (``L`` = the radiance those surfaces show, as
``hdr_mesh.ply`` stores it) and ``F_l(V)`` is the irradiance at ``V`` per unit
intensity of each basis light of light ``l``. The thesis rasterised a 500 x 500
hemicube per vertex; :func:`hemisphere_transfer` casts stratified cosine-weighted
rays instead (``sample_hemisphere``), so every integral ``integral f cos dw`` is
estimated as ``pi / R * sum f`` over the ``R`` rays of a vertex.

Units and conventions
---------------------
* ``radiance`` is what ``hdr_mesh.ply`` stores (``radiance_r/g/b``, linear, the
  scan's relative units); ``indirect`` is irradiance in the same units times sr.
* Area lights: ``area[:, k]`` is ``integral cos dw`` over the rays that hit
  light ``k``'s surface, i.e. the irradiance per unit *radiance* of the light.
* Distant light: ``distant[:, w, j] = integral basis_j(w) cos dw`` over rays that
  leave through window ``w``, the irradiance per unit radiance of basis
  function ``j`` (one cube-map cell, or one spherical harmonic).
* Point and line lights (:mod:`reroom.invert.direct`): per unit radiant
  intensity (W/sr-like) of each inclination bin, ``I cos / d^2``.

How a ray is classified
-----------------------
1. It leaves through window ``w`` if it crosses ``w``'s rectangle (grown by
   ``window_tolerance``) before it hits anything -- a hole or a glazed pane alike.
2. Otherwise, a miss (a hole in the scan that is not a window) and a hit on a
   back face (inside furniture, behind a wall: the mesh's winding says which side
   is outside) are *unobserved*: they carry unknown light, not black.
3. A front-face hit is split between the hit triangle's three vertices by its
   barycentric weights ``b_k``, and each share goes to that vertex's class: a
   window surface (distant light of that window, in the ray's direction), area
   light ``k``, an observed surface (adds ``b_k L_k`` to ``E_indirect``), or an
   unobserved vertex (adds ``b_k`` to ``p_unobserved``). So the radiance at a hit
   is interpolated from the triangle's observed vertices only, and a triangle
   with unobserved vertices counts as observed for the share of its observed
   ones; eq. 5.9 (:meth:`HemisphereTransfer.indirect_rescaled`) then fills in
   the unobserved share with the mean of the observed one. Splitting shares
   rather than rounding to the nearest vertex keeps the estimates smooth, and
   makes a light's surface end half-way into the triangles along its rim.

Origins are offset along the vertex normal by ``offset`` times the vertex's mean
edge length (at least ``caster.eps``), which keeps rays from hitting the vertex's
own triangles. The offset lifts the receiver: a light at distance ``d`` is seen
about ``2 offset / d`` too bright, so the default is small (1 % of an edge: 0.3 mm
on a 2.6 cm scan mesh); 10 % of a 25 cm edge made a 1 m light 5 % too bright.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import trimesh

from reroom.errors import ReroomError
from reroom.invert import _kernels as K
from reroom.invert.area_region import AreaRegion
from reroom.invert.basis import CubemapBasis, SHBasis
from reroom.invert.direct import line_light_transfer, point_light_transfer
from reroom.invert.windows import WindowOpening
from reroom.rays import RayCaster, sample_hemisphere

__all__ = [
    "DEFAULT_RAYS_PER_VERTEX",
    "HemisphereTransfer",
    "WindowOpening",
    "hemisphere_transfer",
    "inset_points",
    "line_light_transfer",
    "mean_edge_lengths",
    "point_light_transfer",
]

#: Rays per vertex: chosen by ``benchmarks/bench_transfer.py`` (see ``docs/invert.md``).
DEFAULT_RAYS_PER_VERTEX = 128
#: Rays traced per call of the caster (bounded memory: about 400 bytes per ray).
BATCH_RAYS = 1 << 21


@dataclass
class HemisphereTransfer:
    """Per-vertex hemisphere integrals (see the module notes for units).

    Attributes
    ----------
    vertices:
        ``(n,)`` indices into the mesh of the receiving vertices.
    indirect:
        ``(n, 3)`` ``E_indirect = integral L cos dw`` over rays hitting observed,
        non-light surfaces.
    p_observed:
        ``(n,)`` cosine-weighted fraction of the hemisphere hitting observed
        non-light surfaces.
    p_unobserved:
        ``(n,)`` ... hitting unobserved vertices or back faces, or escaping through
        holes that are not windows.
    p_light:
        ``(n,)`` ... hitting area-light or window surfaces, or leaving through a
        window opening. The three fractions sum to 1.
    area:
        ``(n, n_area)`` ``integral cos dw`` over rays hitting area light ``k``.
    distant:
        ``(n, n_windows, basis.size)`` ``integral basis_j(w) cos dw`` over rays
        leaving through window ``w`` (``basis.size = 0`` without a basis).
    rays_per_vertex:
        Rays cast per vertex.
    """

    vertices: np.ndarray
    indirect: np.ndarray
    p_observed: np.ndarray
    p_unobserved: np.ndarray
    p_light: np.ndarray
    area: np.ndarray
    distant: np.ndarray
    rays_per_vertex: int

    def indirect_rescaled(self) -> np.ndarray:
        """Eq. 5.9: ``indirect * (p_observed + p_unobserved) / p_observed``.

        The unobserved part of the hemisphere is assumed to send, on average, the
        light the observed part sends. Where nothing observed was hit
        (``p_observed == 0``) the result is 0.
        """
        po = self.p_observed
        scale = np.divide(po + self.p_unobserved, po, out=np.zeros_like(po), where=po > 0)
        return self.indirect * scale[:, None]


def mean_edge_lengths(mesh: trimesh.Trimesh) -> np.ndarray:
    """``(V,)`` mean length of the edges at each vertex (0 for isolated vertices)."""
    edges = np.asarray(mesh.edges_unique, dtype=np.int64)
    length = np.asarray(mesh.edges_unique_length, dtype=np.float64)
    nv = len(mesh.vertices)
    total = np.bincount(edges.ravel(), np.repeat(length, 2), minlength=nv)
    count = np.bincount(edges.ravel(), minlength=nv)
    return np.divide(total, count, out=np.zeros(nv), where=count > 0)


def inset_points(
    mesh: trimesh.Trimesh,
    vertices: np.ndarray,
    normals: np.ndarray,
    inset: float = 0.25,
) -> np.ndarray:
    """Receiving points moved a little into their own surface, away from its boundary.

    A vertex on the border of a surface -- where a scanned wall meets the ceiling, or
    the seam between two parts of a mesh -- lies *in the plane* of the neighbouring
    surface: a ray leaving it sideways starts on that surface and is "occluded" at
    distance 0, so its shadow rays see no light and half its hemisphere is wrongly
    blocked. The photo of that spot shows the lit surface a hair away from the edge, so
    the transfer is computed there instead: each point moves towards the area-weighted
    centroid of its one-ring, in its tangent plane, by ``inset`` times its mean edge
    length at most (and never past the centroid). Interior vertices of a regular mesh
    have their centroid on themselves and do not move.

    Parameters
    ----------
    mesh:
        The scan mesh.
    vertices:
        ``(n,)`` vertex indices.
    normals:
        ``(n, 3)`` unit normals of those vertices.
    inset:
        Largest move, as a fraction of the vertex's mean edge length.

    Returns
    -------
    ``(n, 3)`` points.
    """
    recv = np.asarray(vertices, dtype=np.int64).ravel()
    pts = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    nrm = np.asarray(normals, dtype=np.float64)
    if inset <= 0 or len(faces) == 0:
        return pts[recv].copy()
    tri = pts[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    centre = tri.mean(axis=1) * area[:, None]
    nv = len(pts)
    weight = np.bincount(faces.ravel(), np.repeat(area, 3), minlength=nv)
    acc = np.stack(
        [np.bincount(faces.ravel(), np.repeat(centre[:, k], 3), minlength=nv) for k in range(3)],
        axis=1,
    )
    p = pts[recv]
    w = weight[recv]
    ring = np.divide(acc[recv], w[:, None], out=p.copy(), where=w[:, None] > 0)
    move = ring - p
    move -= np.sum(move * nrm, axis=1, keepdims=True) * nrm
    length = np.linalg.norm(move, axis=1)
    limit = inset * mean_edge_lengths(mesh)[recv]
    scale = np.divide(
        np.minimum(length, limit), length, out=np.zeros_like(length), where=length > 0
    )
    return p + move * scale[:, None]


def _per_vertex(name: str, a: np.ndarray, nv: int, shape: tuple[int, ...]) -> np.ndarray:
    arr = np.asarray(a)
    if arr.shape != (nv, *shape):
        raise ReroomError(
            f"{name} must have shape {(nv, *shape)} (one per mesh vertex), got {arr.shape}"
        )
    return arr


def _grid_shape(n: int) -> tuple[int, int] | None:
    """A near-square ``nx * ny == n`` jitter grid (as :func:`reroom.rays.sample_hemisphere`)."""
    nx = math.isqrt(n)
    while n % nx:
        nx -= 1
    return (nx, n // nx) if n // nx <= 2 * nx else None


def _window_arrays(windows: list[WindowOpening]) -> tuple[np.ndarray, ...]:
    """Window rectangles as arrays for the kernel: centre, unit axes, half lengths, normal."""
    w = len(windows)
    centre, u, v, normal = (np.zeros((w, 3)) for _ in range(4))
    hu, hv = np.zeros(w), np.zeros(w)
    for i, win in enumerate(windows):
        hu[i], hv[i] = np.linalg.norm(win.half_u), np.linalg.norm(win.half_v)
        centre[i], normal[i] = win.centre, win.normal
        u[i], v[i] = win.half_u / hu[i], win.half_v / hv[i]
    return centre, u, v, hu, hv, normal


def _region_arrays(
    regions: Sequence[AreaRegion | None] | None, n_area: int
) -> tuple[np.ndarray, ...]:
    """Area-light outlines as arrays for the kernel: origin, plane axes, padded
    counter-clockwise polygon, corner count (0 where a light has no outline)."""
    regions = list(regions or [])[:n_area]
    n = max(n_area, 1)
    k = max([len(r.polygon) for r in regions if r is not None] + [1])
    origin, u, v = (np.zeros((n, 3)) for _ in range(3))
    poly = np.zeros((n, k, 2))
    count = np.zeros(n, np.int64)
    for i, reg in enumerate(regions):
        if reg is None:
            continue
        origin[i], u[i], v[i] = reg.origin, reg.u, reg.v
        poly[i, : len(reg.polygon)] = reg.polygon
        count[i] = len(reg.polygon)
    return origin, u, v, poly, count


def _distant_sums(
    basis: CubemapBasis | SHBasis,
    nb: int,
    n_win: int,
    rays: int,
    dirs: np.ndarray,
    through: np.ndarray,
    pane: np.ndarray,
    hits,
    faces: np.ndarray,
    win_of: np.ndarray,
) -> np.ndarray:
    """``(nb, n_win, size)`` raw sums of ``basis_j(direction)`` over window rays and pane shares."""
    owner = np.arange(len(dirs)) // rays
    sel = np.flatnonzero(through >= 0)
    parts_owner, parts_win, parts_dir, parts_w = (
        [owner[sel]],
        [through[sel]],
        [dirs[sel]],
        [np.ones(len(sel))],
    )
    sel = np.flatnonzero(pane)
    if len(sel):
        corners = faces[hits.face[sel]]
        bary = hits.barycentric[sel]
        for k in range(3):
            w = win_of[corners[:, k]]
            on = w >= 0
            parts_owner.append(owner[sel[on]])
            parts_win.append(w[on])
            parts_dir.append(dirs[sel[on]])
            parts_w.append(bary[on, k])
    wo, wi = np.concatenate(parts_owner), np.concatenate(parts_win)
    wd, ww = np.concatenate(parts_dir), np.concatenate(parts_w)
    out = np.zeros((nb, n_win, basis.size))
    if len(wo) == 0:
        return out
    key = wo * n_win + wi
    if isinstance(basis, CubemapBasis):
        key = key * basis.size + basis.cell_of(wd)
        return np.bincount(key, ww, minlength=out.size).reshape(out.shape)
    values = basis.evaluate(wd) * ww[:, None]
    for j in range(basis.size):
        out[:, :, j] = np.bincount(key, values[:, j], minlength=nb * n_win).reshape(nb, n_win)
    return out


def hemisphere_transfer(
    caster: RayCaster,
    mesh: trimesh.Trimesh,
    vertices: np.ndarray,
    normals: np.ndarray,
    radiance: np.ndarray,
    observed: np.ndarray,
    area_light_of_vertex: np.ndarray,
    windows: list[WindowOpening],
    distant_basis: CubemapBasis | SHBasis | None,
    rays_per_vertex: int = DEFAULT_RAYS_PER_VERTEX,
    seed: int = 0,
    progress: Callable[[int, int], None] | None = None,
    *,
    window_of_vertex: np.ndarray | None = None,
    offset: float = 0.01,
    inset: float = 0.0,
    window_tolerance: float = 0.02,
    batch_rays: int = BATCH_RAYS,
    area_regions: Sequence[AreaRegion | None] | None = None,
) -> HemisphereTransfer:
    """Cast ``rays_per_vertex`` cosine-weighted rays from each vertex and integrate.

    Parameters
    ----------
    caster:
        A :class:`RayCaster` built on ``mesh``.
    mesh:
        The scan mesh (consistently wound: face normals point out of the surface).
    vertices:
        ``(n,)`` indices of the receiving vertices.
    normals:
        Vertex normals, ``(V, 3)`` for every mesh vertex (e.g.
        :func:`reroom.hdr.observe.vertex_normals`) or ``(n, 3)`` for the receiving
        vertices; an array of ``V`` rows is always read as per mesh vertex.
    radiance, observed:
        ``(V, 3)`` radiance and ``(V,)`` observed flag per mesh vertex (``hdr_mesh.ply``).
    area_light_of_vertex:
        ``(V,)`` int: ``k >= 0`` for the vertices of area light ``k``, -1 elsewhere.
    windows:
        Window openings (rays crossing them carry distant light).
    distant_basis:
        Basis of the distant light, or None to only count window rays in ``p_light``.
    rays_per_vertex:
        Rays per receiving vertex; the default is measured in ``docs/invert.md``.
    seed:
        Seed of the ray sampling.
    progress:
        Called as ``progress(done, total)`` with vertex counts after each batch.
    window_of_vertex:
        ``(V,)`` int: ``w >= 0`` for vertices on window ``w``'s surface (a glazed
        pane, a bright window region), -1 elsewhere; None: no such vertices.
    offset:
        Ray origins start ``offset`` times the vertex's mean edge length along its
        normal (at least ``caster.eps``).
    inset:
        Ray origins also move into their own surface by up to ``inset`` times the mean
        edge length, away from its border (:func:`inset_points`); 0: not at all.
    window_tolerance:
        Metres, see :func:`reroom.invert.windows.rays_through_windows`.
    batch_rays:
        Rays per caster call (memory bound, ~400 bytes per ray).
    area_regions:
        Per area light, its outline (:func:`reroom.invert.area_region.area_region`) or
        None. A hit on a triangle that touches an outlined light and has corners off it
        is the light's inside the outline and the off-light corners' surface outside it,
        as :func:`reroom.invert.area.area_light_transfer` integrates the light; without
        an outline the hit is shared between its corners' classes by barycentric weight.

    Returns
    -------
    HemisphereTransfer

    Raises
    ------
    ReroomError
        If an array does not have one entry per mesh vertex (or per receiver), a
        receiving vertex index is out of range or a receiving vertex has no normal
        (a vertex of no face: leave those out).
    """
    nv = len(mesh.vertices)
    recv = np.asarray(vertices, dtype=np.int64).ravel()
    if len(recv) and (recv.min() < 0 or recv.max() >= nv):
        raise ReroomError(f"receiving vertex indices must lie in [0, {nv})")
    nrm = np.asarray(normals, dtype=np.float64)
    if nrm.shape == (nv, 3):
        # Per mesh vertex (when n == V too: then receivers are usually all vertices).
        nrm = nrm[recv]
    elif nrm.shape != (len(recv), 3):
        raise ReroomError(f"normals must have shape ({len(recv)}, 3) or ({nv}, 3), got {nrm.shape}")
    length = np.linalg.norm(nrm, axis=1)
    if np.any(~(length > 0)):
        raise ReroomError(f"{int(np.sum(~(length > 0)))} receiving vertices have no normal")
    nrm = nrm / length[:, None]
    rad = _per_vertex("radiance", radiance, nv, (3,)).astype(np.float64)
    obs = _per_vertex("observed", observed, nv, ()).astype(bool)
    area_of = _per_vertex("area_light_of_vertex", area_light_of_vertex, nv, ()).astype(np.int64)
    win_of = (
        np.full(nv, -1, np.int64)
        if window_of_vertex is None
        else _per_vertex("window_of_vertex", window_of_vertex, nv, ()).astype(np.int64)
    )
    if rays_per_vertex < 1:
        raise ValueError(f"rays_per_vertex must be positive, got {rays_per_vertex}")
    n_area = int(area_of.max()) + 1 if nv else 0
    n_win = max(len(windows), int(win_of.max()) + 1 if nv else 0)
    nb_size = 0 if distant_basis is None else distant_basis.size

    # Per-vertex class of a hit corner: surfaces carry radiance only if observed, not lights.
    lit = (area_of < 0) & (win_of < 0)
    vdata = np.zeros((nv, 8))
    vdata[:, 3] = obs & lit
    vdata[:, 0:3] = rad * vdata[:, 3:4]
    vdata[:, 4] = ~obs & lit
    vdata[:, 5] = area_of
    vdata[:, 6] = win_of

    n = len(recv)
    R = int(rays_per_vertex)
    out_ind = np.zeros((n, 3))
    out_po = np.zeros(n)
    out_pu = np.zeros(n)
    out_pl = np.zeros(n)
    out_area = np.zeros((n, n_area))
    out_dist = np.zeros((n, n_win, nb_size))

    edge = mean_edge_lengths(mesh)[recv]
    base = inset_points(mesh, recv, nrm, inset) if inset > 0 else mesh.vertices[recv]
    starts = base + np.maximum(offset * edge, caster.eps)[:, None] * nrm
    faces = np.ascontiguousarray(mesh.faces, dtype=np.int32)
    face_normals = caster.face_normals
    rng = np.random.default_rng(seed)
    per_batch = max(1, int(batch_rays) // R)
    grid = _grid_shape(R)
    win_arrays = _window_arrays(windows)
    reg_arrays = _region_arrays(area_regions, n_area)

    for b0 in range(0, n, per_batch):
        b1 = min(n, b0 + per_batch)
        nb = b1 - b0
        if grid is not None:
            jitter = rng.random((nb * R, 2))
            org, dirs = K.hemisphere_rays(starts[b0:b1], nrm[b0:b1], grid[0], grid[1], jitter)
        else:  # R has no near-square grid: Latin hypercube sampling (slower, in numpy)
            dirs = sample_hemisphere(nrm[b0:b1], R, rng)[0].reshape(-1, 3)
            org = np.repeat(starts[b0:b1], R, axis=0)
        hits = caster.intersect(org, dirs)
        through = np.empty(len(dirs), np.int64)
        pane = np.empty(len(dirs), np.bool_)
        area_acc = np.zeros((nb, max(n_area, 1)))
        K.accumulate(
            R, org, dirs, hits.t, hits.face, hits.uv, faces, face_normals, vdata,
            *win_arrays, window_tolerance, *reg_arrays,
            out_ind[b0:b1], out_po[b0:b1], out_pu[b0:b1], out_pl[b0:b1], area_acc, through, pane,
        )  # fmt: skip
        out_area[b0:b1] = area_acc[:, :n_area]
        if distant_basis is not None and n_win:
            out_dist[b0:b1] = _distant_sums(
                distant_basis, nb, n_win, R, dirs, through, pane, hits, faces, win_of
            )
        if progress is not None:
            progress(b1, n)

    # Cosine-weighted sampling: integral f cos dw = pi * mean(f); fractions are plain means.
    scale = np.pi / R
    return HemisphereTransfer(
        vertices=recv,
        indirect=out_ind * scale,
        p_observed=out_po / R,
        p_unobserved=out_pu / R,
        p_light=out_pl / R,
        area=out_area * scale,
        distant=out_dist * scale,
        rays_per_vertex=R,
    )
