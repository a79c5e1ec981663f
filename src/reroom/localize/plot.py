"""Pictures of the scene transforms, like the thesis's Figures 6.1, 6.2 and 6.8 (2D and 3D slices)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from reroom.io.atomic import atomic_path
from reroom.localize.fields import FieldProposer2D, VoteParams, medial_axis
from reroom.localize.scene2d import Room2D, WallSamples

__all__ = ["plot_fields", "plot_fields_3d"]


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


def plot_fields_3d(
    proposer,
    values: ArrayLike,
    path: str | Path,
    true_positions: ArrayLike | None = None,
    found_positions: ArrayLike | None = None,
    heights: ArrayLike | None = None,
    title: str | None = None,
) -> Path:
    """Save a PNG of horizontal slices of the 3D ``D``, ``L`` and ``V`` (one row per height).

    Parameters
    ----------
    proposer:
        A :class:`~reroom.localize.scene3d.FieldProposer3D` (its grid, sites and vote).
    values:
        The light ``B`` at its sites.
    path:
        Output PNG (written atomically).
    true_positions, found_positions:
        Optional ``(K, 3)`` lights: red circles (truth) and green crosses (found), drawn in
        every slice, smaller the farther they are from it.
    heights:
        z of the slices (default: the true lights' heights, else the grid's middle).
    title:
        Figure title.

    Returns
    -------
    The path written.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    grid = proposer.grid
    d, lim, v = proposer.fields(values)
    xs, ys, zs = grid.axes()
    if heights is None:
        heights = (
            np.asarray(true_positions, float).reshape(-1, 3)[:, 2]
            if true_positions is not None and len(true_positions)
            else [zs[len(zs) // 2]]
        )
    heights = np.atleast_1d(np.asarray(heights, float))
    ext = [
        xs[0] - grid.voxel / 2,
        xs[-1] + grid.voxel / 2,
        ys[0] - grid.voxel / 2,
        ys[-1] + grid.voxel / 2,
    ]
    fig = Figure(figsize=(15, 4.8 * len(heights)), dpi=90)
    FigureCanvasAgg(fig)
    axes = np.atleast_2d(fig.subplots(len(heights), 3))
    # Limiters coloured by their site's position around the scene (angle about the centre).
    centre = proposer.points.mean(axis=0)
    angle = np.arctan2(proposer.points[:, 1] - centre[1], proposer.points[:, 0] - centre[0])
    hue_of = (angle / (2 * np.pi) + 0.5 + 0.37 * proposer.points[:, 2]) % 1.0
    for row, z in zip(axes, heights, strict=True):
        k = int(np.clip(np.rint((z - zs[0]) / grid.voxel), 0, len(zs) - 1))
        dk, lk, vk = d[:, :, k].T, lim[:, :, k].T, v[:, :, k].T
        finite = np.isfinite(dk) & (dk > 0)
        logd = np.full(dk.shape, np.nan)
        logd[finite] = np.log10(dk[finite])
        im = row[0].imshow(logd, origin="lower", extent=ext, cmap="magma")
        fig.colorbar(im, ax=row[0], fraction=0.046, pad=0.04, label="log10 D(p)")
        hue = np.full(lk.shape, np.nan)
        hue[lk >= 0] = hue_of[lk[lk >= 0]]
        row[1].imshow(hue, origin="lower", extent=ext, cmap="hsv", interpolation="nearest")
        im = row[2].imshow(vk, origin="lower", extent=ext, cmap="viridis")
        fig.colorbar(im, ax=row[2], fraction=0.046, pad=0.04, label="V(p)")
        row[0].set_title(f"D(p), z = {zs[k]:.2f}")
        row[1].set_title(f"L(p) (limiter site), z = {zs[k]:.2f}")
        row[2].set_title(f"V(p) (distinct limiters, r = {proposer.params.radius}), z = {zs[k]:.2f}")
        for ax in row:
            for pts, style in ((true_positions, "true"), (found_positions, "found")):
                if pts is None or not len(pts):
                    continue
                p = np.asarray(pts, float).reshape(-1, 3)
                size = 120.0 / (1.0 + (np.abs(p[:, 2] - zs[k]) / (4 * grid.voxel)) ** 2)
                if style == "true":
                    ax.scatter(p[:, 0], p[:, 1], s=size, facecolors="none", edgecolors="red", lw=2)
                else:
                    ax.scatter(p[:, 0], p[:, 1], s=0.7 * size, marker="x", color="lime", lw=2)
            ax.set_xlim(ext[0], ext[1])
            ax.set_ylim(ext[2], ext[3])
            ax.set_aspect("equal")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    out = Path(path)
    with atomic_path(out) as tmp:
        fig.savefig(tmp, format="png")
    return out
