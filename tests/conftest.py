"""Suite-wide helpers: what a test needs that the repository does not ship.

A test that needs something outside the package (the shared AutomationML schemas in ``../shared``,
an optional module) asks for it through the ``require`` fixture. Where it is missing the test is
skipped with the reason in the summary (``-ra``) on a workstation, and fails under ``CI=true``, so a
CI run can never turn a missing prerequisite into a green line.
"""

from __future__ import annotations

import importlib
import os
from pathlib import Path
from types import ModuleType

import pytest

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
"""The shared read-only folder next to the repository (``../shared``)."""


def in_ci() -> bool:
    """True when the environment says this is a CI run (``CI=true``, ``1`` or ``yes``)."""
    return os.environ.get("CI", "").strip().lower() in ("true", "1", "yes")


def missing(reason: str) -> None:
    """Skip the running test with ``reason``, or fail it under ``CI=true``."""
    if in_ci():
        pytest.fail(f"{reason} (a missing prerequisite fails under CI=true)", pytrace=False)
    pytest.skip(f"{reason} (set CI=true to make this a failure)")


class Require:
    """What a test needs from outside the package; see the module docstring."""

    shared = SHARED

    @staticmethod
    def module(name: str) -> ModuleType:
        """Import ``name``, or skip/fail saying which module and why it did not import."""
        try:
            return importlib.import_module(name)
        except ImportError as e:
            missing(f"module {name!r} is not importable ({e})")
            raise  # unreachable: missing() always raises

    @staticmethod
    def path(path: Path, what: str) -> Path:
        """``path`` when it exists, otherwise skip/fail naming ``what`` it should hold."""
        if not path.exists():
            missing(f"{what} not found at {path}")
        return path


@pytest.fixture(scope="session")
def require() -> Require:
    """``require.module(name)``, ``require.path(path, what)``, ``require.shared`` (``../shared``)."""
    return Require()
