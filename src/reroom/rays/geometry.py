"""Small point-geometry helpers shared by the stages (line lights' capsules, fittings)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["segment_closest", "segment_distance"]


def segment_closest(p: ArrayLike, a: ArrayLike, b: ArrayLike) -> np.ndarray:
    """``(N, 3)``: the point of the segment ``a``-``b`` nearest each point of ``p``."""
    p = np.asarray(p, float)
    a = np.asarray(a, float)
    ab = np.asarray(b, float) - a
    t = np.clip(((p - a) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
    return a + t[:, None] * ab


def segment_distance(p: ArrayLike, a: ArrayLike, b: ArrayLike) -> np.ndarray:
    """Distance of each point of ``p`` ``(N, 3)`` to the segment ``a``-``b`` (a point if equal)."""
    return np.linalg.norm(np.asarray(p, float) - segment_closest(p, a, b), axis=1)
