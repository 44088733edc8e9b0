"""The exception hierarchy: one root, one subclass per kind of failure."""

from __future__ import annotations

import contextlib
import contextvars
from collections.abc import Iterator
from typing import Any

_api_words: contextvars.ContextVar[bool] = contextvars.ContextVar("refine_api_words", default=False)


def option(cli: str, api: str) -> str:
    """The name of a setting as the caller knows it: ``cli`` (``"--out"``) or, inside :func:`api_words`, ``api``."""
    return api if _api_words.get() else cli


@contextlib.contextmanager
def api_words() -> Iterator[None]:
    """Within the block errors name settings as the Python API does (``out_dir``, not ``--out``)."""
    token = _api_words.set(True)
    try:
        yield
    finally:
        _api_words.reset(token)


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


class NotExecutable(RefineError, LookupError):
    """A document the result does not have.

    A pass is infeasible or timed out, a motion failed, or the result was rebuilt from a dictionary
    without its contents.

    Attributes:
        key: the document asked for (``"rapid"``, ``"pathml"``, ``"contents"``).
        value: the result's status.
        expected: what is available, in words.
        file: always None.
    """

    def __init__(self, message: str, *, key: str, value: Any, expected: str) -> None:
        super().__init__(message)
        self.key, self.value, self.expected, self.file = key, value, expected, None
