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


@pytest.mark.slow
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
    # the settings asked, not the strict copy
    assert answer.problem is shifted and answer.problem.repair.enabled
    assert answer.placement is None


@pytest.mark.slow
def test_every_cad_track_is_a_pass_and_the_demonstration_quality_is_kept(two_track_line_problem):
    """The G-code program of conftest's ``two_track_line_problem``: two feed tracks on the line."""
    from refine.problem import load_problem

    problem = load_problem(two_track_line_problem)
    cache = FusedCache()
    tracks, quality = cache.tracks_for(problem)
    assert len(tracks) == 2 and quality is not None
    first = resolve(problem, tracks, None, quality)
    assert [p.name for p in first.passes] == ["track 1", "track 2"]
    # each pass on its own track: y -100..-10 mm and 10..100 mm (the program's numbers)
    for p, (lo, hi) in zip(first.passes, ((-0.1, -0.01), (0.01, 0.1)), strict=True):
        y = p.fused.positions[:, 1]
        assert y[0] == pytest.approx(lo, abs=1e-9) and y[-1] == pytest.approx(hi, abs=1e-9)
    assert first.demo_quality is quality
    tracks2, quality2 = cache.tracks_for(problem)  # unchanged: reused, not fused again
    assert cache.fused == 1 and tracks2 is tracks and quality2 is quality
    warm = resolve(problem, tracks2, first, quality2)
    assert [p.name for p in warm.passes] == ["track 1", "track 2"] and warm.demo_quality is quality


def test_the_demonstration_quality_in_plain_words():
    from refine.serve.state import demo_quality_html

    assert demo_quality_html(None) == ""
    quality = {
        "n_samples": 1200,
        "sample_step_s": 0.004,  # 250 Hz
        "n_bridged": 2,
        "n_trimmed": 1,
        "longest_bridged_s": 0.031,
        "frame": {
            "observable_rotation_deg": 0.571,
            "observable_sigma_deg": 0.326,
            "detectable_deg": 0.652,
            "offset_m": 0.00284,
            "max_distortion_m": 0.051,
            "rms_after_m": 0.000526,
            "n_points": 618,
        },
        "warnings": ["the <receiver> may have moved"],
        "device_errors": {"n_flagged": 3},
    }
    text = demo_quality_html(quality)
    assert "<li>1200 tracker samples at 250 Hz</li>" in text
    assert "<li>dropouts: 2 bridged (the longest 31 ms), 1 trimmed</li>" in text
    assert (
        "rotation 0.57 deg (± 0.33 deg, told from noise above 0.65 deg), offset 2.8 mm, "
        "distortion up to 51.0 mm, 0.53 mm RMS left over 618 waypoints" in text
    )
    assert "<li>3 samples flagged by the tracker</li>" in text
    assert "the &lt;receiver&gt; may have moved" in text  # escaped


def test_an_ok_warm_attempt_with_placement_bounds_says_the_placement_was_not_needed(calls):
    from refine.robot.registry import robot_for
    from refine.run.solve import solve_problem

    base = tomlkit.parse(GLASS.read_text(encoding="utf-8"))
    bounds = {"repair.placement.translate_m": 0.05, "repair.placement.rotate_deg": 5.0}
    placed = apply_changes(base, bounds, GLASS)[1]
    shifted = apply_changes(base, {**bounds, "move": {"xyz": [0.002, 0.0, 0.0]}}, GLASS)[1]
    assert shifted.repair.placement is not None
    cache = FusedCache()
    previous = resolve(placed, cache.path_for(placed), None)
    calls.clear()
    answer = resolve(shifted, cache.path_for(shifted), previous)
    assert calls == [(False, True)]
    cold = solve_problem(shifted, robot=robot_for(shifted.robot), fused=cache.path_for(shifted))
    assert answer.status == cold.status == "ok"
    assert answer.placement.status == cold.placement.status == "not needed"
    assert answer.placement.bounds == cold.placement.bounds == shifted.repair.placement


def test_a_new_tcp_starts_from_the_previous_rows_and_multipliers_and_gives_the_cold_answer(monkeypatch):
    """Another tool needs another built problem: the warm start still carries the previous last
    problem (its rows taken over) and its multipliers; the answer is the cold solve's."""
    import numpy as np

    from refine.robot.registry import robot_for
    from refine.run.solve import solve_problem

    starts = []
    real = session_module.solve_problem

    def spy(problem, **kw):
        starts.append((kw.get("nlp"), kw.get("warm")))
        return real(problem, **kw)

    monkeypatch.setattr(session_module, "solve_problem", spy)
    base = tomlkit.parse(GLASS.read_text(encoding="utf-8"))
    placed = apply_changes(base, {}, GLASS)[1]
    cache = FusedCache()
    previous = resolve(placed, cache.path_for(placed), None)
    assert previous.status == "ok"
    # 2 mm longer tool, 0.5 deg about x: another tool than the built problem's
    tcp = {"tool.tcp_in_flange": {"xyz": [0.0, 0.0, 0.352], "rpy_deg": [0.5, 0.0, 0.0]}}
    longer = apply_changes(base, tcp, GLASS)[1]
    starts.clear()
    answer = resolve(longer, cache.path_for(longer), previous)
    nlp, warm = starts[0]
    assert nlp is None and warm is not None and not warm.reusable
    assert warm.problem is previous.first.refinement.problem
    assert warm.multipliers is previous.first.refinement.multipliers is not None
    cold = solve_problem(longer, robot=robot_for(longer.robot), fused=cache.path_for(longer))
    assert answer.status == cold.status == "ok"
    assert np.abs(answer.first.refinement.q - cold.first.refinement.q).max() < 1e-4
