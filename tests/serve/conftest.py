"""Lines the browser tests leave for the end of the run: where their screenshots are, their steps' times."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

SUMMARY: list[str] = []
"""Lines printed in the terminal summary (by a run without parallel workers)."""
ARTIFACTS = Path(__file__).resolve().parents[1] / "artifacts" / "serve"
"""Where the browser tests keep their screenshots and ``steps.txt`` (each step's time)."""
LOADED = time.time()
"""When this run collected the tests: an older ``steps.txt`` is another run's."""


def pytest_terminal_summary(terminalreporter) -> None:  # noqa: ANN001 - pytest's reporter
    lines = list(SUMMARY)
    steps = ARTIFACTS / "steps.txt"
    if not lines and steps.is_file() and steps.stat().st_mtime > LOADED:  # the workers' lines do not reach this process: read their file
        lines = [f"refine serve in the browser: screenshots in {ARTIFACTS}"]
        lines += [f"  {line}" for line in steps.read_text(encoding="utf-8").splitlines()]
    for line in lines:
        terminalreporter.write_line(line)


@pytest.fixture(scope="session")
def summary() -> list[str]:
    """The lines printed at the end of the run (append to it)."""
    return SUMMARY


CHROMIUM = Path("/usr/bin/chromium")
"""Debian's chromium, which the browser tests drive (no browser download)."""


class Served:
    """The servers of a run: ``refine serve``'s app on a problem folder, uvicorn on a free port in a thread."""

    def __init__(self) -> None:
        self.running: dict[str, dict] = {}

    def __call__(self, key: str, folder: Path) -> dict:
        """The server of ``key`` (started on ``folder`` the first time): ``url``, ``folder``, ``session``."""
        if key not in self.running:
            self.running[key] = self._start(folder)
        return self.running[key]

    @staticmethod
    def _start(folder: Path) -> dict:
        import threading

        import uvicorn

        from refine.serve.app import create_app
        from refine.serve.session import Session

        session = Session(folder)
        app = create_app(session, folder / "out")
        server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=0, log_level="warning"))
        thread = threading.Thread(target=server.run, daemon=True)
        thread.start()
        deadline = time.time() + 60
        while not server.started and time.time() < deadline:
            time.sleep(0.05)
        assert server.started, "the server did not start within 60 s"
        port = server.servers[0].sockets[0].getsockname()[1]
        return {
            "url": f"http://127.0.0.1:{port}/",
            "folder": folder,
            "session": session,
            "server": server,
            "thread": thread,
        }

    def stop(self, key: str) -> None:
        """Stop the server of ``key`` (waits up to 30 s for it)."""
        info = self.running.pop(key, None)
        if info is not None:
            info["server"].should_exit = True
            info["thread"].join(30)


@pytest.fixture(scope="session")
def served():
    """Start a server once per key for the whole run (:class:`Served`); all stopped at its end."""
    servers = Served()
    yield servers
    for key in list(servers.running):
        servers.stop(key)


@pytest.fixture(scope="session")
def chromium():
    """One chromium for every browser test of the run (Playwright, Debian's executable)."""
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is in the test extra")
    if not CHROMIUM.exists():
        pytest.skip("chromium is not installed (.ci/run installs it)")
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=["--no-sandbox"])
        yield browser
        browser.close()
