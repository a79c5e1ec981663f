"""report.html: self-contained, shows each stage's outputs, names failures; a real browser draws it."""

from __future__ import annotations

import base64
import io
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import make_scan
from PIL import Image

from reroom.errors import ReroomError
from reroom.io.atomic import atomic_write_json
from reroom.io.images import write_rgb8
from reroom.report import find_chromium, image_variance, screenshot, write_report
from reroom.report.html import fmt, table
from reroom.runner import StageResult


def _stage_outputs(run: Path) -> None:
    """Hand-written outputs of the later stages, with values the report must show."""
    atomic_write_json(
        run / "lights" / "lights.json",
        {
            "lights": [
                {
                    "name": "area0",
                    "type": "area",
                    "source": "detected",
                    "centroid": [1.0, 0.5, 2.5],
                    "reason": "kept: <b>bright</b> panel",
                },
                {
                    "name": "tube",
                    "type": "line",
                    "source": "user",
                    "p0": [0.0, 0.0, 2.4],
                    "p1": [1.0, 0.0, 2.4],
                    "reason": "added by the user",
                },
            ],
            "rejected": [
                {"name": "c0", "reason": "rejected: 12 vertices < 50"},
                {"name": "c1", "reason": "rejected: 31 vertices < 50"},
            ],
        },
    )
    atomic_write_json(
        run / "invert" / "scene.json",
        {
            "lights": [
                {"name": "area0", "type": "area", "power": [1.5, 2.5, 3.5]},
                {
                    "name": "tube",
                    "type": "line",
                    "power": [0.25, 0.25, 0.25],
                    "distribution": {
                        "basis": "line",
                        "open_fraction": [[1.0]],
                        "fixture_inside_fraction": 0.11,
                        "fixture_from_photos": {
                            "axis_offset_m": [0.0193, 0.0408],
                            "radius_m": 0.0169,
                            "cutoff_deg": [54.2, None],
                            "stripe_frames": 22,
                        },
                    },
                },
            ],
            "materials": [
                {"name": "wall", "albedo": [0.625, 0.5, 0.375], "solved": True},
                {"name": "floor", "albedo": None, "solved": False},
            ],
        },
    )
    # A goniometric diagram: a recognisable picture (a red square on white).
    gonio = np.full((40, 60, 3), 255, np.uint8)
    gonio[10:30, 20:40] = (200, 0, 0)
    write_rgb8(run / "invert" / "gonio_tube.png", gonio)
    atomic_write_json(
        run / "rerender" / "rerender.json",
        {
            "frames": [{"index": 1, "ratio_of_means": 0.875, "relative_l1": 0.25, "pixels": 700}],
            "median_ratio_of_means": 0.875,
            "median_relative_l1": 0.25,
            "spp": 4,
        },
    )
    write_rgb8(run / "rerender" / "rerender.png", np.full((24, 64, 3), 90, np.uint8))
    write_rgb8(run / "edits" / "paint" / "paint_f00001.png", np.full((24, 32, 3), 30, np.uint8))
    atomic_write_json(
        run / "edits" / "edits.json",
        {
            "sets": [
                {
                    "name": "paint",
                    "folder": "paint",
                    "edits": [{"op": "repaint", "target": "wall", "color": [0.5, 0.1, 0.1]}],
                    "frames": [1],
                    "seconds": 0.5,
                }
            ]
        },
    )


def _images(html: str) -> list[np.ndarray]:
    srcs = re.findall(r'<img src="([^"]*)"', html)
    out = []
    for s in srcs:
        assert s.startswith("data:image/png;base64,"), s[:40]
        data = base64.b64decode(s.split(",", 1)[1])
        out.append(np.asarray(Image.open(io.BytesIO(data)).convert("RGB")))
    return out


@pytest.fixture
def report_run(tmp_path: Path) -> Path:
    run = make_scan(tmp_path / "scan", n_frames=3, width=32, height=24)
    _stage_outputs(run)
    return run


def test_report_is_self_contained_and_shows_each_stage(report_run: Path) -> None:
    results = [
        StageResult("hdr", "skipped", 0.0, "unchanged", "x"),
        StageResult("lights", "ran", 1.25, "no previous run", "y"),
        StageResult("edits", "failed", 0.5, "edit set 'x': no light named 'lamp9'", "z"),
    ]
    path = write_report(report_run, results=results)
    assert path == report_run / "report.html"
    html = path.read_text()
    # Self-contained: no external reference of any kind.
    for bad in ("http://", "https://", "<link", "<script", "url("):
        assert bad not in html
    imgs = _images(html)
    # The 3 input frames, the gonio diagram, the re-render, the edit's photo and render.
    assert len(imgs) == 7
    assert any(im.shape == (40, 60, 3) and (im[20, 30] == (200, 0, 0)).all() for im in imgs)
    assert sum(im.shape == (24, 32, 3) for im in imgs) == 5
    assert any((im == 30).all() for im in imgs)  # the edit render itself
    # Lights: names, types, solved power, the reason escaped, rejected grouped by kind.
    assert "area0" in html and "tube" in html
    assert "1.5, 2.5, 3.5" in html
    assert "kept: &lt;b&gt;bright&lt;/b&gt; panel" in html and "<b>bright" not in html
    # The tube's fixture from the photos (reroom.invert.line_photos), in words.
    assert "moved 19 mm across, 41 mm up), radius (16.9 mm) and a trough (cut-off 54 deg)" in html
    assert "from 22 photos of it" in html
    assert re.search(r"n vertices &lt; n</td><td class=\"num\">2<", html)
    # Materials: the albedo table and its swatch (sRGB of the linear albedo).
    assert "0.625" in html and "0.375" in html
    assert "background:rgb(207,188,165)" in html
    # Re-render figures, the edit's ops, the timing table, the failure named.
    assert "0.875" in html and "&quot;repaint&quot;" in html
    assert "Stage edits failed: edit set &#x27;x&#x27;: no light named &#x27;lamp9&#x27;" in html
    assert "did not finish in this run (stage edits failed)" in html
    # Stages that did not run say so instead of breaking the page.
    assert "No HDR results" in html and "No layout" in html
    assert "could not be drawn" not in html
    assert "no ground truth" in html.lower()
    assert not (report_run / "report" / "evaluation.json").exists()


def test_missing_scan_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(ReroomError, match="transforms.json"):
        write_report(tmp_path)


def test_html_helpers() -> None:
    assert fmt(None) == "&ndash;" and fmt(0.123456) == "0.123" and fmt([1, 2.5]) == "1, 2.5"
    assert fmt("<x>") == "&lt;x&gt;" and fmt(True) == "yes"
    t = table(["a<"], [[1.0], ["<i>"]])
    assert "<th>a&lt;</th>" in t and '<td class="num">1</td>' in t and "&lt;i&gt;" in t


def test_screenshot_errors(tmp_path: Path) -> None:
    with pytest.raises(ReroomError, match="no such page"):
        screenshot(tmp_path / "none.html", tmp_path / "x.png")
    page = tmp_path / "p.html"
    page.write_text("<html></html>")
    with pytest.raises(ReroomError):
        screenshot(page, tmp_path / "x.png", browser=str(tmp_path / "no-browser"))
    assert not (tmp_path / "x.png").exists()


@pytest.mark.skipif(
    find_chromium() is None,
    reason="no chromium binary (scripts/setup.sh installs it with apt-get when it can)",
)
def test_report_in_headless_chromium(report_run: Path, tmp_path: Path) -> None:
    path = write_report(report_run)
    shot = screenshot(path, tmp_path / "shot.png", width=1000, height=1400)
    im = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    assert im.shape == (1400, 1000, 3)
    # Not blank: the page has text, tables and pictures.
    assert image_variance(shot) > 500.0
    # The inline style sheet was applied: the dark header band on a light page.
    assert im[10, 500].sum() < 3 * 60
    assert im[1300, 500].sum() > 3 * 200
    # A blank page, for contrast, has no variance at all.
    blank = tmp_path / "blank.html"
    blank.write_text("<html><body style='background:#fff'></body></html>")
    assert image_variance(screenshot(blank, tmp_path / "blank.png", width=200, height=100)) < 1.0


def _layout_doc(ceiling: str, warnings: list[str]) -> dict:
    return {
        "ceiling": ceiling,
        "floor_z": 0.0,
        "ceiling_z": 2.3,
        "rooms": [
            {
                "name": "room0",
                "area": 17.3,
                "floor_z": 0.0,
                "ceiling_z": 2.3,
                "ceiling": ceiling,
                "walls": [{"index": 0}] * 4,
                "openings": [],
                "baseboard": None,
            }
        ],
        "label_counts": {},
        "notes": [],
        "warnings": warnings,
    }


def test_layout_section_shows_an_estimated_ceiling_and_the_warnings(report_run: Path) -> None:
    from reroom.report.sections import layout_section

    warn = "room0: wall candidates cover 20 % of its outline <partial> & grown"
    atomic_write_json(
        report_run / "layout" / "layout.json", _layout_doc("estimated", ["no ceiling seen", warn])
    )
    html = layout_section(report_run, None)
    assert "The ceiling was not seen" in html and "lower bound" in html
    assert "<h3>Warnings</h3>" in html and "<li>no ceiling seen</li>" in html
    # Plain text, escaped.
    assert "20 % of its outline &lt;partial&gt; &amp; grown" in html and "<partial>" not in html
    assert "<td>2.3 (estimated)</td>" in html
    # The whole report carries it too.
    assert "The ceiling was not seen" in write_report(report_run).read_text()
    # A seen ceiling: no note, no warnings list, the plain height.
    atomic_write_json(report_run / "layout" / "layout.json", _layout_doc("seen", []))
    html = layout_section(report_run, None)
    assert "not seen" not in html and "Warnings" not in html and "estimated" not in html
    assert '<td class="num">2.3</td>' in html


def test_the_lights_table_says_what_shaped_a_profile() -> None:
    from reroom.report.sections import _prior_note

    shade = {"distribution": {"basis": "inclination", "open_fraction": [1.0, 0.0]}}
    assert "what its scanned shade leaves open" in _prior_note(shade)
    tube = {"distribution": {"basis": "line", "open_fraction": [[1.0]]}}
    assert "what its scanned fixture leaves open" in _prior_note(tube)
    closed = {"distribution": {"basis": "inclination", "fixture_inside_fraction": 0.72}}
    assert "closed its fixture: no shape prior" in _prior_note(closed)
    assert _prior_note({}) == "" and _prior_note({"distribution": {"basis": "cubemap"}}) == ""
