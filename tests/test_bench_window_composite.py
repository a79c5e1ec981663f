"""The benchmarks' helpers: the fidelity composite (one run's model with another run's window
maps) and the window-cell comparison's input checks."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_edit_fidelity.py"


def _bench():
    spec = importlib.util.spec_from_file_location("bench_edit_fidelity", BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _run(root: Path, window_bytes: bytes, lights: list[dict]) -> Path:
    (root / "invert" / "textures").mkdir(parents=True)
    (root / "hdr").mkdir()
    (root / "hdr" / "exposures.json").write_text("{}")
    (root / "invert" / "scene.json").write_text(json.dumps({"lights": lights}))
    (root / "invert" / "textures" / "wall.exr").write_bytes(b"texture of " + root.name.encode())
    (root / "invert" / "window_window0.exr").write_bytes(window_bytes)
    return root


def test_composite_takes_only_the_window_maps_from_the_donor(tmp_path):
    lights = [{"name": "area0", "type": "area"}, {"name": "window0", "type": "window"}]
    run = _run(tmp_path / "run", b"4x4 cells", lights)
    donor = _run(tmp_path / "donor", b"8x8 cells", lights)
    out = _bench().composite_window_maps(run, donor, tmp_path / "composite")
    assert (out / "invert" / "window_window0.exr").read_bytes() == b"8x8 cells"
    assert (out / "invert" / "textures" / "wall.exr").read_bytes() == b"texture of run"
    assert (out / "hdr").is_symlink() and (out / "hdr").resolve() == (run / "hdr").resolve()
    # The run itself is left as it was.
    assert (run / "invert" / "window_window0.exr").read_bytes() == b"4x4 cells"


def test_composite_refuses_a_donor_without_the_map_or_a_run_without_a_window(tmp_path):
    bench = _bench()
    run = _run(tmp_path / "run", b"4x4", [{"name": "window0", "type": "window"}])
    donor = tmp_path / "donor"
    (donor / "invert").mkdir(parents=True)
    with pytest.raises(SystemExit, match="window_window0.exr"):
        bench.composite_window_maps(run, donor, tmp_path / "c1")
    bare = _run(tmp_path / "bare", b"-", [{"name": "area0", "type": "area"}])
    with pytest.raises(SystemExit, match="no window"):
        bench.composite_window_maps(bare, run, tmp_path / "c2")


def test_window_cells_benchmark_names_what_is_missing(tmp_path):
    spec = importlib.util.spec_from_file_location(
        "bench_window_cells", BENCH.parent / "bench_window_cells.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    with pytest.raises(SystemExit, match="scene.json is missing"):
        module.solved_cells(tmp_path, "window0")
    (tmp_path / "invert").mkdir()
    (tmp_path / "invert" / "scene.json").write_text(json.dumps({"lights": [{"name": "area0"}]}))
    with pytest.raises(SystemExit, match="no window named 'window0'"):
        module.solved_cells(tmp_path, "window0")
    (tmp_path / "invert" / "scene.json").write_text(
        json.dumps({"lights": [{"name": "window0", "type": "window", "distribution": {}}]})
    )
    with pytest.raises(SystemExit, match="has no render_distribution"):
        module.solved_cells(tmp_path, "window0", render=True)


def test_window_view_benchmark_turns_as_the_evaluation_and_names_what_is_missing(
    tmp_path, monkeypatch
):
    import sys

    import numpy as np

    spec = importlib.util.spec_from_file_location(
        "bench_window_view", BENCH.parent / "bench_window_view.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    # reroom.invert.evaluate turns the HDRI's texel directions by +rotation_deg about +Z
    # (+x to +y at 90 degrees); the benchmark turns a pixel's direction back.
    np.testing.assert_allclose(
        module._turn_z(np.array([[1.0, 0.0, 0.0]]), 90.0), [[0, 1, 0]], atol=1e-12
    )
    d = np.random.default_rng(0).normal(size=(20, 3))
    np.testing.assert_allclose(module._turn_z(module._turn_z(d, 37.0), -37.0), d, atol=1e-12)
    monkeypatch.setattr(sys, "argv", ["bench_window_view.py", str(tmp_path)])
    with pytest.raises(SystemExit, match="scene.json is missing"):
        module.main()
    (tmp_path / "invert").mkdir()
    (tmp_path / "invert" / "scene.json").write_text(json.dumps({"lights": []}))
    with pytest.raises(SystemExit, match="a synthetic scan's truth is needed"):
        module.main()


def test_edit_footprint_is_where_the_truth_changed_and_measures_ours_there():
    import numpy as np

    bench = _bench()
    rng = np.random.default_rng(1)
    ref = 0.5 + 0.01 * rng.random((32, 48, 3))
    tru = ref.copy()
    tru[8:16, 12:24] *= 0.4  # a shadow: 8 x 12 pixels, 60 % darker
    # ours darkens the same pixels by half as much, and is 2 % off elsewhere
    ours_ref = ref * 1.02
    ours = ours_ref.copy()
    ours[8:16, 12:24] *= 0.7
    f = bench.edit_footprint(ours, tru, ours_ref, ref)
    assert f["footprint_share"] == (8 * 12) / (32 * 48)
    assert np.isclose(f["change_ratio"], (0.3 * 1.02) / 0.6, rtol=1e-6)
    want = np.linalg.norm(ours[8:16, 12:24] - tru[8:16, 12:24]) / np.linalg.norm(tru[8:16, 12:24])
    assert np.isclose(f["rel_rmse_footprint"], want)
    # an edit that changes nothing in the view: no footprint
    none = bench.edit_footprint(ours_ref, ref, ours_ref, ref)
    assert none == {"footprint_share": 0.0, "rel_rmse_footprint": None, "change_ratio": None}


def test_window_swap_benchmark_names_what_is_missing(tmp_path, monkeypatch):
    import sys

    spec = importlib.util.spec_from_file_location(
        "bench_window_swap", BENCH.parent / "bench_window_swap.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    monkeypatch.setattr(sys, "argv", ["bench_window_swap.py", str(tmp_path)])
    with pytest.raises(SystemExit, match="scene.json is missing"):
        module.main()
    (tmp_path / "invert").mkdir()
    (tmp_path / "invert" / "scene.json").write_text(
        json.dumps({"lights": [{"name": "window0", "type": "area"}]})
    )
    with pytest.raises(SystemExit, match="no window named 'window0'"):
        module.main()
