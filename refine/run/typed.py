"""Typed views of ``result.json``'s figures: the metrics and the diagnosis as dataclasses.

:class:`Metrics` holds ``result.json``'s ``metrics`` (and each pass's), :class:`Diagnosis` one entry
of its ``diagnosis`` with its :class:`DiagnosisCause` list. Both are read from the document, so a
result rebuilt from its dictionary (``refine.Result.from_dict``) has the same views as the original.
The field names and units are those of ``docs/outputs.md``; ``None`` where the figure does not
apply (no cell, no timing, no CAD).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from refine.arguments import settings_from
from refine.errors import InputError
from refine.types import Array


@dataclass(frozen=True)
class Metrics:
    """The verified figures of a run (worst over passes) or of one pass.

    Attributes:
        max_position_error_m: largest TCP position error [m].
        max_cad_chord_error_m: largest distance of the CAD geometry from the straight moves [m].
        max_orientation_deviation_deg: largest deviation from the demonstrated orientation [deg].
        mean_orientation_deviation_deg: its mean over the waypoints [deg].
        max_slack_deg: largest extra orientation slack a repair used [deg].
        min_joint_margin_rad: least distance of a joint from its limit [rad].
        min_singularity_measure: least scaled manipulability [-].
        min_singular_value: least singular value of the Jacobian [-].
        min_clearance_m: least distance of any checked pair [m], a cell pair or a self pair.
        min_cell_clearance_m: least distance between the robot or tool and a cell object [m]:
            the figure to compare with the cell margin.
        min_self_clearance_m: least distance between robot links and tool shapes among
            themselves [m]: the figure to compare with the self margin.
        cycle_time_s: time of the timed path [s] (summed over passes).
        speed_tracking_error_rel: how far the planned speed falls short of the demonstration [-].
        fusion_residual_median_m: median residual of the fused path [m].
    """

    max_position_error_m: float | None = None
    max_cad_chord_error_m: float | None = None
    max_orientation_deviation_deg: float | None = None
    mean_orientation_deviation_deg: float | None = None
    max_slack_deg: float | None = None
    min_joint_margin_rad: float | None = None
    min_singularity_measure: float | None = None
    min_singular_value: float | None = None
    min_clearance_m: float | None = None
    min_cell_clearance_m: float | None = None
    min_self_clearance_m: float | None = None
    cycle_time_s: float | None = None
    speed_tracking_error_rel: float | None = None
    fusion_residual_median_m: float | None = None

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> Metrics:
        """The metrics of a ``metrics`` mapping; a key this class does not know is an InputError."""
        return settings_from(doc, cls, "metrics")


@dataclass(frozen=True)
class DiagnosisCause:
    """One cause measured in a diagnosed segment (``diagnosis[].causes[]`` of ``result.json``).

    Attributes:
        cause: ``"reach"``, ``"joint limit"``, ``"joint wrap"``, ``"joint step"``, ``"singularity"``,
            ``"collision"``, ``"self-collision"`` or ``"orientation"``.
        figure: the worst value the demonstration asks for, in ``unit`` (None: no figure).
        limit: the bound it breaks, in ``unit``.
        unit: ``"m"``, ``"deg"`` or ``"-"``.
        objects: the two bodies of a collision pair, else empty.
        joint: 1-based joint of a joint limit or wrap, else None.
        explains_deg: the orientation change this cause alone asks for [deg]; None when no
            orientation change is enough.
        suggestion: what would fix it, in words with figures.
        in_answer: measured at the repaired answer (a constraint at its bound there), not at the
            demonstrated orientation.
        waypoints: for a cause in the answer, the runs (first, last inclusive) of waypoints where
            it is at its bound; else empty.
    """

    cause: str
    figure: float | None
    limit: float | None
    unit: str
    objects: tuple[str, ...] = ()
    joint: int | None = None
    explains_deg: float | None = None
    suggestion: str = ""
    in_answer: bool = False
    waypoints: tuple[tuple[int, int], ...] = ()

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> DiagnosisCause:
        """A cause from its ``result.json`` entry."""
        cause = settings_from(doc, cls, "diagnosis.causes[]")
        spans = tuple((int(a), int(b)) for a, b in cause.waypoints)
        return dataclasses.replace(cause, objects=tuple(cause.objects), waypoints=spans)


@dataclass(frozen=True)
class Diagnosis:
    """A segment of a pass that needed extra orientation slack or has no answer, and why.

    Attributes:
        pass_name: the pass (``"pass 1"``, ``"layer 2 pass 1"``).
        status: ``"repaired"`` or ``"infeasible"``.
        index_start, index_end: first and last waypoint of the segment (inclusive).
        s_start_m, s_end_m: their arc lengths [m].
        slack_deg: the largest extra orientation slack used [deg] when repaired, else None.
        causes: every cause measured there, the one that explains most first.
    """

    pass_name: str
    status: str
    index_start: int
    index_end: int
    s_start_m: float
    s_end_m: float
    slack_deg: float | None
    causes: tuple[DiagnosisCause, ...]

    @property
    def cause(self) -> DiagnosisCause:
        """The cause that explains most (the entry's own fields in ``result.json``)."""
        return self.causes[0]

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> Diagnosis:
        """An entry of ``result.json``'s ``diagnosis``."""
        try:
            return cls(
                pass_name=doc["pass"],
                status=doc["status"],
                index_start=int(doc["index_start"]),
                index_end=int(doc["index_end"]),
                s_start_m=float(doc["s_start_m"]),
                s_end_m=float(doc["s_end_m"]),
                slack_deg=doc["slack_deg"],
                causes=tuple(DiagnosisCause.from_dict(c) for c in doc["causes"]),
            )
        except KeyError as e:
            raise InputError(
                f"diagnosis entry: missing {e.args[0]!r}",
                key=f"diagnosis.{e.args[0]}",
                expected="a field of it",
            ) from e


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
