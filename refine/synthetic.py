"""Generated paths for tests, benchmarks and the simulated problems under ``problems/``.

:func:`wave_path` stands in for the output of :func:`refine.fuse.fusion.fuse` when a test or a benchmark
needs a refinement problem of a chosen size without reading files. The other helpers are shared by
the problem generators: footprints of closed beads (:func:`rounded_rectangle`), a worker's smooth
periodic variation (:func:`periodic_wave`), tool orientations of a dragged nozzle
(:func:`tool_rotations`), and a check that the robot can follow a generated path
(:func:`reachability_report`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from refine.frames import matrix_from_zyx, rotation_about, rotvec_from_matrix
from refine.optimise.seed import ik_chain
from refine.optimise.verify import singularity_measures
from refine.paths import FusedPath
from refine.robot.kinematics import TcpKinematics
from refine.types import Array

if TYPE_CHECKING:
    from refine.collision import CollisionModel


def wave_path(
    n_waypoints: int,
    *,
    length_m: float = 1.0,
    centre: tuple[float, float, float] = (1.3, 0.0, 0.6),
    amplitude_m: float = 0.05,
    wavelength_m: float = 0.5,
    tilt_deg: float = 12.0,
    speed_m_s: float = 0.1,
) -> FusedPath:
    """A horizontal sine wave along world y with the tool pointing down and following the tangent.

    Args:
        n_waypoints: number of waypoints N (>= 3).
        length_m: extent along y [m] (the arc length is a little longer).
        centre: centre of the wave in {F} [m].
        amplitude_m: amplitude of the wave in x [m].
        wavelength_m: wavelength along y [m].
        tilt_deg: drag angle: the tool axis leans back against the travel direction [deg].
        speed_m_s: constant demonstrated speed [m/s].

    Returns:
        A FusedPath with N waypoints at equal arc-length steps (to 1e-6 relative).
    """
    # dense curve, then equal arc-length resampling
    y = np.linspace(-length_m / 2, length_m / 2, 20 * n_waypoints)
    x = centre[0] + amplitude_m * np.sin(2 * np.pi * y / wavelength_m)
    dense = np.column_stack([x, centre[1] + y, np.full_like(y, centre[2])])
    s_dense = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(dense, axis=0), axis=1))])
    s = np.linspace(0.0, s_dense[-1], n_waypoints)
    positions = np.column_stack([np.interp(s, s_dense, dense[:, i]) for i in range(3)])
    tangent = np.gradient(positions, axis=0)
    heading = np.arctan2(tangent[:, 1], tangent[:, 0])
    # tool x along the travel direction, tool z down, leaning back by the tilt
    rotations = (
        matrix_from_zyx(heading, np.zeros_like(heading), np.zeros_like(heading))
        @ rotation_about("x", np.pi)
        @ rotation_about("y", -np.radians(tilt_deg))
    )
    speed = np.full(n_waypoints, speed_m_s)
    return FusedPath(
        s=s,
        positions=positions,
        rotations=rotations,
        speed=speed,
        t_demo=s / speed_m_s,
        residual=np.zeros(n_waypoints),
    )


# ---- closed beads: footprints, worker variation, tool orientations ---------------------------------


def rounded_rectangle(
    half_u: float, half_v: float, r: float, n: int
) -> tuple[Array, Array, Array, Array, NDArray[np.bool_], float]:
    """``n`` points of a rounded rectangle at equal arc length, counter-clockwise from (0, -half_v).

    The rectangle is centred on the origin with its sides along the axes; its four corners are
    quarter circles. Point k lies at arc length ``k L / n`` from the middle of the bottom edge.

    Args:
        half_u: half the extent along the first axis [m] (> ``r``).
        half_v: half the extent along the second axis [m] (> ``r``).
        r: corner radius [m] (> 0).
        n: number of points (>= 1).

    Returns:
        u, v: coordinates of the points [m], each (n,).
        du, dv: unit tangents along the travel, each (n,).
        corner: whether each point lies on a corner arc, (n,).
        perimeter: the length L of the closed curve [m].
    """
    a, b = half_u - r, half_v - r
    # (length, kind, origin, extra): straights carry their start point and direction, arcs their
    # centre and start angle; the counter-clockwise order starts in the middle of the bottom edge.
    pieces = [
        (a, "line", (0.0, -half_v), (1.0, 0.0)),
        (0.5 * math.pi * r, "arc", (a, -b), -0.5 * math.pi),
        (2 * b, "line", (half_u, -b), (0.0, 1.0)),
        (0.5 * math.pi * r, "arc", (a, b), 0.0),
        (2 * a, "line", (a, half_v), (-1.0, 0.0)),
        (0.5 * math.pi * r, "arc", (-a, b), 0.5 * math.pi),
        (2 * b, "line", (-half_u, b), (0.0, -1.0)),
        (0.5 * math.pi * r, "arc", (-a, -b), math.pi),
        (a, "line", (-a, -half_v), (1.0, 0.0)),
    ]
    perimeter = sum(p[0] for p in pieces)
    sigma = np.arange(n) * perimeter / n
    u, v, du, dv = (np.empty(n) for _ in range(4))
    corner = np.zeros(n, dtype=bool)
    start = 0.0
    for length, kind, origin, extra in pieces:
        m = (sigma >= start) & (sigma < start + length)
        d = sigma[m] - start
        if kind == "line":
            u[m], v[m] = origin[0] + d * extra[0], origin[1] + d * extra[1]
            du[m], dv[m] = extra
        else:
            phi = extra + d / r
            u[m], v[m] = origin[0] + r * np.cos(phi), origin[1] + r * np.sin(phi)
            du[m], dv[m] = -np.sin(phi), np.cos(phi)
            corner[m] = True
        start += length
    return u, v, du, dv, corner, perimeter


def periodic_wave(
    sigma: ArrayLike, perimeter: float, amplitudes: Sequence[float], rng: np.random.Generator
) -> Array:
    """A smooth wander that closes on itself: sines with 1, 2, ... periods per lap.

    One phase per amplitude is drawn from ``rng`` (uniform in [0, 2π)), in order, so the draw
    advances ``rng`` by ``len(amplitudes)`` numbers whatever the amplitudes are (a zero amplitude
    still consumes its phase).

    Args:
        sigma: arc length along the closed path [m], (N,).
        perimeter: length of the lap [m].
        amplitudes: amplitude of the k-th harmonic (k = 1, 2, ...), in the unit wanted.
        rng: random generator for the phases.

    Returns:
        the sum of ``a_k sin(2π k σ / L + φ_k)``, (N,).
    """
    sigma = np.asarray(sigma, dtype=float)
    phases = rng.uniform(0.0, 2.0 * math.pi, size=len(amplitudes))
    return sum(  # type: ignore[return-value]
        a * np.sin(2.0 * math.pi * (k + 1) * sigma / perimeter + p)
        for k, (a, p) in enumerate(zip(amplitudes, phases, strict=True))
    )


def tool_rotations(
    tangents: ArrayLike, normals: ArrayLike, drag_rad: ArrayLike, *, project: bool = False
) -> Array:
    """Tool orientations R_F_TCP for a bead: z into the surface, tilted back by the drag angle.

    The tool z axis points against the surface normal, leaned back against the travel direction
    by the drag angle (the nozzle points at the bead already laid); the x axis follows the travel.

    Args:
        tangents: unit travel directions, (N, 3).
        normals: unit surface normals pointing out of the surface (towards the tool), (N, 3).
        drag_rad: drag angle per point [rad], (N,).
        project: first make the tangents orthogonal to the normals (and unit again); leave it off
            when they already are (an analytic surface), so no rounding is added.

    Returns:
        rotation matrices (N, 3, 3), columns the tool x, y, z axes in {F}.
    """
    tangents = np.asarray(tangents, dtype=float)
    normals = np.asarray(normals, dtype=float)
    drag_rad = np.asarray(drag_rad, dtype=float)
    if project:
        tangents = tangents - np.einsum("ij,ij->i", tangents, normals)[:, None] * normals
        tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    ca, sa = np.cos(drag_rad)[:, None], np.sin(drag_rad)[:, None]
    z = -ca * normals - sa * tangents
    x = ca * tangents - sa * normals
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=-1)


# ---- reachability of a generated path ----------------------------------------------------------


@dataclass(frozen=True)
class Reachability:
    """What chained IK along a generated path found.

    Attributes:
        qs: joints per target [rad], (N, n).
        errors: pose error norm per target (position [m] and angle [rad] stacked), (N,).
        chain_errors: the same straight from the chain, before any polishing, (N,).
        joint_margins: distance of every joint to its nearer limit [rad], (N, n).
        manipulability: scaled manipulability per target [-], (N,).
        sigma_min: smallest singular value of the scaled TCP Jacobian per target [-], (N,).
        max_step_deg: largest change of any joint between consecutive targets [deg].
        clearance: per cell object, the smallest signed distance [m] to a robot link or tool shape
            over all targets and that body's label; None when no collision model was given.
    """

    qs: Array
    errors: Array
    chain_errors: Array
    joint_margins: Array
    manipulability: Array
    sigma_min: Array
    max_step_deg: float
    clearance: dict[str, tuple[float, str]] | None = None

    @property
    def worst_joint(self) -> int:
        """The joint (1-based) with the smallest limit margin."""
        return int(np.unravel_index(np.argmin(self.joint_margins), self.joint_margins.shape)[1]) + 1


def polish_ik(kin: TcpKinematics, T_target: Array, q: Array, iterations: int = 5) -> tuple[Array, float]:
    """Minimum-norm Gauss-Newton steps on the TCP pose, from a nearly converged ``q``.

    :func:`refine.robot.kinematics.solve_ik` stops at its tolerance (1e-6); a few Gauss-Newton steps
    from there take the error down to rounding, without joint limits.

    Args:
        kin: TCP kinematics.
        T_target: wanted T_F_TCP, (4, 4).
        q: start joints [rad], (n,).
        iterations: number of steps.

    Returns:
        joints [rad] (n,) and the remaining pose error norm (position [m] and angle [rad] stacked).
    """

    def error(q: Array) -> Array:
        T = kin.pose(q)
        return np.concatenate(
            [T_target[:3, 3] - T[:3, 3], rotvec_from_matrix(T_target[:3, :3] @ T[:3, :3].T)]
        )

    for _ in range(iterations):
        q = q + np.linalg.pinv(kin.jacobian(q)) @ error(q)
    return q, float(np.linalg.norm(error(q)))


def reachability_report(
    kin: TcpKinematics,
    targets: ArrayLike,
    *,
    joint_margin_rad: float,
    starts: list[Array],
    collision: CollisionModel | None = None,
    polish_iterations: int = 0,
) -> Reachability:
    """Chain IK along target TCP poses and measure how well the robot can follow them.

    IK is chained with :func:`refine.optimise.seed.ik_chain` inside the joint limits shrunk by
    ``joint_margin_rad``; optionally each solution is polished (:func:`polish_ik`). The
    singularity measures come from :func:`refine.optimise.verify.singularity_measures`, the
    clearance from :meth:`refine.collision.CollisionModel.contacts` (every checked pair between a
    moving body and a cell object; the model's own rules decide which pairs are checked).

    Args:
        kin: TCP kinematics of the robot in the world with its tool.
        targets: wanted T_F_TCP per target, (N, 4, 4).
        joint_margin_rad: margin kept from every joint limit [rad].
        starts: candidate start joints for the first target [rad], each (n,).
        collision: collision model of the cell, or None to skip the clearance.
        polish_iterations: Gauss-Newton steps per target after the chain (0: none).

    Returns:
        the figures, see :class:`Reachability`.
    """
    targets = np.asarray(targets, dtype=float)
    spec = kin.robot.spec
    lower, upper = spec.lower + joint_margin_rad, spec.upper - joint_margin_rad
    qs, chain_errors = ik_chain(kin, targets, lower, upper, starts)
    errors = chain_errors.copy()
    if polish_iterations > 0:
        for k, T in enumerate(targets):
            qs[k], errors[k] = polish_ik(kin, T, qs[k], polish_iterations)
    margins = np.minimum(qs - spec.lower, spec.upper - qs)
    manipulability, sigma_min = singularity_measures(kin, qs)
    steps = np.degrees(np.abs(np.diff(qs, axis=0)).max(axis=1)) if len(qs) > 1 else np.zeros(1)
    clearance = None
    if collision is not None:
        cell = [b for b in collision.bodies if b.kind == "cell"]
        clearance = {b.name: (math.inf, "") for b in cell}
        names = set(clearance)
        for q in qs:
            for c in collision.contacts(q, math.inf):
                if c.other in names and c.distance_m < clearance[c.other][0]:
                    body = c.body if c.body.startswith("tool:") else f"{c.body}/{c.body_shape}"
                    clearance[c.other] = (c.distance_m, body)
    return Reachability(
        qs=qs,
        errors=errors,
        chain_errors=chain_errors,
        joint_margins=margins,
        manipulability=manipulability,
        sigma_min=sigma_min,
        max_step_deg=float(steps.max()),
        clearance=clearance,
    )


def problem_reachability(problem, targets: ArrayLike, seed: int) -> tuple[Reachability, bool]:  # noqa: ANN001
    """:func:`reachability_report` of a loaded problem's robot, tool and cell along target TCP poses.

    The chain starts from :func:`refine.optimise.seed.start_candidates` around ``robot.home_deg``;
    the problem's joint margin, singularity margin and cell margin decide whether it is reachable.

    Args:
        problem: a :class:`refine.problem.Problem` with a registry robot.
        targets: wanted T_F_TCP per target, (N, 4, 4).
        seed: seed of the start candidates.

    Returns:
        The report, and whether every target is reached within all the problem's margins.
    """
    from refine.collision import CollisionModel
    from refine.optimise.seed import start_candidates
    from refine.robot.registry import load_robot

    robot = load_robot(problem.robot.model)
    kin = TcpKinematics(robot, problem.robot.base_in_world, problem.tool.tcp_in_flange, problem.tool.tcp_in_world)
    margin = math.radians(problem.tolerances.joint_margin_deg)
    collision = CollisionModel.for_problem(problem, robot)
    starts = start_candidates(
        robot.spec.lower + margin,
        robot.spec.upper - margin,
        np.radians(robot.spec.from_controller(problem.robot.home_deg)),
        seed=seed,
    )
    report = reachability_report(kin, targets, joint_margin_rad=margin, starts=starts, collision=collision)
    ok = bool(
        report.errors.max() < 1e-6
        and report.joint_margins.min() > margin
        and report.manipulability.min() > problem.tolerances.singularity_margin
        and min(d for d, _ in (report.clearance or {}).values()) > problem.collision.margin_m
    )
    return report, ok


# ---- small problem folders for batches ------------------------------------------------------------


def write_line_problem(
    folder: str | Path,
    *,
    start: Sequence[float] = (0.6, -0.1, 0.3),
    end: Sequence[float] = (0.6, 0.1, 0.3),
    tilt_deg: float = 10.0,
    speed_m_s: float = 0.1,
    robot: str = "ur10e",
    program: str = "urscript",
    spacing_m: float = 0.005,
    rate_hz: float = 100.0,
    noise_m: float = 2e-5,
    noise_deg: float = 0.005,
    seed: int = 0,
) -> Path:
    """Write a small problem folder: a straight bead with a clean demonstration.

    The CAD path is ``path.csv`` (two points, mm); the demonstration ``demo.csv`` is the TCP itself
    with a little tracker noise
    (tracker receiver at the world origin, sensor at the TCP) moving along the line at
    ``speed_m_s`` after a 0.5 s pause, the tool pointing down and tilting about the travel
    direction from 0 to ``tilt_deg``. For batch runs, sweeps and tests that need many problems
    quickly (a few dozen waypoints each).

    Args:
        folder: the problem folder (created).
        start: first point of the line in the world [m].
        end: last point [m].
        tilt_deg: tilt of the tool about the travel direction at the end of the line [deg].
        speed_m_s: the worker's speed along the line [m/s].
        robot: registry robot.
        program: the program format the problem asks for (the robot controller's language).
        spacing_m: waypoint spacing after resampling [m].
        rate_hz: tracker sample rate [Hz].
        noise_m: standard deviation of the tracker's position noise [m] (a still sensor's samples
            are never identical; a frozen log reads as a lost sensor).
        noise_deg: standard deviation of the tracker's angle noise [deg].
        seed: seed of the noise.

    Returns:
        The problem file.
    """
    from refine.frames import tracker_angles_from_matrix

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    a, b = np.asarray(start, dtype=float), np.asarray(end, dtype=float)
    length = float(np.linalg.norm(b - a))
    travel = (b - a) / length
    pause_s = 0.5
    t = np.arange(0.0, pause_s + length / speed_m_s + 1e-9, 1.0 / rate_hz)
    s = np.clip((t - pause_s) * speed_m_s, 0.0, length)
    positions = a + s[:, None] * travel
    down = np.column_stack([travel, np.cross([0.0, 0.0, -1.0], travel), [0.0, 0.0, -1.0]])
    rotations = np.stack([down @ rotation_about("x", math.radians(tilt_deg) * u) for u in s / length])
    rng = np.random.default_rng(seed)
    angles = tracker_angles_from_matrix(rotations) + rng.normal(0.0, noise_deg, (len(t), 3))
    rows = np.column_stack([t, positions + rng.normal(0.0, noise_m, positions.shape), angles])
    (folder / "demo.csv").write_text(
        "t,x,y,z,azimuth,elevation,roll\n" + "\n".join(",".join(f"{v:.9g}" for v in r) for r in rows) + "\n"
    )
    (folder / "path.csv").write_text(
        "x,y,z\n" + "\n".join(",".join(f"{v * 1e3:.6f}" for v in p) for p in (a, b)) + "\n"
    )
    problem = folder / "problem.toml"
    problem.write_text(
        f"""name = "{folder.name}"
description = "Straight bead, {length * 1e3:.0f} mm, tool tilting to {tilt_deg:g} deg (generated)."

[robot]
model = "{robot}"

[tool]
name = "nozzle"
tcp_in_flange = {{ xyz = [0.0, 0.0, 0.15], rpy_deg = [0.0, 0.0, 0.0] }}
axisymmetric = false

[cad]
file = "path.csv"
units = "mm"
spacing_m = {spacing_m}

[demonstration]
file = "demo.csv"
format = "csv"
units = "m"
rate_hz = {rate_hz}

[output]
programs = ["{program}"]
""",
        encoding="utf-8",
    )
    return problem


def write_arc_problem(folder: str | Path, robot: str, program: str, corner: Sequence[float]) -> Path:
    """Write a problem folder: a line, a 20 mm quarter ``ARC`` and a line in a DXF, with a demonstration.

    The path runs 40 mm along +y to the arc's start at ``corner``, turns 90 deg left about +z on a
    20 mm radius and runs 40 mm along -x. The demonstration is the TCP along it at 10 mm/s after a
    0.5 s pause (tracker at the world origin, sensor at the TCP), the tool pointing down, its x axis
    along the travel, tilted 10 deg about it; 1e-5 m and 0.005 deg of noise.
    """
    import ezdxf

    from refine.frames import tracker_angles_from_matrix

    folder, corner = Path(folder), np.asarray(corner, dtype=float)
    folder.mkdir(parents=True, exist_ok=True)
    file = write_line_problem(folder, robot=robot, program=program)
    r, c = 0.02, corner + np.array([-0.02, 0.0, 0.0])  # the arc's centre
    doc = ezdxf.new()
    msp = doc.modelspace()
    mm = 1e3
    msp.add_line(
        ((corner[0]) * mm, (corner[1] - 0.04) * mm, corner[2] * mm),
        (corner[0] * mm, corner[1] * mm, corner[2] * mm),
    )
    msp.add_arc((c[0] * mm, c[1] * mm, c[2] * mm), r * mm, 0.0, 90.0)
    msp.add_line(((c[0]) * mm, (c[1] + r) * mm, c[2] * mm), ((c[0] - 0.04) * mm, (c[1] + r) * mm, c[2] * mm))
    doc.saveas(folder / "path.dxf")
    L = 0.08 + r * math.pi / 2
    t = np.arange(0.0, 0.5 + L / 0.01 + 1e-9, 0.01)
    s = np.clip((t - 0.5) * 0.01, 0.0, L)
    heading = np.where(s < 0.04, 0.0, np.where(s < 0.04 + r * math.pi / 2, (s - 0.04) / r, math.pi / 2))
    arc_s = np.clip(s - 0.04, 0.0, r * math.pi / 2) / r
    p = np.column_stack(
        [
            np.where(s < 0.04, corner[0], c[0] + r * np.cos(arc_s)),
            np.zeros_like(s),
            np.full_like(s, corner[2]),
        ]
    )
    p[:, 1] = np.where(s < 0.04, corner[1] - 0.04 + s, c[1] + r * np.sin(arc_s))
    past = s > 0.04 + r * math.pi / 2
    p[past, 0] = c[0] - (s[past] - 0.04 - r * math.pi / 2)
    travel = np.column_stack([-np.sin(heading), np.cos(heading), np.zeros_like(heading)])
    R = np.stack(
        [
            np.column_stack([d, np.cross([0.0, 0.0, -1.0], d), [0.0, 0.0, -1.0]])
            @ rotation_about("x", math.radians(10.0))
            for d in travel
        ]
    )
    rng = np.random.default_rng(0)
    angles = tracker_angles_from_matrix(R) + rng.normal(0.0, 0.005, (len(t), 3))
    rows = np.column_stack([t, p + rng.normal(0.0, 1e-5, p.shape), angles])
    (folder / "demo.csv").write_text(
        "t,x,y,z,azimuth,elevation,roll\n"
        + "\n".join(",".join(f"{v:.9g}" for v in row) for row in rows)
        + "\n"
    )
    text = file.read_text().replace(
        'file = "path.csv"', 'file = "path.dxf"\nformat = "dxf"\nspacing_m_unused = 0'
    )
    text = text.replace("spacing_m_unused = 0\n", "").replace("spacing_m = 0.005", "spacing_m = 0.002")
    file.write_text(
        text.replace(
            'description = "Straight bead', 'description = "Line, 20 mm arc, line; was: straight bead'
        )
    )
    return file
