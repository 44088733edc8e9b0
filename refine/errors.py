"""The exception hierarchy: one root, one subclass per kind of failure."""

from __future__ import annotations

import contextlib
import contextvars
import difflib
import functools
import inspect
from collections.abc import Callable, Iterator
from typing import Any, TypeVar

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


class ArgumentError(InputError, TypeError):
    """A library call was given an unknown keyword, a missing or extra argument, or a wrong type.

    An :class:`InputError` (so a ``RefineError``) and a ``TypeError``, with ``key`` (the argument),
    ``value`` and ``expected`` (the keywords the call takes, or the type it wants).
    """


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


F = TypeVar("F", bound=Callable[..., Any])


def checked_call(fn: F) -> F:
    """``fn`` whose unknown keyword or missing argument is an ArgumentError (not Python's TypeError).

    The error names the keyword (``key``), its value and the keywords ``fn`` takes (``expected``),
    with the nearest one when the name looks misspelt.
    """
    signature = inspect.signature(fn)
    names = [
        n for n, p in signature.parameters.items() if n not in ("self", "cls") and p.kind != p.VAR_KEYWORD
    ]
    closed = all(p.kind != p.VAR_KEYWORD for p in signature.parameters.values())

    @functools.wraps(fn)
    def call(*args: Any, **kwargs: Any) -> Any:
        # Python binds the arguments by the same rules before ``fn`` runs a line, so the signature
        # is bound (for the message) only when the call raised a TypeError; one from inside ``fn``
        # (the arguments bind) is raised as it was
        try:
            return fn(*args, **kwargs)
        except TypeError:
            try:
                signature.bind(*args, **kwargs)
            except TypeError as e:
                error = e
            else:
                raise
        unknown = next((k for k in kwargs if k not in signature.parameters), None) if closed else None
        near = difflib.get_close_matches(unknown, names, n=1) if unknown else []
        hint = f"; did you mean {near[0]!r}?" if near else ""
        raise ArgumentError(
            f"{fn.__qualname__.removesuffix('.__init__')}: {error}{hint} (it takes {', '.join(names)})",
            key=unknown,
            value=kwargs.get(unknown) if unknown else None,
            expected=f"one of the arguments {', '.join(names)}",
        ) from None

    return call  # type: ignore[return-value]
