"""The reach model's bound on how far a TCP position is out of reach at any orientation.

Soundness is measured against the robot's forward kinematics (Pinocchio) at joints drawn inside the
bounds: no reached position may be out of reach, and no point may be further out of reach than
from the nearest reached one. Tightness comes from a hand derivation on the iiwa: with every joint
at 0 its arm and tool stand straight up from the shoulder, the farthest any TCP position gets from
it, so a point further up that line is out of reach by exactly the excess.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from refine.robot.registry import load_robot

MARGIN = math.radians(2.0)
OUT_OF_REACH = Path(__file__).parent.parent.parent / "problems" / "unreachable" / "out_of_reach"


def _frame(xyz, rpy_deg) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = pin.rpy.rpyToMatrix(*np.radians(rpy_deg))
    T[:3, 3] = xyz
    return T


def _reached(robot, base, tcp, count: int, seed: int = 3) -> np.ndarray:
    """TCP positions in {F} at ``count`` joints drawn inside the limits less the margin."""
    lower, upper = robot.spec.lower + MARGIN, robot.spec.upper - MARGIN
    qs = lower + np.random.default_rng(seed).random((count, robot.nq)) * (upper - lower)
    return np.array([(base @ robot.fk(q) @ tcp)[:3, 3] for q in qs])


@pytest.mark.parametrize("name", ["abb_irb4600_60_205", "kuka_iiwa14_r820"])
def test_no_reached_position_is_out_of_reach(name):
    from refine.optimise.reach import reach_bound

    robot = load_robot(name)
    base = _frame([0.3, -0.2, 0.1], [0.0, 0.0, 30.0])
    tcp = _frame([0.05, 0.0, 0.25], [0.0, 20.0, 0.0])
    lower, upper = robot.spec.lower + MARGIN, robot.spec.upper - MARGIN
    reached = _reached(robot, base, tcp, 1500)
    assert np.all(reach_bound(robot, MARGIN, base, tcp, reached, lower, upper) <= 1e-9)
    # points around the reached ones: never further out than from the nearest reached position
    rng = np.random.default_rng(5)
    points = reached[:300] + rng.normal(size=(300, 3)) * 0.6
    nearest = np.linalg.norm(points[:, None] - reached[None], axis=2).min(axis=1)
    bound = reach_bound(robot, MARGIN, base, tcp, points, lower, upper)
    assert np.all(bound <= nearest + 1e-9)
    assert (bound > 0.0).sum() > 10  # and it proves something about the points far out


def test_a_point_beyond_the_stretched_iiwa_is_out_of_reach_by_the_excess():
    from refine.optimise.reach import reach_bound

    robot = load_robot("kuka_iiwa14_r820")
    base, tcp = _frame([0.0, 0.0, 0.0], [0.0, 0.0, 0.0]), _frame([0.0, 0.0, 0.2], [0.0, 0.0, 0.0])
    lower, upper = robot.spec.lower + MARGIN, robot.spec.upper - MARGIN
    data = robot.model.createData()
    pin.forwardKinematics(robot.model, data, np.zeros(robot.nq))
    shoulder = data.oMi[2].translation  # axis 2 meets axis 1 there
    top = (robot.fk(np.zeros(robot.nq)) @ tcp)[:3, 3]
    up = (top - shoulder) / np.linalg.norm(top - shoulder)
    assert np.allclose(up, [0.0, 0.0, 1.0])  # straight up
    excess = np.array([0.0, 0.01, 0.05, 0.3])
    bound = reach_bound(robot, MARGIN, base, tcp, top + excess[:, None] * up, lower, upper)
    assert bound == pytest.approx(excess, abs=1e-6)


def test_nothing_is_proven_without_a_spherical_wrist_or_outside_the_sampled_bounds():
    from refine.optimise.reach import reach_bound

    far = np.array([[5.0, 0.0, 0.5]])  # beyond either robot's reach
    eye = np.eye(4)
    ur = load_robot("ur10e")  # offset wrist
    assert reach_bound(ur, MARGIN, eye, eye, far, ur.spec.lower + MARGIN, ur.spec.upper - MARGIN)[0] == 0.0
    iiwa = load_robot("kuka_iiwa14_r820")
    lower, upper = iiwa.spec.lower + MARGIN, iiwa.spec.upper - MARGIN
    assert reach_bound(iiwa, MARGIN, eye, eye, far, lower, upper)[0] > 3.0
    wider = upper.copy()
    wider[3] += 2 * MARGIN  # the elbow beyond what the reach model sampled
    assert reach_bound(iiwa, MARGIN, eye, eye, far, lower, wider)[0] == 0.0


@pytest.fixture(scope="module")
def out_of_reach():
    from refine.problem import load_problem
    from refine.robot.registry import robot_for
    from refine.run.stages import fused_path, refinement_for

    problem = load_problem(OUT_OF_REACH)
    robot = robot_for(problem.robot)
    return robot, refinement_for(problem, robot, fused_path(problem))


def test_the_bead_beyond_the_iiwas_reach_is_out_of_reach_by_its_distance_past_the_stretched_arm(out_of_reach):
    from refine.optimise.steady import position_gap

    robot, nlp = out_of_reach
    data = robot.model.createData()
    pin.forwardKinematics(robot.model, data, np.zeros(robot.nq))
    shoulder = nlp.base_in_world[:3, :3] @ data.oMi[2].translation + nlp.base_in_world[:3, 3]
    top = (nlp.base_in_world @ robot.fk(np.zeros(robot.nq)) @ nlp.tcp_in_flange)[:3, 3]
    excess = np.linalg.norm(nlp.fused.positions - shoulder, axis=1) - np.linalg.norm(top - shoulder)
    gap = position_gap(nlp)
    assert gap == pytest.approx(np.maximum(excess, 0.0), abs=1e-6)
    assert gap.max() > 0.02  # the middle of the arc, more than 20 mm out


def test_a_seed_out_of_reach_is_not_chained_with_the_spin_free(out_of_reach, monkeypatch, caplog):
    import logging

    import refine.optimise.steady as steady

    robot, nlp = out_of_reach
    n = nlp.n_waypoints
    abandoned = (np.zeros((n, robot.nq)), np.full(n, np.inf))  # every branch's chain turns the arm over
    chain = np.ones((n, robot.nq))
    monkeypatch.setattr(steady, "chained_seed", lambda *a, **k: abandoned)
    monkeypatch.setattr(steady, "initial_guess", lambda *a, **k: chain)

    def never(*a, **k):
        raise AssertionError("chained with the spin free")

    monkeypatch.setattr(steady, "spin_free_chain", never)
    with caplog.at_level(logging.INFO, logger="refine.optimise.steady"):
        assert steady.whole_chain(nlp, None, None, None, 0.5) is chain
    assert "out of reach at any orientation" in caplog.text
