"""Open a report in headless Chromium (Debian's ``chromium``), read the DOM after load, take screenshots.

``check_report(path)`` runs the page once with ``--dump-dom`` (after the page's own drawing is done:
a virtual-time budget lets its timers and promises run) and returns what the browser printed to
the console and the parsed DOM. Chromium writes every console message of the page to stderr as
``...:CONSOLE:<line>] "<message>", source: ...``; a few of those are Chromium's own advisories on
software WebGL (:data:`BROWSER_ADVISORIES`), not the page's, and are set aside. Run as a script to
print the figures and write screenshots: ``python3 tests/report/browser.py out/x/report.html DIR``.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from lxml import html as lxml_html

BROWSER_ADVISORIES = (
    "GL Driver Message",  # SwiftShader performance notes ("GPU stall due to ReadPixels")
    "Canvas2D: Multiple readback operations",  # a performance hint about getImageData
    "Automatic fallback to software WebGL",
)
FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--enable-unsafe-swiftshader",
    "--disable-dev-shm-usage",
    "--no-first-run",
    "--hide-scrollbars",
    "--enable-logging=stderr",
    "--v=0",
)
_CONSOLE = re.compile(r':CONSOLE:\d+\] "(.*)", source: ')


def chromium() -> str | None:
    """The Chromium executable, or None."""
    return shutil.which("chromium") or shutil.which("chromium-browser")


@dataclass
class PageCheck:
    """What the browser made of a page."""

    console: list[str]  # console messages of the page (advisories removed)
    dom: lxml_html.HtmlElement

    def find(self, element_id: str) -> lxml_html.HtmlElement:
        """The element with this id (AssertionError when there is none)."""
        found = self.dom.get_element_by_id(element_id, None)
        if found is None:
            raise AssertionError(f"no element #{element_id} in the rendered page")
        return found


def _run(args: list[str], timeout_s: float) -> subprocess.CompletedProcess:
    exe = chromium()
    if exe is None:
        raise FileNotFoundError("chromium is not installed (apt-get install chromium)")
    return subprocess.run(
        [exe, *FLAGS, *args], capture_output=True, text=True, timeout=timeout_s, check=False
    )


def check_report(path: Path, budget_ms: int = 20000, timeout_s: float = 180.0) -> PageCheck:
    """Load ``path`` and return its console messages and its DOM after the page has drawn."""
    done = _run([f"--virtual-time-budget={budget_ms}", "--dump-dom", path.resolve().as_uri()], timeout_s)
    if done.returncode != 0 or not done.stdout.strip():
        raise AssertionError(f"chromium failed on {path}: exit {done.returncode}\n{done.stderr[-2000:]}")
    console = [m for m in _CONSOLE.findall(done.stderr) if not any(a in m for a in BROWSER_ADVISORIES)]
    return PageCheck(console, lxml_html.fromstring(done.stdout))


def screenshot(path: Path, png: Path, anchor: str = "", size: tuple[int, int] = (1400, 1000)) -> Path:
    """A screenshot of the page (scrolled to ``#anchor`` when given) as ``png``."""
    png.parent.mkdir(parents=True, exist_ok=True)
    url = path.resolve().as_uri() + (f"#{anchor}" if anchor else "")
    args = ["--virtual-time-budget=20000", f"--window-size={size[0]},{size[1]}", f"--screenshot={png}", url]
    done = _run(args, 180.0)
    if not png.is_file():
        raise AssertionError(
            f"chromium wrote no screenshot of {path}: exit {done.returncode}\n{done.stderr[-2000:]}"
        )
    return png


def main(argv: list[str]) -> int:
    """Print the figures of a report's check and write its two screenshots into a folder."""
    page, folder = Path(argv[0]), Path(argv[1])
    check = check_report(page)
    body = check.dom.find("body")
    print(
        f"{page}: {page.stat().st_size / 1e6:.2f} MB, drawn in {body.get('data-render-ms')} ms after navigation"
    )
    print(f"console messages: {len(check.console)}", *check.console, sep="\n  ")
    for name, anchor in (("first-screen", ""), ("3d", "scene-only")):
        print(screenshot(page, folder / f"{page.parent.name}-{name}.png", anchor))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
