"""A contact sheet: the frames of a scan in a grid, each labelled with its index."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from reroom.io.images import write_rgb8


def contact_sheet(
    images: Sequence[np.ndarray],
    path: str | Path | None = None,
    columns: int = 6,
    labels: Sequence[str] | None = None,
    tile_width: int = 240,
    gap: int = 4,
) -> np.ndarray:
    """Tile 8-bit RGB images into one picture, labelled, and optionally save it.

    Images are resized to ``tile_width`` (keeping their aspect ratio, using the
    first image's). Returns the sheet as ``(H, W, 3)`` uint8.
    """
    from PIL import Image, ImageDraw

    if not images:
        raise ValueError("contact_sheet needs at least one image")
    h0, w0 = images[0].shape[:2]
    tw = tile_width
    th = max(1, round(tw * h0 / w0))
    columns = max(1, min(columns, len(images)))
    rows = (len(images) + columns - 1) // columns
    sheet = Image.new("RGB", (columns * (tw + gap) + gap, rows * (th + gap) + gap), (24, 24, 24))
    draw = ImageDraw.Draw(sheet)
    for i, img in enumerate(images):
        r, c = divmod(i, columns)
        tile = Image.fromarray(np.asarray(img, np.uint8)).resize(
            (tw, th), Image.Resampling.BILINEAR
        )
        x, y = gap + c * (tw + gap), gap + r * (th + gap)
        sheet.paste(tile, (x, y))
        text = labels[i] if labels is not None else str(i)
        draw.rectangle([x, y, x + 7 * len(text) + 6, y + 14], fill=(0, 0, 0))
        draw.text((x + 3, y + 1), text, fill=(255, 255, 255))
    arr = np.asarray(sheet)
    if path is not None:
        write_rgb8(path, arr)
    return arr
