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

from reroom.lights.candidates import Component, bright_components, describe_component
from reroom.lights.decide import evidence
from reroom.lights.lightset import Light, Rejected
from reroom.lights.room import CEILING, FLOOR, OTHER, RoomModel

if TYPE_CHECKING:
    from reroom.lights.detect import LightsOptions

__all__ = ["MeshData", "find_pools"]


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
    for k, m in enumerate(ceiling):
        comp = md.describe(m)
        if comp.area < opt.pool_min_area:
            continue
        name = f"ceiling_pool{k}"
        proposal = _point_from_pool(comp, md.aligned, room, name)
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
    comp: Component, aligned: np.ndarray, room: RoomModel, pool: str
) -> Light | None:
    """A point light inside the top of the object under a lit pool on the ceiling, if any."""
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
    return Light(
        "",
        "point",
        "detected",
        {"position": room.to_world(position), "axis": room.up, "position_is_guess": True},
        {
            "pool": pool,
            "object_top_m": top,
            "pool_contrast": comp.edge_contrast,
        },
        f"kept: point light under a lit pool on the ceiling ({pool}), inside the "
        f"top of an object reaching z = {top:.2f} m (a lamp shade open at the top); the position "
        "is a guess 0.15 m below that top — refine it with `reroom localize` or --move",
    )
