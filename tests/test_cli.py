"""The command-line tool: every command has --help, runs, and reports bad input in one line."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from reroom.cli import app

runner = CliRunner()


@pytest.mark.parametrize(
    "command", [[], ["doctor"], ["synth"], ["info"], ["sheet"], ["import-rgbd"], ["demo"]]
)
def test_help(command: list[str]) -> None:
    result = runner.invoke(app, [*command, "--help"])
    assert result.exit_code == 0, result.output
    assert "Usage" in result.output


def test_synth_info_and_sheet(tmp_path: Path) -> None:
    out = tmp_path / "scan"
    args = [
        "synth",
        "box",
        "--out",
        str(out),
        "--frames",
        "3",
        "--width",
        "32",
        "--height",
        "24",
        "--spp",
        "2",
        "--vertex-spp",
        "2",
    ]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert (out / "transforms.json").is_file()
    assert (out / "contact_sheet.png").is_file()
    again = runner.invoke(app, args)
    assert again.exit_code == 1 and "not empty" in again.output
    assert runner.invoke(app, [*args, "--overwrite"]).exit_code == 0
    info = runner.invoke(app, ["info", str(out)])
    assert info.exit_code == 0, info.output
    assert "frames" in info.output and "32 x 24" in info.output
    sheet = runner.invoke(app, ["sheet", str(out), "--out", str(tmp_path / "s.png")])
    assert sheet.exit_code == 0 and (tmp_path / "s.png").is_file()


def test_errors_are_one_line_not_tracebacks(tmp_path: Path) -> None:
    result = runner.invoke(app, ["info", str(tmp_path / "missing")])
    assert result.exit_code == 1
    assert "error:" in result.output and "does not exist" in result.output
    assert "Traceback" not in result.output
    result = runner.invoke(app, ["synth", "castle", "--out", str(tmp_path / "x")])
    assert result.exit_code == 1 and "unknown preset 'castle'" in result.output


def test_doctor_reports_the_variant() -> None:
    result = runner.invoke(app, ["doctor"])
    assert result.exit_code == 0, result.output
    assert "mitsuba variant" in result.output and "ray engine" in result.output


SLAMBOOK = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "slambook2_rgbd"


@pytest.mark.skipif(not (SLAMBOOK / "pose.txt").is_file(), reason="slambook2 frames not found")
def test_import_rgbd_command(tmp_path: Path) -> None:
    out = tmp_path / "slam"
    result = runner.invoke(
        app, ["import-rgbd", str(SLAMBOOK), "--out", str(out), "--voxel-size", "0.04"]
    )
    assert result.exit_code == 0, result.output
    info = runner.invoke(app, ["info", str(out)])
    assert info.exit_code == 0 and "640 x 480" in info.output


@pytest.mark.skipif(not (SLAMBOOK / "pose.txt").is_file(), reason="slambook2 frames not found")
def test_real_scan_through_hdr_layout_lights_and_localize(tmp_path: Path) -> None:
    """The real slambook2 frames through the stages up to the point lights. Its layout
    finds a window in a rotated room, and the window's axes, rounded in lights.json,
    once failed the exact-perpendicular check there (session 20)."""
    scan = tmp_path / "slam"
    assert runner.invoke(app, ["import-rgbd", str(SLAMBOOK), "--out", str(scan)]).exit_code == 0
    for cmd in (["hdr", "--no-baselines", "--no-report"], ["layout"], ["lights"]):
        result = runner.invoke(app, [cmd[0], str(scan), *cmd[1:]])
        assert result.exit_code == 0, result.output
    lights = json.loads((scan / "lights" / "lights.json").read_text())["lights"]
    assert any(x["type"] == "window" for x in lights)
    result = runner.invoke(app, ["localize", str(scan), "--time-limit", "60"])
    assert result.exit_code == 0, result.output
    assert (scan / "localize" / "lights.json").is_file()


def test_import_rgbd_reports_a_missing_folder(tmp_path: Path) -> None:
    result = runner.invoke(
        app, ["import-rgbd", str(tmp_path / "nothing"), "--out", str(tmp_path / "o")]
    )
    assert result.exit_code == 1 and "error:" in result.output


def test_hdr_then_layout_commands(tmp_path: Path) -> None:
    scan = tmp_path / "scan"
    args = ["synth", "box", "--out", str(scan), "--frames", "8", "--width", "64", "--height", "48"]
    assert (
        runner.invoke(app, [*args, "--spp", "4", "--vertex-spp", "4", "--no-sheet"]).exit_code == 0
    )
    result = runner.invoke(app, ["hdr", str(scan), "--no-baselines", "--no-report"])
    assert result.exit_code == 0, result.output
    assert (scan / "hdr" / "hdr_mesh.ply").is_file()
    result = runner.invoke(app, ["layout", str(scan)])
    assert result.exit_code == 0, result.output
    assert (scan / "layout" / "layout.json").is_file()


def test_invert_refuses_an_unknown_fill(tmp_path: Path) -> None:
    result = runner.invoke(app, ["invert", str(tmp_path), "--unobserved-fill", "zero"])
    assert result.exit_code == 2
    assert "--unobserved-fill must be one of bounce, mean" in result.output


def test_invert_refuses_a_missing_window_view(tmp_path: Path) -> None:
    missing = tmp_path / "view.exr"
    result = runner.invoke(app, ["invert", str(tmp_path), "--window-view", str(missing)])
    assert result.exit_code == 2
    out = " ".join(result.output.split())  # rich wraps long lines
    assert "--window-view" in out and "no such file" in out


def test_demo_scan_state_regenerates_a_scan_with_other_frames_or_samples(tmp_path: Path) -> None:
    """`reroom demo` keeps its scan only if frame count and samples per pixel match."""
    import json

    from reroom.cli import demo_scan_state

    scan = tmp_path / "scan"
    assert demo_scan_state(scan, 24, 64) == "new"
    (scan / "ground_truth").mkdir(parents=True)
    (scan / "transforms.json").write_text(json.dumps({"frames": [{}] * 24}))
    assert demo_scan_state(scan, 24, 64) == "replace"  # no ground truth to read the spp from
    gt = scan / "ground_truth" / "ground_truth.json"
    gt.write_text(json.dumps({"options": {"spp": 16}}))
    assert demo_scan_state(scan, 24, 64) == "replace"  # made before session 16
    gt.write_text(json.dumps({"options": {"spp": 64}}))
    assert demo_scan_state(scan, 24, 64) == "reuse"
    assert demo_scan_state(scan, 12, 64) == "replace"


def test_synth_command_defaults_to_the_generators_frame_samples() -> None:
    """`reroom synth --spp` and `SynthOptions.spp` share one default (64 since session 16)."""
    import inspect

    from reroom.cli import synth
    from reroom.synth.generate import SynthOptions

    assert inspect.signature(synth).parameters["spp"].default == SynthOptions().spp
