"""Where the writers' bytes go: a file on disk, or a dictionary in memory.

Every writer of :mod:`refine.export` hands its finished document to :func:`put_text` or
:func:`put_bytes`. Outside :func:`in_memory` that writes the file (its folder created); inside, the
bytes are kept in the dictionary the block yields, keyed by the path, and nothing touches the disk.
The writers' time stamps (PathML's ``WriterProjectTitle`` date, INFORM's ``///DATE``) come from
:func:`stamp`, which :func:`in_memory` and :func:`stamped` can fix, so that a document rendered in
memory and the file written later are the same bytes.
"""

from __future__ import annotations

import contextlib
import contextvars
from collections.abc import Iterator
from datetime import datetime, timezone
from pathlib import Path

_files: contextvars.ContextVar[dict[Path, bytes] | None] = contextvars.ContextVar("refine_sink", default=None)
_stamp: contextvars.ContextVar[datetime | None] = contextvars.ContextVar("refine_stamp", default=None)


def put_bytes(path: Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` (creating its folder), or keep it in memory inside :func:`in_memory`."""
    path = Path(path)
    files = _files.get()
    if files is None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
    else:
        files[path] = data
    return path


def put_text(path: Path, text: str, encoding: str = "utf-8") -> Path:
    """:func:`put_bytes` of ``text`` encoded as ``encoding`` (line ends as given: no translation)."""
    return put_bytes(path, text.encode(encoding))


def stamp() -> datetime:
    """The time the documents being written carry: the fixed one, else now (UTC)."""
    return _stamp.get() or datetime.now(timezone.utc)


@contextlib.contextmanager
def stamped(when: datetime | None) -> Iterator[None]:
    """Within the block the writers' time stamps are ``when`` (None: the time of writing)."""
    token = _stamp.set(when)
    try:
        yield
    finally:
        _stamp.reset(token)


@contextlib.contextmanager
def in_memory(when: datetime | None = None) -> Iterator[dict[Path, bytes]]:
    """Within the block the writers write nothing: the dictionary yielded receives path -> bytes.

    Args:
        when: the time stamp the documents carry; None for the time of writing.
    """
    files: dict[Path, bytes] = {}
    token = _files.set(files)
    try:
        with stamped(when):
            yield files
    finally:
        _files.reset(token)
