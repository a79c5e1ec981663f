"""The report of a run: a self-contained ``report.html``, and a headless-browser check.

:func:`write_report` draws every stage of a run folder (scan, HDR radiance, layout and
labels, lights with their distributions, materials, re-renders next to the photos, edit
renders, ground-truth errors where the scan has them, timings) into one HTML page with
its images inlined. :func:`screenshot` renders a page in headless Chromium.
"""

from reroom.report.browser import find_chromium, image_variance, screenshot
from reroom.report.build import REPORT_NAME, write_report
from reroom.report.evaluation import evaluate_run

__all__ = [
    "REPORT_NAME",
    "evaluate_run",
    "find_chromium",
    "image_variance",
    "screenshot",
    "write_report",
]
