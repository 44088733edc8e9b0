"""The re-solve of a change: a warm attempt without repairs, then the cold solve `refine run` gives."""

from __future__ import annotations

from pathlib import Path

import pytest
import tomlkit

from refine.serve import session as session_module
from refine.serve.edits import apply_changes
from refine.serve.session import FusedCache, resolve

ROOT = Path(__file__).resolve().parents[2]
GLASS = ROOT / "problems" / "glass_adhesive" / "problem.toml"


def _moved(x_m: float):
    base = tomlkit.parse(GLASS.read_text(encoding="utf-8"))
    return apply_changes(base, {"move": {"xyz": [x_m, 0.0, 0.0], "rpy_deg": [0.0, 0.0, 0.0]}}, GLASS)[1]


@pytest.fixture
def calls(monkeypatch):
    """Every solve_problem call of the session: (repair enabled, warm start given)."""
    seen: list[tuple[bool, bool]] = []
    real = session_module.solve_problem

    def spy(problem, **kw):
        seen.append((problem.repair.enabled, kw.get("warm") is not None))
        return real(problem, **kw)

    monkeypatch.setattr(session_module, "solve_problem", spy)
    return seen


def test_a_warm_attempt_that_fails_is_strict_and_the_verdict_is_the_cold_one(calls):
    from refine.robot.registry import robot_for
    from refine.run.solve import solve_problem

    cache = FusedCache()
    placed = _moved(0.32)  # ok as placed, 320 mm along x: near the edge of the reach
    previous = resolve(placed, cache.path_for(placed), None)
    assert previous.status == "ok"
    far = _moved(0.40)  # 80 mm more: beyond the reach (a warm start, under the 0.1 m of a jump)
    calls.clear()
    answer = resolve(far, cache.path_for(far), previous)
    # the warm attempt runs without the slack repair; only the cold solve repairs, once
    assert calls == [(False, True), (True, False)]
    cold = solve_problem(far, robot=robot_for(far.robot), fused=cache.path_for(far))
    assert answer.status == cold.status == "infeasible"
    assert answer.first.refinement.reason == cold.first.refinement.reason
    assert answer.problem is far and answer.problem.repair.enabled


def test_an_ok_warm_attempt_is_the_answer_with_the_settings_asked(calls):
    cache = FusedCache()
    placed = _moved(0.0)
    previous = resolve(placed, cache.path_for(placed), None)
    shifted = _moved(0.002)
    calls.clear()
    answer = resolve(shifted, cache.path_for(shifted), previous)
    assert calls == [(False, True)]  # one strict warm solve, ok: no cold solve after it
    assert answer.status == "ok"
    assert answer.problem is shifted and answer.problem.repair.enabled  # the settings asked, not the strict copy
    assert answer.placement is None
