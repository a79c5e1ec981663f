"""The renders' default sampler keeps a render linear in its lights.

Mitsuba's ``ldsampler`` (reroom's default for powers of four until session 45) is biased
once a scene has more than one emitter: in the room below, the lamp by the corner renders
0.89-0.90 times as bright alone as with a second, dark, light beside it (64 and 256 spp;
checked by hand with ``sampler="ldsampler"``). A recovered model with its two point
lights on rendered 6.7 % darker than the two rendered alone and summed.
"""

from __future__ import annotations

import numpy as np
import pytest

from reroom.scan.camera import Intrinsics


@pytest.fixture(scope="module")
def mi():
    from reroom.render.mitsuba_env import mitsuba

    return mitsuba()


def _planes(mi) -> dict:
    """A 4 x 3 x 2.5 m room of six separate rectangles (as a scan's fitted planes)."""
    t = mi.ScalarTransform4f
    walls = {
        "floor": t().translate([2, 1.5, 0]).scale([2, 1.5, 1]),
        "ceiling": t().translate([2, 1.5, 2.5]).rotate([1, 0, 0], 180).scale([2, 1.5, 1]),
        "w0": t().translate([2, 0, 1.25]).rotate([1, 0, 0], -90).scale([2, 1.25, 1]),
        "w1": t().translate([2, 3, 1.25]).rotate([1, 0, 0], 90).scale([2, 1.25, 1]),
        "w2": t().translate([0, 1.5, 1.25]).rotate([0, 1, 0], 90).scale([1.25, 1.5, 1]),
        "w3": t().translate([4, 1.5, 1.25]).rotate([0, 1, 0], -90).scale([1.25, 1.5, 1]),
    }
    grey = {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.7}}
    return {
        k: {"type": "rectangle", "to_world": m, "bsdf": {"type": "twosided", "bsdf": grey}}
        for k, m in walls.items()
    }


def _corner_view() -> np.ndarray:
    """Camera-to-world (OpenGL axes) of a camera looking into the room's far top corner."""
    eye, target = np.array([1.0, 0.8, 1.3]), np.array([3.8, 2.8, 2.0])
    fwd = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, np.cross(right, fwd), -fwd, eye
    return c2w


def _mean(mi, lights: dict, spp: int, sampler: str | None = None) -> float:
    """Mean radiance of a 48 x 32 view of the six-plane room lit by ``lights``."""
    from reroom.render.camera import perspective_sensor

    intr = Intrinsics.from_fov(48, 32, 90)
    scene = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 16},
        "sensor": perspective_sensor(_corner_view(), intr, spp, sampler=sampler),
        **_planes(mi),
        **lights,
    }
    return float(np.asarray(mi.render(mi.load_dict(scene), seed=3))[..., :3].mean())


def _point(position, intensity: float) -> dict:
    return {"type": "point", "position": position, "intensity": {"type": "rgb", "value": intensity}}


@pytest.mark.parametrize("spp", [64, 50])  # multijitter, independent
def test_a_dark_light_does_not_change_a_render(mi, spp: int) -> None:
    lamp = _point([3.8, 2.8, 2.3], 1.0)
    alone = _mean(mi, {"lamp": lamp}, spp)
    with_dark = _mean(mi, {"lamp": lamp, "dark": _point([1.0, 1.0, 1.0], 0.0)}, spp)
    assert alone > 0
    assert with_dark / alone == pytest.approx(1.0, abs=0.02)


def test_a_render_is_the_sum_of_its_lights(mi) -> None:
    lamp, other = _point([3.8, 2.8, 2.3], 1.0), _point([0.6, 2.5, 0.8], 0.5)
    together = _mean(mi, {"lamp": lamp, "other": other}, 64)
    parts = _mean(mi, {"lamp": lamp}, 64) + _mean(mi, {"other": other}, 64)
    assert parts / together == pytest.approx(1.0, abs=0.02)
