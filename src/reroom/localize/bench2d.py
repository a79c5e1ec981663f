"""The synthetic 2D dataset of thesis §6.6.1 and the evaluation behind Table 6.1.

Scenes: an empty diffuse square room of side 1, ``K`` isotropic point lights with
intensities uniform in ``[1, 5]``, no light within 5% of the side of another light or a
wall, 400 measurements evenly spaced along the walls; optionally shot noise
``B + k sqrt(B) z`` with ``k = 0.05``. Every scene is drawn from its own seed
``(seed, K, index)``, so a run over fewer rooms per row evaluates the first rooms of the
full run.

Table 6.1's columns, as this module computes them (see docs/localize.md):

* ``random``: fraction of nonlinear solves from random starts (the light count known)
  reaching a low error, averaged over the scenes;
* ``vote``: one round of voting on ``B``, then the intensity and nonlinear solves reach a
  low error;
* ``full``: Algorithm 1 ends with a low-error solution;
* ``solved``: ``full``, and the solution is the ground truth: as many lights, each matched
  one-to-one to a true light within 2.5% of the side (half the minimum light spacing) and
  10% of its intensity.

"Low error": mean squared error below 0.0025 without noise, below 105% of the ground
truth lighting's own error with noise.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import linear_sum_assignment

from reroom.localize.fields import FieldProposer2D, VoteParams
from reroom.localize.measurements import LocalizeError
from reroom.localize.refine import (
    RefineParams,
    localize_lights,
    random_restarts,
    single_round,
)
from reroom.localize.scene2d import (
    Room2D,
    WallSamples,
    box_room,
    light_bounds,
    render_room,
    sample_walls,
    shot_noise,
)

__all__ = [
    "THESIS_TABLE_6_1",
    "Scene2D",
    "SceneResult",
    "evaluate_scene",
    "make_scene",
    "matches_truth",
    "random_lights",
    "settings_for",
    "summarize",
]

#: Table 6.1 of the thesis: ``(noise, K) -> (random, vote, solved, full, median s, max s)``.
THESIS_TABLE_6_1: dict[tuple[str, int], tuple[float, float, float, float, float, float]] = {
    ("none", 2): (0.77, 0.96, 1.00, 1.00, 2, 64),
    ("none", 3): (0.52, 0.73, 1.00, 1.00, 3, 105),
    ("none", 4): (0.29, 0.35, 1.00, 1.00, 29, 250),
    ("none", 5): (0.26, 0.15, 0.94, 0.97, 85, 442),
    ("shot", 2): (0.80, 0.83, 0.78, 0.99, 2, 52),
    ("shot", 3): (0.53, 0.66, 0.73, 0.98, 13, 492),
    ("shot", 4): (0.32, 0.41, 0.64, 0.95, 34, 301),
    ("shot", 5): (0.23, 0.21, 0.38, 0.84, 80, 378),
}

SHOT_NOISE_K = 0.05
NOISELESS_TOLERANCE = 0.0025


@dataclass(frozen=True)
class Scene2D:
    """One synthetic scene: the room, its wall samples, the true lights and the measurements."""

    room: Room2D
    samples: WallSamples
    positions: np.ndarray
    intensities: np.ndarray
    clean: np.ndarray
    values: np.ndarray
    noise: float

    @property
    def truth_mse(self) -> float:
        """Mean squared error of the true lights against the (noisy) measurements."""
        return float(np.mean((self.values - self.clean) ** 2))

    @property
    def tolerance(self) -> float:
        """The thesis's success threshold on the mean squared error."""
        return NOISELESS_TOLERANCE if self.noise == 0 else 1.05 * self.truth_mse


def random_lights(
    n_lights: int,
    rng: np.random.Generator,
    side: float = 1.0,
    margin: float = 0.05,
    intensity_range: tuple[float, float] = (1.0, 5.0),
    max_tries: int = 100_000,
) -> tuple[np.ndarray, np.ndarray]:
    """Positions and intensities of lights at least ``margin * side`` from walls and each other."""
    if n_lights < 1:
        raise LocalizeError(f"random_lights: need at least one light, got {n_lights}")
    gap = margin * side
    pos: list[np.ndarray] = []
    for _ in range(max_tries):
        p = rng.uniform(gap, side - gap, size=2)
        if all(np.linalg.norm(p - q) >= gap for q in pos):
            pos.append(p)
            if len(pos) == n_lights:
                return np.array(pos), rng.uniform(*intensity_range, size=n_lights)
    raise LocalizeError(f"random_lights: could not place {n_lights} lights {gap} apart")


def make_scene(
    n_lights: int,
    index: int,
    noise: float = 0.0,
    seed: int = 0,
    n_measurements: int = 400,
) -> Scene2D:
    """Scene ``index`` of the ``n_lights`` row, deterministic in ``(seed, n_lights, index)``.

    The lights and the noise come from separate streams, so a scene has the same lights
    with and without noise.
    """
    room = box_room(1.0)
    samples = sample_walls(room, n_measurements)
    pos, inten = random_lights(n_lights, np.random.default_rng([seed, n_lights, index]))
    clean = render_room(room, samples, pos, inten)
    values = clean
    if noise > 0:
        values = shot_noise(clean, noise, np.random.default_rng([seed, n_lights, index, 1]))
    return Scene2D(room, samples, pos, inten, clean, values, noise)


def matches_truth(
    positions: ArrayLike,
    intensities: ArrayLike,
    true_positions: ArrayLike,
    true_intensities: ArrayLike,
    position_tolerance: float = 0.025,
    intensity_tolerance: float = 0.1,
) -> bool:
    """Whether found lights are the true ones: same count, and a one-to-one matching in
    which every light is within ``position_tolerance`` and relative ``intensity_tolerance``.
    Positions may be 2D or 3D (the dimension of ``true_positions``)."""
    t = np.asarray(true_positions, dtype=np.float64)
    dim = t.shape[-1] if t.ndim == 2 else 2
    t = t.reshape(-1, dim)
    p = np.asarray(positions, dtype=np.float64).reshape(-1, dim)
    if p.shape[0] != t.shape[0]:
        return False
    cost = np.linalg.norm(p[:, None, :] - t[None, :, :], axis=-1)
    rows, cols = linear_sum_assignment(cost)
    i = np.asarray(intensities, dtype=np.float64).reshape(-1)[rows]
    ti = np.asarray(true_intensities, dtype=np.float64).reshape(-1)[cols]
    return bool(
        np.all(cost[rows, cols] < position_tolerance)
        and np.all(np.abs(i - ti) <= intensity_tolerance * ti)
    )


def settings_for(noise: float) -> tuple[VoteParams, RefineParams]:
    """Voting and refinement settings: the thesis's ring votes with radius 1 without noise;
    with noise its radius 15, but counting distinct limiters (eq. 6.8, see docs/localize.md)."""
    if noise == 0:
        return VoteParams(method="ring", radius=1), RefineParams()
    return VoteParams(method="count", radius=15), RefineParams()


@dataclass
class SceneResult:
    """Evaluation of one scene (one row of the per-scene log)."""

    n_lights: int
    index: int
    noise: float
    random: float
    vote: bool
    full: bool
    solved: bool
    seconds: float
    cpu_seconds: float
    found: int
    iterations: int
    reason: str
    mse: float
    tolerance: float


def evaluate_scene(
    scene: Scene2D,
    index: int = 0,
    resolution: int = 256,
    random_starts: int = 100,
    vote_params: VoteParams | None = None,
    refine_params: RefineParams | None = None,
    seed: int = 0,
) -> SceneResult:
    """Run the random baseline, one round of voting and the full algorithm on ``scene``."""
    vp, rp = settings_for(scene.noise)
    vp, rp = vote_params or vp, refine_params or rp
    meas = scene.samples.measurements(scene.values)
    bounds = light_bounds(scene.room, scene.samples)
    tol = scene.tolerance
    k = scene.positions.shape[0]
    rate = float("nan")
    if random_starts > 0:
        rng = np.random.default_rng([seed, k, index, 2])
        errs = random_restarts(meas, k, bounds, tol, rng, random_starts)
        rate = float(np.mean(errs < tol))
    proposer = FieldProposer2D(scene.room, scene.samples, resolution, vp)
    vote = single_round(meas, proposer, bounds, tol)
    t0, c0 = time.perf_counter(), time.process_time()
    res = localize_lights(meas, proposer, bounds, tol, rp)
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    solved = res.success and matches_truth(
        res.positions, res.intensities, scene.positions, scene.intensities
    )
    return SceneResult(
        k, index, scene.noise, rate, vote.success, res.success, solved, seconds, cpu,
        int(res.positions.shape[0]), res.iterations, res.reason, res.mse, tol,
    )  # fmt: skip


def summarize(results: list[SceneResult]) -> dict[tuple[str, int], dict[str, float]]:
    """Per ``(noise, K)`` row: rates of each column and median / max runtime of ``full``."""
    rows: dict[tuple[str, int], list[SceneResult]] = {}
    for r in results:
        rows.setdefault(("none" if r.noise == 0 else "shot", r.n_lights), []).append(r)
    out = {}
    for key, rs in sorted(rows.items()):
        secs = np.array([r.seconds for r in rs])
        rand = np.array([r.random for r in rs])
        out[key] = {
            "rooms": float(len(rs)),
            "random": float(np.mean(rand)) if np.isfinite(rand).all() else float("nan"),
            "vote": float(np.mean([r.vote for r in rs])),
            "solved": float(np.mean([r.solved for r in rs])),
            "full": float(np.mean([r.full for r in rs])),
            "median_s": float(np.median(secs)),
            "max_s": float(np.max(secs)),
        }
    return out
