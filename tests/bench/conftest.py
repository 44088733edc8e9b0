"""Shared data of the benchmark tests."""

from __future__ import annotations

import pytest

TINY_WAVE = """
[suite.tiny]
generated = ["wave"]
sizes = [20]

[generated.wave]
robot = "abb_irb4600_60_205"
centre_m = [1.3, 0.0, 0.6]
length_m = 0.3
tool_length_m = 0.35
"""
"""A suite of one 20-waypoint wave on the IRB 4600, 0.3 m long (a few seconds for refine)."""


@pytest.fixture(scope="session")
def tiny_wave() -> str:
    """The text of :data:`TINY_WAVE`: a suites file of one short wave."""
    return TINY_WAVE
