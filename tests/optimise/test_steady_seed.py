"""A chained IK seed that turns the arm over in one step is not solved as it is.

On the puzzle piece turned round (the grinder on the iiwa's flange) the chain that follows the CAM
toolpath's arbitrary spin about the tool axis runs the last joint into its limit and the arm over
near the end of the path. The expectations are measured with NumPy on the joints (the largest
change between consecutive waypoints), the robot's forward kinematics and the problem's 20 deg
step bound (docs/problem-file.md, ``tolerances.joint_step_deg``'s default), not with the code under test.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np
import pytest

TURNED = Path(__file__).parent.parent.parent / "problems" / "puzzle_piece_turned"
STEP_BOUND = math.radians(20.0)


@pytest.fixture(scope="module")
def turned():
    from refine.problem import load_problem
    from refine.robot.registry import robot_for
    from refine.run.stages import fused_path, refinement_for

    problem = load_problem(TURNED)
    robot = robot_for(problem.robot)
    nlp = refinement_for(problem, robot, fused_path(problem))
    assert problem.robot.home_deg is None  # the seed starts from the first pose's IK branches
    return robot, nlp, None


def _largest_step(qs: np.ndarray) -> float:
    return float(np.max(np.abs(qs[1:] - qs[:-1])))


def test_largest_step_names_the_joint_and_the_step():
    from refine.optimise.steady import largest_step

    qs = np.zeros((5, 3))
    qs[3:, 1] = 0.7  # joint 2 (index 1) jumps from waypoint 2 to 3
    qs[1:, 0] = -0.2
    assert largest_step(qs) == pytest.approx((0.7, 2, 1))
    assert largest_step(qs[:1]) == (0.0, 0, 0)


def test_the_turned_puzzles_seed_keeps_the_step_bound(turned, caplog):
    from refine.optimise.outcome import problem_kinematics
    from refine.optimise.seed import initial_guess
    from refine.optimise.steady import steady_branch

    robot, nlp, home = turned
    first = initial_guess(nlp, home)
    assert _largest_step(first) > STEP_BOUND  # the chain turns the arm over
    with caplog.at_level(logging.INFO, logger="refine.optimise.steady"):
        seed = steady_branch(nlp, problem_kinematics(nlp), first, home, None, 4)
    assert _largest_step(seed) <= STEP_BOUND
    assert "joint step bound is 20 deg" in caplog.text and "spin about the tool axis free" in caplog.text
    # still on the path: the grinding point on every CAD point, the tool axis on the demonstrated one
    lower, upper = robot.spec.lower, robot.spec.upper
    assert np.all(seed >= lower) and np.all(seed <= upper)
    poses = np.array([nlp.base_in_world @ robot.fk(q) @ nlp.tcp_in_flange for q in seed])
    assert np.linalg.norm(poses[:, :3, 3] - nlp.fused.positions, axis=1).max() < 1e-5
    cos = np.einsum("ki,ki->k", poses[:, :3, 2], nlp.fused.rotations[:, :, 2])
    assert np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).max() < 0.01


def test_a_seed_within_the_bound_stays_as_it_is(turned):
    from refine.optimise.outcome import problem_kinematics
    from refine.optimise.steady import steady_branch

    robot, nlp, home = turned
    steady = np.tile(0.5 * (robot.spec.lower + robot.spec.upper), (nlp.n_waypoints, 1))
    steady[:, 0] += np.linspace(0.0, 0.3, nlp.n_waypoints)  # a small step everywhere
    steady[200:, 5] += math.radians(25.0)  # and one just over the bound: the solve's to take in
    assert math.radians(20.0) < _largest_step(steady) < math.radians(26.0)
    assert steady_branch(nlp, problem_kinematics(nlp), steady, home, None, 4) is steady


def test_a_chain_that_turns_the_arm_over_is_abandoned_where_it_does(turned):
    from refine.optimise.seed import chained_seed

    robot, nlp, home = turned
    whole, _ = chained_seed(nlp, home)
    turn = 1.5 * STEP_BOUND
    steps = np.abs(np.diff(whole, axis=0)).max(axis=1)
    k = int(np.flatnonzero(steps > turn)[0])  # the first step beyond 30 deg, by NumPy on the whole chain
    given_up, errors = chained_seed(nlp, home, give_up=turn)
    assert np.isinf(errors).any()  # every branch turned the arm over: the first is returned abandoned
    assert np.array_equal(given_up[: k + 2], whole[: k + 2])  # the whole chain's, up to the turn
    assert np.all(np.isinf(errors[k + 1 :])) and np.all(given_up[k + 2 :] == whole[k + 1])


def test_the_turned_puzzles_seed_is_chained_spin_free_at_once(turned, caplog):
    from refine.optimise.outcome import problem_kinematics
    from refine.optimise.seed import initial_guess
    from refine.optimise.steady import steady_branch, turn_over_step, whole_chain

    robot, nlp, home = turned
    kin = problem_kinematics(nlp)
    assert turn_over_step(nlp) == pytest.approx(1.5 * STEP_BOUND)
    with caplog.at_level(logging.INFO, logger="refine.optimise.steady"):
        seed = whole_chain(nlp, kin, home, None, turn_over_step(nlp))
    assert "every IK branch's chain turns the arm over" in caplog.text
    assert _largest_step(seed) <= STEP_BOUND
    poses = np.array([nlp.base_in_world @ robot.fk(q) @ nlp.tcp_in_flange for q in seed])
    assert np.linalg.norm(poses[:, :3, 3] - nlp.fused.positions, axis=1).max() < 1e-5
    # the seed the whole chains and the re-chain after them give, to the bit
    assert np.array_equal(seed, steady_branch(nlp, kin, initial_guess(nlp, home), home, None, 4))
