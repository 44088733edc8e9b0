"""The exception hierarchy: one root, one subclass per kind of failure."""

from __future__ import annotations

from typing import Any


class RefineError(Exception):
    """Root of every error raised by refine."""


class InputError(RefineError, ValueError):
    """A problem file, CAD/CAM file or tracker log is malformed or inconsistent.

    Besides the message, the parts a host program would show where they apply (None otherwise):

    Attributes:
        key: the setting or argument, e.g. ``"tolerances.orientation_deg"`` or ``"positions"``.
        value: the value given.
        expected: what is accepted, in words with the unit (``"a number in [0, 90] deg"``).
        file: the file the value came from.
    """

    def __init__(
        self,
        message: str,
        *,
        key: str | None = None,
        value: Any = None,
        expected: str | None = None,
        file: str | None = None,
    ) -> None:
        super().__init__(message)
        self.key, self.value, self.expected, self.file = key, value, expected, file


class SolverError(RefineError):
    """A numerical backend (IPOPT, TOPPRA, FCL) failed for a reason other than infeasibility."""

    def __init__(self, message: str, result: Any = None) -> None:
        super().__init__(message)
        self.result = result


class Cancelled(RefineError):
    """The caller asked the call to stop (its ``cancel`` event or callable): no verdict was reached."""
