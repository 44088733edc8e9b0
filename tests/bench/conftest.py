"""Shared data of the benchmark tests."""

from __future__ import annotations

import json

import pytest

from refine.bench.contenders import CONTENDERS

WAVE = {"robot": "abb_irb4600_60_205", "centre_m": [1.3, 0.0, 0.6], "length_m": 0.3, "tool_length_m": 0.35}
"""A generated family's keys: a sine wave 0.3 m long in front of the IRB 4600 (a few seconds for refine)."""


def family_toml(name: str, spec: dict) -> str:
    """``[generated.NAME]`` with the keys of ``spec`` (strings, numbers and lists of numbers)."""
    return f"\n[generated.{name}]\n" + "".join(f"{k} = {json.dumps(v)}\n" for k, v in spec.items())


TINY_WAVE = '\n[suite.tiny]\ngenerated = ["wave"]\nsizes = [20]\n' + family_toml("wave", WAVE)
"""A suite of one 20-waypoint wave (:data:`WAVE`)."""


@pytest.fixture(scope="session")
def tiny_wave() -> str:
    """The text of :data:`TINY_WAVE`: a suites file of one short wave."""
    return TINY_WAVE


@pytest.fixture(scope="session")
def wave_spec() -> dict:
    """A copy of :data:`WAVE`, the keys of the wave family."""
    return json.loads(json.dumps(WAVE))


@pytest.fixture(scope="session")
def wave_family():
    """``wave_family(name, extra)``: ``[generated.NAME]`` with the wave's keys and the TOML lines ``extra``."""

    def make(name: str, extra: str = "") -> str:
        return family_toml(name, WAVE) + extra

    return make


@pytest.fixture(scope="session")
def tiny_wave_with(tiny_wave):
    """``tiny_wave_with(families, sizes, extra)``: the tiny suite with other families and sizes, and
    ``extra`` TOML (their ``[generated.NAME]`` tables) appended."""

    def make(families: list[str], sizes: list[int], extra: str = "") -> str:
        head = f"generated = {json.dumps(families)}\nsizes = {json.dumps(sizes)}"
        return tiny_wave.replace('generated = ["wave"]\nsizes = [20]', head) + extra

    return make


@pytest.fixture
def registry():
    """CONTENDERS as it was, restored after the test."""
    saved = dict(CONTENDERS)
    yield CONTENDERS
    CONTENDERS.clear()
    CONTENDERS.update(saved)


@pytest.fixture
def write_rows():
    """``write_rows(path, rows)``: a benchmark CSV of ``rows`` (dicts of the columns) under the header."""
    import csv

    from refine.bench.table import COLUMNS

    def write(path, rows):
        with path.open("w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=COLUMNS)
            writer.writeheader()
            writer.writerows(rows)
        return path

    return write
