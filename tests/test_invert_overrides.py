"""``reroom invert --set NAME=VALUE``: any option by name, checked against its type."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from test_invert_pipeline import _box_scan
from typer.testing import CliRunner

from reroom.cli import app
from reroom.invert.overrides import option_names, with_overrides
from reroom.invert.pipeline import InvertOptions
from reroom.invert.solve import SolveOptions

runner = CliRunner()


def test_values_are_parsed_and_typed() -> None:
    base = InvertOptions(rays_per_receiver=64)
    opts = with_overrides(
        base,
        [
            "line_phi_smooth=1e6",
            "bins=16",
            "fixture_margin=0",  # an int where a float is wanted: becomes 0.0
            "refine_points=false",
            "texel=0.02",
            "unobserved_fill=mean",  # a bare word
            "solve.max_vertices=null",
            "solve.huber_delta=0.02",
            "solve.method=alternating",
        ],
    )
    assert opts.line_phi_smooth == 1e6 and opts.bins == 16
    assert opts.fixture_margin == 0.0 and isinstance(opts.fixture_margin, float)
    assert opts.refine_points is False and opts.texel == 0.02
    assert opts.unobserved_fill == "mean"
    assert opts.solve.max_vertices is None and opts.solve.huber_delta == 0.02
    assert opts.solve.method == "alternating"
    assert opts.rays_per_receiver == 64  # what was not set is kept
    assert base.line_phi_smooth == InvertOptions().line_phi_smooth  # the input is untouched
    assert with_overrides(base, []) == base


@pytest.mark.parametrize(
    ("setting", "message"),
    [
        ("line_phi_smoth=1e6", "unknown option 'line_phi_smoth'; the options are: cubemap_n"),
        ("solve=1", "unknown option 'solve'"),
        ("solve.nonsense=1", "unknown option 'solve.nonsense'"),
        ("bins=3.5", "option bins needs int, got 3.5"),
        ("bins=true", "option bins needs int, got True"),
        ("refine_points=1", "option refine_points needs bool, got 1"),
        ("line_phi_smooth=null", "option line_phi_smooth cannot be null"),
        ("solve.method=newton", "option solve.method must be one of alternating, joint"),
        ("seed", "--set needs NAME=VALUE, got 'seed'"),
        ("=3", "--set needs NAME=VALUE"),
    ],
)
def test_bad_settings_are_refused_by_name(setting: str, message: str) -> None:
    with pytest.raises(ValueError, match="^" + message.replace("(", r"\(").replace(".", r"\.")):
        with_overrides(InvertOptions(), [setting])


def test_every_option_is_named() -> None:
    names = option_names()
    assert "line_phi_smooth" in names and "solve.smooth_lambda" in names
    assert "solve" not in names
    n_solve = len([n for n in names if n.startswith("solve.")])
    assert n_solve == len(SolveOptions.__dataclass_fields__)


def test_cli_applies_the_settings(tmp_path: Path) -> None:
    scan = _box_scan(tmp_path)
    args = ["invert", str(scan), "--rays", "64", "--voxel", "0.25", "--no-pictures"]
    args += ["--rerender", "0", "--no-textures"]
    args += ["--set", "line_phi_smooth=7", "--set", "solve.max_vertices=500"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    report = json.loads((scan / "invert" / "report.json").read_text())
    assert report["options"]["line_phi_smooth"] == 7.0
    assert report["options"]["solve"]["max_vertices"] == 500
    assert "solved on 500 of" in result.output


def test_cli_refuses_an_unknown_setting(tmp_path: Path) -> None:
    result = runner.invoke(app, ["invert", str(tmp_path), "--set", "rays=5"])
    assert result.exit_code == 2
    assert "--set: unknown option 'rays'" in result.output
    assert "rays_per_receiver" in result.output


def test_cli_runs_the_alternating_solver(tmp_path: Path) -> None:
    # The joint solver's priors (the photos' colours, the render window's bounds) do
    # not stop it: it goes on without them.
    scan = _box_scan(tmp_path)
    args = ["invert", str(scan), "--rays", "64", "--voxel", "0.25", "--no-pictures"]
    args += ["--rerender", "0", "--no-textures", "--method", "alternating"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    report = json.loads((scan / "invert" / "report.json").read_text())
    assert report["options"]["solve"]["method"] == "alternating"
    assert report["options"]["photo_color"] == 0.0
