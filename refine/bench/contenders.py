"""The contenders of ``refine bench``: refine with each derivative mode and solver, greedy IK, and Drake.

Each contender turns a :class:`~refine.bench.suites.BenchProblem` into joints per waypoint and its
stage times; :func:`verify` then checks every answer the same way (TCP position, orientation cone,
joint limits and singularity margin with Pinocchio, clearance with the dense check when the problem
has a cell), so no contender grades itself.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from refine.bench.suites import BenchProblem
from refine.types import Array

log = logging.getLogger(__name__)


class Unavailable(Exception):
    """A contender that cannot run here (a missing optional package); the message says why."""


@dataclass
class Answer:
    """What a contender returns.

    Attributes:
        status: the contender's own word: ``ok``, ``repaired``, ``infeasible`` or ``failed``.
        q: joints per waypoint [rad] (N, n), or None when it gave none.
        times_s: wall time per stage [s] (``build``, ``seed``, ``solve``).
        cpu_s: process CPU time of the same stages [s].
        iterations: solver iterations (summed), 0 when not applicable.
        note: a short remark (e.g. the solver's status).
        slack_deg: extra orientation slack per waypoint a repaired answer claims [deg], or None.
    """

    status: str
    q: Array | None
    times_s: dict[str, float] = field(default_factory=dict)
    cpu_s: float = 0.0
    iterations: int = 0
    note: str = ""
    slack_deg: Array | None = None


def _refine(problem: BenchProblem, mode: str, solver: str = "ipopt") -> Answer:
    from refine.optimise.solve import solve_refinement
    from refine.optimise.stagewise import MAX_FATROP_WAYPOINTS

    if solver == "fatrop" and problem.n_waypoints > MAX_FATROP_WAYPOINTS:
        return Answer(
            "failed",
            None,
            note=f"not run: fatrop takes at most {MAX_FATROP_WAYPOINTS} waypoints, the path has {problem.n_waypoints}",
        )
    for source in problem.sources:  # no dense check kept from an earlier run of the same problem
        forget = getattr(source, "forget", None)
        if forget is not None:
            forget()
    w0, c0 = time.perf_counter(), time.process_time()
    nlp = problem.refinement(mode, solver)
    build = time.perf_counter() - w0
    build_cpu = time.process_time() - c0
    result = solve_refinement(
        nlp,
        home=problem.home,
        sources=problem.sources,
        repair_max_slack_deg=problem.repair_max_slack_deg,
        max_rounds=problem.max_rounds,
    )
    t = result.timings_s
    times = {"build": build + t.get("build", 0.0), "seed": t.get("seed", 0.0), "solve": t.get("solve", 0.0)}
    # refine verifies inside its loop (and diagnoses a repair); those stages are not counted
    cpu = build_cpu + sum(t.cpu.get(k, 0.0) for k in ("build", "seed", "solve"))
    slack = result.slack_deg if result.status == "repaired" else None
    return Answer(result.status, result.q, times, cpu, result.iterations, result.solver_status[:80], slack)


def refine_assembled(problem: BenchProblem) -> Answer:
    """The refine pipeline as it runs: compiled per-waypoint kernels, assembled derivatives, IPOPT.

    Timed: building the problem (``build``, with any rebuild of the outer loop), seeding it (reach
    tilts, chained IK, the constraints the seed shows to be needed: ``seed``) and solving it (every
    IPOPT round and what each round adds: ``solve``). Not timed: the robot's loading (done once per
    problem, as Drake's plant) and refine's own verification of each round's answer and diagnosis
    of a repair (``verify`` and ``diagnose`` of :class:`refine.stopwatch.StageTimes`); the
    per-waypoint kernels are compiled and cached on disk before the timed runs (the warm-up run).
    """
    return _refine(problem, "assembled")


def refine_casadi_ad(problem: BenchProblem) -> Answer:
    """The refinement with CasADi differentiating the whole problem (the virtual machine, no compiled kernels)."""
    return _refine(problem, "casadi")


def refine_fatrop(problem: BenchProblem) -> Answer:
    """The refinement solved by fatrop on its stage-wise form (:mod:`refine.optimise.stagewise`).

    Timed as :func:`refine_assembled`; the build includes CasADi's set-up of fatrop's stage blocks.
    Paths over :data:`refine.optimise.stagewise.MAX_FATROP_WAYPOINTS` waypoints are not run (status
    ``failed``, saying why).
    """
    return _refine(problem, "assembled", "fatrop")


def greedy_ik(problem: BenchProblem) -> Answer:
    """Per-waypoint IK of the demonstrated pose chained along the path: what a Cartesian planner does."""
    from refine.optimise.seed import ik_chain, start_candidates
    from refine.robot.kinematics import TcpKinematics

    w0, c0 = time.perf_counter(), time.process_time()
    kin = TcpKinematics(problem.robot, problem.base_in_world, problem.tcp_in_flange, problem.tool_in_world)
    margin = np.radians(problem.tolerances.joint_margin_deg)
    lower, upper = problem.robot.spec.lower + margin, problem.robot.spec.upper - margin
    targets = np.tile(np.eye(4), (problem.n_waypoints, 1, 1))
    targets[:, :3, :3], targets[:, :3, 3] = problem.fused.rotations, problem.fused.positions
    q, errors = ik_chain(
        kin,
        targets,
        lower,
        upper,
        start_candidates(lower, upper, problem.home),
        prefer_first=problem.home is not None,
    )
    seconds = time.perf_counter() - w0
    status = "ok" if float(errors.max()) < 1e-6 else "infeasible"
    return Answer(
        status, q, {"seed": seconds}, time.process_time() - c0, 0, f"max pose error {errors.max():.2e}"
    )


def drake_chained_ik(problem: BenchProblem) -> Answer:
    """Drake's InverseKinematics waypoint by waypoint (SNOPT), each from the previous answer.

    Constraints as refine's: the TCP on the CAD point, the orientation inside the cone (the tool
    axis only for an axisymmetric tool), the joints inside their limits minus the margin; cost: the
    squared joint change from the previous waypoint, which is also the initial guess. SNOPT is
    called directly (no solver selection per waypoint).

    Timed, as refine's build + seed + solve: making each waypoint's program (``build``) and
    solving it (``solve``). Not timed, as refine's robot loading is not: the plant, parsed from the
    robot's URDF once per problem and kept (:func:`_drake_plant`), and the start configuration, the
    first configuration of the greedy chain along the whole path (:func:`greedy_ik`), so both
    start on the same IK branch. Raises :class:`Unavailable` without pydrake or SNOPT.
    """
    try:
        from pydrake.math import RotationMatrix
        from pydrake.multibody.inverse_kinematics import InverseKinematics
        from pydrake.solvers import SnoptSolver
    except ImportError as e:
        raise Unavailable(f"pydrake is not installed ({e}); pip install '.[bench]'") from e
    if problem.tool_in_world is not None:
        return Answer("failed", None, note="not run: the Drake contender does not pose a stationary tool")
    snopt = SnoptSolver()
    if not snopt.available():
        raise Unavailable("pydrake has no SNOPT here")

    plant, context, order, flange = _drake_plant(problem)
    robot = problem.robot
    margin = np.radians(problem.tolerances.joint_margin_deg)
    lower, upper = robot.spec.lower + margin, robot.spec.upper - margin
    lo, hi = np.full(plant.num_positions(), -np.inf), np.full(plant.num_positions(), np.inf)
    lo[order], hi[order] = lower, upper
    # SNOPT meets a bound to its feasibility tolerance, about 1e-6 relative; an answer on the cone's
    # edge must still pass the shared check, so Drake gets the cone less a thousandth of a degree
    cone = np.radians(problem.tolerances.orientation_deg - DRAKE_CONE_BACKOFF_DEG)
    tcp = problem.tcp_in_flange
    q_prev = greedy_ik(problem).q[0]

    c0 = time.process_time()
    build = solve = 0.0
    out = np.empty((problem.n_waypoints, robot.nq))
    failed = 0
    guess = np.zeros(plant.num_positions())
    for k in range(problem.n_waypoints):
        t0 = time.perf_counter()
        ik = InverseKinematics(plant, context, with_joint_limits=False)
        qv = ik.q()
        p_target = problem.fused.positions[k]
        ik.AddPositionConstraint(flange, tcp[:3, 3], plant.world_frame(), p_target, p_target)
        R_demo = problem.fused.rotations[k]
        if problem.axisymmetric:
            ik.AddAngleBetweenVectorsConstraint(
                plant.world_frame(), R_demo[:, 2], flange, tcp[:3, 2], 0.0, cone
            )
        else:
            ik.AddOrientationConstraint(
                plant.world_frame(), RotationMatrix(R_demo), flange, RotationMatrix(tcp[:3, :3]), cone
            )
        prog = ik.get_mutable_prog()
        prog.AddBoundingBoxConstraint(lo, hi, qv)
        guess[order] = q_prev
        prog.AddQuadraticErrorCost(np.eye(len(guess)), guess, qv)
        t1 = time.perf_counter()
        result = snopt.Solve(prog, guess)
        t2 = time.perf_counter()
        build, solve = build + t1 - t0, solve + t2 - t1
        if not result.is_success():
            failed += 1
            log.debug("drake-ik: waypoint %d: %s", k, result.get_solution_result())
        q_prev = result.GetSolution(qv)[order]
        out[k] = q_prev
    status = "ok" if failed == 0 else "infeasible"
    return Answer(
        status,
        out,
        {"build": build, "seed": 0.0, "solve": solve},
        time.process_time() - c0,
        0,
        f"{failed} waypoint(s) failed" if failed else "",
    )


def _drake_plant(problem: BenchProblem):
    """Drake's plant of the problem's robot, welded at its base, with a context; made once per problem.

    Returns:
        plant, context, the plant's position index of each of refine's joints, the flange frame.
    """
    if "drake_plant" not in problem.extra:
        from pydrake.math import RigidTransform
        from pydrake.multibody.parsing import Parser
        from pydrake.multibody.plant import MultibodyPlant

        robot = problem.robot
        plant = MultibodyPlant(time_step=0.0)  # no SceneGraph: geometry (meshes) is not loaded
        parser = Parser(plant)
        parser.package_map().PopulateFromFolder(str(robot.spec.urdf.parent))
        (instance,) = parser.AddModels(str(robot.spec.urdf))
        root = plant.GetBodyIndices(instance)[0]
        plant.WeldFrames(
            plant.world_frame(), plant.get_body(root).body_frame(), RigidTransform(problem.base_in_world)
        )
        plant.Finalize()
        order = np.array([plant.GetJointByName(j).position_start() for j in robot.spec.joint_names])
        flange = plant.GetFrameByName(robot.spec.flange_frame)
        problem.extra["drake_plant"] = (plant, plant.CreateDefaultContext(), order, flange)
    return problem.extra["drake_plant"]


DRAKE_CONE_BACKOFF_DEG = 1e-3
"""How much narrower the cone given to Drake is than the problem's [deg]."""

CONTENDERS: dict[str, Callable[[BenchProblem], Answer]] = {
    "refine": refine_assembled,
    "refine-casadi-ad": refine_casadi_ad,
    "refine-fatrop": refine_fatrop,
    "greedy-ik": greedy_ik,
    "drake-ik": drake_chained_ik,
}
"""Every contender by name, in the order the runner tries them."""


@dataclass
class Verdict:
    """The shared verification of an answer.

    Attributes:
        verified: every tolerance kept (position, cone, limits, singularity, clearance).
        max_position_error_m: largest TCP position error [m].
        max_orientation_deviation_deg: largest deviation from the demonstrated orientation [deg].
        min_clearance_m: least clearance (distance minus margin) in the dense check [m], NaN without a cell.
        reason: the first broken tolerance, empty when verified.
        broken_s_m: arc-length range [m] of each stretch that breaks a tolerance (collisions included).
    """

    verified: bool
    max_position_error_m: float
    max_orientation_deviation_deg: float
    min_clearance_m: float
    reason: str
    broken_s_m: list[tuple[float, float]] = field(default_factory=list)


def verify(problem: BenchProblem, q: Array | None, slack_deg: Array | None = None) -> Verdict:
    """Check joints ``q`` with refine's verification (Pinocchio, FCL) against the problem's tolerances."""
    from refine.optimise.verify import check_path
    from refine.robot.kinematics import TcpKinematics

    if q is None or not np.all(np.isfinite(q)):
        return Verdict(False, np.nan, np.nan, np.nan, "no answer")
    kin = TcpKinematics(problem.robot, problem.base_in_world, problem.tcp_in_flange, problem.tool_in_world)
    check = check_path(kin, q, problem.fused, problem.tolerances, problem.axisymmetric, slack_deg)
    violations = list(check.violations)
    broken = [(float(v.s_start_m), float(v.s_end_m)) for v in check.violations]
    clearance = np.nan
    s = problem.fused.s
    for source in problem.sources:
        result = source.clearance(q)
        clearance = result.min_clearance_m
        violations += [f"collision: {r.describe()}" for r in result.runs]
        broken += [(float(s[r.index_start]), float(s[r.index_end])) for r in result.runs]
    first = violations[0] if violations else ""
    return Verdict(
        not violations,
        float(check.position_error_m.max()),
        float(check.orientation_deviation_deg.max()),
        float(clearance),
        first if isinstance(first, str) else first.describe(),
        broken,
    )
