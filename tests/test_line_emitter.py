"""``reroom_line``: the generalized line light (thesis §5.5.4) as a Mitsuba emitter.

Checked against the closed form of a uniform line over a plane, against numerical
quadrature of eq. 5.11 for a tabulated profile, and for its orientation convention.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from reroom.render.mitsuba_env import mitsuba_info

pytestmark = pytest.mark.skipif(
    not mitsuba_info().vectorized,
    reason="Python emitters need a JIT (llvm/cuda) Mitsuba variant",
)

ALBEDO = 0.5
H = 2.0  # height of the line over the floor
P0, P1 = np.array([-1.0, 0.3, H]), np.array([1.0, 0.3, H])


@pytest.fixture(scope="module")
def mi():
    from reroom.render.emitters import register_emitters

    return register_emitters()


def _floor_radiance(mi, light: dict, pts: np.ndarray, seeds: int = 64) -> np.ndarray:
    """Direct-only radiance of a diffuse z = 0 floor at ``pts``, averaged over NEE samples."""
    scene = mi.load_dict(
        {
            "type": "scene",
            "integrator": {"type": "path", "max_depth": 2},
            "floor": {
                "type": "rectangle",
                "to_world": mi.ScalarTransform4f().scale([20.0, 20.0, 1.0]),
                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": ALBEDO}},
            },
            "light": light,
        }
    )
    n = len(pts)
    rep = np.repeat(pts, seeds, axis=0)
    origin = (rep + [0, 0, 0.5]).T.astype(np.float32)
    down = np.tile([[0.0], [0.0], [-1.0]], (1, len(rep))).astype(np.float32)
    ray = mi.Ray3f(mi.Point3f(origin), mi.Vector3f(down))
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(0, len(rep))
    radiance, valid, _ = scene.integrator().sample(scene, sampler, ray)
    assert np.all(np.array(valid))
    return np.array(radiance).T.reshape(n, seeds, 3).mean(axis=1)


def _quadrature(pts: np.ndarray, profile, interpolation: str, up=(0.0, 0.0, 1.0), k: int = 4000):
    """Eq. 5.11 times J: E = int J(theta) cos(phi) cos(incidence) / r^2 dx, floor normal +z."""
    from reroom.render.line_emitter import line_profile_value

    t = (np.arange(k) + 0.5) / k
    xs = P0 + t[:, None] * (P1 - P0)  # (k, 3)
    tangent = (P1 - P0) / np.linalg.norm(P1 - P0)
    up = np.asarray(up, float)
    up_perp = up - (up @ tangent) * tangent
    up_perp /= np.linalg.norm(up_perp)
    e = pts[:, None, :] - xs[None]  # from the line to the receiver
    r2 = (e**2).sum(-1)
    e = e / np.sqrt(r2)[..., None]
    along = e @ tangent
    e_perp = e - along[..., None] * tangent
    cos_phi = np.linalg.norm(e_perp, axis=-1)
    theta = np.arccos(np.clip((e_perp @ up_perp) / np.maximum(cos_phi, 1e-12), -1, 1))
    j = line_profile_value(np.asarray(profile, float), theta, interpolation)
    cos_in = np.clip(-e[..., 2], 0, None)
    return (j * cos_phi * cos_in / r2).mean(axis=1) * np.linalg.norm(P1 - P0)


def test_uniform_line_matches_closed_form(mi) -> None:
    from reroom.render.line_emitter import line_light

    j0 = 3.0
    pts = np.array([[0.0, 0.3, 0.0], [0.5, 0.3, 0.0], [0.0, 1.3, 0.0], [2.5, -1.0, 0.0]])
    got = _floor_radiance(mi, line_light(P0, P1, j0), pts, seeds=512)[:, 0]
    # Directly below the middle: E = J h^2 int dx / (h^2 + x^2)^2 over [-1, 1].
    a = 1.0
    closed = j0 * H**2 * 2 * (a / (2 * H**2 * (H**2 + a**2)) + math.atan(a / H) / (2 * H**3))
    want = ALBEDO / math.pi * _quadrature(pts, [j0], "constant")
    assert want[0] == pytest.approx(ALBEDO / math.pi * closed, rel=1e-5)
    np.testing.assert_allclose(got, want, rtol=0.03)


@pytest.mark.parametrize("interpolation", ["constant", "linear"])
def test_tabulated_profile_matches_quadrature(mi, interpolation) -> None:
    from reroom.render.line_emitter import line_light

    # 8 bins, brighter downwards (theta -> pi), nothing in the top half: like a tube
    # in a housing. The floor sees theta in (pi/2, pi].
    profile = np.array([0.0, 0.0, 0.0, 0.0, 1.0, 2.0, 4.0, 6.0])
    rng = np.random.default_rng(3)
    pts = np.c_[rng.uniform(-3, 3, (40, 2)), np.zeros(40)]
    got = _floor_radiance(mi, line_light(P0, P1, profile, interpolation=interpolation), pts, 256)
    want = ALBEDO / math.pi * _quadrature(pts, profile, interpolation)
    rel = np.abs(got[:, 0] - want) / want.max()
    assert rel.max() < 0.03, rel.max()
    assert got[:, 0].sum() == pytest.approx(want.sum(), rel=0.01)


def test_orientation_up_means_theta_zero(mi) -> None:
    from reroom.render.line_emitter import line_light

    # All light in the top half (theta < pi/2): a floor below sees nothing; flipping
    # 'up' sends it down.
    profile = np.array([5.0, 5.0, 0.0, 0.0])
    pts = np.array([[0.0, 0.3, 0.0], [0.7, 0.8, 0.0]])
    up_light = line_light(P0, P1, profile, up=(0, 0, 1), interpolation="constant")
    down_light = line_light(P0, P1, profile, up=(0, 0, -1), interpolation="constant")
    assert np.all(_floor_radiance(mi, up_light, pts, 16) == 0)
    assert np.all(_floor_radiance(mi, down_light, pts, 16) > 0)


def test_power_and_bad_parameters(mi) -> None:
    from reroom.render.line_emitter import line_light, line_light_power

    # Uniform J over a line of length L: power = pi * L * pi * J.
    assert line_light_power(2.0, 1.5) == pytest.approx(math.pi * 1.5 * math.pi * 2.0, rel=1e-6)
    with pytest.raises(ValueError, match="distinct"):
        line_light(P0, P0, 1.0)
    with pytest.raises(ValueError, match="parallel"):
        line_light(P0, P1, 1.0, up=(1, 0, 0))
    with pytest.raises(ValueError, match=">= 0"):
        line_light(P0, P1, [1.0, -1.0])
    with pytest.raises(ValueError, match="clearance"):
        line_light(P0, P1, 1.0, clearance=-0.1)
    from reroom.render.emitters import goniometric_light

    with pytest.raises(ValueError, match="clearance"):
        goniometric_light(1.0, [0.0, 0.0, 2.0], clearance=float("nan"))
    # The plugins check it too (a hand-written scene dict).
    bad = {**line_light(P0, P1, 1.0), "clearance": -1.0}
    with pytest.raises(Exception, match="clearance"):
        mi.load_dict({"type": "scene", "light": bad})


def _quadrature_2d(pts, profile, interpolation, fold=True, k: int = 4000):
    """Eq. 5.11 times J(theta, phi) on the floor (normal +z), by a fine midpoint rule."""
    from reroom.render.line_emitter import line_profile_value

    t = (np.arange(k) + 0.5) / k
    xs = P0 + t[:, None] * (P1 - P0)
    tangent = (P1 - P0) / np.linalg.norm(P1 - P0)
    e = pts[:, None, :] - xs[None]
    r2 = (e**2).sum(-1)
    e = e / np.sqrt(r2)[..., None]
    along = e @ tangent
    e_perp = e - along[..., None] * tangent
    cos_phi = np.linalg.norm(e_perp, axis=-1)
    theta = np.arccos(np.clip(e_perp[..., 2] / np.maximum(cos_phi, 1e-12), -1, 1))
    j = line_profile_value(profile, theta, interpolation, np.arcsin(along), fold)
    cos_in = np.clip(-e[..., 2], 0, None)
    return (j * cos_phi * cos_in / r2).mean(axis=1) * np.linalg.norm(P1 - P0)


@pytest.mark.parametrize(("interpolation", "fold"), [("constant", True), ("linear", False)])
def test_theta_phi_profile_matches_quadrature(mi, interpolation, fold) -> None:
    from reroom.render.line_emitter import line_light

    # 8 x 3 bins: down-facing, and (unfolded) brighter towards p1 than towards p0.
    theta_part = np.array([0.0, 0.0, 0.0, 0.0, 1.0, 2.0, 4.0, 6.0])
    phi_part = np.array([1.0, 0.5, 0.1]) if fold else np.array([0.2, 1.0, 3.0])
    profile = np.outer(theta_part, phi_part) + np.outer(theta_part > 0, [0.0, 1.0, 0.0])
    rng = np.random.default_rng(4)
    pts = np.c_[rng.uniform(-3, 3, (40, 2)), np.zeros(40)]
    light = line_light(P0, P1, profile, interpolation=interpolation, phi_fold=fold)
    got = _floor_radiance(mi, light, pts, 256)
    want = ALBEDO / math.pi * _quadrature_2d(pts, profile, interpolation, fold)
    rel = np.abs(got[:, 0] - want) / want.max()
    assert rel.max() < 0.03, rel.max()
    assert got[:, 0].sum() == pytest.approx(want.sum(), rel=0.01)


def test_separable_table_in_two_dimensions_is_the_1d_one(mi) -> None:
    from reroom.render.line_emitter import line_light, line_light_power, line_profile_value

    prof = np.array([0.0, 1.0, 2.0, 4.0])
    theta = np.linspace(0, np.pi, 50)
    for interp in ("constant", "linear"):
        flat = line_profile_value(prof, theta, interp)
        grid = line_profile_value(np.repeat(prof[:, None], 3, 1), theta, interp, theta - 1.5)
        np.testing.assert_allclose(grid, flat)
        np.testing.assert_allclose(
            line_light_power(np.repeat(prof[:, None], 3, 1), 1.5, interpolation=interp),
            line_light_power(prof, 1.5, interpolation=interp),
            rtol=1e-4,
        )
    # A (n, 1) table is the separable one; a uniform table has pi^2 L J whatever its bins.
    d = line_light(P0, P1, prof[:, None])
    assert np.array(d["profile"]).shape == (4,) and "phi_fold" not in d
    assert line_light_power(np.full((4, 5), 2.0), 1.5) == pytest.approx(
        math.pi**2 * 1.5 * 2.0, rel=1e-4
    )
    # Folded: the bins hold |phi|, so the same value on either side of the perpendicular plane.
    two = np.array([[1.0, 2.0, 3.0]] * 4)
    v = line_profile_value(two, np.full(2, 1.0), "constant", np.array([-1.2, 1.2]))
    assert v[0] == v[1] == 3.0
    v = line_profile_value(two, np.full(2, 1.0), "constant", np.array([-1.2, 1.2]), fold=False)
    assert v.tolist() == [1.0, 3.0]
    with pytest.raises(ValueError, match=">= 0"):
        line_light(P0, P1, -two)
