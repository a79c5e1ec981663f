"""The README's picture of a report: four of its sections side by side, in headless Chromium.

Usage (after ``reroom demo --out out/demo``)::

    .venv/bin/python scripts/readme_picture.py out/demo/report.html docs/images/report_demo.png

Each section (``run``, ``layout``, ``lights``, ``edits`` by default) is shown alone (the
others hidden by a style rule in a temporary copy of the page) and screenshotted by
:func:`reroom.report.browser.screenshot`; the shots are cropped to ``--height`` pixels
(the first keeps the page's title bar, the others start below it), laid out two by two
and halved.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

from reroom.io.atomic import atomic_path
from reroom.report.browser import screenshot

#: Pixels of the page's title bar and navigation, cut from every shot but the first.
HEADER_PX = 130


def section_shot(page: Path, section: str, work: Path, width: int, height: int) -> np.ndarray:
    """A screenshot of ``page`` with only ``section`` shown."""
    html = page.read_text(encoding="utf-8")
    style = f"<style>section:not(#{section}){{display:none}}</style></head>"
    alone = work / f"only_{section}.html"
    alone.write_text(html.replace("</head>", style, 1), encoding="utf-8")
    shot = screenshot(alone, work / f"{section}.png", width=width, height=height + HEADER_PX)
    return np.asarray(Image.open(shot).convert("RGB"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("report", type=Path, help="a report.html written by reroom run")
    ap.add_argument("out", type=Path, help="the PNG to write")
    ap.add_argument("--sections", default="run,layout,lights,edits")
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--height", type=int, default=1100)
    args = ap.parse_args()
    names = [s.strip() for s in args.sections.split(",") if s.strip()]
    if len(names) != 4:
        raise SystemExit("--sections needs four section ids (two by two)")
    with tempfile.TemporaryDirectory(prefix="reroom-picture-") as tmp:
        shots = [
            section_shot(args.report.resolve(), name, Path(tmp), args.width, args.height)
            for name in names
        ]
    tiles = [
        s[: args.height] if k == 0 else s[HEADER_PX : HEADER_PX + args.height]
        for k, s in enumerate(shots)
    ]
    gap = np.full((args.height, 16, 3), 200, np.uint8)
    rows = [
        np.concatenate([tiles[0], gap, tiles[1]], axis=1),
        np.concatenate([tiles[2], gap, tiles[3]], axis=1),
    ]
    sep = np.full((16, rows[0].shape[1], 3), 200, np.uint8)
    full = Image.fromarray(np.concatenate([rows[0], sep, rows[1]], axis=0))
    half = full.resize((full.width // 2, full.height // 2), Image.LANCZOS)
    with atomic_path(args.out) as tmp_out:
        half.save(tmp_out, format="PNG", optimize=True)
    print(f"wrote {args.out} ({half.width} x {half.height})")


if __name__ == "__main__":
    main()
