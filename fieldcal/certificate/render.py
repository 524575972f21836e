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


def _run(browser: str, page: Path, *options: str, output: str = "") -> bytes | None:
    """Run the browser on ``page``; the bytes it wrote to ``output`` (a name in a private
    directory, so nothing it writes goes through a path anyone else could plant a link at)."""
    # A throw-away profile: nothing read from or left in the user's; no sandbox, which needs
    # privileges a station's service account or a container lacks.
    with tempfile.TemporaryDirectory(prefix="fieldcal-chromium-") as profile:
        written = Path(profile) / "out" / output if output else None
        if written is not None:
            written.parent.mkdir()
        command = [browser, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
                   "--disable-extensions", "--allow-file-access-from-files", f"--user-data-dir={profile}",
                   *(option.format(output=written) for option in options), Path(page).resolve().as_uri()]
        try:
            done = subprocess.run(command, capture_output=True, text=True, timeout=TIMEOUT_S)
        except subprocess.TimeoutExpired:
            raise ValueError(f"{browser}: no answer within {TIMEOUT_S:.0f} s") from None
        data = written.read_bytes() if written is not None and written.is_file() else None
    if done.returncode != 0:
        lines = [line for line in done.stderr.splitlines() if line.strip()]
        raise ValueError(f"{browser} exited with status {done.returncode}"
                         + (f": {lines[-1].strip()}" if lines else ""))
    return data


def print_pdf(page: Path, pdf: Path, browser: str, overwrite: bool = True) -> None:
    """``page`` (an HTML file) printed to ``pdf`` (A4, as its @page rule says; no header nor
    footer added by the browser), written by fieldcal.atomic's rule; a one-line ValueError when
    the browser fails."""
    from fieldcal.atomic import write_atomically

    data = _run(browser, page, "--print-to-pdf={output}", "--no-pdf-header-footer", output="page.pdf")
    if not data:
        raise ValueError(f"{browser} wrote no PDF")
    write_atomically(pdf, data, overwrite=overwrite, hint="give --force to replace it")


def screenshot(page: Path, png: Path, browser: str, width: int = 794, height: int = 1123) -> None:
    """A PNG of the page's first ``width`` × ``height`` CSS pixels (default: one A4 page at 96 dpi)."""
    from fieldcal.atomic import write_atomically

    data = _run(browser, page, "--screenshot={output}", f"--window-size={width},{height}",
                "--hide-scrollbars", output="page.png")
    if not data:
        raise ValueError(f"{browser} wrote no screenshot")
    write_atomically(png, data)
