"""Generate the data of the ``tig_weld`` problem: ``seam.dxf``, ``demo.liberty``, ``truth.csv``.

The cell: a T-joint of two steel plates lies in a 45 deg cradle on a welding table in front of a
KUKA LBR iiwa 14 R820 with a TIG torch and a laser seam-tracking sensor mounted ahead of it. A
welder once welded the root pass by hand with a TIG torch carrying a Polhemus Liberty sensor; this
script makes that demonstration by simulation, so the true torch orientations and speeds are known
(``truth.csv``).

Geometry (numbers below, explained in README.md), in the CAD (workpiece) frame:

* The base plate is bent: a low flat, a bend up of radius ``BEND_RADIUS`` by ``RAMP_DEG``, a ramp,
  a bend back and a high flat. Its top face contains the CAD x axis; the seam runs in the CAD y-z
  plane, starting at the origin along +y, rising on the ramp in +z.
* The web plate is flat, in the plane x = 0 on the seam's +x side, standing on the base plate
  (z up); its bottom edge is cut to the base plate's profile. The fillet is on its -x face.
* Seam frame: tangent ``t``; base-plate normal ``n`` (turns with the bends); web normal (-1, 0, 0);
  bisector ``b = (n + (-1, 0, 0)) / sqrt(2)`` pointing out of the joint; lateral ``l = t x b``.
* ``cad_in_world`` tilts the workpiece 45 deg about the CAD y axis (the flat, 1F position), so on
  the flats the bisector is vertical and the torch points down.
* True torch orientation: z axis into the joint along ``-b``, turned by the work-angle deviation
  ``w`` about ``t`` (positive: towards the base plate, so the work angle from the base plate is
  45 deg + ``w``), then tilted forward by the push angle (the tip points along the travel); x along
  the travel, where the seam-tracking sensor looks ahead.
* True speed: 5 mm/s, slower in the bends, with a slow wander.

The frames are read from ``problem.toml`` so the data always agree with the problem file; the
script also checks that the plate boxes in ``[[cell.objects]]`` match the geometry here. Everything
is deterministic (``SEED``).

Run from the repository root::

    python problems/tig_weld/generate.py             # writes the files, checks reach and clearance
    python problems/tig_weld/generate.py --no-check  # skip the checks
    python problems/tig_weld/generate.py --print-cell  # print the plate boxes as TOML
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import ezdxf
import numpy as np

from refine.collision.geometry import fcl_geometry
from refine.demo.liberty import write_liberty_ascii
from refine.demo.simulate import TrackerModel, simulate_demonstration, write_truth_csv
from refine.frames import fixed_xyz_from_matrix, make_transform, rotation_about
from refine.problem import Problem, load_problem
from refine.synthetic import polish_ik

HERE = Path(__file__).resolve().parent
SEED = 20240612

# ---- seam and plates [m, deg]
LOW_LENGTH = 0.13  # section 1, low flat
BEND_RADIUS = 0.040  # sections 2 and 4, radius of the seam in the bends
RAMP_DEG = 30.0
RAMP_LENGTH = 0.17  # section 3
HIGH_LENGTH = 0.13  # section 5, high flat
POINT_SPACING = 0.001  # DXF vertex spacing along the seam
PLATE_THICKNESS = 0.004  # both plates
BASE_FILLET_SIDE = 0.07  # base plate width on the fillet side of the web (CAD -x)
BASE_BACK_SIDE = 0.03  # base plate width behind the web (CAD +x), web thickness included
WEB_HEIGHT = 0.06  # web plate height above the seam
OVERHANG = 0.015  # plates reach past both seam ends
CRADLE_WIDTH = 0.04  # blocks under the plates' lowest edge, in x
CRADLE_GAP = 0.001  # between a cradle and the plates

# ---- welder
SPEED = 0.0050  # [m/s]
SPEED_BEND = 0.0042  # in the middle of a bend [m/s]
SPEED_WANDER = 0.00015  # amplitude [m/s]
PUSH_DEG = 12.0
PUSH_BEND_DEG = (2.5, -2.0)  # change in the middle of the bend up (valley) and the bend back (ridge)
PUSH_WANDER_DEG = 0.5
WORK_BEND_DEG = (4.0, -3.0)  # work-angle deviation from the bisector in the two bends
WORK_WANDER_DEG = 0.8
BLEND_M = 0.018  # 1-sigma width of the welder's change through a bend [m]


# ---- geometry -----------------------------------------------------------------------------------


def sections() -> list[tuple[float, float]]:
    """(length [m], curvature [1/m]) of the five seam sections, in the CAD y-z plane."""
    arc = BEND_RADIUS * math.radians(RAMP_DEG)
    k = 1.0 / BEND_RADIUS
    return [(LOW_LENGTH, 0.0), (arc, k), (RAMP_LENGTH, 0.0), (arc, -k), (HIGH_LENGTH, 0.0)]


def seam_profile(sigma: np.ndarray):
    """Seam points at arc lengths ``sigma`` [m] in the CAD frame.

    Returns:
        points (n, 3) [m], slope angle phi (n,) [rad] (the tangent is (0, cos phi, sin phi)), and
        the section index (0..4) of each point.
    """
    yz, phi, section = np.zeros((len(sigma), 2)), np.zeros(len(sigma)), np.zeros(len(sigma), int)
    p0, phi0, start = np.zeros(2), 0.0, 0.0
    for j, (length, k) in enumerate(sections()):
        m = (sigma >= start - 1e-12) & (sigma <= start + length + 1e-12)
        d = sigma[m] - start
        ph = phi0 + k * d
        if k == 0.0:
            yz[m] = p0 + d[:, None] * [math.cos(phi0), math.sin(phi0)]
        else:
            yz[m] = p0 + np.column_stack([np.sin(ph) - math.sin(phi0), math.cos(phi0) - np.cos(ph)]) / k
        phi[m], section[m] = ph, j
        end = phi0 + k * length
        p0 = p0 + (
            length * np.array([math.cos(phi0), math.sin(phi0)])
            if k == 0.0
            else np.array([math.sin(end) - math.sin(phi0), math.cos(phi0) - math.cos(end)]) / k
        )
        phi0, start = end, start + length
    return np.column_stack([np.zeros(len(sigma)), yz]), phi, section


def seam_frame(phi: np.ndarray):
    """Tangent, base-plate normal and bisector in the CAD frame, each (n, 3)."""
    zero, c, s = np.zeros_like(phi), np.cos(phi), np.sin(phi)
    t = np.column_stack([zero, c, s])
    n = np.column_stack([zero, -s, c])
    b = (n + [-1.0, 0.0, 0.0]) / math.sqrt(2.0)
    return t, n, b


def torch_rotations(t, b, push_deg, work_deg):
    """R_TCP per point: z into the joint (work angle about t, then push forward), x along travel."""
    p, w = np.radians(push_deg)[:, None], np.radians(work_deg)[:, None]
    lateral = np.cross(t, b)
    z = -np.cos(p) * (np.cos(w) * b + np.sin(w) * lateral) + np.sin(p) * t
    x = t - np.sum(t * z, axis=1, keepdims=True) * z
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    return np.stack([x, np.cross(z, x), z], axis=-1)


def bend_bumps(sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian bumps (peak 1) centred on the middle of the bend up and of the bend back."""
    lengths = np.cumsum([0.0] + [length for length, _ in sections()])
    mids = (0.5 * (lengths[1] + lengths[2]), 0.5 * (lengths[3] + lengths[4]))
    return tuple(np.exp(-0.5 * ((sigma - m) / BLEND_M) ** 2) for m in mids)  # type: ignore[return-value]


def slow_wave(sigma, length, amplitude, rng, periods=(1.0, 2.3)):
    """A smooth random wander along the seam: two sines of random phase, given amplitude."""
    phases = rng.uniform(0.0, 2.0 * math.pi, size=len(periods))
    return amplitude * sum(
        w * np.sin(2.0 * math.pi * k * sigma / length + p)
        for w, k, p in zip((0.7, 0.3), periods, phases, strict=True)
    )


def plate_boxes() -> list[tuple[str, np.ndarray, np.ndarray]]:
    """The two plates as three boxes each (one per flat section), in the CAD frame.

    Each box runs from one virtual sharp corner of the profile (where the tangent lines of two
    flat sections meet) to the next, and past the seam ends by ``OVERHANG``.

    Returns:
        (name, size (3,) [m], pose T_CAD_box (4, 4)) per box.
    """
    lengths = np.cumsum([0.0] + [length for length, _ in sections()])
    tan_half = math.tan(math.radians(RAMP_DEG) / 2.0)
    boxes = []
    for j, name in ((0, "1"), (2, "3"), (4, "5")):
        a, b = lengths[j], lengths[j + 1]
        pts, phi, _ = seam_profile(np.array([a, b]))
        # from the section ends along the tangent to the virtual corners, or past the seam ends
        back = OVERHANG if j == 0 else BEND_RADIUS * tan_half
        ahead = OVERHANG if j == 4 else BEND_RADIUS * tan_half
        t, n, _ = seam_frame(phi[:1])
        start, end = pts[0] - back * t[0], pts[1] + ahead * t[0]
        R = rotation_about("x", phi[0])  # columns: CAD x, along the section, base-plate normal
        length = float(np.linalg.norm(end - start))
        mid = 0.5 * (start + end)
        x_mid = 0.5 * (BASE_BACK_SIDE - BASE_FILLET_SIDE)
        base_centre = mid + x_mid * np.array([1.0, 0.0, 0.0]) - 0.5 * PLATE_THICKNESS * n[0]
        web_centre = mid + 0.5 * PLATE_THICKNESS * np.array([1.0, 0.0, 0.0]) + 0.5 * WEB_HEIGHT * n[0]
        boxes.append(
            (
                f"base_plate_{name}",
                np.array([BASE_FILLET_SIDE + BASE_BACK_SIDE, length, PLATE_THICKNESS]),
                make_transform(R, base_centre),
            )
        )
        boxes.append(
            (
                f"web_plate_{name}",
                np.array([PLATE_THICKNESS, length, WEB_HEIGHT]),
                make_transform(R, web_centre),
            )
        )
    return boxes


# ---- files --------------------------------------------------------------------------------------


def write_seam_dxf(path: Path, seam_cad: np.ndarray, sigma_fine: np.ndarray) -> None:
    """The seam as an open 3D polyline in mm on layer SEAM; plate edges on BASE and WEB."""
    pts, phi, _ = seam_profile(sigma_fine)
    _, n, _ = seam_frame(phi)
    x = np.array([1.0, 0.0, 0.0])
    fixed = ezdxf.options.write_fixed_meta_data_for_testing
    ezdxf.options.write_fixed_meta_data_for_testing = True  # no time stamps: reproducible file
    try:
        doc = ezdxf.new("R2010")
        doc.units = ezdxf.units.MM
        for layer, colour in (("SEAM", 1), ("BASE", 5), ("WEB", 3)):
            doc.layers.add(layer, color=colour)
        msp = doc.modelspace()
        msp.add_polyline3d((seam_cad * 1000.0).tolist(), dxfattribs={"layer": "SEAM"})
        for offset in (-BASE_FILLET_SIDE * x, BASE_BACK_SIDE * x):
            msp.add_polyline3d(((pts + offset) * 1000.0).tolist(), dxfattribs={"layer": "BASE"})
        web_top = pts + WEB_HEIGHT * n
        msp.add_polyline3d((web_top * 1000.0).tolist(), dxfattribs={"layer": "WEB"})
        # the CLASSES section comes out in set order (it varies with PYTHONHASHSEED): fix it
        doc.classes.add_required_classes(doc.dxfversion)
        doc.classes.classes = dict(sorted(doc.classes.classes.items()))
        doc.saveas(path)
    finally:
        ezdxf.options.write_fixed_meta_data_for_testing = fixed


def box_corners(size: np.ndarray, T: np.ndarray) -> np.ndarray:
    """The 8 corners (8, 3) [m] of a box of ``size`` centred on the pose ``T``."""
    signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], dtype=float)
    return (0.5 * signs * size) @ T[:3, :3].T + T[:3, 3]


def cell_boxes(problem: Problem) -> list[tuple[str, np.ndarray, np.ndarray, bool]]:
    """The plate boxes placed in the world by ``cad_in_world``, and the cradles under them.

    A cradle is a block from the table top (the top face of the cell object ``table``) up to
    ``CRADLE_GAP`` below the lowest corner of the plates of a flat section, ``CRADLE_WIDTH`` wide
    in x about that corner, as long as the section: a simplified 45 deg V-block.

    Returns:
        (name, size (3,) [m], pose T_F_box (4, 4), workpiece) per box.
    """
    T_F_CAD = problem.frames.cad_in_world
    plates = [(name, size, T_F_CAD @ T, True) for name, size, T in plate_boxes()]
    table = next(o for o in problem.cell if o.name == "table")
    table_top = table.pose[2, 3] + 0.5 * table.size_m[2]
    cradles = []
    for section, label in (("1", "low"), ("5", "high")):
        corners = np.vstack([box_corners(size, T) for name, size, T, _ in plates if name.endswith(section)])
        low = corners[np.argmin(corners[:, 2])]
        top = corners[:, 2].min() - CRADLE_GAP
        y0, y1 = corners[:, 1].min(), corners[:, 1].max()
        size = np.array([CRADLE_WIDTH, y1 - y0, top - table_top])
        centre = np.array([low[0], 0.5 * (y0 + y1), 0.5 * (top + table_top)])
        cradles.append((f"cradle_{label}", size, make_transform(None, centre), False))
    return plates + cradles


def compare_cell(problem: Problem, print_toml: bool) -> bool:
    """Do the plates and cradles of ``problem.toml`` match the geometry? Optionally print TOML."""
    listed = {o.name: o for o in problem.cell}
    ok = True
    for name, size, T, workpiece in cell_boxes(problem):
        xyz, rpy = T[:3, 3] + 0.0, np.round(fixed_xyz_from_matrix(T[:3, :3]), 1) + 0.0
        if print_toml:
            print(
                f'\n[[cell.objects]]\nname = "{name}"\nshape = "box"\n'
                f"size_m = [{', '.join(f'{v:.4f}' for v in size)}]\n"
                f"pose = {{ xyz = [{', '.join(f'{v:.4f}' for v in xyz)}], "
                f"rpy_deg = [{', '.join(f'{v:.1f}' for v in rpy)}] }}"
                + ("\nworkpiece = true" if workpiece else "")
            )
        o = listed.get(name)
        if o is None or o.workpiece != workpiece:
            print(f"cell: {name} missing from problem.toml or workpiece is not {str(workpiece).lower()}")
            ok = False
            continue
        if (
            o.size_m is None
            or np.abs(np.array(o.size_m) - size).max() > 2e-4
            or np.abs(o.pose - T).max() > 2e-4
        ):
            print(f"cell: {name} in problem.toml differs from the geometry (run with --print-cell)")
            ok = False
    return ok


# ---- checks: reach of every pass, clearance -----------------------------------------------------


def _fcl_object(geometry, T):
    import fcl

    return fcl.CollisionObject(geometry, fcl.Transform(T[:3, :3], T[:3, 3]))


def _distance(a, b) -> float:
    import fcl

    return float(fcl.distance(a, b, fcl.DistanceRequest(), fcl.DistanceResult()))


def run_checks(s, positions, rotations, speed, step: int = 5) -> bool:
    """Chained DLS IK over every ``step``-th point of every pass of the true path; clearances.

    The root pass is the true path; the later passes come from ``refine.fuse.passes`` applied to it.
    Prints, per pass, the worst IK error, the smallest joint-limit margin, the smallest singular
    value and scaled manipulability of the TCP Jacobian (linear rows / reach), the largest joint
    step, and the smallest clearances (robot links to every cell object, tool to the cell objects
    that are not workpieces, and, for information, tool to the workpieces).
    """
    from refine.fuse.passes import Pass, generate_passes
    from refine.optimise.seed import ik_chain, start_candidates
    from refine.paths import FusedPath
    from refine.robot.kinematics import TcpKinematics
    from refine.robot.registry import load_robot

    problem = load_problem(HERE)
    robot = load_robot(problem.robot.model)
    spec, T_F_R = robot.spec, problem.robot.base_in_world
    kin = TcpKinematics(robot, T_F_R, problem.tool.tcp_in_flange)
    margin = math.radians(problem.tolerances.joint_margin_deg)
    lower, upper = spec.lower + margin, spec.upper - margin
    home = None if problem.robot.home_deg is None else np.radians(problem.robot.home_deg)
    starts = start_candidates(lower, upper, home)
    root = FusedPath(s, positions, rotations, speed, s / speed, np.zeros(len(s)))
    passes = generate_passes(root, problem.multipass) if problem.multipass else [Pass(1, 1, 0, 0, 0, root)]
    cell = [(o, _fcl_object(fcl_geometry(o), o.pose)) for o in problem.cell]
    links = [(c, c.geometry) for c in robot.collision_shapes() if c.link != "base_link"]  # base: fixed
    tool = [(o, fcl_geometry(o)) for o in problem.tool.collision]
    ok = True
    print(
        f"checks: every {step}th point, chained DLS IK (refine.optimise.seed.ik_chain) inside the "
        f"limits shrunk by {problem.tolerances.joint_margin_deg:g} deg"
    )
    for p in passes:
        path = p.path
        idx = np.arange(0, len(path), step)
        if idx[-1] != len(path) - 1:
            idx = np.append(idx, len(path) - 1)
        targets = make_transform(path.rotations[idx], path.positions[idx])
        qs, errors = ik_chain(kin, targets, lower, upper, starts)
        chain_error = float(errors.max())
        for k, T in enumerate(targets):  # polish: the chain stops near 1e-6; Gauss-Newton from there
            qs[k], errors[k] = polish_ik(kin, T, qs[k])  # 5 steps
        jm = np.minimum(qs - spec.lower, spec.upper - qs)
        sig, man = [], []
        for q in qs:
            J = kin.jacobian(q)
            Js = np.vstack([J[:3] / spec.reach_m, J[3:]])
            sig.append(np.linalg.svd(Js, compute_uv=False)[-1])
            man.append(math.sqrt(max(np.linalg.det(Js @ Js.T), 0.0)))
        links_min = tool_cell_min = np.inf
        tool_work = {shape.name: np.inf for shape, _ in tool}
        worst = ""
        for q in qs:
            link_T = robot.link_poses(q)
            flange = T_F_R @ robot.fk(q)
            for c, geom in links:
                obj = _fcl_object(geom, T_F_R @ link_T[c.link] @ c.link_T_shape)
                for o, other in cell:
                    d = _distance(obj, other)
                    if d < links_min:
                        links_min, worst = d, f"{c.link}/{c.name} - {o.name}"
            for shape, geom in tool:
                obj = _fcl_object(geom, flange @ shape.pose)
                for o, other in cell:
                    d = _distance(obj, other)
                    if o.workpiece:
                        tool_work[shape.name] = min(tool_work[shape.name], d)
                    else:
                        tool_cell_min = min(tool_cell_min, d)
        good = bool(
            chain_error < 1e-6
            and errors.max() < 1e-9
            and jm.min() >= margin - 1e-9
            and min(man) > problem.tolerances.singularity_margin
            and links_min > problem.collision.margin_m
            and tool_cell_min > problem.collision.margin_m
        )
        ok &= good
        step_max = np.degrees(np.abs(np.diff(qs, axis=0)).max())
        qd = np.degrees(qs)
        print(
            f"  layer {p.layer} pass {p.index} (offset {p.lateral_offset_m * 1000:+.1f} mm, height "
            f"{p.height_m * 1000:.0f} mm, work {p.work_angle_change_deg:+.0f} deg): {len(idx)} targets, "
            f"IK error {chain_error:.1e} (chain), {errors.max():.1e} (polished), min joint margin {math.degrees(jm.min()):.1f} deg "
            f"(joint {int(np.argmin(jm.min(axis=0))) + 1}), min singular value {min(sig):.3f}, "
            f"min manipulability {min(man):.3f}, max joint step {step_max:.1f} deg"
        )
        print(
            f"    clearance: links-cell {links_min * 1000:.0f} mm ({worst}), tool-table/fixture "
            f"{tool_cell_min * 1000:.0f} mm, tool-workpiece (information) "
            + ", ".join(f"{k} {v * 1000:.1f} mm" for k, v in tool_work.items())
            + "; "
            + ("start q [deg] " + str(np.round(qd[0], 1).tolist()) if p.layer == 1 else "")
            + f"{'' if good else '  <-- FAILS'}"
        )
        if p.layer == 1:
            print(
                "    joint ranges [deg]: "
                + ", ".join(
                    f"q{j + 1} {qd[:, j].min():.0f}..{qd[:, j].max():.0f}" for j in range(qd.shape[1])
                )
            )
    print(f"  all passes reachable and clear: {ok}")
    return ok


# ---- main ---------------------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--no-check", action="store_true", help="skip the reach and clearance checks")
    parser.add_argument("--print-cell", action="store_true", help="print the plate boxes as TOML")
    args = parser.parse_args(argv)
    problem = load_problem(HERE)
    T_F_CAD = problem.frames.cad_in_world
    T_F_S = problem.frames.source_in_world
    T_TCP_E = problem.tool.sensor_in_tcp
    rng = np.random.default_rng(SEED)

    # ---- the seam in the CAD frame, vertices POINT_SPACING apart (piece ends included)
    length = sum(piece for piece, _ in sections())
    n = int(math.ceil(length / POINT_SPACING))
    sigma = np.linspace(0.0, length, n + 1)
    seam_cad, phi, _ = seam_profile(sigma)
    t_cad, _, b_cad = seam_frame(phi)
    write_seam_dxf(HERE / "seam.dxf", seam_cad, sigma)

    # ---- in the world; arc length as a polyline reader measures it
    R_F_CAD = T_F_CAD[:3, :3]
    positions = seam_cad @ R_F_CAD.T + T_F_CAD[:3, 3]
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(seam_cad, axis=0), axis=1))])
    t, b = t_cad @ R_F_CAD.T, b_cad @ R_F_CAD.T

    # ---- the welder: push and work angle change through the bends; speed drops there
    valley, ridge = bend_bumps(sigma)
    push = PUSH_DEG + PUSH_BEND_DEG[0] * valley + PUSH_BEND_DEG[1] * ridge
    push += slow_wave(sigma, length, PUSH_WANDER_DEG, rng)
    work = (
        WORK_BEND_DEG[0] * valley + WORK_BEND_DEG[1] * ridge + slow_wave(sigma, length, WORK_WANDER_DEG, rng)
    )
    rotations = torch_rotations(t, b, push, work)
    speed = SPEED - (SPEED - SPEED_BEND) * np.maximum(valley, ridge)
    speed += slow_wave(sigma, length, SPEED_WANDER, rng, periods=(3.0, 5.0))

    # ---- the tracker log
    model = TrackerModel(seed=SEED)
    demo = simulate_demonstration(s, positions, rotations, speed, T_F_S, T_TCP_E, model)
    write_liberty_ascii(HERE / "demo.liberty", demo.log, units="in", rate_hz=model.rate_hz)
    write_truth_csv(HERE / "truth.csv", demo.s, demo.quaternions, demo.speed)

    # ---- summary
    sensor = demo.sensor_in_source[:, :3, 3]
    dist = np.linalg.norm(sensor, axis=1)
    bounds = np.cumsum([0.0] + [piece for piece, _ in sections()])
    print(
        f"seam: {len(sigma)} points, {s[-1]:.4f} m, sections [mm] "
        + ", ".join(f"{(b1 - b0) * 1000:.1f}" for b0, b1 in zip(bounds[:-1], bounds[1:], strict=True))
        + f"; ramp {RAMP_DEG:g} deg, bend radius {BEND_RADIUS * 1000:.0f} mm"
    )
    lo, hi = positions.min(axis=0), positions.max(axis=0)
    print(
        f"seam in world: x {lo[0]:.3f}..{hi[0]:.3f}, y {lo[1]:.3f}..{hi[1]:.3f}, z {lo[2]:.3f}..{hi[2]:.3f} m;"
        f" from the base {np.linalg.norm(positions - problem.robot.base_in_world[:3, 3], axis=1).min():.3f}"
        f"..{np.linalg.norm(positions - problem.robot.base_in_world[:3, 3], axis=1).max():.3f} m"
    )
    tilt = np.degrees(np.arccos(np.clip(-rotations[:, 2, 2], -1.0, 1.0)))
    print(
        f"push {push.min():.1f}..{push.max():.1f} deg, work angle from the base plate "
        f"{45 + work.min():.1f}..{45 + work.max():.1f} deg, torch {tilt.min():.1f}..{tilt.max():.1f} deg "
        f"from vertical, speed {speed.min() * 1000:.2f}..{speed.max() * 1000:.2f} mm/s"
    )
    size = (HERE / "demo.liberty").stat().st_size
    print(
        f"demo: {len(demo.log.t)} samples at {model.rate_hz:g} Hz, {demo.duration_s:.2f} s "
        f"({model.pause_s:g} s pause), {size / 1e6:.2f} MB, outliers at {list(demo.outlier_indices)}"
    )
    print(f"sensor to receiver {dist.min():.2f}..{dist.max():.2f} m")
    print(f"wrote seam.dxf, demo.liberty, truth.csv in {HERE}")

    ok = compare_cell(problem, args.print_cell)
    if not args.no_check:
        ok &= run_checks(s, positions, rotations, speed, step=5)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
