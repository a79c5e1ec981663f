"""Room-scale light localization on a scan (``reroom localize SCAN``), thesis §6.6.3.

Inputs: ``SCAN/hdr/hdr_mesh.ply`` (per-vertex HDR radiance, from ``reroom hdr``) and
``SCAN/layout/layout_labels.ply`` (per-vertex labels, from ``reroom layout``). The
measurements are the observed wall vertices (label 0): diffuse, one shared but unknown
albedo ``rho``, so ``B = pi * radiance`` is ``rho`` times the albedo-free light and the
limiter field does not depend on ``rho``; intensities come out multiplied by ``rho``.
Indirect light is handled crudely, as a constant ambient level (§6.6.3 fits one in the
solve): the 2nd percentile of ``B`` over the walls is subtracted before localization.
The fields ignore occlusion; the solves use ray-cast visibility against the scan mesh.
Ground truth is never read here.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from reroom.errors import ReroomError
from reroom.io.mesh import read_ply
from reroom.localize.fields3d import VoxelGrid
from reroom.localize.measurements import Measurements
from reroom.localize.refine import LocalizeResult, RefineParams, localize_lights
from reroom.localize.scene3d import FieldProposer3D, VoteParams3D

__all__ = ["ScanLocalizeOptions", "localize_scan"]

WALL = 0


@dataclass(frozen=True)
class ScanLocalizeOptions:
    """Options of :func:`localize_scan`.

    Attributes
    ----------
    max_measurements:
        Wall vertices kept (a seeded random subset beyond this).
    voxels:
        Voxels along the longest side of the room's box.
    surface_margin:
        Candidates closer than this (metres) to a mesh vertex are dropped (§6.3.6).
    ambient_percentile:
        Percentile of ``B`` taken as the ambient (indirect) level and subtracted.
    relative_rms:
        Success when the RMS residual is below this fraction of the RMS of ``B``.
    min_power:
        Lights weaker than this fraction of the total intensity are dropped.
    negative_tolerance:
        How far (fraction of the largest ``B``) the unexplained light may dip below zero
        before Algorithm 1 gives up (the thesis: 0, for noiseless data).
    time_limit:
        Seconds for Algorithm 1.
    seed:
        Seed of the subset.
    """

    max_measurements: int = 4000
    voxels: int = 64
    surface_margin: float = 0.15
    ambient_percentile: float = 2.0
    relative_rms: float = 0.05
    min_power: float = 0.05
    negative_tolerance: float = 0.1
    time_limit: float = 900.0
    seed: int = 0


def _inputs(scan: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    hdr = scan / "hdr" / "hdr_mesh.ply"
    labels = scan / "layout" / "layout_labels.ply"
    for path, stage in ((hdr, "hdr"), (labels, "layout")):
        if not path.is_file():
            raise ReroomError(f"{path}: missing (run `reroom {stage} {scan}` first)")
    mesh = read_ply(hdr)
    lab = read_ply(labels)
    if len(lab.vertices) != len(mesh.vertices):
        raise ReroomError(
            f"{labels}: {len(lab.vertices)} vertices, but {hdr} has {len(mesh.vertices)}"
        )
    attrs = mesh.vertex_attributes
    if "radiance" not in attrs or "label" not in lab.vertex_attributes:
        raise ReroomError(f"{hdr} needs 'radiance_r/g/b' and {labels} a 'label' per vertex")
    observed = np.asarray(attrs.get("observed", np.ones(len(mesh.vertices))), bool)
    radiance = np.asarray(attrs["radiance"], np.float64).reshape(-1, 3).mean(axis=1)
    return (
        np.asarray(mesh.vertices, np.float64),
        np.asarray(mesh.faces),
        np.asarray(mesh.vertex_normals, np.float64),
        np.where(observed & np.isfinite(radiance), radiance, np.nan),
        np.asarray(lab.vertex_attributes["label"]).reshape(-1),
    )


def localize_scan(
    scan_dir: str | Path, options: ScanLocalizeOptions | None = None
) -> tuple[LocalizeResult, dict]:
    """Find the point lights of a scanned room from the light on its walls.

    Returns
    -------
    result:
        Algorithm 1's result; ``positions`` in the scan's frame (metres), intensities
        times the walls' albedo (W/sr-like units of ``pi * radiance * m^2``).
    info:
        Inputs and decisions (counts, ambient level, grid, tolerance).
    """
    opt = options or ScanLocalizeOptions()
    scan = Path(scan_dir)
    verts, faces, normals, radiance, labels = _inputs(scan)
    centre = verts.mean(axis=0)
    wall = np.flatnonzero((labels == WALL) & np.isfinite(radiance))
    if wall.size < 50:
        raise ReroomError(f"{scan}: only {wall.size} observed wall vertices, too few to localize")
    rng = np.random.default_rng(opt.seed)
    if wall.size > opt.max_measurements:
        wall = np.sort(rng.choice(wall, opt.max_measurements, replace=False))
    nrm = normals[wall]
    # Scan normals may point either way: turn them towards the room's interior.
    flip = np.einsum("ij,ij->i", centre - verts[wall], nrm) < 0
    nrm[flip] *= -1
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    b = np.pi * radiance[wall]
    ambient = float(np.percentile(b, opt.ambient_percentile))
    b = np.maximum(b - ambient, 0.0)
    meas = Measurements(verts[wall], nrm, b)

    lo, hi = verts.min(axis=0), verts.max(axis=0)
    voxel = float((hi - lo).max()) / opt.voxels
    grid = VoxelGrid.for_box(lo, hi, voxel)
    dist, _ = cKDTree(verts).query(grid.centres().reshape(-1, 3), workers=-1)
    valid = (dist >= opt.surface_margin).reshape(grid.shape)
    radius = 0.5 * float(np.linalg.norm(hi - lo))
    prop = FieldProposer3D(
        meas.points, meas.normals, grid, valid, radius, VoteParams3D(max_candidates=2)
    )

    from reroom.rays import RayCaster

    caster = RayCaster(verts, faces)

    def visibility(positions: np.ndarray) -> np.ndarray:
        return caster.visibility_matrix(meas.points, meas.normals, positions)

    tol = (opt.relative_rms**2) * float(np.mean(b**2))
    margin = opt.surface_margin
    bounds = (lo + margin, hi - margin)
    res = localize_lights(
        meas,
        prop,
        bounds,
        tol,
        RefineParams(
            increment=0.01 * float(np.max(b)) * float(np.median(np.linalg.norm(
                meas.points - centre, axis=1))) ** 2,
            match_distance=0.1 * radius,
            # Noisy data: B' dips below zero by the noise long before lights overshoot.
            negative_tolerance=opt.negative_tolerance,
            time_limit=opt.time_limit,
        ),
        visibility,
    )  # fmt: skip
    keep = res.intensities >= opt.min_power * max(float(res.intensities.sum()), 1e-300)
    res.positions, res.intensities = res.positions[keep], res.intensities[keep]
    info = {
        "wall_vertices": int(wall.size),
        "ambient_B": ambient,
        "grid_shape": list(grid.shape),
        "voxel_m": voxel,
        "tolerance_mse": tol,
        "success": bool(res.success),
        "reason": res.reason,
        "iterations": res.iterations,
        "seconds": res.seconds,
        "mse": res.mse,
    }
    return res, info


def write_localized_lights(res: LocalizeResult, info: dict, out_dir: str | Path) -> Path:
    """Write the lights found as ``lights.json`` (light-description schema, ``source: localize``)."""
    from reroom.lights.lightset import Light, LightSet, write_lights

    lights = [
        Light(
            name=f"localized{i}",
            type="point",
            source="localize",
            geometry={
                "position": [float(x) for x in p],
                "axis": [0.0, 0.0, 1.0],
                "intensity": float(it),
            },
            evidence={"intensity_units": "albedo * pi * radiance * m^2 (albedo unknown)"},
            reason="point light fitted to the direct light on the walls (thesis ch. 6)",
        )
        for i, (p, it) in enumerate(zip(res.positions, res.intensities, strict=True))
    ]
    notes = [] if res.success else [f"localization did not converge: {res.reason}"]
    return write_lights(LightSet(lights=lights, notes=notes, meta={"localize": info}), out_dir)
