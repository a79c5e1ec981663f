"""Receiver normals for the transfer: the surface's orientation, not the mesh's noise.

Every transfer of eq. 5.6 weights light by the cosine to the receiver's normal. The
photos see the *true* surface, whose normal is smooth (a wall is flat); a fused scan's
per-vertex normal (the area-weighted normal of its one-ring,
:func:`reroom.hdr.observe.vertex_normals`) carries the reconstruction's noise. On a
24-frame 160x120 TSDF scan of `furnished` the one-ring normals of the walls lean 15°
from the wall's axis in the median, and the model's radiance at the true parameters
follows the lean (walls leaning up 20 % too bright where lit directly, leaning down
7 % too dark). With the true lights and the true radiance the solve then dimmed every
light by 20-40 % and raised the floor's albedo 21-36 % (docs/invert.md, "Session 32";
our reading: noise in the solve's regressors biases the fit toward weak lights, as
regression dilution does).

:func:`smoothed_vertex_normals` diffuses the normal field over the surface: a few rounds,
each replacing a vertex's normal by the area-weighted mean of the normals within a short
distance that agree with it (a bilateral filter), so that flat surfaces get their plane's
normal while creases (a wall meeting the floor, a table's edge) stay sharp. Written here
because trimesh and Open3D smooth normals over a fixed neighbour count or the one-ring
only, not over a metric reach with an agreement cut-off. (Averaging the face normals
within the whole radius at once gave the same normals within 2° and took 5x as long:
a vertex has about 100 faces within 10 cm of a 3 cm fused mesh, 12 vertices within 5 cm.)

The diffusion has a bias of its own where the fused surface bends (a floor's rounded
edge, furniture): on a well fused scan, whose one-ring normals are already good (the
issue's 300-frame 320x180 scan: 1.4° on the floor), it made the floor 4 % dark.
:func:`receiver_normals` therefore diffuses by default only where the floor's one-ring
normals show the noise (:data:`AUTO_NOISE_DEG`).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from reroom.hdr.observe import vertex_normals

__all__ = [
    "AUTO_NOISE_DEG",
    "AUTO_RADIUS",
    "auto_note",
    "check_normal_radius",
    "normal_lean_deg",
    "receiver_normals",
    "smoothed_vertex_normals",
]


def smoothed_vertex_normals(
    mesh,
    radius: float,
    *,
    min_agreement: float = 0.9,
    steps: int = 4,
) -> np.ndarray:
    """Unit vertex normals diffused over about ``radius`` metres of agreeing surface.

    Each of ``steps`` rounds replaces every vertex's normal by the mean of the normals
    of the vertices within ``radius / sqrt(steps)`` of it (itself included), weighted by
    their areas (a third of their faces'), counting only those whose normal agrees with
    its own: a diffusion whose reach is about ``radius``.

    Parameters
    ----------
    mesh
        Any object with ``vertices (V, 3)`` and ``faces (F, 3)``.
    radius : float
        Metres. 0 returns the one-ring normals (:func:`vertex_normals`).
    min_agreement : float
        A neighbour counts only where the cosine between its normal and the vertex's is
        at least this (0.9: within about 26°), so that averaging never crosses a crease:
        the one-ring normal of a crease's own vertices is halfway between its two sides
        (45° from each at a right angle), and must not pass on to either (at 0.7 it did).
    steps : int
        Rounds of the filter.

    Returns
    -------
    ndarray, shape (V, 3)
        Unit normals; a vertex of no face keeps the zero normal of :func:`vertex_normals`.

    Raises
    ------
    ValueError
        ``radius`` negative or not finite, ``min_agreement`` outside [-1, 1], or
        ``steps`` < 1.
    """
    radius = float(radius)
    if not np.isfinite(radius) or radius < 0:
        raise ValueError(f"normal radius must be a finite number of metres >= 0, got {radius}")
    if not -1.0 <= float(min_agreement) <= 1.0:
        raise ValueError(f"min_agreement must be a cosine in [-1, 1], got {min_agreement}")
    if int(steps) < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    n0 = vertex_normals(mesh)
    v = np.asarray(mesh.vertices, np.float64)
    f = np.asarray(mesh.faces, np.int64)
    if radius == 0 or len(f) == 0:
        return n0
    tri = v[f]
    face_area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    area = np.bincount(f.ravel(), np.repeat(face_area, 3), minlength=len(v)) / 3.0
    tree = cKDTree(v)
    pairs = tree.sparse_distance_matrix(
        tree, radius / np.sqrt(int(steps)), output_type="coo_matrix"
    )
    # sparse_distance_matrix leaves out the zero distances: each vertex with itself
    # (and exact duplicates, which then do not count each other).
    self_ = np.arange(len(v))
    rows = np.concatenate([pairs.row, self_])
    cols = np.concatenate([pairs.col, self_])
    has_face = np.linalg.norm(n0, axis=1) > 0
    keep = has_face[rows] & has_face[cols]
    rows, cols = rows[keep], cols[keep]
    n = n0
    for _ in range(int(steps)):
        agree = np.einsum("ij,ij->i", n[rows], n[cols]) >= min_agreement
        mean = sp.csr_matrix(
            (area[cols[agree]], (rows[agree], cols[agree])), shape=(len(v), len(v))
        )
        s = mean @ n
        length = np.linalg.norm(s, axis=1, keepdims=True)
        n = np.where(length > 0, s / np.maximum(length, 1e-300), n0)
    return n


#: Median lean (degrees) of the floor's one-ring normals above which ``normal_radius``
#: ``None`` (auto) diffuses the normals: 1.4° on the issue's 300-frame 320x180 fused
#: `furnished` scan, where diffusing them made the floor 4 % dark and the tube 7 points
#: brighter; 4.3° and 7.2° on 60- and 24-frame 160x120 fused scans, where it took the
#: albedos from 25 % off to within 4 % (docs/invert.md, "Session 32").
AUTO_NOISE_DEG = 3.0

#: The radius (metres) auto diffuses over.
AUTO_RADIUS = 0.1


def normal_lean_deg(normals: np.ndarray, mask: np.ndarray) -> float | None:
    """Median angle (degrees) of ``normals[mask]`` from their mean direction.

    On a flat surface (the floor) this is the noise of the normals. ``None`` when fewer
    than 100 vertices are selected or their normals cancel.
    """
    n = np.asarray(normals, np.float64)[np.asarray(mask, bool)]
    n = n[np.linalg.norm(n, axis=1) > 0]
    if len(n) < 100:
        return None
    mean = n.sum(axis=0)
    length = float(np.linalg.norm(mean))
    if not length > 0:
        return None
    cos = np.clip(n @ (mean / length), -1.0, 1.0)
    return float(np.degrees(np.arccos(np.median(cos))))


def receiver_normals(
    mesh, radius: float | None, floor: np.ndarray
) -> tuple[np.ndarray, dict[str, float | None]]:
    """The normals the transfer uses, by ``radius`` (``None``: auto), with what was decided.

    ``radius`` > 0 diffuses over that radius, 0 keeps the one-ring normals, ``None``
    diffuses over :data:`AUTO_RADIUS` only where the floor's (``floor``: a vertex mask)
    one-ring normals lean more than :data:`AUTO_NOISE_DEG` in the median (a scan too
    noisy for them), and keeps them otherwise (also when the scan has no floor).

    Returns
    -------
    normals, info
        ``info`` has ``floor_lean_deg`` (of the one-ring normals; ``None`` without a
        floor) and ``radius`` (the one used).
    """
    ring = vertex_normals(mesh)
    lean = normal_lean_deg(ring, floor)
    if radius is None:
        radius = AUTO_RADIUS if lean is not None and lean > AUTO_NOISE_DEG else 0.0
    radius = float(radius)
    normals = smoothed_vertex_normals(mesh, radius) if radius > 0 else ring
    return normals, {"floor_lean_deg": lean, "radius": radius}


def check_normal_radius(radius: float | None) -> None:
    """Refuse a ``normal_radius`` option that is neither ``None`` (auto) nor metres >= 0."""
    if radius is not None and not (np.isfinite(radius) and radius >= 0):
        raise ValueError(
            f"normal_radius must be None (auto) or a finite number of metres >= 0, got {radius}"
        )


def auto_note(radius: float | None, info: dict[str, float | None]) -> str | None:
    """The warning to give when the auto rule (``radius`` ``None``) diffused the normals."""
    if radius is not None or not info["radius"]:
        return None
    return (
        f"the floor's one-ring normals lean {info['floor_lean_deg']:.1f}° in the median "
        f"(> {AUTO_NOISE_DEG:g}°: a noisy scan): the receivers' normals are diffused over "
        f"{info['radius']:g} m (normal_radius)"
    )
