"""Pictures of the 2D scene transforms, like the thesis's Figures 6.1, 6.2 and 6.8."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from reroom.io.atomic import atomic_path
from reroom.localize.fields import FieldProposer2D, VoteParams, medial_axis
from reroom.localize.scene2d import Room2D, WallSamples

__all__ = ["plot_fields"]


def _draw_room(ax, room: Room2D) -> None:
    for loop in room.loops:
        closed = np.vstack([loop, loop[:1]])
        ax.plot(closed[:, 0], closed[:, 1], color="k", lw=1.5)


def _draw_lights(ax, true_positions, found_positions) -> None:
    if true_positions is not None and len(true_positions):
        t = np.asarray(true_positions).reshape(-1, 2)
        ax.scatter(t[:, 0], t[:, 1], s=110, facecolors="none", edgecolors="red", lw=2, label="true")
    if found_positions is not None and len(found_positions):
        f = np.asarray(found_positions).reshape(-1, 2)
        ax.scatter(f[:, 0], f[:, 1], s=70, marker="x", color="lime", lw=2, label="found")


def plot_fields(
    room: Room2D,
    samples: WallSamples,
    values: ArrayLike,
    path: str | Path,
    true_positions: ArrayLike | None = None,
    found_positions: ArrayLike | None = None,
    resolution: int = 256,
    vote_params: VoteParams | None = None,
    title: str | None = None,
) -> Path:
    """Save a PNG with ``D(p)``, ``L(p)`` (with the medial axis) and ``V(p)`` of a 2D scene.

    Parameters
    ----------
    room, samples, values:
        The scene, its measurement sites and the light ``B`` measured there.
    path:
        Output PNG (written atomically).
    true_positions, found_positions:
        Optional ``(K, 2)`` lights drawn as red circles (truth) and green crosses (found).
    resolution, vote_params:
        Field resolution and voting settings (as for :class:`FieldProposer2D`).
    title:
        Figure title.

    Returns
    -------
    The path written.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    prop = FieldProposer2D(room, samples, resolution, vote_params)
    d, lim, v = prop.fields(values)
    axis = medial_axis(lim, samples, prop.threshold, 1)
    ext = prop.grid.extent()
    fig = Figure(figsize=(15, 5.4), dpi=100)
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 3)

    finite = np.isfinite(d) & (d > 0)
    logd = np.full(d.shape, np.nan)
    logd[finite] = np.log10(d[finite])
    im = axes[0].imshow(logd, origin="lower", extent=ext, cmap="magma")
    fig.colorbar(im, ax=axes[0], fraction=0.046, pad=0.04, label="log10 D(p)")
    axes[0].set_title("Intensity-Distance Field D(p)")

    # Colour each limiter by its position along its surface loop, like the thesis's Fig. 6.1d.
    ok = lim >= 0
    frac = np.full(lim.shape, np.nan)
    frac[ok] = samples.arc[lim[ok]] / samples.loop_lengths[samples.loop[lim[ok]]]
    axes[1].imshow(frac, origin="lower", extent=ext, cmap="hsv", interpolation="nearest")
    overlay = np.zeros((*axis.shape, 4))
    overlay[axis] = (1.0, 1.0, 1.0, 0.9)
    axes[1].imshow(overlay, origin="lower", extent=ext, interpolation="nearest")
    axes[1].set_title("Limiter field L(p), medial axis in white")

    im = axes[2].imshow(v, origin="lower", extent=ext, cmap="viridis")
    fig.colorbar(im, ax=axes[2], fraction=0.046, pad=0.04, label="V(p)")
    axes[2].set_title(f"Voting function V(p), r = {prop.params.radius} px")

    for ax in axes:
        _draw_room(ax, room)
        _draw_lights(ax, true_positions, found_positions)
        ax.set_aspect("equal")
        ax.set_xlim(ext[0], ext[1])
        ax.set_ylim(ext[2], ext[3])
    if true_positions is not None or found_positions is not None:
        axes[2].legend(loc="upper right", fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    out = Path(path)
    with atomic_path(out) as tmp:
        fig.savefig(tmp, format="png")
    return out
