"""The floorplan figure: a top view of the scan with the recovered rooms and features."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from reroom.layout.labels import CEILING, FLOOR, OTHER, WALL

_COLOURS = {"door": "#2ca02c", "window": "#1f77b4", "passage": "#ff7f0e"}


def floorplan_figure(path: str | Path, result, dpi: int = 110) -> Path:
    """Draw the floorplan of a :class:`~reroom.layout.pipeline.LayoutResult` to ``path``.

    Background: the scan from above (grey: where the mesh has vertices between floor
    and ceiling, darker for more; the walls' vertices tinted). On top: each room's wall
    polygon, the wall candidates of eq. 4.1 (thin), doors, windows and passages drawn
    along their walls, and the baseboard (dotted, just inside the walls).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from reroom.io.atomic import atomic_path

    st = result.structure
    doc = result.layout
    xyz = st.xyz
    zf, zc = st.floor.z, st.ceiling.z
    mid = (xyz[:, 2] > zf + 0.1) & (xyz[:, 2] < zc - 0.1)
    lo = xyz[:, :2].min(axis=0) - 0.3
    hi = xyz[:, :2].max(axis=0) + 0.3
    cell = max(st.r, 0.02)
    bins = np.ceil((hi - lo) / cell).astype(int)
    h_all, xe, ye = np.histogram2d(
        xyz[mid, 0], xyz[mid, 1], bins=bins, range=[[lo[0], hi[0]], [lo[1], hi[1]]]
    )
    shell = np.isin(result.labels, (FLOOR, CEILING))
    h_floor, _, _ = np.histogram2d(
        xyz[shell, 0], xyz[shell, 1], bins=bins, range=[[lo[0], hi[0]], [lo[1], hi[1]]]
    )
    wall = mid & (result.labels == WALL)
    h_wall, _, _ = np.histogram2d(
        xyz[wall, 0], xyz[wall, 1], bins=bins, range=[[lo[0], hi[0]], [lo[1], hi[1]]]
    )
    other = mid & (result.labels == OTHER)
    h_other, _, _ = np.histogram2d(
        xyz[other, 0], xyz[other, 1], bins=bins, range=[[lo[0], hi[0]], [lo[1], hi[1]]]
    )
    img = np.ones((*h_all.shape, 3))
    img[h_floor > 0] = (0.93, 0.93, 0.90)
    dens = np.clip(np.log1p(h_other) / np.log1p(max(h_other.max(), 1)), 0, 1)
    img -= 0.45 * dens[..., None] * np.array([1.0, 1.0, 1.0])
    wd = np.clip(np.log1p(h_wall) / np.log1p(max(h_wall.max(), 1)), 0, 1)
    img = img * (1 - 0.6 * wd[..., None]) + 0.6 * wd[..., None] * np.array([0.55, 0.35, 0.6])
    img = np.clip(img, 0, 1)

    size = (hi - lo) / max(hi - lo) * 9.0
    fig, ax = plt.subplots(figsize=(max(size[0], 4.0) + 1.5, max(size[1], 3.5) + 1.0))
    ax.imshow(
        np.transpose(img, (1, 0, 2)),
        origin="lower",
        extent=(lo[0], hi[0], lo[1], hi[1]),
        interpolation="nearest",
    )
    for s in st.segments:
        a, b = s.endpoints()
        ax.plot([a[0], b[0]], [a[1], b[1]], color="#999999", lw=0.8, zorder=2)
    for room in doc["rooms"]:
        p = np.asarray(room["polygon"])
        q = np.vstack([p, p[:1]])
        ax.plot(q[:, 0], q[:, 1], color="black", lw=2.2, zorder=3)
        c = p.mean(axis=0)
        ax.text(
            c[0],
            c[1],
            f"{room['name']}\n{room['area']:.1f} m²",
            ha="center",
            va="center",
            fontsize=8,
            zorder=5,
        )
        walls = room["walls"]
        for o in room["openings"]:
            w = walls[o["wall"]]
            a = np.asarray(w["start"])
            t = (np.asarray(w["end"]) - a) / w["length"]
            n = np.asarray(w["inward_normal"])
            p0, p1 = a + t * o["s0"], a + t * o["s1"]
            col = _COLOURS.get(o["kind"], "red")
            ax.plot(
                [p0[0], p1[0]], [p0[1], p1[1]], color=col, lw=6, solid_capstyle="butt", zorder=4
            )
            m = 0.5 * (p0 + p1) + n * 0.25
            ax.text(
                m[0], m[1], o["kind"], color=col, fontsize=7, ha="center", va="center", zorder=5
            )
        bb = room.get("baseboard")
        if bb:
            for piece in bb["pieces"]:
                w = walls[piece["wall"]]
                a = np.asarray(w["start"])
                t = (np.asarray(w["end"]) - a) / w["length"]
                n = np.asarray(w["inward_normal"])
                p0 = a + t * piece["s0"] + n * 0.06
                p1 = a + t * piece["s1"] + n * 0.06
                ax.plot([p0[0], p1[0]], [p0[1], p1[1]], color="#d62728", lw=1.0, ls=":", zorder=4)
    handles = [
        plt.Line2D([], [], color="black", lw=2.2, label="walls (recovered)"),
        plt.Line2D([], [], color="#999999", lw=0.8, label="wall candidates (eq. 4.1)"),
        *[plt.Line2D([], [], color=c, lw=6, label=k) for k, c in _COLOURS.items()],
        plt.Line2D([], [], color="#d62728", lw=1.0, ls=":", label="baseboard"),
    ]
    ax.legend(
        handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7, frameon=False
    )
    bbh = [r["baseboard"]["height"] for r in doc["rooms"] if r.get("baseboard")]
    title = f"floor {zf:.3f} m, ceiling {zc:.3f} m"
    if bbh:
        title += f", baseboard {100 * bbh[0]:.1f} cm"
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal")
    fig.tight_layout()
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return path
