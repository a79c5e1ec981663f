"""Texels solved from every photo pixel's footprint (reroom.invert.texture_solve)."""

from __future__ import annotations

import numpy as np
import pytest

from reroom.invert.texture_solve import (
    FootprintSamples,
    _adjoint,
    _forward,
    _laplacian,
    back_projection,
    sample_range,
    solve_texels,
)

H, W = 40, 56


def _geometry(n: int, rng: np.random.Generator, scale=(1.5, 3.0)) -> FootprintSamples:
    """``n`` samples on one ``H x W`` plane, footprints rotated and 1.5-3 texels wide."""
    centre = np.stack([rng.uniform(0, W - 1, n), rng.uniform(0, H - 1, n)], axis=1)
    s = rng.uniform(*scale, n)
    a = rng.uniform(0, np.pi, n)
    jac = np.empty((n, 2, 2))
    jac[:, 0, 0], jac[:, 0, 1] = s * np.cos(a), -s * np.sin(a)
    jac[:, 1, 0], jac[:, 1, 1] = s * np.sin(a), s * np.cos(a)
    return FootprintSamples(np.zeros(n, np.int64), centre, jac, np.zeros((n, 3)))


def _geo(samples: FootprintSamples, shapes=((H, W),)):
    starts = np.concatenate([[0], np.cumsum([h * w for h, w in shapes])]).astype(np.int64)
    return (
        samples.plane.astype(np.int64),
        samples.centre,
        samples.jacobian,
        starts,
        np.array([w for _, w in shapes], np.int64),
        np.array([h for h, _ in shapes], np.int64),
    )


def _observe(texture: np.ndarray, samples: FootprintSamples) -> FootprintSamples:
    out = np.empty((len(samples), 3))
    _forward(texture, *_geo(samples), out)
    return FootprintSamples(samples.plane, samples.centre, samples.jacobian, out)


def _pattern(rng: np.random.Generator) -> np.ndarray:
    yy, xx = np.mgrid[0:H, 0:W]
    return np.stack(
        [
            0.5 + 0.2 * np.sin(xx / 1.3),
            0.4 + 0.1 * np.cos(yy / 2.1 + xx / 3.0),
            0.3 + 0.1 * (rng.random((H, W)) > 0.5),
        ],
        axis=-1,
    ).reshape(-1, 3)


def test_the_adjoint_is_the_transpose_of_the_forward_operator():
    rng = np.random.default_rng(1)
    samples = _geometry(3000, rng)
    x = rng.random((H * W, 3))
    r = rng.random((len(samples), 3))
    fx = np.empty((len(samples), 3))
    _forward(x, *_geo(samples), fx)
    ftr = _adjoint(r, *_geo(samples), H * W, 2, 0)
    assert np.isclose((fx * r).sum(), (x * ftr).sum(), rtol=1e-12)
    # Each footprint's weights sum to 1: the coverage totals the samples.
    cov = _adjoint(r, *_geo(samples), H * W, 2, 1)[:, 0]
    assert np.isclose(cov.sum(), len(samples))


def test_the_laplacian_is_the_penalty_gradient():
    rng = np.random.default_rng(2)
    shapes = [(4, 5), (3, 2)]
    x = rng.random((26, 3))
    out = np.empty_like(x)
    starts = np.array([0, 20, 26], np.int64)
    _laplacian(x, starts, np.array([5, 2], np.int64), np.array([4, 3], np.int64), out)
    # D^T D x by an explicit difference matrix, no coupling between the two planes.
    rows = []
    for (h, w), s in zip(shapes, starts[:-1], strict=True):
        for r in range(h):
            for c in range(w):
                i = s + r * w + c
                for j in ([i + 1] if c < w - 1 else []) + ([i + w] if r < h - 1 else []):
                    d = np.zeros(26)
                    d[i], d[j] = -1.0, 1.0
                    rows.append(d)
    dmat = np.array(rows)
    np.testing.assert_allclose(out, dmat.T @ dmat @ x, atol=1e-12)


def test_noise_free_samples_give_the_texture_back():
    rng = np.random.default_rng(3)
    truth = _pattern(rng)
    samples = _observe(truth, _geometry(12000, rng))
    x, coverage, stats = solve_texels(samples, [(H, W)], smooth=0.0, iterations=80)
    inner = np.zeros((H, W), bool)
    inner[3:-3, 3:-3] = True
    inner = inner.ravel()
    blurred = back_projection(samples, [(H, W)])
    err = np.sqrt(((x - truth)[inner] ** 2).mean())
    err_blurred = np.sqrt(((blurred - truth)[inner] ** 2).mean())
    # (exact without the anti-ringing clamp; the clamp trims the peaks a little)
    assert err < 0.01 and err_blurred > 0.03
    assert stats["iterations"] > 0 and stats["footprint"] > 1.4
    assert np.all(coverage[inner] > 0)


def test_the_penalty_keeps_noise_down_and_a_step_in_the_samples_range():
    rng = np.random.default_rng(4)
    yy, xx = np.mgrid[0:H, 0:W]
    step = np.repeat(np.where(xx < W / 2 + 0.3, 0.2, 0.6).reshape(-1, 1), 3, axis=1)
    clean = _observe(step, _geometry(12000, rng))
    noisy = FootprintSamples(
        clean.plane, clean.centre, clean.jacobian, clean.value + rng.normal(0, 0.02, (12000, 3))
    )
    flat = (np.abs(xx - W / 2) > 8).ravel() & (yy > 3).ravel() & (yy < H - 4).ravel()
    errs = {}
    for smooth in (0.0, 0.5):
        x, _, st = solve_texels(noisy, [(H, W)], smooth=smooth, iterations=40)
        errs[smooth] = np.sqrt(((x - step)[flat] ** 2).mean())
        lo, hi = sample_range(noisy, [(H, W)], int(np.ceil(st["footprint"])))
        assert np.all((x >= lo - 1e-12) & (x <= hi + 1e-12))
    assert errs[0.5] < 0.7 * errs[0.0] and errs[0.5] < 0.02


def test_bad_initial_shape_is_refused():
    rng = np.random.default_rng(5)
    samples = _geometry(100, rng)
    with pytest.raises(ValueError, match="initial has shape"):
        solve_texels(samples, [(H, W)], np.zeros((5, 3)))


def test_no_samples_return_the_start():
    empty = FootprintSamples(
        np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2, 2)), np.zeros((0, 3))
    )
    x, coverage, stats = solve_texels(empty, [(4, 4)], np.ones((16, 3)))
    np.testing.assert_array_equal(x, 1.0)
    assert not coverage.any() and stats["iterations"] == 0


def test_the_preconditioner_reaches_the_same_answer_in_fewer_steps():
    """Uneven data weight (a dense patch of samples beside a sparse one, as a texel seen
    by forty frames beside one seen by a single grazing frame): Jacobi-preconditioned
    steps converge to the plain steps' answer, and get there sooner."""
    rng = np.random.default_rng(6)
    truth = _pattern(rng)
    geo = _geometry(16000, rng)
    dense = geo.centre[:, 0] < W / 3
    keep = dense | (rng.random(len(geo)) < 0.1)
    samples = _observe(
        truth,
        FootprintSamples(geo.plane[keep], geo.centre[keep], geo.jacobian[keep], geo.value[keep]),
    )
    answer, _, _ = solve_texels(samples, [(H, W)], iterations=400, tol=1e-9, precondition=False)
    residual = {}
    for pc in (False, True):
        x, _, st = solve_texels(samples, [(H, W)], iterations=12, precondition=pc)
        residual[pc] = st["relative_residual"]
        full, _, _ = solve_texels(samples, [(H, W)], iterations=400, tol=1e-9, precondition=pc)
        np.testing.assert_allclose(full, answer, atol=1e-6)
    assert residual[True] < 0.5 * residual[False]


def test_a_texel_only_a_wide_footprint_reaches_stays_finite():
    """The anti-ringing clamp's range is empty where no sample centre lies within a
    median footprint; such a texel (under the edge of a grazing pixel's footprint) keeps
    its solved value instead of an infinite bound."""
    rng = np.random.default_rng(7)
    near = _geometry(4000, rng)
    keep = near.centre[:, 0] < W / 3
    wide = np.array([[[6.0, 0.0], [0.0, 6.0]]])
    samples = _observe(
        _pattern(rng),
        FootprintSamples(
            np.zeros(keep.sum() + 1, np.int64),
            np.vstack([near.centre[keep], [[W - 8.0, H / 2]]]),
            np.concatenate([near.jacobian[keep], wide]),
            np.zeros((keep.sum() + 1, 3)),
        ),
    )
    x, coverage, _ = solve_texels(samples, [(H, W)])
    assert np.isfinite(x).all()
    assert np.any(coverage[(coverage > 0)] < 0.1)


def test_each_plane_takes_its_own_smoothness():
    """Two planes, the same noisy samples on each: the plane given the higher smoothness
    comes out smoother, the other as it does alone, and one number for both planes is
    the same as that number given per plane."""
    rng = np.random.default_rng(8)
    truth = np.full((H * W, 3), 0.5)
    one = _observe(truth, _geometry(6000, rng))
    noise = rng.normal(0, 0.03, one.value.shape)
    two = FootprintSamples(
        np.concatenate([one.plane, one.plane + 1]),
        np.concatenate([one.centre, one.centre]),
        np.concatenate([one.jacobian, one.jacobian]),
        np.concatenate([one.value + noise, one.value + noise]),
    )
    shapes = [(H, W), (H, W)]
    x, _, _ = solve_texels(two, shapes, smooth=np.array([0.5, 4.0]), iterations=400, tol=1e-10)
    inner = np.zeros((H, W), bool)
    inner[3:-3, 3:-3] = True
    inner = inner.ravel()
    err = [np.sqrt(((x[k * H * W : (k + 1) * H * W] - truth)[inner] ** 2).mean()) for k in (0, 1)]
    assert err[1] < 0.6 * err[0]
    alone, _, _ = solve_texels(
        FootprintSamples(one.plane, one.centre, one.jacobian, one.value + noise),
        [(H, W)],
        smooth=0.5,
        iterations=400,
        tol=1e-10,
    )
    np.testing.assert_allclose(x[: H * W], alone, atol=1e-6)
    same, _, _ = solve_texels(two, shapes, smooth=1.0, iterations=10)
    per, _, _ = solve_texels(two, shapes, smooth=np.array([1.0, 1.0]), iterations=10)
    np.testing.assert_array_equal(same, per)
    with pytest.raises(ValueError, match="one per plane"):
        solve_texels(two, shapes, smooth=np.array([1.0, 2.0, 3.0]))
