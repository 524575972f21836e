"""A certificate's PDF (or a PNG of it) from a headless Chromium, where one is installed
(Debian: ``apt-get install chromium``). Without one the HTML page is the certificate."""
from __future__ import annotations

import shutil
import subprocess
import tempfile
from pathlib import Path

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable", "chrome")
TIMEOUT_S = 120.0


def find_browser() -> str | None:
    """The first headless-capable Chromium on PATH, or None."""
    return next((found for name in BROWSERS if (found := shutil.which(name))), None)


def _run(browser: str, page: Path, *options: str) -> None:
    # A throw-away profile: nothing read from or left in the user's; no sandbox, which needs
    # privileges a station's service account or a container lacks.
    with tempfile.TemporaryDirectory(prefix="fieldcal-chromium-") as profile:
        command = [browser, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
                   "--disable-extensions", "--allow-file-access-from-files", f"--user-data-dir={profile}",
                   *options, Path(page).resolve().as_uri()]
        try:
            done = subprocess.run(command, capture_output=True, text=True, timeout=TIMEOUT_S)
        except subprocess.TimeoutExpired:
            raise ValueError(f"{browser}: no answer within {TIMEOUT_S:.0f} s") from None
    if done.returncode != 0:
        lines = [line for line in done.stderr.splitlines() if line.strip()]
        raise ValueError(f"{browser} exited with status {done.returncode}"
                         + (f": {lines[-1].strip()}" if lines else ""))


def print_pdf(page: Path, pdf: Path, browser: str) -> None:
    """``page`` (an HTML file) printed to ``pdf`` (A4, as its @page rule says; no header nor
    footer added by the browser); a one-line ValueError when the browser fails."""
    partial = Path(pdf).with_name(f".{Path(pdf).name}.partial")
    try:
        _run(browser, page, f"--print-to-pdf={partial}", "--no-pdf-header-footer")
        if not partial.is_file() or partial.stat().st_size == 0:
            raise ValueError(f"{browser} wrote no PDF")
        partial.replace(pdf)  # the PDF appears whole or not at all
    finally:
        partial.unlink(missing_ok=True)


def screenshot(page: Path, png: Path, browser: str, width: int = 794, height: int = 1123) -> None:
    """A PNG of the page's first ``width`` × ``height`` CSS pixels (default: one A4 page at 96 dpi)."""
    _run(browser, page, f"--screenshot={Path(png).resolve()}", f"--window-size={width},{height}",
         "--hide-scrollbars")
    if not Path(png).is_file():
        raise ValueError(f"{browser} wrote no screenshot")
