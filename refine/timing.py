"""Time parameterisation: the fastest timing of a joint path under the demonstrated speed.

The joint path ``q(s)`` from ``optimise`` is a cubic spline through the waypoints, parameterised by
the CAD arc length ``s`` [m]. Because the TCP follows the CAD path with ``|dp/ds| = 1``, the path
speed ``ds/dt`` is the TCP speed. TOPPRA (reachability analysis) finds the fastest ``s(t)`` with

* joint velocities ``|q'(s) sdot| <= v_max``,
* joint accelerations ``|q''(s) sdot^2 + q'(s) sddot| <= a_max``,
* the TCP speed ``sdot <= speed_cap(s)``, the smoothed demonstrated speed.

Since the plan is never faster than the demonstration, "fastest" means: it reproduces the demonstrated
speed wherever the robot can and slows down only where a limit binds. :func:`time_parameterise`
reports those places as :class:`SlowSegment` values, each with the limit responsible.

Discretisation: the TOPPRA gridpoints are the waypoints. Between two gridpoints the path acceleration
``sddot`` is constant (so ``sdot^2`` is linear in ``s``). The acceleration limits use TOPPRA's
interpolation scheme: they hold at both ends of every segment with that segment's ``sddot``. Inside
a segment they can be exceeded only by a second-order term in the segment length.

Joint speeds between waypoints: a controller moves from one target to the next in the planned time,
so each joint's mean speed over a segment, ``|q[k+1] - q[k]| / (t[k+1] - t[k])``, must respect its
limit too, not only the speeds at the waypoints; so must the spline's speed inside the segment, which
is bounded exactly (:func:`_between_waypoint_speed_ratio`). Where either exceeds a limit, the path speed at both
ends of that segment is capped lower by the excess and TOPPRA runs again (joint speeds scale with
``sdot``, so one round settles a segment; a few rounds settle their neighbours).
"""

from __future__ import annotations

import functools
import logging
import time
from dataclasses import dataclass

import numpy as np

from refine.errors import InputError, SolverError
from refine.timing_passes import lean_passes
from refine.types import Array

logger = logging.getLogger(__name__)

_VELOCITY_SLACK_REL = 1e-6
"""Relative slack of the final check on joint velocities and on the speed cap."""
_ACCELERATION_SLACK_REL = 1e-3
"""Relative slack of the final check on joint accelerations. TOPPRA shaves 0.01 % off ``sdot^2``
after choosing each ``sddot``; recomputing ``sddot`` from the shaved speeds, as the timing does,
moves the accelerations by that order."""
_BETWEEN_ROUNDS = 6
"""TOPPRA runs at most this often while joint speeds between waypoints are brought within limits."""
_BINDING_REL = 0.01
"""A limit explains a slowdown when a joint uses at least 99 % of it."""
RAMP = "start/stop ramp"


@dataclass(frozen=True)
class SlowSegment:
    """A run of consecutive waypoints where the plan is slower than the demonstration.

    Attributes:
        index_start: first waypoint of the run.
        index_end: last waypoint of the run (inclusive).
        s_start_m: arc length at ``index_start`` [m].
        s_end_m: arc length at ``index_end`` [m].
        min_ratio: smallest planned / demonstrated speed inside the run [-].
        reason: ``"start/stop ramp"``, ``"joint velocity (joint k)"``,
            ``"joint acceleration (joint k)"`` (k 1-based), or ``"not explained by limits
            (closest: ...)"`` when no limit is within 1 % of binding.
    """

    index_start: int
    index_end: int
    s_start_m: float
    s_end_m: float
    min_ratio: float
    reason: str

    def __post_init__(self) -> None:
        if not 0 <= self.index_start <= self.index_end:
            raise InputError(
                f"SlowSegment: need 0 <= index_start <= index_end, got {self.index_start}, {self.index_end}"
            )

    @property
    def explained(self) -> bool:
        """Whether a ramp or a joint limit accounts for the slowdown."""
        return not self.reason.startswith("not explained")


@dataclass(frozen=True)
class Timing:
    """The timed path: when each waypoint is reached and how fast the joints move there.

    ``qdd`` and the accelerations are one-sided: the path acceleration ``sddot`` is constant on each
    segment, so ``qdd[i]`` uses the segment that starts at waypoint ``i`` (the last waypoint uses the
    last segment).

    Attributes:
        t: time at each waypoint [s], shape (N,), t[0] = 0.
        speed: planned path (TCP) speed ds/dt at each waypoint [m/s], shape (N,).
        speed_cap: the demonstrated speed used as the cap [m/s], shape (N,).
        qd: joint velocities [rad/s], shape (N, n).
        qdd: joint accelerations [rad/s^2], shape (N, n).
        cycle_time_s: t[-1] [s].
        slow_segments: runs where speed < (1 - tolerance_rel) * speed_cap, in path order.
        speed_tracking_error_rel: largest relative deficit ``(cap - speed) / cap`` [-] over the
            waypoints where the robot could follow the demonstration, i.e. all waypoints except
            those in a slow segment explained by a ramp or a joint limit. It is below
            ``tolerance_rel`` unless some slowdown is not explained by any limit. 0 when every
            waypoint is explained. Negative deficits (round-off) count as 0.
        speed_tracking_error_mean_rel: mean of the same deficits over the same waypoints [-].
        solve_time_s: wall time of :func:`time_parameterise` [s].
    """

    t: Array
    speed: Array
    speed_cap: Array
    qd: Array
    qdd: Array
    cycle_time_s: float
    slow_segments: tuple[SlowSegment, ...]
    speed_tracking_error_rel: float
    solve_time_s: float
    speed_tracking_error_mean_rel: float

    def __post_init__(self) -> None:
        n = len(self.t)
        for name in ("speed", "speed_cap"):
            if getattr(self, name).shape != (n,):
                raise InputError(f"Timing.{name}: expected shape {(n,)}, got {getattr(self, name).shape}")
        if self.qd.ndim != 2 or self.qd.shape[0] != n or self.qdd.shape != self.qd.shape:
            raise InputError(
                f"Timing.qd, qdd: expected shape ({n}, n), got {self.qd.shape}, {self.qdd.shape}"
            )


def _check_inputs(s, q, speed_cap, velocity_limits, acceleration_limits, tolerance_rel, n_min):
    s = np.asarray(s, dtype=float)
    q = np.asarray(q, dtype=float)
    if s.ndim != 1 or len(s) < n_min:
        raise InputError(f"s: expected shape (N,) with N >= {n_min}, got {s.shape}")
    n_pts = len(s)
    if q.ndim != 2 or q.shape[0] != n_pts or q.shape[1] < 1:
        raise InputError(f"q: expected shape ({n_pts}, n), got {q.shape}")
    dof = q.shape[1]
    arrays = {"s": s, "q": q}
    for name, value, shape in (
        ("speed_cap", speed_cap, (n_pts,)),
        ("velocity_limits", velocity_limits, (dof,)),
        ("acceleration_limits", acceleration_limits, (dof,)),
    ):
        arr = np.asarray(value, dtype=float)
        if arr.shape != shape:
            raise InputError(f"{name}: expected shape {shape}, got {arr.shape}")
        arrays[name] = arr
    for name, arr in arrays.items():
        if not np.all(np.isfinite(arr)):
            raise InputError(f"{name}: contains NaN or infinite values")
    for name in ("speed_cap", "velocity_limits", "acceleration_limits"):
        bad = np.flatnonzero(arrays[name] <= 0.0)
        if bad.size:
            raise InputError(f"{name}: must be > 0, got {arrays[name][bad[0]]:g} at index {bad[0]}")
    steps = np.diff(s)
    if np.any(steps <= 0.0):
        i = int(np.flatnonzero(steps <= 0.0)[0])
        raise InputError(f"s: must strictly increase, got s[{i}] = {s[i]:g} m, s[{i + 1}] = {s[i + 1]:g} m")
    if not (isinstance(tolerance_rel, (int, float)) and 0.0 < tolerance_rel < 1.0):
        raise InputError(f"tolerance_rel: must be in (0, 1), got {tolerance_rel!r}")
    return tuple(arrays[k] for k in ("s", "q", "speed_cap", "velocity_limits", "acceleration_limits"))


@functools.cache
def _toppra():
    """The toppra package and this module's subclasses of it, imported on first use.

    Returned: toppra, the path speed constraint, the free-end TOPPRA and the TOPPRA, both with
    the lean passes of :mod:`refine.timing_passes`, and the spline the TOPPRA runs on.

    toppra imports matplotlib's pyplot when it is imported, for plotting helpers a run never
    calls and at more CPU time than the rest of the timing stage: pyplot is deferred until toppra
    reads from it (:mod:`refine.lazy`), and toppra itself is imported only by a run that times a path.
    """
    from refine.lazy import lean_imports

    with lean_imports():
        import toppra
        import toppra.algorithm
        import toppra.constraint

    class _PathSpeedConstraint(toppra.constraint.LinearConstraint):
        """TOPPRA constraint ``sdot <= cap(s)``: a bound on ``x = sdot^2`` at every gridpoint."""

        def __init__(self, s: Array, cap: Array) -> None:
            super().__init__()
            self.s, self.cap = s, cap
            self.dof = -1  # independent of the path dimension

        def compute_constraint_params(self, path, gridpoints, *args, **kwargs):  # noqa: D102
            cap = np.interp(gridpoints, self.s, self.cap)
            xbound = np.column_stack([np.zeros_like(cap), cap**2])
            return None, None, None, None, None, None, xbound

    class _GridSpline(toppra.SplineInterpolator):
        """toppra's spline through the waypoints, its values at the waypoints evaluated once per order.

        TOPPRA's joint velocity and acceleration constraints and the timing each ask for ``q'``
        and ``q''`` at the gridpoints, the waypoints: at positions equal to the waypoints' to the
        bit, each order is evaluated once and every caller gets a copy of the same values.
        """

        def __call__(self, path_positions, order=0):  # noqa: D102
            grid = self.ss_waypoints
            if (
                isinstance(path_positions, np.ndarray)
                and path_positions.dtype == grid.dtype == np.float64
                and path_positions.shape == grid.shape
                and np.array_equal(path_positions.view(np.uint64), grid.view(np.uint64))
            ):
                at_grid = self.__dict__.setdefault("_at_grid", {})
                if order not in at_grid:
                    at_grid[order] = super().__call__(grid, order)
                return at_grid[order].copy()
            return super().__call__(path_positions, order)

    lean = lean_passes(toppra.algorithm.TOPPRA)  # toppra's passes to the bit, less of its Python

    class _FreeEndTOPPRA(lean):  # type: ignore[misc, valid-type]
        """TOPPRA whose end speed may be anything from 0 up to the ``sd_end`` it is given.

        ``compute_parameterization`` pins the end speed to ``sd_end``; widening the end of the
        controllable sets to ``[0, sd_end]`` lets the greedy forward pass end as fast as it can.
        """

        def compute_controllable_sets(self, sdmin, sdmax):  # noqa: D102
            return super().compute_controllable_sets(0.0, sdmax)

    return toppra, _PathSpeedConstraint, _FreeEndTOPPRA, lean, _GridSpline


@functools.lru_cache(maxsize=32)
def _joint_constraints(velocity_limits: tuple[float, ...], acceleration_limits: tuple[float, ...]):
    """TOPPRA's joint velocity and acceleration constraints for these limits, made once per limits.

    Both hold only their limits (and the discretisation scheme): what they give TOPPRA is computed
    from the path and gridpoints of each call (``compute_constraint_params``), so the same objects
    serve every path with the same limits. Making them checks and formats every limit into a
    description string, for each of the up to :data:`_BETWEEN_ROUNDS` instances of a call.
    """
    toppra = _toppra()[0]
    return (
        toppra.constraint.JointVelocityConstraint(np.array(velocity_limits)),
        toppra.constraint.JointAccelerationConstraint(
            np.array(acceleration_limits), toppra.constraint.DiscretizationType.Interpolation
        ),
    )


def build_toppra(s, q, speed_cap, velocity_limits, acceleration_limits, *, free_end=False):
    """Build the TOPPRA instance without solving it (for inspection and benchmarks).

    Args:
        s: arc length at each waypoint [m], shape (N,), strictly increasing.
        q: joint waypoints [rad], shape (N, n).
        speed_cap: TCP speed cap at each waypoint [m/s], shape (N,).
        velocity_limits: joint speed limits [rad/s], shape (n,).
        acceleration_limits: joint acceleration limits [rad/s^2], shape (n,).
        free_end: let the end speed be anything up to the ``sd_end`` given to
            ``compute_parameterization`` instead of exactly ``sd_end``.

    Returns:
        A ``toppra.algorithm.TOPPRA`` on the spline through (s, q), gridpoints ``s``.
    """
    toppra, _PathSpeedConstraint, _FreeEndTOPPRA, lean, _GridSpline = _toppra()
    path = _GridSpline(s, q)
    velocity, acceleration = _joint_constraints(
        tuple(np.asarray(velocity_limits, dtype=float).tolist()),
        tuple(np.asarray(acceleration_limits, dtype=float).tolist()),
    )
    constraints = [velocity, acceleration, _PathSpeedConstraint(s, speed_cap)]
    algorithm = _FreeEndTOPPRA if free_end else lean
    return algorithm(constraints, path, gridpoints=s, solver_wrapper="seidel")


def _solve_path_speed(instance, sd_start: float, sd_end: float) -> Array:
    """Run TOPPRA; on an uncontrollable start speed retry at the largest controllable one."""
    rc = _toppra()[0].algorithm.ParameterizationReturnCode
    try:
        _, sd, _ = instance.compute_parameterization(sd_start, sd_end)
        data = instance.problem_data
        if data.return_code == rc.FailUncontrollable and data.K is not None and sd_start > 0:
            sd_start = float(np.sqrt(data.K[0, 1]) * (1.0 - 1e-6))
            logger.debug("start speed lowered to the controllable %.4g m/s", sd_start)
            _, sd, _ = instance.compute_parameterization(sd_start, sd_end)
    except Exception as e:
        raise SolverError(f"TOPPRA failed: {e}") from e
    code = instance.problem_data.return_code
    if code != rc.Ok or sd is None or not np.all(np.isfinite(sd)):
        raise SolverError(
            f"TOPPRA found no timing ({code.value}): the joint path cannot be followed within "
            f"the joint velocity and acceleration limits from {sd_start:g} m/s to {sd_end:g} m/s"
        )
    return np.asarray(sd, dtype=float)


def _segment_times(s: Array, speed: Array) -> tuple[Array, Array, Array]:
    """``x = sdot^2`` at the waypoints, the constant ``sddot`` of each segment and the waypoint times."""
    x = speed**2
    ds = np.diff(s)
    sdd = (x[1:] - x[:-1]) / (2.0 * ds)
    mean_speed = 0.5 * (speed[1:] + speed[:-1])
    if np.any(mean_speed <= 0.0):
        i = int(np.flatnonzero(mean_speed <= 0.0)[0])
        raise SolverError(f"TOPPRA stopped the path at s = {s[i]:.4f} m: the timing never ends")
    t = np.concatenate([[0.0], np.cumsum(ds / mean_speed)])
    return x, sdd, t


def _between_waypoint_speed_ratio(
    path, s: Array, q: Array, x: Array, t: Array, vlim: Array, dq: Array, ddq: Array
):
    """Per segment and joint, a bound on the joint speed between the waypoints over its limit [-].

    The larger of the mean speed over the segment, ``|q[k+1] - q[k]| / (t[k+1] - t[k])`` (what a
    controller moving target to target needs), and a bound on the spline's speed ``|q'(s)| sdot(s)``
    inside it: ``q'`` is quadratic on a cubic segment, so its largest magnitude is at an end or where
    ``q''`` (linear) crosses zero; ``sdot^2`` is linear in ``s``, so ``sdot`` is largest at an end.

    Args:
        path: the spline (``toppra.SplineInterpolator``) through ``(s, q)``.
        s: arc length at the waypoints [m], shape (N,).
        q: joints at the waypoints [rad], shape (N, n).
        x: ``sdot^2`` at the waypoints [m^2/s^2], shape (N,).
        t: time at the waypoints [s], shape (N,).
        vlim: joint speed limits [rad/s], shape (n,).
        dq: ``q'`` at the waypoints [rad/m], shape (N, n).
        ddq: ``q''`` at the waypoints [rad/m^2], shape (N, n).

    Returns:
        Shape (N - 1, n).
    """
    mean = np.abs(np.diff(q, axis=0)) / np.diff(t)[:, None]
    a, b = ddq[:-1], ddq[1:]
    turns = a * b < 0.0  # q'' changes sign inside: q' has an extremum there
    with np.errstate(divide="ignore", invalid="ignore"):
        frac = np.where(turns, a / (a - b), 0.0)
    # q' of each joint at its own turning point: its segment's quadratic (Horner, as scipy's PPoly)
    c = path.cspld.c  # (3, N - 1, n): q' = (c0 h + c1) h + c2, h from the segment's start
    h = np.diff(s)[:, None] * np.clip(frac, 0.0, 1.0)
    dq_turn = (c[0] * h + c[1]) * h + c[2]
    dq_max = np.maximum(np.maximum(np.abs(dq[:-1]), np.abs(dq[1:])), np.where(turns, np.abs(dq_turn), 0.0))
    sd_max = np.sqrt(np.maximum(x[:-1], x[1:]))
    return np.maximum(mean, dq_max * sd_max[:, None]) / vlim


def _verify(s: Array, checks) -> None:
    """Raise SolverError at the worst breach among ``(what, unit, values (N, k), limits, slack)``."""
    for what, unit, values, limits, slack in checks:
        limits = np.broadcast_to(limits, values.shape)
        excess = np.abs(values) / limits - (1.0 + slack)
        if np.any(excess > 0):
            i, j = np.unravel_index(np.argmax(excess), excess.shape)
            raise SolverError(
                f"{what.format(j + 1)} {values[i, j]:.6g} {unit} exceeds its limit {limits[i, j]:.6g} "
                f"{unit} at s = {s[i]:.4f} m"
            )


def _at_faster_ends(ratio: Array, speed: Array, between: Array) -> None:
    """Raise ``ratio`` (N, n) at each segment's faster end to the segment's ``between`` (N - 1, n), in place.

    A segment's end is waypoint k+1 where ``speed[k+1] > speed[k]`` [m/s], else waypoint k. A
    waypoint ends at most two segments, and the largest of what it gets is the same in any order
    (``np.maximum.at`` of the ends), so two shifted maxima give it.
    """
    to_end = (speed[1:] > speed[:-1])[:, None]
    np.maximum(ratio[:-1], np.where(to_end, -np.inf, between), out=ratio[:-1])
    np.maximum(ratio[1:], np.where(to_end, between, -np.inf), out=ratio[1:])


def _binding_limit(run: Array, k: int, vel_ratio: Array, acc_ratio: Array) -> str:
    """Name the limit behind a slowdown: what binds at the slowest waypoint, else in the run."""
    candidates = (
        ("joint velocity", vel_ratio[[k]]),
        ("joint acceleration", acc_ratio[[k]]),
        ("joint velocity", vel_ratio[run]),
        ("joint acceleration", acc_ratio[run]),
    )
    for kind, ratio in candidates:
        if ratio.max() >= 1.0 - _BINDING_REL:
            return f"{kind} (joint {int(np.argmax(ratio.max(axis=0))) + 1})"
    kind, ratio = max(candidates[2:], key=lambda c: c[1].max())
    joint = int(np.argmax(ratio.max(axis=0))) + 1
    return f"not explained by limits (closest: {kind} (joint {joint}) at {ratio.max():.0%})"


def _ramp_length(speed: Array, vel_bound: Array) -> int:
    """Waypoints of the ramp from rest: speed keeps rising and no joint velocity binds yet."""
    k = 1
    while k < len(speed) and speed[k] > speed[k - 1] and not vel_bound[k]:
        k += 1
    return k


def _slow_segments(s, speed, ratio, slow, start_stop, vel_ratio, acc_ratio):
    """Split the slow waypoints into runs; name each run's reason.

    With ``start_stop``, a run touching the first (last) waypoint begins (ends) with the ramp from
    (to) rest; the ramp stops where the speed stops rising or a joint velocity limit binds, and the
    rest of such a run is a segment of its own, explained by a limit.
    """
    vel_bound = vel_ratio.max(axis=1) >= 1.0 - _BINDING_REL
    n_pts = len(s)
    pieces = []
    edges = np.diff(np.concatenate([[0], slow.astype(int), [0]]))
    for i0, i1 in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1, strict=True):
        head = tail = None
        if start_stop and i0 == 0:
            head = (0, min(i1, _ramp_length(speed[: i1 + 1], vel_bound) - 1))
            i0 = head[1] + 1
        if start_stop and i1 == n_pts - 1 and i0 <= i1:
            back = _ramp_length(speed[i0:][::-1], vel_bound[i0:][::-1])
            tail = (n_pts - back, n_pts - 1)
            i1 = tail[0] - 1
        pieces += [(head, RAMP)] if head else []
        pieces += [((i0, i1), None)] if i0 <= i1 else []
        pieces += [(tail, RAMP)] if tail else []
    segments = []
    for (a, b), reason in pieces:
        run = np.arange(a, b + 1)
        k = int(run[np.argmin(ratio[run])])
        reason = reason or _binding_limit(run, k, vel_ratio, acc_ratio)
        segments.append(SlowSegment(int(a), int(b), float(s[a]), float(s[b]), float(ratio[k]), reason))
    return tuple(segments)


def time_parameterise(
    s,
    q,
    speed_cap,
    velocity_limits,
    acceleration_limits,
    *,
    tolerance_rel: float = 0.05,
    start_stop: bool = True,
) -> Timing:
    """Time the joint path as fast as the limits allow, never faster than the demonstration.

    Args:
        s: arc length of the CAD path at each waypoint [m], shape (N,), strictly increasing.
        q: joint waypoints [rad], shape (N, n); the TCP follows the CAD path with |dp/ds| = 1.
        speed_cap: demonstrated TCP speed at each waypoint [m/s], shape (N,), > 0; linearly
            interpolated in between.
        velocity_limits: joint speed limits [rad/s], shape (n,), > 0.
        acceleration_limits: joint acceleration limits [rad/s^2], shape (n,), > 0.
        tolerance_rel: a waypoint is slow when speed < (1 - tolerance_rel) * speed_cap [-].
        start_stop: start and end at rest (needs N >= 3). Otherwise start at the cap, lowered
            to what the joint velocity limits and the path ahead allow, and end as fast as the
            cap and the limits allow.

    Returns:
        The timing, verified against the limits at every waypoint; joint speeds also between them.

    Raises:
        InputError: a shape, a non-increasing ``s`` or a non-positive cap or limit.
        SolverError: TOPPRA fails, or its result breaks a limit (the message names the joint,
            ``s`` [m] and the value).
    """
    t_start = time.perf_counter()
    n_min = 3 if start_stop else 2
    checked = _check_inputs(s, q, speed_cap, velocity_limits, acceleration_limits, tolerance_rel, n_min)
    s, q, cap, vlim, alim = checked

    # ---- TOPPRA on the spline through the waypoints, again where joints run too fast in between
    between_cap = np.full(len(s), np.inf)
    for _ in range(_BETWEEN_ROUNDS):
        instance = build_toppra(s, q, np.minimum(cap, between_cap), vlim, alim, free_end=not start_stop)
        dq, ddq = instance.path(s, 1), instance.path(s, 2)
        if start_stop:
            sd_start = sd_end = 0.0
        else:
            with np.errstate(divide="ignore"):
                sd_bound = np.min(vlim / np.abs(dq[[0, -1]]), axis=1)
            sd_start, sd_end = np.minimum(np.minimum(cap, between_cap)[[0, -1]], sd_bound)
        speed = _solve_path_speed(instance, float(sd_start), float(sd_end))
        x, sdd, t = _segment_times(s, speed)
        between = _between_waypoint_speed_ratio(instance.path, s, q, x, t, vlim, dq, ddq)
        excess = between.max(axis=1)
        over = np.flatnonzero(excess > 1.0 + _VELOCITY_SLACK_REL)
        if over.size == 0:
            break
        # joint speeds in a segment scale with sdot: lower both ends by the excess (and a hair)
        factor = 1.0 / (excess[over] * (1.0 + 10 * _VELOCITY_SLACK_REL))
        between_cap[over] = np.minimum(between_cap[over], speed[over] * factor)
        between_cap[over + 1] = np.minimum(between_cap[over + 1], speed[over + 1] * factor)

    # ---- joint velocities and one-sided accelerations
    qd = dq * speed[:, None]
    qdd = ddq * x[:, None] + dq * np.append(sdd, sdd[-1])[:, None]  # segment starting here
    qdd_left = ddq[1:] * x[1:, None] + dq[1:] * sdd[:, None]  # segment ending here
    _verify(
        s,
        [
            ("joint {} velocity", "rad/s", qd, vlim, _VELOCITY_SLACK_REL),
            ("joint {} acceleration", "rad/s^2", qdd, alim, _ACCELERATION_SLACK_REL),
            ("joint {} acceleration", "rad/s^2", qdd_left, alim, _ACCELERATION_SLACK_REL),
            ("TCP speed", "m/s", speed[:, None], cap[:, None], _VELOCITY_SLACK_REL),
            ("joint {} velocity between waypoints", "rad/s", between * vlim, vlim, _VELOCITY_SLACK_REL),
        ],
    )

    # ---- where and why the plan is slower than the demonstration
    ratio = speed / cap
    vel_ratio = np.abs(qd) / vlim
    _at_faster_ends(vel_ratio, speed, between)
    acc_ratio = np.abs(qdd) / alim
    acc_ratio[1:] = np.maximum(acc_ratio[1:], np.abs(qdd_left) / alim)
    slow = ratio < 1.0 - tolerance_rel
    segments = _slow_segments(s, speed, ratio, slow, start_stop, vel_ratio, acc_ratio)
    tracked = np.ones(len(s), dtype=bool)
    for seg in segments:
        if seg.explained:
            tracked[seg.index_start : seg.index_end + 1] = False
    deficit = np.clip(1.0 - ratio[tracked], 0.0, None)
    error_max = float(deficit.max()) if deficit.size else 0.0
    error_mean = float(deficit.mean()) if deficit.size else 0.0

    elapsed = time.perf_counter() - t_start
    logger.info(
        "timed %d waypoints in %.3f s: cycle time %.3f s, %d slow segment(s), tracking error %.1f %%",
        *(len(s), elapsed, t[-1], len(segments), 100 * error_max),
    )
    for seg in segments:
        msg = "slow at s = %.4f..%.4f m, down to %.0f %% of the demo: %s"
        logger.debug(msg, seg.s_start_m, seg.s_end_m, 100 * seg.min_ratio, seg.reason)
    return Timing(
        t=t,
        speed=speed,
        speed_cap=cap.copy(),
        qd=qd,
        qdd=qdd,
        cycle_time_s=float(t[-1]),
        slow_segments=segments,
        speed_tracking_error_rel=error_max,
        solve_time_s=elapsed,
        speed_tracking_error_mean_rel=error_mean,
    )
