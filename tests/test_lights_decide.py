"""The decision rules on hand-made candidates: the height test and an estimated ceiling."""

from __future__ import annotations

import numpy as np
import pytest

from reroom.lights import LightsOptions
from reroom.lights.candidates import Component
from reroom.lights.decide import ceiling_estimated, decide, evidence
from reroom.lights.room import RoomModel

UP = np.array([0.0, 0.0, 1.0])


def _panel(x: float, y: float, z: float, side: float = 0.4) -> tuple[Component, np.ndarray]:
    """A flat, bright, down-facing square panel centred at (x, y, z) (world = aligned)."""
    g = np.linspace(-side / 2, side / 2, 9)
    gx, gy = np.meshgrid(g, g, indexing="ij")
    verts = np.stack([x + gx.ravel(), y + gy.ravel(), np.full(gx.size, z)], axis=1)
    comp = Component(
        vertices=np.arange(len(verts)),
        centroid=np.array([x, y, z]),
        normal=-UP,
        normal_spread=1.0,
        area=side * side,
        axes=np.eye(3),
        extent=np.array([side, side, 0.0]),
        center=np.array([x, y, z]),
        eigenvalues=np.array([side**2 / 12, side**2 / 12, 0.0]),
        mean_radiance=np.array([50.0, 50.0, 50.0]),
        mean_luminance=50.0,
        peak_luminance=60.0,
        edge_contrast=20.0,
    )
    return comp, verts


def _room(ceiling: str | None) -> RoomModel:
    room = {
        "name": "room0",
        "polygon": [[0, 0], [4, 0], [4, 3], [0, 3]],
        "walls": [],
        "openings": [],
    }
    if ceiling is not None:
        room["ceiling"] = ceiling
    return RoomModel(np.eye(3), 0.0, 2.3, [room], np.zeros(1, np.int64))


def _verdict(room: RoomModel, x: float, y: float, z: float) -> tuple:
    comp, verts = _panel(x, y, z)
    ev = evidence(comp, verts, UP, room)
    return decide(comp, ev, LightsOptions(), room, [], 1.0)


@pytest.mark.parametrize("ceiling", ["seen", None])  # None: a layout from before the key
def test_a_light_above_a_seen_ceiling_is_outside_the_room(ceiling: str | None) -> None:
    room = _room(ceiling)
    assert not ceiling_estimated(room)
    assert _verdict(room, 2.0, 1.5, 2.35)[0] == "keep"  # within 10 cm of the ceiling
    verdict = _verdict(room, 2.0, 1.5, 2.6)
    assert verdict[0] == "reject" and verdict[2] == "outside"


def test_an_estimated_ceiling_does_not_bound_a_ceiling_light() -> None:
    room = _room("estimated")
    assert ceiling_estimated(room)
    # 30 cm above the estimated ceiling (a lower bound): a real ceiling light.
    verdict = _verdict(room, 2.0, 1.5, 2.6)
    assert verdict[0] == "keep" and verdict[2] == "area", verdict
    # The floor and the outline still bound it.
    assert _verdict(room, 2.0, 1.5, -0.5)[2] == "outside"
    assert _verdict(room, 6.0, 1.5, 2.6)[2] == "outside"
