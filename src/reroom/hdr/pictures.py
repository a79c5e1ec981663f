"""Pictures of the HDR stage for people: exposure curves and textured-mesh renders.

Renders are ray cast (Embree) with per-vertex colours interpolated over the
triangles and no shading at all, so what one sees is the texture (the radiance)
itself. Two kinds of camera: a *dollhouse* view from above and outside the room
(faces seen from behind are skipped, so the ceiling and the near walls do not
hide the room), and a view from inside the room at a scan frame's pose with a
wider field of view.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from reroom.io.atomic import atomic_path
from reroom.io.images import linear_to_srgb
from reroom.rays import RayCaster
from reroom.scan import Frame, Intrinsics, look_at

__all__ = [
    "dollhouse_camera",
    "inside_camera",
    "plot_exposures",
    "render_vertex_colors",
    "save_panels",
    "to_display",
]

#: Colour of unobserved surfaces in renders (a dull magenta nobody mistakes for radiance).
UNOBSERVED = np.array([0.55, 0.25, 0.55])


def to_display(linear: np.ndarray, gain: float) -> np.ndarray:
    """Linear values times ``gain``, clipped to [0, 1] ("linearly tonemapped and clipped")."""
    return np.clip(np.asarray(linear, np.float64) * gain, 0.0, 1.0)


def dollhouse_camera(
    vertices: np.ndarray,
    width: int = 480,
    height: int = 360,
    azimuth_deg: float = 35.0,
    elevation_deg: float = 55.0,
    fov_y_deg: float = 45.0,
) -> tuple[np.ndarray, Intrinsics]:
    """A camera above and outside the mesh's bounding box, looking at its centre."""
    v = np.asarray(vertices, np.float64)
    lo, hi = v.min(axis=0), v.max(axis=0)
    center = (lo + hi) / 2.0
    radius = 0.5 * float(np.linalg.norm(hi - lo))
    dist = radius / np.sin(np.radians(fov_y_deg) / 2.0) * 1.05
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    direction = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    c2w = look_at(center + dist * direction, center)
    return c2w, Intrinsics.from_fov(width, height, fov_y_deg)


def inside_camera(
    frames: list[Frame],
    width: int = 480,
    height: int = 360,
    fov_y_deg: float = 70.0,
    pitch_deg: float = -10.0,
) -> tuple[np.ndarray, Intrinsics]:
    """A wide view from inside the room: at the mean camera position, looking level.

    The heading is frame 0's viewing direction projected on the floor (+X if it
    looks straight up or down), tilted by ``pitch_deg``; walls fill the view,
    where the seams of a naive texture are easiest to see.
    """
    eye = np.mean([f.center for f in frames], axis=0)
    fwd = np.asarray(frames[0].forward, np.float64).copy()
    fwd[2] = 0.0
    if np.linalg.norm(fwd) < 1e-6:
        fwd = np.array([1.0, 0.0, 0.0])
    fwd /= np.linalg.norm(fwd)
    p = np.radians(pitch_deg)
    target = eye + np.cos(p) * fwd + np.array([0.0, 0.0, np.sin(p)])
    return look_at(eye, target), Intrinsics.from_fov(width, height, fov_y_deg)


def render_vertex_colors(
    caster: RayCaster,
    colors: np.ndarray,
    c2w: np.ndarray,
    intrinsics: Intrinsics,
    *,
    valid: np.ndarray | None = None,
    cull_backfaces: bool = True,
    background: tuple[float, float, float] = (1.0, 1.0, 1.0),
    max_layers: int = 6,
) -> np.ndarray:
    """Ray cast the mesh with per-vertex display colours; return ``(H, W, 3)`` uint8 sRGB.

    Parameters
    ----------
    caster:
        Ray caster of the mesh (its faces index ``colors``).
    colors:
        ``(V, 3)`` linear display values in [0, 1].
    valid:
        ``(V,)`` bool; surfaces interpolated mostly from invalid vertices are drawn
        in :data:`UNOBSERVED`.
    cull_backfaces:
        Skip faces seen from behind (up to ``max_layers`` of them per ray).
    """
    frame = Frame(0, Path(), np.asarray(c2w, np.float64), intrinsics)
    o, d = frame.pixel_rays()
    n = len(o)
    face = np.full(n, -1, np.int64)
    bary = np.zeros((n, 3))
    todo = np.arange(n)
    origin = o.copy()
    for _ in range(max_layers):
        if len(todo) == 0:
            break
        hits = caster.intersect(origin[todo], d[todo])
        hit = hits.hit
        back = np.zeros(len(todo), bool)
        if cull_backfaces:
            back = hit & (np.einsum("ij,ij->i", hits.normals, d[todo]) > 0)
        front = hit & ~back
        face[todo[front]] = hits.face[front]
        bary[todo[front]] = hits.barycentric[front]
        # Step just past a back face and look again.
        nxt = todo[back]
        origin[nxt] = hits.points[back] + d[nxt] * caster.eps
        todo = nxt
    has = face >= 0
    tri = caster.faces[np.maximum(face, 0)]
    col = np.einsum("ij,ijk->ik", bary, np.asarray(colors, np.float64)[tri])
    if valid is not None:
        frac = np.einsum("ij,ij->i", bary, np.asarray(valid, np.float64)[tri])
        col[frac < 0.5] = UNOBSERVED
    out = np.where(has[:, None], col, np.asarray(background, np.float64))
    img = linear_to_srgb(out).reshape(intrinsics.height, intrinsics.width, 3)
    return np.clip(np.round(img * 255.0), 0, 255).astype(np.uint8)


def save_panels(
    path: str | Path,
    panels: list[list[tuple[str, np.ndarray]]],
    title: str | None = None,
) -> Path:
    """Save a grid of titled images (rows of ``(title, uint8 image)``) as one PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows, cols = len(panels), max(len(r) for r in panels)
    h, w = panels[0][0][1].shape[:2]
    scale = 4.2 / w
    fig, axes = plt.subplots(
        rows, cols, figsize=(cols * w * scale, rows * (h * scale + 0.35) + 0.3), squeeze=False
    )
    for r, row in enumerate(panels):
        for c in range(cols):
            ax = axes[r][c]
            ax.axis("off")
            if c < len(row):
                ax.imshow(row[c][1])
                ax.set_title(row[c][0], fontsize=9)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return Path(path)


def plot_exposures(
    path: str | Path,
    curves: dict[str, np.ndarray],
    title: str = "Per-frame scales (exposure x white balance)",
    truth: np.ndarray | None = None,
) -> Path:
    """Plot per-frame scales: log2 of the green channel, and R/G, B/G white balance.

    ``curves`` maps a method name to ``(F, 3)`` scales (NaN = none); ``truth``
    (optional, ``(F, 3)``) adds the true curve and a panel of ratio errors.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n_rows = 3 if truth is not None else 2
    fig, axes = plt.subplots(n_rows, 1, figsize=(8.5, 2.4 * n_rows + 0.6), sharex=True)
    styles = {
        "ours (global)": dict(color="C0", lw=1.6),
        "frame-to-frame": dict(color="C1", lw=1.0),
        "frame-to-model": dict(color="C2", lw=1.0),
        "truth": dict(color="k", lw=1.0, ls="--"),
    }
    all_curves = dict(curves)
    if truth is not None:
        all_curves["truth"] = truth
    for name, s in all_curves.items():
        s = np.asarray(s, np.float64)
        x = np.arange(len(s))
        st = styles.get(name, {})
        with np.errstate(invalid="ignore", divide="ignore"):
            axes[0].plot(x, np.log2(s[:, 1]), label=name, **st)
            axes[1].plot(x, s[:, 0] / s[:, 1], **st)
            axes[1].plot(x, s[:, 2] / s[:, 1], **{**st, "alpha": 0.6})
    axes[0].set_ylabel("log2 t (green)")
    axes[0].legend(fontsize=8, ncol=4, loc="best")
    axes[1].set_ylabel("R/G and B/G")
    if truth is not None:
        tr = np.asarray(truth, np.float64)
        for name, s in curves.items():
            with np.errstate(invalid="ignore", divide="ignore"):
                err = 100.0 * np.max(np.abs(np.asarray(s) / tr - 1.0), axis=1)
            axes[2].semilogy(np.arange(len(s)), np.maximum(err, 1e-3), **styles.get(name, {}))
        axes[2].set_ylabel("ratio error %\n(worst channel)")
    axes[-1].set_xlabel("frame")
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return Path(path)
