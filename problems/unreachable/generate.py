"""Generate the data of the ``unreachable`` problems: per case ``path.csv``, ``demo.liberty``, ``truth.csv``.

Each case is a short demonstration (0.14-0.41 m of path, 100 Hz tracker log) that the robot cannot
execute as shown, for one named reason; README.md explains each case and what refine is expected to
answer. The robot, tool and frames are read from each case's ``problem.toml``, so the data always
agree with the problem file; the geometry of the path and the worker's tool orientations are built
here, several of them relative to the robot's own kinematics (the forearm direction, axis 5's bend),
so that the defect sits exactly where the case says. Everything is deterministic (``SEED`` + a
number from the case name).

Run from the repository root::

    python problems/unreachable/generate.py                # every case
    python problems/unreachable/generate.py joint_wrap     # some cases
    python problems/unreachable/generate.py --check        # + the clearance check of the collision cases
"""

from __future__ import annotations

import argparse
import math
import sys
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from refine.collision.geometry import fcl_geometry
from refine.demo.csv_ import write_demo_csv
from refine.demo.liberty import write_liberty_ascii
from refine.demo.liberty_binary import write_liberty_binary
from refine.demo.simulate import TrackerModel, simulate_demonstration, write_truth_csv
from refine.frames import (
    invert_transform,
    make_transform,
    matrix_from_rotvec,
    transform_points,
)
from refine.problem import load_problem
from refine.robot.kinematics import TcpKinematics, solve_ik
from refine.robot.registry import load_robot

HERE = Path(__file__).resolve().parent
SEED = 20240917
RATE_HZ = 100.0  # tracker sample rate [Hz]: small logs, tremor band (8-12 Hz) well below Nyquist
PAUSE_S = 1.5  # the tool held still at the path start [s]
POINT_SPACING = 0.001  # CAD vertex spacing [m]


# ---- shared helpers -----------------------------------------------------------------------------


@dataclass(frozen=True)
class Case:
    """What a case's problem file says, as numbers.

    Attributes:
        name: folder name.
        kin: TCP kinematics of the robot in the world with the tool.
        source_in_world: T_F_S, (4, 4).
        sensor_in_tcp: T_TCP_E, (4, 4).
        cad_in_world: T_F_CAD, (4, 4).
    """

    name: str
    kin: TcpKinematics
    source_in_world: np.ndarray
    sensor_in_tcp: np.ndarray
    cad_in_world: np.ndarray


@dataclass(frozen=True)
class Demo:
    """A case's true path: positions and tool orientations in {F}, speed along it.

    Attributes:
        positions: TCP positions [m], (N, 3), about ``POINT_SPACING`` apart.
        rotations: true tool orientations R_F_TCP, (N, 3, 3).
        speed: true TCP speed [m/s], (N,).
    """

    positions: np.ndarray
    rotations: np.ndarray
    speed: np.ndarray


def load_case(name: str) -> Case:
    """Read ``<name>/problem.toml`` into the transforms the generator needs."""
    problem = load_problem(HERE / name)
    kin = TcpKinematics(
        load_robot(problem.robot.model), problem.robot.base_in_world, problem.tool.tcp_in_flange
    )
    return Case(
        name, kin, problem.frames.source_in_world, problem.tool.sensor_in_tcp, problem.frames.cad_in_world
    )


def arc_length(points: np.ndarray) -> np.ndarray:
    """Arc length [m] of a polyline's vertices, (N,)."""
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])


def line(a, b) -> np.ndarray:
    """Points from ``a`` to ``b`` [m], ``POINT_SPACING`` apart (or a little less), (N, 3)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    n = int(math.ceil(np.linalg.norm(b - a) / POINT_SPACING))
    return a + np.linspace(0.0, 1.0, n + 1)[:, None] * (b - a)


def smoothstep(x: np.ndarray) -> np.ndarray:
    """0 below 0, 1 above 1, ``3x² - 2x³`` between."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def worker_speed(s: np.ndarray, v: float, ramp_m: float = 0.02) -> np.ndarray:
    """Speed [m/s] along the path: from 40 % of ``v`` up to ``v`` over ``ramp_m`` at each end."""
    up = smoothstep(s / ramp_m) * smoothstep((s[-1] - s) / ramp_m)
    return v * (0.4 + 0.6 * up)


def frame_from_z_x(z: np.ndarray, x_hint: np.ndarray) -> np.ndarray:
    """Rotations (N, 3, 3) with the z axis ``z`` and the x axis ``x_hint`` made orthogonal to it."""
    z = z / np.linalg.norm(z, axis=-1, keepdims=True)
    x = x_hint - np.einsum("ij,ij->i", x_hint, z)[:, None] * z
    x /= np.linalg.norm(x, axis=-1, keepdims=True)
    return np.stack([x, np.cross(z, x), z], axis=-1)


def arm_ik(kin: TcpKinematics, p_world: np.ndarray, q: np.ndarray, iterations: int = 200) -> np.ndarray:
    """Joints that put the TCP at ``p_world`` moving axes 1-3 only (the wrist joints of ``q`` kept).

    Damped least squares on the TCP position from ``q`` [rad]; raises if it does not converge.
    """
    q = np.array(q, dtype=float)
    for _ in range(iterations):
        e = p_world - kin.pose(q)[:3, 3]
        if np.linalg.norm(e) < 1e-10:
            return q
        J = kin.jacobian(q)[:3, :3]
        q[:3] += J.T @ np.linalg.solve(J @ J.T + 1e-6 * np.eye(3), e)
    raise RuntimeError(f"arm IK did not reach {p_world}: error {np.linalg.norm(e):.2e} m")


def arm_path(kin: TcpKinematics, positions: np.ndarray, wrist: np.ndarray, q0: np.ndarray) -> np.ndarray:
    """Joints (N, n) along ``positions`` (N, 3) with the wrist joints ``wrist`` (N, n - 3) imposed."""
    qs = np.empty((len(positions), len(q0)))
    q = np.array(q0, dtype=float)
    for k, (p, w) in enumerate(zip(positions, wrist, strict=True)):
        q[3:] = w
        q = arm_ik(kin, p, q)
        qs[k] = q
    return qs


def write_case(case: Case, demo: Demo, seed: int) -> None:
    """Write ``path.csv`` (CAD frame, mm), ``demo.liberty`` and ``truth.csv`` into the case folder."""
    folder = HERE / case.name
    s = arc_length(demo.positions)
    cad = transform_points(invert_transform(case.cad_in_world), demo.positions) * 1000.0
    with (folder / "path.csv").open("w", encoding="utf-8") as f:
        f.write(f"# {case.name}: CAD path [mm], written by ../generate.py\nx,y,z\n")
        np.savetxt(f, cad, delimiter=",", fmt="%.4f")
    model = TrackerModel(rate_hz=RATE_HZ, pause_s=PAUSE_S, n_outliers=2, seed=seed)
    sim = simulate_demonstration(
        s, demo.positions, demo.rotations, demo.speed, case.source_in_world, case.sensor_in_tcp, model
    )
    write_liberty_ascii(folder / "demo.liberty", sim.log, units="in", rate_hz=RATE_HZ)
    if case.name in ALL_FORMATS:
        write_liberty_binary(folder / "demo.lbin", sim.log, with_timestamp=True, units="in", rate_hz=RATE_HZ)
        write_demo_csv(folder / "demo.csv", sim.log, units="mm")
    write_truth_csv(folder / "truth.csv", sim.s, sim.quaternions, sim.speed)
    print(
        f"{case.name}: path {s[-1]:.3f} m ({len(s)} vertices), demo {len(sim.log.t)} samples "
        f"({sim.duration_s:.1f} s at {RATE_HZ:g} Hz)"
    )


# ---- the cases ----------------------------------------------------------------------------------

WRIST_FLIP_SWEEP_DEG = 20.0  # the gun axis pitches from +20 to -20 deg about axis 5
WRIST_FLIP_MISS_DEG = 2.0  # ... and passes this far beside the forearm axis


def wrist_flip(case: Case) -> Demo:
    """Straight line; the gun axis pitches through the forearm direction, 2 deg to its side.

    The reference is the robot's own singular configuration at each point (axes 4, 5, 6 at 0, the
    gun axis along the forearm): the demonstrated orientation is that one pitched by ``β(s)`` about
    axis 5 (from +20 to -20 deg between s = 0.02 and 0.12 m) and turned ``WRIST_FLIP_MISS_DEG``
    about the axis perpendicular to both, so the gun axis passes 2 deg beside the singular
    direction at s = 0.07 m. The spin about the gun axis stays as at axis 6 = 0.
    """
    positions = line([1.55, -0.07, 0.80], [1.55, 0.07, 0.80])
    s = arc_length(positions)
    q_sing = arm_path(case.kin, positions, np.zeros((len(s), 3)), np.radians([0, 30, 10, 0, 0, 0]))
    R_sing = case.kin.poses(q_sing)[:, :3, :3]
    beta = np.radians(WRIST_FLIP_SWEEP_DEG) * np.cos(np.pi * smoothstep((s - 0.02) / 0.10))
    axis5 = R_sing[:, :, 1]  # at axes 4, 5, 6 = 0 the flange y axis is axis 5
    side = R_sing[:, :, 0]  # perpendicular to axis 5 and to the gun axis
    miss = math.radians(WRIST_FLIP_MISS_DEG)
    rotations = np.stack(
        [
            matrix_from_rotvec(miss * c) @ matrix_from_rotvec(b * a) @ R
            for a, c, b, R in zip(axis5, side, beta, R_sing, strict=True)
        ]
    )
    return Demo(positions, rotations, worker_speed(s, 0.04))


JOINT_LIMIT_BEND_DEG = (-112.0, -130.0)  # axis-5 angle the demonstrated orientation needs: ends, middle


def joint_limit(case: Case) -> Demo:
    """Straight line; the worker tips the gun back towards the robot until axis 5 would need -130 deg.

    Built in joint space: axes 4 and 6 at 0, axis 5 going smoothly from -112 deg at the ends to
    ``JOINT_LIMIT_BEND_DEG[1]`` on s = 0.08-0.12 m, axes 1-3 solved for the TCP on the line; the
    demonstrated orientation is the one these joints give. Axis 5 reaches -125..+120 deg, so this
    is 5 deg past its lower limit (7 deg past the limit less the 2 deg joint margin); the same
    orientation with the wrist flipped (axis 4 + 180, axis 5 negated, axis 6 + 180) is worse, at
    +130 deg against +120.
    """
    positions = line([1.30, -0.10, 0.90], [1.30, 0.10, 0.90])
    s = arc_length(positions)
    lo, hi = np.radians(JOINT_LIMIT_BEND_DEG)
    rise = smoothstep((s - 0.03) / 0.05) * smoothstep((0.17 - s) / 0.05)
    wrist = np.column_stack([np.zeros_like(s), lo + (hi - lo) * rise, np.zeros_like(s)])
    q = arm_path(case.kin, positions, wrist, np.radians([0, 35, -25, 0, -112, 0]))
    return Demo(positions, case.kin.poses(q)[:, :3, :3], worker_speed(s, 0.04))


SPIRAL_RADII_M = (0.015, 0.035)  # inner and outer radius of the spiral bead [m]
SPIRAL_CENTRE = (1.35, 0.0, 0.60)  # [m], in {F}


def spiral(case: Case, turns: float) -> Demo:
    """A flat spiral bead, the slot nozzle pointing straight down and kept across the radius.

    The spiral runs counter-clockwise (seen from above) and outwards from ``SPIRAL_RADII_M[0]`` to
    ``[1]`` in ``turns`` turns about the vertical through ``SPIRAL_CENTRE``; the nozzle's x axis
    stays along the circumferential direction, so the tool spins ``turns`` full turns about its
    own (vertical) axis, all of it on axis 6 (axis 6 decreasing). Whether a spin fits axis 6
    depends on its phase as well as on its size: the spiral starts at the polar angle that centres
    the spin in axis 6's range (the start at axis 6 = +turns * 180 deg), the most favourable one.
    """
    r0, r1 = SPIRAL_RADII_M
    centre = np.asarray(SPIRAL_CENTRE)
    phi_end = 2.0 * math.pi * turns

    def frames(phi):
        across = np.column_stack([-np.sin(phi), np.cos(phi), 0 * phi])
        return frame_from_z_x(np.tile([0.0, 0.0, -1.0], (len(phi), 1)), across)

    # axis 6 at the start for polar angle 0, from IK; the spin about the downward tool axis
    # turns axis 6 by -phi, so starting at phi0 = q6(0) - turns * 180 deg centres the spin
    T = make_transform(frames(np.zeros(1))[0], centre + [r0, 0.0, 0.0])
    free = np.full(case.kin.robot.nq, np.inf)
    q, err = solve_ik(case.kin, T, np.radians([0, 15, 10, 0, 60, 0]), -free, free, max_iterations=500)
    if err > 1e-6:
        raise RuntimeError(f"{case.name}: IK for the spiral start failed (error {err:.1e})")
    phi0 = float(np.mod(q[5] - np.pi * turns + np.pi, 2 * np.pi) - np.pi)
    n = int(math.ceil(phi_end * 0.5 * (r0 + r1) / POINT_SPACING))
    phi = phi0 + np.linspace(0.0, phi_end, n + 1)
    r = r0 + (r1 - r0) * (phi - phi0) / phi_end
    positions = centre + np.column_stack([r * np.cos(phi), r * np.sin(phi), 0 * phi])
    return Demo(positions, frames(phi), worker_speed(arc_length(positions), 0.04))


def joint_wrap(case: Case) -> Demo:
    """Spiral of 2.25 turns: the tool spins 810 deg; axis 6 spans 800 deg (796 inside the margins)."""
    return spiral(case, 2.25)


def joint_wrap_infeasible(case: Case) -> Demo:
    """Spiral of 2.6 turns: the tool spins 936 deg, 140 deg more than axis 6 spans inside its margins."""
    return spiral(case, 2.6)


def drag_frames(travel: np.ndarray, drag_deg: float) -> np.ndarray:
    """Gun pointing down, tipped back along the travel by ``drag_deg`` (the nozzle points at the
    bead already laid), upright across it; x along the travel ``travel`` (N, 3), horizontal."""
    d = math.radians(drag_deg)
    z = math.cos(d) * np.array([0.0, 0.0, -1.0]) - math.sin(d) * travel
    return frame_from_z_x(z, travel)


def tool_through_fixture(case: Case) -> Demo:
    """Straight line along y at x = 1.40 m on the plate, the gun upright across the travel.

    The clamp's face is 30 mm from the path, on the far side (+x), for |y| <= 20 mm; the robot's
    gun body (radius 45 mm) starts 200 mm above the nozzle tip and the clamp is 270 mm tall, so the
    upright gun overlaps it by 15 mm where the body passes (the 10 deg drag moves that stretch
    back along the path: the body runs ahead of the tip).
    """
    positions = line([1.40, -0.125, 0.56], [1.40, 0.125, 0.56])
    s = arc_length(positions)
    travel = np.tile([0.0, 1.0, 0.0], (len(s), 1))
    return Demo(positions, drag_frames(travel, 10.0), worker_speed(s, 0.04))


ELBOW_DRAG_DEG = 20.0  # drag angle of the elbow_through_table demonstration [deg]


def elbow_through_table(case: Case) -> Demo:
    """Straight line away from the robot on a part on a high bench, the gun dragged 20 deg.

    The robot stands on the floor in front of the bench (top at 0.90 m, front edge 0.50 m from
    axis 1); the bead runs on a 20 mm part from x = 1.30 to 1.60 m. Dragging the gun back towards
    the robot puts the wrist farther out, so the arm leans over the bench until the upper arm,
    below the elbow, goes through the bench's front edge, deeper the farther out the TCP is.
    """
    positions = line([1.30, 0.0, 0.92], [1.60, 0.0, 0.92])
    s = arc_length(positions)
    travel = np.tile([1.0, 0.0, 0.0], (len(s), 1))
    return Demo(positions, drag_frames(travel, ELBOW_DRAG_DEG), worker_speed(s, 0.03))


OUT_OF_REACH_CENTRE = (1.04, 0.0, 0.10)  # centre of the half-circle bead in {F} [m]
OUT_OF_REACH_RADIUS = 0.10  # [m]


def out_of_reach(case: Case) -> Demo:
    """Half circle around the far side of a round part; its middle lies beyond the arm's reach.

    The bead runs from (1.04, -0.10) through (1.14, 0) to (1.04, 0.10) at 0.10 m above the robot's
    mounting surface; the iiwa's TCP (0.20 m tool) reaches about 1.116 m from axis 1 at that
    height with any orientation, so the middle of the arc, s = 0.085-0.23 m, is out of reach by up
    to 27 mm. The gun points down, tipped 20 deg away from the robot, its x axis along the travel.
    """
    c = np.asarray(OUT_OF_REACH_CENTRE)
    n = int(math.ceil(math.pi * OUT_OF_REACH_RADIUS / POINT_SPACING))
    theta = np.linspace(-0.5 * math.pi, 0.5 * math.pi, n + 1)
    positions = c + OUT_OF_REACH_RADIUS * np.column_stack([np.cos(theta), np.sin(theta), 0 * theta])
    travel = np.column_stack([-np.sin(theta), np.cos(theta), 0 * theta])
    away = positions * [1.0, 1.0, 0.0]
    away /= np.linalg.norm(away, axis=1, keepdims=True)  # horizontal, away from axis 1
    tip = math.radians(20.0)
    z = math.cos(tip) * np.array([0.0, 0.0, -1.0]) + math.sin(tip) * away
    return Demo(positions, frame_from_z_x(z, travel), worker_speed(arc_length(positions), 0.04))


REACH_RADIUS_M = 0.707  # horizontal distance of the reach cases' arc from axis 1 [m]
REACH_HEIGHT_M = 0.10  # its height above the iiwa's mounting surface [m]


def leaning_arc(lean_deg: tuple[float, float], half_angle_deg: float = 12.0) -> Demo:
    """An arc around axis 1 at ``REACH_RADIUS_M``; the gun leans back towards the robot.

    The gun axis points down, its top leaning away from the robot (the tip towards it) by
    ``lean_deg[0]`` at the ends and ``lean_deg[1]`` on the middle third, smoothly between. The
    wrist centre sits 0.326 m up the gun axis (0.20 m gun + 0.126 m flange), so the lean pushes it
    outwards: at 0.707 m and 10 deg it is 0.766 m from the shoulder (axis 2, 0.36 m up), at 30 deg
    0.870 m, beyond the 0.42 + 0.40 m of the iiwa's two arm links; 20 deg (0.820 m) is the most
    that stays in reach.
    """
    theta = np.radians(
        np.linspace(
            -half_angle_deg,
            half_angle_deg,
            int(math.ceil(math.radians(2 * half_angle_deg) * REACH_RADIUS_M / POINT_SPACING)) + 1,
        )
    )
    radial = np.column_stack([np.cos(theta), np.sin(theta), 0 * theta])
    positions = REACH_RADIUS_M * radial + [0.0, 0.0, REACH_HEIGHT_M]
    s = arc_length(positions)
    third = s[-1] / 3.0
    rise = smoothstep((s - 0.25 * third) / (0.75 * third)) * smoothstep(
        (s[-1] - 0.25 * third - s) / (0.75 * third)
    )
    lean = np.radians(lean_deg[0] + (lean_deg[1] - lean_deg[0]) * rise)
    z = -np.cos(lean)[:, None] * [0.0, 0.0, 1.0] - np.sin(lean)[:, None] * radial
    travel = np.column_stack([-np.sin(theta), np.cos(theta), 0 * theta])
    return Demo(positions, frame_from_z_x(z, travel), worker_speed(s, 0.04))


def reach_tilt(case: Case) -> Demo:
    """Arc leaning 10 -> 30 deg: the wrist centre 0.870 m out in the middle; tilting in repairs it."""
    return leaning_arc((10.0, 25.0))


def reach_beyond_slack(case: Case) -> Demo:
    """Arc leaning 10 -> 45 deg: 25 deg of tilt would be needed, more than the cone and the slack."""
    return leaning_arc((10.0, 45.0))


def reach_near_post(case: Case) -> Demo:
    """As ``reach_tilt``, with a post just inside the arc's middle that the gun passes closely."""
    return leaning_arc((10.0, 25.0))


PLACEMENT_LINE_X_M = 0.85  # the bead of placement_reach runs along y at this distance from axis 1 [m]


def placement_reach(case: Case) -> Demo:
    """Straight bead along y at 0.85 m from axis 1, 0.10 m up, the gun upright: the wrist centre
    (0.326 m above the TCP) is 0.853-0.858 m from the shoulder, beyond the arm's 0.82 m; 0.15 m
    nearer it is 0.703-0.710 m."""
    positions = line((PLACEMENT_LINE_X_M, -0.10, REACH_HEIGHT_M), (PLACEMENT_LINE_X_M, 0.10, REACH_HEIGHT_M))
    travel = np.tile([0.0, 1.0, 0.0], (len(positions), 1))
    down = np.tile([0.0, 0.0, -1.0], (len(positions), 1))
    return Demo(positions, frame_from_z_x(down, travel), worker_speed(arc_length(positions), 0.04))


CASES: dict[str, Callable[[Case], Demo]] = {
    "wrist_flip": wrist_flip,
    "joint_limit": joint_limit,
    "joint_wrap": joint_wrap,
    "joint_wrap_infeasible": joint_wrap_infeasible,
    "tool_through_fixture": tool_through_fixture,
    "elbow_through_table": elbow_through_table,
    "out_of_reach": out_of_reach,
    "reach_tilt": reach_tilt,
    "reach_beyond_slack": reach_beyond_slack,
    "reach_near_post": reach_near_post,
    "placement_reach": placement_reach,
}

ALL_FORMATS = ("reach_tilt",)
"""Cases whose demonstration is also written as Liberty binary (``demo.lbin``) and CSV (``demo.csv``)."""


# ---- clearance check (design aid for the collision cases) --------------------------------------


def _signed_distance(a, b) -> float:
    import fcl

    return fcl.distance(a, b, fcl.DistanceRequest(enable_signed_distance=True), fcl.DistanceResult())


def clearance_check(name: str, every: int = 10, max_tilt_deg: float = 18.0) -> None:
    """Print, along the path, the clearance of the demonstrated orientation and the best one a tilt
    of the tool axis can reach, to tell a repairable collision from an infeasible one.

    Independent of refine's optimiser: joints from IK chained along the true poses
    (:func:`refine.optimise.seed.ik_chain`); then per waypoint the tool axis is tilted by 0..
    ``max_tilt_deg`` in 12 directions, the joints re-solved by IK from the chain's, and the smallest
    signed distance between robot links or tool shapes and the cell objects measured with FCL
    (the tool's shapes are not checked against workpieces).
    """
    import fcl

    from refine.optimise.seed import ik_chain, start_candidates

    problem = load_problem(HERE / name)
    case = load_case(name)
    kin, robot = case.kin, case.kin.robot
    demo = CASES[name](case)
    s = arc_length(demo.positions)
    T_F_R = kin.base_in_world
    margin = math.radians(problem.tolerances.joint_margin_deg)
    lower, upper = robot.spec.lower + margin, robot.spec.upper - margin
    free = np.where(upper - lower > 2 * np.pi, np.inf, 1.0)
    lo, hi = np.where(np.isinf(free), -np.inf, lower), np.where(np.isinf(free), np.inf, upper)
    targets = make_transform(demo.rotations, demo.positions)
    qs, err = ik_chain(kin, targets, lower, upper, start_candidates(lower, upper, None))
    cell = [
        (o, fcl.CollisionObject(fcl_geometry(o), fcl.Transform(o.pose[:3, :3], o.pose[:3, 3])))
        for o in problem.cell
    ]
    tool = [(t, fcl_geometry(t)) for t in problem.tool.collision]
    links = robot.collision_shapes()

    def clearance(q):
        best = (np.inf, "")
        poses = robot.link_poses(q)
        flange = T_F_R @ robot.fk(q)
        for o, obj in cell:
            for sh in links:
                d = _signed_distance(sh.collision_object(T_F_R @ poses[sh.link]), obj)
                best = min(best, (d, f"{sh.link} / {o.name}"))
            if o.workpiece:
                continue
            for t, geom in tool:
                T = flange @ t.pose
                d = _signed_distance(fcl.CollisionObject(geom, fcl.Transform(T[:3, :3], T[:3, 3])), obj)
                best = min(best, (d, f"tool {t.name} / {o.name}"))
        return best

    tilts = np.arange(0.0, max_tilt_deg + 1e-9, 1.0)
    print(
        f"{name}: clearance [mm] (margin {problem.collision.margin_m * 1e3:.0f} mm), IK error max {err.max():.1e}"
    )
    print("     s [m]  demo  (closest pair)                best<=3deg  best<=18deg  tilt needed [deg]")
    for k in range(0, len(s), every):
        d0, pair = clearance(qs[k])
        R = demo.rotations[k]
        best = np.full(len(tilts), -np.inf)
        for i, a in enumerate(tilts):
            for az in np.radians(np.arange(0, 360, 30)) if a > 0 else [0.0]:
                axis = math.cos(az) * R[:, 0] + math.sin(az) * R[:, 1]
                T = make_transform(matrix_from_rotvec(math.radians(a) * axis) @ R, demo.positions[k])
                q, e = solve_ik(kin, T, qs[k], lo, hi, max_iterations=200)
                if e < 1e-6 and np.all(q >= lower - 1e-9) and np.all(q <= upper + 1e-9):
                    best[i] = max(best[i], clearance(q)[0])
        ok = np.flatnonzero(best >= problem.collision.margin_m)
        need = f"{tilts[ok[0]]:.0f}" if ok.size else f"> {max_tilt_deg:.0f}"
        print(
            f"  {s[k]:8.3f} {d0 * 1e3:6.0f}  ({pair:28s})  {best[tilts <= 3].max() * 1e3:9.0f} "
            f"{best.max() * 1e3:11.0f}   {need}"
        )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cases", nargs="*", help=f"cases to make (default: all of {', '.join(CASES)})")
    parser.add_argument(
        "--check", action="store_true", help="also print the clearance check of the cases with a cell"
    )
    args = parser.parse_args(argv)
    unknown = sorted(set(args.cases) - set(CASES))
    if unknown:
        parser.error(f"unknown case(s) {', '.join(unknown)}; available: {', '.join(CASES)}")
    for name in CASES:
        if not args.cases or name in args.cases:
            case = load_case(name)
            write_case(case, CASES[name](case), SEED + zlib.crc32(name.encode()) % 1000)
            if args.check and load_problem(HERE / name).cell:
                clearance_check(name)
    return 0


if __name__ == "__main__":
    sys.exit(main())
