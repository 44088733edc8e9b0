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
import threading
from collections.abc import Callable, Mapping, Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from refine.arguments import (  # noqa: I001
    arc_length_from,
    check_hooks,
    check_position_units,
    check_previous,
    checked_call,
    finite_array,
    home_from,
    joints_from,
    require_run,
    rotations_from,
    settings_from,
    shapes_from,
    speeds_from,
    transform_from,
    typed,
)
from refine.control import Progress, controlled
from refine.errors import InputError, api_words
from refine.problem import Problem
from refine.problem import load_problem as read_problem
from refine.run.again import solve_again
from refine.run.timeout import checked_limit, timed_call, with_time_limit
from refine.run.typed import Diagnosis, Metrics, PassArrays
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
    from refine.run.result import RunResult

__all__ = ["PassArrays", "Result", "load_problem", "refine_path", "solve"]


class Result:
    """What a refinement produced, in memory.

    The arrays of the first (demonstrated) pass are attributes of the result itself; every pass is
    in :attr:`passes`. Nothing is written until :meth:`write` is called; :meth:`program`,
    :meth:`pathml` and :meth:`contents` give the same documents as text without touching the disk.

    The figures :attr:`metrics`, :attr:`passes`, :attr:`diagnosis` and :attr:`placement` read
    from ``result.json``'s document are computed once, on first use: they come from the solved
    passes, which a run never changes (frozen). :meth:`to_dict` is computed anew on each call:
    :meth:`write` adds the files written (``outputs``, ``files``) and their times (``timings_s``).

    Attributes:
        run: the underlying :class:`refine.run.result.RunResult` (problem, robot, per-pass details);
            None for a result rebuilt by :meth:`from_dict`.
    """

    def __init__(self, run: RunResult | None, *, doc: dict[str, Any] | None = None) -> None:
        self.run = run
        self._doc: dict[str, Any] | None = doc
        self._contents: dict[str, Any] | None = None  # rebuilt from a dictionary: its arrays and texts
        self._stamp: datetime | None = None  # the documents' time stamp, fixed at the first rendering
        self._files: dict[tuple[str, ...], dict[str, tuple[str, bytes]]] = {}

    def _figures(self) -> dict[str, Any]:
        """``result.json``'s document as first computed, for the figures of the solved passes."""
        if self._doc is None:
            self._doc = self.to_dict()
        return self._doc

    def __repr__(self) -> str:
        doc = self._figures()
        return (
            f"Result(status={self.status!r}, problem={doc['problem']!r}, "
            f"waypoints={doc['n_waypoints']}, passes={doc['n_passes']})"
        )

    @property
    def status(self) -> str:
        """``"ok"``, ``"repaired"`` (within the repair slack), ``"infeasible"`` or ``"timeout"``."""
        return self.run.status if self.run is not None else self._figures()["status"]

    @property
    def passes(self) -> tuple[PassArrays, ...]:
        """Every pass as arrays, in order (one for a single-pass path)."""
        doc = self._figures()["passes"]
        return tuple(
            PassArrays(
                name=d["name"],
                status=d["status"],
                reason=self._reason(k),
                metrics=dict(d["metrics"]),
                **self._arrays(k),
            )
            for k, d in enumerate(doc)
        )

    def _reason(self, k: int) -> str:
        if self.run is not None:
            return self.run.passes[k].refinement.reason
        return self._contents["reasons"][k] if self._contents else ""

    def _arrays(self, k: int) -> dict[str, Any]:
        if self.run is None:
            from refine.run.contents import arrays_from

            return arrays_from(self._contents, k)
        p = self.run.passes[k]
        return {
            "joints": p.refinement.q.copy(),
            "poses": p.refinement.check.poses.copy(),
            "times": None if p.timing is None else p.timing.t.copy(),
            "speeds": None if p.timing is None else p.timing.speed.copy(),
            "arc_length": p.fused.s.copy(),
        }

    @property
    def joints(self) -> Array:
        """Joint angles of the first pass [rad], shape (N, n)."""
        return self._arrays(0)["joints"]

    @property
    def poses(self) -> Array:
        """TCP poses T_F_TCP of the first pass in the world frame, shape (N, 4, 4) [m]."""
        return self._arrays(0)["poses"]

    @property
    def times(self) -> Array | None:
        """Time of each waypoint of the first pass [s], shape (N,); None when infeasible."""
        return self._arrays(0)["times"]

    @property
    def speeds(self) -> Array | None:
        """Planned TCP speed of the first pass [m/s], shape (N,); None when infeasible."""
        return self._arrays(0)["speeds"]

    @property
    def metrics(self) -> dict[str, Any]:
        """The verified figures over all passes (``result.json``'s ``metrics``)."""
        return dict(self._figures()["metrics"])

    @property
    def figures(self) -> Metrics:
        """:attr:`metrics` as a dataclass (:class:`refine.run.typed.Metrics`: fields and units)."""
        return Metrics.from_dict(self._figures()["metrics"])

    @property
    def diagnosis(self) -> list[dict[str, Any]]:
        """Where and why the path had to deviate: ``result.json``'s ``diagnosis``.

        One entry per repaired or infeasible segment (pass, waypoints, arc lengths, the cause with
        its figure, limit and unit, and a suggestion); empty when every pass is ok. The schema is in
        ``docs/outputs.md``.
        """
        return copy.deepcopy(self._figures()["diagnosis"])

    @property
    def findings(self) -> tuple[Diagnosis, ...]:
        """:attr:`diagnosis` as dataclasses (:class:`refine.run.typed.Diagnosis`, its causes typed too)."""
        return tuple(Diagnosis.from_dict(d) for d in self._figures()["diagnosis"])

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

    @checked_call
    def to_dict(self, *, contents: bool = False) -> dict[str, Any]:
        """The ``result.json`` document of this result, as plain Python values.

        Args:
            contents: also carry, under ``"contents"``, every pass's arrays and the text of every
                file :meth:`write` writes but ``result.json`` and the report (the problem's
                programs), so that :meth:`from_dict` rebuilds a result whose :meth:`program`,
                :meth:`pathml` and arrays are this one's.
        """
        if self.run is None:
            doc = copy.deepcopy(self._figures())
            if contents and self._contents is None:
                from refine.run.contents import arrays_from

                arrays_from(None, 0)  # raises: nothing to carry
        else:
            from refine.export.result_json import result_dict

            doc = result_dict(self.run)
        if contents:
            doc["contents"] = copy.deepcopy(self._contents) if self.run is None else self._contents_now()
        return doc

    def _contents_now(self) -> dict[str, Any]:
        from refine.run.contents import contents_dict

        assert self.run is not None
        out = contents_dict(self.run, self._programs(None), self._when())
        out["reasons"] = [p.refinement.reason for p in self.run.passes]
        return out

    @classmethod
    @checked_call
    def from_dict(cls, doc: Mapping[str, Any]) -> Result:
        """Rebuild a result from :meth:`to_dict`'s document (e.g. after JSON across a process boundary).

        Its :meth:`to_dict` equals ``doc``. With ``doc`` from ``to_dict(contents=True)`` it also has
        the arrays and the documents (:meth:`program`, :meth:`pathml`, :meth:`contents`); without,
        those raise :class:`refine.NotExecutable`. It has no :attr:`run` (None) and
        cannot be written or serve as ``previous=``.
        """
        from refine.run.contents import check_doc

        check_doc(doc)
        doc = copy.deepcopy(dict(doc))
        contents = doc.pop("contents", None)
        result = cls(None, doc=doc)
        result._contents = contents
        if contents:
            result._stamp = datetime.fromisoformat(contents["stamp"])
        return result

    def _when(self) -> datetime:
        if self._stamp is None:
            self._stamp = datetime.now(timezone.utc)
        return self._stamp

    def _programs(self, programs: Sequence[str] | None) -> tuple[str, ...]:
        if programs is None:
            if self.run is None:
                return tuple(self._contents["programs"]) if self._contents else ()
            return tuple(self.run.problem.output.programs or (self.run.robot.spec.default_program,))
        from refine.run.contents import check_programs

        return check_programs(programs)

    def _rendered(self, programs: tuple[str, ...]) -> dict[str, tuple[str, bytes]]:
        from refine.run.contents import files_from, render

        if self.run is None:
            return files_from(self._contents)
        if programs not in self._files:
            from refine.run.preflight import check_programs

            with api_words():
                check_programs(self.run.problem, self.run.robot.spec, programs)
                self._files[programs] = render(self.run, programs, self._when())
        return self._files[programs]

    @checked_call
    def program(self, kind: str) -> str:
        """The text of one robot program, as :meth:`write` would write it, without touching the disk.

        Args:
            kind: ``"rapid"``, ``"krl"`` (the ``.src``; ``"krl_dat"`` for the ``.dat``), ``"urscript"``,
                ``"tp"``, ``"inform"`` or ``"sunrise"``; ``"rapid_1"``, ``"rapid_2"``, ... for the
                modules of a multi-pass RAPID program.

        Raises:
            InputError: ``kind`` is not a program format.
            NotExecutable: no program (an infeasible pass or a failed motion), or a result rebuilt
                without this format's text.
        """
        from refine.run.contents import check_kind, pick

        base = check_kind(kind)
        return pick(self._rendered(self._programs(None) if self.run is None else (base,)), kind, self.status)

    @checked_call
    def pathml(self) -> str:
        """The PathML document (``<name>.aml``) as :meth:`write` would write it, without touching the disk."""
        from refine.run.contents import pick

        return pick(self._rendered(self._programs(None) if self.run is None else ()), "pathml", self.status)

    @checked_call
    def contents(self, programs: Sequence[str] | None = None) -> dict[str, str]:
        """File name -> text of every file :meth:`write` writes but ``result.json`` and ``report.html``.

        Args:
            programs: program formats; None for the problem's ``[output] programs``.
        """
        return {
            name: data.decode("utf-8") for name, data in self._rendered(self._programs(programs)).values()
        }

    @checked_call
    def write(
        self, out_dir: str | Path, programs: Sequence[str] | None = None, *, report: bool = True
    ) -> dict[str, Path]:
        """Write the outputs of ``refine run`` into ``out_dir``.

        The documents carry the time stamp of this result's first rendering (this call, or an
        earlier :meth:`program`, :meth:`pathml` or :meth:`contents`), so that they are the same bytes.

        Args:
            out_dir: the folder (created if missing).
            programs: program formats (``"rapid"``, ``"krl"``, ``"urscript"``); None for the
                problem's ``[output] programs``.
            report: also write ``report.html``.

        Returns:
            kind -> path of every file written (``result``, ``trajectory``, ``pathml``, ...).
        """
        from refine.export.sink import stamped
        from refine.run.write import write_run

        require_run(self, "write", "a result rebuilt from a dictionary cannot be written: use contents()")
        chosen = self._programs(programs) if programs is not None else None
        typed(out_dir, "out_dir", (str, Path), "the path of a folder")
        with api_words(), stamped(self._when()):
            write_run(self.run, Path(out_dir), chosen, report=report)
        return dict(self.run.outputs)


@checked_call
def solve(
    problem: Problem | str | Path,
    *,
    initial_joints: ArrayLike | None = None,
    previous: Result | None = None,
    time_limit_s: float | None = None,
    cancel: threading.Event | Callable[[], bool] | None = None,
    progress: Callable[[Progress], Any] | None = None,
    accept_frame_error: bool = False,
) -> Result:
    """Run a problem through every stage up to the verified, timed path, writing no file.

    Args:
        problem: a loaded :class:`~refine.problem.Problem`, or the path of its folder or file.
        initial_joints: joints (N, n) [rad] to start the first pass from instead of the IK seed.
        previous: an earlier result of the same problem with a small change (tolerances, weights):
            its built problem is reused where it can be and its joints are the start.
        time_limit_s: wall-time budget [s] of the whole call, every stage (and instead of ``[repair]
            time_limit_s``); past it the result's status is ``"timeout"`` and ``reason`` and
            ``to_dict()["stopped_stage"]`` name the stage that stopped (docs/api.md, "Time limit").
        cancel: a :class:`threading.Event` (or a callable returning True) that stops the call:
            checked after every stage, every solve -> verify round and every IPOPT iteration; the
            call then raises :class:`refine.Cancelled`. Ctrl-C raises ``KeyboardInterrupt``, also
            from inside IPOPT; neither ever becomes a verdict.
        progress: called with a :class:`refine.control.Progress` after every stage and every IPOPT
            iteration, in the calling thread; what it raises ends the call.
        accept_frame_error: warn instead of stopping when the tracker frame looks wrong.

    Returns:
        The result; ``result.write(out_dir)`` writes the files ``refine run`` writes.
    """
    check_hooks(cancel, progress)
    check_previous(previous, Result)

    def call(problem: Problem | str | Path = problem) -> Result:
        from refine.run.solve import solve_problem  # imported within the call's time limit
        from refine.run.stages import fused_path

        if not isinstance(problem, Problem):
            typed(problem, "problem", (str, Path), "a refine.Problem or the path of a problem folder or file")
            problem = read_problem(problem)
        problem = with_time_limit(problem, time_limit_s)
        if previous is None:
            q0 = joints_from(initial_joints, None, None)
            return Result(solve_problem(problem, q0=q0, accept_frame_error=accept_frame_error))
        fused = fused_path(problem, accept_frame_error=accept_frame_error)
        return Result(solve_again(problem, previous.run.robot, fused, previous.run, initial_joints))

    with api_words(), controlled(cancel, progress, checked_limit(time_limit_s)):
        return timed_call(getattr(problem, "name", Path(str(problem)).name), call, Result)


@checked_call
def load_problem(path: str | Path, *, allow_outside: bool = False) -> Problem:
    """Read a problem folder or ``problem.toml`` (:func:`refine.problem.load_problem`), errors in the API's words.

    Args:
        path: the problem folder, or its TOML file.
        allow_outside: accept data files outside the problem folder.
    """
    with api_words():
        return read_problem(path, allow_outside=allow_outside)


@checked_call
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
        time_limit_s: wall-time budget [s] of the whole call (every stage, not only the solves;
            each pass's refinement also keeps within it instead of ``[repair] time_limit_s``); when
            it runs out the call returns a result with status ``"timeout"`` whose ``reason`` and
            ``to_dict()["stopped_stage"]`` name the stage that stopped (docs/api.md, "Time limit").
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
    from refine.robot.registry import robot_argument
    from refine.run.contents import check_programs

    robot = robot_argument(robot)
    check_hooks(cancel, progress)
    check_previous(previous, Result)
    typed(name, "name", str, "a str (the problem name)")
    typed(tool_name, "tool_name", str, "a str (the tool's name)")
    typed(axisymmetric, "axisymmetric", (bool, np.bool_), "True or False")
    p = finite_array(positions, "positions", "m")
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 3:
        raise InputError(
            f"positions: expected shape (N, 3) [m] with N >= 3, got {p.shape}",
            key="positions",
            value=p.shape,
            expected="shape (N, 3) [m] with N >= 3",
        )
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
            home_deg=home_from(home_deg, robot.nq),
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
            programs=check_programs(programs) if programs is not None else (robot.spec.default_program,)
        ),
        cell=tuple(cell),
        collision=collision or CollisionSettings(),
        optimise=optimise or OptimiseSettings(),
        repair=repair or RepairSettings(),
    )
    with api_words(), controlled(cancel, progress, checked_limit(time_limit_s)):
        problem = with_time_limit(problem, time_limit_s)
        run = previous.run if previous is not None else None
        return timed_call(
            name, lambda: Result(solve_again(problem, robot, fused, run, initial_joints)), Result
        )
