"""What a run produced, in memory: :class:`RunResult` and its :class:`PassResult` per pass.

These types sit below the pipeline and the writers: the pipeline builds them, and the exporters,
the report and the library API read them. This module imports no stage at run time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from refine.optimise.outcome import Refinement
    from refine.paths import ChordError, FusedPath, Trajectory
    from refine.problem import Problem
    from refine.robot.model import Robot
    from refine.run.evaluate import TruthComparison
    from refine.timing import Timing


@dataclass(frozen=True)
class PassResult:
    """One pass of the path: the fused input, its refinement and its timing.

    Attributes:
        name: ``"pass 1"`` for a single pass, ``"layer 2 pass 1"`` in a multi-pass weld.
        layer: 1-based layer number.
        index: 1-based pass number within its layer.
        fused: the pass's fused path.
        refinement: the optimiser's result and its verification.
        timing: the time parameterisation (None when the refinement was infeasible).
        trajectory: the timed path the exporters read (None when infeasible).
        clearance: the dense clearance check of the refined path (None without collision).
        nlp: the pass's refinement problem as built (a ``RefinementNLP``), for re-solving it
            after a small change; None when not kept. Not pickled: its CasADi expressions and
            compiled solver belong to the process that built them, so a pass that crossed a
            process boundary is re-solved from its joints, with the problem built anew.
        line: the controller's straight-line motion between the waypoints, checked
            (:class:`refine.optimise.controller_line.LineCheck`); None when not checked.
        clearance_kinds: the cell pairs' and the self pairs' least distances apart
            (:class:`refine.run.clearance_kinds.KindMinima`); None without collision.
        circular: the circular moves on the CAD's arcs, each checked in every controller's
            orientation model (:class:`refine.optimise.controller_arc.ArcCheck`, ``[output]
            circular_moves``); None when not asked for.
    """

    name: str
    layer: int
    index: int
    fused: FusedPath
    refinement: Refinement
    timing: Timing | None
    trajectory: Trajectory | None
    clearance: Any = None
    nlp: Any = None
    line: Any = None
    clearance_kinds: Any = None
    circular: Any = None

    def __getstate__(self) -> dict[str, Any]:
        return {**self.__dict__, "nlp": None}

    @property
    def cad_chord(self) -> ChordError | None:
        """How far the CAD geometry lies from the straight moves between the reached TCP positions.

        None for a pass without CAD geometry (a path given as arrays, the later passes of a
        multi-pass weld). Measured against the poses the verifier reached (Pinocchio), so an
        error at a waypoint counts as well as the chord between two.
        """
        fused = self.fused
        if fused.exact_s is None or fused.exact is None:
            return None
        from refine.paths import chord_error

        reached = self.refinement.check.poses[:, :3, 3]
        return chord_error(fused.exact_s, fused.exact, fused.s, reached, fused.positions)


@dataclass(frozen=True)
class RunResult:
    """Everything a run produced, in memory.

    Attributes:
        problem: the problem that was run.
        robot: the loaded robot.
        passes: one entry per pass (one for a single-pass path).
        truth: comparison of the first pass with the simulator's truth, when there is one.
        timings_s: wall time per stage [s], summed over passes.
        outputs: kind -> file written.
        demo_quality: the demonstration quality gate's figures (``refine.demo.quality.DemoQuality``),
            None for a path without a demonstration.
        placement: the placement repair (``refine.run.placement.PlacementRepair``) when ``[repair]
            placement`` is set, else None.
        motions: every motion of the program, verified (``refine.plan.motion.Motion``: home,
            approach, path, retract, link, return); empty when a pass is not executable.
    """

    problem: Problem
    robot: Robot
    passes: tuple[PassResult, ...]
    truth: TruthComparison | None
    timings_s: dict[str, float] = field(default_factory=dict)
    outputs: dict[str, Path] = field(default_factory=dict)
    demo_quality: Any = None
    placement: Any = None
    motions: tuple[Any, ...] = ()

    @property
    def failed_motions(self) -> tuple[Any, ...]:
        """The motions that failed their checks (an air move or line that collides or cannot be made)."""
        return tuple(m for m in self.motions if not m.ok)

    @property
    def first(self) -> PassResult:
        """The first (demonstrated) pass."""
        return self.passes[0]

    @property
    def fused(self) -> FusedPath:
        """The first pass's fused path."""
        return self.first.fused

    @property
    def refinement(self) -> Refinement:
        """The first pass's refinement."""
        return self.first.refinement

    @property
    def timing(self) -> Timing | None:
        """The first pass's timing."""
        return self.first.timing

    @property
    def trajectory(self) -> Trajectory | None:
        """The first pass's timed trajectory."""
        return self.first.trajectory

    @property
    def status(self) -> str:
        """The worst pass's status, in the order of :data:`STATUS_ORDER`."""
        statuses = {p.refinement.status for p in self.passes}
        if self.failed_motions:
            return "infeasible"
        return next((s for s in STATUS_ORDER if s in statuses), "ok")


def summary_lines(result: RunResult) -> list[str]:
    """Human-readable summary of a run, for the CLI."""
    lines = [
        f"problem      {result.problem.name}: robot {result.robot.spec.name}, {len(result.passes)} pass(es)"
    ]
    tol = result.problem.tolerances
    for p in result.passes:
        check = p.refinement.check
        head = f"{p.name}: " if len(result.passes) > 1 else ""
        lines += [
            f"status       {head}{p.refinement.status}, {len(p.fused)} waypoints"
            + (f" ({p.refinement.reason})" if p.refinement.reason else ""),
            f"position     max error {check.position_error_m.max():.2e} m (tolerance {tol.position_m:.0e} m)"
            + _chord_text(p, result.problem.cad),
            f"orientation  max deviation from demo {check.orientation_deviation_deg.max():.3f} deg "
            f"(cone {tol.orientation_deg:g} deg)",
            f"joints       min margin to limits {math.degrees(check.joint_margin_rad.min()):.2f} deg",
            f"singularity  min scaled manipulability {check.singularity.min():.4f}, "
            f"min singular value {check.sigma_min.min():.4f}",
        ]
        if p.clearance is not None:
            from refine.optimise.diagnosis import closest_pair_text

            c, col = p.clearance, result.problem.collision
            pair = closest_pair_text(
                c, {o.name for o in result.problem.cell}, col.margin_m, col.self_margin_m
            )
            lines.append(
                f"clearance    min distance {c.min_distance_m * 1e3:.1f} mm"
                + _kinds_text(p.clearance_kinds, col.margin_m, col.self_margin_m)
                + (f", {pair}" if pair else "")
                + f"; checked between waypoints: {c.queries} queries in {c.time_s:.2f} s"
            )
        if p.line is not None:
            lines.append(f"line         {p.line.describe()}" + ("" if p.line.ok else " (broken)"))
        if p.circular and p.trajectory is not None:
            arcs, worst = p.trajectory.arcs, max(c.cad_deviation_m for c in p.circular)
            lines.append(
                f"arcs         {len(arcs)} of {len(p.circular) // 2} circular move(s) written, up to "
                f"{worst * 1e3:.4f} mm from the CAD arc"
            )
        if p.timing is not None:
            lines.append(
                f"timing       cycle {p.timing.cycle_time_s:.2f} s, "
                f"{len(p.timing.slow_segments)} segment(s) slower than the demo"
            )
    for m in result.motions:
        clear = "" if m.min_distance_m is None else f", min distance {m.min_distance_m * 1e3:.1f} mm"
        via = f", {len(m.via)} via points" if len(m.via) else ""
        lines.append(
            f"motion       {m.kind:<8} {m.name}: {m.status}, {m.duration_s:.2f} s, {m.planner}{via}{clear}"
            + (f" ({m.reason})" if m.issues else "")
        )
    if result.placement is not None:
        lines.append(f"placement    {result.placement.describe()}")
    if result.truth is not None:
        lines.append(f"truth        {result.truth.describe()}")
    total = result.timings_s.get("total")
    stages = ", ".join(f"{k} {v:.3f}" for k, v in result.timings_s.items() if k != "total")
    lines.append(f"time [s]     {stages}" + (f"; total {total:.2f}" if total else ""))
    return lines


def _kinds_text(kinds: Any, margin_m: float, self_margin_m: float) -> str:
    """``": cell pairs 12.0 mm (margin 10 mm), self pairs 4.7 mm (self margin 2 mm)"``."""
    if kinds is None:
        return f" (cell margin {margin_m * 1e3:g} mm, self margin {self_margin_m * 1e3:g} mm)"
    parts = [
        f"{what} {'none checked' if d is None else f'{d * 1e3:.1f} mm'} ({label} {m * 1e3:g} mm)"
        for what, d, label, m in (
            ("cell pairs", kinds.cell_m, "margin", margin_m),
            ("self pairs", kinds.self_m, "self margin", self_margin_m),
        )
    ]
    return ": " + ", ".join(parts)


def _chord_text(p: PassResult, cad: Any) -> str:
    chord = p.cad_chord
    if chord is None:
        return ""
    limit = f" (tolerance {cad.chord_tolerance_m * 1e3:g} mm)" if cad is not None else ""
    return f"; from the CAD {chord.max_m * 1e3:.3f} mm{limit} at s = {chord.s_m:.3f} m"


EXECUTABLE = ("ok", "repaired")

STATUS_ORDER = ("infeasible", "timeout", "repaired", "ok")
"""A run's statuses, worst first: a proof that a pass cannot be done outranks a pass that ran out of
time, which outranks a repair."""
