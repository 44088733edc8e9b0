"""Generate the data of the ``glass_adhesive`` problem: ``bead.dxf``, ``demo.liberty``, ``truth.csv``.

The cell: an automotive rear side window lies on a fixture table in front of an ABB IRB 4600-60/2.05
with a caulk gun. A worker once applied the urethane bead by hand with the same kind of gun, a
Polhemus Liberty sensor on its barrel; this script makes that demonstration by simulation, so the
true tool orientations and speeds are known (``truth.csv``).

Geometry (all numbers below, explained in README.md):

* The window is developed (unrolled) as a rounded rectangle ``WINDOW_LENGTH x WINDOW_WIDTH`` with
  corner radius ``CORNER_RADIUS`` and wrapped onto a cylinder of radius ``CYLINDER_RADIUS`` whose
  axis runs across the window, so it bends along its long axis only. The bead side (inner face)
  is up and concave: in the CAD frame the surface is
  ``(R sin(u/R), v, R (1 - cos(u/R)))`` for developed coordinates ``u`` (long axis) and ``v``.
* The bead is the rounded rectangle offset ``BEAD_OFFSET`` inside the edge, mapped the same way.
  The map is an isometry, so the offset is measured on the glass and arc length is preserved.
  The bead starts in the middle of the long edge farthest from the robot and runs
  counter-clockwise seen from above.
* CAD frame: origin at the lowest point of the glass (its centre), x along the long axis, z up
  (the surface normal there). ``cad_in_world`` in ``problem.toml`` places it.
* True tool orientation: the nozzle (TCP z) points into the glass, against the surface normal,
  tilted by the drag angle (10.5-19.5 deg, smooth along the path) so that the nozzle points back
  at the bead already laid; the TCP x axis follows the travel direction.
* True speed: 112 mm/s on the straights, down to 65 mm/s in the corners, with a slow +-5 mm/s
  wander; all smooth and periodic along the closed bead.

The frames (robot base, tracker receiver, CAD frame, TCP, sensor) are read from ``problem.toml`` so
the data always agree with the problem file. Everything is deterministic (``SEED``).

Run from the repository root::

    python problems/glass_adhesive/generate.py            # writes the files, checks reachability
    python problems/glass_adhesive/generate.py --no-check # skip the IK reachability check
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import ezdxf
import numpy as np
from scipy.ndimage import gaussian_filter1d

from refine.demo.liberty import write_liberty_ascii
from refine.demo.simulate import TrackerModel, simulate_demonstration, write_truth_csv
from refine.frames import invert_transform, make_transform, rotvec_from_matrix, transform_points
from refine.problem import Problem, load_problem
from refine.synthetic import periodic_wave, rounded_rectangle, tool_rotations

HERE = Path(__file__).resolve().parent
SEED = 20240611

# ---- window and bead [m]
WINDOW_LENGTH = 1.20
WINDOW_WIDTH = 0.50
CORNER_RADIUS = 0.120
CYLINDER_RADIUS = 3.5
BEAD_OFFSET = 0.018
POINT_SPACING = 0.0015  # DXF vertex spacing along the bead [m]

# ---- worker
SPEED_STRAIGHT = 0.112  # [m/s]
SPEED_CORNER = 0.065  # [m/s]
SPEED_WANDER = 0.005  # amplitude of the slow speed variation [m/s]
CORNER_BLEND = 0.06  # Gaussian width of the slow-down around corners [m]
DRAG_MEAN_DEG = 15.0
DRAG_WAVES_DEG = (3.5, 1.0)  # amplitudes of the once- and twice-per-lap drag variation [deg]


# ---- geometry -----------------------------------------------------------------------------------


def on_glass(u, v, du=None, dv=None):
    """Map developed coordinates onto the glass in the CAD frame.

    Returns:
        points (n, 3) [m], and when (du, dv) are given also the unit tangents (n, 3) and the
        upward unit normals (n, 3).
    """
    R = CYLINDER_RADIUS
    c, s = np.cos(u / R), np.sin(u / R)
    points = np.column_stack([R * s, v, R * (1.0 - c)])
    if du is None:
        return points
    tangents = np.column_stack([c * du, dv, s * du])
    normals = np.column_stack([-s, np.zeros_like(s), c])
    return points, tangents, normals


# ---- files --------------------------------------------------------------------------------------


def write_bead_dxf(path: Path, bead_cad: np.ndarray, glass_cad: np.ndarray) -> None:
    """Bead and glass edge as closed 3D polylines in millimetres, layers BEAD and GLASS."""
    fixed = ezdxf.options.write_fixed_meta_data_for_testing
    ezdxf.options.write_fixed_meta_data_for_testing = True  # no time stamps: reproducible file
    try:
        doc = ezdxf.new("R2010")
        doc.units = ezdxf.units.MM
        doc.layers.add("BEAD", color=1)
        doc.layers.add("GLASS", color=5)
        msp = doc.modelspace()
        bead_mm, glass_mm = (bead_cad * 1000.0).tolist(), (glass_cad * 1000.0).tolist()
        msp.add_polyline3d(bead_mm, close=True, dxfattribs={"layer": "BEAD"})
        msp.add_polyline3d(glass_mm, close=True, dxfattribs={"layer": "GLASS"})
        # the CLASSES section comes out in set order (it varies with PYTHONHASHSEED): fix it
        doc.classes.add_required_classes(doc.dxfversion)
        doc.classes.classes = dict(sorted(doc.classes.classes.items()))
        doc.saveas(path)
    finally:
        ezdxf.options.write_fixed_meta_data_for_testing = fixed


# ---- reachability -------------------------------------------------------------------------------


def solve_ik(robot, T_base_flange, q, iterations=300, damping=1e-3):
    """Damped least squares on the flange pose from q [rad]; returns q, position and angle errors."""
    for _ in range(iterations):
        T = robot.fk(q)
        e = np.concatenate(
            [T_base_flange[:3, 3] - T[:3, 3], rotvec_from_matrix(T_base_flange[:3, :3] @ T[:3, :3].T)]
        )
        if np.linalg.norm(e[:3]) < 1e-10 and np.linalg.norm(e[3:]) < 1e-10:
            break
        J = robot.jacobian(q)
        dq = J.T @ np.linalg.solve(J @ J.T + damping**2 * np.eye(6), e)
        q = q + dq * min(1.0, 0.3 / max(np.linalg.norm(dq), 1e-12))
    T = robot.fk(q)
    e_p = float(np.linalg.norm(T_base_flange[:3, 3] - T[:3, 3]))
    e_r = float(np.linalg.norm(rotvec_from_matrix(T_base_flange[:3, :3] @ T[:3, :3].T)))
    return q, e_p, e_r


def check_reachability(problem: Problem, positions, rotations, step: int = 10) -> bool:
    """Chained DLS IK over every ``step``-th point of the true path; prints the worst figures."""
    try:
        from refine.robot.registry import load_robot
    except ImportError as e:  # pragma: no cover - the robot module is optional here
        print(f"reachability check skipped: {e}")
        return True
    robot = load_robot(problem.robot.model)
    T_F_R = problem.robot.base_in_world
    T_flange_tcp = problem.tool.tcp_in_flange
    margin = math.radians(problem.tolerances.joint_margin_deg)
    reach = robot.spec.reach_m
    targets = invert_transform(T_F_R) @ make_transform(rotations, positions)
    targets = targets[::step] @ invert_transform(T_flange_tcp)

    # the elbow-up, wrist-down branch; then put joint 6 where the 360 deg turn fits its range
    q0 = np.radians([0.0, 20.0, 10.0, 0.0, 60.0, 0.0])
    q0, *_ = solve_ik(robot, targets[0], q0, iterations=2000)
    qs = [q0]
    for T in targets[1:]:
        qs.append(solve_ik(robot, T, qs[-1])[0])
    q6 = np.array(qs)[:, 5]
    q0[5] -= 2.0 * math.pi * round((q6.max() + q6.min()) / 2.0 / (2.0 * math.pi))

    q = q0
    rows = []
    for T in targets:
        q, e_p, e_r = solve_ik(robot, T, q)
        J = robot.jacobian(q)
        lever = robot.fk(q)[:3, :3] @ T_flange_tcp[:3, 3]
        J_tcp = J.copy()
        J_tcp[:3] -= np.cross(lever, J[3:].T).T  # v_tcp = v_flange + w x lever
        Js = np.vstack([J_tcp[:3] / reach, J_tcp[3:]])
        joint_margin = float(np.min(np.minimum(q - robot.spec.lower, robot.spec.upper - q)))
        sigma_min = float(np.linalg.svd(Js, compute_uv=False)[-1])
        manip = float(np.sqrt(max(np.linalg.det(Js @ Js.T), 0.0)))
        rows.append((e_p, e_r, joint_margin, sigma_min, manip, q.copy()))
    e_p, e_r, jm, smin, manip = (np.array([r[i] for r in rows]) for i in range(5))
    qs = np.degrees(np.array([r[5] for r in rows]))
    singular = problem.tolerances.singularity_margin
    ok = bool(e_p.max() < 1e-6 and e_r.max() < 1e-4 and jm.min() > margin and manip.min() > singular)
    print(
        f"reachability: {len(rows)} IK targets (every {step}th point), chained from q0 [deg] = "
        f"{np.round(qs[0], 1).tolist()}"
    )
    print(f"  worst position error {e_p.max():.2e} m, worst orientation error {e_r.max():.2e} rad")
    print(
        f"  smallest joint-limit margin {math.degrees(jm.min()):.1f} deg "
        f"(required {math.degrees(margin):.1f} deg)"
    )
    print(
        f"  smallest singular value of the scaled TCP Jacobian {smin.min():.3f}, "
        f"smallest scaled manipulability {manip.min():.3f} (required {singular})"
    )
    print(
        "  joint ranges [deg]: "
        + ", ".join(f"q{j + 1} {qs[:, j].min():.0f}..{qs[:, j].max():.0f}" for j in range(qs.shape[1]))
    )
    print(f"  reachable: {ok}")
    return ok


# ---- main ---------------------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--no-check", action="store_true", help="skip the IK reachability check")
    args = parser.parse_args(argv)
    problem = load_problem(HERE)
    T_F_CAD = problem.frames.cad_in_world
    T_F_S = problem.frames.source_in_world
    T_TCP_E = problem.tool.sensor_in_tcp
    rng = np.random.default_rng(SEED)

    # ---- bead and glass edge in the CAD frame
    half_u, half_v = WINDOW_LENGTH / 2 - BEAD_OFFSET, WINDOW_WIDTH / 2 - BEAD_OFFSET
    r_bead = CORNER_RADIUS - BEAD_OFFSET
    perimeter = 2 * (2 * half_u + 2 * half_v) - (8 - 2 * math.pi) * r_bead
    n = int(math.ceil(perimeter / POINT_SPACING))
    u, v, du, dv, corner, perimeter = rounded_rectangle(half_u, half_v, r_bead, n)
    bead_cad, tangents_cad, normals_cad = on_glass(u, v, du, dv)
    n_edge = int(math.ceil(2 * (WINDOW_LENGTH + WINDOW_WIDTH) / 0.005))
    ue, ve, *_ = rounded_rectangle(WINDOW_LENGTH / 2, WINDOW_WIDTH / 2, CORNER_RADIUS, n_edge)
    write_bead_dxf(HERE / "bead.dxf", bead_cad, on_glass(ue, ve))

    # ---- the closed path in the world, arc length as a polyline reader measures it
    closed = np.vstack([bead_cad, bead_cad[:1]])
    positions = transform_points(T_F_CAD, closed)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    R_F_CAD = T_F_CAD[:3, :3]
    tangents = np.vstack([tangents_cad, tangents_cad[:1]]) @ R_F_CAD.T
    normals = np.vstack([normals_cad, normals_cad[:1]]) @ R_F_CAD.T
    sigma = np.append(np.arange(n) * perimeter / n, perimeter)

    # ---- the worker: drag angle and speed, smooth and periodic over the lap
    drag_deg = DRAG_MEAN_DEG + periodic_wave(sigma, perimeter, DRAG_WAVES_DEG, rng)
    rotations = tool_rotations(tangents, normals, np.radians(drag_deg))
    slow = gaussian_filter1d(corner.astype(float), CORNER_BLEND / (perimeter / n), mode="wrap")
    slow = np.append(slow, slow[0]) / slow.max()
    speed = SPEED_STRAIGHT - (SPEED_STRAIGHT - SPEED_CORNER) * slow
    speed += periodic_wave(sigma, perimeter, (0.0, 0.0, SPEED_WANDER), rng)

    # ---- the tracker log
    model = TrackerModel(seed=SEED)
    demo = simulate_demonstration(s, positions, rotations, speed, T_F_S, T_TCP_E, model)
    write_liberty_ascii(HERE / "demo.liberty", demo.log, units="in", rate_hz=model.rate_hz)
    write_truth_csv(HERE / "truth.csv", demo.s, demo.quaternions, demo.speed)

    # ---- summary
    print(
        f"window {WINDOW_LENGTH * 1000:.0f} x {WINDOW_WIDTH * 1000:.0f} mm, corner radius "
        f"{CORNER_RADIUS * 1000:.0f} mm, cylinder radius {CYLINDER_RADIUS} m"
    )
    print(
        f"bead: {n} points, {s[-1]:.4f} m, spacing {s[-1] / n * 1000:.2f} mm, offset "
        f"{BEAD_OFFSET * 1000:.0f} mm, corner radius {r_bead * 1000:.0f} mm"
    )
    print("\n".join(demo.summary(positions, drag_deg, speed)))
    print(f"wrote {', '.join(p for p in ('bead.dxf', 'demo.liberty', 'truth.csv'))} in {HERE}")

    if not args.no_check:
        return 0 if check_reachability(problem, positions, rotations) else 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
