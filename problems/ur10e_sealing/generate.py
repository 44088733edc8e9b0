"""Generate the data of the ``ur10e_sealing`` problem: ``panel.stl``, ``demo.liberty``, ``truth.csv``.

The cell: a formed sheet-metal cover panel lies on a fixture on a table beside a UR10e cobot that
carries a pneumatic sealing valve. The sealant bead runs along the panel's edge (where the panel
will sit on its frame). There is no separate CAD path: the path is the open boundary of the
panel's mesh (``[cad] format = "mesh"``, ``boundary = true``). A worker once applied the bead by hand
with a cartridge gun, a Polhemus Liberty sensor on its barrel; this script makes that
demonstration by simulation, so the true tool orientations and speeds are known (``truth.csv``).

Geometry (all numbers below, explained in README.md):

* The panel's footprint is a rounded rectangle ``PANEL_LENGTH x PANEL_WIDTH`` with corner radius
  ``CORNER_RADIUS``; over it the panel is the saddle ``z = x^2 / (2 RADIUS_LONG) - y^2 / (2
  RADIUS_ACROSS)`` (CAD frame: origin at the saddle point, x along the long axis, z up). Along its
  length it sags (the ends are 50 mm up), across it is crowned (the long edges are 26 mm down), so
  its edge is a closed, genuinely non-planar curve.
* The mesh (``panel.stl``, binary STL in millimetres, normals up) is built from rings: the
  boundary ring has a vertex every ``EDGE_SPACING`` of arc length; ``N_RINGS - 1`` inner rings are
  the footprint scaled by 0.9, 0.8, ... with fewer vertices; a fan closes the centre. Every
  vertex lies exactly on the saddle.
* The true path is the mesh's open boundary, found with trimesh (``Trimesh.outline``) on the STL
  as written, independently of ``refine.cad``: started at the vertex nearest ``[cad] start_near``
  (the middle of the long edge nearest the robot) and run counter-clockwise seen from above.
* True tool orientation: the nozzle (TCP z) points into the panel, against its upward surface
  normal (analytic, from the saddle), tilted back by the drag angle (12-18 deg, smooth along the
  path) so that the nozzle points at the bead already laid; the TCP x axis follows the travel
  direction (the worker's gun turns once about the vertical over the lap).
* True speed: 120 mm/s along the straight edges, down to 70 mm/s in the corners, with a slow
  +-8 mm/s wander; all smooth and periodic along the closed bead.

The frames (robot base, tracker receiver, CAD frame, TCP, sensor) and the cell are read from
``problem.toml`` so that the data always agree with the problem file. Everything is deterministic
(``SEED``; the STL has an all-zero header and no time stamp).

Run from the repository root::

    python problems/ur10e_sealing/generate.py            # writes the files, checks reachability
    python problems/ur10e_sealing/generate.py --no-check # skip the IK and clearance check
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
from pathlib import Path

import numpy as np
import trimesh
from scipy.ndimage import gaussian_filter1d

from refine.demo.liberty import write_liberty_ascii
from refine.demo.simulate import TrackerModel, simulate_demonstration, write_truth_csv
from refine.frames import make_transform, transform_points
from refine.problem import Problem, load_problem
from refine.synthetic import periodic_wave, reachability_report, rounded_rectangle, tool_rotations

HERE = Path(__file__).resolve().parent
SEED = 20240917
MESH_FILE = "panel.stl"

# ---- panel [m]
PANEL_LENGTH = 0.80
PANEL_WIDTH = 0.50
CORNER_RADIUS = 0.080
RADIUS_LONG = 1.6  # the saddle's radius of curvature along the long axis (concave up)
RADIUS_ACROSS = 1.2  # ... across it (convex up)
EDGE_SPACING = 0.003  # vertex spacing along the boundary ring [m]
N_RINGS = 10  # boundary ring + inner rings
INNER_DENSITY = 0.3  # inner rings: this fraction of the boundary ring's vertices, times the scale

# ---- worker
SPEED_STRAIGHT = 0.120  # [m/s]
SPEED_CORNER = 0.070  # [m/s]
SPEED_WANDER = 0.008  # amplitude of the slow speed variation [m/s]
CORNER_BLEND = 0.05  # Gaussian width of the slow-down around corners [m]
DRAG_MEAN_DEG = 15.0
DRAG_WAVES_DEG = (2.0, 1.0)  # amplitudes of the once- and twice-per-lap drag variation [deg]

# ---- reachability check
CHECK_STEP = 5  # check every 5th point of the true path


# ---- geometry -----------------------------------------------------------------------------------


def saddle_z(x, y):
    """Height of the panel [m] over the CAD point (x, y) [m]."""
    return x**2 / (2.0 * RADIUS_LONG) - y**2 / (2.0 * RADIUS_ACROSS)


def saddle_normals(x, y):
    """Upward unit normals of the panel at (x, y) [m], shape (n, 3)."""
    n = np.column_stack([-x / RADIUS_LONG, y / RADIUS_ACROSS, np.ones_like(x)])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def zip_rings(outer: np.ndarray, inner: np.ndarray) -> list[tuple[int, int, int]]:
    """Triangles between two closed rings of vertex indices that start at the same angle.

    Both rings run counter-clockwise seen from above and are sampled evenly in the same parameter;
    the zipper advances along whichever ring's next vertex comes first, so every triangle is
    counter-clockwise (normal up).
    """
    na, nb = len(outer), len(inner)
    faces, i, j = [], 0, 0
    while i < na or j < nb:
        if i < na and (j == nb or (i + 1) / na <= (j + 1) / nb):
            faces.append((outer[i], outer[(i + 1) % na], inner[j % nb]))
            i += 1
        else:
            faces.append((outer[i % na], inner[(j + 1) % nb], inner[j]))
            j += 1
    return faces


def panel_mesh() -> tuple[trimesh.Trimesh, float]:
    """The panel as a triangle mesh in the CAD frame [mm], and the footprint's perimeter [m]."""
    half_u, half_v = PANEL_LENGTH / 2, PANEL_WIDTH / 2
    # an even count puts a vertex in the middle of each long edge, where the bead starts
    n_edge = 2 * math.ceil(rounded_rectangle(half_u, half_v, CORNER_RADIUS, 1)[-1] / (2 * EDGE_SPACING))
    vertices, rings = [], []
    count = 0
    for k in range(N_RINGS):
        scale = 1.0 - k / N_RINGS
        n = n_edge if k == 0 else max(16, round(n_edge * scale * INNER_DENSITY))
        x, y, *_, perimeter = rounded_rectangle(half_u, half_v, CORNER_RADIUS, n)
        x, y = scale * x, scale * y
        vertices.append(np.column_stack([x, y, saddle_z(x, y)]))
        rings.append(count + np.arange(n))
        count += n
        if k == 0:
            edge_perimeter = perimeter
    vertices.append(np.zeros((1, 3)))  # the saddle point, centre of the fan
    faces = []
    for outer, inner in zip(rings[:-1], rings[1:], strict=True):
        faces += zip_rings(outer, inner)
    last = rings[-1]
    faces += [(last[i], last[(i + 1) % len(last)], count) for i in range(len(last))]
    mesh = trimesh.Trimesh(np.vstack(vertices) * 1000.0, np.array(faces), process=True)
    return mesh, edge_perimeter


def boundary_path(mesh: trimesh.Trimesh, start_near) -> np.ndarray:
    """The mesh's open boundary as a closed polyline in the CAD frame [m], shape (K + 1, 3).

    Trimesh finds the boundary edges (edges of one face only) and chains them; the loop is started
    at its vertex nearest ``start_near`` [m], run counter-clockwise seen from above, and closed by
    repeating its first vertex.
    """
    outline = mesh.outline()
    if len(outline.entities) != 1 or not outline.entities[0].closed:
        raise RuntimeError(f"the panel should have one closed boundary, got {outline.entities}")
    loop = outline.discrete[0][:-1] / 1000.0  # discrete repeats the first vertex
    x, y = loop[:, 0], loop[:, 1]
    if np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) < 0.0:  # shoelace: clockwise
        loop = loop[::-1]
    first = int(np.argmin(np.linalg.norm(loop - np.asarray(start_near), axis=1)))
    loop = np.roll(loop, -first, axis=0)
    return np.vstack([loop, loop[:1]])


def closed_tangents(points: np.ndarray) -> np.ndarray:
    """Unit tangents of a closed polyline (last point = first) by central differences, (K + 1, 3)."""
    ring = points[:-1]
    t = np.roll(ring, -1, axis=0) - np.roll(ring, 1, axis=0)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    return np.vstack([t, t[:1]])


# ---- reachability and clearance ------------------------------------------------------------------


def check_reachability(problem: Problem, positions, rotations) -> bool:
    """Chained DLS IK over every ``CHECK_STEP``-th point of the true path; prints the figures."""
    from refine.collision import CollisionModel
    from refine.optimise.seed import start_candidates
    from refine.robot.kinematics import TcpKinematics
    from refine.robot.registry import load_robot

    robot = load_robot(problem.robot.model)
    spec = robot.spec
    kin = TcpKinematics(robot, problem.robot.base_in_world, problem.tool.tcp_in_flange)
    margin = math.radians(problem.tolerances.joint_margin_deg)
    home = np.radians(problem.robot.home_deg)
    targets = make_transform(rotations, positions)[::CHECK_STEP]
    logging.getLogger("refine.collision").setLevel(logging.ERROR)  # the open panel mesh is meant
    collision = CollisionModel.for_problem(problem, robot)
    starts = start_candidates(spec.lower + margin, spec.upper - margin, home, seed=SEED)
    report = reachability_report(kin, targets, joint_margin_rad=margin, starts=starts, collision=collision)
    gaps = report.clearance or {}
    singular = problem.tolerances.singularity_margin
    collision_margin = problem.collision.margin_m
    ok = bool(
        report.errors.max() < 1e-6
        and report.joint_margins.min() > margin
        and report.manipulability.min() > singular
        and min(d for d, _ in gaps.values()) > collision_margin
    )
    qd = np.degrees(report.qs)
    print(
        f"reachability: {len(qd)} IK targets (every {CHECK_STEP}th point), chained from q0 [deg] = "
        f"{np.round(qd[0], 1).tolist()}"
    )
    print(
        f"  worst pose error {report.errors.max():.2e} (m and rad stacked), largest joint step between "
        f"targets {report.max_step_deg:.1f} deg"
    )
    print(
        f"  smallest joint-limit margin {math.degrees(report.joint_margins.min()):.1f} deg "
        f"(joint {report.worst_joint}; required {math.degrees(margin):.1f} deg)"
    )
    print(
        f"  smallest singular value of the scaled TCP Jacobian {report.sigma_min.min():.3f}, "
        f"smallest scaled manipulability {report.manipulability.min():.4f} (required {singular})"
    )
    print(
        f"  smallest clearance (required {collision_margin * 1000:.0f} mm): "
        + ", ".join(
            f"{name} {d * 1000:.0f} mm ({who.replace('tool:', 'tool/')})" for name, (d, who) in gaps.items()
        )
    )
    print(
        "  joint ranges [deg]: "
        + ", ".join(f"q{j + 1} {qd[:, j].min():.0f}..{qd[:, j].max():.0f}" for j in range(qd.shape[1]))
    )
    print(f"  reachable: {ok}")
    return ok


# ---- main ---------------------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--no-check", action="store_true", help="skip the IK and clearance check")
    args = parser.parse_args(argv)
    problem = load_problem(HERE)
    T_F_CAD = problem.frames.cad_in_world
    T_F_S = problem.frames.source_in_world
    T_TCP_E = problem.tool.sensor_in_tcp
    rng = np.random.default_rng(SEED)

    # ---- the panel mesh, written and read back: the truth comes from the file the reader sees
    mesh, footprint_perimeter = panel_mesh()
    (HERE / MESH_FILE).write_bytes(mesh.export(file_type="stl"))
    written = trimesh.load(HERE / MESH_FILE, file_type="stl", process=True)
    start_near = np.asarray(problem.cad.start_near) / 1000.0  # [mm] in problem.toml
    bead_cad = boundary_path(written, start_near)

    # ---- the closed path in the world, arc length as a polyline reader measures it
    positions = transform_points(T_F_CAD, bead_cad)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(bead_cad, axis=0), axis=1))])
    perimeter = s[-1]
    R_F_CAD = T_F_CAD[:3, :3]
    normals = saddle_normals(bead_cad[:, 0], bead_cad[:, 1]) @ R_F_CAD.T
    tangents = closed_tangents(bead_cad) @ R_F_CAD.T

    # ---- the worker: drag angle and speed, smooth and periodic over the lap
    drag_deg = DRAG_MEAN_DEG + periodic_wave(s, perimeter, DRAG_WAVES_DEG, rng)
    rotations = tool_rotations(tangents, normals, np.radians(drag_deg), project=True)
    half_u, half_v = PANEL_LENGTH / 2 - CORNER_RADIUS, PANEL_WIDTH / 2 - CORNER_RADIUS
    corner = (np.abs(bead_cad[:-1, 0]) > half_u + 1e-9) & (np.abs(bead_cad[:-1, 1]) > half_v + 1e-9)
    spacing = perimeter / len(corner)
    slow = gaussian_filter1d(corner.astype(float), CORNER_BLEND / spacing, mode="wrap")
    slow = np.append(slow, slow[0]) / slow.max()
    speed = SPEED_STRAIGHT - (SPEED_STRAIGHT - SPEED_CORNER) * slow
    speed += periodic_wave(s, perimeter, (0.0, 0.0, SPEED_WANDER), rng)

    # ---- the tracker log
    model = TrackerModel(seed=SEED)
    demo = simulate_demonstration(s, positions, rotations, speed, T_F_S, T_TCP_E, model)
    write_liberty_ascii(HERE / "demo.liberty", demo.log, units="in", rate_hz=model.rate_hz)
    write_truth_csv(HERE / "truth.csv", demo.s, demo.quaternions, demo.speed)

    # ---- summary
    tilt = np.degrees(np.arccos(np.clip(-rotations[:, 2, 2], -1.0, 1.0)))
    normal_tilt = np.degrees(np.arccos(np.clip(normals[:, 2], -1.0, 1.0)))
    size_kb = (HERE / MESH_FILE).stat().st_size / 1024
    print(
        f"panel {PANEL_LENGTH * 1000:.0f} x {PANEL_WIDTH * 1000:.0f} mm, corner radius "
        f"{CORNER_RADIUS * 1000:.0f} mm, saddle radii {RADIUS_LONG} m (along) / "
        f"{RADIUS_ACROSS} m (across); footprint perimeter {footprint_perimeter:.4f} m"
    )
    print(
        f"mesh {MESH_FILE}: {len(written.vertices)} vertices, {len(written.faces)} faces, "
        f"{size_kb:.0f} KiB, area {written.area / 1e6:.4f} m^2, watertight {written.is_watertight}"
    )
    print(
        f"bead (mesh boundary): {len(bead_cad) - 1} vertices, {perimeter:.4f} m, spacing "
        f"{perimeter / (len(bead_cad) - 1) * 1000:.2f} mm, CAD z {bead_cad[:, 2].min() * 1000:.1f}.."
        f"{bead_cad[:, 2].max() * 1000:.1f} mm, starts at CAD {np.round(bead_cad[0] * 1000, 1).tolist()} mm"
    )
    print("\n".join(demo.summary(positions, drag_deg, speed)))
    print(
        f"surface normal {normal_tilt.min():.1f}..{normal_tilt.max():.1f} deg from vertical, "
        f"tool axis {tilt.min():.1f}..{tilt.max():.1f} deg from vertical"
    )
    print(f"wrote {MESH_FILE}, demo.liberty, truth.csv in {HERE}")

    if not args.no_check:
        return 0 if check_reachability(problem, positions, rotations) else 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
