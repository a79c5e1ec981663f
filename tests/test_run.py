"""``reroom run``: every stage end to end on a tiny synthetic scan, resumable, failures named."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from reroom.cli import app
from reroom.errors import ReroomError
from reroom.run import STAGES, RunOptions, prepare_run_dir, run_scan
from reroom.runner import RECORD_NAME, read_record


def _status(res) -> dict[str, str]:
    return {r.name: r.status for r in res.results}


def _edit_file(path: Path, ops: list[dict]) -> Path:
    path.write_text(json.dumps({"format": "reroom-edits", "version": 1, "edits": ops}))
    return path


def _opts(out: Path, edits: Path | None = None) -> RunOptions:
    # One frame, few samples, no default edit sets: the test is about the run, not the
    # pictures (the user's edit file is the one edit set rendered).
    return RunOptions(out_dir=out, edits_file=edits, frames_to_render=1, spp=4, default_edits=False)


@pytest.fixture(scope="module")
def first_run(tmp_path_factory: pytest.TempPathFactory):
    """A 12-frame 80x60 furnished scan and one complete run of it into a separate folder."""
    from reroom.synth.generate import SynthOptions, generate_scan

    root = tmp_path_factory.mktemp("run")
    scan = root / "scan"
    generate_scan(
        "furnished", scan, SynthOptions(frames=12, width=80, height=60, spp=4, vertex_spp=16)
    )
    edits = _edit_file(
        root / "paint.json", [{"op": "repaint", "target": "wall", "color": [0.6, 0.2, 0.2]}]
    )
    out = root / "out"
    res = run_scan(scan, _opts(out, edits))
    return scan, out, edits, res


def test_first_run_makes_every_stage_and_leaves_the_scan_alone(first_run) -> None:
    scan, out, _, res = first_run
    assert res.failed is None, res.failed and res.failed.reason
    assert [r.name for r in res.results] == list(STAGES)
    assert set(_status(res).values()) == {"ran"}
    for name in STAGES:
        rec = read_record(out / name)
        assert rec is not None and rec["stage"] == name
    # The scan folder was only read: the run folder holds links to its files.
    assert not any((scan / name).exists() for name in STAGES)
    assert (out / "transforms.json").is_symlink() and (out / "images").is_symlink()
    edits = json.loads((out / "edits" / "edits.json").read_text())
    assert [s["name"] for s in edits["sets"]] == ["paint"]
    assert edits["spp"] == 4 and edits["denoised"] is True  # the renders are denoised
    assert json.loads((out / "rerender" / "rerender.json").read_text())["denoised"] is True
    assert list((out / "edits" / "paint").glob("*.png"))
    html = (out / "report.html").read_text()
    assert "paint" in html and "could not be drawn" not in html
    # The photo textures of the planes: written by invert, shown in the report.
    textures = json.loads((out / "invert" / "scene.json").read_text())["textures"]
    assert "floor" in {t["label"] for t in textures}
    assert all((out / "invert" / t["file"]).is_file() for t in textures)
    assert "Albedo textures of the room" in html
    # The renders' window: refitted at 8x8 cells with the photos' bounds (the defaults).
    doc = json.loads((out / "invert" / "scene.json").read_text())
    windows = [x for x in doc["lights"] if x["type"] == "window"]
    assert windows
    for w in windows:
        assert w["render_distribution"]["n"] == 8 and len(w["render_distribution"]["cells"]) == 384
        assert w["render_distribution"]["photo_bounds"]["cells"] >= 0
    # Ground truth: each stage's evaluation made it into the report.
    ev = json.loads((out / "report" / "evaluation.json").read_text())
    assert set(ev) == {"hdr", "layout", "lights", "invert"}
    assert not any("error" in v for v in ev.values())
    assert "Errors against ground truth" in html and "floorplan IoU" in html


def test_second_run_skips_every_stage(first_run) -> None:
    scan, out, edits, _ = first_run
    res = run_scan(scan, _opts(out, edits))
    assert set(_status(res).values()) == {"skipped"}
    assert res.seconds < 15.0


def test_changed_input_reruns_that_stage_and_the_ones_after(first_run, tmp_path: Path) -> None:
    scan, out, edits, _ = first_run
    run = tmp_path / "copy"
    shutil.copytree(out, run, symlinks=True)
    # The edits stage's input changes: it and the report run again, nothing before them.
    edits2 = _edit_file(
        tmp_path / "paint.json", [{"op": "repaint", "target": "wall", "color": [0.2, 0.6, 0.2]}]
    )
    res = run_scan(scan, _opts(run, edits2))
    st = _status(res)
    assert [st[s] for s in STAGES[:5]] == ["skipped"] * 5
    assert st["edits"] == "ran" and st["report"] == "ran"
    assert res.results[5].reason == "inputs or options changed"
    # An upstream output changes (the model rewritten): the stages reading it run again.
    model = run / "invert" / "scene.json"
    model.write_text(json.dumps(json.loads(model.read_text()), indent=1))
    res = run_scan(scan, _opts(run, edits2))
    st = _status(res)
    assert [st[s] for s in STAGES[:4]] == ["skipped"] * 4
    assert [st[s] for s in STAGES[4:]] == ["ran"] * 3


def test_a_failing_stage_is_named_and_earlier_results_are_kept(first_run, tmp_path: Path) -> None:
    scan, out, _, _ = first_run
    run = tmp_path / "copy"
    shutil.copytree(out, run, symlinks=True)
    bad = _edit_file(tmp_path / "bad.json", [{"op": "light", "name": "lamp99", "off": True}])
    res = run_scan(scan, _opts(run, bad))
    assert res.failed is not None and res.failed.name == "edits"
    assert "lamp99" in res.failed.reason and "bad" in res.failed.reason
    st = _status(res)
    assert [st[s] for s in STAGES[:5]] == ["skipped"] * 5 and "report" not in st
    # No record for the failed stage (the old one went when it started), earlier ones kept.
    assert not (run / "edits" / RECORD_NAME).exists()
    assert all((run / s / RECORD_NAME).is_file() for s in STAGES[:5])
    html = (run / "report.html").read_text()
    assert "Stage edits failed" in html and "lamp99" in html
    # The next good run (from the command line) resumes at the failed stage.
    good = _edit_file(
        tmp_path / "good.json", [{"op": "repaint", "target": "floor", "color": [0.5, 0.5, 0.2]}]
    )
    args = ["run", str(scan), "--out", str(run), "--frames-to-render", "1", "--spp", "4"]
    r = CliRunner().invoke(app, [*args, "--edits", str(good), "--no-default-edits"])
    assert r.exit_code == 0, r.output
    st = {
        line.split()[1]: line.split()[3] for line in r.output.splitlines() if line.count("│") >= 4
    }
    assert st["hdr"] == "skipped" and st["edits"] == "ran" and st["report"] == "ran"


def test_bad_options_fail_before_any_work(first_run, tmp_path: Path) -> None:
    scan, _, _, _ = first_run
    with pytest.raises(ReroomError, match="unknown stage"):
        run_scan(scan, _opts(tmp_path / "x"), force=["hdrr"])
    r = CliRunner().invoke(app, ["run", str(scan), "--out", str(tmp_path / "x"), "--force", "hdrr"])
    assert r.exit_code == 1 and "unknown stage hdrr" in r.output and "Traceback" not in r.output
    bad = tmp_path / "bad.json"
    bad.write_text('{"format": "something"}')
    with pytest.raises(ReroomError, match="bad.json"):
        run_scan(scan, _opts(tmp_path / "x", bad))
    assert not (tmp_path / "x").exists()
    with pytest.raises(ReroomError, match="transforms.json"):
        prepare_run_dir(tmp_path, None)
    # A run folder that holds something else under a scan file's name is refused.
    other = tmp_path / "other"
    other.mkdir()
    (other / "transforms.json").write_text("{}")
    with pytest.raises(ReroomError, match="not a link"):
        prepare_run_dir(scan, other)


def test_a_window_view_is_an_input_of_the_inverse_rendering(first_run, tmp_path: Path) -> None:
    """``reroom run --window-view``: the invert stage and those after it run again with the
    view (the file is an input: its content counts), which reaches the invert stage's
    options, and a view that cannot be read fails before any work, naming the file."""
    from reroom.io.images import write_exr

    scan, out, edits, _ = first_run
    run = tmp_path / "copy"
    shutil.copytree(out, run, symlinks=True)
    h = 16
    sky = np.ones((h, 2 * h, 3), np.float32)
    sky[: h // 2] *= 4.0  # brighter above the horizon
    view = write_exr(tmp_path / "view.exr", sky)

    def opts(path: Path | None) -> RunOptions:
        o = _opts(run, edits)
        o.window_view = path
        return o

    st = _status(run_scan(scan, opts(view)))
    assert [st[s] for s in STAGES[:3]] == ["skipped"] * 3
    assert [st[s] for s in STAGES[3:]] == ["ran"] * 4
    assert read_record(run / "invert")["options"]["window_view_hdri"] == "view.exr"
    # The window is refitted for the renders with the view too, and its map is the view's
    # (what the view does to a window's cells and map: test_invert_window_env.py).
    doc = json.loads((run / "invert" / "scene.json").read_text())
    for w in [x for x in doc["lights"] if x["type"] == "window"]:
        assert w["render_distribution"]["n"] == 8 and w["environment_source"] == "view+cells"
    # The same view again: nothing to do; other content in that file: the invert stage.
    assert set(_status(run_scan(scan, opts(view))).values()) == {"skipped"}
    write_exr(view, sky[::-1].copy())
    st = _status(run_scan(scan, opts(view)))
    assert st["lights"] == "skipped" and st["invert"] == "ran"
    # Bad views are refused before any stage runs.
    with pytest.raises(ReroomError, match="nothing.exr"):
        run_scan(scan, opts(tmp_path / "nothing.exr"))
    junk = tmp_path / "junk.exr"
    junk.write_bytes(b"not an exr")
    with pytest.raises(ReroomError, match="junk.exr"):
        run_scan(scan, opts(junk))
    write_exr(junk, np.zeros_like(sky))
    with pytest.raises(ReroomError, match="black"):
        run_scan(scan, opts(junk))
    r = CliRunner().invoke(app, ["run", str(scan), "--out", str(run), "--window-view", str(junk)])
    assert r.exit_code != 0 and "junk.exr" in r.output and "Traceback" not in r.output


def test_a_scan_s_own_window_view_is_taken(first_run, tmp_path: Path) -> None:
    """A scan folder's ``window_view.exr`` is the captured view when none is given."""
    from reroom.io.images import write_exr
    from reroom.run import WINDOW_VIEW_FILE

    scan, out, edits, _ = first_run
    run = tmp_path / "copy"
    shutil.copytree(out, run, symlinks=True)
    sky = np.ones((16, 32, 3), np.float32)
    sky[:8] *= 3.0
    own = scan / WINDOW_VIEW_FILE
    try:
        write_exr(own, sky)
        res = run_scan(scan, _opts(run, edits))
        assert _status(res)["invert"] == "ran"
        assert read_record(run / "invert")["options"]["window_view_hdri"] == WINDOW_VIEW_FILE
        assert any(WINDOW_VIEW_FILE in n for n in res.notes)
        own.write_bytes(b"not an exr")  # refused before any work, its source named
        with pytest.raises(ReroomError, match=f"the scan's {WINDOW_VIEW_FILE}"):
            run_scan(scan, _opts(run, edits))
    finally:
        own.unlink(missing_ok=True)


def test_run_folder_links_the_scan_and_may_live_inside_it(tmp_path: Path) -> None:
    from conftest import make_scan

    scan = make_scan(tmp_path / "scan")
    (scan / "hdr").mkdir()  # an earlier in-place run's output: not linked
    run = prepare_run_dir(scan, scan / "runs" / "a")
    names = sorted(p.name for p in run.iterdir())
    assert names == sorted(p.name for p in scan.iterdir() if p.name not in ("hdr", "runs"))
    assert all((run / n).is_symlink() for n in names)
    assert prepare_run_dir(scan, scan / "runs" / "a") == run  # again: nothing to do
    assert prepare_run_dir(scan, None) == scan and prepare_run_dir(scan, scan) == scan
