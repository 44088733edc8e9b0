"""A library call solved again: what an earlier run of the same robot built, reused.

:func:`solve_again` is the step behind ``refine.solve(..., previous=)`` and
``refine.refine_path(..., previous=)``, and :func:`warm_from` the start ``refine serve``'s
re-solves take too: the earlier run's problem where it still fits, and its joints, last problem
and multipliers as the start (:mod:`refine.optimise.warm`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from numpy.typing import ArrayLike

from refine.arguments import joints_from

if TYPE_CHECKING:
    from refine.optimise.problem import RefinementNLP
    from refine.optimise.warm import WarmStart
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
    from refine.run.solve import solve_problem

    nlp = None
    warm = None
    q0 = joints_from(initial_joints, len(fused), robot.nq)
    if previous is not None:
        nlp, warm = warm_from(previous, problem, robot, fused)
        if q0 is not None:
            warm = None
    return solve_problem(problem, robot=robot, fused=fused, nlp=nlp, q0=q0, warm=warm)


def warm_from(
    previous: RunResult, problem: Problem, robot: Robot, fused: FusedPath
) -> tuple[RefinementNLP | None, WarmStart | None]:
    """The built problem to reuse and the start of a solve of ``problem`` on ``fused`` from ``previous``.

    The built problem is ``previous``'s first pass's when the robot, base, tool and weights are the
    same (:func:`refine.optimise.problem.reuse_for` checks the rest), else None. The start
    (:class:`refine.optimise.warm.WarmStart`, None for another robot or number of waypoints) holds
    the previous joints, to be moved onto the new poses, and its last problem and multipliers:
    kept where the built problem is, else their rows taken over by the new problem; and its
    motions, which the new program's are planned from (each verified again).
    """
    from refine.optimise.problem import reuse_for
    from refine.optimise.warm import WarmStart, built_for
    from refine.run.stages import weights_for

    first = previous.first
    same = previous.robot is robot and built_for(
        first.nlp, problem.robot.base_in_world, problem.tool, weights_for(problem, robot)
    )
    nlp = reuse_for(first.nlp, fused, problem.tolerances) if same else None
    if previous.robot is not robot or first.refinement.q.shape != (len(fused), robot.nq):
        return nlp, None
    last, multipliers = first.refinement.problem, first.refinement.multipliers
    if first.refinement.strict_problem is not None:
        # a repaired answer: the strict problem it grew from, whose rows the strict re-solve
        # needs again; the elastic solve's multipliers are not its
        last, multipliers = first.refinement.strict_problem, None
    return nlp, WarmStart(
        first.refinement.q,
        first.fused.rotations if len(first.fused) == len(fused) else None,
        last,
        multipliers,
        first.clearance,
        reusable=nlp is not None,
        line=first.line,
        motions=tuple(previous.motions),
    )
