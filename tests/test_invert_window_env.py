"""The window's rendering map from the photos (reroom.invert.window_env)."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

from reroom.invert.basis import CubemapBasis
from reroom.invert.export import latlong_from_cubemap, light_entries
from reroom.invert.window_env import (
    WindowPhotos,
    cell_lower_bounds,
    cell_means,
    fill_gaps,
    latlong_directions,
    latlong_solid_angles,
    observe_windows,
    refine_cells,
)
from reroom.invert.windows import WindowOpening
from reroom.io.images import read_exr
from reroom.rays import RayCaster
from reroom.render.emitters import latlong_direction_to_uv
from reroom.scan import Intrinsics, look_at, write_scan

H = 32  # lat-long rows of the test maps
SCALES = [1.0, 0.5]
WINDOW = WindowOpening(
    "window0",
    np.array([0.0, -1.5, 1.25]),
    np.array([0.8, 0.0, 0.0]),
    np.array([0.0, 0.0, 0.6]),
    np.array([0.0, 1.0, 0.0]),
)


def _environment() -> np.ndarray:
    """A texel-constant lat-long environment: smooth colours, a very bright band on top."""
    d = latlong_directions(H)
    env = np.stack(
        [0.35 + 0.25 * d[..., 0], 0.45 + 0.2 * d[..., 2], 0.5 - 0.2 * d[..., 0] * d[..., 2]], -1
    )
    theta = (np.arange(H) + 0.5) / H * 180.0
    env[(theta > 72) & (theta < 80)] *= 10.0  # saturates in every frame
    return env


def _texel(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    uv = latlong_direction_to_uv(d)
    col = np.minimum((uv[:, 0] * 2 * H).astype(int), 2 * H - 1)
    row = np.minimum((uv[:, 1] * H).astype(int), H - 1)
    return row, col


def _room() -> trimesh.Trimesh:
    mesh = trimesh.creation.box(extents=[4.0, 3.0, 2.5])
    mesh.apply_translation([0, 0, 1.25])
    return mesh


@pytest.fixture(scope="module")
def window_scan(tmp_path_factory) -> tuple[Path, np.ndarray]:
    """A box room (the window a pane in its -Y wall) and two frames rendered by hand."""
    root = tmp_path_factory.mktemp("winscan")
    mesh = _room()
    env = _environment()
    intr = Intrinsics.from_fov(96, 72, 70.0)
    poses = [look_at([0.0, 0.6, 1.25], WINDOW.centre), look_at([0.6, 1.0, 1.5], WINDOW.centre)]
    caster = RayCaster(mesh)
    images = []
    from reroom.invert.windows import rays_through_windows
    from reroom.scan.camera import Frame

    for pose, scale in zip(poses, SCALES, strict=True):
        frame = Frame(0, root / "x.png", pose, intr)
        o, d = frame.pixel_rays()
        hits = caster.intersect(o, d, tmin=caster.eps)
        through = rays_through_windows(o, d, hits.t, [WINDOW]) >= 0
        linear = np.full((len(d), 3), 0.05)
        row, col = _texel(d[through])
        linear[through] = env[row, col] * scale
        code = np.round(255.0 * np.clip(linear, 0, 1) ** (1 / 2.2)).astype(np.uint8)
        images.append(code.reshape(intr.height, intr.width, 3))
    write_scan(root, mesh, intr, poses, images, meta={"reroom": {"response": "gamma2.2"}})
    (root / "hdr").mkdir()
    doc = {
        "response": "gamma2.2",
        "reference_frame": 0,
        "frames": [{"index": j, "scale": [s] * 3} for j, s in enumerate(SCALES)],
    }
    (root / "hdr" / "exposures.json").write_text(json.dumps(doc))
    return root, env


def _cell_means(env: np.ndarray, basis: CubemapBasis) -> np.ndarray:
    h = env.shape[0]
    cell = basis.cell_of(latlong_directions(h).reshape(-1, 3))
    a = latlong_solid_angles(h).ravel()
    num = np.stack(
        [np.bincount(cell, a * env.reshape(-1, 3)[:, c], basis.size) for c in range(3)], 1
    )
    return num / np.bincount(cell, a, basis.size)[:, None]


def test_solid_angles_sum_to_sphere():
    assert latlong_solid_angles(H).sum() == pytest.approx(4 * np.pi)
    cells = np.arange(96 * 3, dtype=float).reshape(96, 3)
    basis = CubemapBasis(4)
    # the cube-map picture's texels belong to the cell of their centre, as refine_cells'
    assert np.allclose(_cell_means(latlong_from_cubemap(cells, basis, H), basis), cells)


def test_observed_texels_match_environment(window_scan):
    root, env = window_scan
    (photos,), stats = observe_windows(root, _room(), [WINDOW], height=H)
    assert stats["frames_used"] == 2 and stats["samples"][0] > 1000
    seen = photos.count > 0
    assert seen.sum() > 40
    # linearised, divided by each frame's scale: the environment's radiance (8-bit steps)
    np.testing.assert_allclose(photos.mean[seen], env[seen], rtol=0.03)
    assert np.isnan(photos.mean[~seen]).all()
    sat = (photos.saturated > 0) & ~seen
    assert sat.sum() > 5
    # a saturated sample's bound is 1 / scale of the frame (white level), below the truth
    assert np.all(photos.bound[sat] <= env[sat] * 1.001)
    assert np.all(photos.bound[sat].max(axis=-1) >= 1.0 - 1e-6)


def test_one_pass_bins_the_pixels_at_several_heights(window_scan):
    """``also_heights`` gives the maps a separate call at that height gives, bit for bit."""
    root, _ = window_scan
    (coarse,), stats = observe_windows(root, _room(), [WINDOW], height=H, also_heights=(3 * H,))
    (fine,) = stats["also"][3 * H]
    (alone,), _ = observe_windows(root, _room(), [WINDOW], height=3 * H)
    (again,), _ = observe_windows(root, _room(), [WINDOW], height=H)
    for a, b in ((fine, alone), (coarse, again)):
        for field in ("mean", "count", "bound", "saturated", "channel_mean"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert fine.height == 3 * H


def test_refined_map_reproduces_observed_texels_and_keeps_cell_means(window_scan):
    root, env = window_scan
    basis = CubemapBasis(4)
    (photos,), _ = observe_windows(root, _room(), [WINDOW], height=H)
    seen = photos.count > 0
    cell = basis.cell_of(latlong_directions(H).reshape(-1, 3)).reshape(H, 2 * H)
    a = latlong_solid_angles(H)
    # Solved cells that equal the environment's mean over each cell's observed part:
    # the refined map must then show the observed texels as they are.
    solved = _cell_means(env, basis)
    for j in np.unique(cell[seen]):
        m = seen & (cell == j) & (photos.saturated == 0)
        if m.any():
            solved[j] = (a[m, None] * env[m]).sum(0) / a[m].sum()
    unsat_cells = [j for j in np.unique(cell[seen]) if not (photos.saturated[cell == j] > 0).any()]
    assert unsat_cells, "the test needs a cell seen without saturation"
    out, info = refine_cells(solved, basis, photos, min_texels=4, min_samples=16)
    assert info["cells_refined"] >= len(unsat_cells)
    for j in unsat_cells:
        m = seen & (cell == j)
        if m.sum() >= 4:
            np.testing.assert_allclose(out[m], env[m], rtol=0.03)
    # every cell keeps its solved mean, whatever the photos or the bounds did
    np.testing.assert_allclose(_cell_means(out, basis), solved, rtol=1e-9, atol=1e-12)
    # texels of cells the photos do not see show the solved value
    unseen_cells = ~np.isin(cell, np.unique(cell[seen | (photos.saturated > 0)]))
    np.testing.assert_allclose(out[unseen_cells], solved[cell[unseen_cells]])
    # with other solved values: the shape within a cell is the photos', the mean the solve's
    other = solved * np.linspace(0.5, 2.0, basis.size)[:, None]
    out2, _ = refine_cells(other, basis, photos, min_texels=4, min_samples=16)
    np.testing.assert_allclose(_cell_means(out2, basis), other, rtol=1e-9, atol=1e-12)
    for j in unsat_cells:
        m = seen & (cell == j)
        if m.sum() >= 4:
            ratio = out2[m] / env[m]
            assert np.std(ratio) / np.mean(ratio) < 0.03


def _photos_one_cell(value: float, bound: float) -> tuple[WindowPhotos, np.ndarray, np.ndarray]:
    """Hand-made photos: one cell, half its texels seen at ``value``, one saturated texel."""
    basis = CubemapBasis(4)
    h = 32
    cell = basis.cell_of(latlong_directions(h).reshape(-1, 3)).reshape(h, 2 * h)
    j = int(cell[h // 2, h // 2])
    texels = np.argwhere(cell == j)
    mean = np.full((h, 2 * h, 3), np.nan)
    count = np.zeros((h, 2 * h), np.int64)
    for r, c in texels[: len(texels) // 2]:
        mean[r, c] = value * (1 + 0.1 * (c % 3))
        count[r, c] = 10
    sat_texel = tuple(texels[-1])
    bound_map = np.zeros((h, 2 * h, 3))
    saturated = np.zeros((h, 2 * h), np.int64)
    bound_map[sat_texel] = bound
    saturated[sat_texel] = 3
    return WindowPhotos(mean, count, bound_map, saturated), cell == j, np.array(sat_texel)


@pytest.mark.parametrize("bound, capped", [(3.0, False), (400.0, True)])
def test_saturated_bounds_raise_texels_but_keep_the_mean(bound, capped):
    basis = CubemapBasis(4)
    # seen texels brighter than the solved cell: the cell-scaled bound falls below the bound
    photos, in_cell, sat = _photos_one_cell(2.0, bound)
    solved = np.ones((basis.size, 3))
    out, info = refine_cells(solved, basis, photos, min_texels=4, min_samples=4)
    assert info["cells_refined"] == 1 and info["cells_bound_raised"] == 1
    assert info["cells_bound_capped"] == int(capped)
    np.testing.assert_allclose(_cell_means(out, basis), solved, rtol=1e-9)
    if capped:
        assert np.all(out[tuple(sat)] < bound)  # the solved energy wins over the bound
    else:
        np.testing.assert_allclose(out[tuple(sat)], bound)
    assert np.all(out[~in_cell] == 1.0)
    # without bounds, the texel keeps the cell's value (the shape comes from seen texels)
    out2, info2 = refine_cells(solved, basis, photos, min_texels=4, min_samples=4, use_bounds=False)
    assert info2["cells_bound_raised"] == 0 and out2[tuple(sat)][0] < bound


def test_too_few_observations_keep_the_solved_cell():
    basis = CubemapBasis(4)
    photos, _, _ = _photos_one_cell(0.5, 0.0)
    photos.saturated[:] = 0
    solved = np.full((basis.size, 3), 2.0)
    out, info = refine_cells(solved, basis, photos, min_texels=10_000)
    assert info["cells_refined"] == 0
    np.testing.assert_allclose(out, 2.0)


def test_fill_gaps_fills_isolated_holes_only():
    mean = np.full((8, 16, 3), np.nan)
    count = np.zeros((8, 16), np.int64)
    mean[2:5, 2:5] = 1.0
    count[2:5, 2:5] = 2
    mean[3, 3], count[3, 3] = np.nan, 0  # a hole inside the seen region
    photos = fill_gaps(WindowPhotos(mean, count, np.zeros((8, 16, 3)), np.zeros((8, 16), int)))
    assert np.allclose(photos.mean[3, 3], 1.0) and photos.count[3, 3] == 0
    assert np.isnan(photos.mean[7, 10]).all()


def test_unreadable_frame_is_skipped_with_a_warning(window_scan, tmp_path):
    import shutil

    root, env = window_scan
    copy = tmp_path / "scan"
    shutil.copytree(root, copy)
    bad = copy / "images" / "frame_00001.png"
    bad.write_bytes(b"not a png")
    with pytest.warns(UserWarning, match="frame_00001.png"):
        (photos,), stats = observe_windows(copy, _room(), [WINDOW], height=H)
    assert stats["frames_used"] == 1 and stats["frames_unreadable"] == [str(bad)]
    seen = photos.count > 0
    np.testing.assert_allclose(photos.mean[seen], env[seen], rtol=0.03)


def test_light_entries_write_both_maps(tmp_path):
    basis = CubemapBasis(4)
    cells = np.linspace(0.1, 2.0, basis.size * 3).reshape(basis.size, 3)
    env = np.full((128, 256, 3), 0.7, np.float32)
    geo = {
        "centre": WINDOW.centre.tolist(),
        "half_u": WINDOW.half_u.tolist(),
        "half_v": WINDOW.half_v.tolist(),
        "normal": WINDOW.normal.tolist(),
    }
    result = SimpleNamespace(
        cubemap_n=4,
        lights=[SimpleNamespace(name="window0", kind="window")],
        light_info=[{"geometry": geo}],
        solve=SimpleNamespace(intensities={"window0": cells}, light_share={"window0": 1.0}),
    )
    (e,) = light_entries(result, tmp_path, window_maps={"window0": (env, {"cells_refined": 3})})
    assert e["environment_exr"] == "window_window0.exr"
    assert e["environment_cells_exr"] == "window_window0_cells.exr"
    assert e["environment_source"] == "photos+cells"
    np.testing.assert_allclose(read_exr(tmp_path / "window_window0.exr")[..., :3], 0.7)
    np.testing.assert_allclose(
        read_exr(tmp_path / e["environment_cells_exr"])[..., :3],
        latlong_from_cubemap(cells, basis),
        rtol=1e-6,
    )
    (e2,) = light_entries(result, tmp_path / "plain")
    assert e2["environment_source"] == "cells"


def test_frames_that_cannot_see_a_window_are_skipped_before_casting():
    from reroom.invert.window_env import _may_see_windows
    from reroom.scan.camera import Frame

    intr = Intrinsics.from_fov(96, 72, 70.0)
    towards = Frame(0, Path("x.png"), look_at([0.0, 0.6, 1.25], WINDOW.centre), intr)
    away = Frame(1, Path("x.png"), look_at([0.0, 0.6, 1.25], [0.0, 3.0, 1.25]), intr)
    # close enough that every corner of the window is outside the image
    close = Frame(2, Path("x.png"), look_at([0.0, -1.3, 1.25], WINDOW.centre), intr)
    assert _may_see_windows(towards, [WINDOW])
    assert not _may_see_windows(away, [WINDOW])
    assert _may_see_windows(close, [WINDOW])
    assert not _may_see_windows(towards, [])


def test_cell_means_use_clean_texels_only(window_scan):
    root, env = window_scan
    basis = CubemapBasis(4)
    (photos,), _ = observe_windows(root, _room(), [WINDOW], height=H)
    means, fraction = cell_means(photos, basis, min_texels=4, min_samples=16)
    ok = np.isfinite(means).all(axis=1)
    assert ok.sum() >= 2 and np.all(fraction[ok] > 0) and np.all(fraction[ok] <= 1)
    assert np.all(fraction[~ok] == 0)
    # Each mean is the solid-angle weighted environment over the cell's clean texels.
    cell = basis.cell_of(latlong_directions(H).reshape(-1, 3))
    a = latlong_solid_angles(H).ravel()
    clean = ((photos.count > 0) & (photos.saturated == 0)).ravel()
    for j in np.flatnonzero(ok):
        m = clean & (cell == j)
        want = (a[m, None] * env.reshape(-1, 3)[m]).sum(0) / a[m].sum()
        np.testing.assert_allclose(means[j], want, rtol=0.03)
        assert fraction[j] == pytest.approx(a[m].sum() / a[cell == j].sum())
    # No cell with a saturated sample has a mean: its clean texels are its darker part.
    sat_cells = np.unique(cell[photos.saturated.ravel() > 0])
    assert len(sat_cells) and not ok[sat_cells].any()
    # One saturated sample in a clean cell takes the whole cell out.
    spoiled = photos.saturated.copy()
    flat = int(np.flatnonzero(clean & ok[cell])[0])
    r, c = divmod(flat, 2 * H)
    spoiled[r, c] = 1
    j = int(cell[flat])
    _, frac2 = cell_means(
        WindowPhotos(photos.mean, photos.count, photos.bound, spoiled),
        basis,
        min_texels=4,
        min_samples=16,
    )
    assert fraction[j] > 0 and frac2[j] == 0
    # Too few clean texels: no mean.
    none, zero = cell_means(photos, basis, min_texels=10_000)
    assert np.isnan(none).all() and np.all(zero == 0)


def test_cell_lower_bounds_never_exceed_the_truth_and_count_clipped_pixels(window_scan):
    """What the photos prove: below each cell's true mean (unseen texels count 0, a
    clipped one its bound), exactly the seen share of a flat cell, and the bright band
    that saturates in every frame held at its bound, not at 0."""
    from reroom.invert.pipeline import InvertOptions, _window_photos

    root, env = window_scan
    basis = CubemapBasis(4)
    (photos,), _ = observe_windows(root, _room(), [WINDOW], height=H)
    lower = cell_lower_bounds(photos, basis)
    truth = _cell_means(env, basis)
    assert lower.shape == (basis.size, 3) and np.all(lower >= 0)
    # (the unsaturated texels are 8-bit readings: within a code of the truth)
    assert np.all(lower <= truth * 1.02 + 1e-12)
    seen = ((photos.count > 0) | (photos.saturated > 0)).ravel()
    cell = basis.cell_of(latlong_directions(H).reshape(-1, 3))
    assert np.all(lower[np.setdiff1d(np.arange(basis.size), cell[seen])] == 0)
    sat_only = ((photos.saturated > 0) & (photos.count == 0)).ravel()
    j = int(np.bincount(cell[sat_only], minlength=basis.size).argmax())
    assert sat_only.any() and np.all(lower[j] > 0)
    # A hand-made cell: half its texels seen at 2, one saturated texel bounded at 5.
    hand, in_cell, sat = _photos_one_cell(2.0, 5.0)
    lb = cell_lower_bounds(hand, basis)
    a = latlong_solid_angles(32)
    m = np.isfinite(hand.mean).all(-1)
    want = (a * np.where(m, hand.mean[..., 0], 0))[in_cell].sum() + a[tuple(sat)] * 5.0
    k = int(basis.cell_of(latlong_directions(32)[tuple(sat)][None])[0])
    assert lb[k, 0] == pytest.approx(want / a[in_cell].sum())
    assert np.count_nonzero(lb.max(axis=1)) == 1
    # The pipeline reads the photos before the solve when the option asks for them.
    notes: list[str] = []
    opts = InvertOptions(window_photo_bounds=True)
    assert _window_photos(root, _room(), None, [WINDOW], opts, notes) is not None
    # ... and for the render window's bounds (the default), only when there is a render
    # window.
    assert _window_photos(root, _room(), None, [WINDOW], InvertOptions(), notes) is not None
    opts = InvertOptions(render_window_photo_bounds=True, render_window_cells=0)
    assert _window_photos(root, _room(), None, [WINDOW], opts, notes) is None


def test_pipeline_builds_the_window_prior_from_the_photos(window_scan, tmp_path):
    from reroom.invert.pipeline import InvertOptions, _window_photo_priors, _window_photos

    root, env = window_scan
    basis = CubemapBasis(4)
    notes: list[str] = []
    # No option that uses them before the solve: not read (the default reads them for
    # the render window's bounds, see test_cell_lower_bounds_never_exceed_the_truth...).
    bare = InvertOptions(render_window_photo_bounds=False)
    assert _window_photos(root, _room(), None, [WINDOW], bare, notes) is None
    off = _window_photo_priors(None, [WINDOW], basis, InvertOptions())
    assert off == [(None, None, {})]
    opts = InvertOptions(window_photo_prior=1e5)
    photos = _window_photos(root, _room(), None, [WINDOW], opts, notes)
    ((prior, weight, info),) = _window_photo_priors(photos, [WINDOW], basis, opts)
    seen = weight > 0
    assert info["photo_prior"]["cells"] == int(seen.sum()) > 0
    assert np.all(weight <= 1e5) and np.all(np.isfinite(prior))
    np.testing.assert_allclose(prior[seen], _cell_means(env, basis)[seen], rtol=0.35)
    # Photos that cannot be read back: no prior, and a note that says why.
    notes.clear()
    assert _window_photos(tmp_path, _room(), None, [WINDOW], opts, notes) is None
    assert "window photos: not used before the solve" in notes[0]
    assert _window_photo_priors(None, [WINDOW], basis, opts) == [(None, None, {})]


def test_cell_shapes_follow_the_photos_with_mean_one_per_cell(window_scan):
    from reroom.invert.window_env import cell_shapes, latlong_lookup

    root, env = window_scan
    basis = CubemapBasis(4)
    (photos,), _ = observe_windows(root, _room(), [WINDOW], height=H)
    shape, info = cell_shapes(photos, basis, min_texels=4, min_samples=16)
    assert shape.shape == (H, 2 * H) and np.all(shape > 0)
    cell = basis.cell_of(latlong_directions(H).reshape(-1, 3))
    area = latlong_solid_angles(H).ravel()
    flat_shape = shape.ravel()
    shaped = np.unique(cell[flat_shape != 1.0])
    assert info["cells_shaped"] >= len(shaped) >= 1 and info["spread"] > 0
    for j in shaped:
        m = cell == j
        assert np.average(flat_shape[m], weights=area[m]) == pytest.approx(1.0, rel=1e-9)
        # Within a cell, the texels the photos saw unsaturated keep the environment's
        # luminance ratios (8-bit steps aside).
        seen = m & (photos.count.ravel() > 0)
        if seen.sum() >= 2:
            lum = env.reshape(-1, 3)[seen] @ np.array([0.2126, 0.7152, 0.0722])
            ratio = flat_shape[seen] / lum
            np.testing.assert_allclose(ratio, ratio.mean(), rtol=0.05)
    # Cells the photos do not see stay flat, and the lookup reads the texel a direction
    # falls in.
    unseen = np.setdiff1d(np.arange(basis.size), np.unique(cell[photos.count.ravel() > 0]))
    assert np.all(flat_shape[np.isin(cell, unseen)] == 1.0)
    look = latlong_lookup(shape)
    d = latlong_directions(H).reshape(-1, 3)
    np.testing.assert_array_equal(look(d), flat_shape)
    # Too few observations: flat everywhere.
    none, info0 = cell_shapes(photos, basis, min_texels=10_000)
    assert np.all(none == 1.0) and info0 == {"cells_shaped": 0, "spread": 0.0}


def test_window_view_spreads_cells_as_the_captured_view():
    from reroom.invert.window_env import WindowView

    basis = CubemapBasis(4)
    env = _environment()  # smooth colours with a bright band: a pattern within cells
    n_in = np.array([0.0, 1.0, 0.0])
    # Any overall scale of the capture: only the pattern is used.
    view = WindowView.from_image(3.0 * env, basis, n_in, samples=2_000_000)
    shown = np.all(view.means > 0, axis=1)
    assert shown.sum() >= 16  # the cells of the half-sphere beyond the wall
    rng = np.random.default_rng(5)
    d = rng.standard_normal((2_000_000, 3))
    d = d[d @ n_in < 0]
    cell = basis.cell_of(d)
    w = view.weight(basis)(d)
    # The transfer's weight is 1 on average over each shown cell's outgoing directions ...
    # (cells with enough samples: the bright band makes the mean noisy in small ones)
    for j in np.flatnonzero(shown):
        if np.count_nonzero(cell == j) >= 20_000:
            assert w[cell == j].mean() == pytest.approx(1.0, rel=0.02)
    # ... and follows the view within it: the bright band weighs several times its cell.
    assert w.max() > 3.0 and w.min() < 1.0
    # The rendering map puts each solved cell where the view puts its light: over the
    # outgoing directions its mean is the solved value, and its pattern is the view's.
    cells = rng.uniform(0.5, 2.0, (basis.size, 3))
    h = H
    m = view.environment(cells, basis, h).reshape(-1, 3)
    dirs = latlong_directions(h).reshape(-1, 3)
    area = latlong_solid_angles(h).ravel()
    out = dirs @ n_in < 0
    c = basis.cell_of(dirs)
    j = int(np.flatnonzero(shown)[0])
    sel = out & (c == j)
    mean = (area[sel, None] * m[sel]).sum(0) / area[sel].sum()
    np.testing.assert_allclose(mean, cells[j], rtol=0.05)
    ratio = m[sel] / env.reshape(-1, 3)[sel]
    np.testing.assert_allclose(ratio, np.broadcast_to(ratio.mean(axis=0), ratio.shape), rtol=0.05)
    # A black view leaves the cells flat.
    flat = WindowView.from_image(np.zeros_like(env), basis, n_in, samples=10_000)
    assert np.all(flat.weight(basis)(d[:100]) == 1.0)


def test_pipeline_rejects_an_unreadable_view_hdri(tmp_path):
    from reroom.errors import ScanError
    from reroom.invert.pipeline import InvertOptions, _window_view

    bad = tmp_path / "view.exr"
    bad.write_text("not an image")
    with pytest.raises(ScanError, match="view.exr"):
        _window_view(InvertOptions(window_view_hdri=str(bad)), CubemapBasis(4), WINDOW)
    from reroom.io.images import write_exr

    for name, img in (
        ("black.exr", np.zeros((8, 16, 3))),
        ("nan.exr", np.full((8, 16, 3), np.nan)),
    ):
        path = tmp_path / name
        write_exr(path, img.astype(np.float32))
        with pytest.raises(ScanError, match=f"{name}.*black or not finite"):
            _window_view(InvertOptions(window_view_hdri=str(path)), CubemapBasis(4), WINDOW)


def test_window_power_counts_the_cells_spread():
    from reroom.invert.export import window_power

    basis = CubemapBasis(4)
    cells = np.random.default_rng(0).uniform(0.5, 2.0, (basis.size, 3))
    n_in = np.array([0.0, 1.0, 0.0])
    flat = window_power(cells, basis, n_in, 1.5)
    twice = window_power(cells, basis, n_in, 1.5, direction_weight=lambda d: np.full(len(d), 2.0))
    np.testing.assert_allclose(twice, 2.0 * flat, rtol=1e-12)
    # A weight of mean 1 over each cell but larger where the cosine is: more flux.
    tilted = window_power(cells, basis, n_in, 1.5, direction_weight=lambda d: 2.0 * np.abs(d[:, 1]))
    assert np.all(tilted > flat)


def test_view_map_shows_the_photos_where_they_saw_the_outdoors(window_scan):
    from reroom.invert.window_env import photo_environments, view_map

    root, env = window_scan
    (photos,), _ = observe_windows(root, _room(), [WINDOW], height=H)
    light = np.full((H, 2 * H, 3), 0.3)
    view, info = view_map(photos, light)
    seen = np.isfinite(photos.mean).all(axis=-1)
    assert info["texels_measured"] == seen.sum() > 40
    # Measured texels: the photos' radiance (not the light map's 0.3); the rest: the
    # light map, raised to what the clipped samples prove.
    np.testing.assert_allclose(view[seen], env[seen], rtol=0.03)
    sat_only = (photos.saturated > 0) & ~seen
    assert sat_only.sum() > 5
    np.testing.assert_allclose(view[sat_only], np.maximum(0.3, photos.bound[sat_only]))
    never = ~seen & (photos.saturated == 0)
    np.testing.assert_allclose(view[never], 0.3)
    # Through photo_environments: the view at its own resolution, the light map as before.
    basis = CubemapBasis(4)
    cells = _cell_means(env, basis)
    maps, infos, _ = photo_environments(
        root, _room(), [(WINDOW, cells)], basis, height=H, view_height=2 * H
    )
    assert infos[0]["view_map"].shape == (2 * H, 4 * H, 3)
    assert infos[0]["view"]["height"] == 2 * H and infos[0]["view"]["texels_measured"] > 100
    assert maps[0].shape == (H, 2 * H, 3)


def test_light_entries_write_the_view_map(tmp_path):
    basis = CubemapBasis(4)
    cells = np.full((basis.size, 3), 0.5)
    geo = {k: getattr(WINDOW, k).tolist() for k in ("centre", "half_u", "half_v", "normal")}
    result = SimpleNamespace(
        cubemap_n=4,
        lights=[SimpleNamespace(name="window0", kind="window")],
        light_info=[{"geometry": geo}],
        solve=SimpleNamespace(intensities={"window0": cells}, light_share={"window0": 1.0}),
    )
    env = np.full((16, 32, 3), 0.7, np.float32)
    view = np.full((32, 64, 3), 2.0, np.float32)
    figures = {"cells_refined": 3, "view_map": view, "view": {"texels_measured": 9}}
    (e,) = light_entries(result, tmp_path, window_maps={"window0": (env, figures)})
    assert e["view_exr"] == "window_window0_view.exr"
    np.testing.assert_allclose(read_exr(tmp_path / e["view_exr"])[..., :3], 2.0)
    assert "view_map" not in e["environment_photos"]  # the array goes to the file only
    assert e["environment_photos"]["view"] == {"texels_measured": 9}
    json.dumps(e)


def test_view_map_takes_a_clipped_pixels_measured_channels_and_the_skys_colour():
    from reroom.invert.window_env import view_map

    h = 8
    mean = np.full((h, 2 * h, 3), np.nan)
    count = np.zeros((h, 2 * h), int)
    bound = np.zeros((h, 2 * h, 3))
    sat = np.zeros((h, 2 * h), int)
    channel = np.full((h, 2 * h, 3), np.nan)
    sky = np.array([0.6, 0.8, 1.0])
    mean[2, :8] = sky * np.linspace(0.5, 1.0, 8)[:, None]  # seen unsaturated; brightest = sky
    count[2, :8] = 3
    channel[2, :8] = mean[2, :8]
    # Clipped in red and green, blue measured at 3: the sky's colour says (1.8, 2.4, 3).
    bound[3, 0], sat[3, 0], channel[3, 0, 2] = [1.0, 1.0, 3.0], 2, 3.0
    # Same, but the bound is above what the colour says in red: the bound wins there.
    bound[3, 1], sat[3, 1], channel[3, 1, 2] = [2.5, 1.0, 3.0], 2, 3.0
    # Clipped everywhere: the light map raised to the bound.
    bound[3, 2], sat[3, 2] = [0.2, 5.0, 0.2], 1
    photos = WindowPhotos(mean, count, bound, sat, channel)
    env = np.full((h, 2 * h, 3), 0.5)
    view, info = view_map(photos, env)
    np.testing.assert_allclose(view[3, 0], [1.8, 2.4, 3.0])
    np.testing.assert_allclose(view[3, 1], [2.5, 2.4, 3.0])
    np.testing.assert_allclose(view[3, 2], [0.5, 5.0, 0.5])
    np.testing.assert_allclose(view[2, :8], mean[2, :8])
    np.testing.assert_allclose(view[5, 5], 0.5)  # never seen: the light map
    assert info == {"texels_measured": 8, "texels_partly_clipped": 2, "texels_from_light": 118}
