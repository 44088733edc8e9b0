"""The exception hierarchy: one root, one subclass per kind of failure."""

from __future__ import annotations

from typing import Any


class RefineError(Exception):
    """Root of every error raised by refine."""


class InputError(RefineError, ValueError):
    """A problem file, CAD/CAM file or tracker log is malformed or inconsistent."""


class SolverError(RefineError):
    """A numerical backend (IPOPT, TOPPRA, FCL) failed for a reason other than infeasibility."""

    def __init__(self, message: str, result: Any = None) -> None:
        super().__init__(message)
        self.result = result


class Cancelled(RefineError):
    """The caller asked the call to stop (its ``cancel`` event or callable): no verdict was reached."""
