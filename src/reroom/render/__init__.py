"""Rendering infrastructure: choosing and initialising a Mitsuba 3 variant."""

from reroom.render.mitsuba_env import MitsubaInfo, mitsuba, mitsuba_info

__all__ = ["MitsubaInfo", "mitsuba", "mitsuba_info"]
