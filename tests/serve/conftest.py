"""Lines the browser tests leave for the end of the run: where their screenshots are, their steps' times."""

from __future__ import annotations

import pytest

SUMMARY: list[str] = []
"""Lines printed in the terminal summary."""


def pytest_terminal_summary(terminalreporter) -> None:  # noqa: ANN001 - pytest's reporter
    for line in SUMMARY:
        terminalreporter.write_line(line)


@pytest.fixture(scope="session")
def summary() -> list[str]:
    """The lines printed at the end of the run (append to it)."""
    return SUMMARY
