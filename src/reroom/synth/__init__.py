"""Synthetic room scans with ground truth, rendered by Mitsuba 3's path tracer.

``reroom synth PRESET --out DIR`` builds a room (:mod:`~reroom.synth.presets`),
walks a simulated handheld camera through it (:mod:`~reroom.synth.trajectory`),
path-traces each frame, simulates auto-exposure, white balance, response,
noise and quantisation (:mod:`~reroom.synth.camera_sim`), and writes a scan plus
``ground_truth/`` (:mod:`~reroom.synth.generate`).
"""

from reroom.synth.labels import LABEL_NAMES, LABELS

__all__ = ["LABELS", "LABEL_NAMES"]
