"""A redundant arm's coarse copies of the path: their waypoints, their problems, the seed from their answers.

A redundant arm's seed comes from the refinement of a coarse copy of the path
(:func:`refine.optimise.solve.coarse_seed`): the same problem over evenly spaced waypoints
(:func:`coarse_waypoints`, posed by :func:`coarse_copy`), whose answer, interpolated along the arc
length and projected onto the poses of a finer path (:func:`projected`), starts the finer solve next
to its answer. A held part on a long path climbs a ladder of two such copies
(:func:`ladder_waypoints`): the first copy's answer seeds a finer copy, whose answer seeds the full
solve. The solves themselves are :mod:`refine.optimise.solve`'s.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from refine.optimise.outcome import problem_bounds, problem_kinematics, problem_targets
from refine.optimise.problem import ActiveSet, RefinementNLP
from refine.optimise.seed import seed_axis_only
from refine.paths import FusedPath
from refine.robot.kinematics import CONVERGED, solve_ik_batch
from refine.types import Array

COARSE_SEED_MIN_PATH = 40
"""A redundant arm's seed on a path of at least this many waypoints comes from a coarse refinement
(:func:`refine.optimise.solve.coarse_seed`). Shorter paths keep the chained seed: there the coarse
copy holds half the waypoints or more and saves little or nothing (generated iiwa wave without
mid-range cost, CPU of the solve [s], chained / coarse seed: 30 waypoints 0.141 / 0.104, 36: 0.129 /
0.128, 40: 0.136 / 0.105; with the pipeline's mid-range cost 30: 0.047 / 0.050)."""


COARSE_SEED_WAYPOINTS = 16
"""The coarse refinement holds every :data:`COARSE_SEED_STRIDE`-th waypoint, and at least this many.
Without a mid-range cost its solve needs about as many iterations as the full one from the chained
seed (120-220 on the LBR iiwa, whatever the length), so the fewer waypoints it has the cheaper the
seed, down to where it misses the path's shape and the full solve's iterations grow again: 6-10
coarse waypoints leave the full solve 6 to 155 iterations, and on the bends of the TIG seam (237
waypoints, mid-range cost) 12 leave it 11 where 16-40 leave 5 (CPU 0.095 s against 0.077-0.080
s). On the wave without mid-range cost, chained / 40 / 16 coarse waypoints: 100 waypoints 0.257 /
- / 0.124 s, 120: - / 0.175 / 0.121 s, 400: - / 0.198 / 0.163 s. A path whose fine shape sets the
elbow is seeded far from its answer: on Tesseract's puzzle piece (443 waypoints, a held part) the
16-waypoint answer's joints 1, 3, 5 and 7 lie up to 1.45 rad from the full answer's (the coarse copy's
objective is 2.45 at its own answer, 3.76 at the full answer's joints), and the full solve takes 132
iterations to move them; 32, 48 or 64 coarse waypoints lead it to other local optima (full objective
7.64, 8.00, 7.64 against 7.59). Nor does a coarse-copy term for the fine path's joint motion about
each chord help there: the least-norm joint steps of the demonstrated pose steps' deviations,
``trace((J Jᵀ)⁻¹ S)`` per coarse waypoint, predict 4.14 and 3.60 [deg²] at the two optima where the
full answers spend 2.77 and 2.84 (the cone absorbs most of the demonstrated axis's wiggles; the
position wiggles are worth 2e-4), so it ranks them wrongly and leads the full solve to the 7.64
optimum (92 iterations instead of 132). A held part's long path climbs a ladder instead
(:data:`COARSE_LADDER_WAYPOINTS`)."""


COARSE_SEEDED_MU_INIT = 1e-4
"""IPOPT's initial barrier parameter [-] for the first full solve of a held part (a stationary tool)
from the coarse seed (:func:`refine.optimise.solve.coarse_seed`), which starts next to the answer,
and for the solve of the ladder's finer copy (:data:`COARSE_LADDER_WAYPOINTS`): IPOPT's default 0.1
pushes the seed off the cone it already sits on, and the monotone barrier of a held part
(:data:`refine.optimise.problem.HELD_PART_IPOPT`) then spends most of its iterations coming back."""


COARSE_SEED_STRIDE = 40
"""Waypoints per coarse step on long paths: wider steps leave the interpolated seed too far from the
answer (LBR iiwa, 6,400 waypoints: 40 coarse waypoints, 164 apart, 175 iterations; 160, 40 apart, 21)."""


COARSE_LADDER_MIN_PATH = 320
"""A held part (a stationary tool) on a redundant arm, solved with IPOPT, on a path of more than this
many waypoints climbs the coarse ladder (:data:`COARSE_LADDER_WAYPOINTS`): twice the ladder's finer
copy, so that copy holds at most every other waypoint (measured on the puzzle piece's 437 and 443
waypoints only)."""


COARSE_LADDER_WAYPOINTS = 160
"""The ladder's finer copy: this many evenly spaced waypoints (:func:`ladder_waypoints`), seeded from
the :data:`COARSE_SEED_WAYPOINTS` copy's answer and solved with ``ipopt.mu_init``
:data:`COARSE_SEEDED_MU_INIT` (at IPOPT's default 0.1 the puzzle piece, below, takes 207
iterations in all instead of 192); its answer seeds the full solve. On Tesseract's puzzle piece (bench
``puzzle_piece_tesseract``: 437 waypoints, the iiwa holding the part against the grinder) the
16-waypoint answer leaves the full solve 132 iterations to move the elbow; the finer copy moves it
at a fraction of the cost per iteration. Sizes tried there: IPOPT iterations of the finer copy and
of the full solve (the 16-waypoint copy takes 57), the full objective [deg²], median CPU of 5 runs
of the whole refinement [s]::

    finer copy [waypoints]   its iterations   full solve's   objective   CPU [s]
          none                   -              132          7.58621     0.836
            40                  26            132 *          7.58621     0.872
            80                  99            132 *          7.58621     0.933
           120                  87            132 *          7.58621     0.980
           130                  79            132 *          7.58621     0.988
           140                  87               59          7.63939     0.561
           150                  88               46          7.58621     0.496
           155                  74               54          7.58621     0.531
           160                  95               40          7.58621     0.481
           165                  78            132 *          7.58621     0.975
           170                  86            132 *          7.58621     1.013
           175                  89               43          7.58621     0.511
           180                  77               46          7.58621     0.509
           190                  85            132 *          7.58621     1.070
           200                 101            132 *          7.58621     1.086
           240                 122            132 *          7.58621     1.197

At the sizes marked * the finer answer's projection misses 2-4 poses (at 170: waypoints 316-318,
between two of the copy's, where joint 4 is at its limit less the margin and the least-squares
projection, held inside the bounds, ends 1.5-3e-4 from the pose), so the 16-waypoint answer seeds
the full solve as without the ladder (132 iterations) and the finer copy's solve is spent for
nothing. 140 lands on another local optimum; 150-180 less 165 and 170 keep the answer of the solve
without a ladder (to 8.1e-10 rad at 160), 160 the fastest. The size is tuned on this one path: on
another the projection may miss where it does not here, which costs the finer copy's solve and
leaves the answer as it was."""


def coarse_waypoints(problem: RefinementNLP) -> Array | None:
    """The waypoints of the coarse copy (sorted indices, the first 0), or None.

    Every :data:`COARSE_SEED_STRIDE`-th waypoint, at least :data:`COARSE_SEED_WAYPOINTS`, evenly
    spaced and rounded; None for a non-redundant arm or a path shorter than
    :data:`COARSE_SEED_MIN_PATH`.
    """
    N = problem.n_waypoints
    if problem.dof <= 6 or N < COARSE_SEED_MIN_PATH:
        return None
    count = max(COARSE_SEED_WAYPOINTS, N // COARSE_SEED_STRIDE)
    return _evenly(N, count)


def ladder_waypoints(problem: RefinementNLP) -> Array | None:
    """The waypoints of the ladder's finer copy (sorted indices, the first 0), or None.

    :data:`COARSE_LADDER_WAYPOINTS` evenly spaced and rounded, for a held part (a stationary tool)
    on a redundant arm solved with IPOPT on a path of more than :data:`COARSE_LADDER_MIN_PATH`
    waypoints; None for any other problem (its coarse seed comes from one copy alone).
    """
    N = problem.n_waypoints
    if (
        problem.tool_in_world is None
        or problem.dof <= 6
        or problem.solver_name != "ipopt"
        or N <= COARSE_LADDER_MIN_PATH
    ):
        return None
    return _evenly(N, COARSE_LADDER_WAYPOINTS)


def _evenly(N: int, count: int) -> Array:
    return np.unique(np.linspace(0, N - 1, count).round().astype(int))


def coarse_copy(problem: RefinementNLP, idx: Array, wall_time_s: float | None = None) -> RefinementNLP:
    """``problem`` over the waypoints ``idx`` alone: no active or joint-step rows, the step bound widened.

    The joint-step bound is scaled by the widest step between the copy's waypoints, at most 360 deg
    (no bound at all); no clearance rows are added (the copy is solved without sources).
    ``wall_time_s`` [s]: the time left of the refinement's limit, the copy's IPOPT
    ``max_wall_time`` when less than the problem's (as a given option, so every round keeps it);
    None for the problem's own.
    """
    if wall_time_s is not None and problem.solver_name == "ipopt":
        own = float(problem.solver_options.get("ipopt.max_wall_time", math.inf))
        limit = {"ipopt.max_wall_time": max(1e-3, min(own, wall_time_s))}  # IPOPT wants > 0
        problem = replace(
            problem,
            solver_options={**problem.solver_options, **limit},
            given_options={**problem.given_options, **limit},
        )
    f = problem.fused
    coarse_path = FusedPath(
        f.s[idx], f.positions[idx], f.rotations[idx], f.speed[idx], f.t_demo[idx], f.residual[idx]
    )
    spread = float(np.diff(idx).max())  # waypoint steps per coarse step
    step = min(problem.tolerances.joint_step_deg * spread, 360.0)  # 360 deg: no bound at all
    tolerances = replace(problem.tolerances, joint_step_deg=step)
    return problem.rebuilt(fused=coarse_path, tolerances=tolerances, active=ActiveSet(), joint_steps=())


def projected(
    problem: RefinementNLP, idx: Array, q_coarse: Array, at: Array | None = None
) -> tuple[Array, int]:
    """Joints (len(at), n) [rad] at the waypoints ``at`` (all when None) from ``q_coarse`` at ``idx``.

    ``q_coarse`` interpolated along the arc length and projected onto each waypoint's exact pose by
    least-squares IK without null-space drift (a stationary tool's spin stays where ``q_coarse``
    has it). Returns the joints and how many poses the projection misses (the joints are a seed
    only when none).
    """
    s = problem.fused.s
    at = np.arange(problem.n_waypoints) if at is None else at
    q = np.column_stack([np.interp(s[at], s[idx], q_coarse[:, j]) for j in range(problem.dof)])
    lower, upper = problem_bounds(problem)
    q, err = solve_ik_batch(
        problem_kinematics(problem),
        problem_targets(problem)[at],
        q,
        lower,
        upper,
        nullspace_gain=0.0,
        axis_only=seed_axis_only(problem),
    )
    return q, int(np.count_nonzero(~(err < 10.0 * CONVERGED)))
