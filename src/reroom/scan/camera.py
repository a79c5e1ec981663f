"""Pinhole / OpenCV camera models and posed frames.

Conventions (see ``docs/formats.md``):

* World: metres, +Z up.
* ``c2w`` is the 4x4 camera-to-world matrix in **OpenGL** camera axes
  (x right, y up, looking down -z), as in nerfstudio's ``transforms.json``.
* Pixel coordinates: ``(u, v)`` with the origin at the top-left corner of the
  top-left pixel, so the centre of pixel ``(i, j)`` is ``(j + 0.5, i + 0.5)``.
  Intrinsics ``cx, cy`` use the same convention.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from reroom.io.images import read_depth_mm, read_rgb8

#: Flip between OpenGL camera axes (y up, -z forward) and OpenCV axes (y down, +z forward).
GL_TO_CV = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class Intrinsics:
    """Camera intrinsics: image size, focal lengths, principal point, distortion.

    ``model`` is ``"PINHOLE"`` or ``"OPENCV"`` (radial ``k1, k2`` and tangential
    ``p1, p2`` coefficients, OpenCV's convention).
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    model: str = "PINHOLE"
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0

    @property
    def K(self) -> np.ndarray:
        """The 3x3 calibration matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def has_distortion(self) -> bool:
        return self.model == "OPENCV" and any((self.k1, self.k2, self.p1, self.p2))

    @property
    def fov_y_deg(self) -> float:
        """Vertical field of view in degrees (ignoring distortion)."""
        return float(np.degrees(2.0 * np.arctan2(self.height / 2.0, self.fy)))

    def scaled(self, factor: float) -> Intrinsics:
        """The intrinsics of the same camera with the image resized by ``factor``."""
        return Intrinsics(
            width=round(self.width * factor),
            height=round(self.height * factor),
            fx=self.fx * factor,
            fy=self.fy * factor,
            cx=self.cx * factor,
            cy=self.cy * factor,
            model=self.model,
            k1=self.k1,
            k2=self.k2,
            p1=self.p1,
            p2=self.p2,
        )

    def distort(self, xn: np.ndarray, yn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Apply the lens distortion to normalised image coordinates."""
        if not self.has_distortion:
            return xn, yn
        r2 = xn * xn + yn * yn
        radial = 1.0 + self.k1 * r2 + self.k2 * r2 * r2
        xd = xn * radial + 2.0 * self.p1 * xn * yn + self.p2 * (r2 + 2.0 * xn * xn)
        yd = yn * radial + self.p1 * (r2 + 2.0 * yn * yn) + 2.0 * self.p2 * xn * yn
        return xd, yd

    def undistort(
        self, xd: np.ndarray, yd: np.ndarray, iterations: int = 20
    ) -> tuple[np.ndarray, np.ndarray]:
        """Invert :meth:`distort` by fixed-point iteration (accurate for mild distortion)."""
        if not self.has_distortion:
            return xd, yd
        xn, yn = xd.copy(), yd.copy()
        for _ in range(iterations):
            r2 = xn * xn + yn * yn
            radial = 1.0 + self.k1 * r2 + self.k2 * r2 * r2
            dx = 2.0 * self.p1 * xn * yn + self.p2 * (r2 + 2.0 * xn * xn)
            dy = self.p1 * (r2 + 2.0 * yn * yn) + 2.0 * self.p2 * xn * yn
            xn = (xd - dx) / radial
            yn = (yd - dy) / radial
        return xn, yn

    def to_json(self) -> dict:
        d = {
            "camera_model": self.model,
            "w": self.width,
            "h": self.height,
            "fl_x": self.fx,
            "fl_y": self.fy,
            "cx": self.cx,
            "cy": self.cy,
        }
        if self.model == "OPENCV":
            d.update(k1=self.k1, k2=self.k2, p1=self.p1, p2=self.p2)
        return d

    @staticmethod
    def from_fov(width: int, height: int, fov_y_deg: float) -> Intrinsics:
        """A centred pinhole camera with square pixels and the given vertical field of view."""
        f = (height / 2.0) / np.tan(np.radians(fov_y_deg) / 2.0)
        return Intrinsics(width, height, float(f), float(f), width / 2.0, height / 2.0)


@dataclass
class Frame:
    """One posed image of a scan. Pixels are read lazily, on demand."""

    index: int
    image_path: Path
    c2w: np.ndarray
    intrinsics: Intrinsics
    depth_path: Path | None = None
    extra: dict = field(default_factory=dict)

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates."""
        return self.c2w[:3, 3].copy()

    @property
    def forward(self) -> np.ndarray:
        """Unit viewing direction (the optical axis) in world coordinates."""
        return -self.c2w[:3, 2] / np.linalg.norm(self.c2w[:3, 2])

    @property
    def w2c(self) -> np.ndarray:
        """World-to-camera matrix (OpenGL axes)."""
        r = self.c2w[:3, :3]
        t = self.c2w[:3, 3]
        out = np.eye(4)
        out[:3, :3] = r.T
        out[:3, 3] = -r.T @ t
        return out

    def load_image(self) -> np.ndarray:
        """Decode the frame's 8-bit RGB image, checking its size against the intrinsics."""
        from reroom.errors import ScanError

        img = read_rgb8(self.image_path)
        h, w = img.shape[:2]
        if (w, h) != (self.intrinsics.width, self.intrinsics.height):
            raise ScanError(
                self.image_path,
                f"image is {w}x{h} but the intrinsics say "
                f"{self.intrinsics.width}x{self.intrinsics.height}",
            )
        return img

    def load_depth(self) -> np.ndarray | None:
        """Decode the frame's depth map in metres (0 = no data), or ``None`` if it has none."""
        if self.depth_path is None:
            return None
        return read_depth_mm(self.depth_path)

    def world_to_cv(self, points: np.ndarray) -> np.ndarray:
        """World points ``(N, 3)`` to camera coordinates in OpenCV axes (z = depth)."""
        w2c = self.w2c
        p_gl = points @ w2c[:3, :3].T + w2c[:3, 3]
        return p_gl @ GL_TO_CV.T

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Project world points into the image.

        Returns
        -------
        uv:
            ``(N, 2)`` pixel coordinates (continuous; pixel ``(i, j)`` covers
            ``[j, j+1) x [i, i+1)``).
        depth:
            ``(N,)`` depth along the optical axis (negative behind the camera).
        inside:
            ``(N,)`` bool, in front of the camera and inside the image.
        """
        k = self.intrinsics
        pc = self.world_to_cv(np.asarray(points, dtype=np.float64))
        z = pc[:, 2]
        safe = np.where(np.abs(z) > 1e-12, z, 1e-12)
        xd, yd = k.distort(pc[:, 0] / safe, pc[:, 1] / safe)
        uv = np.stack([k.fx * xd + k.cx, k.fy * yd + k.cy], axis=1)
        inside = (
            (z > 1e-6)
            & (uv[:, 0] >= 0)
            & (uv[:, 0] < k.width)
            & (uv[:, 1] >= 0)
            & (uv[:, 1] < k.height)
        )
        return uv, z, inside

    def pixel_rays(self, uv: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """World-space rays through pixel positions ``uv`` (default: every pixel centre).

        Returns ``(origins, directions)``, each ``(N, 3)``, with unit directions;
        without ``uv`` the rays are in row-major pixel order.
        """
        k = self.intrinsics
        if uv is None:
            jj, ii = np.meshgrid(np.arange(k.width) + 0.5, np.arange(k.height) + 0.5)
            uv = np.stack([jj.ravel(), ii.ravel()], axis=1)
        xd = (uv[:, 0] - k.cx) / k.fx
        yd = (uv[:, 1] - k.cy) / k.fy
        xn, yn = k.undistort(xd, yd)
        d_cv = np.stack([xn, yn, np.ones_like(xn)], axis=1)
        d_world = (d_cv @ GL_TO_CV.T) @ self.c2w[:3, :3].T
        d_world /= np.linalg.norm(d_world, axis=1, keepdims=True)
        origins = np.broadcast_to(self.center, d_world.shape).copy()
        return origins, d_world


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray | None = None) -> np.ndarray:
    """Camera-to-world matrix (OpenGL axes) for a camera at ``eye`` looking at ``target``."""
    up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, dtype=float)
    eye = np.asarray(eye, dtype=float)
    fwd = np.asarray(target, dtype=float) - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, up)
    if np.linalg.norm(right) < 1e-9:  # looking straight along `up`
        right = np.cross(fwd, np.array([1.0, 0.0, 0.0]))
    right /= np.linalg.norm(right)
    true_up = np.cross(right, fwd)
    c2w = np.eye(4)
    c2w[:3, 0] = right
    c2w[:3, 1] = true_up
    c2w[:3, 2] = -fwd
    c2w[:3, 3] = eye
    return c2w
