"""Resumable pipeline runs: a stage whose inputs did not change is not recomputed.

``reroom run SCAN`` chains the stages (HDR, layout, lights, inverse rendering, edits,
report). Each :class:`Stage` names the files it reads, the options that shape its
result and the files it writes. After a stage succeeds, a record with the
*fingerprint* of its inputs is written into its output folder
(``.reroom_stage.json``, atomically, after the outputs); the next run skips the stage
when the fingerprint is the same and every output exists. A crash mid-stage leaves no
record, so the stage runs again.

The fingerprint hashes the reroom version, the stage name, its options (as canonical
JSON) and each input file: the content (SHA-256) of files up to 64 MB, and the size and
modification time of larger ones (the frames of a long scan are many and big, and are
never rewritten in place). Upstream outputs are small (JSON, PLY, NPZ), so a stage that
re-ran upstream with an identical result does not trigger the ones after it.
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from reroom import __version__
from reroom.io.atomic import atomic_write_json

__all__ = ["Stage", "StageResult", "fingerprint", "read_record", "run_stages", "RECORD_NAME"]

#: Name of the record a finished stage leaves in its output folder.
RECORD_NAME = ".reroom_stage.json"
_CONTENT_HASH_LIMIT = 64 * 1024 * 1024


@dataclass
class Stage:
    """One step of a run.

    Attributes
    ----------
    name:
        Short name (``"hdr"``, ``"layout"``, ...), shown in progress and reports.
    out_dir:
        Folder the stage writes (its record goes there too).
    inputs:
        Files whose content the result depends on (missing ones are hashed as
        missing, so their appearance triggers a re-run); or a function returning them,
        called just before the stage would run (for inputs such as "every file an
        upstream stage wrote", known only once it ran).
    options:
        JSON-able options that shape the result.
    outputs:
        Files that must exist for the stage to count as done.
    run:
        ``run(progress)`` does the work; ``progress(stage, done, total)``.
    """

    name: str
    out_dir: Path
    inputs: Sequence[Path] | Callable[[], Sequence[Path]]
    options: dict[str, Any]
    outputs: Sequence[Path]
    run: Callable[[Callable[[str, int, int], None]], Any]


@dataclass
class StageResult:
    """What happened to a stage: ``status`` is ``ran``, ``skipped`` or ``failed``."""

    name: str
    status: str
    seconds: float
    reason: str
    fingerprint: str
    error: BaseException | None = field(default=None, repr=False)


def _hash_file(h: Any, path: Path, root: Path | None = None) -> None:
    name = path
    if root is not None and path.is_relative_to(root):
        name = path.relative_to(root)
    h.update(str(name).encode())
    if not path.exists():
        h.update(b"<missing>")
        return
    st = path.stat()
    if path.is_dir():
        h.update(b"<dir>")
        return
    if st.st_size > _CONTENT_HASH_LIMIT:
        h.update(f"<size {st.st_size} mtime {st.st_mtime_ns}>".encode())
        return
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)


def fingerprint(
    name: str, inputs: Iterable[Path], options: dict[str, Any], root: str | Path | None = None
) -> str:
    """SHA-256 of the reroom version, the stage name, its options and its input files.

    Input files under ``root`` are named by their path relative to it, so a run folder
    that is moved or copied whole keeps its fingerprints (its stages are not re-run).
    """
    h = hashlib.sha256()
    h.update(f"reroom {__version__}\nstage {name}\n".encode())
    h.update(json.dumps(options, sort_keys=True, default=str).encode())
    base = Path(root) if root is not None else None
    for p in sorted(Path(x) for x in inputs):
        _hash_file(h, p, base)
    return h.hexdigest()


def read_record(out_dir: str | Path) -> dict[str, Any] | None:
    """The record a finished stage left in ``out_dir`` (``None``: none, or unreadable).

    Keys: ``stage``, ``fingerprint``, ``reroom`` (version), ``seconds``, ``finished``
    (local time), ``options``.
    """
    path = Path(out_dir) / RECORD_NAME
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) else None


def _record(stage: Stage) -> dict[str, Any] | None:
    return read_record(stage.out_dir)


def run_stages(
    stages: Sequence[Stage],
    force: Iterable[str] = (),
    progress: Callable[[str, int, int], None] | None = None,
    stop_on_error: bool = True,
    root: str | Path | None = None,
) -> list[StageResult]:
    """Run stages in order, skipping those whose fingerprint and outputs are unchanged.

    Parameters
    ----------
    stages:
        The stages, upstream first. A stage's fingerprint is computed just before it
        would run, so it sees what the stages before it wrote.
    force:
        Names of stages to run even if unchanged (``"all"`` for every stage).
    progress:
        ``progress(stage, done, total)``, passed on to the stages.
    stop_on_error:
        Stop at the first failing stage (the default: later stages would read stale
        or missing inputs). The failed stage keeps no record; earlier stages' results
        stay valid and are reused by the next run.
    root:
        The run's folder: inputs under it are fingerprinted by their relative path
        (see :func:`fingerprint`).

    Returns
    -------
    list of StageResult
        One per stage reached.
    """
    force = set(force)
    report = progress or (lambda stage, done, total: None)
    results: list[StageResult] = []
    for stage in stages:
        inputs = stage.inputs() if callable(stage.inputs) else stage.inputs
        fp = fingerprint(stage.name, inputs, stage.options, root)
        rec = _record(stage)
        missing = [str(p) for p in stage.outputs if not Path(p).exists()]
        if stage.name in force or "all" in force:
            reason = "forced"
        elif rec is None:
            reason = "no previous run"
        elif rec.get("fingerprint") != fp:
            reason = "inputs or options changed"
        elif missing:
            reason = f"outputs missing ({len(missing)})"
        else:
            results.append(StageResult(stage.name, "skipped", 0.0, "unchanged", fp))
            report(stage.name, 1, 1)
            continue
        # The old record goes before the stage starts: if the stage then fails, the
        # outputs it leaves must not pass for a finished run of the old inputs.
        (Path(stage.out_dir) / RECORD_NAME).unlink(missing_ok=True)
        t = time.perf_counter()
        try:
            stage.run(report)
        except Exception as exc:
            results.append(
                StageResult(stage.name, "failed", time.perf_counter() - t, str(exc), fp, exc)
            )
            if stop_on_error:
                break
            continue
        seconds = time.perf_counter() - t
        missing = [str(p) for p in stage.outputs if not Path(p).exists()]
        if missing:
            err = RuntimeError(f"stage {stage.name} did not write {missing}")
            results.append(StageResult(stage.name, "failed", seconds, str(err), fp, err))
            if stop_on_error:
                break
            continue
        Path(stage.out_dir).mkdir(parents=True, exist_ok=True)
        atomic_write_json(
            Path(stage.out_dir) / RECORD_NAME,
            {
                "stage": stage.name,
                "fingerprint": fp,
                "reroom": __version__,
                "seconds": round(seconds, 3),
                "finished": time.strftime("%Y-%m-%dT%H:%M:%S"),
                "options": stage.options,
            },
        )
        results.append(StageResult(stage.name, "ran", seconds, reason, fp))
    return results
