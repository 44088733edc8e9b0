r"""Circular moves on the CAD's arcs: where to write them, and the motion a controller runs on them, checked.

Where the path follows a circular arc of the CAD (a DXF ``ARC``, a polyline bulge, a G-code
``G2``/``G3``: the readers keep the arc's ends as waypoints and place the others on it), a
program may write one circular move (RAPID ``MoveC``, KRL ``CIRC``, URScript ``movec``) through a
via target to an end target instead of the straight moves between the waypoints.

**Where** (:func:`arc_pieces`): maximal runs of at least four consecutive waypoints on one circle
(within :data:`ON_CIRCLE_M`, not on a line) that is one of the CAD's arcs
(:data:`CIRCLE_MATCH_M`), cut into pieces whose sweep is at most :data:`MAX_SWEEP_DEG` (below
every controller's limit) and whose one speed (a circular move runs at one: the slowest
segment's, rounded down to the programs' step) stays within ``speed_share`` of every segment's.
Each piece runs from waypoint ``start`` through ``via`` (its middle waypoint) to ``end``.

**The model** (per controller in ``docs/outputs.md``), at the share ``f`` in [0, 1] of the sweep
``φ`` (the controller runs the circle at a constant speed, so ``f`` is also the share of the arc
length): the position ``c + r (cos(fφ) e₁ + sin(fφ) e₂)`` on the circle through the three
targets' positions (centre ``c``, radius ``r``, ``e₁`` towards the start, ``e₂ = n × e₁`` with
``n`` the normal the motion turns about), and the orientation

* :data:`SLERP` (KRL ``CIRC`` with ``$ORI_TYPE = #VAR`` and ``$CIRC_TYPE = #BASE``, URScript
  ``movec`` with ``mode=0``): ``R_s exp(f log(R_sᵀ R_e))`` from the start's to the end's
  orientation in the base, the via's orientation unused;
* :data:`PATH_FRAME` (RAPID ``MoveC`` with ``CirPathMode \PathFrame``): the orientation relative
  to the circle's path frame (which turns by ``fφ`` about ``n``) turned at a constant rate from
  the start's to the end's: ``Rot(n, fφ) R_s exp(f log(R_sᵀ Rot(n, -φ) R_e))``.

**The check** (:func:`check_circular_moves`): every piece is sampled at ``f = i/m``; the joints at
each sample are solved by damped least squares from the refined joints interpolated at the same
place of the arc (no pull to mid-range: the refined branch); at every sample the IK's residual,
the joint-limit margin, the singularity margin and, with a collision model, the clearance along
the joints through the samples; the distance of the circle from the CAD geometry; and at every
refined waypoint inside the piece the angle between the controller's orientation and the refined
one (tool axis and whole rotation), and between it and the demonstration's against the cone.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from refine.optimise.controller_line import IK_TOLERANCE, JOINT_TOLERANCE_RAD, SINGULARITY_TOLERANCE
from refine.optimise.verify import singularity_measures
from refine.robot.kinematics import TcpKinematics, solve_ik_batch
from refine.settings import Tolerances
from refine.types import Array

SLERP = "slerp"
"""Orientation model: the start's orientation turned to the end's at a constant rate, in the base."""
PATH_FRAME = "path_frame"
"""Orientation model: the start's orientation in the circle's path frame turned to the end's."""
MODELS = (SLERP, PATH_FRAME)

MODEL_OF_FORMAT = {"rapid": PATH_FRAME, "krl": SLERP, "urscript": SLERP}
"""The orientation model each program format's circular move is written for."""

ON_CIRCLE_M = 5e-6
"""A waypoint this close to a circle is on it [m] (the readers flatten arcs within 1 µm)."""
MAX_RADIUS_M = 5.0
"""Three waypoints on a circle of a larger radius are on a line, not an arc [m]."""
MAX_SWEEP_DEG = 90.0
"""Largest sweep of one circular move [deg]: below ABB's 240 deg and KUKA's and UR's 360 deg."""
SAMPLES_PER_SEGMENT = 8
"""Samples of the circle per refined segment the piece replaces."""
IK_FAILED = 1e-6
"""A sample whose IK stays further than this from the circle [m and rad stacked] has no answer."""
CAD_TOLERANCE_M = 1e-5
"""Largest distance of the circle from the CAD geometry a piece may have [m]."""


@dataclass(frozen=True)
class ArcPiece:
    """One circular move: waypoints ``start`` -> ``via`` -> ``end`` on one circle.

    Attributes:
        start, via, end: waypoint indices (start < via < end).
        centre: the circle's centre in {F} [m], (3,).
        radius_m: its radius [m].
        normal: the unit axis the motion turns about (right hand), (3,).
        sweep_rad: the angle swept from start to end [rad], in (0, 2 pi).
        speed_m_s: the move's one programmed speed, the slowest of its segments' planned rounded
            down to the programs' speed step [m/s].
        start_point: the start target's position in {F} [m], (3,) (where the sweep is counted from).
    """

    start: int
    via: int
    end: int
    centre: Array
    radius_m: float
    normal: Array
    sweep_rad: float
    speed_m_s: float
    start_point: Array

    @property
    def length_m(self) -> float:
        """The arc's length [m]."""
        return self.radius_m * self.sweep_rad


def circle_through(p0: Array, pv: Array, p1: Array) -> tuple[Array, float, Array, float] | None:
    """The circle from ``p0`` through ``pv`` to ``p1``: centre, radius, turning normal, sweep [rad].

    None when the three points are (nearly) on a line (radius above :data:`MAX_RADIUS_M`).
    """
    b, c = pv - p0, p1 - p0
    w = np.cross(b, c)
    ww = float(w @ w)
    if ww <= 0.0:
        return None
    centre = p0 + np.cross(float(b @ b) * c - float(c @ c) * b, w) / (2.0 * ww)
    radius = float(np.linalg.norm(p0 - centre))
    if radius > MAX_RADIUS_M:
        return None
    normal = w / math.sqrt(ww)  # p0 -> pv -> p1 turns positively about w: the shorter way through pv
    e1 = (p0 - centre) / radius
    e2 = np.cross(normal, e1)
    d = p1 - centre
    sweep = math.atan2(float(d @ e2), float(d @ e1)) % (2.0 * math.pi)
    return centre, radius, normal, sweep


def _angles(points: Array, centre: Array, normal: Array) -> Array:
    """The angle of every point about the circle's normal from the first one [rad], unwrapped."""
    e1 = points[0] - centre
    e1 = e1 / np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    d = points - centre
    return np.unwrap(np.arctan2(d @ e2, d @ e1))


def _on_circle(points: Array) -> tuple[Array, float, Array, float] | None:
    """The circle ``points`` (K >= 3, in order) lie on, turning one way; None when they do not."""
    circle = circle_through(points[0], points[len(points) // 2], points[-1])
    if circle is None:
        return None
    centre, radius, normal, _ = circle
    d = points - centre
    off_plane = np.abs(d @ normal)
    off_circle = np.abs(np.linalg.norm(d - np.outer(d @ normal, normal), axis=1) - radius)
    if max(off_plane.max(), off_circle.max()) > ON_CIRCLE_M:
        return None
    ang = _angles(points, centre, normal)
    if np.any(np.diff(ang) <= 0.0):
        return None
    return centre, radius, normal, float(ang[-1])


def _four_on_circle(positions: Array) -> NDArray[np.bool_]:
    """Which windows of four waypoints ``a..a+3`` may lie on one circle, all at once, (N-3,).

    The distances of :func:`_on_circle` for every window, vectorised; a window is kept unless it
    is off its circle by twice :data:`ON_CIRCLE_M` or its radius is twice :data:`MAX_RADIUS_M`
    (rounding cannot move a figure that far), so every window :func:`_on_circle` accepts is kept
    and the kept ones are decided by it.
    """
    p0, pv, p1 = positions[:-3], positions[2:-1], positions[3:]  # _on_circle's three: first, middle, last
    b, c = pv - p0, p1 - p0
    w = np.cross(b, c)
    ww = np.einsum("ij,ij->i", w, w)
    safe = np.where(ww > 0.0, ww, 1.0)
    bb, cc = np.einsum("ij,ij->i", b, b), np.einsum("ij,ij->i", c, c)
    centre = p0 + np.cross(bb[:, None] * c - cc[:, None] * b, w) / (2.0 * safe[:, None])
    radius = np.linalg.norm(p0 - centre, axis=1)
    normal = w / np.sqrt(safe)[:, None]
    windows = np.stack([positions[i : len(positions) - 3 + i] for i in range(4)], axis=1)  # (N-3, 4, 3)
    d = windows - centre[:, None, :]
    along = np.einsum("kij,kj->ki", d, normal)
    off = np.maximum(
        np.abs(along), np.abs(np.linalg.norm(d - along[..., None] * normal[:, None, :], axis=2) - radius[:, None])
    ).max(axis=1)
    return (ww > 0.0) & (radius <= 2.0 * MAX_RADIUS_M) & (off <= 2.0 * ON_CIRCLE_M)


def arc_runs(positions: Array) -> list[tuple[int, int]]:
    """Maximal runs ``(a, b)`` of at least four waypoints ``a..b`` (b - a >= 3) on one circle, in order."""
    positions = np.asarray(positions, dtype=float)
    runs: list[tuple[int, int]] = []
    a, n = 0, len(positions)
    maybe = _four_on_circle(positions) if n >= 4 else np.zeros(0, dtype=bool)
    while a + 3 < n:
        if not maybe[a] or _on_circle(positions[a : a + 4]) is None:  # any three points are on a circle: four tell
            a += 1
            continue
        b = a + 3
        while b + 1 < n and _on_circle(positions[a : b + 2]) is not None:
            b += 1
        runs.append((a, b))
        a = b  # an arc's end may start the next arc (two arcs meeting at a feature point)
    return runs


CIRCLE_MATCH_M = 1e-5
"""A run's circle is the CAD's arc when their centres and radii agree to this [m] (and their planes)."""


def _is_cad_circle(centre: Array, radius: float, normal: Array, circles: list) -> bool:
    return any(
        np.linalg.norm(centre - c) <= CIRCLE_MATCH_M
        and abs(radius - r) <= CIRCLE_MATCH_M
        and np.linalg.norm(np.cross(normal, n / np.linalg.norm(n))) <= CIRCLE_MATCH_M / max(radius, 1e-3)
        for c, r, n in circles
    )


SPEED_RESOLUTION_M_S = 1e-4
"""The programs' speed step [m/s]: a circular move's speed is its slowest segment's rounded down to it."""


def _one_speed(v: Array, step: float) -> float:
    """A circular move's one speed: the slowest of ``v`` rounded down to ``step`` (at least one step)."""
    return max(math.floor(float(v.min()) / step + 1e-9), 1) * step


def arc_pieces(
    positions: Array,
    segment_speeds: Array,
    speed_share: float,
    circles: list | None = None,
    speed_resolution_m_s: float = SPEED_RESOLUTION_M_S,
) -> list[ArcPiece]:
    """The circular moves of a path: its arcs cut by sweep and speed (see the module notes).

    Args:
        positions: the waypoints' CAD positions in {F} [m], (N, 3).
        segment_speeds: planned speed of every segment k -> k+1 [m/s], (N-1,).
        speed_share: largest shortfall of the move's one speed below a segment's planned speed [-].
        circles: the CAD's arcs, ``(centre [m] (3,), radius [m], normal (3,))`` each
            (:func:`refine.cad.cad_circles`): only runs on one of them become pieces (waypoints on a
            spline or a mesh boundary that happen to lie on a circle do not); None for every run.
        speed_resolution_m_s: the programs' speed step [m/s]: the move's speed, its slowest
            segment's rounded down to it, must stay within ``speed_share`` of every segment's.

    Returns:
        The pieces in path order; waypoints outside them keep their straight moves.
    """
    if circles is not None and not circles:
        return []  # no CAD arc: no run can match one (the filter below drops every run)
    positions = np.asarray(positions, dtype=float)
    v = np.asarray(segment_speeds, dtype=float)
    pieces: list[ArcPiece] = []
    max_sweep = math.radians(MAX_SWEEP_DEG)
    for a, b in arc_runs(positions):
        found = _on_circle(positions[a : b + 1])
        assert found is not None
        centre, radius, normal, _ = found
        if circles is not None and not _is_cad_circle(centre, radius, normal, circles):
            continue
        ang = _angles(positions[a : b + 1], centre, normal)
        k0 = a
        while k0 + 2 <= b:
            k1 = k0 + 1
            while (
                k1 + 1 <= b
                and ang[k1 + 1 - a] - ang[k0 - a] <= max_sweep * (1.0 + 1e-9)
                and _one_speed(v[k0 : k1 + 1], speed_resolution_m_s)
                >= (1.0 - speed_share) * v[k0 : k1 + 1].max()
            ):
                k1 += 1
            if k1 - k0 < 2:
                k0 += 1
                continue
            via = (k0 + k1) // 2
            circle = circle_through(positions[k0], positions[via], positions[k1])
            assert circle is not None
            c, r, nrm, sweep = circle
            pieces.append(
                ArcPiece(
                    k0,
                    via,
                    k1,
                    c,
                    r,
                    nrm,
                    sweep,
                    _one_speed(v[k0:k1], speed_resolution_m_s),
                    positions[k0].copy(),
                )
            )
            k0 = k1
    return pieces


def circle_points(piece: ArcPiece, theta: Array) -> Array:
    """Points of the piece's circle at the angles ``theta`` from its start [rad], (M, 3)."""
    e1 = (piece.start_point - piece.centre) / piece.radius_m
    e2 = np.cross(piece.normal, e1)
    theta = np.asarray(theta, dtype=float)
    return piece.centre + piece.radius_m * (np.outer(np.cos(theta), e1) + np.outer(np.sin(theta), e2))


def arc_poses(piece: ArcPiece, R_start: Array, R_end: Array, f: Array, model: str) -> Array:
    """Poses (M, 4, 4) of the controller's circular move at the shares ``f`` (M,) of its sweep.

    Args:
        piece: the move.
        R_start: orientation R_F_TCP of its start target, (3, 3).
        R_end: orientation R_F_TCP of its end target, (3, 3).
        f: shares of the sweep in [0, 1], (M,).
        model: :data:`SLERP` or :data:`PATH_FRAME` (see the module notes).
    """
    if model not in MODELS:
        raise ValueError(f"circular move model {model!r} is not one of {MODELS}")
    f = np.asarray(f, dtype=float)
    theta = f * piece.sweep_rad
    out = np.zeros((len(f), 4, 4))
    out[:, 3, 3] = 1.0
    out[:, :3, 3] = circle_points(piece, theta)
    Rs, Re = Rotation.from_matrix(R_start), Rotation.from_matrix(R_end)
    if model == SLERP:
        step = (Rs.inv() * Re).as_rotvec()
        out[:, :3, :3] = (Rs * Rotation.from_rotvec(np.outer(f, step))).as_matrix()
    else:
        turn = Rotation.from_rotvec(np.outer(theta, piece.normal))
        end_in_start_frame = Rotation.from_rotvec(-piece.sweep_rad * piece.normal) * Re
        step = (Rs.inv() * end_in_start_frame).as_rotvec()
        out[:, :3, :3] = (turn * Rs * Rotation.from_rotvec(np.outer(f, step))).as_matrix()
    return out


@dataclass(frozen=True)
class ArcCheck:
    """One circular move as the controller runs it, checked.

    Attributes:
        piece: the move.
        model: its orientation model.
        ik_error: the largest IK residual on it [m and rad stacked].
        joint_margin_rad: the least joint-limit margin on it [rad].
        singularity: the least scaled manipulability on it [-].
        cad_deviation_m: the largest distance of its circle from the CAD geometry [m] (NaN without it).
        axis_vs_refined_deg: at the refined waypoints inside it, the largest angle between its tool
            axis and the refined one [deg].
        rotation_vs_refined_deg: the same for the whole orientation [deg].
        vs_demo_deg: the largest angle from the demonstration's orientation at those waypoints (the
            tool axis's when the spin is free) [deg], for the cone.
        clearance_m: the least clearance by the dense check along its joints [m]; None when the
            motion bound proved every margin (or without a collision check).
        q: the joints at its samples [rad], (M, n).
        reasons: what it breaks (empty when it passes).
    """

    piece: ArcPiece
    model: str
    ik_error: float
    joint_margin_rad: float
    singularity: float
    cad_deviation_m: float
    axis_vs_refined_deg: float
    rotation_vs_refined_deg: float
    vs_demo_deg: float
    clearance_m: float | None
    q: Array
    reasons: tuple[str, ...]

    @property
    def ok(self) -> bool:
        """True when the move breaks no tolerance."""
        return not self.reasons

    def as_json(self) -> dict:
        """Its figures, for ``result.json`` and the benchmark."""
        p = self.piece
        return {
            "start": p.start,
            "via": p.via,
            "end": p.end,
            "model": self.model,
            "radius_m": p.radius_m,
            "sweep_deg": math.degrees(p.sweep_rad),
            "speed_m_s": p.speed_m_s,
            "max_ik_error": self.ik_error,
            "min_joint_margin_rad": self.joint_margin_rad,
            "min_singularity_measure": self.singularity,
            "max_cad_deviation_m": self.cad_deviation_m,
            "max_axis_vs_refined_deg": self.axis_vs_refined_deg,
            "max_rotation_vs_refined_deg": self.rotation_vs_refined_deg,
            "max_vs_demo_deg": self.vs_demo_deg,
            "min_clearance_m": self.clearance_m,
            "ok": self.ok,
            "reasons": list(self.reasons),
        }


def distance_to_polyline(points: Array, polyline: Array) -> Array:
    """Distance of every point (M, 3) from the polyline (K, 3), K >= 2 [m], (M,)."""
    a, b = polyline[:-1], polyline[1:]
    d = b - a
    dd = np.maximum(np.einsum("ij,ij->i", d, d), 1e-300)
    rel = points[:, None, :] - a[None]
    t = np.clip(np.einsum("mkj,kj->mk", rel, d) / dd, 0.0, 1.0)
    foot = a[None] + t[..., None] * d[None]
    return np.linalg.norm(points[:, None, :] - foot, axis=2).min(axis=1)


def check_circular_moves(
    kin: TcpKinematics,
    q: Array,
    poses: Array,
    pieces: list[ArcPiece],
    model: str,
    tolerances: Tolerances,
    *,
    rotations_demo: Array | None = None,
    axisymmetric: bool = False,
    exact: Array | None = None,
    clearance: Callable[[Array], tuple[float | None, float]] | None = None,
) -> list[ArcCheck]:
    """Check every circular move as the controller runs it (see the module notes).

    Args:
        kin: TCP kinematics of the robot, base and tool.
        q: refined joints per waypoint [rad], (N, n).
        poses: refined TCP poses T_F_TCP per waypoint, (N, 4, 4) (the targets the program writes).
        pieces: the moves (:func:`arc_pieces`).
        model: the controller's orientation model, :data:`SLERP` or :data:`PATH_FRAME`.
        tolerances: joint margin, singularity margin and orientation cone.
        rotations_demo: demonstrated orientation per waypoint, (N, 3, 3), for the cone; None to skip.
        axisymmetric: the spin about the tool axis is free (the cone is the tool axis's).
        exact: the CAD geometry in {F} [m], (M, 3), a dense polyline; None to skip that figure.
        clearance: joints (K, n) [rad] -> (None when every margin is proved kept, else the least
            clearance of that joint path by the dense check [m]; the tolerance a clearance may fall
            below 0 [m]). None without a collision check.

    Returns:
        One check per piece.
    """
    q = np.asarray(q, dtype=float)
    spec = kin.robot.spec
    margin = math.radians(tolerances.joint_margin_deg) - JOINT_TOLERANCE_RAD
    out = []
    for piece in pieces:
        k = np.arange(piece.start, piece.end + 1)
        ang = _angles(poses[k, :3, 3], piece.centre, piece.normal)
        share = ang / ang[-1]  # where each refined waypoint lies on the move
        m = SAMPLES_PER_SEGMENT * (piece.end - piece.start)
        f = np.arange(m + 1) / m
        targets = arc_poses(piece, poses[piece.start, :3, :3], poses[piece.end, :3, :3], f, model)
        # the refined joints at the same place of the arc: the IK's start, on the refined branch
        seed = np.column_stack([np.interp(f, share, q[k, j]) for j in range(q.shape[1])])
        q_arc, err = solve_ik_batch(
            kin,
            targets,
            seed,
            spec.lower,
            spec.upper,
            tol=IK_TOLERANCE,
            max_iterations=60,
            nullspace_gain=0.0,
        )
        margins = float(np.minimum(q_arc - spec.lower, spec.upper - q_arc).min())
        sing, _ = singularity_measures(kin, q_arc, smallest=False)
        held = arc_poses(piece, poses[piece.start, :3, :3], poses[piece.end, :3, :3], share, model)[:, :3, :3]
        axis = np.degrees(
            np.arccos(np.clip(np.einsum("ki,ki->k", held[:, :, 2], poses[k, :3, 2]), -1.0, 1.0))
        )
        whole = np.degrees(
            Rotation.from_matrix(np.einsum("kji,kjl->kil", held, poses[k, :3, :3])).magnitude()
        )
        demo = math.nan
        if rotations_demo is not None:
            Rd = np.asarray(rotations_demo)[k]
            if axisymmetric:
                demo = float(
                    np.degrees(
                        np.arccos(np.clip(np.einsum("ki,ki->k", held[:, :, 2], Rd[:, :, 2]), -1, 1))
                    ).max()
                )
            else:
                demo = float(
                    np.degrees(Rotation.from_matrix(np.einsum("kji,kjl->kil", held, Rd)).magnitude()).max()
                )
        cad = (
            math.nan
            if exact is None
            else float(distance_to_polyline(targets[:, :3, 3], np.asarray(exact)).max())
        )
        clear = None
        reasons = []
        if clearance is not None:
            clear, tolerance_m = clearance(q_arc)
            if clear is not None and clear < -tolerance_m:
                reasons.append(f"clearance on the circular move {clear * 1e3:.3f} mm")
        if float(err.max()) > IK_FAILED:
            reasons.append(f"no IK on the circular move (residual {float(err.max()):.3g} m+rad)")
        if margins < margin:
            reasons.append(f"joint limit on the circular move (margin {math.degrees(margins):.4f} deg)")
        if float(sing.min()) < tolerances.singularity_margin - SINGULARITY_TOLERANCE:
            reasons.append(f"singularity on the circular move (measure {float(sing.min()):.4g})")
        if not (cad <= CAD_TOLERANCE_M) and exact is not None:
            reasons.append(
                f"circular move {cad * 1e3:.4f} mm off the CAD arc (limit {CAD_TOLERANCE_M * 1e3:g} mm)"
            )
        if demo > tolerances.orientation_deg + 1e-9:
            reasons.append(
                f"circular move's orientation {demo:.3f} deg from the demonstration (cone {tolerances.orientation_deg:g} deg)"
            )
        out.append(
            ArcCheck(
                piece,
                model,
                float(err.max()),
                margins,
                float(sing.min()),
                cad,
                float(axis.max()),
                float(whole.max()),
                demo,
                clear,
                q_arc,
                tuple(reasons),
            )
        )
    return out
