"""Splitting a solved point light's bins in two (reroom.invert.fine_profiles)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from test_invert_pipeline import _lit_box_scan

from reroom.invert import InvertOptions, run_invert
from reroom.invert.basis import InclinationBasis
from reroom.invert.fine_profiles import apply_shares, bin_solid_angles, coarsen, split_bins
from reroom.io.mesh import read_ply


def test_an_exact_fine_profile_is_recovered_and_each_bin_keeps_its_flux() -> None:
    """Receivers lit by a beam with structure inside the coarse bins (a dip and a
    cut-off): the split recovers it from the coarse solve, flux per bin unchanged."""
    rng = np.random.default_rng(0)
    m, n = 32, 400
    theta = InclinationBasis(2 * m).bin_centres()
    nadir = np.degrees(np.pi - theta)
    beam = np.where(nadir < 28, 2.0 + np.cos(np.radians(12 * nadir)), 0.0)  # a dip, a cut
    truth = beam[:, None] * [1.0, 0.9, 0.7]
    # Each receiver sees a few neighbouring half bins (as a wall sees a band of angles).
    f = np.zeros((n, 2 * m))
    for i in range(n):
        j = rng.integers(0, 2 * m - 3)
        f[i, j : j + 3] = rng.uniform(0.1, 1.0, 3)
    gain = np.full((n, 3), 0.2)
    target = gain * (f @ truth)
    fine_exact, share = split_bins(coarsen(truth), f, target, gain, np.ones((n, 3)), ridge=1e-9)
    np.testing.assert_allclose(fine_exact, truth, rtol=1e-6, atol=1e-9)
    assert share.min() >= 0 and share.max() <= 1
    fine_exact = apply_shares(coarsen(truth), share)
    # With noise the flux of each bin still is the coarse solve's, exactly.
    noisy = target * rng.lognormal(0.0, 0.2, target.shape)
    fine, _ = split_bins(coarsen(truth), f, noisy, gain, np.ones((n, 3)))
    np.testing.assert_allclose(coarsen(fine), coarsen(truth), rtol=1e-12)
    np.testing.assert_allclose(apply_shares(coarsen(truth), share), fine_exact, rtol=1e-9)


def test_bins_no_receiver_sees_stay_even_and_bad_sizes_are_refused() -> None:
    m, n = 4, 50
    coarse = np.ones((m, 3))
    f = np.zeros((n, 2 * m))
    f[:, :2] = 1.0  # only bin 0's halves are seen, with more light in the first half
    w = bin_solid_angles(InclinationBasis(2 * m))
    target = np.full((n, 3), 0.0)
    fine, share = split_bins(coarse, f, target, np.ones((n, 3)), np.ones((n, 3)))
    even = w[0::2] / (w[0::2] + w[1::2])
    np.testing.assert_allclose(share[1:], even[1:], atol=1e-9)
    np.testing.assert_allclose(fine[2:], 1.0, rtol=1e-9)
    with pytest.raises(ValueError, match="expected 8"):
        split_bins(coarse, f[:, :6], target, np.ones((n, 3)), np.ones((n, 3)))


def test_the_pipeline_exports_twice_the_bins_at_the_solve_s_power(tmp_path: Path) -> None:
    """The lit box with its lamp, solved with and without the split: twice the bins
    in `scene.json`, the IES file and the solve's result, the same power."""
    from reroom.lights.lightset import Light, LightSet, write_lights

    truth = np.array([1.4, 1.1, 1.7])
    entries = {}
    for split in (False, True):
        scan = _lit_box_scan(tmp_path / str(split), truth)
        nv = len(read_ply(scan / "hdr" / "hdr_mesh.ply").vertices)
        lamp = Light(
            "lamp", "point", "user", {"position": truth.tolist(), "axis": [0, 0, 1.0]}, {}, "t"
        )
        write_lights(LightSet([lamp], [], np.full(nv, -1, np.int32)), scan / "lights")
        opts = InvertOptions(
            rays_per_receiver=16, receiver_voxel=0.25, pictures=False, refine_points=False,
            point_splits=int(split),
        )  # fmt: skip
        result = run_invert(scan, None, opts)
        entries[split] = json.loads((scan / "invert" / "scene.json").read_text())["lights"][0]
        bins = len(entries[split]["distribution"]["profile"])
        assert bins == (2 * opts.bins if split else opts.bins)
        assert len(result.solve.intensities["lamp"]) == bins
        assert len(entries[split]["distribution"]["support"]) == bins
        assert (scan / "invert" / "lamp.ies").is_file()
    assert entries[True]["distribution"]["split_from_bins"] == opts.bins
    np.testing.assert_allclose(entries[True]["power"], entries[False]["power"], rtol=1e-6)


def test_a_negative_number_of_splits_is_refused_before_any_work(tmp_path: Path) -> None:
    for bad in (
        {"point_splits": -1},
        {"fill_albedo": 0.0},
        {"point_photo_clusters": "wall,sofa"},
        {"point_photo_samples": 10},
        {"window_view_height": -1},
        {"surroundings_min_escape": 1.5},
        {"texture_smooth": -0.5},
        {"texture_smooth": float("nan")},
        {"texture_smooth_wall": -1.0},
        {"texture_smooth_floor": float("inf")},
        {"texture_iterations": 0},
    ):
        with pytest.raises(ValueError, match=next(iter(bad))):
            run_invert(tmp_path / "nothing_here", None, InvertOptions(**bad))
    assert not (tmp_path / "nothing_here").exists()
