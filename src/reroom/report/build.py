"""``report.html``: one self-contained page showing every stage of a run."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from pathlib import Path

from reroom import __version__
from reroom.io.atomic import atomic_write_json, atomic_write_text, nan_to_null
from reroom.report import sections as S
from reroom.report.evaluation import evaluate_run
from reroom.report.html import esc, page
from reroom.runner import StageResult

__all__ = ["REPORT_NAME", "write_report"]

#: The report's file name in the run folder.
REPORT_NAME = "report.html"

_DEFAULT_STAGES = ("hdr", "layout", "lights", "invert", "rerender", "edits", "report")

#: The stage whose outputs each section shows.
_SECTION_STAGE = {
    "hdr": "hdr",
    "layout": "layout",
    "lights": "lights",
    "materials": "invert",
    "rerender": "rerender",
    "edits": "edits",
}


def _guarded(fn: Callable[[], str]) -> str:
    """A section's HTML, or a note naming what went wrong.

    A report is a diagnostic: a section that cannot be drawn (a stage's output is
    corrupt, a picture fails) is reported in place instead of taking the others down.
    """
    try:
        return fn()
    except Exception as exc:
        return f'<p class="failed">This section could not be drawn: {esc(type(exc).__name__)}: {esc(exc)}</p>'


def write_report(
    run_dir: str | Path,
    *,
    evaluate: bool = True,
    results: Sequence[StageResult] | None = None,
    stages: Sequence[str] = _DEFAULT_STAGES,
    path: str | Path | None = None,
) -> Path:
    """Write ``report.html`` for a run folder (atomically) and return its path.

    Parameters
    ----------
    run_dir:
        The run folder: the scan (or its ``--out`` copy of links) with the stages'
        output folders.
    evaluate:
        Where the scan has ``ground_truth/``, add each stage's errors (evaluation code
        reads the truth; the numbers are also written to ``report/evaluation.json``).
    results:
        This run's stage results (status, reason, seconds) for the timing table.
    stages:
        Stage names in order, for the timing table.
    path:
        Where to write (default ``RUN/report.html``).

    Returns
    -------
    Path
        The report.

    Raises
    ------
    ScanError
        If the run folder is not a scan.
    """
    from reroom.scan import load_scan

    run = Path(run_dir)
    out = Path(path) if path is not None else run / REPORT_NAME
    t0 = time.perf_counter()
    scan = load_scan(run)
    results = list(results or [])
    ev: dict = {}
    ev_note = ""
    if evaluate and scan.has_ground_truth:
        ev = evaluate_run(run)
        atomic_write_json(run / "report" / "evaluation.json", nan_to_null(ev))
    elif evaluate:
        ev_note = "<p>This scan has no ground truth: no errors to show.</p>"
    body = [
        ("run", "Run and timings", _guarded(lambda: S.run_section(run, list(stages), results))),
        ("scan", "Scan", _guarded(lambda: S.scan_section(scan))),
        ("hdr", "HDR radiance", _guarded(lambda: S.hdr_section(run, scan))),
        ("layout", "Layout and labels", _guarded(lambda: S.layout_section(run, scan))),
        ("lights", "Lights", _guarded(lambda: S.lights_section(run))),
        ("materials", "Materials", _guarded(lambda: S.materials_section(run, scan))),
        ("rerender", "Re-renders next to the photos", _guarded(lambda: S.rerender_section(run))),
        ("edits", "Edits", _guarded(lambda: S.edits_section(run, scan))),
    ]
    failed = next((r.name for r in results if r.status == "failed"), None)
    if failed is not None and failed in stages:
        # Stages from the failed one on did not finish in this run: whatever of theirs is
        # on disk comes from an earlier run.
        stale = set(list(stages)[list(stages).index(failed) :])
        note = (
            '<p class="failed">This stage did not finish in this run (stage {0} failed): '
            "what is shown here, if anything, comes from an earlier run.</p>"
        )
        body = [
            (a, t, note.format(esc(failed)) + html if _SECTION_STAGE.get(a) in stale else html)
            for a, t, html in body
        ]
    if evaluate:
        body.append(
            (
                "truth",
                "Errors against ground truth",
                ev_note or _guarded(lambda: S.evaluation_section(ev)),
            )
        )
    origin = scan.meta.get("reroom") if isinstance(scan.meta.get("reroom"), dict) else {}
    kind = f" (synthetic, preset {origin['preset']})" if origin.get("preset") else ""
    subtitle = (
        f"{scan.root.name}{kind}: {len(scan.frames)} frames. reroom {__version__}, "
        f"written {time.strftime('%Y-%m-%d %H:%M:%S')} in {time.perf_counter() - t0:.1f} s."
    )
    atomic_write_text(out, page(f"reroom report: {scan.root.name}", subtitle, body))
    return out
