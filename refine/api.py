"""The library API: refine a path from Python, from a problem folder or straight from arrays.

Three calls cover an offline-programming step that holds its path in memory:

* :func:`load_problem` reads a problem folder, :func:`solve` runs it without writing files;
* :func:`refine_path` refines positions and orientations given as NumPy arrays, with the same
  engine, verification and diagnosis as ``refine run``;
* :meth:`Result.write` writes the files ``refine run`` writes, whenever the caller wants them.

A :class:`Result` exposes the refined joints, the TCP poses, the timing and the verified figures
as NumPy arrays and plain values; :meth:`Result.to_dict` is the ``result.json`` document. A second
call can start from a previous answer: ``initial_joints=`` warm-starts the solver, and
``previous=`` also reuses the built problem when only the path or the tolerances changed a little
(see :func:`refine.optimise.problem.reuse_for`). Every name here is documented in ``docs/api.md``.
"""

from __future__ import annotations

import copy
import dataclasses
import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from refine.arguments import (  # noqa: I001
    arc_length_from,
    check_position_units,
    finite_array,
    joints_from,
    rotations_from,
    settings_from,
    shapes_from,
    speeds_from,
    transform_from,
)
from refine.control import Progress, controlled
from refine.errors import InputError
from refine.problem import Problem, load_problem
from refine.settings import (
    CollisionSettings,
    OptimiseSettings,
    OutputSettings,
    ProcessSettings,
    RepairSettings,
    RobotSettings,
    Shape,
    Tolerances,
    ToolSettings,
)
from refine.types import Array

if TYPE_CHECKING:
    from refine.robot.model import Robot
    from refine.run.result import PassResult, RunResult

__all__ = ["PassArrays", "Result", "load_problem", "refine_path", "solve"]




@dataclass(frozen=True)
class PassArrays:
    """One pass of a result as arrays (SI units, world frame {F}).

    Attributes:
        name: ``"pass 1"``, or ``"layer 2 pass 1"`` in a multi-pass weld.
        status: ``"ok"``, ``"repaired"`` or ``"infeasible"``.
        reason: empty when ok; otherwise what was repaired or why it is infeasible.
        joints: joint angles per waypoint [rad], shape (N, n).
        poses: TCP pose reached per waypoint, T_F_TCP, shape (N, 4, 4) [m].
        times: time of each waypoint [s], shape (N,); None when infeasible (no timing).
        speeds: planned TCP speed [m/s], shape (N,); None when infeasible.
        arc_length: arc length along the path [m], shape (N,).
        metrics: the pass's verified figures, as in ``result.json``'s ``passes[].metrics``.
    """

    name: str
    status: str
    reason: str
    joints: Array
    poses: Array
    times: Array | None
    speeds: Array | None
    arc_length: Array
    metrics: dict[str, Any]


class Result:
    """What a refinement produced, in memory.

    The arrays of the first (demonstrated) pass are attributes of the result itself; every pass is
    in :attr:`passes`. Nothing is written until :meth:`write` is called.

    The figures :attr:`metrics`, :attr:`passes`, :attr:`diagnosis` and :attr:`placement` read
    from ``result.json``'s document are computed once, on first use: they come from the solved
    passes, which a run never changes (frozen). :meth:`to_dict` is computed anew on each call:
    :meth:`write` adds the files written (``outputs``, ``files``) and their times (``timings_s``).

    Attributes:
        run: the underlying :class:`refine.run.result.RunResult` (problem, robot, per-pass details).
    """

    def __init__(self, run: RunResult) -> None:
        self.run = run
        self._doc: dict[str, Any] | None = None

    def _figures(self) -> dict[str, Any]:
        """``result.json``'s document as first computed, for the figures of the solved passes."""
        if self._doc is None:
            self._doc = self.to_dict()
        return self._doc

    def __repr__(self) -> str:
        return (
            f"Result(status={self.status!r}, problem={self.run.problem.name!r}, "
            f"waypoints={len(self.run.first.fused)}, passes={len(self.run.passes)})"
        )

    @property
    def status(self) -> str:
        """``"ok"``, ``"repaired"`` (within the repair slack) or ``"infeasible"``."""
        return self.run.status

    @property
    def passes(self) -> tuple[PassArrays, ...]:
        """Every pass as arrays, in order (one for a single-pass path)."""
        doc = self._figures()["passes"]
        return tuple(_pass_arrays(p, d["metrics"]) for p, d in zip(self.run.passes, doc, strict=True))

    @property
    def joints(self) -> Array:
        """Joint angles of the first pass [rad], shape (N, n)."""
        return self.run.first.refinement.q.copy()

    @property
    def poses(self) -> Array:
        """TCP poses T_F_TCP of the first pass in the world frame, shape (N, 4, 4) [m]."""
        return self.run.first.refinement.check.poses.copy()

    @property
    def times(self) -> Array | None:
        """Time of each waypoint of the first pass [s], shape (N,); None when infeasible."""
        timing = self.run.first.timing
        return None if timing is None else timing.t.copy()

    @property
    def speeds(self) -> Array | None:
        """Planned TCP speed of the first pass [m/s], shape (N,); None when infeasible."""
        timing = self.run.first.timing
        return None if timing is None else timing.speed.copy()

    @property
    def metrics(self) -> dict[str, Any]:
        """The verified figures over all passes (``result.json``'s ``metrics``)."""
        return dict(self._figures()["metrics"])

    @property
    def diagnosis(self) -> list[dict[str, Any]]:
        """Where and why the path had to deviate: ``result.json``'s ``diagnosis``.

        One entry per repaired or infeasible segment (pass, waypoints, arc lengths, the cause with
        its figure, limit and unit, and a suggestion); empty when every pass is ok. The schema is in
        ``docs/outputs.md``.
        """
        return copy.deepcopy(self._figures()["diagnosis"])

    @property
    def placement(self) -> dict[str, Any] | None:
        """The workpiece move of ``[repair] placement``: ``result.json``'s ``placement``.

        Its status (``"ok"`` when a move was found and verified by the strict pipeline, ``"not
        needed"`` or ``"infeasible"``), the move (translation [m], rotation axis and angle [deg]
        in the world frame), the moved objects and the strict run's metrics; the schema is
        ``docs/placement.schema.json``. None when the problem does not ask for a placement search.
        """
        return copy.deepcopy(self._figures()["placement"])

    @property
    def motions(self) -> list[dict[str, Any]]:
        """Every motion of the program, verified: ``result.json``'s ``motions``.

        Home, approach, path, retract, the links between passes and the return, each with its
        start and end, duration, planner, via points, least distance and status; the schema is
        ``docs/motions.schema.json``. Empty when a pass is not executable.
        """
        return copy.deepcopy(self._figures()["motions"])

    def to_dict(self) -> dict[str, Any]:
        """The ``result.json`` document of this result, as plain Python values."""
        from refine.export.result_json import result_dict

        return result_dict(self.run)

    def write(
        self, out_dir: str | Path, programs: Sequence[str] | None = None, *, report: bool = True
    ) -> dict[str, Path]:
        """Write the outputs of ``refine run`` into ``out_dir``.

        Args:
            out_dir: the folder (created if missing).
            programs: program formats (``"rapid"``, ``"krl"``, ``"urscript"``); None for the
                problem's ``[output] programs``.
            report: also write ``report.html``.

        Returns:
            kind -> path of every file written (``result``, ``trajectory``, ``pathml``, ...).
        """
        from refine.run.write import write_run

        write_run(self.run, Path(out_dir), tuple(programs) if programs is not None else None, report=report)
        return dict(self.run.outputs)


def _pass_arrays(p: PassResult, metrics: dict[str, Any]) -> PassArrays:
    return PassArrays(
        name=p.name,
        status=p.refinement.status,
        reason=p.refinement.reason,
        joints=p.refinement.q.copy(),
        poses=p.refinement.check.poses.copy(),
        times=None if p.timing is None else p.timing.t.copy(),
        speeds=None if p.timing is None else p.timing.speed.copy(),
        arc_length=p.fused.s.copy(),
        metrics=dict(metrics),
    )


def solve(
    problem: Problem | str | Path,
    *,
    initial_joints: ArrayLike | None = None,
    previous: Result | None = None,
    time_limit_s: float | None = None,
    cancel: threading.Event | Callable[[], bool] | None = None,
    progress: Callable[[Progress], Any] | None = None,
) -> Result:
    """Run a problem through every stage up to the verified, timed path, writing no file.

    Args:
        problem: a loaded :class:`~refine.problem.Problem`, or the path of its folder or file.
        initial_joints: joints (N, n) [rad] to start the first pass from instead of the IK seed.
        previous: an earlier result of the same problem with a small change (tolerances, weights):
            its built problem is reused where it can be and its joints are the start.
        time_limit_s: wall-time budget [s] of each pass's refinement, instead of the problem's
            ``[repair] time_limit_s``; when it runs out before a verdict the status is ``"timeout"``.
        cancel: a :class:`threading.Event` (or a callable returning True) that stops the call:
            checked after every stage, every solve -> verify round and every IPOPT iteration; the
            call then raises :class:`refine.Cancelled`. Ctrl-C raises ``KeyboardInterrupt``, also
            from inside IPOPT; neither ever becomes a verdict.
        progress: called with a :class:`refine.control.Progress` after every stage and every IPOPT
            iteration, in the calling thread; what it raises ends the call.

    Returns:
        The result; ``result.write(out_dir)`` writes the files ``refine run`` writes.
    """
    from refine.run.solve import solve_problem
    from refine.run.stages import fused_path

    with controlled(cancel, progress):
        if not isinstance(problem, Problem):
            problem = load_problem(problem)
        problem = _with_time_limit(problem, time_limit_s)
        if previous is None:
            q0 = joints_from(initial_joints, None, None)
            return Result(solve_problem(problem, q0=q0))
        fused = fused_path(problem)
        return _solve_again(problem, previous.run.robot, fused, previous, initial_joints)


def _with_time_limit(problem: Problem, time_limit_s: float | None) -> Problem:
    if time_limit_s is None:
        return problem
    return dataclasses.replace(problem, repair=dataclasses.replace(problem.repair, time_limit_s=time_limit_s))


def _solve_again(
    problem: Problem, robot: Robot, fused: Any, previous: Result | None, initial_joints: ArrayLike | None
) -> Result:
    from refine.optimise.problem import reuse_for
    from refine.optimise.warm import WarmStart
    from refine.run.solve import solve_problem
    from refine.run.stages import weights_for

    nlp = None
    warm = None
    n = robot.nq
    q0 = joints_from(initial_joints, len(fused), n)
    if previous is not None:
        first = previous.run.first
        old = first.nlp
        same = (
            old is not None
            and previous.run.robot is robot
            and np.array_equal(old.base_in_world, problem.robot.base_in_world)
            and np.array_equal(old.tcp_in_flange, problem.tool.tcp_in_flange)
            and old.axisymmetric == problem.tool.axisymmetric
            and old.weights == weights_for(problem, robot)
        )
        nlp = reuse_for(old, fused, problem.tolerances) if same else None
        if q0 is None and previous.run.robot is robot and first.refinement.q.shape == (len(fused), n):
            # the previous joints moved onto the new poses, and its last problem and multipliers
            # where the robot, tool and weights are the same (refine.optimise.warm)
            warm = WarmStart(
                first.refinement.q,
                first.fused.rotations if len(first.fused) == len(fused) else None,
                first.refinement.problem if nlp is not None else None,
                first.refinement.multipliers if nlp is not None else None,
                first.clearance,
            )
    return Result(solve_problem(problem, robot=robot, fused=fused, nlp=nlp, q0=q0, warm=warm))


def refine_path(
    robot: Robot | str,
    positions: ArrayLike,
    orientations: ArrayLike,
    *,
    speeds: ArrayLike | float | None = None,
    arc_length: ArrayLike | None = None,
    tcp_in_flange: ArrayLike | None = None,
    base_in_world: ArrayLike | None = None,
    tolerances: Tolerances | Mapping[str, float] | None = None,
    cell: Sequence[Shape] = (),
    tool_shapes: Sequence[Shape] = (),
    axisymmetric: bool = False,
    initial_joints: ArrayLike | None = None,
    previous: Result | None = None,
    name: str = "path",
    tool_name: str = "tool",
    home_deg: Sequence[float] | None = None,
    collision: CollisionSettings | None = None,
    optimise: OptimiseSettings | None = None,
    repair: RepairSettings | None = None,
    process: ProcessSettings | None = None,
    programs: Sequence[str] | None = None,
    quaternion_order: str | None = None,
    time_limit_s: float | None = None,
    cancel: threading.Event | Callable[[], bool] | None = None,
    progress: Callable[[Progress], Any] | None = None,
) -> Result:
    """Refine a path given as arrays, with the engine, verification and diagnosis of ``refine run``.

    The TCP follows ``positions`` exactly while its orientation stays within the tolerance cone
    around ``orientations``.

    Args:
        robot: a :class:`refine.robot.model.Robot` (e.g. from ``Robot.from_urdf``) or a registry name.
        positions: TCP targets in the world frame {F} [m], shape (N, 3), N >= 3.
        orientations: demonstrated TCP orientations R_F_TCP: (N, 4) unit quaternions in the order
            ``quaternion_order`` states, or (N, 3, 3) rotation matrices.
        speeds: demonstrated TCP speed [m/s], (N,) or one number; None for no cap but the robot's
            limits (:data:`SPEED_CAP_WITHOUT_DEMO_M_S`).
        arc_length: arc length of each waypoint along the path [m], (N,), strictly increasing;
            None for the cumulative distance between consecutive positions.
        tcp_in_flange: T_flange_TCP (4, 4); None for the identity.
        base_in_world: T_F_R, the robot base in the world (4, 4); None for the identity.
        tolerances: a :class:`refine.settings.Tolerances` or a mapping of its fields
            (``{"orientation_deg": 5.0}``); None for the defaults.
        cell: the cell's collision objects (:class:`refine.settings.Shape`, world frame).
        tool_shapes: the tool's collision shapes (poses in the flange frame).
        axisymmetric: the spin about the TCP z axis is free.
        initial_joints: joints (N, n) [rad] to start from instead of the IK seed (warm start).
        previous: an earlier result for the same robot, tool and number of waypoints: its built
            problem is reused when the path and tolerances changed only a little, and its joints
            are the start unless ``initial_joints`` is given.
        name: the problem name (output file names, program module name).
        tool_name: the tool's name in programs.
        home_deg: preferred first configuration [deg] for the IK seed.
        collision: ``[collision]`` settings (margins); None for the defaults.
        optimise: ``[optimise]`` cost weights; None for the defaults.
        repair: ``[repair]`` settings; None for the defaults.
        process: ``[process]`` settings (output name, parameters); None for the defaults.
        programs: programs :meth:`Result.write` writes by default; None for the one of the robot's
            controller (``robot.spec.default_program``: KRL for the KR arms, Sunrise for the LBR iiwa).
        quaternion_order: ``"wxyz"`` (scalar first, as ``trajectory.csv``) or ``"xyzw"`` (scalar
            last, as scipy's ``Rotation.as_quat()``); required with quaternions, since both orders
            read any unit quaternion.
        time_limit_s: wall-time budget [s] of each pass's refinement, instead of the problem's
            ``[repair] time_limit_s``; when it runs out before a verdict the status is ``"timeout"``.
        cancel: a :class:`threading.Event` (or a callable returning True) that stops the call:
            checked after every stage, every solve -> verify round and every IPOPT iteration; the
            call then raises :class:`refine.Cancelled`. Ctrl-C raises ``KeyboardInterrupt``, also
            from inside IPOPT; neither ever becomes a verdict.
        progress: called with a :class:`refine.control.Progress` after every stage and every IPOPT
            iteration, in the calling thread; what it raises ends the call.

    Returns:
        The verified, timed result (no file written).

    Raises:
        InputError: a shape, a non-finite value, a non-rotation, a non-increasing arc length,
            quaternions without their order, positions that read as millimetres (nowhere within
            ten reaches of the base), speeds above 10 m/s; the message names the argument and the unit.
    """
    from refine.paths import FusedPath
    from refine.robot.model import Robot
    from refine.robot.registry import load_robot

    if isinstance(robot, str):
        robot = load_robot(robot)
    elif not isinstance(robot, Robot):
        raise InputError(f"robot: expected a refine.Robot or a registry name, got {type(robot).__name__}")
    p = finite_array(positions, "positions", "m")
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 3:
        raise InputError(f"positions: expected shape (N, 3) [m] with N >= 3, got {p.shape}")
    N = len(p)
    base = transform_from(base_in_world, "base_in_world")
    check_position_units(p, robot, base)
    R = rotations_from(orientations, N, quaternion_order)
    s = arc_length_from(p, arc_length)
    v = speeds_from(speeds, N)
    dt = np.diff(s) * 0.5 * (1.0 / v[1:] + 1.0 / v[:-1])
    fused = FusedPath(s, p, R, v, np.concatenate([[0.0], np.cumsum(dt)]), np.zeros(N))
    tolerances = settings_from(tolerances, Tolerances, "tolerances")
    collision = settings_from(collision, CollisionSettings, "collision")
    optimise = settings_from(optimise, OptimiseSettings, "optimise")
    repair = settings_from(repair, RepairSettings, "repair")
    process = settings_from(process, ProcessSettings, "process")
    cell = shapes_from(cell, "cell")
    tool_shapes = shapes_from(tool_shapes, "tool_shapes")
    problem = Problem(
        name=name,
        root=Path.cwd(),
        robot=RobotSettings(
            model=robot.spec.name,
            base_in_world=base,
            home_deg=None if home_deg is None else tuple(float(a) for a in home_deg),
        ),
        tool=ToolSettings(
            name=tool_name,
            tcp_in_flange=transform_from(tcp_in_flange, "tcp_in_flange"),
            axisymmetric=bool(axisymmetric),
            collision=tuple(tool_shapes),
        ),
        cad=None,
        demonstration=None,
        tolerances=tolerances,
        process=process or ProcessSettings(),
        output=OutputSettings(
            programs=tuple(programs) if programs is not None else (robot.spec.default_program,)
        ),
        cell=tuple(cell),
        collision=collision or CollisionSettings(),
        optimise=optimise or OptimiseSettings(),
        repair=repair or RepairSettings(),
    )
    with controlled(cancel, progress):
        return _solve_again(_with_time_limit(problem, time_limit_s), robot, fused, previous, initial_joints)
