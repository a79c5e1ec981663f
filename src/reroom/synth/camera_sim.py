"""Simulate an auto-exposing, auto-white-balancing camera on linear HDR renders.

The path tracer gives linear scene radiance per pixel. A phone or Tango
camera then

1. meters the scene and picks an exposure (log-average luminance mapped to
   mid-grey, smoothed over time like a real AE loop, within shutter/gain limits),
2. picks per-channel white-balance gains (grey world, also smoothed, G = 1),
3. adds shot noise (Poisson, approximated as Gaussian with variance proportional
   to the signal) and read noise,
4. clips at the full-well / white level, applies a response curve (gamma 2.2 by
   default, or sRGB) and quantises to 8 bits.

The per-channel scale ``t_j^c = exposure_j * wb_j^c`` maps scene radiance to
the linear sensor value in [0, 1] before clipping; it is exactly the unknown
of the thesis's eq. 3.1, and the generator stores it as ground truth.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from reroom.io.images import linear_to_srgb

LUMA = np.array([0.2126, 0.7152, 0.0722])


@dataclass(frozen=True)
class CameraModel:
    """Parameters of the simulated camera (defaults: a phone-like sensor)."""

    response: str = "gamma2.2"  # "gamma2.2" | "srgb" | "linear"
    key: float = 0.18  # mid-grey target for the log-average luminance
    ae_speed: float = 0.35  # fraction of the way to the metered exposure per frame
    awb_speed: float = 0.25
    min_exposure: float = 1e-4
    max_exposure: float = 1e4
    full_well: float = 3000.0  # electrons at white level: shot-noise variance = x / full_well
    read_noise: float = 0.002  # std of read noise, in units of the white level
    noise: bool = True

    def to_json(self) -> dict:
        return asdict(self)


def apply_response(x: np.ndarray, response: str) -> np.ndarray:
    """Map linear sensor values in [0, 1] to encoded values in [0, 1]."""
    x = np.clip(x, 0.0, 1.0)
    if response == "gamma2.2":
        return x ** (1.0 / 2.2)
    if response == "srgb":
        return linear_to_srgb(x)
    if response == "linear":
        return x
    raise ValueError(f"unknown response curve {response!r} (gamma2.2, srgb, linear)")


def inverse_response(v: np.ndarray, response: str) -> np.ndarray:
    """Inverse of :func:`apply_response` for encoded values in [0, 1]."""
    v = np.clip(np.asarray(v, dtype=np.float64), 0.0, 1.0)
    if response == "gamma2.2":
        return v**2.2
    if response == "srgb":
        return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)
    if response == "linear":
        return v
    raise ValueError(f"unknown response curve {response!r} (gamma2.2, srgb, linear)")


class AutoCamera:
    """Stateful auto-exposure / auto-white-balance camera; call :meth:`capture` per frame."""

    def __init__(self, model: CameraModel, rng: np.random.Generator) -> None:
        self.model = model
        self.rng = rng
        self._exposure: float | None = None
        self._wb: np.ndarray | None = None

    def meter(self, radiance: np.ndarray) -> tuple[float, np.ndarray]:
        """Exposure and white balance this frame alone would ask for (no smoothing)."""
        lum = radiance @ LUMA
        valid = np.isfinite(lum)
        logavg = float(np.exp(np.mean(np.log(np.maximum(lum[valid], 1e-6)))))
        exposure = self.model.key / max(logavg, 1e-9)
        means = np.array([np.mean(np.maximum(radiance[..., c][valid], 0)) for c in range(3)])
        wb = np.clip(means[1] / np.maximum(means, 1e-9), 0.5, 2.0)
        return exposure, wb

    def capture(self, radiance: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
        """Expose, white-balance, add noise, encode and quantise one linear frame.

        Returns ``(image_uint8, scale_rgb, exposure, wb_rgb)`` where
        ``scale_rgb = exposure * wb_rgb`` is the per-channel linear scale.
        """
        m = self.model
        radiance = np.asarray(radiance, dtype=np.float64)
        target_e, target_wb = self.meter(radiance)
        if self._exposure is None:
            self._exposure, self._wb = target_e, target_wb
        else:
            # Real AE/AWB loops converge over several frames; smooth in the log domain.
            self._exposure = float(
                np.exp(
                    np.log(self._exposure)
                    + m.ae_speed * (np.log(target_e) - np.log(self._exposure))
                )
            )
            self._wb = np.exp(
                np.log(self._wb) + m.awb_speed * (np.log(target_wb) - np.log(self._wb))
            )
        self._exposure = float(np.clip(self._exposure, m.min_exposure, m.max_exposure))
        scale = self._exposure * self._wb
        x = np.maximum(radiance, 0.0) * scale
        if m.noise:
            sigma = np.sqrt(np.minimum(x, 1.5) / m.full_well + m.read_noise**2)
            x = x + self.rng.standard_normal(x.shape) * sigma
        v = apply_response(x, m.response)
        img = np.clip(np.round(v * 255.0), 0, 255).astype(np.uint8)
        return img, scale.copy(), self._exposure, self._wb.copy()
