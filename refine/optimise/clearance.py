"""Clearance to the cell as linearised constraints, the way sequential trajectory optimisers do it.

FCL distances are not differentiable inside CasADi. Each outer round of
:func:`refine.optimise.solve.solve_refinement` asks :class:`ClearanceSource` for rows: at every
waypoint (and inside every segment the dense check found too close) the pairs closer than the
margin plus a look-ahead give one row each, the signed distance linearised at the witness points,
``d(q) ≈ d0 + g·(q - q0) >= margin``. The rows replace the previous round's; the loop ends when the
dense check (:func:`refine.collision.check_path_clearance`, between waypoints at the problem's
``check_step_m`` of TCP travel) finds every margin kept. A path not checked yet (the seed) that the
motion bound alone proves clear (:func:`refine.collision.margins_proved`) gets no rows without the
dense check's figures.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace

import numpy as np

from refine.collision import CollisionModel, Contact, PathClearance, check_path_clearance, margins_proved
from refine.collision.carry import CheckedBounds, carried_bounds, carried_directions
from refine.optimise.problem import LinearRow, RefinementNLP
from refine.optimise.verify import Violation
from refine.problem import Problem
from refine.robot.kinematics import TcpKinematics
from refine.robot.model import Robot
from refine.types import Array

log = logging.getLogger(__name__)

LOOK_AHEAD_M = 0.03
"""Pairs within margin + this distance get a row, so the next solve cannot push them in [m]."""

RECENT_CHECKS = 8
"""Dense checks kept for reuse, by joint path."""

BACK_OFF_M = 0.0005
"""Each row asks for this much more than the margin [m]: the distance is curved where the row is
flat, and without it the rounds end a fraction of a millimetre inside the margin."""


@dataclass
class ClearanceSource:
    """Linearised clearance rows and the dense clearance check for one robot, tool and cell.

    Attributes:
        model: the FCL collision model.
        kin: TCP kinematics of the same robot, base and tool.
        check_step_m: largest TCP travel between two poses of the dense check [m].
        last: the last dense check made, by joints (for reports).
        prior: a previous check's bounds (of a previous answer, re-solving) that the checks of
            nearby paths start from (:mod:`refine.collision.carry`), or None.
        stats: queries and time spent, for the collision cost figures.
    """

    model: CollisionModel
    kin: TcpKinematics
    check_step_m: float
    last: PathClearance | None = None
    prior: CheckedBounds | None = None
    _recent: dict[tuple, PathClearance] = field(default_factory=dict)
    stats: dict[str, float] = field(
        default_factory=lambda: {"rounds": 0, "rows": 0, "check_s": 0.0, "rows_s": 0.0}
    )

    @classmethod
    def for_problem(cls, problem: Problem, robot: Robot) -> ClearanceSource:
        """The source for a problem's robot placement, tool shapes, cell and ``[collision]``."""
        model = CollisionModel.for_problem(problem, robot)
        kin = TcpKinematics(
            robot, problem.robot.base_in_world, problem.tool.tcp_in_flange, problem.tool.tcp_in_world
        )
        return cls(model, kin, problem.collision.check_step_m)

    def forget(self) -> None:
        """Drop the dense checks kept for reuse, so the next refinement starts as a fresh run's would."""
        self._recent.clear()
        self.last = None

    # ---- the ConstraintSource protocol ------------------------------------------------------

    def clearance(self, q: Array) -> PathClearance:
        """The dense check of joints ``q`` (N, n), reused when ``q`` is one of the last checked.

        The solver checks several candidate paths (rounds, repair branches) and may return an
        earlier one; the report's figures then come from the check already made.
        """
        q = np.asarray(q, dtype=float)
        key = self._key(q)
        found = self._recent.pop(key, None)
        if found is None:
            t0 = time.perf_counter()
            found = check_path_clearance(
                self.model,
                q,
                self.kin,
                self.check_step_m,
                prior=self._carried(q),
                directions=self._directions(q, turned=True),
                every_waypoint=False,
            )
            self.stats["check_s"] += time.perf_counter() - t0
        self._recent[key] = found  # most recent last
        while len(self._recent) > RECENT_CHECKS:
            del self._recent[next(iter(self._recent))]
        self.last = found
        return found

    def carry_from(self, clearance: object) -> None:
        """Start the checks from a previous answer's check (``PathClearance``) where it is near."""
        self.prior = getattr(clearance, "bounds", None)

    def _carried(self, q: Array) -> Array | None:
        return None if self.prior is None else carried_bounds(self.model, self.prior, q)

    def _directions(self, q: Array, *, turned: bool = False) -> Array | None:
        return None if self.prior is None else carried_directions(self.model, self.prior, q, turned=turned)

    @staticmethod
    def _key(q: Array) -> tuple:
        return (q.shape, q.tobytes())

    def violations(self, problem: RefinementNLP, q: Array) -> list[Violation]:
        """Runs of segments below the margin, as violations naming the objects [m]."""
        check = self.clearance(q)
        s = problem.fused.s
        cell = {b.name for b in self.model.bodies if b.kind == "cell"}
        out = []
        for r in check.runs:
            # the worst pair's own margin: the cell margin, or the self margin for a robot/tool pair
            own_self = r.worst_pair[1] not in cell
            out.append(
                Violation(
                    r.index_start,
                    r.index_end,
                    float(s[r.index_start]),
                    float(s[r.index_end]),
                    f"{'self-collision' if own_self else 'collision'} ({', '.join(r.objects)})",
                    r.min_distance_m,
                    "m",
                    r.min_distance_m - r.min_clearance_m,
                )
            )
        return out

    def rows(self, problem: RefinementNLP, q: Array) -> tuple[LinearRow, ...]:
        """Fresh rows for every close pair along ``q``; empty when the dense check passes.

        A path not checked yet (the seed) is first put to the motion bound's proof alone
        (:func:`refine.collision.margins_proved`): a path it proves clear needs no rows, and the
        check's figures are not needed for it.
        """
        q = np.asarray(q, dtype=float)
        if self._key(q) not in self._recent:
            t0 = time.perf_counter()
            proved = margins_proved(self.model, q, prior=self._carried(q), directions=self._directions(q))
            self.stats["check_s"] += time.perf_counter() - t0
            if proved:
                return ()
        if self.clearance(q).ok:
            return ()
        t0 = time.perf_counter()
        self.stats["rounds"] += 1
        reach = self.model.margin_m + LOOK_AHEAD_M
        rows: list[LinearRow] = []
        for k in range(len(q)):
            rows += self._rows_at(q[k], k, 0.0, reach)
        for k in np.flatnonzero(self.last.segment_clearance_m < 0.0):  # type: ignore[union-attr]
            if k + 1 < len(q):
                rows += self._rows_at(0.5 * (q[k] + q[k + 1]), int(k), 0.5, reach)
        self.stats["rows"] += len(rows)
        self.stats["rows_s"] += time.perf_counter() - t0
        log.info("clearance: %d linearised rows from %d waypoints", len(rows), len(q))
        return tuple(rows)

    def refresh_rows(self, rows: tuple[LinearRow, ...], q: Array) -> tuple[LinearRow, ...]:
        """``rows`` with their bounds taken again at joints ``q`` (N, n), their gradients kept.

        Each row's bodies (its label, ``"body / other"``, as the contacts name them) are measured at
        the row's place along ``q`` in the cell as it is now, so a row made before a cell object
        moved asks for the margin from where the object is: ``g·q' >= margin + back-off - d(q) + g·q``.
        A body of several shapes (a link's collision pieces) is measured by its nearest shape pair
        to the other, so the refreshed row asks for at least what its own pair needs. A row whose
        bodies this source does not check is kept as it is.
        """
        q = np.asarray(q, dtype=float)
        name = {b.label: b.name for b in self.model.bodies}
        pairs: dict[str, list[int]] = {}
        for p, (a, b) in enumerate(self.model.pairs):
            pairs.setdefault(f"{name[a]} / {name[b]}", []).append(p)
        margins = self.model.pair_margins
        out = []
        for r in rows:
            found = pairs.get(r.label)
            if not found:
                out.append(r)
                continue
            qk = q[r.k] if r.f == 0.0 else (1.0 - r.f) * q[r.k] + r.f * q[min(r.k + 1, len(q) - 1)]
            need = max(float(margins[p]) - self.model.pair_distance(qk, p) for p in found)
            g = np.asarray(r.gradient, dtype=float)
            out.append(replace(r, lower=need + BACK_OFF_M + float(g @ qk)))
        return tuple(out)

    def _rows_at(self, qk: Array, k: int, f: float, reach: float) -> list[LinearRow]:
        contacts: list[Contact] = self.model.contacts(qk, reach)
        if not contacts:
            return []
        grads = self.model.distance_gradients(qk, contacts)
        return [
            LinearRow(
                k, f, g, c.margin_m + BACK_OFF_M - c.distance_m + float(g @ qk), f"{c.body} / {c.other}"
            )
            for c, g in zip(contacts, grads, strict=True)
            if np.linalg.norm(g) > 1e-9
        ]
