"""Check a report in a real browser: a headless Chromium screenshot.

``chromium --headless --screenshot`` loads the page exactly as a user's browser would
(layout, inlined images decoded), so a screenshot that is not blank shows the page
renders. On Debian ``apt-get install chromium`` provides the binary (``scripts/setup.sh``
installs it when it is missing and it can).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from reroom.errors import ReroomError
from reroom.io.atomic import atomic_path

__all__ = ["BROWSERS", "find_chromium", "screenshot", "image_variance"]

#: Binary names tried, in order (``REROOM_CHROMIUM`` overrides them).
BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable", "chrome")


def find_chromium() -> str | None:
    """Path of a Chromium-family browser: ``$REROOM_CHROMIUM`` or the first on ``PATH``."""
    env = os.environ.get("REROOM_CHROMIUM")
    if env:
        return env if Path(env).is_file() or shutil.which(env) else None
    for name in BROWSERS:
        path = shutil.which(name)
        if path:
            return path
    return None


def screenshot(
    html_path: str | Path,
    png_path: str | Path,
    *,
    width: int = 1280,
    height: int = 2400,
    timeout: float = 120.0,
    browser: str | None = None,
) -> Path:
    """Render ``html_path`` in headless Chromium and save a ``width`` x ``height`` PNG.

    Parameters
    ----------
    html_path:
        The page (a local file).
    png_path:
        Where the screenshot goes (written atomically).
    width, height:
        The browser window, CSS pixels (the screenshot shows its top ``height`` pixels).
    timeout:
        Seconds before the browser is given up on.
    browser:
        Browser binary (default: :func:`find_chromium`).

    Returns
    -------
    Path
        ``png_path``.

    Raises
    ------
    ReroomError
        When no browser exists, the page does not exist, or the browser fails, times
        out or writes no image (the message has the end of its output).
    """
    page = Path(html_path).resolve()
    if not page.is_file():
        raise ReroomError(f"{page}: no such page to screenshot")
    exe = browser or find_chromium()
    if exe is None:
        raise ReroomError(
            "no Chromium browser found (tried $REROOM_CHROMIUM and "
            f"{', '.join(BROWSERS)}): install one, e.g. apt-get install chromium"
        )
    out = Path(png_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="reroom-chromium-") as profile:
        with atomic_path(out) as tmp:
            shot = Path(tmp).with_suffix(".png")  # Chromium insists on the extension
            cmd = [
                exe,
                "--headless",
                "--disable-gpu",
                "--hide-scrollbars",
                # Root (CI containers) cannot use Chromium's sandbox; the page is our own.
                *(["--no-sandbox"] if hasattr(os, "geteuid") and os.geteuid() == 0 else []),
                "--no-first-run",
                "--disable-extensions",
                "--disable-dev-shm-usage",  # containers often have a tiny /dev/shm
                f"--user-data-dir={profile}",
                f"--window-size={int(width)},{int(height)}",
                f"--screenshot={shot}",
                page.as_uri(),
            ]
            try:
                proc = subprocess.run(
                    cmd, capture_output=True, text=True, timeout=timeout, check=False
                )
            except OSError as exc:
                raise ReroomError(f"{exe}: cannot be started ({exc.strerror or exc})") from exc
            except subprocess.TimeoutExpired as exc:
                raise ReroomError(f"{exe}: no screenshot of {page} within {timeout:.0f} s") from exc
            if proc.returncode != 0 or not shot.is_file() or shot.stat().st_size == 0:
                tail = (proc.stderr or proc.stdout or "").strip()[-600:]
                raise ReroomError(
                    f"{exe}: screenshot of {page} failed (exit {proc.returncode}): {tail}"
                )
            if shot != Path(tmp):
                os.replace(shot, tmp)
    return out


def image_variance(png_path: str | Path) -> float:
    """Variance of a picture's grey levels (0-255): 0 for a blank page."""
    from PIL import Image

    with Image.open(png_path) as im:
        grey = np.asarray(im.convert("L"), np.float64)
    return float(grey.var())
