"""Rendering for the synthetic generator: see :mod:`reroom.render.frames`."""

from reroom.render.frames import FrameRenderer, probe_radiance

__all__ = ["FrameRenderer", "probe_radiance"]
