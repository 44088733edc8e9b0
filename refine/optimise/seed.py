"""Initial guess for the refinement: damped least-squares IK chained along the path.

Each waypoint's IK starts from the previous waypoint's solution, so the seed stays on one IK branch
and never wraps a joint. The first waypoint is solved from several start configurations (the
problem's home, the robot's mid-range, and seeded random ones); the start that converges with the
largest joint-limit margin wins. The seed asks for the full demonstrated pose; where that pose is
out of reach or past a limit the DLS step lands on the nearest reachable one, and the NLP takes it
from there.
"""

from __future__ import annotations

import functools
import logging
import math
from contextvars import ContextVar

import numpy as np

from refine.optimise.diagnosis import reach_gap
from refine.optimise.outcome import problem_bounds, problem_kinematics, problem_targets
from refine.optimise.problem import RefinementNLP
from refine.optimise.verify import (
    Violation,
    runs,
)
from refine.robot.kinematics import (
    CONVERGED,
    NULLSPACE_GAIN,
    TcpKinematics,
    axis_error,
    pose_error,
    solve_ik,
    solve_ik_batch,
)
from refine.types import Array

log = logging.getLogger(__name__)


COARSE_STEP_M = 0.02
COARSE_STEP_RAD = 0.05
"""Largest TCP travel [m] and turn [rad] between the waypoints chained one by one; the waypoints
between them start from the joints interpolated between their neighbours and are solved together."""


def _coarse(targets: Array, axis_only: bool = False) -> Array:
    """Indices of the waypoints to chain one by one: the first, the last, and enough between."""
    dp = np.linalg.norm(np.diff(targets[:, :3, 3], axis=0), axis=1)
    R = targets[:, :3, :3]
    cos = (np.einsum("kij,kij->k", R[1:], R[:-1]) - 1.0) / 2.0
    if axis_only:  # the turn of the tool axis alone
        cos = np.einsum("ki,ki->k", R[1:, :, 2], R[:-1, :, 2])
    dtheta = np.arccos(np.clip(cos, -1.0, 1.0))
    travel = np.concatenate([[0.0], np.cumsum(np.maximum(dp / COARSE_STEP_M, dtheta / COARSE_STEP_RAD))])
    # a new chained waypoint wherever the travel since the last one would exceed one step
    idx = [0]
    for k in range(1, len(targets)):
        if travel[k] - travel[idx[-1]] > 1.0:
            idx.append(k - 1 if k - 1 > idx[-1] else k)
    if idx[-1] != len(targets) - 1:
        idx.append(len(targets) - 1)
    return np.array(idx)


def _chain(
    kin: TcpKinematics, targets: Array, q_first: Array, lower: Array, upper: Array,
    axis_only: bool = False, at: Array | None = None, give_up: float | None = None,
) -> tuple[Array, Array]:  # fmt: skip
    """IK chained along ``targets`` from ``q_first``.

    Waypoints a coarse step apart (:data:`COARSE_STEP_M`, :data:`COARSE_STEP_RAD`) are chained one
    by one; those between are solved together (:func:`solve_ik_batch`) from the joints
    interpolated between their chained neighbours. A span whose waypoints do not all converge
    close to the interpolation, or a coarse chain that does not converge everywhere, is chained
    one waypoint at a time instead, so the answer stays on the branch a full chain would follow.
    ``axis_only``: the spin about the tool axis is free (:func:`refine.robot.kinematics.solve_ik`).
    ``at``: the waypoints (sorted indices) whose joints are wanted, None for all: the others
    between the chained ones are not solved, and those asked for are as the whole chain has them
    unless a span re-chained for a waypoint not asked for.
    ``give_up``: a joint step [rad] between two waypoints chained one by one beyond which the chain
    is abandoned (:func:`_chain_each`); the coarse chain's steps span several waypoints, and keep it.
    """
    coarse = _coarse(targets, axis_only)
    if len(coarse) >= 0.5 * len(targets):
        qs, errors = _chain_each(kin, targets, q_first, lower, upper, axis_only, give_up)
        return (qs, errors) if at is None else (qs[at], errors[at])
    qs_c, err_c = _chain_each(kin, targets[coarse], q_first, lower, upper, axis_only)
    if float(err_c.max()) > CONVERGED:
        qs, errors = _chain_each(kin, targets, q_first, lower, upper, axis_only, give_up)
        return (qs, errors) if at is None else (qs[at], errors[at])
    N = len(targets)
    qs, errors = np.empty((N, len(q_first))), np.zeros(N)
    qs[coarse], errors[coarse] = qs_c, err_c
    inner = np.setdiff1d(np.arange(N) if at is None else at, coarse)
    seg = np.searchsorted(coarse, inner) - 1  # inner waypoint -> its coarse span
    a, b = coarse[seg], coarse[seg + 1]
    t = ((inner - a) / (b - a))[:, None]
    guess = qs[a] + t * (qs[b] - qs[a])
    if inner.size:
        qs[inner], errors[inner] = solve_ik_batch(
            kin, targets[inner], guess, lower, upper, axis_only=axis_only
        )
    span = np.abs(qs_c[1:] - qs_c[:-1]).max(axis=1)  # per coarse span
    off = np.abs(qs[inner] - guess).max(axis=1)
    bad = (errors[inner] > CONVERGED) | (off > np.maximum(span[seg], 0.05))
    for j in np.unique(seg[bad]):
        lo, hi = coarse[j], coarse[j + 1]
        qs[lo : hi + 1], errors[lo : hi + 1] = _chain_each(
            kin, targets[lo : hi + 1], qs[lo], lower, upper, axis_only, give_up
        )
    return (qs, errors) if at is None else (qs[at], errors[at])


_CHAINS: ContextVar[dict | None] = ContextVar("chains", default=None)
"""The chains already solved inside :func:`remembering_chains`, by their inputs; None outside it."""


def remembering_chains(solve):
    """Decorate ``solve`` so that a chain asked for again inside it is solved once.

    A refinement's seed can chain the same branch more than once (at the coarse waypoints, then
    along the whole path, then as a branch tried after an infeasible answer); a chain is a pure
    function of its kinematics, targets, first joints and bounds, so the repeat is the first's
    answer, to the bit.
    """

    @functools.wraps(solve)
    def remembering(*args, **kwargs):
        token = _CHAINS.set({} if _CHAINS.get() is None else _CHAINS.get())
        try:
            return solve(*args, **kwargs)
        finally:
            _CHAINS.reset(token)

    return remembering


def _chain_each(
    kin: TcpKinematics, targets: Array, q_first: Array, lower: Array, upper: Array, axis_only: bool = False,
    give_up: float | None = None,
) -> tuple[Array, Array]:  # fmt: skip
    """IK chained one waypoint at a time along ``targets`` from ``q_first`` (remembered, see above).

    ``give_up``: when a joint moves further than this [rad] from one waypoint to the next, the
    chain stops there; the waypoints after it keep the last joints and an infinite error. Until
    then it is the chain without ``give_up``, which one that is not abandoned is.
    """
    memo = _CHAINS.get()
    if memo is None:
        return _solve_chain(kin, targets, q_first, lower, upper, axis_only, give_up)
    arrays = (kin.base_in_world, kin.tcp_in_flange, kin.tool_in_world, targets, q_first, lower, upper)
    key = (id(kin.robot), axis_only) + tuple(
        None if a is None else np.asarray(a, float).tobytes() for a in arrays
    )
    found = memo.get(key)  # the whole chain answers any step to give up at
    if found is None or found[0] is not kin.robot:  # the robot kept with it: its id is not reused
        found = memo.get(key + (give_up,))
    if found is None or found[0] is not kin.robot:
        found = (kin.robot, *_solve_chain(kin, targets, q_first, lower, upper, axis_only, give_up))
        memo[key if np.isfinite(found[2]).all() else key + (give_up,)] = found
    qs, errors = found[1].copy(), found[2].copy()
    if give_up is not None and np.isfinite(errors).all():
        far = np.flatnonzero(np.abs(np.diff(qs, axis=0)).max(axis=1) > give_up) if len(qs) > 1 else []
        if len(far):
            qs[far[0] + 2 :], errors[far[0] + 1 :] = qs[far[0] + 1], np.inf
    return qs, errors


def _solve_chain(
    kin: TcpKinematics, targets: Array, q_first: Array, lower: Array, upper: Array, axis_only: bool = False,
    give_up: float | None = None,
) -> tuple[Array, Array]:  # fmt: skip
    chain = kin.robot.chain
    if len(targets) and chain is not None and chain.compiled:
        return _solve_chain_compiled(kin, targets, q_first, lower, upper, give_up, axis_only)
    qs = np.empty((len(targets), len(q_first)))
    errors = np.empty(len(targets))
    q = q_first
    for k, T in enumerate(targets):
        guess = q
        if k >= 2:  # predict from the last step where it is small (not near a singularity)
            last = q - qs[k - 2]
            if float(np.abs(last).max()) <= PREDICT_STEP_MAX:
                guess = q + last
        q, errors[k] = solve_ik(kin, T, guess, lower, upper, axis_only=axis_only)
        qs[k] = q
        if give_up is not None and k and float(np.abs(q - qs[k - 1]).max()) > give_up:
            qs[k + 1 :], errors[k:] = q, np.inf
            break
    return qs, errors


def _solve_chain_compiled(
    kin: TcpKinematics, targets: Array, q_first: Array, lower: Array, upper: Array, give_up: float | None,
    axis_only: bool = False,
) -> tuple[Array, Array]:  # fmt: skip
    """:func:`_solve_chain` with the chain's IK in C, the same answers to rounding.

    :meth:`CompiledChain.ik_solve <refine.robot.compiled_chain.CompiledChain.ik_solve>`, chained:
    :func:`solve_ik`'s iterations from the same starts, the whole pose or the tool axis alone. A
    waypoint whose rotation error (the angle between the axes) comes within 1e-3 rad of a half
    turn is solved by :func:`solve_ik` (NumPy's ``log3`` or :func:`axis_error`'s turn over) and
    the chain goes on after it in C.
    """
    n, nq = len(targets), len(q_first)
    qs, errors = np.empty((n, nq)), np.empty(n)
    placements = (kin.base_in_world, kin.tcp_in_flange, kin.tool_in_world)
    gain = NULLSPACE_GAIN if nq > 6 else 0.0
    stop = np.inf if give_up is None else give_up
    first = 0
    while first < n:
        flag = kin.robot.chain.ik_solve(
            np.reshape(q_first, (1, nq)), placements, targets, (lower, upper), 1e-3, CONVERGED, gain, 100,
            None, (PREDICT_STEP_MAX, stop, qs, errors, first), axis_only,
        )[4]  # fmt: skip
        if not (flag == 1).any():
            break
        k = int(np.argmax(flag == 1))
        guess = q_first if k == 0 else qs[k - 1]
        if k >= 2 and float(np.abs(qs[k - 1] - qs[k - 2]).max()) <= PREDICT_STEP_MAX:
            guess = qs[k - 1] + (qs[k - 1] - qs[k - 2])
        qs[k], errors[k] = solve_ik(kin, targets[k], guess, lower, upper, axis_only=axis_only)
        first = k + 1
    if give_up is not None and n > 1:  # the first step beyond it: the chain stops there
        far = np.flatnonzero(np.abs(np.diff(qs, axis=0)).max(axis=1) > give_up)
        if far.size:
            qs[far[0] + 2 :], errors[far[0] + 1 :] = qs[far[0] + 1], np.inf
    return qs, errors


PREDICT_STEP_MAX = 0.1
"""The chain starts each waypoint's IK from the last answer plus the last step (a linear
prediction, which saves about a fifth of the IK iterations) when no joint moved more than this in
that step [rad]; otherwise, as near a singularity where the wrist turns fast, from the last answer."""


def shift_turns(qs: Array, lower: Array, upper: Array) -> Array:
    """Shift every joint whose range spans more than a full turn by whole turns to fit its limits.

    A revolute joint at q and at q ± 2π puts the robot in the same pose, so for joints like ABB's
    axes 4 and 6 (±400°) the chain's excursion can be moved as a whole. The shift chosen centres
    the excursion in the limits as well as whole turns allow.
    """
    qs = np.array(qs, dtype=float)
    for j in np.flatnonzero(upper - lower > 2 * np.pi):
        lo, hi = qs[:, j].min(), qs[:, j].max()
        centre = 0.5 * (lower[j] + upper[j]) - 0.5 * (lo + hi)
        qs[:, j] += 2 * np.pi * np.round(centre / (2 * np.pi))
    return qs


def ik_chain(
    kin: TcpKinematics,
    targets: Array,
    lower: Array,
    upper: Array,
    starts: list[Array],
    *,
    max_chains: int = 4,
    prefer_first: bool = False,
    axis_only: bool = False,
    at: Array | None = None,
    give_up: float | None = None,
) -> tuple[Array, Array]:
    """IK chained along ``targets`` (N, 4, 4), trying the distinct first-waypoint solutions of ``starts``.

    Joints whose range spans more than a full turn are chained without their limits and then shifted
    by whole turns (:func:`shift_turns`); a chain that still leaves the limits is chained again with
    them. Up to ``max_chains`` distinct IK branches of the first waypoint are chained; the first chain
    that converges everywhere inside the limits wins, otherwise the one with the smallest error.

    Args:
        kin: TCP kinematics.
        targets: T_F_TCP per waypoint, shape (N, 4, 4).
        lower: lower joint bounds [rad] (n,) (already shrunk by the joint margin).
        upper: upper joint bounds [rad] (n,) (already shrunk by the joint margin).
        starts: candidate start configurations for the first waypoint [rad].
        max_chains: how many distinct first-waypoint solutions to chain at most.
        prefer_first: chain the first start's branch first (the problem's home), whatever its
            joint margin; otherwise branches are tried by decreasing joint margin.
        axis_only: reach the targets' positions and tool axes, the spin about the axis free.
        at: sorted waypoint indices, the first 0, whose joints alone are wanted (None: all); the
            chain solves only its chained waypoints and these (:func:`_chain`), and judges the
            branches by them.
        give_up: a joint step [rad] from one waypoint to the next at which a chain is abandoned
            (:func:`_chain_each`): its errors from there on are infinite, so a branch that keeps
            its steps wins; when every branch is abandoned, the first is returned so.

    With ``prefer_first`` the first start's branch is chained before the other starts are solved
    (:func:`first_solutions` costs about as much as a chain of 6,400 waypoints when some start does
    not converge); their branches follow only if that chain does not converge everywhere.

    Returns:
        joints (N, n) [rad] and the pose error norm per waypoint (N,), or at ``at`` only.
    """
    best: tuple[float, Array, Array] | None = None
    if prefer_first:  # the home's branch first: the other starts are solved only if its chain fails
        home = first_solutions(
            kin, targets[0], lower, upper, starts[:1], prefer_first=True, axis_only=axis_only
        )
        for qs, errors in _chains(kin, targets, lower, upper, home, axis_only, at, give_up):
            best = (float(errors.max()), qs, errors)
            if best[0] <= CONVERGED:
                return qs, errors
    firsts = first_solutions(
        kin, targets[0], lower, upper, starts, prefer_first=prefer_first, axis_only=axis_only
    )
    if not firsts:  # nothing converged: chain from the closest attempt and let the NLP decide
        firsts = [
            solve_ik(kin, targets[0], starts[0], lower, upper, max_iterations=300, axis_only=axis_only)[0]
        ]
    elif best is not None:  # the home's branch is chained already (first_solutions puts it first)
        firsts = firsts[1:max_chains]
    for qs, errors in _chains(kin, targets, lower, upper, firsts[:max_chains], axis_only, at, give_up):
        score = float(errors.max())
        if best is None or score < best[0]:
            best = (score, qs, errors)
        if score <= CONVERGED:
            break
    assert best is not None
    log.debug("IK seed: max pose error %.3g over %d waypoints", best[0], len(targets))
    return best[1], best[2]


def first_solutions(
    kin: TcpKinematics,
    T_first: Array,
    lower: Array,
    upper: Array,
    starts: list[Array],
    *,
    prefer_first: bool = False,
    axis_only: bool = False,
) -> list[Array]:
    """The distinct IK solutions of the first pose from ``starts``, multi-turn joints unbounded.

    The home start's solution comes first when ``prefer_first``, the others by decreasing joint margin.
    """
    wraps = upper - lower > 2 * np.pi
    free_lower, free_upper = np.where(wraps, -np.inf, lower), np.where(wraps, np.inf, upper)
    found: list[tuple[float, Array]] = []
    solutions, errors = solve_ik_batch(
        kin,
        np.repeat(np.asarray(T_first)[None], len(starts), axis=0),
        np.array(starts),
        free_lower,
        free_upper,
        max_iterations=300,
        axis_only=axis_only,
    )
    for i, (q, err) in enumerate(zip(solutions, errors, strict=True)):
        if err > CONVERGED:
            continue
        key = np.where(wraps, np.mod(q, 2 * np.pi), q)
        if any(np.allclose(key, np.where(wraps, np.mod(f, 2 * np.pi), f), atol=1e-3) for _, f in found):
            continue
        margin = float(np.min(np.minimum(q - free_lower, free_upper - q)))
        found.append((-np.inf if prefer_first and i == 0 else -margin, q))
    found.sort(key=lambda item: item[0])
    return [q for _, q in found]


def _chains(
    kin: TcpKinematics,
    targets: Array,
    lower: Array,
    upper: Array,
    firsts: list[Array],
    axis_only: bool = False,
    at: Array | None = None,
    give_up: float | None = None,
):
    """Chain IK from each first-waypoint solution in turn (a generator: chains cost time).

    ``at``: the waypoints whose joints are wanted (:func:`ik_chain`); None for all. ``give_up``: the
    joint step [rad] that abandons a chain (:func:`_chain_each`); an abandoned chain is yielded as it is.
    """
    wraps = upper - lower > 2 * np.pi
    free_lower, free_upper = np.where(wraps, -np.inf, lower), np.where(wraps, np.inf, upper)
    for q_first in firsts:
        qs, errors = _chain(kin, targets, q_first, free_lower, free_upper, axis_only, at, give_up)
        qs = shift_turns(qs, lower, upper)
        if np.isinf(errors).any():  # abandoned
            yield qs, errors
            continue
        outside = np.any(qs < lower - 1e-9, axis=0) | np.any(qs > upper + 1e-9, axis=0)
        if np.any(outside & ~wraps):
            qs, errors = _chain(
                kin, targets, np.clip(qs[0], lower, upper), lower, upper, axis_only, at, give_up
            )
        elif np.any(outside):
            # a multi-turn joint whose excursion exceeds its range: no whole-turn shift fits it, so
            # centre it exactly (turning the tool by the shift) and clip both ends; the strict
            # problem is infeasible and its repair takes the excess out of the orientation at both ends
            for j in np.flatnonzero(outside):
                qs[:, j] += 0.5 * (lower[j] + upper[j]) - 0.5 * (qs[:, j].max() + qs[:, j].min())
            qs = np.clip(qs, lower, upper)
            reached, wanted = kin.poses(qs), targets if at is None else targets[at]
            if axis_only:  # the poses' errors only (the Jacobians passed are placeholders)
                errors = np.linalg.norm(
                    axis_error(reached, wanted, np.zeros((len(qs), 6, qs.shape[1]))), axis=1
                )
            else:
                errors = np.array(
                    [np.linalg.norm(pose_error(P, T)) for P, T in zip(reached, wanted, strict=True)]
                )
        yield qs, errors


def alternative_seeds(
    kin: TcpKinematics,
    targets: Array,
    lower: Array,
    upper: Array,
    starts: list[Array],
    *,
    skip: Array,
    count: int = 2,
    axis_only: bool = False,
) -> list[Array]:
    """Up to ``count`` seeds chained from other IK branches of the first waypoint than ``skip``'s."""
    wraps = upper - lower > 2 * np.pi
    key = np.where(wraps, np.mod(skip[0], 2 * np.pi), skip[0])
    others = [
        q
        for q in first_solutions(kin, targets[0], lower, upper, starts, axis_only=axis_only)
        if not np.allclose(np.where(wraps, np.mod(q, 2 * np.pi), q), key, atol=1e-2)
    ]
    return [qs for qs, _ in _chains(kin, targets, lower, upper, others[:count], axis_only)]


def start_candidates(
    lower: Array, upper: Array, home: Array | None, n_random: int = 6, seed: int = 0
) -> list[Array]:
    """Start configurations for the first waypoint: home, mid-range, and seeded random ones [rad]."""
    rng = np.random.default_rng(seed)
    mid = 0.5 * (lower + upper)
    span = np.minimum(upper - lower, 2 * np.pi)
    cands = [] if home is None else [np.asarray(home, dtype=float)]
    cands.append(mid)
    cands += [mid + (rng.random(len(mid)) - 0.5) * span for _ in range(n_random)]
    return cands


def reach_shortfall(
    kin: TcpKinematics, targets: Array, lower: Array, upper: Array, starts: list[Array]
) -> Array:
    """How far each target position stays out of reach [m], shape (N,): 0 for reachable ones.

    Position-only DLS IK from every start for the first target, then from the previous target's
    answer and the first two starts; the best distance found. A shortfall well above the IK
    tolerance means the point is out of the robot's reach inside its joint limits.
    """
    out = np.empty(len(targets))
    previous: list[Array] = []
    for k, T in enumerate(targets):
        best = (np.inf, starts[0])
        for q0 in previous + starts[: 2 if previous else None]:
            q, err = solve_ik(kin, T, q0, lower, upper, max_iterations=200, position_only=True)
            if err < best[0]:
                best = (err, q)
        out[k], previous = best[0], [best[1]]
    return np.where(out < 1e-6, 0.0, out)


REACH_TOLERANCE_M = 1e-3
"""A CAD point the best position-only IK misses by more than this is reported out of reach [m]."""


def initial_guess(problem: RefinementNLP, home: Array | None = None, rotations: Array | None = None) -> Array:
    """IK seed (N, n) [rad] chained along the path, from the best of several first-waypoint starts.

    ``rotations`` (N, 3, 3) replaces the demonstrated tool orientations as IK targets (e.g. tilted
    into reach, :func:`refine.optimise.diagnosis.reach_tilts`).
    """
    return chained_seed(problem, home, rotations)[0]


def chained_seed(
    problem: RefinementNLP,
    home: Array | None = None,
    rotations: Array | None = None,
    at: Array | None = None,
    give_up: float | None = None,
) -> tuple[Array, Array]:
    """:func:`initial_guess`'s joints [rad] and pose error per waypoint, or at the waypoints ``at`` only.

    ``at``: sorted waypoint indices, the first 0 (:func:`ik_chain`): the chain then solves only
    its chained waypoints and these, which costs a fraction of the whole chain on a long path.
    ``give_up``: the joint step [rad] at which a branch's chain is abandoned (:func:`ik_chain`).
    """
    lower, upper = problem_bounds(problem)
    starts = start_candidates(lower, upper, home)
    targets = problem_targets(problem)
    if rotations is not None:
        targets[:, :3, :3] = rotations
    axis_only = seed_axis_only(problem)
    if axis_only:  # turn each target about the tool axis to keep the elbow in range, then reach it
        from refine.optimise.reach import reach_model
        from refine.optimise.spin import path_spins, spun

        reach = reach_model(problem.robot, math.radians(problem.tolerances.joint_margin_deg))
        if reach.spherical:
            spins = path_spins(
                reach, targets, problem.base_in_world, problem.tcp_in_flange, problem.tool_in_world
            )
            targets, axis_only = spun(targets, spins), False
    return ik_chain(
        problem_kinematics(problem),
        targets,
        lower,
        upper,
        starts,
        prefer_first=home is not None,
        axis_only=axis_only,
        at=at,
        give_up=give_up,
    )


def seed_axis_only(problem: RefinementNLP) -> bool:
    """Whether the IK seed leaves the spin about the tool axis free: an axisymmetric stationary tool.

    A CAM toolpath gives the tool axis with an arbitrary spin about it (the puzzle piece's turns by
    up to 49 deg from one point to the next), which a robot holding the part would have to follow.
    """
    return problem.axisymmetric and problem.tool_in_world is not None


def out_of_reach(
    problem: RefinementNLP, q_seed: Array, home: Array | None, poses: Array | None = None
) -> list[Violation]:
    """Runs of waypoints whose CAD point no configuration inside the limits reaches.

    ``poses``: the TCP poses T_F_TCP (N, 4, 4) at ``q_seed`` when the caller has them, or None.
    """
    kin = problem_kinematics(problem)
    reached = kin.poses(q_seed) if poses is None else poses
    missed = np.linalg.norm(reached[:, :3, 3] - problem.fused.positions, axis=1) > REACH_TOLERANCE_M
    if not missed.any():
        return []
    lower, upper = problem_bounds(problem)
    shortfall = np.zeros(problem.n_waypoints)
    # points the wrist centre cannot bring into the arm's range at any orientation are out of reach
    # for certain (refine.optimise.reach.ReachModel); IK measures the rest
    certain = reach_gap(kin, problem.fused.positions, problem.tolerances.joint_margin_deg)
    sure = missed & (certain > REACH_TOLERANCE_M)  # a lower bound: the wrist joints' limits ignored
    shortfall[sure] = certain[sure]
    idx = np.flatnonzero(missed & ~sure)
    if idx.size:
        starts = start_candidates(lower, upper, home)
        shortfall[idx] = reach_shortfall(kin, problem_targets(problem)[idx], lower, upper, starts)
    s = problem.fused.s
    return [
        Violation(
            a,
            b,
            float(s[a]),
            float(s[b]),
            "out of reach",
            float(shortfall[a : b + 1].max()),
            "m",
            REACH_TOLERANCE_M,
        )
        for a, b in runs(shortfall > REACH_TOLERANCE_M)
    ]
