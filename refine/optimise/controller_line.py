r"""The motion a controller runs between two path targets: a straight TCP line, checked.

The programs move between path targets with Cartesian linear moves (RAPID ``MoveL``, KRL ``LIN``,
URScript ``movel``): the TCP runs on the straight line between the two targets and the orientation
is interpolated between theirs. The joints follow from the controller's inverse kinematics along
that line, not from a linear interpolation of the joints. This module models that motion and
checks it.

**The model** (per controller family in ``docs/outputs.md``), for t in [0, 1] between targets k
and k+1 with poses (p_k, R_k) and (p_{k+1}, R_{k+1}):

* position ``p(t) = p_k + t (p_{k+1} - p_k)``;
* orientation ``R(t) = R_k exp(t log(R_kᵀ R_{k+1}))``, the shortest rotation at a constant rate
  (quaternion slerp; :data:`SLERP`);
* inside a run the programs hand to the controller's wrist-singularity handling (RAPID
  ``SingArea \Wrist``, KRL ``$ORI_TYPE = #JOINT``; :data:`WRIST`), the controller gives up the
  exact orientation and moves the wrist in joint space: there the orientation is the joint-linear
  one, ``R(q_k + t (q_{k+1} - q_k))``, and the position still the line's.

**The check** (:func:`check_controller_lines`): every segment is sampled at ``t = i/m``
(``m`` even and >= :data:`MIN_SAMPLES`, more where a joint moves more than
:data:`MAX_SAMPLE_STEP_DEG` between samples); the joints at each sample are solved by damped least squares from the joint-linear
interpolation (moved by one Newton step, :func:`refine.optimise.line_start.newton_start`; on a
re-solve, where the waypoints barely moved, plus the previous answer's bow at the same sample,
:func:`refine.optimise.line_start.previous_bows`), without a pull to mid-range, so they stay on the refined joints' branch (as the
controller's IK from its current joints). At every sample: the IK's residual, the joint-limit
margins (kept to the full ``joint_margin_deg``, less the waypoint check's 1e-7 rad of rounding),
the singularity measure (to the full ``singularity_margin``, less 1e-9). The clearance is proved along the joint path through the
waypoints and the samples (the collision model's motion bound, :func:`refine.collision.check.margins_proved`),
and where the proof falls short that path is checked densely and its breaks reported. The figures
compare the two motions: the distance of the joint-linear TCP from the straight line, the angle
between the two orientations, the difference of the joints at equal t and what that difference can
change any clearance by, ``|q_line(t) - q_lin(t)| @ R`` with ``R`` the joints' reach
(:func:`refine.collision.check.joint_reach`): no point of the robot or tool is further apart
between the two motions at equal t.

**Fed back to the refinement** (:class:`ControllerLineSource`): the line's joints bow away from the
joint-linear ones by about the square of the step (1e-6 rad at 1 mm spacing), so a refinement that
holds its waypoints exactly at a joint limit's margin or at the singularity margin (an active
bound) has a line that dips just below it. The source checks the line of every answer the
refinement's rounds verify and, where the line breaks a joint margin or the singularity margin,
adds linear rows at the offending samples (:func:`line_rows`), and the rounds solve again from the
answer, so the verified path keeps the full margins on the controller's line.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from refine.optimise.line_ik import joint_linear, line_manipulability, segment_starts, solve_line
from refine.optimise.line_start import largest_per_row
from refine.optimise.problem import LinearRow
from refine.optimise.verify import Violation, runs
from refine.robot.kinematics import TcpKinematics
from refine.settings import Tolerances
from refine.types import Array

SLERP = "slerp"
"""Orientation model: shortest rotation between the two targets at a constant rate."""
WRIST = "wrist"
"""Orientation model inside a wrist-singularity run: the joint-linear wrist's orientation."""

MIN_SAMPLES = 8
"""Sub-steps per segment at least (7 samples inside it)."""
MAX_SAMPLE_STEP_DEG = 0.5
"""More sub-steps where a joint moves more than this between two samples [deg]."""
IK_TOLERANCE = 1e-9
"""Pose error [m and rad stacked] the IK along the line must reach."""
JOINT_TOLERANCE_RAD = 1e-7
"""Rounding a joint margin on the line may show [rad], as the waypoints' check allows."""
SINGULARITY_TOLERANCE = 1e-9
"""Rounding the singularity measure on the line may show [-], as the waypoints' check allows."""
SINGULARITY_HEADROOM = 1e-6
"""A singularity row asks for this much more than the margin [-]: the measure is linearised at the
line's sample, so the answer's measure differs from the row's by the square of its change."""
GRADIENT_STEP_RAD = 1e-7
"""Forward-difference step of the singularity measure's gradient [rad]."""
IK_FAILED = 1e-6
"""A sample whose IK stays further than this from the line [m and rad stacked] has no answer."""


@dataclass(frozen=True)
class LineCheck:
    """The controller's straight-line motion of a joint path, checked and compared with the joint-linear one.

    Attributes:
        samples: sub-steps per segment, (N-1,).
        t: parameter of every sample inside its segment, (M,).
        segment: segment of every sample, (M,).
        q: joints of every sample by IK along the line [rad], (M, n).
        ik_error: IK residual per sample [m and rad stacked], (M,).
        position_difference_m: per segment, the largest distance of the joint-linear TCP from the
            straight line [m], (N-1,).
        orientation_difference_deg: per segment, the largest angle between the joint-linear and the
            controller's orientation at equal t [deg], (N-1,).
        joint_difference_deg: per segment, the largest joint difference of the two motions at equal
            t [deg], (N-1,).
        joint_margin_rad: per segment, the least joint-limit margin on the line [rad], (N-1,).
        singularity: per segment, the least scaled manipulability on the line [-], (N-1,).
        clearance_m: per segment, the least clearance on the line by the dense check [m], (N-1,);
            None when the motion bound proved every margin (or without a collision check).
        clearance_proved: the motion bound proved every margin along the line's joint path; None
            without a collision check.
        clearance_change_m: per segment, the largest change of any clearance between the
            joint-linear motion and the line's at equal t (the joint difference times the joints'
            reach) [m], (N-1,); None without a collision check.
        violations: what the line breaks (empty when it passes).
        start_correction: per sample, what the IK changed its Newton start by [rad], (M, n), a row
            NaN where it started from a previous line's bow, for a re-solve's start
            (:func:`refine.optimise.line_start.previous_corrections`); None when not recorded.
        bow: per sample, the joint difference of the two motions ``|q - q_lin|`` [rad], (M, n),
            for a later check of the same joints (``check_controller_lines(..., known=)``); None
            for a check that took its IK from such a one.
        joint_margins_rad: per segment and joint, the least joint-limit margin on the line [rad],
            (N-1, n), likewise.
    """

    samples: Array
    t: Array
    segment: Array
    q: Array
    ik_error: Array
    position_difference_m: Array
    orientation_difference_deg: Array
    joint_difference_deg: Array
    joint_margin_rad: Array
    singularity: Array
    clearance_m: Array | None
    clearance_proved: bool | None
    clearance_change_m: Array | None
    violations: tuple[Violation, ...]
    start_correction: Array | None = None
    bow: Array | None = field(default=None, repr=False)
    joint_margins_rad: Array | None = field(default=None, repr=False)

    @property
    def ok(self) -> bool:
        """True when the controller's line breaks no tolerance."""
        return not self.violations

    def as_json(self, joint_linear_clearance_m: Array | None = None) -> dict:
        """The figures ``result.json`` writes (``passes[i].line``).

        Args:
            joint_linear_clearance_m: the least clearance per segment of the joint-linear motion
                [m], (N-1,), for the bound on the line's (less ``clearance_change_m``); None to
                leave it out.
        """
        least_clearance = None
        if joint_linear_clearance_m is not None and self.clearance_change_m is not None:
            least_clearance = float(np.min(np.asarray(joint_linear_clearance_m) - self.clearance_change_m))
        if self.clearance_m is not None:
            least_clearance = float(self.clearance_m.min())
        return {
            "ok": self.ok,
            "samples": int(len(self.t)),
            "max_position_difference_m": float(self.position_difference_m.max(initial=0.0)),
            "max_orientation_difference_deg": float(self.orientation_difference_deg.max(initial=0.0)),
            "max_joint_difference_deg": float(self.joint_difference_deg.max(initial=0.0)),
            "max_ik_error": float(self.ik_error.max(initial=0.0)),
            "min_joint_margin_rad": float(self.joint_margin_rad.min(initial=np.inf)),
            "min_singularity_measure": float(self.singularity.min(initial=np.inf)),
            "clearance_proved": self.clearance_proved,
            "max_clearance_change_m": (
                None if self.clearance_change_m is None else float(self.clearance_change_m.max(initial=0.0))
            ),
            "min_clearance_m": least_clearance,
            "violations": [v.describe() for v in self.violations],
        }

    def describe(self) -> str:
        """One line: the largest differences to the joint-linear motion."""
        return (
            f"controller line vs joint-linear: {self.position_difference_m.max(initial=0.0) * 1e3:.4f} mm, "
            f"{self.orientation_difference_deg.max(initial=0.0):.4f} deg orientation, "
            f"{self.joint_difference_deg.max(initial=0.0):.4f} deg joints"
        )


def sample_parameters(q: Array) -> tuple[Array, Array, Array]:
    """Sub-steps per segment (N-1,), and each inner sample's segment (M,) and parameter t (M,)."""
    dq = np.degrees(np.abs(np.diff(q, axis=0))).max(axis=1)
    m = np.maximum(MIN_SAMPLES, np.ceil(dq / MAX_SAMPLE_STEP_DEG)).astype(int)
    m += m % 2  # even: the midpoint, where a segment's two motions are furthest apart, is a sample
    segment = np.repeat(np.arange(len(m)), m - 1)
    first = np.concatenate([[0], np.cumsum(m - 1)[:-1]])
    t = (np.arange(len(segment)) - first[segment] + 1) / m[segment]
    return m, segment, t


def segment_margins(q_line: Array, first: Array, lower: Array, upper: Array) -> Array:
    """Per segment and joint, the least joint-limit margin ``min(q - lower, upper - q)`` of the samples [rad], (N-1, n).

    From each segment's least and largest joint (``first``: each segment's first sample, the
    samples segment after segment): a rounded difference is monotonic in its operands, so the
    least margin to a limit is the margin of the sample nearest it, to the bit.
    """
    q_t = q_line.T  # the reductions run along each joint's row
    least = np.minimum.reduceat(q_t, first, axis=1).T
    most = np.maximum.reduceat(q_t, first, axis=1).T
    return np.minimum(least - lower, upper - most)


def through_samples(q: Array, q_line: Array, m: Array, segment: Array, t: Array) -> tuple[Array, Array]:
    """The joint path through every waypoint and every sample in order, and each row's place ``k + t``.

    Args:
        q: the waypoints' joints [rad], (N, n).
        q_line: the samples' joints [rad], (M, n), segment after segment as
            :func:`sample_parameters` puts them (``m - 1`` inside segment k).
        m: sub-steps per segment, (N-1,).
        segment: each sample's segment, (M,).
        t: each sample's parameter in (0, 1), (M,).

    Returns:
        The joints (N + M, n) [rad] (waypoint k, then segment k's samples, then waypoint k+1) and
        each row's place along ``q`` in segments (N + M,).
    """
    at_waypoint = np.concatenate([[0], np.cumsum(m)])  # waypoint k: k + its earlier segments' samples
    at_sample = np.ones(len(segment) + len(q), dtype=bool)
    at_sample[at_waypoint] = False
    dense = np.empty((len(at_sample), q.shape[1]))
    dense[at_waypoint], dense[at_sample] = q, q_line
    place = np.empty(len(at_sample))
    place[at_waypoint], place[at_sample] = np.arange(len(q), dtype=float), segment + t
    return dense, place


def _segment_max(values: Array, segment: Array, count: int, initial: float) -> Array:
    out = np.full(count, initial)
    np.maximum.at(out, segment, values)
    return out


def _segment_min(values: Array, segment: Array, count: int) -> Array:
    out = np.full(count, np.inf)
    np.minimum.at(out, segment, values)
    return out


def check_controller_lines(
    kin: TcpKinematics,
    q: Array,
    s: Array,
    tolerances: Tolerances,
    *,
    wrist: Array | None = None,
    clearance: Callable[[Array], tuple[Array | None, float]] | None = None,
    reach: Array | None = None,
    known: LineCheck | None = None,
    previous: tuple[Array, LineCheck] | None = None,
) -> LineCheck:
    """Check the controller's straight-line motion between the waypoints of joint path ``q``.

    Args:
        kin: TCP kinematics of the robot, base and tool.
        q: refined joints per waypoint [rad], (N, n).
        s: arc length per waypoint [m], (N,) (for the violations).
        tolerances: joint margin and singularity margin to keep on the line.
        wrist: per segment, True where the program hands the wrist to the controller's singularity
            handling (orientation joint-linear), (N-1,); None for nowhere.
        clearance: the clearance check of a joint path: joints (K, n) [rad] and each row's place
            along ``q`` in segments (K,) (``k + t``, waypoint k at ``t = 0``) -> None when every
            margin is proved kept, else the least clearance per segment of that path by the dense
            check [m] (K-1,); and the tolerance a clearance may fall below 0 [m]. None without a
            collision check.
        reach: per joint, the largest distance of any robot or tool point from its axis [m], (n,),
            for ``clearance_change_m``; None without a collision check.
        known: a check of the same joints ``q`` with the same kinematics and ``wrist`` (e.g. the
            refinement's own of its answer, :meth:`ControllerLineSource.checked`): its line joints,
            IK residuals and singularity measures are the same function of the same arguments, so
            they are taken as they are, with its per-segment differences to the joint-linear
            motion, and only the limits, the violations (at ``s``) and the clearance are done
            (with its bows and joint margins too where it recorded them for as many sub-steps per
            segment); None to solve the line's IK.
        previous: a previous answer's joints (N, n) [rad] and its line check (a re-solve's): its
            bows ``q_line - q_lin`` start the IK at the samples it has
            (:func:`refine.optimise.line_start.previous_bows`), which then converges to the same
            tolerance (:data:`IK_TOLERANCE`); None for none.

    Returns:
        The per-segment figures and the violations.
    """
    q = np.asarray(q, dtype=float)
    n_seg = len(q) - 1
    wrist = np.zeros(n_seg, dtype=bool) if wrist is None else np.asarray(wrist, dtype=bool)
    m, segment, t = sample_parameters(q)
    spec = kin.robot.spec
    first = segment_starts(segment)
    bow = joint_margins = q_lin = None
    reused: LineCheck | None = None  # a check whose bows and margins are this one's
    taken = False  # the IK taken from ``known``, not solved
    if known is not None and known.q.shape == (len(t), q.shape[1]):
        taken = True
        q_line, err, sing_seg = known.q, known.ik_error, known.singularity
        off_seg, angle_seg = known.position_difference_m, known.orientation_difference_deg
        correction = known.start_correction
        if known.bow is not None and known.joint_margins_rad is not None and np.array_equal(known.samples, m):
            # the same samples of the same joints: its bows and margins are these, to the bit
            bow, joint_margins, reused = known.bow, known.joint_margins_rad, known
    else:
        q_lin = joint_linear(q, segment, t)
        q_line, err, correction, sing_seg, off_seg, angle_seg = solve_line(
            kin, q, m, segment, t, wrist, IK_TOLERANCE, previous, q_lin
        )
    if bow is None:
        bow = np.abs(q_line - (joint_linear(q, segment, t) if q_lin is None else q_lin))
        joint_margins = segment_margins(q_line, first, spec.lower, spec.upper)  # per segment and joint

    violations: list[Violation] = []

    def add(bad: Array, reason: str, values: Array, unit: str, limit: float, worst_is_max: bool) -> None:
        for i, j in runs(bad):
            part = values[i : j + 1]
            part = part[np.isfinite(part)]
            worst = float(part.max() if worst_is_max else part.min()) if part.size else math.nan
            violations.append(Violation(i, j, float(s[i]), float(s[j]), reason, worst, unit, limit))

    ik_worst = np.maximum.reduceat(err, first)
    add(ik_worst > IK_FAILED, "no IK on the controller's line", ik_worst, "m+rad", IK_FAILED, True)
    margin = math.radians(tolerances.joint_margin_deg) - JOINT_TOLERANCE_RAD
    for j in range(q.shape[1]):
        add(
            joint_margins[:, j] < margin,
            f"joint limit on the controller's line (joint {j + 1})",
            joint_margins[:, j],
            "rad",
            margin,
            False,
        )
    sing_tol = tolerances.singularity_margin - SINGULARITY_TOLERANCE
    add(
        sing_seg < sing_tol,
        "singularity on the controller's line",
        sing_seg,
        "-",
        tolerances.singularity_margin,
        False,
    )

    clear = change = proved = None
    if reach is not None:
        change = np.maximum.reduceat(bow @ np.asarray(reach, dtype=float), first)
    if clearance is not None:
        dense, dense_seg = through_samples(q, q_line, m, segment, t)
        per_dense, tolerance_m = clearance(dense, dense_seg)
        proved = per_dense is None
    if clearance is not None and per_dense is not None:
        owner = np.minimum(np.floor(dense_seg[:-1]).astype(int), n_seg - 1)  # each dense step's segment
        clear = _segment_min(per_dense, owner, n_seg)
        add(clear < -tolerance_m, "clearance on the controller's line", clear, "m", -tolerance_m, False)
    return LineCheck(
        samples=m,
        t=t,
        segment=segment,
        q=q_line,
        ik_error=err,
        position_difference_m=off_seg,
        orientation_difference_deg=angle_seg,
        joint_difference_deg=(
            np.degrees(np.maximum.reduceat(largest_per_row(bow), first))
            if reused is None
            else reused.joint_difference_deg
        ),
        joint_margin_rad=joint_margins.min(axis=1) if reused is None else reused.joint_margin_rad,
        singularity=sing_seg,
        clearance_m=clear,
        clearance_proved=proved,
        clearance_change_m=change,
        violations=tuple(violations),
        start_correction=correction,
        bow=None if taken else bow,  # only a check that solved its IK serves a later one as known
        joint_margins_rad=None if taken else joint_margins,
    )


LINE_LABEL = "controller line"
"""The label every row of :func:`line_rows` starts with."""

LINE_REASONS = ("joint limit on the controller's line", "singularity on the controller's line")
"""The violations of the line the refinement's rows can mend (the others the final check reports)."""


def line_rows(kin: TcpKinematics, q: Array, line: LineCheck, tolerances: Tolerances) -> tuple[LinearRow, ...]:
    """Linear rows on the joints that keep the controller's line of ``q`` at the full margins.

    At a sample at ``t`` inside segment ``k`` the line's joints are the joint-linear ones
    ``q_lin = (1-t) q_k + t q_{k+1}`` plus the bow ``d = q_line - q_lin``, which a small change of
    the waypoints leaves the same to first order. So, for every sample that breaks a margin:

    * joint j under its lower limit's margin: ``q_lin_j >= lower_j + margin - d_j``
      (above the upper one: ``-q_lin_j >= -(upper_j - margin - d_j)``);
    * singularity measure ``w`` under ``singularity_margin``: ``w`` linearised at the sample,
      ``∇w · q_lin >= margin + headroom - w(q_line) + ∇w · q_lin``
      (:data:`SINGULARITY_HEADROOM`; ``∇w`` by forward differences).

    Args:
        kin: TCP kinematics.
        q: the joints whose line was checked [rad], (N, n).
        line: its check (:func:`check_controller_lines`).
        tolerances: the margins.

    Returns:
        The rows, labelled ``controller line ...`` (a later round's row at the same sample and
        label replaces this one).
    """
    spec = kin.robot.spec
    q = np.asarray(q, dtype=float)
    seg, t = line.segment, line.t
    q_lin = q[seg] + t[:, None] * (q[seg + 1] - q[seg])
    bow = line.q - q_lin
    margin = math.radians(tolerances.joint_margin_deg)
    rows: list[LinearRow] = []
    n = q.shape[1]
    for j in range(n):
        e = np.zeros(n)
        e[j] = 1.0
        for i in np.flatnonzero(line.q[:, j] - spec.lower[j] < margin - JOINT_TOLERANCE_RAD):
            lower = spec.lower[j] + margin - bow[i, j]
            rows.append(
                LinearRow(int(seg[i]), float(t[i]), e, float(lower), f"{LINE_LABEL} joint {j + 1} lower")
            )
        for i in np.flatnonzero(spec.upper[j] - line.q[:, j] < margin - JOINT_TOLERANCE_RAD):
            lower = -(spec.upper[j] - margin - bow[i, j])
            rows.append(
                LinearRow(int(seg[i]), float(t[i]), -e, float(lower), f"{LINE_LABEL} joint {j + 1} upper")
            )
    sing_limit = tolerances.singularity_margin - SINGULARITY_TOLERANCE
    if tolerances.singularity_margin > 0 and (line.singularity < sing_limit).any():
        # only the segments whose least measure (the same function of the same joints) is low
        # hold a sample under the margin
        near = np.flatnonzero(line.singularity[seg] < sing_limit)
        w = np.full(len(t), np.inf)
        w[near] = line_manipulability(kin, kin.jacobians(line.q[near]))
        low = np.flatnonzero(w < sing_limit)
        if low.size:
            at = line.q[low]
            stepped = (at[:, None, :] + GRADIENT_STEP_RAD * np.eye(n)[None]).reshape(-1, n)
            w_step = line_manipulability(kin, kin.jacobians(stepped))
            grad = (w_step.reshape(len(low), n) - w[low, None]) / GRADIENT_STEP_RAD
            for g, i in zip(grad, low, strict=True):
                lower = tolerances.singularity_margin + SINGULARITY_HEADROOM - w[i] + float(g @ q_lin[i])
                rows.append(LinearRow(int(seg[i]), float(t[i]), g, float(lower), f"{LINE_LABEL} singularity"))
    return tuple(rows)


@dataclass
class ControllerLineSource:
    """The controller's line as a constraint source of the refinement's rounds.

    Each answer the rounds verify is checked on the controller's line (joint margins, singularity;
    the clearance and the IK are the final check's, :func:`check_controller_lines` with a
    collision check); a break is a violation of that answer, and :func:`line_rows` are the rows
    the next round adds. Rows are made only for an answer whose violations were asked for (not
    for the seed, whose line means nothing yet).

    Attributes:
        kin: TCP kinematics of the robot, base and tool.
        tolerances: the margins to keep.
        wrist: joints (N, n) -> per segment, True where the program hands the wrist to the
            controller (see :func:`check_controller_lines`); None for nowhere.
        checks: lines checked, for the figures (how many rounds looked at the line).
        previous: a previous answer's joints (N, n) [rad] and line check, whose bows and start
            corrections start the line's IK (``check_controller_lines(..., previous=)``) until the
            source has checked an answer of as many waypoints itself (the rounds' previous answer,
            whose line then starts the next); None for none.
    """

    kin: TcpKinematics
    tolerances: Tolerances
    wrist: Callable[[Array], Array] | None = None
    checks: int = 0
    previous: tuple[Array, LineCheck] | None = None
    _last: tuple[Array, LineCheck] | None = None
    _last_wrist: Array | None = None

    def _check(self, q: Array) -> LineCheck:
        q = np.asarray(q, dtype=float)
        if self._last is not None and self._last[0].shape == q.shape and np.array_equal(self._last[0], q):
            return self._last[1]
        s = np.arange(len(q), dtype=float)
        wrist = (
            np.zeros(len(q) - 1, dtype=bool) if self.wrist is None else np.asarray(self.wrist(q), dtype=bool)
        )
        # the rounds' previous answer is nearer than a previous call's: its line starts this one's IK
        near = self._last if self._last is not None and self._last[0].shape == q.shape else self.previous
        line = check_controller_lines(self.kin, q, s, self.tolerances, wrist=wrist, previous=near)
        self.checks += 1
        self._last, self._last_wrist = (q.copy(), line), wrist
        return line

    def checked(self, q: Array, kin: TcpKinematics, wrist: Array) -> LineCheck | None:
        """This source's line check of joints ``q`` (N, n), or None.

        Given only when ``q`` are the last joints it checked, with kinematics equal to ``kin`` (the
        robot, base, TCP and stationary tool) and the same ``wrist`` segments (N-1,): the check
        :func:`check_controller_lines` would make of those arguments (its ``known``).
        """
        q = np.asarray(q, dtype=float)
        if self._last is None or self._last[0].shape != q.shape or not np.array_equal(self._last[0], q):
            return None
        mine = self.kin
        same_tool = (mine.tool_in_world is None) == (kin.tool_in_world is None) and (
            kin.tool_in_world is None or np.array_equal(mine.tool_in_world, kin.tool_in_world)
        )
        if not (
            mine.robot is kin.robot
            and np.array_equal(mine.base_in_world, kin.base_in_world)
            and np.array_equal(mine.tcp_in_flange, kin.tcp_in_flange)
            and same_tool
            and np.array_equal(self._last_wrist, np.asarray(wrist, dtype=bool))
        ):
            return None
        return self._last[1]

    def violations(self, problem: object, q: Array) -> list[Violation]:
        """The line's joint-margin and singularity breaks of joints ``q`` (N, n), with the path's arc lengths."""
        line = self._check(q)
        s = np.asarray(problem.fused.s, dtype=float)  # type: ignore[attr-defined]
        return [
            replace(v, s_start_m=float(s[v.index_start]), s_end_m=float(s[v.index_end]))
            for v in line.violations
            if v.reason.startswith(LINE_REASONS)
        ]

    def rows(self, problem: object, q: Array) -> tuple[LinearRow, ...]:
        """Rows for the breaks of the last verified answer when ``q`` is it; () otherwise."""
        q = np.asarray(q, dtype=float)
        if self._last is None or self._last[0].shape != q.shape or not np.array_equal(self._last[0], q):
            return ()
        line = self._last[1]
        if not any(v.reason.startswith(LINE_REASONS) for v in line.violations):
            return ()
        return line_rows(self.kin, q, line, self.tolerances)

    def refresh_rows(self, rows: tuple[LinearRow, ...], q: Array) -> tuple[LinearRow, ...]:
        """``rows`` without this source's: a line's rows hold for the path they were made on only.

        A re-solve of a moved path (:mod:`refine.optimise.warm`) then builds its problem anew, and
        its rounds add the rows its own line needs.
        """
        return tuple(r for r in rows if not r.label.startswith(LINE_LABEL))

    def clearance(self, q: Array) -> None:
        """No clearance figures: the line's clearance is the final check's."""
        return None
