"""TSDF fusion (Open3D voxel-block grid) and ICP pose refinement for RGB-D captures."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from reroom.importers.capture_io import _nearest_rotation
from reroom.scan.camera import Intrinsics

ProgressFn = Callable[[int, int], None]


def _o3d():
    try:
        import open3d as o3d
    except ImportError as exc:  # pragma: no cover - depends on the machine
        raise ImportError(
            f"RGB-D import needs Open3D (pip install open3d-cpu); importing it failed: {exc}. "
            "On Debian, open3d also needs the system package libusb-1.0-0."
        ) from exc
    return o3d


def _clean_mesh(mesh: Any, min_component_fraction: float, min_component_triangles: int) -> Any:
    mesh.remove_degenerate_triangles()
    mesh.remove_duplicated_triangles()
    mesh.remove_duplicated_vertices()
    mesh.remove_unreferenced_vertices()
    if len(mesh.triangles) == 0:
        return mesh
    clusters, counts, _ = mesh.cluster_connected_triangles()
    clusters, counts = np.asarray(clusters), np.asarray(counts)
    keep_min = max(min_component_triangles, int(min_component_fraction * len(clusters)))
    small = counts[clusters] < keep_min
    if small.all():  # everything is small: keep the largest component at least
        small = clusters != int(np.argmax(counts))
    mesh.remove_triangles_by_mask(small)
    mesh.remove_unreferenced_vertices()
    # Cleaning can leave zero-area slivers whose vertices merged; drop them too.
    tris = np.asarray(mesh.triangles)
    verts = np.asarray(mesh.vertices)
    if len(tris):
        cross = np.cross(
            verts[tris[:, 1]] - verts[tris[:, 0]], verts[tris[:, 2]] - verts[tris[:, 0]]
        )
        zero = np.linalg.norm(cross, axis=1) < 1e-12
        if zero.any():
            mesh.remove_triangles_by_mask(zero)
            mesh.remove_unreferenced_vertices()
    return mesh


def canonical_order(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A fused mesh's vertices and faces in an order that depends only on the geometry.

    Open3D's voxel-block grid keeps its blocks in a hash map filled by several threads,
    so two fusions of the same frames list the same vertices in different orders (on a
    12-frame synthetic scan: all 164,822 vertices the same, 2 of 313,491 faces
    different, the order entirely different). Everything downstream that samples by
    index (the solve's seeded subset of receivers, the point-light fittings) then
    differs from run to run. Sorting fixes that: vertices lexicographically by their
    coordinates, each face rotated to start at its smallest index (the winding kept),
    faces lexicographically.

    Returns
    -------
    order, faces
        ``order`` (V,): the old index of each new vertex (``vertices[order]`` are the
        new vertices; per-vertex attributes are reordered the same way); ``faces``
        (F, 3): the faces on the new indices, in their new order.
    """
    vertices = np.asarray(vertices)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    order = np.lexsort(vertices.T[::-1])  # x first, then y, then z
    rank = np.empty(len(order), dtype=np.int64)
    rank[order] = np.arange(len(order))
    f = rank[faces]
    shift = np.argmin(f, axis=1)
    f = np.take_along_axis(f, (shift[:, None] + np.arange(3)) % 3, axis=1)
    f = f[np.lexsort(f.T[::-1])]
    return order, f


class TsdfFusion:
    """Colour TSDF fusion on Open3D's voxel-block grid (a sparse, hashed volume).

    This is Open3D's tensor pipeline (:class:`open3d.t.geometry.VoxelBlockGrid`),
    the successor of the legacy ``ScalableTSDFVolume``; the legacy class
    integrates but extracts an empty mesh in the ``open3d-cpu`` 0.20 wheel used
    here, so it is not used.

    Depth is given as uint16 millimetres, colour as ``(H, W, 3)`` uint8, poses
    as camera-to-world in OpenCV axes.
    """

    def __init__(
        self,
        intrinsics: Intrinsics,
        voxel_size: float,
        sdf_trunc: float,
        depth_trunc: float,
        *,
        block_resolution: int = 8,
        initial_blocks: int = 4000,
    ) -> None:
        o3d = _o3d()
        import open3d.core as o3c

        self._o3d, self._o3c = o3d, o3c
        self.device = o3c.Device("CPU:0")
        self.voxel_size = float(voxel_size)
        self.trunc_multiplier = float(sdf_trunc) / float(voxel_size)
        self.depth_trunc = float(depth_trunc)
        self.intrinsics = intrinsics
        # The intrinsics go in as they are, pixel centres at +0.5 as in reroom.
        # Open3D's integration projects a voxel and truncates its coordinate to
        # pick the depth pixel, so pixel k covers [k, k+1): reroom's convention.
        # (Shifting cx, cy by -0.5 put every fused surface half a pixel off: the
        # floor and ceiling 4 mm low at 320x180, 8 mm at 160x120, walls seen
        # edge-on unchanged; see test_fusion_puts_surfaces_where_the_depth_says.)
        k = np.array(
            [
                [intrinsics.fx, 0.0, intrinsics.cx],
                [0.0, intrinsics.fy, intrinsics.cy],
                [0.0, 0.0, 1.0],
            ]
        )
        self._k = o3c.Tensor(k, o3c.float64)
        # The hash map grows as needed; ``initial_blocks`` only sizes the first allocation.
        self.grid = o3d.t.geometry.VoxelBlockGrid(
            attr_names=("tsdf", "weight", "color"),
            attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
            attr_channels=((1), (1), (3)),
            voxel_size=self.voxel_size,
            block_resolution=int(block_resolution),
            block_count=int(initial_blocks),
            device=self.device,
        )

    @property
    def n_blocks(self) -> int:
        return int(self.grid.hashmap().size())

    def integrate(self, rgb: np.ndarray, depth_mm: np.ndarray, c2w_cv: np.ndarray) -> None:
        o3d, o3c = self._o3d, self._o3c
        depth = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(depth_mm, dtype=np.uint16)))
        color = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(rgb, dtype=np.uint8)))
        extrinsic = o3c.Tensor(np.linalg.inv(np.asarray(c2w_cv, dtype=np.float64)), o3c.float64)
        blocks = self.grid.compute_unique_block_coordinates(
            depth, self._k, extrinsic, 1000.0, self.depth_trunc, self.trunc_multiplier
        )
        self.grid.integrate(
            blocks,
            depth,
            color,
            self._k,
            self._k,
            extrinsic,
            1000.0,
            self.depth_trunc,
            self.trunc_multiplier,
        )

    def extract_mesh(self, min_observations: int = 1) -> Any:
        """The zero level set as a legacy ``open3d.geometry.TriangleMesh`` (colours 0..1).

        Only voxels fused from at least ``min_observations`` frames take part.
        """
        if self.n_blocks == 0:
            return self._o3d.geometry.TriangleMesh()
        mesh = self.grid.extract_triangle_mesh(weight_threshold=float(min_observations) - 0.5)
        return mesh.to_legacy()


class PoseRefiner:
    """Sequential point-to-plane ICP of each depth frame against the frames before it.

    Frame ``k``'s depth (up to ``max_depth``, down-sampled to ``voxel``) is
    aligned to a local model made of the last ``window`` aligned frames, in
    three passes (clouds thinned to 2, 2 and 1 voxel; correspondences within
    5, 2.5 and 1.25 voxels: 10, 5 and 2.5 cm at 2 cm) with a Tukey kernel. The search
    starts from the given pose carrying the previous frame's correction,
    because errors in an odometry-like trajectory are correlated.

    The alignment is rejected (the start pose is kept) when fewer than
    ``min_fitness`` of the frame's points find a partner within the last
    distance, when the matched surfaces leave a direction of translation
    unconstrained (``min_conditioning``, see :meth:`_conditioning`: a wall
    and the floor, a corridor), or when it moves the pose more than
    ``max_translation`` metres or ``max_rotation_deg`` degrees: ICP on little
    overlap or on degenerate geometry slides instead of locking.
    """

    def __init__(
        self,
        intrinsics: Intrinsics,
        *,
        voxel: float = 0.02,
        max_depth: float = 4.0,
        window: int = 3,
        min_fitness: float = 0.3,
        max_translation: float = 0.3,
        max_rotation_deg: float = 10.0,
        max_points: int = 6000,
        min_conditioning: float = 0.05,
    ) -> None:
        self.o3d = _o3d()
        self.max_points = int(max_points)
        self.min_conditioning = float(min_conditioning)
        self.intr = intrinsics
        self.voxel = float(voxel)
        self.max_depth = float(max_depth)
        self.window = int(window)
        self.min_fitness = float(min_fitness)
        self.max_translation = float(max_translation)
        self.max_rotation_deg = float(max_rotation_deg)
        self._recent: list[Any] = []  # world-space clouds of the last frames
        self._correction = np.eye(4)  # refined @ inv(given) of the previous frame
        self.frames: list[dict[str, Any]] = []

    def _points(self, depth_m: np.ndarray) -> Any:
        o3d, k = self.o3d, self.intr
        v, u = np.nonzero((depth_m > 0) & (depth_m < self.max_depth))
        z = depth_m[v, u].astype(np.float64)
        pts = np.stack([(u + 0.5 - k.cx) * z / k.fx, (v + 0.5 - k.cy) * z / k.fy, z], axis=1)
        return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))

    def _down(self, cloud: Any, voxel: float) -> Any:
        out = cloud.voxel_down_sample(voxel)
        out.estimate_normals(
            self.o3d.geometry.KDTreeSearchParamHybrid(radius=4.0 * voxel, max_nn=30)
        )
        return out

    def refine(self, depth_m: np.ndarray, c2w_cv: np.ndarray) -> np.ndarray:
        """Return the refined camera-to-world pose of the next frame (OpenCV axes)."""
        reg = self.o3d.pipelines.registration
        given = np.asarray(c2w_cv, dtype=np.float64)
        start = self._correction @ given
        raw = self._points(depth_m)
        record: dict[str, Any] = {"status": "first"}
        pose = start
        if self._recent and len(raw.points) >= 100:
            model_raw = self.o3d.geometry.PointCloud()
            for c in self._recent:
                model_raw += c
            t = start
            result = None
            # Coarse to fine: (cloud voxel, correspondence distance, iterations).
            for vox, dist, iters in (
                (2.0 * self.voxel, 5.0 * self.voxel, 20),
                (2.0 * self.voxel, 2.5 * self.voxel, 15),
                (self.voxel, 1.25 * self.voxel, 10),
            ):
                # Point-to-plane needs normals on the model only; a capped,
                # evenly thinned source keeps each pass cheap.
                src = raw.voxel_down_sample(vox)
                if len(src.points) > self.max_points:
                    src = src.uniform_down_sample(int(math.ceil(len(src.points) / self.max_points)))
                dst = self._down(model_raw, vox)
                result = reg.registration_icp(
                    src,
                    dst,
                    dist,
                    t,
                    reg.TransformationEstimationPointToPlane(reg.TukeyLoss(k=dist)),
                    reg.ICPConvergenceCriteria(max_iteration=iters),
                )
                t = result.transformation
            conditioning = self._conditioning(raw.voxel_down_sample(self.voxel), dst, t, dist)
            delta = t @ np.linalg.inv(start)
            move = float(np.linalg.norm(t[:3, 3] - start[:3, 3]))
            cos = (np.trace(delta[:3, :3]) - 1.0) / 2.0
            turn = math.degrees(math.acos(max(-1.0, min(1.0, cos))))
            ok = (
                result is not None
                and conditioning >= self.min_conditioning
                and result.fitness >= self.min_fitness
                and move <= self.max_translation
                and turn <= self.max_rotation_deg
            )
            if ok:
                pose = np.array(t)
                pose[:3, :3] = _nearest_rotation(pose[:3, :3])
            record = {
                "status": "refined" if ok else "rejected",
                "fitness": round(float(result.fitness), 4),
                "inlier_rmse_m": round(float(result.inlier_rmse), 5),
                "icp_move_m": round(move, 4),
                "icp_turn_deg": round(turn, 3),
                "conditioning": round(conditioning, 4),
            }
        total = pose @ np.linalg.inv(given)
        cos = (np.trace(total[:3, :3]) - 1.0) / 2.0
        record["change_from_given_m"] = round(float(np.linalg.norm(pose[:3, 3] - given[:3, 3])), 4)
        record["change_from_given_deg"] = round(
            math.degrees(math.acos(max(-1.0, min(1.0, cos)))), 3
        )
        self.frames.append(record)
        self._correction = total
        # Keep a lightly thinned copy in world space for the next frames' model.
        self._recent.append(raw.voxel_down_sample(0.5 * self.voxel).transform(pose))
        if len(self._recent) > self.window:
            self._recent.pop(0)
        return pose

    def _conditioning(self, src: Any, dst: Any, t: np.ndarray, dist: float) -> float:
        """How well the matched model normals pin down a translation (0 = not at all).

        The smallest eigenvalue of the mean ``n n^T`` over matched model normals:
        about 1/3 when the frame sees surfaces facing three independent ways,
        near 0 when one direction has no surface across it (a wall and the
        floor only: sliding along the wall costs nothing, and ICP drifts).
        """
        from scipy.spatial import cKDTree

        pts = np.asarray(src.points) @ t[:3, :3].T + t[:3, 3]
        model_pts = np.asarray(dst.points)
        if len(pts) == 0 or len(model_pts) == 0:
            return 0.0
        d, idx = cKDTree(model_pts).query(pts, distance_upper_bound=dist)
        hit = np.isfinite(d)
        if hit.sum() < 50:
            return 0.0
        n = np.asarray(dst.normals)[idx[hit]]
        return float(np.linalg.eigvalsh(n.T @ n / len(n))[0])

    def report(self) -> dict[str, Any]:
        return {
            "method": "sequential point-to-plane ICP against the last frames",
            "voxel": self.voxel,
            "max_depth": self.max_depth,
            "window": self.window,
            "frames": self.frames,
        }
