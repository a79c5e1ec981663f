"""Lit pools of light on the ceiling and floor, and point lights proposed under them.

A lamp shade open at the top throws a bright, soft-edged pool on the ceiling above
it; a point light is proposed inside the top of the object under the pool (its
position is a guess and says so). Floor pools are reported, not turned into lights:
a downlight with no visible emitter and a patch of sunlight look alike.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree

from reroom.lights.candidates import (
    Component,
    bright_components,
    describe_component,
    fit_circle,
)
from reroom.lights.decide import evidence
from reroom.lights.lightset import Light, Rejected
from reroom.lights.room import CEILING, FLOOR, OTHER, RoomModel

if TYPE_CHECKING:
    from reroom.lights.detect import LightsOptions

__all__ = ["MeshData", "bulb_from_pool_edge", "find_pools", "fit_circle", "hugs_an_emitter"]

#: Metres: pool vertices this close to a kept emitter's vertices are the emitter's own
#: neighbourhood (e.g. the ceiling 2 cm behind a ceiling panel, which the frames'
#: reprojection can paint with the panel's radiance), not a pool thrown from below.
EMITTER_HALO_M = 0.05


@dataclass
class MeshData:
    """The per-vertex arrays the component measurements need."""

    vertices: np.ndarray
    normals: np.ndarray
    areas: np.ndarray
    radiance: np.ndarray
    luminance: np.ndarray
    observed: np.ndarray
    tree: cKDTree
    ring: float
    aligned: np.ndarray

    def describe(self, members: np.ndarray) -> Component:
        """Measure the component with vertices ``members``."""
        return describe_component(
            members,
            self.vertices,
            self.normals,
            self.areas,
            self.radiance,
            self.luminance,
            self.observed,
            self.tree,
            self.ring,
        )


def find_pools(
    md: MeshData,
    taken: np.ndarray,
    adjacency,
    room: RoomModel,
    opt: LightsOptions,
    up: np.ndarray,
) -> tuple[list[tuple[Light, np.ndarray]], list[Rejected]]:
    """Lit pools on the ceiling (point-light proposals under them) and on the floor."""
    proposals: list[tuple[Light, np.ndarray]] = []
    rejected: list[Rejected] = []
    usable = md.observed & ~taken
    floor_median = max(_median(md.luminance, room.labels, FLOOR), 1e-12)
    ceiling = _lit_pools(md.luminance, usable, room.labels, CEILING, adjacency, opt.pool_factor)
    emitters = cKDTree(md.vertices[taken]) if taken.any() else None
    for k, m in enumerate(ceiling):
        comp = md.describe(m)
        if comp.area < opt.pool_min_area:
            continue
        name = f"ceiling_pool{k}"
        if hugs_an_emitter(md.vertices[m], emitters):
            rejected.append(
                Rejected(
                    name,
                    "ceiling pool",
                    "bright ceiling right at a kept emitter (most of its vertices within "
                    f"{100 * EMITTER_HALO_M:.0f} cm of it): the emitter's own surroundings, "
                    "not a pool from a light below",
                    evidence(comp, md.aligned, up, room),
                )
            )
            continue
        proposal = _point_from_pool(comp, md.aligned, room, name, md.luminance, md.observed)
        ev = evidence(comp, md.aligned, up, room)
        if proposal is not None:
            proposals.append((proposal, np.zeros(0, np.int64)))
            why = (
                "lit pool on the ceiling, not an emitter: a point light is proposed "
                "inside the top of the object under it "
                f"(z = {proposal.evidence['object_top_m']:.2f} m)"
            )
        else:
            why = (
                "lit pool on the ceiling with no object under it: light from a source "
                "the scan does not show (add it with --add-point or `reroom localize`)"
            )
        rejected.append(Rejected(name, "ceiling pool", why, ev))
    floor = _lit_pools(md.luminance, usable, room.labels, FLOOR, adjacency, opt.pool_factor)
    for k, m in enumerate(floor):
        comp = md.describe(m)
        if comp.area < opt.pool_min_area:
            continue
        ev = evidence(comp, md.aligned, up, room)
        rejected.append(
            Rejected(
                f"floor_pool{k}",
                "floor pool",
                f"lit pool on the floor at {np.round(comp.centroid[:2], 2).tolist()}, "
                f"{comp.mean_luminance / floor_median:.1f}x "
                "the floor's median: lit by a light above it (a downlight with no visible "
                "emitter?) or by daylight; not detectable as an emitter -- add a point light "
                "with --add-point or find it with `reroom localize`",
                ev,
            )
        )
    return proposals, rejected


def hugs_an_emitter(
    points: np.ndarray, emitters: cKDTree | None, radius: float = EMITTER_HALO_M
) -> bool:
    """Whether most of a pool's ``points`` lie within ``radius`` of a kept emitter's vertices.

    On the 640x360 `furnished` scan the ceiling vertices 2 cm above the ceiling panel
    (hidden behind it) took the panel's radiance in the reprojection and made a 0.6 x
    0.6 m "pool" of the panel's shape; a point light was then proposed inside the table
    under it. A pool thrown by a lamp below lies away from every emitter.
    """
    if emitters is None or len(points) == 0:
        return False
    dist, _ = emitters.query(np.asarray(points, float), distance_upper_bound=radius)
    return bool(np.mean(np.isfinite(dist)) > 0.5)


def _median(luminance: np.ndarray, labels: np.ndarray, label: int) -> float:
    sel = labels == label
    return float(np.median(luminance[sel])) if sel.any() else 0.0


def _lit_pools(
    luminance: np.ndarray,
    usable: np.ndarray,
    labels: np.ndarray,
    label: int,
    adjacency,
    factor: float,
) -> list[np.ndarray]:
    """Connected regions of one surface class brighter than ``factor`` x its median."""
    sel = usable & (labels == label)
    if sel.sum() < 10:
        return []
    level = factor * float(np.median(luminance[sel]))
    _, members = bright_components(adjacency, sel & (luminance >= level))
    return members


def _point_from_pool(
    comp: Component,
    aligned: np.ndarray,
    room: RoomModel,
    pool: str,
    luminance: np.ndarray | None = None,
    observed: np.ndarray | None = None,
) -> Light | None:
    """A point light inside the top of the object under a lit pool on the ceiling, if any.

    Its place is measured when it can be (:func:`bulb_from_pool_edge`: on the axis of
    the object's top opening, at the height from which the opening's rim casts the
    pool's edge); otherwise it is a guess 0.15 m under the object's top, and says so.
    """
    c = room.to_aligned(comp.centroid)
    radius = max(comp.extent[0] / 2, 0.3)
    other = room.labels == OTHER
    xy = aligned[:, :2]
    below = other & (np.linalg.norm(xy - c[:2], axis=1) < radius)
    below &= aligned[:, 2] < room.ceiling_z - 0.3
    below &= aligned[:, 2] > room.floor_z + 0.5
    if below.sum() < 10:
        return None
    pts = aligned[below]
    top = float(np.percentile(pts[:, 2], 98))
    rim = pts[pts[:, 2] > top - 0.1]
    position = np.array([rim[:, 0].mean(), rim[:, 1].mean(), top - 0.15])
    measured = None
    if luminance is not None:
        ceiling = (room.labels == CEILING) & (observed if observed is not None else True)
        measured = bulb_from_pool_edge(
            aligned[ceiling], luminance[ceiling], pts, top, room.ceiling_z
        )
    ev = {"pool": pool, "object_top_m": top, "pool_contrast": comp.edge_contrast}
    geometry = {"position": room.to_world(position), "axis": room.up, "position_is_guess": True}
    if measured is not None:
        position = measured.pop("position")
        ev.update(measured)
        geometry = {"position": room.to_world(position), "axis": room.up}
        where = (
            f"on its opening's axis, {top - position[2]:.2f} m under that top, where the "
            f"opening (radius {measured['opening_radius_m']:.3f} m) casts the pool's edge "
            f"({measured['pool_edge_radius_m']:.2f} m from the axis in "
            f"{measured['edge_sectors']} directions)"
        )
    else:
        where = "the position is a guess 0.15 m below that top — refine it with `reroom localize` or --move"
    return Light(
        "",
        "point",
        "detected",
        geometry,
        ev,
        f"kept: point light under a lit pool on the ceiling ({pool}), inside the "
        f"top of an object reaching z = {top:.2f} m (a lamp shade open at the top); {where}",
    )


def _half_way(prof: np.ndarray, centres: np.ndarray) -> float:
    """Where ``prof`` (falling from its first to its last value) crosses their mean,
    linearly between the window centres ``centres``; the middle centre if no pair of
    neighbouring values brackets it (NaN gaps)."""
    mid = 0.5 * (prof[0] + prof[-1])
    for j in range(len(prof) - 1):
        a, b = prof[j], prof[j + 1]
        if np.isnan(a) or np.isnan(b):
            continue
        if a >= mid > b:
            return float(centres[j] + (centres[j + 1] - centres[j]) * (a - mid) / (a - b))
    return float(centres[len(centres) // 2])


def bulb_from_pool_edge(
    ceiling: np.ndarray,
    ceiling_luminance: np.ndarray,
    body: np.ndarray,
    top: float,
    ceiling_z: float,
    sectors: int = 16,
    step: float | None = None,
    min_drop: float = 0.25,
    min_sectors: int = 3,
) -> dict | None:
    """Where a bulb inside an open-topped shade is, from the pool its opening casts.

    A bulb at height ``z_b`` on the axis of an opening of radius ``R`` at height
    ``z_t`` lights the ceiling (``z_c``) out to ``rho = R (z_c - z_b) / (z_t - z_b)``
    (similar triangles), and the pool ends there in a sharp edge. So
    ``z_b = (rho z_t - R z_c) / (rho - R)``, with ``rho`` measured on the photos' ceiling
    and ``R`` on the scan. A height from the light's effect on the walls (what
    ``reroom localize`` fits) depends on the mesh's occlusion by the shade, which a
    depth-fused scan gets wrong (it closes openings no camera looked into); this needs
    only the opening's rim. Near the throw the height is well conditioned: on a
    ``furnished`` lamp (``rho`` 1.16 m, ``R`` 0.13 m) 10 cm of ``rho`` move it 1.4 cm.

    Parameters
    ----------
    ceiling, ceiling_luminance:
        Observed ceiling vertices (aligned frame, z up) and their luminance.
    body:
        The object's vertices under the pool (aligned frame).
    top, ceiling_z:
        The object's top and the ceiling's height.
    sectors, step, min_drop, min_sectors:
        The edge is searched along ``sectors`` directions round the axis, in radial
        bins of ``step`` (medians over ``2 step``; default 0.04 m or 0.8 x the ceiling
        vertices' spacing, whichever is larger), as the steepest fall between adjacent
        disjoint windows of at least ``min_drop`` of the level before it, placed where
        the profile crosses half-way down; directions where walls cut the pool short or
        the fall is not sharp give none, and ``min_sectors`` must agree (within 10 % of
        their median).

    Returns
    -------
    dict or None
        ``position`` (aligned frame), ``opening_radius_m``, ``pool_edge_radius_m``,
        ``edge_sectors``, ``height_from``: "pool edge"; None when the rim or the edge
        cannot be measured.
    """
    rim = body[body[:, 2] > top - 0.04]
    if len(rim) < 10:
        return None
    axis, r_open = fit_circle(rim[:, :2])
    if (
        not np.isfinite(r_open)
        or r_open <= 0.01
        # Checked against the rim itself: ``body`` is everything under the pool, and a
        # sofa beside the lamp moves its mean 0.4 m (session 25, a fused scan).
        or np.linalg.norm(axis - rim[:, :2].mean(0)) > 0.3
    ):
        return None
    # The light leaves through the opening's innermost edge: a clean scan's rim has the
    # shade's outer face and its lining (0.140 and 0.134 m on the synthetic lamps), and
    # the circle through both is 3 mm too wide, which puts the bulb 6 mm low (session
    # 25). A rim that thin gives its inner ring; a thick one (a depth-fused scan closes
    # the opening with a lid of every radius) keeps the circle, which placed the bulb
    # within 1 cm there.
    d_rim = np.linalg.norm(rim[:, :2] - axis, axis=1)
    p10, p90 = np.percentile(d_rim, [10, 90])
    if p90 - p10 < 0.02:
        r_open = float(p10)
    d = ceiling[:, :2] - axis
    r = np.linalg.norm(d, axis=1)
    az = np.arctan2(d[:, 1], d[:, 0])
    if step is None:  # fine enough for the edge, coarse enough for the mesh's vertices
        near = ceiling[r < 3.0]
        if len(near) < 20:
            return None
        spacing = float(np.median(cKDTree(near).query(near, k=2)[0][:, 1]))
        step = max(0.04, 0.8 * spacing)
    bins = np.arange(r_open + 0.05, 3.0, step)
    edges = []
    for s in range(sectors):
        a0 = -np.pi + s * 2.0 * np.pi / sectors
        sel = (az >= a0) & (az < a0 + 2.0 * np.pi / sectors)
        prof = np.full(len(bins), np.nan)
        for k, b in enumerate(bins):
            m = sel & (r >= b) & (r < b + 2 * step)
            if m.sum() >= 3:
                prof[k] = np.median(ceiling_luminance[m])
        if np.isnan(prof).mean() > 0.3:  # a wall cuts the pool short this way
            continue
        # The fall between a window and the next disjoint one (two bins on): neighbouring
        # windows overlap by half, and a sharp edge between them splits its fall over two
        # differences, each of which can miss ``min_drop`` (session 25: `box_points`'
        # lamp, 35 % over two bins, 22-24 % over one, in four of its six sectors).
        # It is placed where the profile crosses half-way between the levels on either
        # side (windows centred at ``bins + step``): a sharp edge half a bin past the
        # last bright window's centre, a soft one (the shade's rim, the bulb's size)
        # in its middle.
        g = prof[2:] - prof[:-2]
        if g.size == 0 or np.all(np.isnan(g)):
            continue
        k = int(np.nanargmin(g))
        if -g[k] >= min_drop * prof[k]:
            edges.append(_half_way(prof[k : k + 3], bins[k : k + 3] + step))
    if len(edges) < min_sectors:
        return None
    e = np.asarray(edges)
    med = float(np.median(e))
    agree = e[np.abs(e - med) <= 0.1 * med]
    if len(agree) < min_sectors:
        return None
    rho = float(np.median(agree))
    if rho <= 1.5 * r_open:
        return None
    z_b = (rho * top - r_open * ceiling_z) / (rho - r_open)
    if not top - 0.6 < z_b < top:
        return None
    return {
        "position": np.array([axis[0], axis[1], z_b]),
        "opening_radius_m": r_open,
        "pool_edge_radius_m": rho,
        "edge_sectors": len(agree),
        "height_from": "pool edge",
    }
