"""The inverse-rendering solve (eq. 5.7) on synthetic transfer matrices with known answers."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.sparse as sp

from reroom.invert.solve import (
    InverseProblem,
    LightBlock,
    SolveError,
    SolveOptions,
    indirect_weights,
    per_vertex_albedo,
    solve_lighting,
)
from reroom.invert.synthetic import synthetic_problem

EXACT = SolveOptions(smooth_lambda=0.0, huber_delta=None, reweight_c=None, tolerance=1e-12)


def _seen_error(result, truth) -> float:
    worst = 0.0
    for name, true in truth.intensities.items():
        seen = truth.seen[name]
        err = np.abs(result.intensities[name][seen] - true[seen]).max() / np.abs(true).max()
        worst = max(worst, err)
    return worst


def test_exact_problem_with_every_light_kind_is_recovered() -> None:
    problem, truth = synthetic_problem(1500, seed=1)
    result = solve_lighting(problem, EXACT)
    assert result.converged
    np.testing.assert_allclose(result.albedo, truth.albedo, atol=1e-6)
    assert _seen_error(result, truth) < 1e-6
    for name in ("lamp", "tube"):
        color = result.colors[name]
        assert np.linalg.norm(color) == pytest.approx(1.0, abs=1e-9)
        # monochrome: every bin's RGB is the same colour times a scalar
        np.testing.assert_allclose(
            result.intensities[name], np.outer(result.profiles[name], color), atol=1e-12
        )


def test_alternating_solver_recovers_an_uncoupled_problem() -> None:
    problem, truth = synthetic_problem(1500, lights=("area", "window"), seed=4)
    opts = SolveOptions(
        method="alternating",
        smooth_lambda=0.0,
        huber_delta=None,
        reweight_c=None,
        max_iterations=400,
        tolerance=1e-14,
    )
    result = solve_lighting(problem, opts)
    np.testing.assert_allclose(result.albedo, truth.albedo, rtol=1e-4)
    assert _seen_error(result, truth) < 1e-3


@pytest.mark.parametrize("method", ["joint", "alternating"])
def test_progress_ends_at_its_total_when_the_solve_converges_early(method) -> None:
    problem, _ = synthetic_problem(600, lights=("area", "window"), seed=5)
    calls: list[tuple[int, int]] = []
    opts = SolveOptions(method=method, max_iterations=400, max_rounds=30, tolerance=1e-5)
    result = solve_lighting(problem, opts, progress=lambda _s, d, n: calls.append((d, n)))
    assert result.converged
    done, total = calls[-1]
    assert done == total
    # and it did stop early: fewer reports than the total
    assert len(calls) <= total


def test_huber_resists_outlier_vertices() -> None:
    problem, truth = synthetic_problem(2000, seed=2, noise=0.01, outlier_fraction=0.1)
    plain = solve_lighting(problem, SolveOptions(huber_delta=None, reweight_c=None))
    robust = solve_lighting(problem, SolveOptions(huber_delta=0.02, reweight_c=None))
    err_plain = np.abs(plain.albedo / truth.albedo - 1).max()
    err_robust = np.abs(robust.albedo / truth.albedo - 1).max()
    assert err_robust < 0.02
    assert err_robust < 0.5 * err_plain
    # the outliers end up with the smallest weights
    w = robust.weights.mean(axis=1)
    assert np.median(w[truth.outliers]) < 0.5 * np.median(np.delete(w, truth.outliers))


def test_intensities_stay_nonnegative_under_noise() -> None:
    problem, _ = synthetic_problem(1500, seed=5, noise=0.05)
    result = solve_lighting(problem)
    for values in result.intensities.values():
        assert values.min() >= 0.0
    assert np.all((result.albedo >= 0) & (result.albedo < 1))


def test_smoothness_fills_window_cells_no_vertex_sees() -> None:
    problem, truth = synthetic_problem(1500, lights=("window",), seed=3)
    result = solve_lighting(problem, SolveOptions(huber_delta=None, reweight_c=None))
    sky = result.intensities["window"]
    unseen = ~truth.seen["window"]
    assert unseen.sum() > 20
    seen_vals = sky[~unseen]
    # harmonic fill: within the range of the seen cells, and not zero
    assert sky[unseen].min() > 0.5 * seen_vals.min()
    assert sky[unseen].max() <= seen_vals.max() * (1 + 1e-6)
    without = solve_lighting(problem, EXACT)
    assert without.intensities["window"][unseen].max() == pytest.approx(0.0, abs=1e-6)


def test_monochrome_colour_is_recovered_under_noise() -> None:
    problem, truth = synthetic_problem(2000, lights=("point",), seed=6, noise=0.02)
    result = solve_lighting(problem, SolveOptions(reweight_c=None))
    true_color = truth.intensities["lamp"][0] / np.linalg.norm(truth.intensities["lamp"][0])
    np.testing.assert_allclose(result.colors["lamp"], true_color, atol=0.01)


def test_reweighting_of_eq_5_8() -> None:
    radiance = np.array([[0.5, 1.0, 2.0]])
    indirect = np.array([[1.0, 1.0, 1.0]])
    w = indirect_weights(radiance, indirect, c=10.0)
    np.testing.assert_allclose(w, [[1.0, 1.0, np.exp(-10.0)]])
    assert indirect_weights(np.ones((1, 3)), np.zeros((1, 3)), floor=1e-3).min() == 1e-3


def test_light_that_explains_nothing_is_reported() -> None:
    problem, _ = synthetic_problem(1500, lights=("area", "point"), seed=7)
    extra = sp.csr_matrix(np.random.default_rng(0).uniform(0, 0.01, size=(1500, 1)))
    dark = InverseProblem(
        radiance=problem.radiance,
        indirect=problem.indirect,
        cluster=problem.cluster,
        cluster_names=problem.cluster_names,
        transfer=sp.hstack([problem.transfer, extra]).tocsr(),
        lights=[*problem.lights, LightBlock("switched_off", "area", 1)],
    )
    result = solve_lighting(dark, EXACT)
    assert result.intensities["switched_off"].max() < 1e-6
    assert any("switched_off" in w and "explains nothing" in w for w in result.warnings)


def test_light_no_vertex_sees_and_no_lights() -> None:
    problem, truth = synthetic_problem(800, lights=("area",), seed=8)
    blind = InverseProblem(
        radiance=problem.radiance,
        indirect=problem.indirect,
        cluster=problem.cluster,
        cluster_names=problem.cluster_names,
        transfer=sp.hstack([problem.transfer, sp.csr_matrix((800, 2))]).tocsr(),
        lights=[*problem.lights, LightBlock("hidden", "area", 2)],
    )
    result = solve_lighting(blind, EXACT)
    assert any("hidden" in w and "no clustered vertex" in w for w in result.warnings)
    np.testing.assert_allclose(result.albedo, truth.albedo, atol=1e-6)

    # no lights at all: the albedo explains everything with indirect light only
    none = InverseProblem(
        radiance=problem.indirect * 0.2 / np.pi,
        indirect=problem.indirect,
        cluster=problem.cluster,
        cluster_names=problem.cluster_names,
        transfer=sp.csr_matrix((800, 0)),
        lights=[],
    )
    result = solve_lighting(none, EXACT)
    np.testing.assert_allclose(result.albedo, 0.2, atol=1e-9)
    assert any("no lights" in w for w in result.warnings)


def test_small_and_empty_clusters_are_left_out_with_a_warning() -> None:
    problem, truth = synthetic_problem(1500, lights=("area", "window"), seed=9)
    cluster = problem.cluster.copy()
    ceiling = np.flatnonzero(cluster == 2)
    cluster[ceiling[5:]] = 0  # only 5 ceiling vertices remain...
    radiance = problem.radiance.copy()
    radiance[ceiling[5:]] *= truth.albedo[0] / truth.albedo[2]  # ...the rest became wall
    names = [*problem.cluster_names, "door"]
    small = InverseProblem(
        radiance, problem.indirect, cluster, names, problem.transfer, problem.lights
    )
    result = solve_lighting(small, EXACT)
    assert not result.cluster_used[2] and not result.cluster_used[3]
    assert np.isnan(result.albedo[2]).all() and np.isnan(result.albedo[3]).all()
    np.testing.assert_allclose(result.albedo[:2], truth.albedo[:2], atol=1e-6)
    text = " ".join(result.warnings)
    assert "'ceiling' has only 5" in text and "'door' has no observed vertex" in text


def test_bad_shapes_raise() -> None:
    problem, _ = synthetic_problem(100, lights=("area",), seed=0)
    bad = InverseProblem(
        problem.radiance,
        problem.indirect,
        problem.cluster,
        problem.cluster_names,
        problem.transfer,
        [LightBlock("panel", "area", 2)],
    )
    with pytest.raises(SolveError, match="transfer has shape"):
        solve_lighting(bad)
    with pytest.raises(SolveError, match="unknown solve method"):
        solve_lighting(problem, SolveOptions(method="newton"))  # type: ignore[arg-type]


def test_subset_solve_matches_the_full_solve() -> None:
    problem, truth = synthetic_problem(3000, lights=("area", "window"), seed=10)
    result = solve_lighting(problem, SolveOptions(max_vertices=1000, reweight_c=None))
    assert any("solved on" in w for w in result.warnings)
    np.testing.assert_allclose(result.albedo, truth.albedo, rtol=1e-3)
    assert np.isfinite(result.residual[problem.cluster >= 0]).all()


def test_subset_counts_the_rarely_seen_receivers_once() -> None:
    # The subset keeps every receiver of a rarely seen basis element; if those receivers
    # carry a model error, they must weigh in the subset's solve as in the full one's
    # (the sampled rest stands for all the others), not 4x as much.
    problem, truth = synthetic_problem(6000, lights=("area", "window"), seed=10)
    n = len(problem.radiance)
    rng = np.random.default_rng(10)
    few = rng.choice(n, 20, replace=False)
    spot = sp.csr_matrix((rng.uniform(0.01, 0.02, 20), (few, np.zeros(20, int))), shape=(n, 1))
    radiance = problem.radiance.copy()
    radiance[few] *= 2.0  # an error of the model that only these receivers carry
    biased = InverseProblem(
        radiance,
        problem.indirect,
        problem.cluster,
        problem.cluster_names,
        sp.hstack([problem.transfer, spot]).tocsr(),
        [*problem.lights, LightBlock("spot", "area", 1)],
    )
    plain = {"reweight_c": None, "huber_delta": None, "smooth_lambda": 0.0}
    full = solve_lighting(biased, SolveOptions(max_vertices=None, **plain))
    subset = solve_lighting(biased, SolveOptions(max_vertices=1500, **plain))
    assert any("solved on 1500 of 6000" in w for w in subset.warnings)
    assert np.abs(full.albedo / truth.albedo - 1).max() > 0.004  # the error is visible
    # unweighted, the subset's albedos were 1.3-1.9 % off the full solve's
    np.testing.assert_allclose(subset.albedo, full.albedo, rtol=0.002)


def test_per_vertex_albedo_flags_nonphysical_values() -> None:
    problem, truth = synthetic_problem(600, lights=("area", "point"), seed=11)
    result = solve_lighting(problem, EXACT)
    radiance = problem.radiance.copy()
    radiance[:10] *= 3.0 / truth.albedo[problem.cluster[:10]].min()  # too bright: rho > 1
    albedo, nonphysical = per_vertex_albedo(
        radiance, problem.indirect, problem.transfer, problem.lights, result
    )
    np.testing.assert_allclose(albedo[10:], truth.albedo[problem.cluster[10:]], rtol=1e-6)
    assert nonphysical[:10].all() and not nonphysical[10:].any()
    assert albedo[:10].max() > 1.0  # kept, not clipped


def test_per_vertex_albedo_divides_by_the_footprint_irradiance() -> None:
    """A crease vertex: its point irradiance is a tenth of its neighbours', while its
    radiance, like the photos', is the mean over the pixels around it (session 20)."""
    from reroom.invert.solve import footprint_operator

    problem, truth = synthetic_problem(600, lights=("area", "point"), seed=11)
    result = solve_lighting(problem, EXACT)
    n = len(problem.radiance)
    # A fan of 5 triangles around vertex 0 over vertices 0-5; the rest stand alone.
    verts = np.zeros((n, 3))
    ang = np.linspace(0.0, 2 * np.pi, 6)[:-1]
    verts[1:6, :2] = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    faces = np.array([[0, i, i % 5 + 1] for i in range(1, 6)])
    op = footprint_operator(faces, np.arange(n), n, verts, rings=1)
    np.testing.assert_allclose(np.asarray(op.sum(axis=1)).ravel(), 1.0)
    assert op[0].nnz == 6 and op[10].nnz == 1  # the fan's centre sees its ring
    # The plain ratio at each vertex, then the same with the footprint's irradiance:
    # where the irradiance is uniform over the footprint nothing changes.
    plain, _ = per_vertex_albedo(
        problem.radiance, problem.indirect, problem.transfer, problem.lights, result
    )
    identity = footprint_operator(faces, np.arange(n), n, verts, rings=0)
    same, _ = per_vertex_albedo(
        problem.radiance,
        problem.indirect,
        problem.transfer,
        problem.lights,
        result,
        footprint=identity,
    )
    np.testing.assert_allclose(same, plain)
    # Vertex 0's point irradiance cut to a tenth (the crease), its radiance the
    # footprint's mean: the plain ratio is far too high, the footprint's right.
    from reroom.invert.solve import model_irradiance

    e = model_irradiance(problem.indirect, problem.transfer, problem.lights, result)
    rho = truth.albedo[problem.cluster]
    e_crease = e.copy()
    e_crease[0] *= 0.1
    mean_e = np.asarray(op @ e_crease)
    radiance = problem.radiance.copy()
    radiance[0] = rho[0] / np.pi * mean_e[0]
    # The crease as the model sees it: vertex 0's transfer row and E_ind cut to a tenth.
    cut = sp.diags(np.where(np.arange(n) == 0, 0.1, 1.0))
    crease = (radiance, problem.indirect * (e_crease / e), (cut @ problem.transfer).tocsr())
    got_plain, _ = per_vertex_albedo(*crease, problem.lights, result)
    assert np.all(got_plain[0] > 2.0 * rho[0])
    got, _ = per_vertex_albedo(*crease, problem.lights, result, footprint=op)
    np.testing.assert_allclose(got[0], rho[0], rtol=1e-6)


def _room_with_a_tube(phi_bins: int, fold: bool = True, seed: int = 12):
    """Eq. 5.6 in a closed 4 x 3 x 2.6 m room lit by a ray-traced line light (2D bins)."""
    import trimesh

    from reroom.invert import LineBasis, line_light_transfer
    from reroom.rays import RayCaster

    box = trimesh.creation.box(extents=(4.0, 3.0, 2.6))
    box.apply_translation((2.0, 1.5, 1.3))
    for _ in range(4):
        box = box.subdivide()
    box.invert()  # normals into the room
    p, n = np.asarray(box.vertices), np.asarray(box.vertex_normals)
    basis = LineBasis(8, phi_bins, fold)
    f = line_light_transfer(
        RayCaster(box), p, n, [1.4, 1.5, 2.2], [2.6, 1.5, 2.2], [0, 0, 1], basis, 8
    )
    rng = np.random.default_rng(seed)
    cluster = np.where(p[:, 2] < 1e-6, 1, np.where(p[:, 2] > 2.6 - 1e-6, 2, 0))
    albedo = np.array([[0.70, 0.65, 0.55], [0.35, 0.25, 0.15], [0.85, 0.85, 0.85]])
    indirect = rng.uniform(0.05, 0.3, size=(len(p), 1)) * np.array([1.0, 0.95, 0.85])
    theta, phi = np.meshgrid(basis.theta_centres(), basis.phi_centres(), indexing="ij")
    # Brighter downwards and less towards the line's axis: not separable in theta, phi.
    profile = (1.2 + 0.8 * np.cos(np.pi - theta)) * (
        1.0 - 0.5 * np.abs(phi) / (np.pi / 2) * (0.3 + 0.7 * theta / np.pi)
    )
    color = np.array([0.9, 1.0, 0.8]) / np.linalg.norm([0.9, 1.0, 0.8])
    intens = profile.reshape(-1, 1) * color
    radiance = albedo[cluster] / np.pi * (indirect + f @ intens)
    adj, weights = basis.adjacency(phi_weight=2.0)
    problem = InverseProblem(
        radiance=radiance,
        indirect=indirect,
        cluster=cluster,
        cluster_names=["wall", "floor", "ceiling"],
        transfer=sp.csr_matrix(f),
        lights=[LightBlock("tube", "line", basis.size, True, adj, weights)],
    )
    return problem, albedo, intens, f


@pytest.mark.parametrize("fold", [True, False])
def test_exact_line_light_with_phi_bins_is_recovered(fold) -> None:
    problem, albedo, intens, f = _room_with_a_tube(phi_bins=3, fold=fold)
    seen = (f > 0).sum(axis=0) > 0
    assert seen.sum() >= 18  # most of the (theta, phi) bins have receivers
    result = solve_lighting(problem, EXACT)
    assert result.converged
    np.testing.assert_allclose(result.albedo, albedo, atol=1e-6)
    got = result.intensities["tube"]
    assert np.abs(got[seen] - intens[seen]).max() < 1e-6 * np.abs(intens).max()
    # the phi split is real: a separable fit of the same data is off by far more
    sep = np.asarray(f.reshape(len(f), 8, 3).sum(axis=2))
    flat = InverseProblem(
        problem.radiance,
        problem.indirect,
        problem.cluster,
        problem.cluster_names,
        sp.csr_matrix(sep),
        [LightBlock("tube", "line", 8, True)],
    )
    assert np.abs(solve_lighting(flat, EXACT).albedo - albedo).max() > 1e-3


def _bins_0_and_2_seen(n: int, bins: int, seed: int):
    """Vertices of three clusters, half seeing bin 0 and half bin 2 of a ``bins``-bin light."""
    rng = np.random.default_rng(seed)
    cluster = rng.integers(0, 3, n)
    f = np.zeros((n, bins))
    f[: n // 2, 0] = rng.uniform(0.1, 1, n // 2)
    f[n // 2 :, 2] = rng.uniform(0.1, 1, n - n // 2)
    albedo = np.array([[0.7, 0.6, 0.5], [0.3, 0.3, 0.2], [0.8, 0.8, 0.8]])
    indirect = rng.uniform(0.1, 0.3, (n, 3))
    return cluster, f, albedo, indirect


def test_pair_weights_shape_the_fill_of_unseen_bins() -> None:
    # Three bins of a chain, the middle one unseen: with the smoothness alone it is the
    # weighted mean of its neighbours, (w1 a + w2 b) / (w1 + w2).
    n = 400
    cluster, f, albedo, indirect = _bins_0_and_2_seen(n, 3, seed=13)
    truth = np.array([[1.0], [0.0], [4.0]]) * np.ones(3)
    radiance = albedo[cluster] / np.pi * (indirect + f @ truth)
    for w, expected in (((1.0, 1.0), 2.5), ((3.0, 1.0), 1.75)):
        block = LightBlock("lamp", "point", 3, False, np.array([[0, 1], [1, 2]]), np.array(w))
        problem = InverseProblem(
            radiance, indirect, cluster, ["wall", "floor", "ceiling"], sp.csr_matrix(f), [block]
        )
        opts = SolveOptions(smooth_lambda=1e-6, huber_delta=None, reweight_c=None)
        got = solve_lighting(problem, opts).intensities["lamp"]
        np.testing.assert_allclose(got[1], expected, rtol=1e-3)
    bad = LightBlock("lamp", "point", 3, False, np.array([[0, 1], [1, 2]]), np.array([1.0]))
    with pytest.raises(SolveError, match="one finite weight"):
        solve_lighting(
            InverseProblem(radiance, indirect, cluster, ["a", "b", "c"], sp.csr_matrix(f), [bad])
        )


def test_box_qp_matches_bvls() -> None:
    import scipy.linalg
    import scipy.optimize

    from reroom.invert.solve import _box_qp

    rng = np.random.default_rng(14)
    # Small problems, then large ones where about a fifth of the variables end at a bound
    # (block principal pivoting exchanges many at once; Murty's rule backs it up).
    for trial in range(106):
        k = int(rng.integers(2, 40)) if trial < 100 else 300
        a = rng.normal(size=(k + 3, k))
        h = a.T @ a + 1e-3 * np.eye(k)
        g = 3 * rng.normal(size=k)
        lo = np.where(rng.random(k) < 0.6, -rng.uniform(0, 2, k), 0.0)
        hi = np.where(rng.random(k) < 0.3, rng.uniform(0, 2, k), np.inf)
        s = _box_qp(h, g, lo, hi)
        assert s is not None
        rf = scipy.linalg.cholesky(h)
        b = -scipy.linalg.solve_triangular(rf, g, trans="T")
        ref = scipy.optimize.lsq_linear(rf, b, bounds=(lo, hi), method="bvls", tol=1e-14).x
        assert np.all(s >= lo) and np.all(s <= hi)
        np.testing.assert_allclose(s, ref, atol=1e-9 * (1 + np.abs(ref).max()))


def _chain_problem(shape=None, shape_weight=0.0, seed=14):
    """Four bins of a monochrome light, bins 1 and 3 seen by no vertex; truth ``3 v``."""
    cluster, f, albedo, indirect = _bins_0_and_2_seen(600, 4, seed)
    v = np.array([1.0, 0.5, 0.8, 0.1])
    color = np.array([1.0, 0.9, 0.7]) / np.linalg.norm([1.0, 0.9, 0.7])
    truth = 3.0 * v[:, None] * color
    radiance = albedo[cluster] / np.pi * (indirect + f @ truth)
    chain = np.array([[0, 1], [1, 2], [2, 3]])
    block = LightBlock("tube", "line", 4, True, chain, shape=shape, shape_weight=shape_weight)
    problem = InverseProblem(
        radiance, indirect, cluster, ["wall", "floor", "ceiling"], sp.csr_matrix(f), [block]
    )
    return problem, truth, albedo


@pytest.mark.parametrize("method", ["alternating", "joint"])
def test_shape_prior_fills_unseen_bins_with_the_prior_shape(method) -> None:
    opts = SolveOptions(
        method=method, smooth_lambda=1e-6, huber_delta=None, reweight_c=None, tolerance=1e-12
    )
    # Smoothness alone: the unseen bins are the mean of their seen neighbours.
    problem, truth, albedo = _chain_problem()
    got = solve_lighting(problem, opts).intensities["tube"]
    assert abs(got[1, 0] - got[[0, 2], 0].mean()) < 1e-3 * truth[0, 0]
    assert got[1, 0] > 1.5 * truth[1, 0]
    # A consistent prior (any scale: i0 stays free) gives the truth everywhere.
    shape = np.array([1.0, 0.5, 0.8, 0.1]) * 7.0
    problem, truth, albedo = _chain_problem(shape, shape_weight=1e4)
    result = solve_lighting(problem, opts)
    got = result.intensities["tube"]
    np.testing.assert_allclose(got / got[0], truth / truth[0], rtol=3e-3)
    if method == "joint":  # the alternating solver creeps along the scale valley
        np.testing.assert_allclose(got, truth, rtol=2e-3)
        np.testing.assert_allclose(result.albedo, albedo, rtol=1e-4)


def test_shape_prior_is_validated() -> None:
    problem, _, _ = _chain_problem(np.array([1.0, -0.5, 1.0, 1.0]), 1.0)
    with pytest.raises(SolveError, match="finite shape >= 0 of 4 values"):
        solve_lighting(problem)
    problem, _, _ = _chain_problem(np.ones(3), 1.0)
    with pytest.raises(SolveError, match="finite shape >= 0 of 4 values"):
        solve_lighting(problem)
    problem, _, _ = _chain_problem(np.ones(4), -1.0)
    with pytest.raises(SolveError, match="shape_weight >= 0"):
        solve_lighting(problem)


def _window_with_prior(measured: np.ndarray, weight: np.ndarray, seed: int = 3):
    problem, truth = synthetic_problem(1500, lights=("window",), seed=seed)
    problem.lights[0] = dataclasses.replace(problem.lights[0], prior=measured, prior_weight=weight)
    return problem, truth


@pytest.mark.parametrize("method", ["alternating", "joint"])
def test_measured_prior_sets_the_cells_no_vertex_sees(method) -> None:
    opts = SolveOptions(
        method=method, smooth_lambda=1e-6, huber_delta=None, reweight_c=None, tolerance=1e-12
    )
    _, truth = synthetic_problem(1500, lights=("window",), seed=3)
    true = truth.intensities["window"]
    unseen = ~truth.seen["window"]
    assert unseen.sum() > 20
    # Measured only where no vertex sees: those cells take the measurement, not the
    # harmonic fill, and the seen cells stay the data's.
    measured = np.where(unseen[:, None], true, np.nan)
    problem, _ = _window_with_prior(measured, np.where(unseen, 1e4, 0.0))
    got = solve_lighting(problem, opts).intensities["window"]
    np.testing.assert_allclose(got[unseen], true[unseen], rtol=1e-3)
    scale = np.abs(true).max()
    assert np.abs(got[~unseen] - true[~unseen]).max() < 2e-3 * scale
    plain = solve_lighting(synthetic_problem(1500, lights=("window",), seed=3)[0], opts)
    assert np.abs(plain.intensities["window"][unseen] - true[unseen]).max() > 0.05 * scale
    # A wrong measurement of a seen cell with a small weight leaves the data in charge.
    wrong = np.full_like(true, np.nan)
    k = int(np.flatnonzero(~unseen)[0])
    wrong[k] = 3.0 * true[k]
    weight = np.zeros(len(true))
    weight[k] = 1e-3
    problem, _ = _window_with_prior(wrong, weight)
    got = solve_lighting(problem, opts).intensities["window"]
    np.testing.assert_allclose(got[k], true[k], rtol=2e-3)


def test_measured_prior_is_validated() -> None:
    n = synthetic_problem(200, lights=("window",), seed=3)[0].lights[0].size
    problem, _ = _window_with_prior(np.ones((n, 3)), -np.ones(n))
    with pytest.raises(SolveError, match="one finite prior weight >= 0 per element"):
        solve_lighting(problem)
    problem, _ = _window_with_prior(np.ones((n - 1, 3)), np.ones(n))
    with pytest.raises(SolveError, match=r"needs a prior of shape"):
        solve_lighting(problem)
    problem, _ = _window_with_prior(np.full((n, 3), np.nan), np.ones(n))
    with pytest.raises(SolveError, match="must be finite, >= 0"):
        solve_lighting(problem)
    problem, _, _ = _chain_problem()
    problem.lights[0] = dataclasses.replace(
        problem.lights[0], prior=np.ones((4, 3)), prior_weight=np.ones(4)
    )
    with pytest.raises(SolveError, match="needs a chromatic light"):
        solve_lighting(problem)


def test_lower_bounds_hold_the_cells_no_vertex_sees_and_leave_the_seen_ones() -> None:
    """A window's cells no vertex sees come out at their lower bound (the smoothness
    would leave them near their neighbours, below it), the bound of a seen cell below
    its truth changes nothing, and one above its truth holds it there."""
    opts = SolveOptions(smooth_lambda=1e-6, huber_delta=None, reweight_c=None, tolerance=1e-12)
    problem, truth = synthetic_problem(1500, lights=("window",), seed=3)
    true = truth.intensities["window"]
    unseen = ~truth.seen["window"]
    plain = solve_lighting(problem, opts).intensities["window"]
    scale = np.abs(true).max()
    lower = np.zeros_like(true)
    lower[unseen] = plain[unseen] + 0.5 * scale  # above what the smoothness fills in
    seen_low = int(np.flatnonzero(~unseen)[0])
    lower[seen_low] = 0.5 * true[seen_low]
    seen_high = int(np.flatnonzero(~unseen)[1])
    lower[seen_high] = 1.5 * true[seen_high]
    problem.lights[0] = dataclasses.replace(problem.lights[0], lower=lower)
    got = solve_lighting(problem, opts).intensities["window"]
    assert np.all(got >= lower - 1e-9 * scale)
    np.testing.assert_allclose(got[unseen], lower[unseen], rtol=1e-6)
    # (the cell held above its truth pushes its neighbours down a little)
    np.testing.assert_allclose(got[seen_low], true[seen_low], rtol=1e-2)
    np.testing.assert_allclose(got[seen_high], lower[seen_high], rtol=1e-6)


def test_lower_bounds_are_validated() -> None:
    problem, _ = synthetic_problem(200, lights=("window",), seed=3)
    n = problem.lights[0].size
    for bad, match in (
        (-np.ones((n, 3)), "lower bounds >= 0"),
        (np.ones((n - 1, 3)), "lower bounds >= 0 of shape"),
        (np.full((n, 3), np.inf), "infinite lower bound"),
    ):
        problem.lights[0] = dataclasses.replace(problem.lights[0], lower=bad)
        with pytest.raises(SolveError, match=match):
            solve_lighting(problem)
    problem.lights[0] = dataclasses.replace(problem.lights[0], lower=np.ones((n, 3)))
    with pytest.raises(SolveError, match="need the joint solver"):
        solve_lighting(problem, SolveOptions(method="alternating"))
    # NaN and 0 mean no bound: the solve is the plain one
    problem.lights[0] = dataclasses.replace(problem.lights[0], lower=np.full((n, 3), np.nan))
    a = solve_lighting(problem).intensities["window"]
    problem.lights[0] = dataclasses.replace(problem.lights[0], lower=None)
    np.testing.assert_array_equal(a, solve_lighting(problem).intensities["window"])
    problem, _, _ = _chain_problem()
    problem.lights[0] = dataclasses.replace(problem.lights[0], lower=np.ones((4, 3)))
    with pytest.raises(SolveError, match="need a chromatic light"):
        solve_lighting(problem)


def test_colour_prior_holds_a_monochrome_light_to_its_measured_colour() -> None:
    """A prior at the true colour leaves the exact solve exact; a prior elsewhere moves
    the colour toward it as its weight grows (the data pays for it)."""
    opts = dataclasses.replace(EXACT, method="joint")
    problem, truth = synthetic_problem(1500, lights=("area", "line"), seed=5)
    true = truth.intensities["tube"][0] / np.linalg.norm(truth.intensities["tube"][0])
    i_tube = next(i for i, lt in enumerate(problem.lights) if lt.name == "tube")
    tube = problem.lights[i_tube]
    problem.lights[i_tube] = dataclasses.replace(
        tube, color_prior=3.0 * true, color_prior_weight=100.0
    )
    result = solve_lighting(problem, opts)
    np.testing.assert_allclose(result.colors["tube"], true, atol=1e-6)
    np.testing.assert_allclose(result.albedo, truth.albedo, atol=1e-5)
    wrong = true * np.array([1.2, 1.0, 0.8])
    wrong /= np.linalg.norm(wrong)
    off = []
    for weight in (1e-8, 1e-2, 1e2):
        problem.lights[i_tube] = dataclasses.replace(
            tube, color_prior=wrong, color_prior_weight=weight
        )
        got = solve_lighting(problem, opts).colors["tube"]
        off.append(np.linalg.norm(got - wrong))
    assert off[0] == pytest.approx(np.linalg.norm(true - wrong), rel=1e-3)
    assert off[0] > off[1] > off[2]
    assert off[2] < 0.01 * off[0]


def test_colour_prior_is_validated() -> None:
    problem, _ = synthetic_problem(200, lights=("area", "line"), seed=5)
    i_tube = next(i for i, lt in enumerate(problem.lights) if lt.name == "tube")
    tube = problem.lights[i_tube]
    for prior, weight, match in (
        (None, 1.0, "colour prior of 3"),
        (np.array([1.0, np.nan, 1.0]), 1.0, "colour prior of 3"),
        (np.array([1.0, 1.0]), 1.0, "colour prior of 3"),
        (np.zeros(3), 1.0, "colour prior of 3"),
        (np.ones(3), -1.0, "color_prior_weight >= 0"),
    ):
        problem.lights[i_tube] = dataclasses.replace(
            tube, color_prior=prior, color_prior_weight=weight
        )
        with pytest.raises(SolveError, match=match):
            solve_lighting(problem)
    problem.lights[i_tube] = dataclasses.replace(tube, color_prior=np.ones(3), color_prior_weight=1)
    with pytest.raises(SolveError, match="colour prior needs the joint solver"):
        solve_lighting(problem, SolveOptions(method="alternating"))
    panel = problem.lights[0]
    problem.lights[i_tube] = tube
    problem.lights[0] = dataclasses.replace(panel, color_prior=np.ones(3), color_prior_weight=1)
    with pytest.raises(SolveError, match="needs a monochrome light"):
        solve_lighting(problem)
