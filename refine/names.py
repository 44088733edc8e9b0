"""Safe names: text from a problem file made fit for file names, program identifiers and comments.

Problem text (the problem's ``name``, the tool's name, pass names) ends up in three places where it
could do harm: in output **file names** (a ``/`` or ``..`` would write outside the output folder, a
leading dot hides the file), as **identifiers** in robot programs (RAPID ``MODULE``, KRL ``DEF``,
URScript ``def``), and inside **comments** of those programs (a newline would end the comment and
turn the rest of the text into program statements). Every writer goes through these functions:

* :func:`file_stem`: letters, digits, ``_``, ``-`` and inner ``.`` only; no leading dot or dash;
  at most :data:`MAX_STEM` characters; never empty, never a Windows device name.
* :func:`identifier`: an ASCII letter, then letters, digits and ``_``; at most ``max_len``.
* :func:`comment_text`: one line of printable ASCII (control and line-separator characters, and
  anything outside ASCII, become ``?`` or a space), at most ``max_len`` characters, so a comment
  ends where the writer ends it.
"""

from __future__ import annotations

import re
import unicodedata

MAX_STEM = 64
"""Longest output file stem [characters]; leaves room for suffixes within every file system's 255."""

_WINDOWS_DEVICES = {
    "con",
    "prn",
    "aux",
    "nul",
    *(f"com{i}" for i in range(10)),
    *(f"lpt{i}" for i in range(10)),
}
_UNSAFE_STEM = re.compile(r"[^A-Za-z0-9_.\-]+")
_UNSAFE_IDENT = re.compile(r"[^A-Za-z0-9_]+")


def _ascii(text: str) -> str:
    """``text`` folded to ASCII: accents dropped (``é`` -> ``e``), anything else as ``?``."""
    folded = unicodedata.normalize("NFKD", str(text))
    return "".join(c if ord(c) < 128 else ("" if unicodedata.combining(c) else "?") for c in folded)


def file_stem(text: str, fallback: str = "problem") -> str:
    """A file name stem safe on every file system and inside the output folder.

    Args:
        text: the wanted name, e.g. the problem's ``name``.
        fallback: used when nothing safe is left (must itself be safe).

    Returns:
        ``text`` with every run of characters other than ASCII letters, digits, ``_``, ``-`` and
        ``.`` replaced by ``_``, leading dots, dashes and underscores removed, trailing dots
        removed, cut to :data:`MAX_STEM` characters; ``fallback`` when that leaves nothing or a
        name made of dots.
    """
    stem = _UNSAFE_STEM.sub("_", _ascii(text).replace("?", "_"))
    stem = stem.lstrip("._-")[:MAX_STEM].rstrip(".")
    if not stem.strip("._-") or stem.split(".")[0].lower() in _WINDOWS_DEVICES:
        return fallback if not stem.strip("._-") else f"{fallback}_{stem}"[:MAX_STEM]
    return stem


def identifier(text: str, fallback: str, max_len: int = 32) -> str:
    """A program identifier: an ASCII letter first, then letters, digits and ``_``.

    Args:
        text: the wanted name.
        fallback: prefix used when ``text`` does not start with a letter (must start with one).
        max_len: longest identifier the dialect allows (RAPID 32, KRL 24).

    Returns:
        The identifier, at most ``max_len`` characters.
    """
    name = _UNSAFE_IDENT.sub("_", _ascii(text).replace("?", "_")).strip("_")
    if not name or not ("a" <= name[0].lower() <= "z"):
        name = f"{fallback}_{name}".rstrip("_")
    return name[:max_len].rstrip("_") or fallback[:max_len]


def comment_text(text: str, max_len: int = 120) -> str:
    """One line of printable ASCII that cannot end the comment it is written into.

    Every character that is not printable ASCII (newlines, carriage returns, tabs, form feeds,
    vertical tabs, NEL, the Unicode line and paragraph separators, NUL, escape sequences) becomes
    a space or ``?``; runs of spaces collapse; the result is cut to ``max_len`` characters.
    """
    spaced = "".join(" " if unicodedata.category(c)[0] in "CZ" else c for c in str(text))
    folded = "".join(c if " " <= c <= "~" else "?" for c in _ascii(spaced))
    line = re.sub(r" {2,}", " ", folded).strip()
    return line if len(line) <= max_len else line[: max_len - 3] + "..."


def message_text(text: str, max_len: int = 2000) -> str:
    """An error message fit for a terminal.

    Control characters (but newlines) and undecodable bytes are shown as escapes, and the message
    is cut to ``max_len`` characters, so one quoting a broken file can neither drive the terminal
    nor flood it.
    """
    out = "".join(
        c if c == "\n" or (c.isprintable() and not 0xD800 <= ord(c) <= 0xDFFF) else repr(c)[1:-1]
        for c in str(text)
    )
    return out if len(out) <= max_len else out[: max_len - 25] + f" ... ({len(out)} characters)"
