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

from refine.control import Progress, controlled
from refine.errors import InputError
from refine.plausible import CAD_SPEED_LIMIT_M_S
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


MM_SUSPECT_REACHES = 10.0
"""Positions whose nearest point is this many reaches from the robot's base are refused: no cell
puts a path that far, while millimetres read as metres put it a thousand times too far."""

QUATERNION_ORDERS = ("wxyz", "xyzw")
"""The quaternion orders :func:`refine_path` reads, one of which the caller must state."""

SPEED_CAP_WITHOUT_DEMO_M_S = 5.0
"""TCP speed cap [m/s] when :func:`refine_path` gets no speeds: above what industrial arms reach
along a process path, so the joint speed and acceleration limits alone set the timing. The
``slow_segments`` of such a result compare against this cap."""


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
            q0 = _joints(initial_joints, None, None)
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
    q0 = _joints(initial_joints, len(fused), n)
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


def _joints(q: ArrayLike | None, N: int | None, n: int | None) -> Array | None:
    if q is None:
        return None
    q = np.asarray(q, dtype=float)
    if q.ndim != 2 or (N is not None and q.shape != (N, n)):
        want = f"({N}, {n})" if N is not None else "(N, n)"
        raise InputError(f"initial_joints: expected shape {want} [rad], got {q.shape}")
    if not np.all(np.isfinite(q)):
        raise InputError("initial_joints: contains NaN or infinite values [rad]")
    return q


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
    p = _finite(positions, "positions", "m")
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 3:
        raise InputError(f"positions: expected shape (N, 3) [m] with N >= 3, got {p.shape}")
    N = len(p)
    base = _transform(base_in_world, "base_in_world")
    _check_position_units(p, robot, base)
    R = _rotations(orientations, N, quaternion_order)
    s = _arc_length(p, arc_length)
    v = _speeds(speeds, N)
    dt = np.diff(s) * 0.5 * (1.0 / v[1:] + 1.0 / v[:-1])
    fused = FusedPath(s, p, R, v, np.concatenate([[0.0], np.cumsum(dt)]), np.zeros(N))
    tolerances = _settings(tolerances, Tolerances, "tolerances")
    collision = _settings(collision, CollisionSettings, "collision")
    optimise = _settings(optimise, OptimiseSettings, "optimise")
    repair = _settings(repair, RepairSettings, "repair")
    process = _settings(process, ProcessSettings, "process")
    cell = _shapes(cell, "cell")
    tool_shapes = _shapes(tool_shapes, "tool_shapes")
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
            tcp_in_flange=_transform(tcp_in_flange, "tcp_in_flange"),
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


def _settings(value: Any, cls: type, name: str) -> Any:
    """``value`` as a ``cls``: an instance, a mapping of its fields, or None for the defaults.

    Anything else, or an unknown field, is an InputError naming the argument and the fields.
    """
    if value is None:
        return cls()
    if isinstance(value, cls):
        return value
    fields = [f.name for f in dataclasses.fields(cls)]
    if not isinstance(value, Mapping):
        raise InputError(
            f"{name}: expected a refine.{cls.__name__} or a mapping of its fields, got {type(value).__name__}",
            key=name,
            value=value,
            expected=f"refine.{cls.__name__} or a mapping of {', '.join(fields)}",
        )
    unknown = sorted(set(value) - set(fields))
    if unknown:
        raise InputError(
            f"{name}: unknown field(s) {', '.join(map(repr, unknown))}; the fields are {', '.join(fields)}",
            key=f"{name}.{unknown[0]}",
            value=value[unknown[0]],
            expected=f"one of the fields {', '.join(fields)}",
        )
    return cls(**dict(value))


def _shapes(shapes: Any, name: str) -> tuple:
    """``shapes`` as a tuple of :class:`refine.settings.Shape`; anything else is an InputError."""
    items = tuple(shapes or ())
    for k, shape in enumerate(items):
        if not isinstance(shape, Shape):
            raise InputError(
                f"{name}[{k}]: expected a refine.Shape, got {type(shape).__name__} (a problem file's "
                f"table becomes one with refine.Shape(kind=..., name=..., ...))",
                key=f"{name}[{k}]",
                value=shape,
                expected="refine.Shape",
            )
    return items


def _finite(a: ArrayLike, name: str, unit: str) -> Array:
    try:
        arr = np.asarray(a, dtype=float)
    except (TypeError, ValueError) as e:
        raise InputError(f"{name}: not an array of numbers [{unit}]: {e}") from e
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name}: contains NaN or infinite values [{unit}]")
    return arr


def _rotations(orientations: ArrayLike, N: int, order: str | None) -> Array:
    from refine.frames import check_rotation, matrix_from_quaternion

    o = _finite(orientations, "orientations", "-")
    if o.shape == (N, 4):
        if order not in QUATERNION_ORDERS:
            raise InputError(
                f"orientations: (N, 4) quaternions need quaternion_order='wxyz' (scalar first, as in "
                f"trajectory.csv) or 'xyzw' (scalar last, as scipy's Rotation.as_quat()), got "
                f"{order!r}: every unit quaternion is valid in both orders, so the order cannot be "
                "told from the numbers"
            )
        if order == "xyzw":
            o = np.column_stack([o[:, 3], o[:, :3]])
        norms = np.linalg.norm(o, axis=1)
        if np.any(np.abs(norms - 1.0) > 1e-3):
            k = int(np.argmax(np.abs(norms - 1.0)))
            raise InputError(
                f"orientations: quaternion {k} has length {norms[k]:.6f}; expected unit quaternions "
                "(qw, qx, qy, qz)"
            )
        return matrix_from_quaternion(o)
    if o.shape == (N, 3, 3):
        return check_rotation(o, "orientations").copy()
    raise InputError(
        f"orientations: expected (N, 4) quaternions (qw, qx, qy, qz) or (N, 3, 3) rotation matrices "
        f"with N = {N} (the number of positions), got {o.shape}"
    )


def _arc_length(p: Array, arc_length: ArrayLike | None) -> Array:
    if arc_length is None:
        steps = np.linalg.norm(np.diff(p, axis=0), axis=1)
        if np.any(steps <= 0.0):
            k = int(np.flatnonzero(steps <= 0.0)[0])
            raise InputError(f"positions: waypoints {k} and {k + 1} coincide; the path must move [m]")
        return np.concatenate([[0.0], np.cumsum(steps)])
    s = _finite(arc_length, "arc_length", "m")
    if s.shape != (len(p),):
        raise InputError(f"arc_length: expected shape ({len(p)},) [m], got {s.shape}")
    if np.any(np.diff(s) <= 0.0):
        raise InputError("arc_length: must strictly increase along the path [m]")
    return s - s[0]


def _speeds(speeds: ArrayLike | float | None, N: int) -> Array:
    if speeds is None:
        return np.full(N, SPEED_CAP_WITHOUT_DEMO_M_S)
    v = _finite(speeds, "speeds", "m/s")
    if v.ndim == 0:
        v = np.full(N, float(v))
    if v.shape != (N,):
        raise InputError(f"speeds: expected shape ({N},) or one number [m/s], got {v.shape}")
    if np.any(v <= 0.0):
        raise InputError(f"speeds: every speed must be > 0 m/s, got min {v.min():g} m/s")
    if v.max() > CAD_SPEED_LIMIT_M_S:
        k = int(np.argmax(v))
        raise InputError(
            f"speeds: {v[k]:g} m/s at waypoint {k} is beyond {CAD_SPEED_LIMIT_M_S:g} m/s, faster than "
            f"industrial robots move their tool; speeds are in m/s ({v[k]:g} mm/s would be "
            f"{v[k] / 1000:g} m/s)"
        )
    return v


def _check_position_units(p: Array, robot: Any, base_in_world: Array) -> None:
    """Refuse positions no part of which the robot could reach in metres but could in millimetres."""
    reach = float(robot.spec.reach_m)
    base = base_in_world[:3, 3]
    nearest = float(np.linalg.norm(p - base, axis=1).min())
    if nearest <= MM_SUSPECT_REACHES * reach:
        return
    in_mm = float(np.linalg.norm(p / 1000.0 - base, axis=1).max())
    hint = (
        f"; read as millimetres they would be within {in_mm:.3g} m of it: positions are in metres"
        if in_mm <= reach
        else ""
    )
    raise InputError(
        f"positions: the nearest is {nearest:.4g} m from the robot's base, {nearest / reach:.3g} times "
        f"its reach of {reach:g} m{hint}"
    )


def _transform(T: ArrayLike | None, name: str) -> Array:
    from refine.frames import check_transform

    if T is None:
        return np.eye(4)
    return check_transform(_finite(T, name, "m"), name).copy()
