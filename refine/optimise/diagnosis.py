"""Why a segment of a path needed orientation slack or has no answer: the root cause, with its figure.

A refinement that is ``repaired`` or ``infeasible`` is explained here segment by segment. For each
segment the candidate causes are measured independently of the optimiser's own bookkeeping (reach
of the wrist centre or TCP, joint limits and multi-turn joints, the singularity measure, the
clearance of the dense check) and ordered by how much of the needed slack each explains. The
entries are what ``result.json`` reports under ``diagnosis`` (schema in
``docs/diagnosis.schema.json``); the ``repairs`` list and the texts are derived from them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from refine.optimise.binding import binding_at, bound_text, waypoint_runs
from refine.optimise.reach import reach_model, rotations_about, shoulder_circle_distances
from refine.optimise.verify import runs, singularity_measures
from refine.paths import FusedPath
from refine.robot.kinematics import TcpKinematics, solve_ik
from refine.settings import Tolerances
from refine.types import Array


def closest_pair_text(clearance: Any, cell_names: set[str], margin_m: float, self_margin_m: float) -> str:
    """The pair with the least clearance along a checked path, saying whether it is a cell or a self pair.

    Args:
        clearance: a :class:`refine.collision.PathClearance`.
        cell_names: the names of the cell's objects (any other name is a robot link or tool shape).
        margin_m: the cell margin [m].
        self_margin_m: the self margin [m] (robot links and tool shapes among themselves).

    Returns:
        e.g. ``"least clearance link_5/link_5 vs link_7/link_7 (self pair, self margin 5 mm) at 6.2 mm"``,
        or an empty string for a path of one waypoint.
    """
    if not len(clearance.segment_clearance_m):
        return ""
    k = int(np.argmin(clearance.segment_clearance_m))
    body, other = clearance.segment_pair[k]
    if other in cell_names:
        kind, margin = "cell pair, margin", margin_m
    else:
        kind, margin = "self pair, self margin", self_margin_m
    distance = float(clearance.segment_clearance_m[k]) + margin  # that pair's own distance
    return f"least clearance {body} vs {other} ({kind} {margin * 1e3:g} mm) at {distance * 1e3:.1f} mm"


# ---- reach -------------------------------------------------------------------------------------


# ---- findings ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Cause:
    """One thing that keeps a segment from the demonstrated orientation, with its figure.

    Attributes:
        cause: ``"reach"``, ``"joint limit"``, ``"joint wrap"``, ``"singularity"``, ``"collision"``
            (robot or tool against the cell), ``"self-collision"`` (robot and tool among
            themselves) or ``"orientation"`` (none of these measured: the cone with the joint-step
            bound and the other tolerances together).
        figure: the worst value the demonstration asks for inside the segment, in ``unit``: the
            wrist-centre (or TCP) distance from the shoulder, the joint angle, the scaled
            manipulability, the signed distance of the pair (negative: depth).
        limit: the bound it breaks, in ``unit``: the reach, the joint limit less the margin, the
            singularity margin, the pair's clearance margin.
        unit: ``"m"``, ``"deg"`` or ``"-"``.
        objects: the pair's two bodies (collision), else empty.
        joint: 1-based joint number (joint limit, joint wrap), else None.
        explains_deg: the orientation change this cause alone asks for [deg] (inf when no change
            of orientation is enough), the measure the causes are ordered by.
        suggestion: what would fix it, in words with figures.
        in_answer: measured at the answer rather than at the demonstrated orientation: a constraint
            at its bound there (:mod:`refine.optimise.binding`); ``explains_deg`` is then 0.
        waypoints: for a cause in the answer, the runs of waypoints (first, last inclusive) where
            it is at its bound; else empty.
    """

    cause: str
    figure: float
    limit: float
    unit: str
    objects: tuple[str, ...] = ()
    joint: int | None = None
    explains_deg: float = 0.0
    suggestion: str = ""
    in_answer: bool = False
    waypoints: tuple[tuple[int, int], ...] = ()

    @property
    def label(self) -> str:
        """The cause as the repair reasons write it: ``"joint limit (joint 5)"``, ``"collision"``."""
        return f"{self.cause} (joint {self.joint})" if self.joint is not None else self.cause

    def at_bound(self) -> str:
        """A constraint at its bound in the answer, in words (:func:`refine.optimise.binding.bound_text`)."""
        return bound_text(self)

    def as_json(self) -> dict[str, Any]:
        """Plain values for ``result.json``."""
        return {
            "cause": self.cause,
            "figure": _finite(self.figure),
            "limit": _finite(self.limit),
            "unit": self.unit,
            "objects": list(self.objects),
            "joint": self.joint,
            "explains_deg": _finite(self.explains_deg),
            "suggestion": self.suggestion,
            "in_answer": self.in_answer,
            "waypoints": [list(w) for w in self.waypoints],
        }



@dataclass(frozen=True)
class Finding:
    """A segment that needed extra orientation slack or has no answer, and why.

    Attributes:
        status: ``"repaired"`` (verified with ``slack_deg``) or ``"infeasible"``.
        index_start, index_end: first and last waypoint (inclusive).
        s_start_m, s_end_m: their arc lengths [m].
        causes: every cause measured there, the one that explains most first.
        slack_deg: the largest extra orientation slack used inside [deg] (repaired), else None.
    """

    status: str
    index_start: int
    index_end: int
    s_start_m: float
    s_end_m: float
    causes: tuple[Cause, ...]
    slack_deg: float | None = None

    @property
    def cause(self) -> Cause:
        """The cause that explains most."""
        return self.causes[0]

    def describe(self) -> str:
        """One line for messages and reports."""
        head = (
            f"waypoints {self.index_start}-{self.index_end} (s = {self.s_start_m:.3f}-{self.s_end_m:.3f} m): "
        )
        if self.slack_deg is not None:
            head += f"{self.slack_deg:.2f} deg extra orientation slack, "
        c = self.cause
        objs = f" ({', '.join(c.objects)})" if c.objects else ""
        text = head + c.label + objs + (f": {c.suggestion}" if c.suggestion else "")
        text += waypoint_runs(c.waypoints) if c.in_answer else ""
        held = [x for x in self.causes[1:] if x.in_answer]
        if held:
            text += "; at its bound in the answer: " + "; ".join(x.at_bound() for x in held)
        return text

    def as_json(self) -> dict[str, Any]:
        """The ``diagnosis`` entry of ``result.json`` (docs/diagnosis.schema.json)."""
        c = self.cause
        return {
            "status": self.status,
            "index_start": self.index_start,
            "index_end": self.index_end,
            "s_start_m": self.s_start_m,
            "s_end_m": self.s_end_m,
            "cause": c.cause,
            "figure": _finite(c.figure),
            "limit": _finite(c.limit),
            "unit": c.unit,
            "objects": list(c.objects),
            "joint": c.joint,
            "slack_deg": self.slack_deg,
            "suggestion": c.suggestion,
            "causes": [x.as_json() for x in self.causes],
        }


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def segments(mask: Array, gap: int = 2) -> list[tuple[int, int]]:
    """Runs of True in ``mask`` (first, last inclusive), runs closer than ``gap`` waypoints merged."""
    out: list[tuple[int, int]] = []
    for a, b in runs(np.asarray(mask, dtype=bool)):
        if out and a - out[-1][1] <= gap:
            out[-1] = (out[-1][0], b)
        else:
            out.append((a, b))
    return out


@dataclass
class Diagnoser:
    """Measures the causes of the segments of one problem (robot, tool, path, tolerances, cell).

    Attributes:
        kin: TCP kinematics.
        fused: the fused path (CAD positions, demonstrated orientations, arc length).
        tolerances: the strict tolerances.
        axisymmetric: only the tool axis counts (the spin about it is free).
        model: the collision model, or None without collision checking.
    """

    kin: TcpKinematics
    fused: FusedPath
    tolerances: Tolerances
    axisymmetric: bool
    model: Any = None

    def __post_init__(self) -> None:
        spec = self.kin.robot.spec
        self.margin = math.radians(self.tolerances.joint_margin_deg)
        self.lower, self.upper = spec.lower + self.margin, spec.upper - self.margin
        self.reach = reach_model(self.kin.robot, self.margin)
        if self.kin.tool_in_world is not None:  # the targets are in the held part: no wrist-centre geometry
            self.reach = replace(self.reach, spherical=False)
        self.cell = set() if self.model is None else {b.name for b in self.model.bodies if b.kind == "cell"}

    # -- the demonstrated pose and configuration -------------------------------------------------

    def target(self, k: int, qk: Array) -> Array:
        """The demonstrated TCP pose at waypoint ``k``.

        For an axisymmetric tool: the reached pose ``qk`` turned the least that puts its axis on the
        demonstrated one (the spin about the axis is free).
        """
        T = np.eye(4)
        T[:3, 3] = self.fused.positions[k]
        R_demo = self.fused.rotations[k]
        if not self.axisymmetric:
            T[:3, :3] = R_demo
            return T
        R = self.kin.pose(qk)[:3, :3]
        z0, z1 = R[:, 2], R_demo[:, 2]
        axis = np.cross(z0, z1)
        angle = math.atan2(np.linalg.norm(axis), float(z0 @ z1))
        if np.linalg.norm(axis) < 1e-12:
            T[:3, :3] = R if angle < 1.0 else R_demo
            return T
        T[:3, :3] = rotations_about(axis / np.linalg.norm(axis), np.array([angle]))[0] @ R
        return T

    def _orientation_jacobian(self, q: Array) -> tuple[Array, Array]:
        J = self.kin.jacobian(q)
        Jw = J[3:]
        if self.axisymmetric:
            z = self.kin.pose(q)[:3, 2]
            Jw = (np.eye(3) - np.outer(z, z)) @ Jw
        return J[:3], Jw

    def orientation_needed_deg(self, q: Array, row: Array, delta: float) -> float:
        """The least change of tool orientation [deg] that moves ``row · q`` by ``delta``.

        The TCP position is held; linearised at ``q``; 0 when a redundant arm can do it in its null
        space. The change is a least-squares problem with two equality rows, solved by its KKT system.
        """
        Jp, Jw = self._orientation_jacobian(q)
        n = len(q)
        H = Jw.T @ Jw + 1e-6 * np.eye(n)
        A = np.vstack([Jp, row])
        b = np.concatenate([np.zeros(3), [delta]])
        K = np.block([[H, A.T], [A, np.zeros((4, 4))]])
        try:
            dq = np.linalg.solve(K, np.concatenate([np.zeros(n), b]))[:n]
        except np.linalg.LinAlgError:
            return math.inf
        return math.degrees(float(np.linalg.norm(Jw @ dq)))

    # -- each cause, per waypoint ----------------------------------------------------------------

    def reach_at(self, T: Array, inset_m: float = 0.0) -> tuple[float, float, float, float, Array]:
        """Wrist-centre distance from the shoulder at the demonstrated pose ``T``, and the tilt that fixes it.

        Returns:
            the distance [m], the tilt of the tool towards (or away from) the shoulder that brings it
            inside the reachable range [deg] (0 when inside, inf when no tilt does), the distance
            after tilting by the cone [m], the closest any tilt comes to the range [m], and the
            tool orientation tilted that much (3, 3) in {F} (the demonstrated one when no tilt does).
            With ``inset_m`` the range is narrowed by that much at both ends.
        """
        T_base = np.linalg.inv(self.kin.base_in_world) @ T
        p, R = T_base[:3, 3], T_base[:3, :3]
        v = (np.linalg.inv(self.kin.tcp_in_flange) @ np.append(self.reach.point_in_flange, 1.0))[:3]
        wc = p + R @ v
        d0 = float(self.reach.distance(wc[None])[0])
        L = float(np.linalg.norm(v))
        lo, hi = self.reach.r_min_m + inset_m, self.reach.r_max_m - inset_m
        if lo <= d0 <= hi or L < 1e-9:
            return d0, 0.0, d0, d0, T[:3, :3]
        front, back = self.reach.shoulders(wc[None])
        s = (
            front[0]
            if abs(np.linalg.norm(wc - front[0]) - d0) < abs(np.linalg.norm(wc - back[0]) - d0)
            else back[0]
        )
        u = (wc - p) / L
        e = s - p
        e = e / np.linalg.norm(e) * (1.0 if d0 > hi else -1.0)  # towards or away
        axis = np.cross(u, e)
        if np.linalg.norm(axis) < 1e-12:
            axis = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
        axis /= np.linalg.norm(axis)
        betas = np.radians(np.arange(0.0, 180.01, 0.1))
        points = p + L * np.einsum("nij,j->ni", rotations_about(axis, betas), u)
        d = self.reach.distance(points)
        inside = np.flatnonzero((d >= lo - 1e-9) & (d <= hi + 1e-9))
        cone = int(round(self.tolerances.orientation_deg / 0.1))
        tilt = math.degrees(betas[inside[0]]) if inside.size else math.inf
        R_in = T[:3, :3]
        if inside.size:
            axis_world = self.kin.base_in_world[:3, :3] @ axis
            R_in = rotations_about(axis_world, betas[inside[:1]])[0] @ T[:3, :3]
        return d0, tilt, float(d[min(cone, len(d) - 1)]), float(d.min() if d0 > hi else d.max()), R_in

    def configuration(self, T: Array, q0: Array) -> tuple[Array, bool]:
        """Joints that reach the demonstrated pose ``T`` from ``q0``, ignoring the joint limits."""
        free = np.full(len(q0), 100.0)  # [rad]: no limit, and no pull to mid-range on a redundant arm
        q, err = solve_ik(self.kin, T, q0, -free, free, max_iterations=200)
        return q, err < 1e-6

    def joint_causes(self, q: Array) -> list[Cause]:
        """Joints of ``q`` beyond their limits less the margin.

        A joint that turns less than a full turn may take ``q ± 2π``; a multi-turn joint must take
        its value (the path is continuous).
        """
        out = []
        for j in range(len(q)):
            lo, hi = self.lower[j], self.upper[j]
            multi = hi - lo > 2 * math.pi
            values = [q[j]] if multi else [q[j] + 2 * math.pi * t for t in (-2, -1, 0, 1, 2)]
            excess = [max(lo - v, v - hi, 0.0) for v in values]
            i = int(np.argmin(excess))
            if excess[i] <= 1e-6:
                continue
            v = values[i]
            bound = lo if v < lo else hi
            row = np.zeros(len(q))
            row[j] = 1.0
            needed = self.orientation_needed_deg(q, row, bound - v)
            kind = "joint wrap" if multi else "joint limit"
            out.append(
                Cause(
                    kind,
                    math.degrees(v),
                    math.degrees(bound),
                    "deg",
                    joint=j + 1,
                    explains_deg=needed,
                    suggestion=(
                        f"joint {j + 1} would need {math.degrees(v):.1f} deg, {math.degrees(abs(v - bound)):.1f} deg "
                        f"beyond {math.degrees(bound):.1f} deg (its limit less the {self.tolerances.joint_margin_deg:g} "
                        f"deg margin); about {needed:.1f} deg of tool orientation change brings it back"
                        + (", or start the path with the tool turned the other way" if multi else "")
                    ),
                )
            )
        return out

    def singularity_cause(self, q: Array) -> Cause | None:
        """The scaled manipulability at ``q`` when below the margin."""
        margin = self.tolerances.singularity_margin
        w, _ = singularity_measures(self.kin, q[None])
        if margin <= 0 or w[0] >= margin:
            return None
        h = 1e-6
        grad = np.array(
            [(singularity_measures(self.kin, (q + h * e)[None])[0][0] - w[0]) / h for e in np.eye(len(q))]
        )
        needed = (
            self.orientation_needed_deg(q, grad, margin - w[0]) if np.linalg.norm(grad) > 1e-9 else math.inf
        )
        return Cause(
            "singularity",
            float(w[0]),
            margin,
            "-",
            explains_deg=needed,
            suggestion=(
                f"scaled manipulability {w[0]:.4f} below the margin {margin:g}; about {needed:.1f} deg of tool "
                "orientation change away from the singular direction keeps the margin"
            ),
        )

    def collision_causes(self, q: Array) -> list[Cause]:
        """The pairs closer than their margin at ``q``."""
        if self.model is None:
            return []
        reach = max(self.model.margin_m, self.model.self_margin_m)
        contacts = [c for c in self.model.contacts(q, reach) if c.distance_m < c.margin_m]
        if not contacts:
            return []
        grads = self.model.distance_gradients(q, contacts)
        out = []
        for c, g in zip(contacts, grads, strict=True):
            needed = (
                self.orientation_needed_deg(q, g, c.margin_m - c.distance_m)
                if np.linalg.norm(g) > 1e-9
                else math.inf
            )
            own_self = c.other not in self.cell
            where = "self margin" if own_self else "cell margin"
            out.append(
                Cause(
                    "self-collision" if own_self else "collision",
                    c.distance_m,
                    c.margin_m,
                    "m",
                    objects=(c.body, c.other),
                    explains_deg=needed,
                    suggestion=(
                        f"{c.body} and {c.other} at {c.distance_m * 1e3:.1f} mm "
                        f"({(c.margin_m - c.distance_m) * 1e3:.1f} mm inside the {where} {c.margin_m * 1e3:g} mm); "
                        f"about {needed:.1f} deg of tool orientation change clears it"
                        + ("" if own_self else f", or move {c.other}")
                    ),
                )
            )
        return out

    # -- a segment -------------------------------------------------------------------------------

    def segment(self, status: str, a: int, b: int, q: Array, slack_deg: float | None = None) -> Finding:
        """The causes of waypoints ``a``..``b`` (inclusive) of the answer ``q`` (N, n) [rad]."""
        found: dict[tuple, Cause] = {}

        def keep(c: Cause) -> None:
            # per cause: the worst figure (farthest beyond its limit) and the most it explains
            key = (c.cause, c.joint, c.objects)
            old = found.get(key)
            if old is None:
                found[key] = c
                return
            worst = c if abs(c.figure - c.limit) > abs(old.figure - old.limit) else old
            most = c if c.explains_deg > old.explains_deg else old
            found[key] = replace(worst, explains_deg=most.explains_deg, suggestion=most.suggestion)

        q_prev = None
        reach_rows = []
        for k in range(a, b + 1):
            T = self.target(k, q[k])
            if self.reach.spherical:
                d, tilt, d_cone, d_best, _ = self.reach_at(T)
                if tilt > 0.0:  # out of reach as demonstrated: no configuration to measure the rest at
                    reach_rows.append((d, tilt, d_cone, d_best))
                    q_prev = None
                    continue
            start = q[k] if q_prev is None else q_prev
            qd, ok = self.configuration(T, start)
            if not ok and q_prev is not None:
                qd, ok = self.configuration(T, q[k])
            if not ok:
                if not self.reach.spherical or not reach_rows:
                    miss = float(np.linalg.norm(self.kin.pose(qd)[:3, 3] - T[:3, 3]))
                    reach_rows.append((miss,))
                q_prev = None
                continue
            q_prev = qd
            sc = self.singularity_cause(qd)
            for c in [*self.joint_causes(qd), *([sc] if sc else []), *self.collision_causes(qd)]:
                keep(c)
        causes = list(found.values())
        if reach_rows:
            causes.append(self._reach_cause(reach_rows))
        causes.sort(key=lambda c: -c.explains_deg)
        if status == "repaired":  # and every constraint that holds the answer there
            for entry in binding_at(self.kin, q, a, b, self.tolerances, self.lower, self.upper, self.model, self.cell):
                causes.append(Cause(**entry, in_answer=True))
        if not causes:
            causes = [
                Cause(
                    "orientation",
                    math.nan,
                    self.tolerances.orientation_deg,
                    "deg",
                    suggestion="no single limit measured at the demonstrated orientation; the cone together "
                    "with the joint-step bound and the other tolerances forced it",
                )
            ]
        s = self.fused.s
        return Finding(status, a, b, float(s[a]), float(s[b]), tuple(causes), slack_deg)

    def _reach_cause(self, rows: list[tuple]) -> Cause:
        if all(len(r) == 4 for r in rows):
            d = np.array([r[0] for r in rows])
            tilt = max(r[1] for r in rows)
            d_cone = np.array([r[2] for r in rows])
            d_best = np.array([r[3] for r in rows])
            far = bool(np.max(d) > self.reach.r_max_m)
            worst = float(d.max() if far else d.min())
            limit = self.reach.r_max_m if far else self.reach.r_min_m
            # the shift that keeps the demonstrated orientation (to the cone), and the least at any tilt
            move = float(np.max(np.abs(d_cone - limit)))
            least = float(np.max(np.abs(d_best - limit))) if not math.isfinite(tilt) else 0.0
            cone = self.tolerances.orientation_deg
            text = (
                f"the wrist centre is {d.min():.3f}-{d.max():.3f} m from the shoulder (axis 2) at the demonstrated "
                f"orientation and {d_cone.min():.3f}-{d_cone.max():.3f} m within the {cone:g} deg cone; the arm "
                f"reaches {self.reach.r_min_m:.3f}-{self.reach.r_max_m:.3f} m: "
                + (
                    f"tilting the tool {tilt:.1f} deg {'towards' if far else 'away from'} the robot brings it in"
                    if math.isfinite(tilt)
                    else "no tilt of the tool brings it in"
                )
                + f"; or move the part {move:.3f} m {'closer to' if far else 'away from'} the robot to keep the "
                "demonstrated orientation"
                + (f" (at least {least:.3f} m whatever the orientation)" if least > 0 else "")
            )
            return Cause("reach", worst, limit, "m", explains_deg=tilt, suggestion=text)
        miss = max(r[0] for r in rows if len(r) == 1)
        return Cause(
            "reach",
            miss,
            0.0,
            "m",
            explains_deg=math.inf,
            suggestion=f"the demonstrated pose is out of reach inside the joint limits: the TCP misses it by "
            f"{miss:.4f} m; move the part closer to the robot",
        )


def reach_gap(kin: TcpKinematics, positions: Array, joint_margin_deg: float) -> Array:
    """How far each TCP position (N, 3) in {F} is out of reach at any tool orientation [m].

    The wrist centre lies on a sphere of fixed radius L around the TCP; the gap is how far that
    sphere stays outside the wrist centre's range of distances from the shoulder, wherever axis 1
    turns the shoulder on its circle: beyond ``r_max_m`` from its nearest point, or inside
    ``r_min_m`` of its farthest (:func:`refine.optimise.reach.shoulder_circle_distances`). Zeros for
    a robot without a spherical wrist (nothing certain to say).
    """
    reach = reach_model(kin.robot, math.radians(joint_margin_deg))
    out = np.zeros(len(positions))
    if not reach.spherical or kin.tool_in_world is not None:
        return out
    T_inv = np.linalg.inv(kin.base_in_world)
    p = positions @ T_inv[:3, :3].T + T_inv[:3, 3]
    L = float(np.linalg.norm((np.linalg.inv(kin.tcp_in_flange) @ np.append(reach.point_in_flange, 1.0))[:3]))
    d_min, d_max = shoulder_circle_distances(reach, p)
    return np.maximum(np.maximum(d_min - L - reach.r_max_m, reach.r_min_m - d_max - L), 0.0)


def reach_tilts(
    kin: TcpKinematics, fused: FusedPath, tolerances: Tolerances, axisymmetric: bool, inset_m: float = 0.0
) -> tuple[Array, Array]:
    """The tilt of the tool each demonstrated pose needs for its wrist centre to be in reach.

    Args:
        kin: TCP kinematics.
        fused: the fused path (demonstrated poses).
        tolerances: the strict tolerances (joint margin, cone).
        axisymmetric: only the tool axis counts.
        inset_m: narrow the reachable range by this much at both ends [m] (keeps the elbow off
            its stretched singularity).

    Returns:
        tilt per waypoint [deg] (0: in reach as demonstrated, inf: no tilt brings it in; all
        zeros for a robot without a spherical wrist), and the demonstrated rotations tilted that
        much (N, 3, 3).
    """
    d = Diagnoser(kin, fused, tolerances, axisymmetric)
    tilts = np.zeros(len(fused.s))
    rotations = np.array(fused.rotations, dtype=float)
    if not d.reach.spherical:
        return tilts, rotations
    # the wrist centre of every demonstrated pose at once; only the poses out of range need a tilt
    T_base = np.linalg.inv(kin.base_in_world)
    R_base = T_base[:3, :3] @ np.asarray(fused.rotations, dtype=float)
    p_base = np.asarray(fused.positions, dtype=float) @ T_base[:3, :3].T + T_base[:3, 3]
    v = (np.linalg.inv(kin.tcp_in_flange) @ np.append(d.reach.point_in_flange, 1.0))[:3]
    distance = d.reach.distance(p_base + R_base @ v)
    lo, hi = d.reach.r_min_m + inset_m, d.reach.r_max_m - inset_m
    for k in np.flatnonzero((distance < lo) | (distance > hi)):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = fused.rotations[k], fused.positions[k]
        _, tilts[k], _, _, rotations[k] = d.reach_at(T, inset_m)
    return tilts, rotations
