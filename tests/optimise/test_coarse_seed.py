"""The redundant arm's seed from a coarse refinement (``refine.optimise.solve.coarse_seed``).

The reference is the refinement solved from the plain chained-IK seed: the coarse seed must lead
to the same answer. Poses are checked with the robot's own forward kinematics, placed by hand.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from refine.bench.suites import generated_problem, load_suites
from refine.optimise.solve import coarse_seed, initial_guess, solve_refinement


@functools.cache
def _iiwa(n: int):
    problem = generated_problem("test", "iiwa", load_suites()["generated"]["iiwa"], n)
    return problem, problem.refinement()


def test_the_coarse_seed_reaches_every_pose_and_leads_to_the_same_answer():
    problem, nlp = _iiwa(200)
    chain = initial_guess(nlp, problem.home)
    seed = coarse_seed(nlp, chain)
    assert seed is not None and seed.shape == chain.shape
    lower, upper = problem.robot.spec.lower, problem.robot.spec.upper
    assert np.all(seed >= lower - 1e-12) and np.all(seed <= upper + 1e-12)
    for k in range(0, len(seed), 17):  # the TCP at the CAD point with the demonstrated orientation
        T = problem.base_in_world @ problem.robot.fk(seed[k]) @ problem.tcp_in_flange
        np.testing.assert_allclose(T[:3, 3], problem.fused.positions[k], atol=1e-5)
        np.testing.assert_allclose(T[:3, :3], problem.fused.rotations[k], atol=1e-5)
    plain = solve_refinement(nlp, chain, home=problem.home)
    smooth = solve_refinement(nlp, seed, home=problem.home)
    assert plain.status == smooth.status == "ok"
    np.testing.assert_allclose(smooth.q, plain.q, atol=1e-5)
    # the coarse seed starts next to the answer, the chain does not (its elbow is tens of degrees off)
    assert np.abs(seed - plain.q).max() < np.radians(3.0) < np.abs(chain - plain.q).max()
    assert smooth.iterations < plain.iterations


@pytest.mark.parametrize(("family", "n"), [("irb4600", 200), ("iiwa", 100)])
def test_no_coarse_seed_for_a_six_axis_arm_or_a_short_path(family, n):
    problem = generated_problem("test", family, load_suites()["generated"][family], n)
    nlp = problem.refinement()
    assert coarse_seed(nlp, initial_guess(nlp, problem.home)) is None
