"""The ``verified`` column counts the runs whose answer keeps what it claims.

An ``ok`` answer claims the problem's tolerances, a ``repaired`` one the tolerances with the
orientation slack it reports and no more; ``infeasible`` (or failed) claims no path and reads ``–``.
The paths here are made by hand: the greedy chain on the demonstrated poses (deviation about 0), and
the same chain on poses tilted by a known angle about each tool's own x axis, at the same points.
"""

from __future__ import annotations

import numpy as np
import pytest

from refine.bench.contenders import Answer, greedy_ik, register_contender
from refine.bench.report import verified_cell, write_report
from refine.bench.runner import claim_kept, run_suites

EXTRA_DEG = 2.0
"""The tilt beyond the problem's orientation tolerance (3 deg by default) [deg]."""


def _tilted(problem, extra_deg: float = EXTRA_DEG) -> tuple[np.ndarray, float]:
    """The greedy chain to the demonstrated points with every tool turned by cone + ``extra_deg``.

    A turn by θ about the tool's own x axis moves its z axis (the tool axis) by θ exactly, so the
    path deviates by θ at every waypoint and keeps the points. Returns the joints and θ [deg].
    """
    from refine.optimise.seed import ik_chain, start_candidates
    from refine.robot.kinematics import TcpKinematics

    theta = problem.tolerances.orientation_deg + extra_deg
    c, s = np.cos(np.radians(theta)), np.sin(np.radians(theta))
    turn = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    kin = TcpKinematics(problem.robot, problem.base_in_world, problem.tcp_in_flange, problem.tool_in_world)
    margin = np.radians(problem.tolerances.joint_margin_deg)
    lower, upper = problem.robot.spec.lower + margin, problem.robot.spec.upper - margin
    targets = np.tile(np.eye(4), (problem.n_waypoints, 1, 1))
    targets[:, :3, :3] = problem.fused.rotations @ turn
    targets[:, :3, 3] = problem.fused.positions
    q, _ = ik_chain(kin, targets, lower, upper, start_candidates(lower, upper, problem.home))
    return q, theta


def _repaired(slack_over_tilt_deg: float):
    """A contender answering the tilted path as ``repaired`` with slack = tilt - cone + the given figure."""

    def contender(problem):
        q, theta = _tilted(problem)
        slack = np.full(problem.n_waypoints, theta - problem.tolerances.orientation_deg + slack_over_tilt_deg)
        return Answer("repaired", q, {"solve": 0.001}, 0.001, slack_deg=slack)

    return contender


def _infeasible(problem):
    """Says infeasible, handing over the greedy chain's joints (which keep every tolerance)."""
    answer = greedy_ik(problem)
    return Answer("infeasible", answer.q, answer.times_s, answer.cpu_s)


def test_claim_kept_by_hand():
    assert claim_kept("ok", True, True) is True
    assert claim_kept("ok", False, True) is False  # an ok answer is held to the strict tolerances
    assert claim_kept("repaired", False, True) is True  # within the slack it reports
    assert claim_kept("repaired", True, False) is False  # not within it: the strict pass is no excuse
    for status in ("infeasible", "failed", "error", "timeout"):
        assert claim_kept(status, True, True) is None  # no path claimed


def test_verified_counts_the_claims_kept_of_every_run(tmp_path, registry, tiny_wave):
    suites = tmp_path / "suites.toml"
    suites.write_text(tiny_wave)
    register_contender("within-slack", _repaired(+1.0))  # slack 3 deg for a 2 deg excess: kept
    register_contender("beyond-slack", _repaired(-1.0))  # slack 1 deg for a 2 deg excess: not kept
    register_contender("says-infeasible", _infeasible)
    calls = []

    def mixed(problem):
        """ok (greedy, kept), then infeasible (no claim), then repaired beyond its slack (not kept)."""
        calls.append(1)
        return [greedy_ik, _infeasible, _repaired(-1.0)][len(calls) - 1](problem)

    register_contender("mixed", mixed)
    names = ["greedy-ik", "within-slack", "beyond-slack", "says-infeasible"]
    out = tmp_path / "bench.csv"
    rows = run_suites(["tiny"], names, out, suites_file=suites, echo=lambda _: None, isolate=False)
    rows += run_suites(
        ["tiny"], ["mixed"], out, suites_file=suites, repeat=3, echo=lambda _: None, isolate=False
    )
    by = {r["contender"]: r for r in rows}
    theta = 3.0 + EXTRA_DEG
    # the tilted paths deviate by the tilt everywhere and break only the cone
    for name in ("within-slack", "beyond-slack"):
        assert by[name]["max_orientation_deviation_deg"] == pytest.approx(theta, abs=1e-3), name
        assert "orientation" in by[name]["reason"], name
    expected = {  # (verified, verified_runs, claimed_runs, strict_runs)
        "greedy-ik": (True, 1, 1, 1),
        "within-slack": (True, 1, 1, 0),
        "beyond-slack": (False, 0, 1, 0),
        "says-infeasible": ("", 0, 0, 1),
        "mixed": (False, 1, 2, 2),
    }
    for name, figures in expected.items():
        row = by[name]
        got = (row["verified"], row["verified_runs"], row["claimed_runs"], row["strict_runs"])
        assert got == figures, name
    # the repaired answer within its slack is no success on a problem not built to be repaired
    assert not by["within-slack"]["success"] and by["greedy-ik"]["success"]
    # the report's column, from the CSV
    report = write_report(out, tmp_path / "report").read_text()
    cells = {
        "greedy-ik": "| ok | – | 1/1 |",
        "within-slack": "| repaired | – | 1/1 |",
        "beyond-slack": "| repaired | – | 0/1 |",
        "says-infeasible": "| infeasible | – | – |",
    }
    assert "| mixed | repaired | – | 1/2 of 3 |" in report  # the last run's status, 2 of 3 claimed
    first = write_report(out, tmp_path / "first", run_ids=[r["run_id"] for r in rows[:1]]).read_text()
    for name, cell in cells.items():
        assert f"| {name} {cell}" in first, name
    # the strict check's broken cone reads as the slack used, for the verified repair only
    within = next(line for line in first.splitlines() if "| within-slack | repaired |" in line)
    beyond = next(line for line in first.splitlines() if "| beyond-slack | repaired |" in line)
    assert "| within its slack; strict: orientation" in within
    assert "within its slack" not in beyond and "| orientation" in beyond
    assert verified_cell({"claimed_runs": "", "verified_runs": "0", "repeats": "3"}) == "–"
