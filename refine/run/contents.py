"""A run's files as text in memory, and the per-pass arrays as plain lists (for ``Result.to_dict``).

:func:`render` runs the writers of :mod:`refine.export.writers` into memory
(:func:`refine.export.sink.in_memory`): the trajectory CSV, the PathML document, the motions and the
programs, byte for byte what :meth:`refine.Result.write` puts on disk when both carry the same time
stamp. :func:`contents_dict` and :func:`arrays_from` carry those texts and the arrays through a
plain dictionary and back.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from refine.errors import InputError, NotExecutable
from refine.settings import PROGRAM_FORMATS

if TYPE_CHECKING:
    from refine.run.result import RunResult

MEMORY_DIR = Path("in-memory")
"""The folder name the writers are given when rendering into memory (nothing is created)."""

PASS_ARRAYS = ("joints", "poses", "times", "speeds", "arc_length")


def render(run: RunResult, programs: tuple[str, ...], when: datetime) -> dict[str, tuple[str, bytes]]:
    """Kind -> (file name, bytes) of every file the writers write for ``programs``, in memory.

    Empty when a pass is infeasible or a motion failed (``write`` writes only ``result.json`` then).
    """
    from refine.export.sink import in_memory
    from refine.export.writers import write_outputs

    with in_memory(when) as files:
        outputs = write_outputs(run, MEMORY_DIR, programs)
    return {kind: (path.name, files[path]) for kind, path in outputs.items()}


def check_kind(kind: object) -> str:
    """The program format of ``kind`` (``"rapid"``, ``"krl"``, or an output kind ``"rapid_2"``, ``"krl_dat"``)."""
    base = kind.split("_")[0] if isinstance(kind, str) else None
    if base not in PROGRAM_FORMATS:
        raise InputError(
            f"kind: {kind!r} is not a program format",
            key="kind",
            value=kind,
            expected=f"one of {', '.join(PROGRAM_FORMATS)} (or an output kind such as 'rapid_2', 'krl_dat')",
        )
    return base


def pick(files: dict[str, tuple[str, bytes]], kind: str, status: str) -> str:
    """The text of output ``kind`` (``"krl"`` is the ``.src``), or :class:`NotExecutable`."""
    key = "krl_src" if kind == "krl" else kind
    if key not in files:
        have = sorted(k for k in files if k.split("_")[0] in PROGRAM_FORMATS or k == "pathml")
        if kind == "rapid" and any(k.startswith("rapid_") for k in files):
            extra = ": a multi-pass RAPID program is one module per pass, 'rapid_1', 'rapid_2', ..."
        else:
            extra = ""
        raise NotExecutable(
            f"no {kind!r} document for this result (status {status!r}){extra}",
            key=kind,
            value=status,
            expected="one of " + (", ".join(have) if have else "nothing: no pass is executable"),
        )
    return files[key][1].decode("utf-8")


def contents_dict(run: RunResult, programs: tuple[str, ...], when: datetime) -> dict[str, Any]:
    """The ``contents`` of ``Result.to_dict(contents=True)``: arrays per pass and the files' texts."""
    files = render(run, programs, when)
    return {
        "stamp": when.isoformat(),
        "programs": list(programs),
        "files": {kind: {"name": name, "text": data.decode("utf-8")} for kind, (name, data) in files.items()},
        "passes": [
            {
                "joints": p.refinement.q.tolist(),
                "poses": p.refinement.check.poses.tolist(),
                "times": None if p.timing is None else p.timing.t.tolist(),
                "speeds": None if p.timing is None else p.timing.speed.tolist(),
                "arc_length": p.fused.s.tolist(),
            }
            for p in run.passes
        ],
    }


def files_from(contents: dict[str, Any] | None) -> dict[str, tuple[str, bytes]]:
    """The rendered files of a ``contents`` mapping, or :class:`NotExecutable` without one."""
    if not contents:
        arrays_from(contents, 0)  # raises: rebuilt without contents
    return {k: (v["name"], v["text"].encode("utf-8")) for k, v in contents["files"].items()}


def arrays_from(contents: dict[str, Any] | None, k: int) -> dict[str, np.ndarray | None]:
    """Pass ``k``'s arrays from a ``contents`` mapping, or :class:`NotExecutable` without one."""
    if not contents:
        raise NotExecutable(
            "this result was rebuilt from a dictionary without its contents: no arrays",
            key="contents",
            value=None,
            expected="a dictionary from Result.to_dict(contents=True)",
        )
    doc = contents["passes"][k]
    return {name: None if doc[name] is None else np.asarray(doc[name], float) for name in PASS_ARRAYS}


def check_programs(programs: object) -> tuple[str, ...]:
    """``programs`` as a tuple of program formats, or an InputError naming the one that is not."""
    if isinstance(programs, str) or not isinstance(programs, Sequence):
        raise InputError(
            f"programs: expected a list of program formats, got {programs!r}",
            key="programs",
            value=programs,
            expected=f"a list of {', '.join(PROGRAM_FORMATS)}",
        )
    for k, kind in enumerate(programs):
        if kind not in PROGRAM_FORMATS:
            raise InputError(
                f"programs[{k}]: {kind!r} is not a program format",
                key=f"programs[{k}]",
                value=kind,
                expected=f"one of {', '.join(PROGRAM_FORMATS)}",
            )
    return tuple(programs)


def check_doc(doc: object) -> None:
    """Refuse what is not a ``Result.to_dict()`` document (InputError)."""
    if not isinstance(doc, Mapping) or "schema_version" not in doc or "metrics" not in doc:
        raise InputError(
            "from_dict: expected the dictionary of Result.to_dict()",
            key="doc",
            value=type(doc).__name__,
            expected="a mapping with schema_version, status, metrics, ...",
        )
