"""Solving again from a previous answer: its joints moved onto the new poses, its built problem kept.

A re-solve after a small change (the part moved a few millimetres, another cone, another tool
offset) starts from what the previous solve ended with (:class:`WarmStart`):

* the seed is the previous joints projected onto the new poses (:func:`warm_seed`): each waypoint's
  least-squares IK from its previous joints, without null-space drift, towards the new position with
  the previous orientation turned as the demonstration turned. No chained IK, no start candidates,
  and no reach search (the projection reaches every pose the previous answer nearly reached);
* the problem is the previous solve's last one, with its active set (singularity bounds, clearance
  rows) and joint-step rows, given the new path and tolerances as parameters and bounds
  (:func:`reuse_final`): no CasADi build. For another tool or base the new problem takes over
  that active set and those rows (:func:`rebuilt_like`);
* the solve starts from the previous multipliers (row by row, see
  :class:`refine.optimise.rounds.RoundLoop`): first as a Newton correction of the previous
  answer's KKT system with its active set (:mod:`refine.optimise.correction`), accepted only when
  it is an answer of the whole problem, else by IPOPT;
* the dense clearance checks start from the previous check's distance bounds less the motion since
  (:mod:`refine.collision.carry`), so only the pairs the motion brought near are measured again.

The answer then runs through the rounds and the verification of any other solve, so it is checked
(and grown, where a row is missing) exactly as a cold one.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from refine.optimise.outcome import problem_bounds, problem_kinematics, problem_targets
from refine.optimise.problem import RefinementNLP, joint_bounds, path_params, path_row_bounds, reuse_for
from refine.paths import FusedPath
from refine.robot.kinematics import CONVERGED, solve_ik_batch
from refine.settings import Tolerances
from refine.types import Array

WARM_SEED_TOLERANCE = 1e-4
"""The warm seed's projection stops at this pose error [m and rad stacked]. The seed only starts the
solve, which corrects it to the answer and from this close takes as many steps: on the glass cell
with the part moved 2 mm, one Gauss-Newton step from the previous joints leaves 1.5e-5 (where the
seed projected to 1e-6 is 2.6e-5 rad from the answer), and the Newton correction still converges in
two steps to the same answer (to 4e-15 rad). The projection's second pass of the kinematics over
the path is saved."""


@dataclass(frozen=True)
class WarmStart:
    """What a re-solve keeps of the previous answer.

    Attributes:
        q: the previous answer's joints (N, n) [rad].
        rotations: the demonstrated orientations R_F_TCP (N, 3, 3) the previous answer was refined
            for; None when unknown (the seed then keeps the previous reached orientations).
        problem: the previous solve's last problem (its active set and joint-step rows), or None.
        multipliers: the previous last solve's multipliers, as kept by
            :class:`refine.optimise.rounds.RoundLoop` (by row, and of the variable bounds), or None.
        clearance: the previous answer's dense clearance check (a ``PathClearance``), whose bounds
            the new checks start from (:mod:`refine.collision.carry`), or None.
        reusable: whether ``problem``'s solver is the new problem's too (the same robot, base, tool
            and weights: :func:`reuse_final`); otherwise only its active set and joint-step rows
            are taken over, into the new problem (:func:`rebuilt_like`).
        line: the previous answer's controller line check (a ``LineCheck`` of ``q``), whose bows
            start the new line's IK (:func:`refine.optimise.line_start.previous_bows`), or None.
        motions: the previous run's motions (``refine.plan.motion.Motion``), which the program's
            motions are planned again from (:func:`refine.plan.program.plan_program`), or ().
    """

    q: Array
    rotations: Array | None = None
    problem: RefinementNLP | None = None
    multipliers: tuple[dict[tuple, float], Array] | None = None
    clearance: object = None
    reusable: bool = True
    line: object = None
    motions: tuple[object, ...] = ()


def warm_seed(
    problem: RefinementNLP,
    warm: WarmStart,
    jacobians_out: Array | None = None,
    poses_out: Array | None = None,
) -> Array:
    """The previous joints moved onto ``problem``'s poses (N, n) [rad].

    Each waypoint's target is the new CAD position with the previous reached orientation turned by
    the change of the demonstrated orientation there (``R_demo_new R_demo_oldᵀ R_reached``): a
    rigidly moved part moves the previous answer's poses rigidly, a new cone or weight leaves them
    where they were. Least-squares IK (:func:`refine.robot.kinematics.solve_ik_batch`, no
    null-space drift, to :data:`WARM_SEED_TOLERANCE`) from the previous joints moves each waypoint
    the least. A waypoint whose projection does not converge keeps what the IK reached (the NLP
    takes it from there).
    ``jacobians_out``, ``poses_out``: arrays (N, 6, n) and (N, 4, 4) to receive the TCP Jacobian
    and pose T_F_TCP at each returned row, or None. One evaluation at the previous joints serves
    the test of which waypoints moved, the returned rows that did not, and the projection's first
    iteration; the rows it moves get its own last evaluation.
    """
    q0 = np.asarray(warm.q, dtype=float)
    kin = problem_kinematics(problem)
    lower, upper = problem_bounds(problem)
    q0 = np.clip(q0, lower, upper)
    reached, J0 = kin.poses_jacobians(q0)
    targets = problem_targets(problem)
    R = reached[:, :3, :3]
    if warm.rotations is not None:
        R = problem.fused.rotations @ np.transpose(warm.rotations, (0, 2, 1)) @ R
    targets[:, :3, :3] = R
    position = np.linalg.norm(reached[:, :3, 3] - targets[:, :3, 3], axis=1)
    cos = (np.einsum("kij,kij->k", reached[:, :3, :3], R) - 1.0) / 2.0
    turn = np.arccos(np.clip(cos, -1.0, 1.0))
    off = position + turn > CONVERGED
    if jacobians_out is not None:
        jacobians_out[~off] = J0[~off]
    if poses_out is not None:
        poses_out[~off] = reached[~off]
    if not off.any():
        return q0
    every = bool(off.all())  # a moved part, tool or base moves every waypoint: no copies in and out
    rows = slice(None) if every else off
    moved, moved_poses = jacobians_out, poses_out
    if not every:
        moved = None if jacobians_out is None else np.empty((int(off.sum()),) + J0.shape[1:])
        moved_poses = None if poses_out is None else np.empty((int(off.sum()), 4, 4))
    q = q0.copy()
    q[rows], _ = solve_ik_batch(
        kin,
        targets[rows],
        q0[rows],
        lower,
        upper,
        tol=WARM_SEED_TOLERANCE,
        nullspace_gain=0.0,
        jacobians_out=moved,
        poses_out=moved_poses,
        start=(reached[rows, :3, 3], reached[rows, :3, :3], J0[rows]),
    )
    if moved is not None and not every:
        jacobians_out[off] = moved
    if moved_poses is not None and not every:
        poses_out[off] = moved_poses
    return q


def reuse_final(
    final: RefinementNLP, built: RefinementNLP, fused: FusedPath, tolerances: Tolerances
) -> RefinementNLP | None:
    """The previous solve's last problem ``final`` with a new path and tolerances, or None.

    ``final`` holds the active set and joint-step rows the previous rounds found; its solver is
    kept, and only the parameters and bounds change: the path rows and joint steps from
    ``tolerances`` (:func:`refine.optimise.problem.path_row_bounds`), the singularity rows at the
    new margin, the linear rows at their bounds (rows whose bound depends on where the cell is are
    the constraint source's to refresh: their next round replaces them). ``built`` is the problem
    as first built (``reuse_for`` checks that the robot, tool and spacing allow a reuse); None when
    it refuses, when ``final`` is an elastic problem, or when its size differs.
    """
    if not _reusable(built, fused, tolerances):
        return None
    N = final.n_waypoints
    if final.elastic_deg is not None or len(fused) != N or final.robot is not built.robot:
        return None
    lower, upper = joint_bounds(final.robot, tolerances)
    lbg_path, ubg_path = path_row_bounds(tolerances, N, final.dof, steps=final.step_rows())
    a = final.active
    singular = len(a.singular_waypoints) + len(a.singular_segments)
    rows = len(a.linear_rows)
    head = len(lbg_path)
    if len(final.lbg) != head + singular + rows:
        return None
    lbg = np.concatenate(
        [lbg_path, np.full(singular, tolerances.singularity_margin), final.lbg[head + singular :]]
    )
    ubg = np.concatenate([ubg_path, final.ubg[head:]])
    return replace(
        final,
        params=path_params(fused),
        lbx=np.tile(lower, N),
        ubx=np.tile(upper, N),
        lbg=lbg,
        ubg=ubg,
        fused=fused,
        tolerances=tolerances,
        build_time_s=0.0,
    )


def _reusable(built: RefinementNLP, fused: FusedPath, tolerances: Tolerances) -> bool:
    """Whether ``reuse_for(built, fused, tolerances)`` gives a problem, without making it.

    That function refuses the elastic problem, an active set, another number of waypoints and a
    mean spacing off the built one's; the tolerances only set the bounds it makes. A problem
    already holding this very path (as ``reuse_for`` made it) has its own spacing (ratio exactly
    1 where its mean spacing is positive), so the first three tests decide. Any other problem is
    asked through ``reuse_for`` itself.
    """
    a = built.active
    if (
        built.fused is fused
        and built.elastic_deg is None
        and not (a.singular_waypoints or a.singular_segments or a.linear_rows)
        and len(fused) == built.n_waypoints > 1
        and float(np.mean(np.diff(fused.s))) > 0.0
    ):
        return True
    return reuse_for(built, fused, tolerances) is not None


def rebuilt_like(final: RefinementNLP, built: RefinementNLP) -> RefinementNLP | None:
    """``built`` (the problem of another tool or base) with the rows of the previous last problem ``final``.

    The previous active set (singularity bounds, linear rows) and joint-step rows, so that the
    previous multipliers name the same rows (:class:`refine.optimise.rounds.RoundLoop`): ``built``
    itself where its rows are already those, else ``built`` rebuilt with them (the linear rows'
    bounds are then refreshed like a kept problem's). None when either is elastic, or the robot or
    the number of waypoints differ.
    """
    from refine.optimise.correction import row_layout

    if final.elastic_deg is not None or built.elastic_deg is not None:
        return None
    if final.robot is not built.robot or final.n_waypoints != built.n_waypoints:
        return None
    if row_layout(final) == row_layout(built):
        return built
    return built.rebuilt(active=final.active, joint_steps=final.joint_steps)


def built_for(built: RefinementNLP | None, base_in_world: Array, tool: object, weights: object) -> bool:
    """Whether ``built`` was made for this base, tool (``ToolSettings``) and cost weights, so it can be reused.

    The base, the flange-side frame (``tcp_in_flange``), a stationary tool's frame in the world
    (``tcp_in_world``, or none on either side), the tool's symmetry and the weights must all be
    the same; :func:`refine.optimise.problem.reuse_for` checks the rest.
    """
    if built is None:
        return False
    fixed = getattr(tool, "tcp_in_world", None)
    same_fixed = (built.tool_in_world is None and fixed is None) or (
        built.tool_in_world is not None and fixed is not None and np.array_equal(built.tool_in_world, fixed)
    )
    return bool(
        same_fixed
        and np.array_equal(built.base_in_world, base_in_world)
        and np.array_equal(built.tcp_in_flange, tool.tcp_in_flange)
        and built.axisymmetric == tool.axisymmetric
        and built.weights == weights
    )
