"""The contenders of ``refine bench``: refine with each derivative mode and solver, greedy IK, and Drake.

A contender is a callable ``(BenchProblem) -> Answer`` (:data:`Contender`, docs/bench.md): it turns
a :class:`~refine.bench.suites.BenchProblem` into joints per waypoint and its stage times;
:func:`verify` then checks every answer the same way (TCP position, orientation cone, joint limits
and singularity margin with Pinocchio, clearance with the dense check when the problem has a cell),
so no contender grades itself. Contenders are registered by name in :data:`CONTENDERS`: the
built-in ones, plug-ins from a file (:func:`load_contender_file`) or from the entry-point group
:data:`ENTRY_POINT_GROUP` (:func:`load_entry_points`); :func:`timed_call` is the runner's clock.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from refine.bench.suites import BenchProblem
from refine.errors import InputError
from refine.types import Array

log = logging.getLogger(__name__)


class Unavailable(Exception):
    """A contender that cannot run here (a missing optional package); the message says why."""


class NotPosed(Exception):
    """A contender that cannot pose this one problem (it runs on the others); the message says why.

    Its row on the problem has status ``unavailable`` and the reason in ``note``, and enters no
    table, average or ratio of the report.
    """


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
        solver_status: the iterative solver's own return status (IPOPT's ``Solve_Succeeded``,
            ``Maximum_Iterations_Exceeded``, ...), empty for a contender without one; a status of
            :data:`refine.bench.outcomes.NOT_CONVERGED` makes the row no success, however it verifies.
        solver_options: the solver options the contender used, as it reports them (empty when it
            reports none); refine's: :func:`refine_options`.
        verify_s, verify_cpu_s: wall and CPU time [s] of its own check, outside ``times_s``
            (refine's :data:`OWN_CHECK_STAGES`); NaN for a contender without one.
    """

    status: str
    q: Array | None
    times_s: dict[str, float] = field(default_factory=dict)
    cpu_s: float = 0.0
    iterations: int = 0
    note: str = ""
    slack_deg: Array | None = None
    solver_status: str = ""
    solver_options: dict[str, Any] = field(default_factory=dict)
    verify_s: float = float("nan")
    verify_cpu_s: float = float("nan")


OWN_CHECK_STAGES = ("verify", "diagnose")
"""refine's own check: its verification of every round's answer and its diagnosis of a repair."""


def solve_as_refine(
    problem: BenchProblem, mode: str = "assembled", solver: str = "ipopt", solver_options: dict | None = None
) -> tuple[Any, float, float]:
    """Build ``problem``'s refinement and solve it as ``refine run`` does (the refine contenders' call).

    The solver options are the problem's (``problem.solver_options``, those of ``solver``'s prefix)
    updated with ``solver_options``; refine's defaults fill in the rest. With a time limit
    (``problem.time_limit_s``) the refinement stops its solves when the limit less the build's
    time runs out (status ``timeout``), and IPOPT gets it as ``ipopt.max_wall_time`` unless given.

    Returns:
        the :class:`refine.optimise.outcome.Refinement`, the first round's problem, and the build's
        wall and CPU time [s].
    """
    from refine.optimise.solve import solve_refinement
    from refine.optimise.stagewise import FATROP_PREFIX

    for source in problem.sources:  # no dense check kept from an earlier run of the same problem
        forget = getattr(source, "forget", None)
        if forget is not None:
            forget()
    prefix = FATROP_PREFIX if solver == "fatrop" else "ipopt."
    given = {k: v for k, v in problem.solver_options.items() if k.startswith(prefix)}
    given.update(solver_options or {})
    options = dict(given)
    if problem.time_limit_s is not None and solver != "fatrop":  # one solve cannot overrun the limit
        options.setdefault("ipopt.max_wall_time", float(problem.time_limit_s))
    w0, c0 = time.perf_counter(), time.process_time()
    nlp = problem.refinement(mode, solver, solver_options=options)
    build = time.perf_counter() - w0
    build_cpu = time.process_time() - c0
    result = solve_refinement(
        nlp,
        home=problem.home,
        sources=problem.sources,
        repair_max_slack_deg=problem.repair_max_slack_deg,
        max_rounds=problem.max_rounds,
        time_limit_s=None if problem.time_limit_s is None else max(problem.time_limit_s - build, 0.0),
    )
    return result, nlp, build, build_cpu


def refine_options(nlp: Any, first: dict[str, Any] | None = None) -> dict[str, Any]:
    """What refine's solve of ``nlp`` used: its solver's options, which were given, and what rounds change.

    ``options``: the first round's options of the problem's solver (refine's defaults and the given
    ones): ``first``, the options of the first solve when known
    (:attr:`refine.optimise.outcome.Refinement.first_options`), else ``nlp``'s; ``given``: the keys the caller gave, which no round overrides; ``later_rounds`` and
    ``repair``: the options refine sets itself for a round that starts from the last answer
    (:data:`refine.optimise.rounds.WARM_START_OPTIONS`) and for the elastic repair
    (:data:`refine.optimise.rounds.ELASTIC_OPTIONS`), less the given ones.
    """
    from refine.optimise.rounds import ELASTIC_OPTIONS, WARM_START_OPTIONS
    from refine.optimise.stagewise import FATROP_PREFIX

    prefix = FATROP_PREFIX if nlp.solver_name == "fatrop" else "ipopt."
    given = nlp.given_options

    def own(options: dict[str, Any]) -> dict[str, Any]:
        return {k: v for k, v in options.items() if k.startswith(prefix) and k not in given}

    options = {k: v for k, v in (first or nlp.solver_options).items() if k.startswith(prefix)}
    if nlp.solver_name == "fatrop":  # fatrop's defaults are merged in its stage-wise solver
        options = {f"{FATROP_PREFIX}{k}": v for k, v in getattr(nlp.solver, "options", {}).items()}
    return {
        "options": options,
        "given": sorted(given),
        "later_rounds": own(WARM_START_OPTIONS),
        "repair": own(ELASTIC_OPTIONS),
    }


def _refine(problem: BenchProblem, mode: str, solver: str = "ipopt") -> Answer:
    from refine.optimise.stagewise import MAX_FATROP_WAYPOINTS

    if solver == "fatrop" and problem.n_waypoints > MAX_FATROP_WAYPOINTS:
        raise NotPosed(
            f"fatrop takes at most {MAX_FATROP_WAYPOINTS} waypoints, the path has {problem.n_waypoints}"
        )
    result, nlp, build, build_cpu = solve_as_refine(problem, mode, solver)
    t = result.timings_s
    times = {"build": build + t.get("build", 0.0), "seed": t.get("seed", 0.0), "solve": t.get("solve", 0.0)}
    # refine verifies inside its loop (and diagnoses a repair): outside the timed window, in verify_s
    cpu = build_cpu + sum(t.cpu.get(k, 0.0) for k in ("build", "seed", "solve"))
    slack = result.slack_deg if result.status == "repaired" else None
    solved = result.problem if result.problem is not None else nlp
    options = refine_options(solved, result.first_options)
    options["kernels"] = kernel_settings(mode)
    return Answer(
        result.status,
        result.q,
        times,
        cpu,
        result.iterations,
        result.solver_status[:80],
        slack,
        solver_status=result.solver_status.split(";")[0].strip(),
        solver_options=options,
        verify_s=sum(t.get(k, 0.0) for k in OWN_CHECK_STAGES),
        verify_cpu_s=sum(t.cpu.get(k, 0.0) for k in OWN_CHECK_STAGES),
    )


def kernel_settings(mode: str) -> dict[str, Any]:
    """How refine's derivatives were made in ``mode``: compiled kernels or CasADi's virtual machine.

    Compiled: the C compiler and its flags (:mod:`refine.optimise.compiled`).
    """
    from refine.optimise.compiled import COMPILE_FLAGS, compiler

    cc = compiler() if mode == "assembled" else None
    if cc is None:
        return {"mode": mode, "compiled": False}
    return {"mode": mode, "compiled": True, "compiler": cc, "flags": list(COMPILE_FLAGS)}


def refine_assembled(problem: BenchProblem) -> Answer:
    """The refine pipeline as it runs: compiled per-waypoint kernels, assembled derivatives, IPOPT.

    Timed: building the problem (``build``, with any rebuild of the outer loop), seeding it (reach
    tilts, chained IK, the constraints the seed shows to be needed: ``seed``) and solving it (every
    IPOPT round and what each round adds: ``solve``). Not timed: the robot's loading (once per
    problem, as Drake's plant), refine's own check (:data:`OWN_CHECK_STAGES`, in ``verify_s``);
    the kernels are compiled and cached on disk before the timed runs (the warm-up run).
    """
    return _refine(problem, "assembled")


def refine_casadi_ad(problem: BenchProblem) -> Answer:
    """The refinement with CasADi differentiating the whole problem (the virtual machine, no compiled kernels)."""
    return _refine(problem, "casadi")


def refine_fatrop(problem: BenchProblem) -> Answer:
    """The refinement solved by fatrop on its stage-wise form (:mod:`refine.optimise.stagewise`).

    Timed as :func:`refine_assembled`; the build includes CasADi's set-up of fatrop's stage blocks.
    Paths over :data:`refine.optimise.stagewise.MAX_FATROP_WAYPOINTS` waypoints are not posed
    (:class:`NotPosed`, saying why).
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
    status = "ok" if float(errors.max()) < GREEDY_POSE_ERROR else "infeasible"
    return Answer(
        status,
        q,
        {"seed": seconds},
        time.process_time() - c0,
        0,
        f"max pose error {errors.max():.2e}",
        solver_options={"ik": "refine.optimise.seed.ik_chain", "ok_below_pose_error": GREEDY_POSE_ERROR},
    )


GREEDY_POSE_ERROR = 1e-6
"""The chained IK's largest pose error (as :func:`refine.optimise.seed.ik_chain` measures it) below
which greedy IK answers ``ok``."""


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
    start on the same IK branch. Raises :class:`Unavailable` without pydrake or SNOPT, and
    :class:`NotPosed` on a stationary tool.
    """
    try:
        from pydrake.math import RotationMatrix
        from pydrake.multibody.inverse_kinematics import InverseKinematics
        from pydrake.solvers import SnoptSolver
    except ImportError as e:
        raise Unavailable(f"pydrake is not installed ({e}); pip install '.[bench]'") from e
    if problem.tool_in_world is not None:
        raise NotPosed("the Drake contender does not pose a stationary tool (the robot holding the part)")
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
    results: dict[str, int] = {}  # SNOPT's solution result -> waypoints
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
        word = str(result.get_solution_result()).rpartition(".")[2]
        results[word] = results.get(word, 0) + 1
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
        solver_status=", ".join(f"{word} x{n}" for word, n in sorted(results.items(), key=lambda r: -r[1])),
        solver_options={
            "solver": "SNOPT (Drake's defaults)",
            "cone_backoff_deg": DRAKE_CONE_BACKOFF_DEG,
            "cost": "squared joint change from the previous waypoint",
        },
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


def _drake_setup(problem: BenchProblem) -> None:
    """The Drake contender's set-up: its plant (:func:`_drake_plant`); :class:`Unavailable` without pydrake.

    None on a stationary tool, which the contender does not pose (:class:`NotPosed` from its call).
    """
    try:
        import pydrake  # noqa: F401
    except ImportError as e:
        raise Unavailable(f"pydrake is not installed ({e}); pip install '.[bench]'") from e
    if problem.tool_in_world is None:
        _drake_plant(problem)


drake_chained_ik.setup = _drake_setup  # made once per problem, before the runs (refine.bench.watchdog)

DRAKE_CONE_BACKOFF_DEG = 1e-3
"""How much narrower the cone given to Drake is than the problem's [deg]."""

Contender = Callable[[BenchProblem], Answer]
"""A contender: called with one problem, returns its :class:`Answer` (docs/bench.md, "Plug-in contenders")."""

for _keeper in (refine_assembled, refine_casadi_ad, refine_fatrop):
    _keeper.keeps_time_limit = True  # they stop at problem.time_limit_s (refine.bench.watchdog)

CONTENDERS: dict[str, Contender] = {
    "refine": refine_assembled,
    "refine-casadi-ad": refine_casadi_ad,
    "refine-fatrop": refine_fatrop,
    "greedy-ik": greedy_ik,
    "drake-ik": drake_chained_ik,
}
"""Every contender by name, in the order the runner tries them (plug-ins after the built-in ones)."""

ENTRY_POINT_GROUP = "refine.bench.contenders"
"""The entry-point group of installed plug-in contenders: each entry point's name is the contender's
name, its object a :data:`Contender`."""


def register_contender(name: str, function: Contender, *, replace: bool = False) -> str:
    """Add ``function`` to :data:`CONTENDERS` as ``name``; returns the name.

    Raises:
        InputError: the name is empty or holds a space, comma or colon; ``function`` is not
            callable; or another contender has the name (unless ``replace``).
    """
    if not name or any(c in name for c in " ,:") or not name.isprintable():
        raise InputError(
            f"contender name {name!r}: give a non-empty name without spaces, commas or colons",
            key="contender",
            value=name,
        )
    if not callable(function):
        raise InputError(
            f"contender {name!r} is a {type(function).__name__}, not a callable", key="contender", value=name
        )
    known = CONTENDERS.get(name)
    if known is not None and known is not function and not replace:
        raise InputError(
            f"a contender named {name!r} exists already; give another name", key="contender", value=name
        )
    CONTENDERS[name] = function
    return name


def load_contender_file(spec: str) -> str:
    """Register the contender ``NAME`` defined in ``FILE.py`` (``spec`` = ``FILE.py:NAME``); returns NAME.

    The file is run as a module of its own (named after the file), so it may import refine and
    anything installed.

    Raises:
        InputError: ``spec`` is not ``FILE:NAME``, the file is missing or fails to import, or it has
            no callable ``NAME``.
    """
    import importlib.util
    from pathlib import Path

    file, sep, name = spec.rpartition(":")
    if not sep or not file or not name:
        raise InputError(
            f"--contender-file {spec!r}: expected FILE.py:NAME", key="contender-file", value=spec
        )
    path = Path(file)
    if not path.is_file():
        raise InputError(f"--contender-file {spec!r}: no file {path}", key="contender-file", value=spec)
    module_spec = importlib.util.spec_from_file_location(f"refine_bench_plugin_{path.stem}", path)
    module = importlib.util.module_from_spec(module_spec)
    try:
        module_spec.loader.exec_module(module)
    except Exception as e:
        raise InputError(
            f"--contender-file {spec!r}: {path} failed to import: {type(e).__name__}: {e}"
        ) from e
    if not hasattr(module, name):
        found = sorted(k for k, v in vars(module).items() if callable(v) and not k.startswith("_"))
        raise InputError(
            f"--contender-file {spec!r}: {path} defines no {name!r}; its callables: {', '.join(found)}",
            key="contender-file",
            value=spec,
        )
    return register_contender(name, getattr(module, name))


def load_entry_points() -> list[str]:
    """Register every installed contender of the entry-point group :data:`ENTRY_POINT_GROUP`; their names.

    Raises:
        InputError: an entry point fails to load, or its name is taken.
    """
    from importlib import metadata

    names = []
    for entry in metadata.entry_points(group=ENTRY_POINT_GROUP):
        try:
            function = entry.load()
        except Exception as e:
            raise InputError(
                f"contender entry point {entry.name} = {entry.value}: {type(e).__name__}: {e}"
            ) from e
        names.append(register_contender(entry.name, function))
    return names


def parse_solver_option(text: str) -> tuple[str, Any]:
    """``key=value`` of ``--solver-option`` as (key, typed value): an int, else a float, else the text.

    A key without a solver prefix is IPOPT's (``max_iter`` -> ``ipopt.max_iter``); ``fatrop.``
    keys go to fatrop. ``yes``/``no`` stay text, as IPOPT takes them.

    Raises:
        InputError: no ``=``, or an empty key or value.
    """
    key, sep, value = text.partition("=")
    key, value = key.strip(), value.strip()
    if not sep or not key or not value:
        raise InputError(
            f"--solver-option {text!r}: expected key=value, e.g. max_iter=100 or ipopt.tol=1e-8",
            key="solver-option",
            value=text,
            expected="key=value",
        )
    if "." not in key:
        key = f"ipopt.{key}"
    for kind in (int, float):
        try:
            return key, kind(value)
        except ValueError:
            pass
    return key, value


def timed_call(problem: BenchProblem, name: str, function: Contender) -> tuple[Answer, float]:
    """One run of a contender and its wall time [s] on the runner's clock (``time.perf_counter``).

    The clock runs around the whole call, whatever the contender times itself. A crash is an
    ``error`` answer with the exception in its note; :class:`Unavailable` passes through (the
    runner then skips the contender), and so does :class:`NotPosed` (the runner then skips it on
    this problem); an answer of another type is an ``error`` too.
    """
    t0 = time.perf_counter()
    try:
        answer = function(problem)
    except (Unavailable, NotPosed):
        raise
    except Exception as e:  # a contender crashing is a result, not the end of the benchmark
        log.warning("%s on %s failed: %s", name, problem.name, e)
        answer = Answer("error", None, note=f"{type(e).__name__}: {str(e)[:120]}")
    if not isinstance(answer, Answer):
        answer = Answer("error", None, note=f"returned a {type(answer).__name__}, not an Answer")
    return answer, time.perf_counter() - t0


@dataclass
class Verdict:
    """The shared verification of an answer.

    Attributes:
        verified: every tolerance kept (position, cone, limits, singularity, clearance).
        max_position_error_m: largest TCP position error [m].
        max_orientation_deviation_deg: largest deviation from the demonstrated orientation [deg].
        min_clearance_m: least clearance (distance minus margin) in the dense check [m], NaN without a cell.
        max_joint_step_deg: largest change of any joint between neighbouring waypoints [deg].
        reason: the first broken tolerance, empty when verified.
        broken_s_m: arc-length range [m] of each stretch that breaks a tolerance (collisions included).
    """

    verified: bool
    max_position_error_m: float
    max_orientation_deviation_deg: float
    min_clearance_m: float
    max_joint_step_deg: float
    reason: str
    broken_s_m: list[tuple[float, float]] = field(default_factory=list)


def verify(problem: BenchProblem, q: Array | None, slack_deg: Array | None = None) -> Verdict:
    """Check joints ``q`` with refine's verification (Pinocchio, FCL) against the problem's tolerances."""
    from refine.optimise.verify import check_path
    from refine.robot.kinematics import TcpKinematics

    if q is None or not np.all(np.isfinite(q)):
        return Verdict(False, np.nan, np.nan, np.nan, np.nan, "no answer")
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
        float(np.degrees(np.abs(np.diff(q, axis=0)).max(initial=0.0))),
        first if isinstance(first, str) else first.describe(),
        broken,
    )
