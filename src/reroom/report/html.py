"""Self-contained HTML: escaped text, tables, and images inlined as base64 PNG.

Nothing here refers to anything outside the page (no stylesheets, scripts, fonts or
image URLs), so a report can be mailed, archived or opened offline.
"""

from __future__ import annotations

import base64
import html
import io
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "CSS",
    "esc",
    "figure",
    "fmt",
    "image_uri",
    "img",
    "page",
    "section",
    "swatch",
    "table",
]

#: The page's whole style sheet (inlined).
CSS = """
body { font: 14px/1.45 system-ui, -apple-system, "Segoe UI", Roboto, sans-serif;
       margin: 0; color: #1d2733; background: #f4f5f7; }
header { background: #1d2733; color: #fff; padding: 18px 28px; }
header h1 { margin: 0 0 4px 0; font-size: 22px; }
header p { margin: 0; color: #c8d0da; }
nav { background: #fff; border-bottom: 1px solid #dde1e6; padding: 8px 28px; }
nav a { margin-right: 14px; color: #2a62b8; text-decoration: none; }
main { padding: 8px 28px 40px 28px; max-width: 1400px; }
section { background: #fff; border: 1px solid #dde1e6; border-radius: 6px;
          margin: 16px 0; padding: 12px 18px; }
h2 { font-size: 18px; margin: 4px 0 10px 0; }
h3 { font-size: 15px; margin: 14px 0 6px 0; }
table { border-collapse: collapse; margin: 6px 0 10px 0; }
th, td { border: 1px solid #dde1e6; padding: 3px 8px; text-align: left; vertical-align: top; }
th { background: #eef1f5; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
figure { display: inline-block; margin: 4px 10px 10px 0; vertical-align: top; }
figure img { display: block; max-width: 100%; border: 1px solid #dde1e6; }
figure[style] img { width: 100%; }
figcaption { font-size: 12px; color: #5b6675; max-width: 640px; }
.ok { color: #1a7f37; font-weight: 600; }
.skipped { color: #5b6675; }
.failed { color: #c62828; font-weight: 600; }
.note { color: #8a5a00; }
.swatch { display: inline-block; width: 28px; height: 16px; border: 1px solid #999;
          vertical-align: middle; }
pre { background: #f4f5f7; padding: 6px 8px; overflow-x: auto; font-size: 12px; }
"""


def esc(text: Any) -> str:
    """HTML-escape ``str(text)``."""
    return html.escape(str(text), quote=True)


def fmt(value: Any, digits: int = 3) -> str:
    """A number with ``digits`` significant digits; lists joined; ``None`` as a dash."""
    if value is None:
        return "&ndash;"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        v = float(value)
        if not np.isfinite(v):
            return esc(v)
        return f"{v:.{digits}g}"
    if isinstance(value, list | tuple | np.ndarray):
        return ", ".join(fmt(v, digits) for v in value)
    return esc(value)


def image_uri(image: np.ndarray | str | Path, max_width: int | None = None) -> str:
    """A ``data:image/png;base64,...`` URI of an 8-bit image or of an image file.

    Parameters
    ----------
    image:
        ``(H, W, 3|4)`` or ``(H, W)`` uint8 array, or the path of a PNG/JPEG file.
    max_width:
        Downscale (Lanczos) to at most this width first; files are re-encoded then.
    """
    from PIL import Image

    if isinstance(image, str | Path):
        path = Path(image)
        if max_width is None and path.suffix.lower() == ".png":
            return "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode()
        pil = Image.open(path)
        pil.load()
    else:
        pil = Image.fromarray(np.ascontiguousarray(image))
    if max_width is not None and pil.width > max_width:
        h = max(1, round(pil.height * max_width / pil.width))
        pil = pil.resize((max_width, h), Image.Resampling.LANCZOS)
    if pil.mode not in ("RGB", "RGBA", "L"):
        pil = pil.convert("RGB")
    buf = io.BytesIO()
    pil.save(buf, format="PNG", compress_level=6)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()


def img(image: np.ndarray | str | Path, alt: str, max_width: int | None = None) -> str:
    """An ``<img>`` with the image inlined."""
    return f'<img src="{image_uri(image, max_width)}" alt="{esc(alt)}">'


def figure(
    image: np.ndarray | str | Path, caption: str, max_width: int | None = None, width: int = 0
) -> str:
    """A ``<figure>`` with an inlined image and an (escaped) caption.

    ``width`` (CSS pixels, 0: natural size) sets the displayed width.
    """
    style = f' style="width:{width}px"' if width else ""
    return (
        f"<figure{style}>{img(image, caption, max_width)}"
        f"<figcaption>{esc(caption)}</figcaption></figure>"
    )


def swatch(rgb_linear: Sequence[float]) -> str:
    """A small box filled with a linear RGB colour (sRGB-encoded for display)."""
    from reroom.io.images import linear_to_srgb

    c = np.clip(linear_to_srgb(np.clip(np.asarray(rgb_linear, float), 0, 1)), 0, 1)
    r, g, b = (int(round(255 * x)) for x in c)
    return f'<span class="swatch" style="background:rgb({r},{g},{b})"></span>'


def table(headers: Sequence[str] | None, rows: Iterable[Sequence[Any]], raw: bool = False) -> str:
    """An HTML table; cells are formatted with :func:`fmt` unless ``raw`` (already HTML).

    ``headers`` ``None``: no header row (a key-value table).
    """
    head = "".join(f"<th>{esc(h)}</th>" for h in headers or [])
    body = []
    for row in rows:
        cells = []
        for v in row:
            num = isinstance(v, int | float | np.integer | np.floating) and not isinstance(v, bool)
            text = v if raw and isinstance(v, str) else fmt(v)
            cells.append(f'<td class="num">{text}</td>' if num else f"<td>{text}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    thead = f"<thead><tr>{head}</tr></thead>" if headers else ""
    return f"<table>{thead}<tbody>{''.join(body)}</tbody></table>"


def section(anchor: str, title: str, body: str) -> str:
    """A ``<section>`` with an id (for the navigation bar) and a heading."""
    return f'<section id="{esc(anchor)}"><h2>{esc(title)}</h2>{body}</section>'


def page(title: str, subtitle: str, sections: Sequence[tuple[str, str, str]]) -> str:
    """The whole document: header, navigation, then ``(anchor, title, body)`` sections."""
    nav = "".join(f'<a href="#{esc(a)}">{esc(t)}</a>' for a, t, _ in sections)
    body = "".join(section(a, t, b) for a, t, b in sections)
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f"<title>{esc(title)}</title><style>{CSS}</style></head><body>"
        f"<header><h1>{esc(title)}</h1><p>{esc(subtitle)}</p></header>"
        f"<nav>{nav}</nav><main>{body}</main></body></html>\n"
    )
