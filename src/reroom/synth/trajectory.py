"""Handheld walk-and-look-around camera paths.

A person scanning a room walks a loop through it at eye height, sweeping the
camera left and right and up and down so that walls, floor, ceiling and lights
all get seen, and comes back to where they started (a loop closure, which is
what global exposure calibration must get right). The path follows waypoints
given by the preset, arc-length parameterised, with smooth yaw/pitch sweeps and
small hand jitter.
"""

from __future__ import annotations

import numpy as np

from reroom.scan.camera import look_at


def walk_and_look(
    waypoints: np.ndarray,
    n_frames: int,
    rng: np.random.Generator,
    eye_height: float = 1.5,
    yaw_sweep_deg: float = 75.0,
    sweeps: float = 3.0,
    pitch_range_deg: tuple[float, float] = (-40.0, 35.0),
    closed: bool = True,
    jitter: float = 0.02,
) -> list[np.ndarray]:
    """Camera-to-world poses (OpenGL axes) along a waypoint path.

    Parameters
    ----------
    waypoints:
        ``(K, 2)`` xy points (or ``(K, 3)`` with per-waypoint eye height).
    n_frames:
        Number of poses, spread evenly by arc length.
    yaw_sweep_deg, sweeps:
        Amplitude and number of left-right look-around sweeps per loop; the
        camera looks mostly across the room, at the far walls (to the left of
        the walking direction for a counter-clockwise loop), which covers a
        room in fewer frames than filming the nearest wall.
    pitch_range_deg:
        Range of the up-down sweep (it completes ~2.3 cycles per yaw cycle so
        every yaw sees floor and ceiling at some point).
    closed:
        Return to the first waypoint at the end (loop closure).
    jitter:
        Std of the hand's positional jitter in metres (angles jitter by ~1 deg).
    """
    wp = np.asarray(waypoints, float)
    if wp.shape[1] == 2:
        wp = np.hstack([wp, np.full((len(wp), 1), eye_height)])
    if closed:
        wp = np.vstack([wp, wp[:1]])
    seg = np.linalg.norm(np.diff(wp[:, :2], axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    total = cum[-1]
    s = np.linspace(0.0, total, n_frames, endpoint=not closed)
    pos = np.stack([np.interp(s, cum, wp[:, k]) for k in range(3)], axis=1)
    # Walking direction, smoothed over ~0.6 m so corners do not snap the view.
    ahead = np.stack(
        [
            np.interp(
                np.minimum(s + 0.3, total) if not closed else (s + 0.3) % total, cum, wp[:, k]
            )
            for k in range(2)
        ],
        1,
    )
    behind = np.stack(
        [
            np.interp(np.maximum(s - 0.3, 0) if not closed else (s - 0.3) % total, cum, wp[:, k])
            for k in range(2)
        ],
        1,
    )
    heading = np.arctan2(ahead[:, 1] - behind[:, 1], ahead[:, 0] - behind[:, 0])
    phase = 2 * np.pi * s / max(total, 1e-9)
    yaw = (
        heading
        + np.pi / 2
        + np.radians(yaw_sweep_deg) * np.sin(sweeps * phase + rng.uniform(0, 2 * np.pi))
    )
    lo, hi = np.radians(pitch_range_deg[0]), np.radians(pitch_range_deg[1])
    pitch = 0.5 * (lo + hi) + 0.5 * (hi - lo) * np.sin(
        2.3 * sweeps * phase + rng.uniform(0, 2 * np.pi)
    )
    yaw = yaw + np.radians(1.0) * rng.standard_normal(n_frames)
    pitch = pitch + np.radians(1.0) * rng.standard_normal(n_frames)
    pos = pos + jitter * rng.standard_normal(pos.shape)
    poses = []
    for p, a, b in zip(pos, yaw, pitch, strict=True):
        d = np.array([np.cos(a) * np.cos(b), np.sin(a) * np.cos(b), np.sin(b)])
        c2w = look_at(p, p + d)
        roll = np.radians(1.5) * rng.standard_normal()  # handheld roll
        c, sn = np.cos(roll), np.sin(roll)
        r = c2w[:3, :3] @ np.array([[c, -sn, 0], [sn, c, 0], [0, 0, 1]])
        c2w[:3, :3] = r
        poses.append(c2w)
    return poses
