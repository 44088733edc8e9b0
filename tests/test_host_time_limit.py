"""A library call's ``time_limit_s`` is one budget for the whole call: past it, status ``timeout``.

The host's progress callback spends the budget at a chosen stage (it moves the call's deadline to
now), so the stage that must notice is known without timing anything: the next check after it.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import refine
from refine.control import OutOfTime, check_cancelled, controlled, current


def _line(n: int = 16) -> tuple[np.ndarray, np.ndarray]:
    positions = np.column_stack([np.full(n, 0.6), np.linspace(-0.15, 0.15, n), np.full(n, 0.3)])
    down = Rotation.from_euler("x", 180.0, degrees=True).as_matrix()  # tool z pointing down
    return positions, np.repeat(down[None], n, axis=0)


LIMIT_S = 60.0
"""The calls' limit: far more than they need, so that only the spent budget stops them."""


def _spend_at(stage: str, iteration: int = 0):
    def progress(p: refine.Progress) -> None:
        if p.stage == stage and p.iteration == iteration:
            current().deadline = time.perf_counter()  # the budget is gone from this moment

    return progress


def test_a_limit_that_runs_out_before_the_solve_stops_the_call_at_that_stage():
    positions, R = _line()
    result = refine.refine_path(
        "ur10e", positions, R, speeds=0.1, time_limit_s=LIMIT_S, progress=_spend_at("build")
    )
    assert result.status == "timeout"
    doc = result.to_dict()
    # the sleep came after "build" finished; the check right after it is build's own
    assert doc["stopped_stage"] == "build"
    assert "during the build stage" in doc["reason"] and "60 s" in doc["reason"]
    assert doc["passes"] == [] and doc["metrics"] == {}
    assert result.run is None
    with pytest.raises(refine.NotExecutable):
        result.program("urscript")
    again = refine.Result.from_dict(doc)
    assert again.status == "timeout" and again.to_dict() == doc


def test_a_limit_that_runs_out_inside_ipopt_stops_it_at_that_iteration(tmp_path):
    positions, R = _line()
    seen: list[refine.Progress] = []

    def progress(p: refine.Progress) -> None:
        seen.append(p)
        _spend_at("solve", 1)(p)

    result = refine.refine_path("ur10e", positions, R, speeds=0.1, time_limit_s=LIMIT_S, progress=progress)
    assert result.status == "timeout"
    # IPOPT's callback stopped it at the iteration that ran past the limit: no iteration after it
    assert [p.iteration for p in seen if p.stage == "solve"] == [1]
    first = result.run.first.refinement
    assert first.time_limit_reached and "time limit of 60 s" in first.reason
    assert result.to_dict()["stopped_stage"] == "refine"
    assert not any(s.stage == "timing" for s in seen)  # no verdict, so no timing


def test_a_call_without_a_limit_never_times_out_and_a_bad_limit_is_refused():
    with controlled():
        check_cancelled("load")  # no limit: no OutOfTime however late
    with controlled(time_limit_s=0.0):
        with pytest.raises(OutOfTime, match="during the fuse stage"):
            check_cancelled("fuse")
    positions, R = _line()
    for bad in (0.0, -1.0, "1", float("nan"), True):
        with pytest.raises(refine.InputError) as e:
            refine.refine_path("ur10e", positions, R, speeds=0.1, time_limit_s=bad)
        assert e.value.key == "time_limit_s"
