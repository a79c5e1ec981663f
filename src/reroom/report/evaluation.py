"""Ground-truth errors of every stage, for the report (reads ``ground_truth/``).

This is evaluation code: it calls each stage's own evaluation function
(:func:`reroom.hdr.evaluate.evaluate_hdr`, :func:`reroom.layout.evaluate.evaluate_scan`,
:func:`reroom.lights.evaluate.evaluate_lights`, :func:`reroom.invert.evaluate.evaluate_invert`)
on the outputs of a run. Estimation never sees the truth.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

__all__ = ["evaluate_run", "has_ground_truth"]


def has_ground_truth(run: Path) -> bool:
    """Whether the scan of a run folder has synthetic ground truth."""
    return (Path(run) / "ground_truth" / "ground_truth.json").is_file()


def evaluate_run(run: str | Path) -> dict[str, dict[str, Any]]:
    """Each stage's ground-truth errors, for the stages whose outputs exist.

    Parameters
    ----------
    run:
        A run folder (the scan with ``hdr/``, ``layout/``, ``lights/``, ``invert/``).

    Returns
    -------
    dict
        Stage name to the stage's evaluation result plus ``seconds``; a stage whose
        evaluation failed maps to ``{"error": message}`` (the report shows it; a
        failing evaluation must not hide the rest of the report). Empty without
        ground truth.
    """
    run = Path(run)
    if not has_ground_truth(run):
        return {}
    out: dict[str, dict[str, Any]] = {}

    def attempt(name: str, needed: list[Path], fn) -> None:
        if not all(p.exists() for p in needed):
            return
        t = time.perf_counter()
        try:
            res = fn()
        except Exception as exc:  # report it, go on with the other stages
            out[name] = {"error": f"{type(exc).__name__}: {exc}"}
            return
        res = dict(res)
        res["seconds"] = time.perf_counter() - t
        out[name] = res

    def hdr() -> dict:
        from reroom.hdr.evaluate import evaluate_hdr

        return evaluate_hdr(run, run / "hdr", write=False)

    def layout() -> dict:
        from reroom.layout.evaluate import evaluate_scan

        return evaluate_scan(
            run / "layout" / "layout.json", run, run / "layout" / "layout_labels.ply"
        )

    def lights() -> dict:
        from reroom.lights.evaluate import evaluate_lights

        return evaluate_lights(run / "lights" / "lights.json", run)

    def invert() -> dict:
        from reroom.invert.evaluate import evaluate_invert

        return evaluate_invert(run, run / "invert")

    attempt("hdr", [run / "hdr" / "exposures.json", run / "hdr" / "hdr_mesh.ply"], hdr)
    attempt("layout", [run / "layout" / "layout.json"], layout)
    attempt("lights", [run / "lights" / "lights.json"], lights)
    attempt("invert", [run / "invert" / "scene.json", run / "invert" / "albedo.ply"], invert)
    return out
