"""benchmarks/bench_view_error.py: where in a view the error is (blocks, boxes, holes)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_view_error.py"
FIDELITY = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_edit_fidelity.py"


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(BENCH), *args], capture_output=True, text=True, timeout=120
    )


def test_holes_boxes_and_blocks_of_a_saved_pair(tmp_path):
    import importlib.util

    spec = importlib.util.spec_from_file_location("bench_edit_fidelity", FIDELITY)
    fidelity = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(fidelity)
    truth = np.full((40, 60, 3), 1.0)
    ours = truth.copy()
    ours[0:10, 0:20] = 0.0  # a hole: 200 pixels black in ours, lit in the truth
    ours[30:40, 40:60] *= 0.5  # a dim patch: 200 pixels at half
    fidelity.save_pair(tmp_path / "pairs" / "reference_new1.npz", ours, truth)
    assert not list((tmp_path / "pairs").glob("*.partial*"))
    out = _run(str(tmp_path), "reference", "new1", "--block", "20", "--box", "dim:30:40:40:60")
    assert out.returncode == 0, out.stderr
    text = out.stdout
    # Squared error: 200 x 3 from the hole, 200 x 3 x 0.25 from the patch.
    share_hole = 600 / (600 + 150)
    assert f"200 pixels, {share_hole:.1%} of the squared error" in text
    assert f"box dim [30:40, 40:60]: {1 - share_hole:.1%}" in text
    assert "ratio 0.500/0.500/0.500" in text
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if "per 20 x 20 block" in line) + 1
    end = lines.index("", start)
    grid = np.array([[float(x) for x in line.split()] for line in lines[start:end]])
    assert grid.shape == (2, 3) and abs(grid.sum() - 100.0) < 0.5
    assert abs(grid[0, 0] - 100 * share_hole) < 0.1


def test_a_missing_pair_is_named(tmp_path):
    out = _run(str(tmp_path), "reference", "new1")
    assert out.returncode != 0
    assert "reference_new1.npz: no such file" in out.stderr
