"""Reading a problem file's TOML: its size, encoding and syntax checked, errors naming file and line."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from refine.errors import InputError

try:  # Python 3.11+
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

MAX_PROBLEM_FILE_BYTES = 1 << 20
"""Largest problem.toml read [bytes] (1 MiB; the bundled ones are under 5 kB)."""


def read_problem_toml(path: Path) -> dict[str, Any]:
    """The parsed TOML of ``path``; size, encoding and syntax errors name the file and line."""
    try:
        size = path.stat().st_size
        if size > MAX_PROBLEM_FILE_BYTES:
            raise InputError(
                f"{path}: {size} bytes is too large for a problem file (limit {MAX_PROBLEM_FILE_BYTES} bytes)"
            )
        raw = path.read_bytes()
    except OSError as e:
        raise InputError(f"{path}: cannot be read: {e.strerror}") from e
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = raw[: e.start].count(b"\n") + 1
        raise InputError(
            f"{path}:{line}: not UTF-8 text (byte 0x{raw[e.start]:02x} at offset {e.start})"
        ) from e
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise InputError(f"{path}: not valid TOML: {e}") from e
