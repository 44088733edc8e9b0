"""A library call solved again: what an earlier run of the same robot built, reused.

:func:`solve_again` is the step behind ``refine.solve(..., previous=)`` and
``refine.refine_path(..., previous=)``: the earlier run's problem where it still fits, and its
joints as the start (:mod:`refine.optimise.warm`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from numpy.typing import ArrayLike

from refine.arguments import joints_from

if TYPE_CHECKING:
    from refine.paths import FusedPath
    from refine.problem import Problem
    from refine.robot.model import Robot
    from refine.run.result import RunResult


def solve_again(
    problem: Problem,
    robot: Robot,
    fused: FusedPath,
    previous: RunResult | None,
    initial_joints: ArrayLike | None,
) -> RunResult:
    """Solve ``problem`` on ``fused``, reusing what ``previous`` (a run of the same robot) built.

    Its first pass's problem is reused when the robot, base, tool and weights are the same
    (:func:`refine.optimise.problem.reuse_for`), and its joints, moved onto the new poses, are the
    start unless ``initial_joints`` (N, n) [rad] is given; its last problem's active set and its
    multipliers start the solve (also of a problem rebuilt for another tool or base).
    """
    from refine.optimise.problem import reuse_for
    from refine.optimise.warm import WarmStart, built_for
    from refine.run.solve import solve_problem
    from refine.run.stages import weights_for

    nlp = None
    warm = None
    n = robot.nq
    q0 = joints_from(initial_joints, len(fused), n)
    if previous is not None:
        first = previous.first
        old = first.nlp
        same = previous.robot is robot and built_for(
            old, problem.robot.base_in_world, problem.tool, weights_for(problem, robot)
        )
        nlp = reuse_for(old, fused, problem.tolerances) if same else None
        if q0 is None and previous.robot is robot and first.refinement.q.shape == (len(fused), n):
            # the previous joints moved onto the new poses, and its last problem and multipliers:
            # kept where the robot, tool and weights are the same, else their rows taken over by
            # the new problem (refine.optimise.warm)
            warm = WarmStart(
                first.refinement.q,
                first.fused.rotations if len(first.fused) == len(fused) else None,
                first.refinement.problem,
                first.refinement.multipliers,
                first.clearance,
                reusable=nlp is not None,
                line=first.line,
            )
    return solve_problem(problem, robot=robot, fused=fused, nlp=nlp, q0=q0, warm=warm)
