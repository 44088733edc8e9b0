"""The peers of ``refine bench``: Tesseract's TrajOpt and Descartes (the ``peers`` extra).

Each is posed as a careful user of Tesseract would pose the problem (``tesseract-robotics`` on
PyPI, 0.5): one environment of the robot, its tool and the cell, made from refine's own files
(:func:`tesseract_environment`), and one Cartesian waypoint per path point, the TCP's target pose
in the world.

- TrajOpt (:func:`trajopt`): every waypoint seeded by refine's chained IK of the demonstrated pose
  (the greedy-IK contender, timed as the seed); the position held exactly and the orientation
  inside a tolerance box that lies inside the cone (each rotation-vector component within
  cone/sqrt(3), or within cone/sqrt(2) about x and y and free about the tool axis for an
  axisymmetric tool); collision as a constraint with the problem's cell margin; the joints inside
  their limits less the problem's joint margin; smooth velocities as TrajOpt's default cost. On
  the puzzle piece as Tesseract poses it, as Tesseract's example poses it: every waypoint seeded
  by the example's start state, the pose held by the Cartesian constraint with the turn about the
  tool axis free by a zero coefficient (:data:`EXAMPLE_COEFF`); on the puzzle piece turned round
  (:data:`EXAMPLE_POSED`) the same, the example's start state its seed too; a problem
  file's stationary tool is not posed (:class:`~refine.bench.contenders.NotPosed`).
- Descartes (:func:`descartes`): the same waypoints, sampled about the tool axis (the whole turn
  for an axisymmetric tool in :data:`DESCARTES_SAMPLE_DEG` steps, else three turns within half the
  cone), joint solutions a whole turn apart where a joint's range allows them, the
  numerical IK of every sample (KDL, the only IK the wheel ships for any arm), the collision of
  every vertex with the cell margin, the shortest joint path through the ladder graph. The
  wheel's Python profile samples about one axis only: a grid of tilts within the cone cannot be
  given to it, so a non-axisymmetric tool keeps its tilt as demonstrated. On a stationary TCP
  (the puzzle piece as Tesseract poses it) the wheel's Descartes aborts the process (an uncaught
  std::out_of_range), so it is not called there (:class:`~refine.bench.contenders.NotPosed`).

Rules neither keeps (the shared verification still checks them, so an answer that breaks one is
not verified): refine's joint-step bound between waypoints, its singularity margin, the
self-collision margin where it differs from the cell margin, and the dense clearance check between
waypoints (TrajOpt checks its continuous collision between waypoints; Descartes only at them).
The environment is made once per problem and kept, as Drake's plant and refine's robot are, and
is not timed.
"""

from __future__ import annotations

import ctypes
import math
import time
from typing import Any

import numpy as np

from refine.bench.contenders import CONTENDERS, Answer, NotPosed, greedy_ik
from refine.bench.suites import BenchProblem
from refine.bench.tesseract_env import TCP, WORLD, cell_model, compose_urdf, tesseract_environment
from refine.types import Array

__all__ = ["PEERS", "TCP", "WORLD", "compose_urdf", "descartes", "tesseract_environment", "trajopt"]

TRAJOPT_NAMESPACE = "TrajOptMotionPlannerTask"
DESCARTES_NAMESPACE = "DescartesMotionPlannerTask"
PROFILE = "REFINE_BENCH"

DESCARTES_SAMPLE_DEG = 10.0
"""Step of Descartes' samples about the tool axis [deg] (36 samples over a whole turn)."""

CONE_BACKOFF_DEG = 1e-3
"""How much narrower than the problem's cone the peers' orientation tolerance is [deg]."""

EXAMPLE_COEFF = (100.0, 100.0, 100.0, 10.0, 10.0, 0.0)
"""TrajOpt's Cartesian constraint coefficients on the puzzle piece as Tesseract poses it (x, y, z,
then rotation about x, y, z of the TCP): the rotation about the tool axis free (0), as Tesseract's
puzzle-piece example; the position weighted 100, so the SQP's merit drives it to micrometres."""

EXAMPLE_POSED = frozenset({"puzzle_piece_turned"})
"""Problem files TrajOpt poses as Tesseract's puzzle-piece example poses a puzzle path: the
Cartesian constraint with :data:`EXAMPLE_COEFF`, no tolerance box, every waypoint seeded by the
example's start state (:data:`EXAMPLE_START_RAD`), TrajOpt's seed from the current state. The
chained IK's seed turns the arm over near the path's end, which the SQP's trust region keeps:
posed with it, TrajOpt answered with a 188 deg joint step, 1.9 µm off the path, in 3.7x the CPU."""

EXAMPLE_START_RAD = (-0.785398, 0.4, 0.0, -1.9, 0.0, 1.0, 0.0)
"""The iiwa's start state in Tesseract's puzzle-piece example [rad]: the seed of every waypoint."""


def _isometry(t: dict[str, Any], T: Array) -> Any:
    iso = t["common"].Isometry3d()
    iso.setMatrix(np.ascontiguousarray(T, dtype=float))
    return iso


def _program(
    t: dict[str, Any],
    problem: BenchProblem,
    manip: Any,
    names: list[str],
    seed: Array | None = None,
    tolerance: Array | None = None,
) -> Any:
    """One linear move per path point to its Cartesian waypoint (the TCP's target in the world).

    ``seed``: joints per waypoint [rad] (N, n) given as each waypoint's seed; ``tolerance``: the
    waypoints' symmetric tolerance box (position [m], rotation vector [rad]) (6,).
    """
    cl = t["cl"]
    program = cl.CompositeInstruction(PROFILE)
    program.setManipulatorInfo(manip)
    fused = problem.fused
    for k in range(problem.n_waypoints):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = fused.rotations[k], fused.positions[k]
        waypoint = cl.CartesianWaypoint(_isometry(t, T))
        if tolerance is not None:
            waypoint.setLowerTolerance(-np.asarray(tolerance, dtype=float))
            waypoint.setUpperTolerance(np.asarray(tolerance, dtype=float))
        if seed is not None:
            waypoint.setSeed(t["common"].JointState(names, np.asarray(seed[k], dtype=float)))
        move = cl.MoveInstruction(
            cl.CartesianWaypointPoly_wrap_CartesianWaypoint(waypoint),
            cl.MoveInstructionType_LINEAR,
            PROFILE,
            manip,
        )
        program.appendMoveInstruction(cl.MoveInstructionPoly_wrap_MoveInstruction(move))
    return program


def _joints(t: dict[str, Any], results: Any, n: int, nq: int) -> Array | None:
    cl = t["cl"]
    rows = []
    flat = results.flatten()  # kept: its items refer into it
    for i in range(len(flat)):
        instruction = flat[i]
        if not instruction.isMoveInstruction():
            continue
        move = cl.InstructionPoly_as_MoveInstructionPoly(instruction)  # kept: the waypoint refers into it
        waypoint = move.getWaypoint()
        if waypoint.isStateWaypoint():
            rows.append(np.asarray(cl.WaypointPoly_as_StateWaypointPoly(waypoint).getPosition(), dtype=float))
        elif waypoint.isJointWaypoint():
            rows.append(np.asarray(cl.WaypointPoly_as_JointWaypointPoly(waypoint).getPosition(), dtype=float))
    q = np.array(rows).reshape(len(rows), -1)
    if q.shape != (n, nq):
        return None
    return q


def _cone_rad(problem: BenchProblem) -> float:
    return math.radians(problem.tolerances.orientation_deg - CONE_BACKOFF_DEG)


def set_vector6(config: Any, name: str, values: tuple[float, ...] | Array) -> None:
    """Set a six-vector field (``Eigen::Matrix<double, 6, 1>``) of a Tesseract profile's config.

    The wheel's bindings map only dynamic Eigen vectors to NumPy: the getter of a fixed six-vector
    hands out a copy as an opaque pointer, and the setter takes only such a pointer. So the copy's
    six doubles (Eigen stores them contiguously) are written through ``ctypes`` and handed back.
    """
    value = getattr(config, name)
    cells = (ctypes.c_double * 6).from_address(int(value))
    cells[:] = [float(v) for v in values]
    setattr(config, name, value)
    written = list((ctypes.c_double * 6).from_address(int(getattr(config, name))))
    if written != [float(v) for v in values]:
        raise RuntimeError(f"Tesseract kept {written} for {name}, not {list(values)}")


def trajopt(problem: BenchProblem) -> Answer:
    """TrajOpt over the whole path, seeded by chained IK, the cone as its orientation tolerance.

    On the puzzle piece as Tesseract poses it (``problem.extra["tesseract_files"]``) it is posed
    as Tesseract's own puzzle-piece example poses it: every waypoint seeded by the example's start
    state (:data:`EXAMPLE_START_RAD`), the pose held by a Cartesian constraint whose coefficients
    (:data:`EXAMPLE_COEFF`) leave the rotation about the tool axis free, no tolerance box. A
    problem file in :data:`EXAMPLE_POSED` (the puzzle piece turned round) is posed the same way.

    Timed: the chained IK (``seed``; none where posed as the example), making the program and
    profiles (``build``) and TrajOpt's solve, which builds its own problem (``solve``). Raises
    :class:`Unavailable` without the extra, :class:`NotPosed` on a problem file's stationary tool.
    """
    files = "tesseract_files" in problem.extra
    example = files or problem.name in EXAMPLE_POSED
    if problem.tool_in_world is not None and not files:
        raise NotPosed("a problem file's stationary tool is not composed into a Tesseract workcell")
    t, env, manip, _, names, _ = tesseract_environment(problem)
    T = t["trajopt"]
    c0 = time.process_time()
    w0 = time.perf_counter()
    plan = T.TrajOptDefaultPlanProfile()  # the Cartesian waypoints as constraints
    if example:
        seed = np.tile(np.asarray(EXAMPLE_START_RAD, dtype=float), (problem.n_waypoints, 1))
        box = None
        set_vector6(plan.cartesian_constraint_config, "coeff", EXAMPLE_COEFF)
    else:
        seed = greedy_ik(problem).q
        cone = _cone_rad(problem)
        if problem.axisymmetric:
            box = np.array([0.0, 0.0, 0.0, cone / math.sqrt(2.0), cone / math.sqrt(2.0), math.pi])
        else:
            box = np.array([0.0, 0.0, 0.0] + [cone / math.sqrt(3.0)] * 3)
    w1 = time.perf_counter()
    composite = T.TrajOptDefaultCompositeProfile()
    model = cell_model(problem)
    composite.collision_cost_config.enabled = False
    composite.collision_constraint_config.enabled = model is not None
    if model is not None:
        composite.collision_constraint_config.safety_margin = float(model.margin_m)
    profiles = t["cl"].ProfileDictionary()
    profiles.addProfile(TRAJOPT_NAMESPACE, PROFILE, plan)
    profiles.addProfile(TRAJOPT_NAMESPACE, PROFILE, composite)
    request = t["planners"].PlannerRequest()
    request.instructions = _program(t, problem, manip, names, seed, box)
    request.env = env
    request.profiles = profiles
    planner = T.TrajOptMotionPlanner(TRAJOPT_NAMESPACE)
    w2 = time.perf_counter()
    response = planner.solve(request)
    w3 = time.perf_counter()
    q = _joints(t, response.results, problem.n_waypoints, problem.robot.nq) if response.successful else None
    note = "" if response.successful else f"TrajOpt: {response.message}"[:80]
    options = {
        "sqp": _settings(T.BasicTrustRegionSQPParameters(), SQP_SETTINGS),  # no solver profile: its defaults
        "orientation_box_rad": None if box is None else [float(v) for v in box[3:]],
        "cartesian_coeff": list(EXAMPLE_COEFF) if example else "TrajOpt's default (5 on each axis)",
        "seed": "the example's start state" if example else "chained IK (greedy-ik)",
        **_settings(composite, COMPOSITE_SETTINGS),
        "collision_constraint": bool(composite.collision_constraint_config.enabled),
        "safety_margin_m": float(model.margin_m) if model is not None else None,
    }
    return Answer(
        "ok" if q is not None else "failed",
        q,
        {"build": w2 - w0, "seed": 0.0, "solve": w3 - w2}
        if example
        else {"build": w2 - w1, "seed": w1 - w0, "solve": w3 - w2},
        time.process_time() - c0,
        0,
        note,
        solver_status=_status(response),
        solver_options=options,
    )


def descartes(problem: BenchProblem) -> Answer:
    """Descartes over the whole path: samples about the tool axis, IK of each, the shortest joint path.

    Timed: making the program and profile (``build``) and Descartes' solve (sampling, IK, vertex
    collision, the ladder graph's search: ``solve``). Raises :class:`Unavailable` without the extra,
    :class:`NotPosed` on a stationary tool.
    """
    if problem.tool_in_world is not None:
        # measured: the wheel's Descartes aborts the process (std::out_of_range, uncaught in C++)
        # on the puzzle piece's stationary TCP, so it is not called there
        raise NotPosed("Descartes of tesseract-robotics 0.5.1 aborts on a stationary TCP (not called)")
    t, env, manip, _, names, _ = tesseract_environment(problem)
    D = t["descartes"]
    c0 = time.process_time()
    w0 = time.perf_counter()
    profile = D.DescartesDefaultPlanProfileD()
    profile.target_pose_fixed = False
    profile.target_pose_sample_axis = np.array([0.0, 0.0, 1.0])
    if problem.axisymmetric:
        profile.target_pose_sample_min, profile.target_pose_sample_max = -math.pi, math.pi
        profile.target_pose_sample_resolution = math.radians(DESCARTES_SAMPLE_DEG)
    else:  # three turns about the tool axis, inside the cone by half of it (room for the IK's tolerance)
        half = 0.5 * _cone_rad(problem)
        profile.target_pose_sample_min, profile.target_pose_sample_max = -half, half
        profile.target_pose_sample_resolution = half
    model = cell_model(problem)
    profile.enable_collision = model is not None
    profile.allow_collision = model is None  # without a cell nothing is checked, as for refine
    if model is not None:
        _set_margin(t, profile.vertex_collision_check_config, float(model.margin_m))
    profile.enable_edge_collision = False
    profile.use_redundant_joint_solutions = True  # whole turns of a joint whose range spans more
    profiles = t["cl"].ProfileDictionary()
    profiles.addProfile(DESCARTES_NAMESPACE, PROFILE, D.cast_DescartesPlanProfileD(profile))
    request = t["planners"].PlannerRequest()
    request.instructions = _program(t, problem, manip, names, None)
    request.env = env
    request.profiles = profiles
    planner = D.DescartesMotionPlannerD(DESCARTES_NAMESPACE)
    w1 = time.perf_counter()
    response = planner.solve(request)
    w2 = time.perf_counter()
    q = _joints(t, response.results, problem.n_waypoints, problem.robot.nq) if response.successful else None
    note = "" if response.successful else f"Descartes: {response.message}"[:80]
    options = _settings(profile, DESCARTES_SETTINGS)
    options["target_pose_sample_axis"] = [float(v) for v in np.ravel(profile.target_pose_sample_axis)]
    options["collision_margin_m"] = float(model.margin_m) if model is not None else None
    return Answer(
        "ok" if q is not None else "failed",
        q,
        {"build": w1 - w0, "seed": 0.0, "solve": w2 - w1},
        time.process_time() - c0,
        0,
        note,
        solver_status=_status(response),
        solver_options=options,
    )


SQP_SETTINGS = (
    "max_iter", "max_time", "cnt_tolerance", "min_approx_improve", "min_trust_box_size", "trust_box_size",
    "improve_ratio_threshold", "trust_shrink_ratio", "trust_expand_ratio", "max_merit_coeff_increases",
    "merit_coeff_increase_ratio", "initial_merit_error_coeff",
)  # fmt: skip
"""TrajOpt's trust-region SQP settings recorded in a row's ``solver_options`` (``sqp``)."""

COMPOSITE_SETTINGS = ("smooth_velocities", "velocity_coeff", "smooth_accelerations", "smooth_jerks",
                      "avoid_singularity", "longest_valid_segment_length")  # fmt: skip
"""TrajOpt's composite-profile settings recorded in a row's ``solver_options``."""

DESCARTES_SETTINGS = (
    "target_pose_fixed", "target_pose_sample_min", "target_pose_sample_max", "target_pose_sample_resolution",
    "enable_collision", "allow_collision", "enable_edge_collision", "use_redundant_joint_solutions",
)  # fmt: skip
"""Descartes' plan-profile settings recorded in a row's ``solver_options``."""


def _settings(source: Any, names: tuple[str, ...]) -> dict[str, Any]:
    """The named attributes of a Tesseract profile or parameter set, as JSON-ready numbers and flags."""
    found = {}
    for name in names:
        value = getattr(source, name)
        if isinstance(value, float) and not math.isfinite(value):
            value = str(value)  # TrajOpt's "no limit" is the largest double
        elif isinstance(value, float) and abs(value) > 1e300:
            value = "unlimited"
        elif hasattr(value, "tolist"):
            value = np.asarray(value).tolist()
        found[name] = value
    return found


def _status(response: Any) -> str:
    """The planner's own word on its solve: ``successful`` or its message (Tesseract has no status code)."""
    return "successful" if response.successful else str(response.message)[:80]


def _set_margin(t: dict[str, Any], config: Any, margin_m: float) -> None:
    """Give a collision check config the cell margin as its default margin [m]."""
    manager = config.contact_manager_config
    manager.margin_data = t["common"].CollisionMarginData(margin_m)
    manager.margin_data_override_type = t["common"].CollisionMarginOverrideType_OVERRIDE_DEFAULT_MARGIN


for _peer in (trajopt, descartes):
    _peer.setup = tesseract_environment  # made once per problem, before the runs (refine.bench.watchdog)

PEERS = {"trajopt": trajopt, "descartes": descartes}
"""The peers by name; they join :data:`refine.bench.contenders.CONTENDERS` when this module is imported."""

CONTENDERS.update(PEERS)
