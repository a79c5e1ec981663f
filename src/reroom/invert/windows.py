"""Window openings as world rectangles, and which rays leave a room through them.

A window is where distant light (thesis §5.5.2) enters. In a fused scan the
glass is usually a hole, sometimes a surface; :class:`WindowOpening` describes
the opening as a rectangle that :func:`rays_through_windows` tests rays against,
so both cases count as the window.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from reroom.errors import ReroomError

__all__ = ["PERPENDICULAR_TOLERANCE", "WindowOpening", "rays_through_windows"]

#: Largest cosine between a window's two half axes that is taken for rounding and made
#: exact; above it the opening is not a rectangle.
PERPENDICULAR_TOLERANCE = 1e-3


@dataclass
class WindowOpening:
    """A window as a world rectangle ``centre + s half_u + t half_v``, ``|s|, |t| <= 1``.

    Attributes
    ----------
    name:
        A label for reports (``"room0/window1"``).
    centre:
        ``(3,)`` centre, metres, in the mesh's frame.
    half_u, half_v:
        ``(3,)`` perpendicular half-axis vectors (their lengths are the half widths).
    normal:
        ``(3,)`` unit normal pointing into the room.
    """

    name: str
    centre: np.ndarray
    half_u: np.ndarray
    half_v: np.ndarray
    normal: np.ndarray

    def __post_init__(self) -> None:
        for key in ("centre", "half_u", "half_v", "normal"):
            value = np.asarray(getattr(self, key), dtype=np.float64)
            if value.shape != (3,) or not np.isfinite(value).all():
                raise ReroomError(f"window {self.name!r}: {key} must be 3 finite numbers")
            setattr(self, key, value)
        lu, lv, ln = (np.linalg.norm(x) for x in (self.half_u, self.half_v, self.normal))
        if lu == 0 or lv == 0 or ln == 0:
            raise ReroomError(f"window {self.name!r}: zero-length half axis or normal")
        # Files store the axes rounded (lights.json keeps 6 decimals), which on a rotated
        # room leaves them off perpendicular by ~1e-6 relative: accept up to 1e-3 (0.06
        # degrees) and make them exact; anything more is a skewed opening, an error.
        if abs(self.half_u @ self.half_v) > PERPENDICULAR_TOLERANCE * lu * lv:
            raise ReroomError(
                f"window {self.name!r}: half_u and half_v are not perpendicular "
                f"(cosine {self.half_u @ self.half_v / (lu * lv):.2g})"
            )
        self.half_v = self.half_v - (self.half_v @ self.half_u) / lu**2 * self.half_u
        self.normal = self.normal / ln

    @property
    def area(self) -> float:
        """Area of the rectangle, square metres."""
        return float(4.0 * np.linalg.norm(self.half_u) * np.linalg.norm(self.half_v))

    def corners(self) -> np.ndarray:
        """``(4, 3)`` corners, counter-clockwise seen from the room."""
        c, u, v = self.centre, self.half_u, self.half_v
        return np.array([c - u - v, c + u - v, c + u + v, c - u + v])

    @classmethod
    def from_corners(cls, name: str, corners: np.ndarray, normal: np.ndarray) -> WindowOpening:
        """From four corners in order around the rectangle (as ``scene.json`` stores them)."""
        c = np.asarray(corners, dtype=np.float64)
        if c.shape != (4, 3):
            raise ReroomError(f"window {name!r}: corners must be a 4 x 3 array, got {c.shape}")
        return cls(name, c.mean(axis=0), (c[1] - c[0]) / 2.0, (c[3] - c[0]) / 2.0, normal)

    @classmethod
    def from_layout(cls, layout_json: dict, *, at_depth: bool = True) -> list[WindowOpening]:
        """The windows among ``rooms[].openings[]`` of a ``layout.json`` document that
        open outside (one with ``into``, leading into another room, lets in no daylight).

        ``layout.json`` works in its aligned frame (``aligned = rotation @ mesh``);
        the rectangles are returned in the mesh's frame.

        Parameters
        ----------
        layout_json:
            The parsed document (see ``docs/layout.md``).
        at_depth:
            Put the rectangle at the opening's measured ``depth`` behind the wall
            plane (where the glass is, at the back of the reveal), so that rays
            hitting the reveal count as reflected light of the reveal, not as
            distant light. False puts it in the wall plane.

        Raises
        ------
        ReroomError
            If the document lacks the keys used or an opening refers to a missing wall.
        """
        try:
            rot = np.asarray(layout_json.get("rotation", np.eye(3)), dtype=np.float64)
            out = []
            for room in layout_json["rooms"]:
                walls = room["walls"]
                k = 0
                for o in room.get("openings", []):
                    if o["kind"] != "window" or o.get("into"):
                        continue
                    if not 0 <= int(o["wall"]) < len(walls):
                        raise ReroomError(
                            f"layout.json: room {room.get('name')!r} opening on wall "
                            f"{o['wall']} of {len(walls)}"
                        )
                    w = walls[int(o["wall"])]
                    start = np.asarray(w["start"], dtype=np.float64)[:2]
                    end = np.asarray(w["end"], dtype=np.float64)[:2]
                    along = (end - start) / np.linalg.norm(end - start)
                    inward = np.asarray(w["inward_normal"], dtype=np.float64)[:2]
                    inward = inward / np.linalg.norm(inward)
                    s0, s1, z0, z1 = (float(o[key]) for key in ("s0", "s1", "z0", "z1"))
                    depth = max(float(o.get("depth", 0.0)), 0.0) if at_depth else 0.0
                    xy = start + along * (s0 + s1) / 2.0 - inward * depth
                    centre = np.array([xy[0], xy[1], (z0 + z1) / 2.0])
                    half_u = np.array([along[0], along[1], 0.0]) * (s1 - s0) / 2.0
                    half_v = np.array([0.0, 0.0, (z1 - z0) / 2.0])
                    normal = np.array([inward[0], inward[1], 0.0])
                    # aligned = rot @ mesh, so mesh = rot.T @ aligned (rows of rot are orthonormal).
                    out.append(
                        cls(
                            f"{room.get('name', 'room')}/window{k}",
                            rot.T @ centre,
                            rot.T @ half_u,
                            rot.T @ half_v,
                            rot.T @ normal,
                        )
                    )
                    k += 1
            return out
        except (KeyError, TypeError, ValueError) as exc:
            raise ReroomError(f"layout.json: cannot read the window openings ({exc!r})") from exc


def rays_through_windows(
    origins: np.ndarray,
    directions: np.ndarray,
    t_hit: np.ndarray,
    windows: list[WindowOpening],
    *,
    tolerance: float = 0.02,
) -> np.ndarray:
    """Which window, if any, each ray crosses before it hits anything.

    Parameters
    ----------
    origins, directions:
        ``(N, 3)`` rays (unit directions).
    t_hit:
        ``(N,)`` distance to the closest hit (``inf`` for a miss).
    windows:
        The openings.
    tolerance:
        Metres: a ray counts when it crosses the rectangle at most this far
        *behind* its hit (so that a glazed pane lying in the rectangle's plane still
        counts as the window), or crosses the rectangle grown by this much on every
        side with nothing within this distance beyond the crossing (a gap between
        the rectangle and the ragged rim of a hole; the wall around the window
        still stops rays).

    Returns
    -------
    ``(N,)`` int64: index of the window crossed first, or -1.
    """
    n = len(origins)
    best = np.full(n, -1, dtype=np.int64)
    best_t = np.full(n, np.inf)
    for w, win in enumerate(windows):
        denom = directions @ win.normal
        # Rays leaving the room cross the plane against the inward normal.
        leaving = denom < -1e-9
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(leaving, ((win.centre - origins) @ win.normal) / denom, np.inf)
        ok = leaving & (t > 0) & (t <= t_hit + tolerance) & (t < best_t)
        idx = np.flatnonzero(ok)
        if len(idx) == 0:
            continue
        rel = origins[idx] + t[idx, None] * directions[idx] - win.centre
        lu, lv = np.linalg.norm(win.half_u), np.linalg.norm(win.half_v)
        su = np.abs(rel @ (win.half_u / lu)) - lu
        sv = np.abs(rel @ (win.half_v / lv)) - lv
        # Inside the rectangle: counts even if a pane is hit up to `tolerance` before it.
        # In the margin around it: only if nothing lies near the plane there (a gap between
        # the rectangle and the ragged rim of a hole), so the wall beside it does not count.
        inside = (su <= 0) & (sv <= 0)
        margin = (su <= tolerance) & (sv <= tolerance) & (t_hit[idx] > t[idx] + tolerance)
        idx = idx[inside | margin]
        best[idx] = w
        best_t[idx] = t[idx]
    return best
