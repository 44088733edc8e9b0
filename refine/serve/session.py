"""The problem being edited in the browser, its warm re-solves (the latest change wins), and writing it.

A :class:`Session` holds the problem file's TOML document as read (or as last saved), the changes
made since, the problem they describe and its last answer. :meth:`Session.change` checks a change
at once (as the problem file would be checked) and hands the new problem to a
:class:`LatestSolver`: one thread that solves one problem at a time and, when it is free, takes
only the newest problem asked for, so a drag that sends many changes never queues stale solves.

A re-solve starts from the previous answer: the fused path is reused when the change leaves the
CAD path and the demonstration alone, moved rigidly when the workpiece moved with its receiver,
and the solve starts as ``refine.solve(..., previous=...)`` does (:mod:`refine.optimise.warm`:
the previous joints moved onto the new poses, the previous last problem and multipliers kept where
robot, base, tool and weights are the same). A solve still running when a newer change comes is
stopped (:func:`refine.control.controlled`). Writing saves the problem
file and runs it as ``refine run`` does (:func:`refine.run.write.run`), from the saved file.
"""

from __future__ import annotations

import difflib
import logging
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import tomlkit

from refine.control import controlled
from refine.errors import Cancelled, InputError
from refine.frames import invert_transform
from refine.optimise.moves import moved_path
from refine.optimise.problem import RefinementNLP, reuse_for
from refine.optimise.warm import WarmStart, built_for
from refine.paths import FusedPath
from refine.problem import Problem, load_problem
from refine.robot.model import Robot
from refine.robot.registry import robot_for
from refine.run.placement import PlacementRepair
from refine.run.result import RunResult
from refine.run.solve import solve_problem
from refine.run.stages import fused_tracks, weights_for
from refine.serve.edits import apply_changes, check_keys

log = logging.getLogger(__name__)

RIGID_ATOL = 1e-5
"""Tolerance on the receiver-to-CAD transform under which a workpiece move keeps the fused path [m, -]:
above the rounding of the poses written into the problem file (:data:`refine.serve.edits.DECIMALS_M`)."""


@dataclass
class Job:
    """One problem to solve: the revision of the changes that made it."""

    revision: int
    problem: Problem
    changes: dict[str, Any]
    asked_s: float = field(default_factory=time.perf_counter)
    solve_s: float = 0.0


class LatestSolver:
    """A thread that solves the newest job asked for; jobs superseded while it was busy are dropped.

    A solve under way when a newer job arrives is stopped too, when ``solve`` asks
    :meth:`superseded` (the session runs it under :func:`refine.control.controlled`, whose cancel
    ends the solve at its next stage or IPOPT iteration with :class:`refine.errors.Cancelled`):
    a cancelled job is counted as dropped and never answered.

    Args:
        solve: solves a job (a :class:`Job`, or any value for another kind of work, such as
            building the scene of an answer); what it returns (or the error it raises) goes to ``done``.
        done: called on the solver's thread with the job and ``(answer, error)``.
        name: the thread's name.
    """

    def __init__(
        self,
        solve: Callable[[Any], Any],
        done: Callable[[Any, Any, BaseException | None], None],
        name: str = "refine-serve-solver",
    ) -> None:
        self._solve, self._done = solve, done
        self._wake = threading.Condition()
        self._pending: Job | None = None
        self._stopping = False
        self.busy = False
        self.solved = 0
        self.dropped = 0
        self.cancelled = 0
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    def submit(self, job: Job) -> None:
        """Ask for ``job``; a job still waiting is replaced (and counted as dropped)."""
        with self._wake:
            if self._pending is not None:
                self.dropped += 1
            self._pending = job
            self._wake.notify()

    def superseded(self) -> bool:
        """Whether a newer job waits than the one being solved (the running solve may stop)."""
        return self._pending is not None or self._stopping

    def idle(self) -> bool:
        """Whether nothing is being solved and nothing waits."""
        with self._wake:
            return not self.busy and self._pending is None

    def stop(self, timeout_s: float = 5.0) -> None:
        """Drop the waiting job and end the thread after the solve under way [s to wait for it]."""
        with self._wake:
            self._stopping = True
            self._pending = None
            self._wake.notify()
        self._thread.join(timeout_s)

    def _loop(self) -> None:
        while True:
            with self._wake:
                while self._pending is None and not self._stopping:
                    self._wake.wait()
                if self._stopping:
                    return
                job, self._pending = self._pending, None
                self.busy = True
            answer, error = None, None
            try:
                answer = self._solve(job)
            except Cancelled:  # a newer job came: it is answered instead
                with self._wake:
                    self.busy = False
                    self.cancelled += 1
                    self.dropped += 1
                continue
            except Exception as e:  # the error goes to the page; the thread keeps serving
                error = e
            with self._wake:
                self.busy = False
                self.solved += 1
            self._done(job, answer, error)


def fusion_inputs(problem: Problem) -> str:
    """What the fused path depends on besides the frames' placement in {F} (compared as text)."""
    return repr((problem.cad, problem.demonstration, np.round(problem.tool.sensor_in_tcp, 12).tolist()))


def _relative(problem: Problem) -> np.ndarray:
    f = problem.frames
    return invert_transform(f.source_in_world) @ f.cad_in_world


class FusedCache:
    """The last fused tracks, reused (or moved rigidly with the workpiece) while their inputs hold.

    A CAD file with several tracks gives one path per track, each solved as a pass as ``refine run``
    solves them (:func:`refine.run.stages.fused_tracks`); the demonstration quality gate's figures
    (``demo_quality``) are kept with them, since a rigid move of the workpiece with its receiver
    leaves the demonstration relative to the CAD path as it was.
    """

    def __init__(self) -> None:
        self._problem: Problem | None = None
        self._key: str | None = None
        self._tracks: list[FusedPath] = []
        self.quality: Any = None
        self.reused = 0
        self.fused = 0

    def tracks_for(self, problem: Problem) -> tuple[list[FusedPath], Any]:
        """The fused path of every track of ``problem`` and the quality gate's figures (or None)."""
        old, key = self._problem, fusion_inputs(problem)
        if old is not None and self._tracks and key == self._key:
            D = problem.frames.cad_in_world @ invert_transform(old.frames.cad_in_world)
            if np.allclose(D, np.eye(4), atol=RIGID_ATOL):
                self.reused += 1
                return self._tracks, self.quality
            pathml = problem.cad is not None and problem.cad.format == "pathml"
            if not pathml and np.allclose(_relative(old), _relative(problem), atol=RIGID_ATOL):
                self.reused += 1
                return [moved_path(f, D) for f in self._tracks], self.quality
        self.fused += 1
        qualities: list[Any] = []
        tracks = fused_tracks(problem, qualities=qualities)
        self._problem, self._key, self._tracks = problem, key, tracks
        self.quality = qualities[0] if qualities else None
        return tracks, self.quality

    def path_for(self, problem: Problem) -> FusedPath:
        """The fused path of ``problem``'s first track (:meth:`tracks_for`)."""
        return self.tracks_for(problem)[0][0]


WARM_MOVE_M = 0.1
"""Farthest a waypoint may have moved since the previous answer for that answer to be the start [m]:
a warm start is for small changes, and a jump beyond it is solved cold at once rather than after a
warm solve that is not ``ok``."""


def near(previous: RunResult, fused: FusedPath) -> bool:
    """Whether ``fused`` has the previous first pass's waypoints, none moved beyond :data:`WARM_MOVE_M`."""
    old = previous.first.fused.positions
    if old.shape != fused.positions.shape:
        return False
    return bool(np.linalg.norm(old - fused.positions, axis=1).max() <= WARM_MOVE_M)


def warm_start(
    previous: RunResult, problem: Problem, robot: Robot, fused: FusedPath
) -> tuple[RefinementNLP | None, WarmStart | None]:
    """The built problem to reuse and the start :func:`resolve` takes from ``previous`` (its docstring).

    The previous last problem and multipliers are kept only with its built problem, which needs the
    same base, tool and weights (:func:`refine.optimise.problem.reuse_for` checks the rest).
    """
    first = previous.first
    built = first.nlp
    setup = built_for(built, problem.robot.base_in_world, problem.tool, weights_for(problem, robot))
    nlp = reuse_for(built, fused, problem.tolerances) if setup else None
    if first.refinement.q.shape != (len(fused), robot.nq):
        return nlp, None
    kept = nlp is not None
    return nlp, WarmStart(
        q=first.refinement.q,
        rotations=first.fused.rotations if len(first.fused) == len(fused) else None,
        problem=first.refinement.problem if kept else None,
        multipliers=first.refinement.multipliers if kept else None,
        clearance=first.clearance,
        line=first.line,
    )


def resolve(
    problem: Problem,
    fused: FusedPath | Sequence[FusedPath],
    previous: RunResult | None,
    quality: Any = None,
) -> RunResult:
    """Solve ``problem`` on ``fused``, from ``previous``'s answer where it applies (module docstring).

    ``fused`` is the first pass's path or the paths of every track of the CAD file (each a pass,
    the first warm-started); ``quality`` the demonstration quality gate's figures kept in the result.

    The start is :class:`refine.optimise.warm.WarmStart`, as ``refine.solve(..., previous=...)``
    re-solves: the previous joints moved onto the new poses and, when robot, base, tool and
    weights are the same, the previous last problem, its multipliers and its clearance bounds.
    Only an ``ok`` answer is a start, and only for a path :func:`near` the one it answered: a
    repaired or failed one holds joints bent by the slack or left where the solver gave up, and a
    path moved far (a jump of the part) is solved as ``refine run`` solves it. The warm solve is
    :func:`strict` (no repair); when it is not ``ok`` the problem is solved again from the IK seed,
    repairs included, and that answer is kept, so a verdict never depends on the changes before it
    (the cold answer is the one ``refine run`` gives) and a change out of reach is repaired once.
    """
    robot = robot_for(problem.robot)
    tracks = [fused] if isinstance(fused, FusedPath) else list(fused)
    fused, given = tracks[0], {"tracks": tracks, "demo_quality": quality}
    if previous is not None and previous.robot is robot and previous.status == "ok" and near(previous, fused):
        nlp, warm = warm_start(previous, problem, robot, fused)
        if warm is not None:
            result = solve_problem(strict(problem), robot=robot, nlp=nlp, warm=warm, **given)
            if result.status == "ok":
                return as_asked(result, problem)
            log.info("serve: the strict warm solve is %s; solving from the IK seed", result.status)
    return solve_problem(problem, robot=robot, **given)


def strict(problem: Problem) -> Problem:
    """``problem`` without its repairs (the slack repair and the placement search): a warm attempt.

    A warm start is kept only when its answer is ``ok``, which needs no repair; a warm attempt that
    repaired would be thrown away and repaired once more from the IK seed.
    """
    return replace(problem, repair=replace(problem.repair, enabled=False, placement=None))


def as_asked(result: RunResult, problem: Problem) -> RunResult:
    """The ``ok`` answer of :func:`strict` ``problem`` as the answer of ``problem``.

    An ``ok`` run needs no repair, so the run of ``problem`` itself gives the same passes; only its
    settings and, with ``[repair] placement``, the placement outcome (``not needed``) are its own.
    """
    bounds = problem.repair.placement
    return replace(result, problem=problem, placement=None if bounds is None else PlacementRepair("not needed", bounds))


@dataclass
class Answer:
    """The last solve: its revision, changes, result or error, and timings [s]."""

    revision: int
    changes: dict[str, Any]
    result: RunResult | None
    error: str | None
    solve_s: float
    latency_s: float


class Session:
    """A problem folder open for editing (module docstring).

    Args:
        folder: the problem folder or its ``problem.toml``.
        on_answer: called (on the solver's thread) with every finished :class:`Answer`.
    """

    def __init__(self, folder: Path, on_answer: Callable[[Answer], None] | None = None) -> None:
        path = Path(folder)
        self.path = (path / "problem.toml" if path.is_dir() else path).resolve()
        self.folder = self.path.parent
        self._lock = threading.Lock()
        self._engine = threading.Lock()  # one solve or write at a time: they share the robot's model
        self._on_answer = on_answer
        self._cache = FusedCache()
        self._load()
        self.revision = 0
        self.answer: Answer | None = None
        self.solver = LatestSolver(self._solve, self._finished)

    def _load(self) -> None:
        self.problem = load_problem(self.path)  # checks the file as `refine run` does
        self.text = self.path.read_text(encoding="utf-8")
        self.base = tomlkit.parse(self.text)
        self.doc = self.base
        self.changes: dict[str, Any] = {}

    def on_answer(self, callback: Callable[[Answer], None]) -> None:
        """Call ``callback`` (on the solver's thread) with every finished :class:`Answer`."""
        self._on_answer = callback

    def start(self) -> None:
        """Solve the problem as loaded (revision 0)."""
        self.solver.submit(Job(self.revision, self.problem, {}))

    def change(self, changes: Mapping[str, Any]) -> int:
        """Merge ``changes`` into the session's changes, check them and ask for a solve.

        The edited values are compared as the page sent them (plain numbers and lists): a change
        that leaves every one as it was (a drag's last pose sent again on release, a field left
        as it was) is neither checked nor solved again, and its revision is the current one.

        Returns:
            The new revision (the current one when nothing changed).

        Raises:
            InputError: a key the page may not change or a value the problem file would refuse;
                the session is left as it was.
        """
        check_keys(changes)
        with self._lock:
            merged = {**self.changes, **changes}
            if merged == self.changes:
                return self.revision
            doc, problem = apply_changes(self.base, merged, self.path)
            self.revision += 1
            self.changes, self.doc, self.problem = merged, doc, problem
            job = Job(self.revision, problem, dict(merged))
        self.solver.submit(job)
        return job.revision

    def reset(self) -> int:
        """Drop every change since the file was read or saved and solve it again."""
        with self._lock:
            self.revision += 1
            self.changes, self.doc = {}, self.base
            self.problem = load_problem(self.path)
            job = Job(self.revision, self.problem, {})
        self.solver.submit(job)
        return job.revision

    def _solve(self, job: Job) -> RunResult:
        previous = self.answer.result if self.answer is not None else None
        t0 = time.perf_counter()
        with self._engine, controlled(cancel=self.solver.superseded):
            try:
                tracks, quality = self._cache.tracks_for(job.problem)
                return resolve(job.problem, tracks, previous, quality)
            finally:
                job.solve_s = time.perf_counter() - t0

    def _finished(self, job: Job, result: RunResult | None, error: BaseException | None) -> None:
        now = time.perf_counter()
        if error is not None and not isinstance(error, InputError):
            log.exception("serve: the solve of revision %d failed", job.revision, exc_info=error)
        message = None
        if error is not None:
            message = str(error) if isinstance(error, InputError) else f"{type(error).__name__}: {error}"
        answer = Answer(
            job.revision,
            job.changes,
            result if error is None else (self.answer.result if self.answer else None),
            message,
            job.solve_s,
            now - job.asked_s,
        )
        if error is None:
            self.answer = answer
        if self._on_answer is not None:
            self._on_answer(answer)

    def current_text(self) -> str:
        """The problem file as it would be saved."""
        with self._lock:
            return tomlkit.dumps(self.doc)

    def diff(self) -> str:
        """The unified diff from the file on disk to the problem file as it would be saved."""
        saved = self.path.read_text(encoding="utf-8")
        return "".join(
            difflib.unified_diff(
                saved.splitlines(keepends=True),
                self.current_text().splitlines(keepends=True),
                fromfile="problem.toml (on disk)",
                tofile="problem.toml (in the app)",
            )
        )

    def _replace_file(self, text: str) -> None:
        tmp = self.path.with_name(f".{self.path.name}.saving")
        tmp.write_text(text, encoding="utf-8")
        tmp.replace(self.path)  # a reader never sees half a file

    def save(self) -> Path:
        """Write the problem file with the changes (comments and order kept) and make it the base."""
        text = self.current_text()
        self._replace_file(text)
        with self._lock:
            self.text = text
            self.base = tomlkit.parse(text)
            self.doc = self.base
            self.changes = {}
        return self.path

    def write(self, out_dir: Path) -> RunResult:
        """Save the problem file and write every output into ``out_dir`` as ``refine run`` does.

        The saved file is read back and run by :func:`refine.run.write.run`, the function behind
        ``refine run``, so the files are those the command would write (all or nothing). When the
        run raises, the problem file is put back as it was and the changes are kept, so the file
        and the outputs never disagree.
        """
        from refine.run.write import run

        with self._engine:
            on_disk = self.path.read_text(encoding="utf-8")
            with self._lock:
                kept = (self.text, self.base, self.doc, dict(self.changes))
            self.save()
            try:
                return run(load_problem(self.path), out_dir)
            except BaseException:
                self._replace_file(on_disk)
                with self._lock:
                    self.text, self.base, self.doc, self.changes = kept
                raise

    def close(self) -> None:
        """Stop the solver thread."""
        self.solver.stop()
