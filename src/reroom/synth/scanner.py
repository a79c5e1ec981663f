"""Scanner-like geometry: corrupted meshes and meshes fused from rendered depth maps.

Real scans are not clean CAD meshes: depth sensors are noisy, fusion leaves
holes where nothing was seen, windows (glass or openings) return no depth, and
meshes get decimated. These functions make such meshes from the true scene so
later stages are tested on what a scanner delivers.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import trimesh

from reroom.scan.camera import Frame, Intrinsics

#: The synthetic scanner's voxel grid is turned this far about the vertical from
#: the scene's axes (see :func:`fuse_depth_maps`); any angle well away from the
#: walls' multiples of 90 deg does.
GRID_YAW_DEG = 17.0


def corrupt_mesh(
    vertices: np.ndarray,
    faces: np.ndarray,
    rng: np.random.Generator,
    noise_std: float = 0.004,
    hole_fraction: float = 0.03,
    hole_radius: float = 0.15,
    decimate: float = 1.0,
) -> trimesh.Trimesh:
    """Weld, decimate, punch holes into and jitter a clean mesh.

    Parameters
    ----------
    noise_std:
        Std (metres) of Gaussian vertex displacement along the vertex normal.
    hole_fraction:
        Approximate fraction of the surface area removed, in round holes of
        ``hole_radius`` metres centred on random vertices.
    decimate:
        Fraction of faces kept by quadric decimation (1 = no decimation).
    """
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    mesh.merge_vertices()
    if decimate < 1.0:
        import open3d as o3d

        om = o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(mesh.vertices), o3d.utility.Vector3iVector(mesh.faces)
        )
        om = om.simplify_quadric_decimation(max(4, int(len(mesh.faces) * decimate)))
        mesh = trimesh.Trimesh(np.asarray(om.vertices), np.asarray(om.triangles), process=False)
    if hole_fraction > 0:
        area = mesh.area
        n_holes = max(1, int(round(hole_fraction * area / (np.pi * hole_radius**2))))
        centers = mesh.vertices[rng.choice(len(mesh.vertices), n_holes, replace=False)]
        tc = mesh.triangles_center
        from scipy.spatial import cKDTree

        d, _ = cKDTree(centers).query(tc)
        keep = d > hole_radius * rng.uniform(0.5, 1.0)
        mesh.update_faces(keep)
        mesh.remove_unreferenced_vertices()
    if noise_std > 0:
        n = mesh.vertex_normals
        mesh.vertices = mesh.vertices + n * (noise_std * rng.standard_normal(len(n)))[:, None]
    return mesh


def render_depth(caster, frame: Frame) -> np.ndarray:
    """Depth map (metres along the optical axis, 0 = no return) of a frame by ray casting."""
    origins, dirs = frame.pixel_rays()
    hits = caster.intersect(origins, dirs)
    depth = np.where(hits.hit, hits.t * (dirs @ frame.forward), 0.0)
    k = frame.intrinsics
    return depth.reshape(k.height, k.width)


def kinect_noise(
    depth: np.ndarray, rng: np.random.Generator, sigma_at_1m: float = 0.0015
) -> np.ndarray:
    """Structured-light depth noise growing with the square of depth (0 stays 0)."""
    noisy = depth + sigma_at_1m * depth**2 * rng.standard_normal(depth.shape)
    return np.where(depth > 0, noisy, 0.0)


def fuse_depth_maps(
    depths: Sequence[np.ndarray],
    frames: Sequence[Frame],
    intr: Intrinsics,
    voxel_size: float = 0.03,
    depth_trunc: float = 8.0,
    progress: Callable[[int, int], None] | None = None,
    grid_yaw_deg: float = GRID_YAW_DEG,
) -> trimesh.Trimesh:
    """TSDF-fuse depth maps (metres) from posed frames into a mesh.

    Uses the same Open3D voxel-block-grid fusion as the RGB-D importer
    (:class:`reroom.importers.rgbd.TsdfFusion`), so synthetic "scanned" meshes
    are made exactly the way real captures are.

    The voxel grid is placed as a capture app's would be, not on the scene's
    round coordinates: upright (gravity-aligned, as phone AR captures are),
    turned by ``grid_yaw_deg`` about the vertical and raised by half a voxel.
    A plane that falls on a layer of voxel centres fuses into a surface that
    flips between the layers from frame noise: twice the vertices, twice the
    normals' lean (a box room on the grid at 3 cm: 222k vertices, the floor's
    normals 5.9 deg off against 2.6 off the grid; benchmarks/bench_fusion.py),
    and it snaps to the layer when within a few mm of it. The synthetic rooms' walls, floors and
    ceilings sit at multiples of the voxel, where no real room's would.
    """
    from scipy.spatial.transform import Rotation

    from reroom.errors import ReroomError
    from reroom.importers.fusion import TsdfFusion, canonical_order

    # world -> grid: turn about +Z, then raise by half a voxel.
    to_grid = np.eye(4)
    to_grid[:3, :3] = Rotation.from_euler("z", grid_yaw_deg, degrees=True).as_matrix()
    to_grid[2, 3] = 0.5 * voxel_size
    fusion = TsdfFusion(intr, voxel_size, 4 * voxel_size, depth_trunc)
    gl_to_cv = np.diag([1.0, -1.0, -1.0, 1.0])
    grey = np.zeros((intr.height, intr.width, 3), np.uint8)
    for i, (depth, frame) in enumerate(zip(depths, frames, strict=True)):
        mm = np.clip(np.round(np.nan_to_num(depth) * 1000.0), 0, 65535).astype(np.uint16)
        fusion.integrate(grey, mm, to_grid @ frame.c2w @ gl_to_cv)
        if progress is not None:
            progress(i + 1, len(frames))
    om = fusion.extract_mesh()
    om.remove_degenerate_triangles()
    om.remove_duplicated_triangles()
    om.remove_duplicated_vertices()
    om.remove_unreferenced_vertices()
    grid_vertices = np.asarray(om.vertices)
    world_vertices = (grid_vertices - to_grid[:3, 3]) @ to_grid[:3, :3]
    mesh = trimesh.Trimesh(world_vertices, np.asarray(om.triangles), process=False)
    if len(mesh.faces) == 0:
        raise ReroomError("TSDF fusion of the rendered depth maps produced an empty mesh")
    # Keep the components that carry the room; drop floating specks from depth noise.
    comps = mesh.split(only_watertight=False)
    if len(comps) > 1:
        big = [c for c in comps if len(c.faces) >= max(50, 0.002 * len(mesh.faces))]
        mesh = trimesh.util.concatenate(big)
    order, faces = canonical_order(mesh.vertices, mesh.faces)
    return trimesh.Trimesh(np.asarray(mesh.vertices)[order], faces, process=False)
