"""Resumable runs: stages are skipped exactly when their inputs and options are unchanged."""

from __future__ import annotations

from pathlib import Path

from reroom.runner import RECORD_NAME, Stage, run_stages


def _stages(tmp: Path, calls: list[str], b_option: int = 1, b_fails: bool = False) -> list[Stage]:
    src = tmp / "input.txt"
    a_out = tmp / "a" / "a.txt"
    b_out = tmp / "b" / "b.txt"

    def run_a(progress) -> None:
        calls.append("a")
        a_out.parent.mkdir(exist_ok=True)
        a_out.write_text(src.read_text().upper())

    def run_b(progress) -> None:
        calls.append("b")
        if b_fails:
            raise RuntimeError("b crashed")
        b_out.parent.mkdir(exist_ok=True)
        b_out.write_text(a_out.read_text() * b_option)

    return [
        Stage("a", tmp / "a", [src], {}, [a_out], run_a),
        Stage("b", tmp / "b", [a_out], {"repeat": b_option}, [b_out], run_b),
    ]


def _status(results) -> list[str]:
    return [r.status for r in results]


def test_skips_unchanged_and_reruns_what_changed(tmp_path: Path) -> None:
    (tmp_path / "input.txt").write_text("room")
    calls: list[str] = []
    assert _status(run_stages(_stages(tmp_path, calls))) == ["ran", "ran"]
    assert _status(run_stages(_stages(tmp_path, calls))) == ["skipped", "skipped"]
    assert calls == ["a", "b"]

    # An option of b only: a is kept.
    res = run_stages(_stages(tmp_path, calls, b_option=2))
    assert _status(res) == ["skipped", "ran"] and res[1].reason == "inputs or options changed"
    assert (tmp_path / "b" / "b.txt").read_text() == "ROOMROOM"

    # The input of a: both run (a's output changed).
    (tmp_path / "input.txt").write_text("hall")
    assert _status(run_stages(_stages(tmp_path, calls, b_option=2))) == ["ran", "ran"]

    # Same content rewritten upstream: a runs (forced), b sees identical bytes and is kept.
    res = run_stages(_stages(tmp_path, calls, b_option=2), force=["a"])
    assert _status(res) == ["ran", "skipped"]

    # A deleted output makes its stage run again.
    (tmp_path / "b" / "b.txt").unlink()
    res = run_stages(_stages(tmp_path, calls, b_option=2))
    assert _status(res) == ["skipped", "ran"] and res[1].reason.startswith("outputs missing")


def test_a_crash_leaves_no_record_and_keeps_earlier_stages(tmp_path: Path) -> None:
    (tmp_path / "input.txt").write_text("room")
    calls: list[str] = []
    res = run_stages(_stages(tmp_path, calls, b_fails=True))
    assert _status(res) == ["ran", "failed"]
    assert "b crashed" in res[1].reason and isinstance(res[1].error, RuntimeError)
    assert (tmp_path / "a" / RECORD_NAME).is_file()
    assert not (tmp_path / "b" / RECORD_NAME).exists()
    res = run_stages(_stages(tmp_path, calls))
    assert _status(res) == ["skipped", "ran"] and res[1].reason == "no previous run"


def test_stage_that_writes_nothing_fails(tmp_path: Path) -> None:
    def noop(progress) -> None:
        pass

    res = run_stages([Stage("x", tmp_path / "x", [], {}, [tmp_path / "x" / "out"], noop)])
    assert _status(res) == ["failed"] and "did not write" in res[0].reason
    assert not (tmp_path / "x" / RECORD_NAME).exists()
