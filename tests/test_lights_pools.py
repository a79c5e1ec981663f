"""The bulb inside an open-topped shade, placed from the pool its opening casts."""

from __future__ import annotations

import numpy as np

from reroom.lights.pools import bulb_from_pool_edge

CEILING_Z = 2.7


def _shade(rng, axis, r_open: float, top: float) -> np.ndarray:
    """400 points of a sloped shade 0.28 m tall, open at ``top`` with radius ``r_open``."""
    t = rng.uniform(0.0, 2.0 * np.pi, 400)
    z = rng.uniform(top - 0.28, top, 400)
    rad = r_open + 0.08 * (top - z) / 0.28
    return np.column_stack([axis[0] + rad * np.cos(t), axis[1] + rad * np.sin(t), z])


def _lamp(bulb_z: float, axis=(0.55, 0.55), r_open: float = 0.14, top: float = 1.64, seed=0):
    """A ceiling seen in a corner room (walls at x = 0 and y = 0, 6 x 4.5 m), lit by a
    bulb on the axis of a shade whose top opening has radius ``r_open`` at ``top``."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform([0.0, 0.0], [6.0, 4.5], (9000, 2))
    ceiling = np.column_stack([xy, np.full(len(xy), CEILING_Z)])
    r = np.linalg.norm(xy - axis, axis=1)
    h = CEILING_Z - bulb_z
    edge = r_open * h / (top - bulb_z)
    cos = h / np.sqrt(h * h + r * r)
    lum = 0.2 + np.where(r < edge, 4.0 * cos**3 / h**2, 0.0)  # direct inside, dim beyond
    lum *= rng.normal(1.0, 0.03, len(lum))  # photo noise
    return ceiling, lum, _shade(rng, axis, r_open, top), top, edge


def test_bulb_height_from_the_pool_edge():
    for bulb_z in (1.50, 1.45, 1.55):
        ceiling, lum, body, top, edge = _lamp(bulb_z)
        out = bulb_from_pool_edge(ceiling, lum, body, top, CEILING_Z)
        assert out is not None, bulb_z
        # The walls cut the pool short towards the corner; the other directions see its edge.
        assert out["edge_sectors"] >= 3
        assert abs(out["pool_edge_radius_m"] - edge) < 0.06, (out, edge)
        assert abs(out["opening_radius_m"] - 0.14) < 0.01  # the 4 cm band of a sloped shade
        np.testing.assert_allclose(out["position"][:2], [0.55, 0.55], atol=0.005)
        assert abs(out["position"][2] - bulb_z) < 0.02, (bulb_z, out)


def test_no_edge_no_place():
    ceiling, lum, body, top, _ = _lamp(1.5)
    # A ceiling lit evenly (no pool edge): nothing to measure.
    flat = np.full(len(lum), 1.0)
    assert bulb_from_pool_edge(ceiling, flat, body, top, CEILING_Z) is None
    # No rim under the pool.
    assert bulb_from_pool_edge(ceiling, lum, body[:5], top, CEILING_Z) is None


def test_a_pool_right_behind_an_emitter_is_not_a_pool() -> None:
    from scipy.spatial import cKDTree

    from reroom.lights.pools import hugs_an_emitter

    g = np.linspace(0.0, 0.6, 13)
    xx, yy = np.meshgrid(g, g)
    panel = np.stack([xx.ravel(), yy.ravel(), np.full(xx.size, 2.68)], 1)
    behind = panel + [0.0, 0.0, 0.02]  # the ceiling 2 cm above the panel
    away = behind + [1.5, 0.0, 0.0]  # a real pool 1.5 m along the ceiling
    emitters = cKDTree(panel)
    assert hugs_an_emitter(behind, emitters)
    assert not hugs_an_emitter(away, emitters)
    assert not hugs_an_emitter(behind, None)


def _soft_lamp(bulb_z: float = 1.5, blur: float = 0.12, seed: int = 1):
    """``_lamp`` in a 5 x 4 m room's corner, its pool's edge blurred over ``blur`` metres
    (the shade's rim and the photos' pixels soften it), on a 6 cm ceiling grid, about
    2.5x the ceiling's level inside: `box_points`' floor lamp (session 25)."""
    rng = np.random.default_rng(seed)
    g = np.arange(0.03, 5.0, 0.06), np.arange(0.03, 4.0, 0.06)
    xx, yy = np.meshgrid(*g)
    xy = np.column_stack([xx.ravel(), yy.ravel()])
    ceiling = np.column_stack([xy, np.full(len(xy), CEILING_Z)])
    axis, r_open, top = np.array([4.45, 3.45]), 0.137, 1.64
    r = np.linalg.norm(xy - axis, axis=1)
    h = CEILING_Z - bulb_z
    edge = r_open * h / (top - bulb_z)
    inside = np.clip(0.5 - (r - edge) / blur, 0.0, 1.0)  # a linear ramp across the edge
    lum = 0.13 * (1.0 + 1.6 * inside * (h / np.sqrt(h * h + r * r)) ** 3 / 0.9)
    lum *= rng.normal(1.0, 0.02, len(lum))
    return ceiling, lum, _shade(rng, axis, r_open, top), top, edge


def test_a_soft_pool_edge_in_a_corner_is_found():
    ceiling, lum, body, top, edge = _soft_lamp()
    out = bulb_from_pool_edge(ceiling, lum, body, top, CEILING_Z)
    assert out is not None
    assert abs(out["pool_edge_radius_m"] - edge) < 0.08, (out, edge)
    assert abs(out["position"][2] - 1.5) < 0.03, out


def test_a_lamp_pool_two_and_a_half_times_the_ceiling_is_a_pool():
    """A lamp's pool about 2.5x the ceiling's median luminance is found with the default
    ``pool_factor`` (`box_points`' floor lamp; the ceiling is lit by a panel and a window
    too), and a ceiling lit evenly is not."""
    import scipy.sparse as sp

    from reroom.lights.detect import LightsOptions
    from reroom.lights.pools import _lit_pools

    ceiling, lum, _, _, edge = _soft_lamp()
    nx, ny = 83, 67  # the 6 cm grid of _soft_lamp
    assert len(ceiling) == nx * ny
    ids = np.arange(nx * ny).reshape(ny, nx)
    pairs = np.concatenate(
        [np.column_stack([ids[:, :-1].ravel(), ids[:, 1:].ravel()]),
         np.column_stack([ids[:-1].ravel(), ids[1:].ravel()])]
    )  # fmt: skip
    adj = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), (nx * ny,) * 2)
    adj = (adj + adj.T).tocsr()
    usable = np.ones(len(lum), bool)
    labels = np.full(len(lum), 2)
    factor = LightsOptions().pool_factor
    assert np.median(lum[np.linalg.norm(ceiling[:, :2] - [4.45, 3.45], axis=1) < 0.4]) < (
        3.0 * np.median(lum)
    )  # below the old factor of 3
    pools = _lit_pools(lum, usable, labels, 2, adj, factor)
    assert len(pools) >= 1
    r = np.linalg.norm(ceiling[pools[0], :2] - [4.45, 3.45], axis=1)
    assert r.max() < edge + 0.1 and len(pools[0]) > 50
    flat = 0.13 * np.random.default_rng(2).normal(1.0, 0.05, len(lum))
    assert _lit_pools(flat, usable, labels, 2, adj, factor) == []


def test_the_opening_is_the_rims_inner_ring_unless_a_lid_closes_it():
    """A clean scan's rim has the shade's outer face and its lining: the light leaves by
    the inner ring, and the bulb is placed from it; a fused scan's lid (points of every
    radius at the top) keeps the fitted circle instead of a radius inside the lid."""
    rng = np.random.default_rng(3)
    bulb_z, top, inner, outer = 1.5, 1.64, 0.134, 0.140
    ceiling, lum, _, _, _ = _lamp(bulb_z, r_open=inner, top=top)
    t = rng.uniform(0.0, 2.0 * np.pi, 400)
    ring = np.where(np.arange(400) % 2 == 0, inner, outer)
    rim = np.column_stack([0.55 + ring * np.cos(t), 0.55 + ring * np.sin(t), np.full(400, top)])
    below = _lamp(bulb_z, r_open=outer, top=top)[2]
    body = np.concatenate([rim, below[below[:, 2] < top - 0.05]])
    out = bulb_from_pool_edge(ceiling, lum, body, top, CEILING_Z)
    assert out is not None
    assert abs(out["opening_radius_m"] - inner) < 0.002, out
    assert abs(out["position"][2] - bulb_z) < 0.012, out
    rr = 0.137 * np.sqrt(rng.uniform(0.0, 1.0, 400))
    lid = np.column_stack([0.55 + rr * np.cos(t), 0.55 + rr * np.sin(t), np.full(400, top)])
    out = bulb_from_pool_edge(ceiling, lum, np.concatenate([body, lid]), top, CEILING_Z)
    assert out is None or out["opening_radius_m"] > 0.08, out


def test_other_furniture_under_the_pool_does_not_hide_the_lamp():
    """``body`` is every object under the pool: a sofa beside the lamp (lower than the
    shade's top) must not move the rim's check off the lamp."""
    ceiling, lum, body, top, _ = _lamp(1.5)
    rng = np.random.default_rng(4)
    sofa = rng.uniform([0.2, 0.9, 0.4], [1.2, 1.8, 0.8], (3000, 3))
    out = bulb_from_pool_edge(ceiling, lum, np.concatenate([body, sofa]), top, CEILING_Z)
    assert out is not None
    assert abs(out["position"][2] - 1.5) < 0.02, out
