"""One BLAS thread for the solvers of many small dense problems.

OpenBLAS with a thread per core spends more time waking and joining its threads than
computing on the small matrices of reroom's solves (the exposures' and the lights'
normal equations, the localization's trust-region steps), the more so while numba or
Embree threads share the two cores. Measured on the main job's scan: the lights stage of
``reroom run`` (its localization's ``least_squares`` SVDs) took 46 s with two BLAS
threads and 24 s with one (docs/benchmarks.md, session 47).
"""

from __future__ import annotations

from contextlib import AbstractContextManager, nullcontext

__all__ = ["one_blas_thread"]


def one_blas_thread() -> AbstractContextManager:
    """A context in which BLAS (numpy's and scipy's OpenBLAS) runs on one thread.

    A no-op where threadpoolctl is missing (it comes with scikit-learn, a dependency).
    """
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - threadpoolctl comes with scikit-learn
        return nullcontext()
    return threadpool_limits(1, user_api="blas")
