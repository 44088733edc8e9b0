"""Build the glass cell's calibration measurements and calibrate the problem's frames from them.

The glass cell of ``problems/glass_adhesive`` is the truth: its frames are the ones the
demonstration was simulated with. This script

1. copies the CAD file, the demonstration and its truth from ``glass_adhesive``, and writes
   ``problem.toml`` with the frames as a cell drawing would give them (centimetres and degrees off);
2. simulates the measurements, with the truth frames, into small files under ``measurements/``:
   a pivot swing and six touched fixture points (tracker: 1 mm noise, 60 mm far-field z error,
   spikes; one point touched 20 mm off), six-point TCP readings and five workpiece touches
   (robot: 0.05 mm repeatability, 0.001 deg joint-reading noise);
3. runs ``refine calibrate pivot | tcp | receiver | workpiece ... --write`` on them, in that order
   (the receiver needs the pivot's tip, the workpiece the TCP), so every frame of ``problem.toml``
   comes from a measurement; ``base_in_world`` stays the identity, the robot base defining the
   world;
4. measures how well the procedure repeats (the same simulations with other seeds) and writes the
   spread of the results as the ``[calibration]`` table.

Run from the repository root: ``python problems/glass_calibrated/generate.py``.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np

from refine.calibrate.files import update_problem
from refine.calibrate.pivot import solve_pivot
from refine.calibrate.receiver import register_receiver_from_log
from refine.calibrate.robot_touch import calibrate_tcp, register_workpiece, tcp_positions_world
from refine.calibrate.simulate import (
    calibration_tracker_model,
    simulate_pivot,
    simulate_tcp_readings,
    simulate_touches,
    simulate_workpiece_readings,
)
from refine.cli import main as refine_main
from refine.demo import write_liberty_ascii
from refine.frames import invert_transform, rotvec_from_matrix, transform_from_xyz_rpy
from refine.problem import load_problem
from refine.robot.registry import load_robot

HERE = Path(__file__).resolve().parent
GLASS = HERE.parent / "glass_adhesive"
MEASURED = HERE / "measurements"
RATE_HZ = 60.0  # the logs are recorded at a quarter of the Liberty's 240 Hz to keep them small
REPEATS = 8  # seeds for the repeatability of each calibration

PIVOT_IN_SOURCE = np.array([0.30, 0.20, -0.27])  # a divot on the table next to the receiver [m]
FIXTURE_POINTS = np.array(  # reference points on the fixture and the table, world frame [m]
    [
        [1.00, -0.55, 0.45],
        [1.70, -0.35, 0.60],
        [1.05, -0.05, 0.80],
        [1.75, 0.15, 0.45],
        [0.90, 0.40, 0.60],
        [1.55, 0.60, 0.95],
    ]
)
WRONG_TOUCH = {3: [0.0, 0.02, 0.0]}  # the worker rested the tip 20 mm off the fourth point
REFERENCE_IN_BASE = np.array([1.2, 0.5, 0.55])  # the TCP calibration spike, base frame [m]
CYLINDER_RADIUS = 3.5  # the glass's bend [m]
REPEATABILITY_M = 5e-5
JOINT_NOISE_DEG = 0.001
SENSOR_ROTATION_SIGMA_DEG = 0.5  # the sensor mount's orientation is taken from its drawing, not measured


def glass_points() -> np.ndarray:
    """Five points on the bent glass, CAD frame [m]: near the four corners and the centre."""
    u = np.array([-0.55, 0.55, 0.55, -0.55, 0.0])
    v = np.array([-0.20, -0.20, 0.20, 0.20, 0.0])
    R = CYLINDER_RADIUS
    return np.column_stack([R * np.sin(u / R), v, R * (1.0 - np.cos(u / R))])


def write_points(path: Path, points: np.ndarray, prefix: str) -> None:
    rows = ["name,x,y,z"] + [
        f"{prefix}{k + 1},{p[0]:.6f},{p[1]:.6f},{p[2]:.6f}" for k, p in enumerate(points)
    ]
    path.write_text("\n".join(rows) + "\n")


def write_joints(path: Path, joints: np.ndarray) -> None:
    rows = [",".join(f"j{k + 1}" for k in range(joints.shape[1]))]
    rows += [",".join(f"{v:.5f}" for v in np.degrees(q)) for q in joints]
    path.write_text("\n".join(rows) + "\n")


def simulate(truth, robot, seed: int) -> dict:
    """All four measurements with the given seed; returns the simulations."""
    tip = invert_transform(truth.tool.sensor_in_tcp)[:3, 3]
    model = calibration_tracker_model(rate_hz=RATE_HZ, seed=seed)
    cad = truth.frames.cad_in_world
    return {
        "pivot": simulate_pivot(tip, PIVOT_IN_SOURCE, duration_s=10.0, model=model),
        "touch": simulate_touches(
            FIXTURE_POINTS, truth.frames.source_in_world, tip, WRONG_TOUCH, model=model, seed=seed
        ),
        "tcp": simulate_tcp_readings(
            robot,
            truth.tool.tcp_in_flange,
            REFERENCE_IN_BASE,
            six_point=True,
            repeatability_m=REPEATABILITY_M,
            joint_noise_deg=JOINT_NOISE_DEG,
            seed=seed,
        ),
        "workpiece": simulate_workpiece_readings(
            robot,
            truth.robot.base_in_world,
            truth.tool.tcp_in_flange,
            cad,
            glass_points(),
            repeatability_m=REPEATABILITY_M,
            joint_noise_deg=JOINT_NOISE_DEG,
            seed=seed,
        ),
    }


def repeatability(truth, robot) -> dict[str, tuple[float, float]]:
    """Spread (RMS per axis) of each calibrated frame over REPEATS seeds: (translation [m], angle [deg])."""
    errors: dict[str, list[np.ndarray]] = {
        "sensor_in_tcp": [],
        "source_in_world": [],
        "tcp_in_flange": [],
        "cad_in_world": [],
    }
    for seed in range(100, 100 + REPEATS):
        sims = simulate(truth, robot, seed)
        tip = solve_pivot(sims["pivot"].log.positions, sims["pivot"].log.rotations).values["tip_in_sensor_m"]
        R_E_TCP = truth.tool.sensor_in_tcp[:3, :3].T
        Y = invert_transform(np.block([[R_E_TCP, tip[:, None]], [np.zeros((1, 3)), np.ones((1, 1))]]))
        S = register_receiver_from_log(sims["touch"].log, tip, FIXTURE_POINTS).values["source_in_world"]
        X = calibrate_tcp(robot.fk_many(sims["tcp"].joints), six_point=True).values["tcp_in_flange"]
        world = tcp_positions_world(robot.fk_many(sims["workpiece"].joints), truth.robot.base_in_world, X)
        C = register_workpiece(world, glass_points()).values["cad_in_world"]
        for name, T, T_true in (
            ("sensor_in_tcp", Y, truth.tool.sensor_in_tcp),
            ("source_in_world", S, truth.frames.source_in_world),
            ("tcp_in_flange", X, truth.tool.tcp_in_flange),
            ("cad_in_world", C, truth.frames.cad_in_world),
        ):
            delta = invert_transform(T_true) @ T
            errors[name].append(np.concatenate([delta[:3, 3], rotvec_from_matrix(delta[:3, :3])]))
    out = {}
    for name, rows in errors.items():
        e = np.array(rows)
        out[name] = (
            float(np.sqrt(np.mean(e[:, :3] ** 2))),
            float(np.degrees(np.sqrt(np.mean(e[:, 3:] ** 2)))),
        )
    return out


def main() -> int:
    truth = load_problem(GLASS)
    robot = load_robot(truth.robot.model)
    MEASURED.mkdir(exist_ok=True)
    for name in ("bead.dxf", "demo.liberty", "truth.csv"):
        shutil.copyfile(GLASS / name, HERE / name)

    # ---- problem.toml with the frames of the cell drawing
    text = (GLASS / "problem.toml").read_text()
    text = text.replace('name = "glass_adhesive"', 'name = "glass_calibrated"', 1)
    text = text.replace(
        "# The CAD path, the tracker log and the truth are made by generate.py; see README.md.",
        "# The glass cell with every frame measured by `refine calibrate` (see README.md); the CAD path,\n"
        "# the demonstration and its truth are copies of glass_adhesive's.",
        1,
    )
    (HERE / "problem.toml").write_text(text)
    drawing = {
        ("frames", "source_in_world"): transform_from_xyz_rpy([1.28, -0.85, 0.70], [0.0, 0.0, 88.0]),
        ("frames", "cad_in_world"): transform_from_xyz_rpy([1.32, 0.02, 0.62], [0.0, 0.0, 91.0]),
        ("tool", "tcp_in_flange"): transform_from_xyz_rpy([0.0, 0.0, 0.34], [0.0, 0.0, 0.0]),
        ("tool", "sensor_in_tcp"): transform_from_xyz_rpy([-0.03, 0.0, -0.24], [180.0, 0.0, 30.0]),
    }
    for (table, key), T in drawing.items():
        update_problem(HERE, table, key, T)

    # ---- the measurement files (seed 1)
    sims = simulate(truth, robot, seed=1)
    write_liberty_ascii(MEASURED / "pivot.liberty", sims["pivot"].log, units="in", rate_hz=RATE_HZ)
    write_liberty_ascii(MEASURED / "touch.liberty", sims["touch"].log, units="in", rate_hz=RATE_HZ)
    write_points(MEASURED / "fixture_points.csv", FIXTURE_POINTS, "F")
    write_joints(MEASURED / "tcp.csv", sims["tcp"].joints)
    write_joints(MEASURED / "workpiece.csv", sims["workpiece"].joints)
    write_points(MEASURED / "glass_points.csv", glass_points(), "G")

    # ---- calibrate, in order, writing into problem.toml
    m, p = str(MEASURED), str(HERE)
    rate = ["--rate-hz", str(RATE_HZ)]
    commands = [
        ["calibrate", "pivot", f"{m}/pivot.liberty", *rate, "--write", p],
        ["calibrate", "tcp", f"{m}/tcp.csv", "--six-point", "--problem", p, "--write", p],
        [
            "calibrate",
            "receiver",
            f"{m}/touch.liberty",
            f"{m}/fixture_points.csv",
            *rate,
            "--problem",
            p,
            "--write",
            p,
        ],
        [
            "calibrate",
            "workpiece",
            f"{m}/workpiece.csv",
            f"{m}/glass_points.csv",
            "--problem",
            p,
            "--write",
            p,
        ],
    ]
    for args in commands:
        print("$ refine " + " ".join(a.replace(str(HERE.parents[1]) + "/", "") for a in args))
        if refine_main(args) != 0:
            return 1

    # ---- the procedure's repeatability as the [calibration] table
    spread = repeatability(truth, robot)
    lines = [
        "",
        "# the spread of each calibration over 8 repeats (simulated, generate.py): 1 sigma per axis",
        "[calibration]",
    ]
    for name, (xyz, ang) in spread.items():
        if name == "sensor_in_tcp":  # a pivot measures the tip, not the orientation: assume the drawing's
            lines.append("# sensor_in_tcp: rotation not measured (the mounting drawing's), 0.5 deg assumed")
            ang = SENSOR_ROTATION_SIGMA_DEG
        lines.append(f"{name} = {{ xyz_m = {xyz:.2e}, rpy_deg = {ang:.2e} }}")
    lines.append("samples = 2000")
    with (HERE / "problem.toml").open("a", encoding="utf-8") as f:
        f.write("\n".join(lines) + "\n")
    load_problem(HERE)
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
