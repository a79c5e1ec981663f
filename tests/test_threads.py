"""BLAS on one thread where reroom's small dense solves run (reroom.threads)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from reroom.threads import one_blas_thread

threadpoolctl = pytest.importorskip("threadpoolctl")


def _blas_threads() -> list[int]:
    return [i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"]


def test_one_blas_thread_limits_blas_inside_and_restores_it() -> None:
    np.linalg.svd(np.eye(3))  # numpy's BLAS is loaded
    before = _blas_threads()
    with one_blas_thread():
        inside = _blas_threads()
    assert inside and all(n == 1 for n in inside)
    assert _blas_threads() == before


def test_localize_scan_fits_on_one_blas_thread(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    import reroom.localize.scan as scan_module

    seen: list[int] = []

    def search(scan_dir, options, progress):
        seen.extend(_blas_threads())
        return "found"

    monkeypatch.setattr(scan_module, "_localize_scan", search)
    assert scan_module.localize_scan(tmp_path) == "found"
    assert seen and all(n == 1 for n in seen)
