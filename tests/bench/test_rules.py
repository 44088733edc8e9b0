"""The largest joint step of every answer and the rules each contender keeps, in the CSV and the report."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest

from refine.bench import peers  # noqa: F401  (registers trajopt and descartes)
from refine.bench.contenders import CONTENDERS, Answer, greedy_ik, register_contender, verify
from refine.bench.report import write_report
from refine.bench.rules import RULES, UNSTATED, columns, kept
from refine.bench.runner import run_suites
from refine.bench.suites import generated_problem, load_suites
from refine.bench.table import COLUMNS, check_header
from refine.errors import InputError

STEP_RAD = 0.2
"""The one large step of the hand-made answer: joint 3 jumps by 0.2 rad between two waypoints."""

STEP_DEG = 0.2 * 180.0 / 3.141592653589793
"""The same step in degrees, 11.459 deg, by hand."""


def _hand_made(problem) -> np.ndarray:
    """Joints that creep 0.001 rad per waypoint on joint 1 and jump by :data:`STEP_RAD` on joint 3 once."""
    n, nq = problem.n_waypoints, problem.robot.nq
    q = np.zeros((n, nq))
    q[:, 0] = 0.001 * np.arange(n)
    q[n // 2 :, 2] = STEP_RAD
    q[:, 4] = 0.5  # the wrist off its zero singularity: irrelevant to the step
    return q


@pytest.fixture
def suites_file(tmp_path, tiny_wave):
    path = tmp_path / "suites.toml"
    path.write_text(tiny_wave)
    return path


def test_the_verifier_measures_the_largest_step_of_any_answer(suites_file):
    problem = generated_problem("tiny", "wave", load_suites(suites_file)["generated"]["wave"], 20)
    verdict = verify(problem, _hand_made(problem))
    assert verdict.max_joint_step_deg == pytest.approx(STEP_DEG, rel=1e-9)
    # a motionless answer has no step; no answer has none to measure
    still = np.tile(greedy_ik(problem).q[:1], (problem.n_waypoints, 1))
    assert verify(problem, still).max_joint_step_deg == 0.0
    assert math.isnan(verify(problem, None).max_joint_step_deg)


def test_every_built_in_contender_states_its_rules():
    for name in CONTENDERS:
        assert kept(name, CONTENDERS[name]) is not None, name
    assert set(kept("refine")) == set(RULES)
    # as the peers are posed: neither bounds the joint step nor keeps a singularity margin, and
    # Descartes checks collision at the waypoints only
    for peer in ("trajopt", "descartes", "drake-ik"):
        assert {"joint-step", "singularity"}.isdisjoint(kept(peer)), peer
        assert {"position", "cone", "joint-margin"} <= set(kept(peer)), peer
    assert "clearance-between" in kept("trajopt") and "clearance-between" not in kept("descartes")
    cols = columns("descartes")
    assert set(cols["rules_kept"].split(";")) | set(cols["rules_not_kept"].split(";")) == set(RULES)
    assert columns("someone-else") == {"rules_kept": UNSTATED, "rules_not_kept": UNSTATED}


def test_a_plug_in_states_its_rules_by_name_and_unknown_names_are_refused():
    def mine(problem):
        return None

    mine.rules_kept = ("position", "joint-step")
    assert columns("mine", mine) == {
        "rules_kept": "position;joint-step",
        "rules_not_kept": "cone;joint-margin;singularity;clearance-waypoints;clearance-between;self-clearance",
    }
    mine.rules_kept = ("position", "speed")
    with pytest.raises(InputError, match="speed"):
        kept("mine", mine)


def test_the_csv_and_the_report_carry_the_step_and_the_rules(registry, suites_file, tmp_path):
    def hand_made(problem):
        return Answer("ok", _hand_made(problem))

    hand_made.rules_kept = ("position", "cone")
    register_contender("hand-made", hand_made)
    csv_path = tmp_path / "b.csv"
    run_suites(["tiny"], ["hand-made"], csv_path, suites_file=suites_file, warmup=0, echo=lambda _: None)
    with csv_path.open() as f:
        (row,) = list(csv.DictReader(f))
    assert float(row["max_joint_step_deg"]) == pytest.approx(STEP_DEG, abs=1e-4)  # 6 digits in the CSV
    assert row["rules_kept"] == "position;cone"
    assert "joint-step" in row["rules_not_kept"] and "position" not in row["rules_not_kept"]
    report = write_report(csv_path, tmp_path / "report").read_text()
    assert "| hand-made | position, cone | joint-margin, joint-step," in report
    assert f"| {STEP_DEG:.2f} |" in report  # 11.46 deg in the suite's table


def test_a_csv_of_the_previous_schema_is_refused(tmp_path):
    previous = [c for c in COLUMNS if c not in ("max_joint_step_deg", "rules_kept", "rules_not_kept")]
    old = tmp_path / "old.csv"
    old.write_text(",".join(previous) + "\n")
    with pytest.raises(InputError, match="schema"):
        check_header(old)
