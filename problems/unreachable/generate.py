"""Generate the data of the ``unreachable`` problems: per case ``path.csv``, ``demo.liberty``, ``truth.csv``.

Each case is a short demonstration (0.2-0.4 m of path, 100 Hz tracker log) that the robot cannot
execute as shown, for one named reason; README.md explains each case and what refine is expected to
answer. The robot, tool and frames are read from each case's ``problem.toml``, so the data always
agree with the problem file; the geometry of the path and the worker's tool orientations are built
here, several of them relative to the robot's own kinematics (the forearm direction, axis 5's bend),
so that the defect sits exactly where the case says. Everything is deterministic (``SEED`` + the
case index).

Run from the repository root::

    python problems/unreachable/generate.py                # every case
    python problems/unreachable/generate.py joint_wrap     # some cases
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from refine.demo.liberty import write_liberty_ascii
from refine.demo.simulate import TrackerModel, simulate_demonstration, write_truth_csv
from refine.frames import (
    invert_transform,
    make_transform,
    matrix_from_rotvec,
    transform_from_xyz_rpy,
    transform_points,
)
from refine.optimise.seed import TcpKinematics, solve_ik
from refine.robot import load_robot

try:  # Python 3.11+
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

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


def pose(table: dict | None) -> np.ndarray:
    """A problem-file pose ``{xyz, rpy_deg}`` as (4, 4); identity when absent."""
    table = table or {}
    return transform_from_xyz_rpy(table.get("xyz", [0.0, 0.0, 0.0]), table.get("rpy_deg", [0.0, 0.0, 0.0]))


def load_case(name: str) -> Case:
    """Read ``<name>/problem.toml`` into the transforms the generator needs."""
    problem = tomllib.loads((HERE / name / "problem.toml").read_text(encoding="utf-8"))
    robot = load_robot(problem["robot"]["model"])
    kin = TcpKinematics(robot, pose(problem["robot"].get("base_in_world")), pose(problem["tool"]["tcp_in_flange"]))
    frames = problem.get("frames", {})
    return Case(
        name,
        kin,
        pose(frames.get("source_in_world")),
        pose(problem["tool"].get("sensor_in_tcp")),
        pose(frames.get("cad_in_world")),
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
    write_truth_csv(folder / "truth.csv", sim.s, sim.quaternions, sim.speed)
    print(
        f"{case.name}: path {s[-1]:.3f} m ({len(s)} vertices), demo {len(sim.log.t)} samples "
        f"({sim.duration_s:.1f} s at {RATE_HZ:g} Hz)"
    )


# ---- the cases ----------------------------------------------------------------------------------

WRIST_FLIP_SWEEP_DEG = 20.0  # the gun axis pitches from +20 to -20 deg about the forearm axis
WRIST_FLIP_MISS_DEG = 2.0  # ... and passes this far beside it


def wrist_flip(case: Case) -> Demo:
    """Straight line; the gun axis pitches through the forearm direction, 2 deg to its side.

    The reference is the robot's own singular configuration at each point (axes 4, 5, 6 at 0, the
    gun axis along the forearm): the demonstrated gun axis is that direction pitched by ``β(s)``
    about axis 5 (from +20 to -20 deg between s = 0.04 and 0.16 m) and turned
    ``WRIST_FLIP_MISS_DEG`` about the third axis, so it passes 2 deg beside the singularity at
    s = 0.10 m. The spin about the gun axis stays as at axis 6 = 0.
    """
    positions = line([1.55, -0.10, 0.80], [1.55, 0.10, 0.80])
    s = arc_length(positions)
    q_sing = arm_path(case.kin, positions, np.zeros((len(s), 3)), np.radians([0, 30, 10, 0, 0, 0]))
    R_sing = case.kin.poses(q_sing)[:, :3, :3]
    beta = np.radians(WRIST_FLIP_SWEEP_DEG) * np.cos(np.pi * smoothstep((s - 0.04) / 0.12))
    axis5 = R_sing[:, :, 1]  # at axes 4, 5, 6 = 0 the flange y axis is axis 5
    side = R_sing[:, :, 0]  # perpendicular to axis 5 and to the gun axis
    rotations = np.stack(
        [
            matrix_from_rotvec(math.radians(WRIST_FLIP_MISS_DEG) * c) @ matrix_from_rotvec(b * a) @ R
            for a, c, b, R in zip(axis5, side, beta, R_sing, strict=True)
        ]
    )
    return Demo(positions, rotations, worker_speed(s, 0.04))


JOINT_LIMIT_BEND_DEG = (-112.0, -130.0)  # axis-5 bend the demonstrated orientation needs: ends, middle


def joint_limit(case: Case) -> Demo:
    """Straight line; the worker tips the gun up and back until axis 5 would need -130 deg.

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


def spiral(case: Case, centre, turns: float) -> Demo:
    """A flat spiral bead, the slot nozzle pointing straight down and kept across the radius.

    The spiral runs counter-clockwise (seen from above) and outwards from ``SPIRAL_RADII_M[0]`` to
    ``[1]`` in ``turns`` turns about the vertical through ``centre``; the nozzle's x axis stays
    along the circumferential direction, so the tool spins ``turns`` full turns about its own
    (vertical) axis, all of it on axis 6 (axis 6 decreasing). Whether a spin fits axis 6 depends
    on its phase as well as on its size: the spiral starts at the polar angle that centres the
    spin in axis 6's range (the start at axis 6 = +turns * 180 deg), the most favourable phase.
    """
    r0, r1 = SPIRAL_RADII_M
    centre = np.asarray(centre, dtype=float)
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
    phi = phi0 + np.linspace(0.0, phi_end, int(math.ceil(phi_end * 0.5 * (r0 + r1) / POINT_SPACING)) + 1)
    r = r0 + (r1 - r0) * (phi - phi0) / phi_end
    positions = centre + np.column_stack([r * np.cos(phi), r * np.sin(phi), 0 * phi])
    return Demo(positions, frames(phi), worker_speed(arc_length(positions), 0.04))


def joint_wrap(case: Case) -> Demo:
    """Spiral of 2.25 turns: the tool spins 810 deg; axis 6 spans 800 deg (796 inside the margins)."""
    return spiral(case, [1.35, 0.0, 0.60], 2.25)


def joint_wrap_infeasible(case: Case) -> Demo:
    """Spiral of 2.6 turns: the tool spins 936 deg, 140 deg more than axis 6 spans inside its margins."""
    return spiral(case, [1.35, 0.0, 0.60], 2.6)

CASES: dict[str, Callable[[Case], Demo]] = {
    "wrist_flip": wrist_flip,
    "joint_limit": joint_limit,
    "joint_wrap": joint_wrap,
    "joint_wrap_infeasible": joint_wrap_infeasible,
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cases", nargs="*", help=f"cases to make (default: all of {', '.join(CASES)})")
    args = parser.parse_args(argv)
    unknown = sorted(set(args.cases) - set(CASES))
    if unknown:
        parser.error(f"unknown case(s) {', '.join(unknown)}; available: {', '.join(CASES)}")
    for index, name in enumerate(CASES):
        if not args.cases or name in args.cases:
            write_case(load_case(name), CASES[name](load_case(name)), SEED + index)
    return 0


if __name__ == "__main__":
    sys.exit(main())
