"""The chained IK seed that keeps the joint steps: a chain that turns the arm over is not solved as it is.

A chain that turns the arm over between two waypoints (a joint moving further than
:data:`TURN_OVER_STEPS` times ``tolerances.joint_step_deg`` in one step) starts every round far from
an answer. An axisymmetric tool's chain is made again with the spin about its axis free; else the
first waypoint's other IK branches are chained and ranked (:func:`rank_chains`).
"""

from __future__ import annotations

import logging
import math

import numpy as np

from refine.optimise.outcome import problem_bounds, problem_targets
from refine.optimise.problem import RefinementNLP
from refine.optimise.reach import reach_bound
from refine.optimise.seed import (
    REACH_TOLERANCE_M,
    alternative_seeds,
    chained_seed,
    ik_chain,
    initial_guess,
    seed_axis_only,
    start_candidates,
)
from refine.robot.kinematics import CONVERGED, TcpKinematics
from refine.types import Array

log = logging.getLogger(__name__)


STEP_TOLERANCE = 1e-6
"""A seed's joint step counts as beyond the step bound by more than this fraction of it."""

TURN_OVER_STEPS = 1.5
"""A chained seed whose largest joint step exceeds this many step bounds turned the arm over, and is
chained again (:func:`steady_branch`); a step just over the bound is the solve's to take in."""


def rank_chains(
    kin: TcpKinematics, targets: Array, lower: Array, upper: Array, chains: list[Array]
) -> list[Array]:
    """IK chains (N, n) best first: those on the targets (N, 4, 4) everywhere, then by joint margin.

    A chain reaches every target within :data:`REACH_TOLERANCE_M` (position [m] plus rotation
    [rad]) or it does not; among either kind, the larger the smallest distance to a joint limit
    along the whole path, the better. A branch judged by its first pose alone can run into a joint
    limit further on, and its repair then needs the orientation it cannot reach there.
    """
    return sorted(chains, key=lambda qs: chain_key(kin, targets, lower, upper, qs))


def chain_key(
    kin: TcpKinematics, targets: Array, lower: Array, upper: Array, qs: Array
) -> tuple[bool, float]:
    """Whether chain ``qs`` (N, n) misses a target (N, 4, 4), and its smallest joint margin [rad] negated."""
    poses = kin.poses(qs)
    position = np.linalg.norm(poses[:, :3, 3] - targets[:, :3, 3], axis=1)
    cos = (np.einsum("kij,kij->k", poses[:, :3, :3], targets[:, :3, :3]) - 1.0) / 2.0
    error = position + np.arccos(np.clip(cos, -1.0, 1.0))
    margin = float(np.min(np.minimum(qs - lower, upper - qs)))
    return bool(error.max() > REACH_TOLERANCE_M), -margin


def largest_step(qs: Array) -> tuple[float, int, int]:
    """The largest joint change between consecutive waypoints of ``qs`` (N, n) [rad], with k and j.

    The change is joint j's from waypoint k to k + 1; (0, 0, 0) for a single waypoint.
    """
    if len(qs) < 2:
        return 0.0, 0, 0
    steps = np.abs(np.diff(qs, axis=0))
    k, j = np.unravel_index(int(np.argmax(steps)), steps.shape)
    return float(steps[k, j]), int(k), int(j)


def steady_branch(
    problem: RefinementNLP,
    kin: TcpKinematics,
    q_seed: Array,
    home: Array | None,
    rotations: Array | None,
    count: int,
) -> Array:
    """``q_seed``, or another IK branch's chain when ``q_seed`` steps further than the step bound.

    A chain that turns the arm over between two waypoints (a joint moving more than
    :data:`TURN_OVER_STEPS` times ``tolerances.joint_step_deg`` in one step) starts every round far
    from an answer: the solve has to undo the turn against the step rows. Up to ``count`` chains from the first waypoint's
    other IK branches are ranked as the branches tried after an infeasible answer
    (:func:`rank_chains`); the first that reaches every target and keeps every step within the
    bound replaces the seed. None does: the seed stays, and the rounds decide.
    """
    bound = math.radians(problem.tolerances.joint_step_deg)
    step, k, j = largest_step(q_seed)
    if step <= bound * TURN_OVER_STEPS:
        return q_seed
    lower, upper = problem_bounds(problem)
    targets = problem_targets(problem)
    if rotations is not None:
        targets[:, :3, :3] = rotations
    starts = start_candidates(lower, upper, home)
    why = (
        f"IK seed: joint {j + 1} moves {math.degrees(step):.1f} deg from waypoint {k} to {k + 1} "
        f"(the joint step bound is {problem.tolerances.joint_step_deg:g} deg)"
    )
    if problem.axisymmetric and not seed_axis_only(problem):
        qs = spin_free_chain(problem, kin, home, rotations)
        if qs is not None:
            log.info(
                "%s: chained again with the spin about the tool axis free, whose largest step is %.1f deg, "
                "it is the seed",
                why,
                math.degrees(largest_step(qs)[0]),
            )
            return qs
    chains = alternative_seeds(kin, targets, lower, upper, starts, skip=q_seed, count=count)
    for m, qs in enumerate(rank_chains(kin, targets, lower, upper, chains), start=2):
        other = largest_step(qs)[0]
        if not chain_key(kin, targets, lower, upper, qs)[0] and other <= bound * (1.0 + STEP_TOLERANCE):
            log.info(
                "%s: the chain of IK branch %d, whose largest step is %.1f deg, is the seed",
                why,
                m,
                math.degrees(other),
            )
            return qs
    log.info("%s: none of %d other IK branches' chains keeps the steps; the seed stays", why, len(chains))
    return q_seed


def turn_over_step(problem: RefinementNLP) -> float | None:
    """The joint step [rad] at which the seed abandons a chain that turns the arm over, or None.

    Only a tool on the flange that is axisymmetric gives one up: its chain can be made again with
    the spin about the tool axis free (:func:`spin_free_chain`).
    """
    if not problem.axisymmetric or seed_axis_only(problem):
        return None
    return math.radians(problem.tolerances.joint_step_deg) * TURN_OVER_STEPS


def whole_chain(
    problem: RefinementNLP,
    kin: TcpKinematics,
    home: Array | None,
    rotations: Array | None,
    give_up: float | None,
) -> Array:
    """The chained IK seed along the whole path (N, n) [rad], each branch's chain abandoned at ``give_up``.

    A chain that turns the arm over (a joint step beyond ``give_up`` [rad], :func:`turn_over_step`)
    would be chained again with the spin free after it is finished (:func:`steady_branch`): when
    every branch's chain turns it over, that chain is made at once. Else, or when it does not keep
    the steps, the seed is the chain without ``give_up``. A target position out of reach at any
    orientation by more than :data:`REACH_TOLERANCE_M` (:func:`position_gap`, a lower bound) leaves
    the chain with the spin free an error above ``CONVERGED`` there, which :func:`spin_free_chain`
    turns down: it is not chained.
    """
    if give_up is None:
        return initial_guess(problem, home, rotations)
    qs, errors = chained_seed(problem, home, rotations, give_up=give_up)
    if np.isfinite(errors).all():
        return qs
    gap = position_gap(problem)
    if gap.max() > REACH_TOLERANCE_M:  # the chain with the spin free cannot reach every target
        log.info(
            "IK seed: every IK branch's chain turns the arm over, and waypoint %d is %.1f mm out of reach "
            "at any orientation: not chained with the spin about the tool axis free",
            int(np.argmax(gap)),
            1e3 * float(gap.max()),
        )
        return initial_guess(problem, home, rotations)
    free = spin_free_chain(problem, kin, home, rotations)
    if free is None:
        return initial_guess(problem, home, rotations)
    step, k, j = largest_step(qs)
    log.info(
        "IK seed: every IK branch's chain turns the arm over (the first's joint %d moves %.1f deg from "
        "waypoint %d to %d, beyond %.1f deg, %g times the joint step bound of %g deg): chained with the "
        "spin about the tool axis free, whose largest step is %.1f deg, it is the seed",
        j + 1,
        math.degrees(step),
        k,
        k + 1,
        math.degrees(give_up),
        TURN_OVER_STEPS,
        problem.tolerances.joint_step_deg,
        math.degrees(largest_step(free)[0]),
    )
    return free


def position_gap(problem: RefinementNLP) -> Array:
    """A lower bound [m] on how far each CAD point (N,) is from the TCP positions the joint bounds reach.

    The reach model's bound at any tool orientation (:func:`refine.optimise.reach.reach_bound`), for
    the joints inside the refinement's bounds; zeros where it proves nothing (a stationary tool, a
    robot without a spherical wrist).
    """
    if problem.tool_in_world is not None:
        return np.zeros(problem.n_waypoints)
    lower, upper = problem_bounds(problem)
    margin = math.radians(problem.tolerances.joint_margin_deg)
    return reach_bound(
        problem.robot,
        margin,
        problem.base_in_world,
        problem.tcp_in_flange,
        problem.fused.positions,
        lower,
        upper,
    )


def spin_free_chain(
    problem: RefinementNLP, kin: TcpKinematics, home: Array | None, rotations: Array | None
) -> Array | None:
    """The seed (N, n) [rad] chained with the spin about the tool axis free, or None.

    The demonstrated spin about an axisymmetric tool's axis (a CAM toolpath's is arbitrary) can
    drive the last joint into its limit and the chain over to another branch. None when that chain
    misses a pose or steps further than the joint step bound.
    """
    lower, upper = problem_bounds(problem)
    targets = problem_targets(problem)
    if rotations is not None:
        targets[:, :3, :3] = rotations
    starts = start_candidates(lower, upper, home)
    qs, errors = ik_chain(kin, targets, lower, upper, starts, prefer_first=home is not None, axis_only=True)
    bound = math.radians(problem.tolerances.joint_step_deg)
    if float(errors.max()) <= CONVERGED and largest_step(qs)[0] <= bound * (1.0 + STEP_TOLERANCE):
        return qs
    return None
