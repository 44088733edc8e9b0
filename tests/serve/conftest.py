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
