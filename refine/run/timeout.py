"""The result of a library call whose ``time_limit_s`` ran out: status ``"timeout"``, never a verdict.

A call's time limit is one deadline for the whole call (:mod:`refine.control`). When it passes, the
stage that notices raises :class:`refine.control.OutOfTime`; :func:`timed_call` catches it and
returns a result (:class:`refine.api.Result`, without a run) whose ``to_dict()`` has the fields of
``result.json`` a host reads first: ``status`` ``"timeout"``, a ``reason`` naming the stage, the
budget and the wall time used, ``stopped_stage``, no passes, no metrics, no program. What each stage
does at the limit is in docs/api.md ("Time limit").
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from typing import Any

from refine.control import OutOfTime
from refine.errors import InputError
from refine.export.result_json import SCHEMA_VERSION
from refine.problem import Problem


def timeout_doc(problem: str, stage: str, time_limit_s: float | None, elapsed_s: float) -> dict[str, Any]:
    """The ``to_dict()`` document of a call stopped by its time limit during ``stage``.

    Args:
        problem: the problem's name.
        stage: the stage that noticed the limit (``"load"``, ``"fuse"``, ``"solve"``, ...).
        time_limit_s: the call's budget [s].
        elapsed_s: wall time from the call's start to the stop [s].
    """
    return {
        "schema_version": SCHEMA_VERSION,
        "status": "timeout",
        "reason": (
            f"time limit of {time_limit_s:g} s (time_limit_s) reached during the {stage} stage, "
            f"after {elapsed_s:.2f} s: no verdict, no program"
        ),
        "stopped_stage": stage,
        "problem": problem,
        "n_waypoints": 0,
        "n_passes": 0,
        "metrics": {},
        "diagnosis": [],
        "repairs": [],
        "violations": [],
        "passes": [],
        "motions": [],
        "placement": None,
        "solver": {"time_limit_reached": True},
        "timings_s": {"run": elapsed_s},
    }


def timed_call(problem: str, call: Callable[[], Any], result: Callable[..., Any]) -> Any:
    """``call()``, or ``result(None, doc=timeout_doc(...))`` when it raised :class:`OutOfTime`.

    Args:
        problem: the problem's name, for the document.
        call: the call's work, run inside :func:`refine.control.controlled`.
        result: the result class (:class:`refine.api.Result`), built with no run and the document.
    """
    t0 = time.perf_counter()
    try:
        return call()
    except OutOfTime as e:
        return result(None, doc=timeout_doc(problem, e.stage, e.time_limit_s, time.perf_counter() - t0))


def checked_limit(time_limit_s: Any) -> float | None:
    """A call's ``time_limit_s`` [s] as a float, None for none; an InputError unless in [0.1, 86400] s."""
    if time_limit_s is None:
        return None
    ok = isinstance(time_limit_s, (int, float)) and not isinstance(time_limit_s, bool)
    if not (ok and math.isfinite(time_limit_s) and 0.1 <= time_limit_s <= 86400.0):
        raise InputError(
            f"time_limit_s: expected a number in [0.1, 86400] s, got {time_limit_s!r}",
            key="time_limit_s",
            value=time_limit_s,
            expected="a number in [0.1, 86400] s",
        )
    return float(time_limit_s)


def with_time_limit(problem: Problem, time_limit_s: float | None) -> Problem:
    """``problem`` with ``[repair] time_limit_s`` the call's budget when one is given (per pass within it)."""
    if time_limit_s is None:
        return problem
    return dataclasses.replace(problem, repair=dataclasses.replace(problem.repair, time_limit_s=time_limit_s))
