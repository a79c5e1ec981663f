"""Batched ray casting against a triangle mesh, with Embree (via embreex) or Mitsuba.

Precision and offsets
---------------------
Both backends trace in float32. To keep that precision where it matters, the
mesh is translated so that its bounding box is centred on the origin before it
is handed to the backend, and every ray origin is translated the same way (in
float64); hit distances do not change under translation, and hit points are
recomputed in float64 from the caller's origins.

embreex always starts rays at distance 0 (``tnear`` is not exposed), and in
Embree's robust mode a ray that starts on a surface hits it at ``t = 0`` (in
the default mode it usually does not, but only by luck of rounding). :meth:`RayCaster.intersect` and :meth:`RayCaster.occluded` therefore
take a ``tmin`` which is applied by moving the origin ``tmin`` along the
(normalised) direction; the distances they report are still measured from the
caller's origin. :meth:`RayCaster.visible_points` offsets the start point along
the surface normal instead (see there), which unlike a step along the ray also
works for rays that leave the surface at a grazing angle.

The default offset, :attr:`RayCaster.eps`, is ``1e-4`` times the bounding-box
diagonal: 0.7 mm for a 5 x 4 x 2.5 m room, some thousand times the float32
rounding error of coordinates of that size (about 2e-7 m at 3 m).

Embree is not perfectly watertight, even in robust mode: a ray through a
shared vertex or edge can, rarely, pass between the triangles (6 of 1464 rays
aimed exactly at the vertices of an icosphere miss; 365 without robust mode).
Visibility through a closed mesh can therefore leak along such rays.

Threads
-------
embreex releases the GIL while it traces, so large batches are cut into
chunks that run on a :class:`~concurrent.futures.ThreadPoolExecutor`
(``os.cpu_count()`` workers by default). Each chunk is traced with the same
committed scene, which Embree allows from any number of threads; results do
not depend on the chunking. The Mitsuba backend parallelises internally
(Dr.Jit's own thread pool) and is always driven from one Python thread.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import cached_property
from typing import Literal

import numpy as np
import trimesh
from numpy.typing import ArrayLike

from reroom.errors import ReroomError

__all__ = ["Hits", "RayCaster"]

Backend = Literal["embree", "mitsuba"]

#: Default self-intersection offset, relative to the mesh's bounding-box diagonal.
EPS_REL = 1e-4
#: Rays per chunk handed to one worker thread (see benchmarks/bench_rays.py).
DEFAULT_CHUNK = 1 << 16


@dataclass(frozen=True)
class Hits:
    """Closest hits of a batch of ``N`` rays.

    Attributes
    ----------
    t:
        ``(N,)`` float64 distance from the ray origin along the unit direction
        (metres); ``inf`` where the ray missed.
    face:
        ``(N,)`` int64 index of the triangle hit; ``-1`` where missed.
    hit:
        ``(N,)`` bool, ``face >= 0``.
    points:
        ``(N, 3)`` float64 hit points ``origin + t * direction``; NaN where missed.
    uv:
        ``(N, 2)`` float64 barycentric coordinates ``(u, v)`` of the hit in its
        triangle ``(v0, v1, v2)``: the point is ``(1 - u - v) v0 + u v1 + v v2``.
        NaN where missed.
    face_normals:
        ``(F, 3)`` unit normals of the mesh's faces, from which :attr:`normals`
        is looked up on first use.
    """

    t: np.ndarray
    face: np.ndarray
    hit: np.ndarray
    points: np.ndarray
    uv: np.ndarray
    face_normals: np.ndarray = field(repr=False, compare=False)

    def __len__(self) -> int:
        return len(self.t)

    @cached_property
    def normals(self) -> np.ndarray:
        """``(N, 3)`` float64 unit geometric normals of the faces hit; NaN where missed.

        They follow the face winding (right-hand rule), not the ray: flip them
        where ``dot(normal, direction) > 0`` for the side the ray arrived from.
        Computed on first access, as most callers never need them.
        """
        out = np.take(self.face_normals, self.face, axis=0, mode="clip")
        out[~self.hit] = np.nan
        return out

    @property
    def barycentric(self) -> np.ndarray:
        """``(N, 3)`` weights ``(1 - u - v, u, v)`` of the hit face's three vertices."""
        u, v = self.uv[:, 0], self.uv[:, 1]
        return np.stack([1.0 - u - v, u, v], axis=1)


def _as_rays(name: str, a: ArrayLike) -> np.ndarray:
    """``a`` as a float64 ``(N, 3)`` (or ``(3,)``) array, checked to be finite."""
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim not in (1, 2) or arr.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (N, 3) or (3,), got {arr.shape}")
    finite = np.isfinite(arr)
    if not finite.all():
        rows = np.flatnonzero(~finite.reshape(-1, 3).all(axis=1))
        raise ValueError(
            f"{name} contain non-finite values (NaN or inf) in {len(rows)} rows, "
            f"first at row {int(rows[0])}"
        )
    return arr


def _broadcast_rays(
    origins: ArrayLike, directions: ArrayLike
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validate and broadcast rays; returns ``(origins, unit_directions, norms)``, all ``(N, ...)``."""
    o = _as_rays("origins", origins)
    d = _as_rays("directions", directions)
    try:
        o, d = np.broadcast_arrays(np.atleast_2d(o), np.atleast_2d(d))
    except ValueError:
        raise ValueError(
            f"origins {np.shape(origins)} and directions {np.shape(directions)} do not broadcast"
        ) from None
    norm = np.sqrt(np.einsum("ij,ij->i", d, d))
    zero = norm == 0.0
    if zero.any():
        raise ValueError(
            f"directions contain {int(np.count_nonzero(zero))} zero-length vectors, "
            f"first at row {int(np.flatnonzero(zero)[0])}"
        )
    return o, d / norm[:, None], norm


def _ray_interval(name: str, value: ArrayLike, n: int) -> np.ndarray:
    """A per-ray float64 bound (``tmin`` or ``tmax``), broadcast to ``(n,)``."""
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim > 1 or (arr.ndim == 1 and len(arr) not in (1, n)):
        raise ValueError(f"{name} must be a scalar or have shape ({n},), got {arr.shape}")
    if np.isnan(arr).any():
        raise ValueError(f"{name} contains NaN")
    if (arr < 0).any():
        raise ValueError(f"{name} must be non-negative")
    return np.broadcast_to(arr, (n,))


def _face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    tri = vertices[faces]
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(nrm, axis=1, keepdims=True)
    # Zero-area faces keep a zero normal; Embree never reports hits on them.
    return np.divide(nrm, length, out=np.zeros_like(nrm), where=length > 0)


class _EmbreeBackend:
    """One committed embreex scene; its queries are thread-safe once committed."""

    parallel = True

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, robust: bool) -> None:
        from embreex import mesh_construction, rtcore_scene

        self.scene = rtcore_scene.EmbreeScene(robust=robust)
        # The mesh object must outlive the scene's use of it; keep a reference.
        self.mesh = mesh_construction.TriangleMesh(
            self.scene, np.ascontiguousarray(vertices, np.float32), np.ascontiguousarray(faces)
        )
        # embreex commits lazily inside the first run() and guards that with a plain
        # flag, so two threads making the first query could commit twice: commit now.
        one = np.zeros((1, 3), np.float32)
        self.scene.run(one, one + np.float32(1.0), dists=np.ones(1, np.float32))

    def intersect(
        self, o: np.ndarray, d: np.ndarray, tfar: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """float32 ``(t, u, v)`` and int ``face`` (-1 on a miss) of the closest hits."""
        # run() writes the hit distances into `dists` in place: tfar is a private buffer.
        r = self.scene.run(o, d, dists=tfar, output=1)
        return r["tfar"], r["primID"], r["u"], r["v"]

    def occluded(self, o: np.ndarray, d: np.ndarray, tfar: np.ndarray) -> np.ndarray:
        # For OCCLUDED queries embreex returns geomID 0 (our only mesh) or -1.
        return self.scene.run(o, d, dists=tfar, query="OCCLUDED") != -1


class _MitsubaBackend:
    """A Mitsuba scene holding the mesh; Dr.Jit parallelises each query itself."""

    parallel = False

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        from reroom.render import mitsuba

        mi = mitsuba()
        if mi.variant().startswith("scalar"):
            # scalar_rgb has no vectorised queries; tracing ray by ray in Python is useless.
            raise ReroomError(
                f"the Mitsuba ray backend needs a vectorised (llvm) variant, not "
                f"{mi.variant()}; use backend='embree'"
            )
        self.mi = mi
        mesh = mi.Mesh(
            "reroom_rays",
            len(vertices),
            len(faces),
            has_vertex_normals=False,
            has_vertex_texcoords=False,
        )
        params = mi.traverse(mesh)
        params["vertex_positions"] = mi.Float(np.ascontiguousarray(vertices, np.float32).ravel())
        params["faces"] = mi.UInt32(np.ascontiguousarray(faces, np.uint32).ravel())
        params.update()
        self.scene = mi.load_dict({"type": "scene", "mesh": mesh})
        # Dr.Jit's tracing state is per thread but its JIT cache is not documented as
        # safe to share; RayCaster never calls in parallel, and the lock covers callers
        # who share one caster between their own threads.
        self.lock = threading.Lock()

    def _rays(self, o: np.ndarray, d: np.ndarray, tfar: np.ndarray):
        mi = self.mi
        # Mitsuba's maxt must be finite: inf becomes the largest float32.
        maxt = np.minimum(tfar, np.finfo(np.float32).max)
        return mi.Ray3f(
            mi.Point3f(o[:, 0], o[:, 1], o[:, 2]),
            mi.Vector3f(d[:, 0], d[:, 1], d[:, 2]),
            mi.Float(maxt),
            mi.Float(0.0),
            [],
        )

    def intersect(
        self, o: np.ndarray, d: np.ndarray, tfar: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        with self.lock:
            pi = self.scene.ray_intersect_preliminary(self._rays(o, d, tfar), coherent=False)
            valid = np.asarray(pi.is_valid(), dtype=bool)
            prim = np.where(valid, np.asarray(pi.prim_index).astype(np.int64), -1)
            uv = np.asarray(pi.prim_uv, dtype=np.float32)
            return np.asarray(pi.t, dtype=np.float32), prim, uv[0], uv[1]

    def occluded(self, o: np.ndarray, d: np.ndarray, tfar: np.ndarray) -> np.ndarray:
        with self.lock:
            hit = self.scene.ray_test(self._rays(o, d, tfar), coherent=False)
            return np.asarray(hit, dtype=bool)


class RayCaster:
    """Closest-hit, occlusion and visibility queries against one triangle mesh.

    Parameters
    ----------
    mesh:
        A :class:`trimesh.Trimesh`, or an ``(V, 3)`` vertex array when ``faces``
        is given.
    faces:
        ``(F, 3)`` vertex indices, when ``mesh`` is a vertex array.
    backend:
        ``"embree"`` (embreex, multi-threaded here) or ``"mitsuba"`` (Mitsuba 3's
        ``llvm_ad_rgb`` variant, see :func:`reroom.render.mitsuba`).
    threads:
        Worker threads for the Embree backend; ``None`` means ``os.cpu_count()``.
    chunk_size:
        Rays per work item. Batches no larger than this run in the calling thread.
    robust:
        Use Embree's robust traversal, so that rays through a shared edge or vertex
        very rarely slip between two triangles (see the module notes). It costs
        about 5-10 % in speed.
    eps:
        Self-intersection offset in metres; default ``1e-4`` times the bounding-box
        diagonal.

    Raises
    ------
    ReroomError
        If the mesh has no faces or vertices, its vertices are not finite, or a
        face index is out of range.
    """

    def __init__(
        self,
        mesh: trimesh.Trimesh | ArrayLike,
        faces: ArrayLike | None = None,
        *,
        backend: Backend = "embree",
        threads: int | None = None,
        chunk_size: int = DEFAULT_CHUNK,
        robust: bool = True,
        eps: float | None = None,
    ) -> None:
        if isinstance(mesh, trimesh.Trimesh):
            if faces is not None:
                raise ValueError("pass either a Trimesh or vertices and faces, not both")
            vertices, faces = mesh.vertices, mesh.faces
        else:
            if faces is None:
                raise ValueError("faces are required when mesh is a vertex array")
            vertices = mesh
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces)
        if v.size == 0:
            v = v.reshape(0, 3)
        if v.ndim != 2 or v.shape[1] != 3:
            raise ReroomError(f"vertices must be a (V, 3) array, got shape {v.shape}")
        if f.size == 0 or len(v) == 0:
            raise ReroomError(
                f"cannot cast rays at an empty mesh ({len(v)} vertices, {f.size // 3} faces)"
            )
        if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
            raise ReroomError(f"faces must be an (F, 3) integer array, got {f.dtype} {f.shape}")
        if not np.isfinite(v).all():
            raise ReroomError("mesh vertices contain non-finite coordinates")
        if f.min() < 0 or f.max() >= len(v):
            raise ReroomError(
                f"face indices must lie in [0, {len(v)}), found [{f.min()}, {f.max()}]"
            )
        if backend not in ("embree", "mitsuba"):
            raise ValueError(f"backend must be 'embree' or 'mitsuba', not {backend!r}")
        if chunk_size < 1:
            raise ValueError(f"chunk_size must be positive, got {chunk_size}")

        self.vertices = v
        self.faces = f.astype(np.int64)
        self.face_normals = _face_normals(v, self.faces)
        lo, hi = v.min(axis=0), v.max(axis=0)
        self.center = (lo + hi) / 2.0
        diag = float(np.linalg.norm(hi - lo))
        #: Bounding-box diagonal, metres (1.0 for a mesh squashed to a point).
        self.scale = diag if diag > 0 else 1.0
        self.eps = float(eps) if eps is not None else EPS_REL * self.scale
        self.backend = backend
        self.threads = max(1, threads if threads is not None else (os.cpu_count() or 1))
        self.chunk_size = int(chunk_size)

        local = v - self.center
        if backend == "embree":
            self._backend: _EmbreeBackend | _MitsubaBackend = _EmbreeBackend(
                local, f.astype(np.int32), robust
            )
        else:
            self._backend = _MitsubaBackend(local, f)

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    # -- plumbing ---------------------------------------------------------------------------

    def _map_chunks(self, n: int, work: Callable[[int, int], None]) -> None:
        """Call ``work(start, stop)`` over ``[0, n)`` in chunks, on threads where that helps."""
        if self._backend.parallel:
            size = self.chunk_size
        else:
            # One big call per few million rays: Dr.Jit parallelises, and capping the
            # batch only bounds its memory.
            size = max(self.chunk_size, 1 << 22)
        bounds = [(s, min(s + size, n)) for s in range(0, n, size)]
        if len(bounds) <= 1 or self.threads == 1 or not self._backend.parallel:
            for s, e in bounds:
                work(s, e)
            return
        with ThreadPoolExecutor(max_workers=min(self.threads, len(bounds))) as pool:
            # list() re-raises the first exception of any chunk.
            list(pool.map(lambda b: work(*b), bounds))

    def _local_rays(
        self, o: np.ndarray, d: np.ndarray, tmin: np.ndarray, tmax: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """float32 origins (moved by tmin, in the centred frame), directions and ray lengths."""
        if tmin.any():
            o = o + tmin[:, None] * d
        # Subtract in float64 and round once into a float32 `out`. (Passing
        # dtype=float32 instead would round the inputs first and lose the point of
        # centring: 8 mm steps at 1e5 m.)
        o32 = np.empty(o.shape, np.float32)
        np.subtract(o, self.center, out=o32, casting="unsafe")
        d32 = d.astype(np.float32)
        with np.errstate(over="ignore"):  # a finite tmax beyond float32 range becomes inf
            tfar = (tmax - tmin).astype(np.float32)
        return o32, d32, tfar

    # -- queries ----------------------------------------------------------------------------

    def intersect(
        self,
        origins: ArrayLike,
        directions: ArrayLike,
        tmin: ArrayLike = 0.0,
        tmax: ArrayLike = np.inf,
    ) -> Hits:
        """Closest hit of each ray within ``[tmin, tmax]``.

        Parameters
        ----------
        origins, directions:
            ``(N, 3)`` arrays, or ``(3,)`` to share one origin or direction between
            all rays. Directions need not be unit length; they are normalised, and
            all distances are in metres.
        tmin, tmax:
            Scalars or ``(N,)`` arrays. A hit closer than ``tmin`` is ignored (use
            ``tmin=caster.eps`` for rays leaving a surface).

        Returns
        -------
        Hits

        Raises
        ------
        ValueError
            On non-finite origins or directions, zero-length directions, shapes
            that do not broadcast, or a negative or NaN ``tmin``/``tmax``.
        """
        o, d, _ = _broadcast_rays(origins, directions)
        n = len(o)
        lo = _ray_interval("tmin", tmin, n)
        hi = _ray_interval("tmax", tmax, n)
        if (hi < lo).any():
            raise ValueError("tmax must not be smaller than tmin")

        t = np.empty(n)
        face = np.empty(n, dtype=np.int64)
        uv = np.empty((n, 2))
        points = np.empty((n, 3))

        def work(s: int, e: int) -> None:
            o32, d32, tfar = self._local_rays(o[s:e], d[s:e], lo[s:e], hi[s:e])
            tt, prim, u, v = self._backend.intersect(o32, d32, tfar)
            miss = prim < 0
            # Whole-slice writes, then patch the misses: in rooms nearly every ray hits,
            # and fancy-indexed scatters of the hits cost more than the tracing.
            ts = t[s:e]
            np.add(tt, lo[s:e], out=ts)
            ts[miss] = np.inf
            face[s:e] = prim
            uv[s:e, 0] = u
            uv[s:e, 1] = v
            uv[s:e][miss] = np.nan
            ps = points[s:e]
            with np.errstate(invalid="ignore"):  # inf * 0 on misses, overwritten below
                np.multiply(d[s:e], ts[:, None], out=ps)
            ps += o[s:e]
            ps[miss] = np.nan

        self._map_chunks(n, work)
        return Hits(
            t=t, face=face, hit=face >= 0, points=points, uv=uv, face_normals=self.face_normals
        )

    def occluded(
        self,
        origins: ArrayLike,
        directions: ArrayLike,
        tmax: ArrayLike = np.inf,
        tmin: ArrayLike = 0.0,
    ) -> np.ndarray:
        """Whether each ray hits anything within ``[tmin, tmax]`` (Embree's occlusion query).

        Arguments as for :meth:`intersect`; returns an ``(N,)`` bool array. This is
        cheaper than :meth:`intersect` because traversal stops at the first hit.
        """
        o, d, _ = _broadcast_rays(origins, directions)
        n = len(o)
        lo = _ray_interval("tmin", tmin, n)
        hi = _ray_interval("tmax", tmax, n)
        if (hi < lo).any():
            raise ValueError("tmax must not be smaller than tmin")
        out = np.zeros(n, dtype=bool)

        def work(s: int, e: int) -> None:
            o32, d32, tfar = self._local_rays(o[s:e], d[s:e], lo[s:e], hi[s:e])
            out[s:e] = self._backend.occluded(o32, d32, tfar)

        self._map_chunks(n, work)
        return out

    def visible_points(
        self,
        points: ArrayLike,
        normals: ArrayLike | None,
        targets: ArrayLike,
        *,
        offset: float | None = None,
        require_facing: bool = True,
    ) -> np.ndarray:
        """Whether the segment from each surface point to its target is unobstructed.

        Typical uses: which mesh vertices a camera centre sees, which are lit by a
        point light.

        Parameters
        ----------
        points:
            ``(N, 3)`` points on (or near) the mesh surface.
        normals:
            ``(N, 3)`` surface normals at the points (need not be unit length), or
            None. With normals, each segment starts at ``point + offset * n``, which
            keeps it clear of the point's own surface even when it leaves at a
            grazing angle. Without them it starts ``offset`` along the segment.
        targets:
            ``(3,)`` for one target shared by all points (a camera centre, a light),
            or ``(N, 3)`` for one target per point.
        offset:
            Offset in metres at the start, and also how far short of the target
            the segment stops (so that a target lying on a surface does not hide
            itself); default :attr:`eps`.
        require_facing:
            With normals, count points whose normal faces away from their target
            (``dot(n, target - point) <= 0``) as not visible, without casting.

        Returns
        -------
        ``(N,)`` bool array. A point closer to its target than ``2 * offset`` is
        visible.

        Raises
        ------
        ValueError
            On non-finite inputs, zero normals, or shapes that do not match.
        """
        p = np.atleast_2d(_as_rays("points", points))
        tgt = np.atleast_2d(_as_rays("targets", targets))
        if len(tgt) not in (1, len(p)):
            raise ValueError(
                f"targets must have shape (3,) or ({len(p)}, 3), got {np.shape(targets)}"
            )
        tgt = np.broadcast_to(tgt, p.shape)
        off = self.eps if offset is None else float(offset)
        if not off >= 0:
            raise ValueError(f"offset must be non-negative, got {offset}")

        visible = np.ones(len(p), dtype=bool)
        start = p
        if normals is not None:
            nrm = np.atleast_2d(_as_rays("normals", normals))
            if nrm.shape != p.shape:
                raise ValueError(f"normals must have shape {p.shape}, got {nrm.shape}")
            length = np.linalg.norm(nrm, axis=1)
            if np.any(length == 0):
                raise ValueError(
                    f"normals contain {int(np.count_nonzero(length == 0))} zero vectors"
                )
            nrm = nrm / length[:, None]
            if require_facing:
                visible &= np.einsum("ij,ij->i", nrm, tgt - p) > 0
            start = p + off * nrm
            step_along = 0.0
        else:
            step_along = off

        seg = tgt - start
        dist = np.linalg.norm(seg, axis=1)
        cast = visible & (dist > 2.0 * off)
        idx = np.flatnonzero(cast)
        if len(idx):
            blocked = self.occluded(
                start[idx], seg[idx], tmax=dist[idx] - off, tmin=np.minimum(step_along, dist[idx])
            )
            visible[idx[blocked]] = False
        return visible

    def visibility_matrix(
        self,
        points: ArrayLike,
        normals: ArrayLike | None,
        targets: ArrayLike,
        *,
        offset: float | None = None,
        require_facing: bool = True,
    ) -> np.ndarray:
        """:meth:`visible_points` for every pair of ``(N, 3)`` points and ``(K, 3)`` targets.

        Returns an ``(N, K)`` bool array; column ``k`` is
        ``visible_points(points, normals, targets[k])``.
        """
        tgt = np.atleast_2d(_as_rays("targets", targets))
        p = np.atleast_2d(np.asarray(points, dtype=np.float64))
        out = np.zeros((len(p), len(tgt)), dtype=bool)
        for k, target in enumerate(tgt):
            out[:, k] = self.visible_points(
                p, normals, target, offset=offset, require_facing=require_facing
            )
        return out
