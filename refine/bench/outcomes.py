"""How a benchmark row is scored: success, detection of a stated infeasibility, the time penalty.

The rules (docs/bench.md, "Outcome columns"):

* ``success``: the contender claimed an answer (status ``ok`` or ``repaired``), the run ended
  within the time limit without raising, its solver's own status is not one of
  :data:`NOT_CONVERGED` (IPOPT's ``Maximum_Iterations_Exceeded`` is no success even when the path
  happens to verify), and the shared verification passed (a ``repaired`` answer with the slack it
  reports, on a problem built to be repaired). Nothing else is a success; in particular answering
  ``infeasible`` never is. With several timed runs, every one must be a success.
* ``detected_infeasible``: only on a problem whose file states it infeasible (``[expected] status
  = "infeasible"`` with an ``s_range_m``). The contender answered ``infeasible`` itself (not by
  raising, not past the time limit) *with an attempt*: finite joints for every waypoint. The shared
  verification must reject that attempt (an attempt that passes would refute the statement), and
  one of the stretches it finds broken must overlap the stated ``s_range_m`` (the rule a problem
  file sets for refine's own diagnosis). An ``infeasible`` without joints is no detection.
* A row that is neither a success nor a detection is a failed row; in the time summaries it counts
  as the time limit (:func:`penalised`), never as the seconds it happened to take.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from refine.types import Array

DEFAULT_TIME_LIMIT_S = 300.0
"""Wall time one run of a contender may take [s] before it counts as timed out."""

CLAIMS = ("ok", "repaired")
"""The statuses by which a contender claims an executable answer."""

NOT_CONVERGED = (
    "Maximum_",  # IPOPT: Maximum_Iterations_Exceeded, Maximum_CpuTime_Exceeded, Maximum_WallTime_Exceeded
    "Restoration_Failed",
    "Error_In_Step_Computation",
    "Search_Direction_Becomes_Too_Small",
    "Diverging_Iterates",
    "User_Requested_Stop",
    "Not_Enough_Degrees_Of_Freedom",
    "Infeasible_Problem_Detected",
    "Invalid_",
    "Unrecoverable_Exception",
    "NonIpopt_Exception_Thrown",
    "Insufficient_Memory",
    "Internal_Error",
    "not solved",  # fatrop through refine.optimise.stagewise: "not solved (return flag ...)"
)
"""Beginnings of a solver's return status that say it stopped without converging (IPOPT's names)."""


def converged(solver_status: str) -> bool:
    """Whether a solver's return status allows a success: empty (no iterative solver) or not :data:`NOT_CONVERGED`."""
    return not solver_status.strip().startswith(NOT_CONVERGED)


@dataclass(frozen=True)
class Scored:
    """The outcome columns of one row.

    Attributes:
        success: a verified answer (see the module's rules).
        detected_infeasible: a stated infeasibility detected with an attempt (see the module's rules).
        failed: neither of the two: the row counts as the time limit in time summaries.
    """

    success: bool
    detected_infeasible: bool

    @property
    def failed(self) -> bool:
        """Neither a success nor a detection."""
        return not (self.success or self.detected_infeasible)


def score(
    expected: str,
    expected_s_range_m: tuple[float, float] | None,
    status: str,
    q: Array | None,
    n_waypoints: int,
    verified: bool,
    verified_repaired: bool,
    broken_s_m: list[tuple[float, float]],
    timed_out: bool,
    solver_status: str = "",
) -> Scored:
    """Score one row by the module's rules.

    Args:
        expected: the outcome the problem states (``infeasible``, ``repaired``, ``ok`` or empty).
        expected_s_range_m: the stated arc-length range [m] of the infeasibility, or None.
        status: the contender's own status; ``error`` when it raised.
        q: the joints it returned (N, n) [rad], or None.
        n_waypoints: N of the problem.
        verified: the shared verification passed (strict tolerances).
        verified_repaired: it passed with the slack a ``repaired`` answer reports.
        broken_s_m: arc-length ranges [m] of the stretches the verification found broken.
        timed_out: a timed run took longer than the time limit.
        solver_status: the solver's own return status (empty without one): see :func:`converged`.
    """
    if timed_out or status not in CLAIMS + ("infeasible",):
        return Scored(False, False)
    if status in CLAIMS:
        repaired_ok = expected == "repaired" and status == "repaired" and verified_repaired
        return Scored((verified or repaired_ok) and converged(solver_status), False)
    detected = (
        expected == "infeasible"
        and expected_s_range_m is not None
        and attempted(q, n_waypoints)
        and not verified
        and any(overlaps(stretch, expected_s_range_m) for stretch in broken_s_m)
    )
    return Scored(False, detected)


def attempted(q: Array | None, n_waypoints: int) -> bool:
    """Joints for every one of ``n_waypoints`` waypoints, all finite."""
    if q is None:
        return False
    q = np.asarray(q, dtype=float)
    return q.ndim == 2 and q.shape[0] == n_waypoints and bool(np.all(np.isfinite(q)))


def overlaps(a: tuple[float, float], b: tuple[float, float]) -> bool:
    """Two closed ranges share a point."""
    return min(a) <= max(b) and min(b) <= max(a)


def penalised(seconds: float, failed: bool, time_limit_s: float) -> float:
    """The time a row counts as in summaries [s]: the time limit for a failed row."""
    return time_limit_s if failed else seconds
