"""What a refinement returns, and the refinement problem's targets, bounds and kinematics.

What a refinement returns: :class:`Refinement` with its :class:`Repair` segments and diagnosis, the
answers given without a solve (out of reach, time limit), and the refinement problem's targets,
bounds and kinematics that every stage of the solve reads.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from refine.control import note_timeout
from refine.optimise.diagnosis import Diagnoser, Finding, segments
from refine.optimise.problem import ActiveSet, ConstraintSource, RefinementNLP
from refine.optimise.verify import (
    PathCheck,
    check_path,
)
from refine.robot.kinematics import TcpKinematics
from refine.types import Array

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Repair:
    """A segment the strict tolerances could not hold, and what it took.

    Attributes:
        index_start, index_end: first and last waypoint (inclusive).
        s_start_m, s_end_m: their arc lengths [m].
        slack_deg: the largest extra orientation slack used inside [deg].
        reason: the binding constraint: ``"joint limit (joint 5)"``, ``"singularity"``,
            ``"collision"``, ``"joint wrap (joint 6)"`` or ``"orientation"`` when none is active.
        objects: the cell objects or links involved (collision), else empty.
    """

    index_start: int
    index_end: int
    s_start_m: float
    s_end_m: float
    slack_deg: float
    reason: str
    objects: tuple[str, ...] = ()

    def describe(self) -> str:
        """One line for messages and reports."""
        objs = f" ({', '.join(self.objects)})" if self.objects else ""
        return (
            f"waypoints {self.index_start}-{self.index_end} (s = {self.s_start_m:.3f}-{self.s_end_m:.3f} m): "
            f"{self.slack_deg:.2f} deg extra orientation slack, {self.reason}{objs}"
        )


@dataclass(frozen=True)
class Refinement:
    """The outcome of a refinement.

    Attributes:
        status: ``"ok"``, ``"repaired"`` (feasible with extra orientation slack), ``"infeasible"``, or
            ``"timeout"`` (the time budget ran out before a verdict: neither an answer nor a proof).
        reason: empty when ok; otherwise why, naming segments, constraint and figures.
        q: joints per waypoint [rad], shape (N, n).
        q_seed: the IK seed the solver started from [rad], shape (N, n).
        check: the numeric verification of ``q``.
        solver_status: the solver's return status (of the last solve).
        iterations: the solver's iterations, summed over all solves (with a redundant arm's coarse
            seed's, :func:`coarse_seed`).
        outer_iterations: solve -> verify rounds.
        active: the constraints added by the outer loop in the last round.
        slack_deg: extra orientation slack used per waypoint [deg], (N,) (zeros unless repaired).
        repairs: the repaired segments (derived from ``diagnosis``).
        timings_s: ``seed``, ``solve``, ``verify``, ``build`` (rebuilds) wall times [s]; a
            :class:`StageTimes`, whose ``cpu`` holds the process CPU time of the same stages.
        diagnosis: every segment that needed slack or has no answer, with its measured causes
            (:mod:`refine.optimise.diagnosis`); empty when ok.
        time_limit_reached: the time budget ran out before a verdict (status ``timeout``), or after
            the first IK branch's verdict, before the others were tried.
        problem: the last problem solved (with the active set and joint-step rows the rounds
            found), for a re-solve to start from (:mod:`refine.optimise.warm`); None when none was solved.
        multipliers: that solve's multipliers by row and of the variable bounds, or None.
        strict_problem: when ``problem`` is the elastic (repair) problem, the strict problem it was
            built from (the active set and joint-step rows the strict rounds found), for a re-solve
            to start from instead; None otherwise.
        first_options: the solver options of the first solve of the full problem that gave this
            result (the later rounds' and the repair's differ, :mod:`refine.optimise.rounds`); empty
            when none was solved.
    """

    status: str
    reason: str
    q: Array
    q_seed: Array
    check: PathCheck
    solver_status: str
    iterations: int
    outer_iterations: int = 1
    active: ActiveSet = field(default_factory=ActiveSet)
    slack_deg: Array = field(default_factory=lambda: np.zeros(0))
    repairs: tuple[Repair, ...] = ()
    timings_s: dict[str, float] = field(default_factory=dict)
    diagnosis: tuple[Finding, ...] = ()
    time_limit_reached: bool = False
    problem: RefinementNLP | None = None
    multipliers: tuple[Mapping[tuple, float], Array] | None = None
    first_options: dict[str, Any] = field(default_factory=dict)
    strict_problem: RefinementNLP | None = None

    def __getstate__(self) -> dict[str, Any]:
        # the built problem's CasADi expressions and solver stay in the process that built them
        return {**self.__dict__, "problem": None, "strict_problem": None}


def problem_targets(problem: RefinementNLP) -> Array:
    """The target TCP poses (N, 4, 4) in {F}: the CAD positions with the demonstrated orientations."""
    targets = np.zeros((problem.n_waypoints, 4, 4))
    targets[:, :3, :3] = problem.fused.rotations
    targets[:, :3, 3] = problem.fused.positions
    targets[:, 3, 3] = 1.0
    return targets


def problem_kinematics(problem: RefinementNLP) -> TcpKinematics:
    """The numeric TCP kinematics of the refinement's robot, base and tool (stationary or not)."""
    return TcpKinematics(problem.robot, problem.base_in_world, problem.tcp_in_flange, problem.tool_in_world)


def problem_bounds(problem: RefinementNLP) -> tuple[Array, Array]:
    """The joint bounds (lower, upper) [rad] the refinement keeps (the limits less the joint margin)."""
    n = problem.dof
    return problem.lbx[:n], problem.ubx[:n]


class TimeLimitReached(Exception):
    """The refinement's wall-time budget ran out before a verdict (internal to this module)."""


def timed_out(
    problem: RefinementNLP,
    q_seed: Array,
    time_limit_s: float | None,
    timings: dict[str, float],
    where: str = "",
) -> Refinement:
    """The answer when the time budget ran out before any verdict: status ``timeout``, saying so.

    ``where``: where the time went, for the reason (after "before a verdict"); ``time_limit_s``
    None when only the solver's own wall-time limit (``ipopt.max_wall_time``) stopped it.
    """
    call_limit_s = note_timeout()  # a library call's own limit, for the message
    time_limit_s = call_limit_s if call_limit_s is not None else time_limit_s
    limit = (
        f"time limit of {time_limit_s:g} s ([repair] time_limit_s, or the call's time_limit_s)"
        if time_limit_s is not None
        else f"IPOPT's wall-time limit of {problem.solver_options.get('ipopt.max_wall_time')} s "
        "(ipopt.max_wall_time)"
    )
    reason = (
        f"{limit} reached before a verdict{', ' + where if where else ''}: neither an "
        "answer nor a proof of infeasibility was found; raise the limit to let the solver finish"
    )
    log.warning("refinement stopped: %s", reason)
    return replace(
        unsolved(problem, q_seed, reason, "time limit reached", timings, time_limit_reached=True),
        status="timeout",
    )


def unsolved(
    problem: RefinementNLP,
    q_seed: Array,
    reason: str,
    solver_status: str,
    timings: dict[str, float],
    findings: tuple[Finding, ...] = (),
    time_limit_reached: bool = False,
) -> Refinement:
    """An infeasible answer without a solve: the seed, checked, with the reason and diagnosis."""
    check = check_path(
        problem_kinematics(problem), q_seed, problem.fused, problem.tolerances, problem.axisymmetric
    )
    return Refinement(
        "infeasible",
        reason,
        q_seed,
        q_seed,
        check,
        solver_status,
        0,
        0,
        slack_deg=np.zeros(problem.n_waypoints),
        timings_s=timings,
        diagnosis=findings,
        time_limit_reached=time_limit_reached,
    )


def describe_check(check: PathCheck, stats: dict) -> str:
    """The solver's status and the first ten broken tolerances of a verification, for a reason text."""
    text = f"{stats.get('solver', 'IPOPT')}: {stats.get('return_status', 'unknown')}; " + "; ".join(
        v.describe() for v in check.violations[:10]
    )
    if len(check.violations) > 10:
        text += f"; and {len(check.violations) - 10} more segments"
    return text


def findings_of(
    problem: RefinementNLP,
    sources: tuple[ConstraintSource, ...],
    status: str,
    q: Array,
    mask: Array,
    slack: Array | None = None,
) -> tuple[Finding, ...]:
    """The diagnosis of every run of ``mask`` (waypoints that needed slack or break a tolerance)."""
    model = next((getattr(src, "model", None) for src in sources if hasattr(src, "model")), None)
    diagnoser = Diagnoser(
        problem_kinematics(problem), problem.fused, problem.tolerances, problem.axisymmetric, model
    )
    return tuple(
        diagnoser.segment(status, a, b, q, None if slack is None else float(np.max(slack[a : b + 1])))
        for a, b in segments(mask)
    )
