"""Generate the data of the ``kr8_arc_weld`` problem: ``seam.dxf``, ``demo.liberty``, ``truth.csv``.

The cell: a bracket (a bent L-shaped web plate standing on a base plate) lies on a welding table in
front of a KUKA KR 8 R1440-2 arc HW carrying a 22 deg bent-neck MAG torch through its hollow wrist.
The inside fillet between web and base plate runs along the first leg, round the bend and along the
second leg. A welder once welded it by hand with a MAG torch carrying a Polhemus Liberty sensor;
this script makes that demonstration by simulation, so the true torch orientations and speeds are
known (``truth.csv``).

Geometry (numbers below, explained in README.md), in the CAD (bracket) frame, z up from the base
plate's top face:

* Seam (the root of the fillet): from the origin along +y for ``LEG_1``, a quarter circle of radius
  ``BEND_RADIUS`` about ``(BEND_RADIUS, LEG_1)`` turning to +x, then along +x for ``LEG_2``. The DXF
  holds it as one ``LWPOLYLINE`` whose middle segment is a bulge (the exact arc).
* The web plate stands behind the seam: on the first leg its face is the plane x = 0 (the plate at
  x < 0), on the second leg the plane y = ``LEG_1 + BEND_RADIUS`` (the plate beyond), round the
  bend the cylinder of radius ``BEND_RADIUS``. ``n_web`` is the web face's normal into the fillet.
* True torch orientation: the nozzle (TCP z) points into the joint along ``-b``, the bisector
  ``b = (z + n_web) / sqrt(2)`` (work angle 45 deg), turned by a small work-angle wander, and
  tilted forward by the push angle (the tip points along the travel, as MAG welders push); TCP x
  along the travel.
* True speed: 8 mm/s on the legs, 6.5 mm/s round the bend, with a slow wander.

The frames are read from ``problem.toml`` so the data always agree with it; the script also checks
that the plate boxes of ``[[cell.objects]]`` match the geometry here. Deterministic (``SEED``).

Run from the repository root::

    python problems/kr8_arc_weld/generate.py            # writes the files, checks reach and clearance
    python problems/kr8_arc_weld/generate.py --no-check # skip the IK and clearance check

``problems/m20ia_arc_weld`` and ``problems/gp12_arc_weld`` weld the same seam in the same cell with
other robots: their ``generate.py`` run this one's :func:`main` into their own folders.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
from pathlib import Path

import ezdxf
import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.spatial.transform import Rotation

from refine.demo.liberty import write_liberty_ascii
from refine.demo.simulate import TrackerModel, simulate_demonstration, write_truth_csv
from refine.frames import make_transform, transform_points
from refine.problem import Problem, load_problem
from refine.synthetic import problem_reachability, tool_rotations

HERE = Path(__file__).resolve().parent
SEED = 20241130

# ---- bracket [m]
LEG_1 = 0.25
BEND_RADIUS = 0.02
LEG_2 = 0.20
POINT_SPACING = 0.001  # sampling of the true path (the DXF holds the exact arc)
WEB_THICKNESS = 0.006
WEB_HEIGHT = 0.08
BASE_THICKNESS = 0.02
BASE_X = (-0.02, 0.30)  # base plate extent in CAD x and y
BASE_Y = (-0.03, 0.30)

# ---- welder
SPEED = 0.008  # [m/s]
SPEED_BEND = 0.0065
SPEED_WANDER = 0.0003
BEND_BLEND = 0.012  # Gaussian width of the slow-down round the bend [m]
PUSH_DEG = 10.0
PUSH_WANDER_DEG = 1.5
WORK_WANDER_DEG = 1.0

CHECK_STEP = 10  # reachability check on every 10th point of the true path


def seam() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The true seam in the CAD frame: exact arc length, points, unit tangents, web normals [m], bend flags."""
    arc_len = math.pi * BEND_RADIUS / 2.0
    total = LEG_1 + arc_len + LEG_2
    s = np.linspace(0.0, total, round(total / POINT_SPACING) + 1)
    p, t, n = np.zeros((len(s), 3)), np.zeros((len(s), 3)), np.zeros((len(s), 3))
    bend = (s > LEG_1) & (s < LEG_1 + arc_len)
    first, second = s <= LEG_1, s >= LEG_1 + arc_len
    p[first] = np.column_stack([np.zeros(first.sum()), s[first], np.zeros(first.sum())])
    t[first], n[first] = [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]
    u = s[second] - LEG_1 - arc_len
    p[second] = np.column_stack([BEND_RADIUS + u, np.full(len(u), LEG_1 + BEND_RADIUS), np.zeros(len(u))])
    t[second], n[second] = [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]
    phi = (s[bend] - LEG_1) / BEND_RADIUS  # 0 at the bend's start
    centre = np.array([BEND_RADIUS, LEG_1, 0.0])
    radial = np.column_stack([-np.cos(phi), np.sin(phi), np.zeros(len(phi))])  # centre -> seam
    p[bend] = centre + BEND_RADIUS * radial
    t[bend] = np.column_stack([np.sin(phi), np.cos(phi), np.zeros(len(phi))])
    n[bend] = -radial  # the web face round the bend looks at the centre
    return s, p, t, n, bend


def write_dxf(path: Path) -> None:
    """The seam as an LWPOLYLINE with the bend as a bulge (layer SEAM), the plate outlines for context."""
    fixed = ezdxf.options.write_fixed_meta_data_for_testing
    ezdxf.options.write_fixed_meta_data_for_testing = True  # no time stamps: reproducible file
    try:
        doc = ezdxf.new("R2010")
        doc.units = ezdxf.units.MM
        for layer, colour in (("SEAM", 1), ("BASE", 5)):
            doc.layers.add(layer, color=colour)
        msp = doc.modelspace()
        bulge = math.tan(-math.pi / 8.0)  # a quarter circle turning clockwise seen from +z
        mm = 1000.0
        msp.add_lwpolyline(
            [
                (0.0, 0.0, 0.0),
                (0.0, LEG_1 * mm, bulge),
                (BEND_RADIUS * mm, (LEG_1 + BEND_RADIUS) * mm, 0.0),
                ((BEND_RADIUS + LEG_2) * mm, (LEG_1 + BEND_RADIUS) * mm, 0.0),
            ],
            format="xyb",
            dxfattribs={"layer": "SEAM"},
        )
        corners = [
            (BASE_X[0], BASE_Y[0]),
            (BASE_X[1], BASE_Y[0]),
            (BASE_X[1], BASE_Y[1]),
            (BASE_X[0], BASE_Y[1]),
        ]
        msp.add_lwpolyline([(x * mm, y * mm) for x, y in corners], close=True, dxfattribs={"layer": "BASE"})
        doc.classes.add_required_classes(doc.dxfversion)
        doc.classes.classes = dict(sorted(doc.classes.classes.items()))
        doc.saveas(path)
    finally:
        ezdxf.options.write_fixed_meta_data_for_testing = fixed


def check_cell(problem: Problem) -> None:
    """The plate boxes of ``problem.toml`` are where this geometry puts them (1e-6 m)."""
    T = problem.frames.cad_in_world
    w, h = WEB_THICKNESS, WEB_HEIGHT
    expected = {  # CAD centre, size
        "base_plate": (
            [sum(BASE_X) / 2, sum(BASE_Y) / 2, -BASE_THICKNESS / 2],
            [BASE_X[1] - BASE_X[0], BASE_Y[1] - BASE_Y[0], BASE_THICKNESS],
        ),
        "web_leg_1": ([-w / 2, (LEG_1 - 0.01) / 2, h / 2], [w, LEG_1 + 0.01, h]),
        "web_leg_2": (
            [BEND_RADIUS + (LEG_2 + 0.01) / 2, LEG_1 + BEND_RADIUS + w / 2, h / 2],
            [LEG_2 + 0.01, w, h],
        ),
    }
    objects = {o.name: o for o in problem.cell}
    for name, (centre, size) in expected.items():
        o = objects[name]
        centre_world = transform_points(T, np.array([centre]))[0]
        size_world = np.abs(T[:3, :3]) @ np.array(size)
        if not (
            np.allclose(o.pose[:3, 3], centre_world, atol=1e-6)
            and np.allclose(o.size_m, size_world, atol=1e-6)
        ):
            raise SystemExit(
                f"cell object {name}: problem.toml has centre {o.pose[:3, 3]}, size {o.size_m}; "
                f"the geometry gives {np.round(centre_world, 6)}, {np.round(size_world, 6)}"
            )


def check_reachability(problem: Problem, positions: np.ndarray, rotations: np.ndarray) -> bool:
    """Chained IK over every ``CHECK_STEP``-th point of the true path; prints the figures."""
    targets = make_transform(rotations, positions)[::CHECK_STEP]
    report, ok = problem_reachability(problem, targets, SEED)
    from refine.robot.registry import load_robot

    qd = np.degrees(load_robot(problem.robot.model).spec.to_controller(report.qs))  # the controller's joints
    print(
        f"reachability: {len(qd)} IK targets, from A1..A6 [deg] = {np.round(qd[0], 1).tolist()}; worst pose "
        f"error {report.errors.max():.2e}, smallest joint margin {math.degrees(report.joint_margins.min()):.1f} "
        f"deg (A{report.worst_joint}), smallest scaled manipulability {report.manipulability.min():.4f}"
    )
    print(
        "  smallest clearance: "
        + ", ".join(f"{k} {d * 1000:.0f} mm ({who})" for k, (d, who) in (report.clearance or {}).items())
    )
    print(
        "  axis ranges [deg]: "
        + ", ".join(
            f"A{j + 1} {lo:.0f}..{hi:.0f}"
            for j, (lo, hi) in enumerate(zip(qd.min(0), qd.max(0), strict=True))
        )
    )
    print(f"  reachable: {ok}")
    return ok


def main(argv: list[str] | None = None, folder: Path = HERE) -> int:
    """Write the files into ``folder`` (this problem's, or another problem's on the same cell)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--no-check", action="store_true", help="skip the IK and clearance check")
    args = parser.parse_args(argv)
    write_dxf(folder / "seam.dxf")
    for name in ("demo.liberty", "truth.csv"):  # the problem names them; the first run writes them below
        (folder / name).touch()
    problem = load_problem(folder)
    check_cell(problem)
    T_F_CAD = problem.frames.cad_in_world
    rng = np.random.default_rng(SEED)

    s, p, t, n_web, bend = seam()  # s: the exact arc length, which bounds any reader's flattened arc

    # ---- the welder: work angle 45 deg (+ wander) about the travel, push angle (+ wander), speed
    R = T_F_CAD[:3, :3]
    up = np.array([0.0, 0.0, 1.0])
    bisector = (up + n_web) / np.linalg.norm(up + n_web, axis=1, keepdims=True)
    work = gaussian_filter1d(rng.standard_normal(len(s)), 0.04 / POINT_SPACING)  # smooth over ~40 mm
    work *= np.radians(WORK_WANDER_DEG) / np.abs(work).max()
    push = PUSH_DEG + PUSH_WANDER_DEG * np.sin(2.0 * math.pi * s / s[-1] + rng.uniform(0, 2 * math.pi))
    normals = Rotation.from_rotvec(t * work[:, None]).apply(
        bisector
    )  # the work-angle wander about the travel
    rotations = tool_rotations(t @ R.T, normals @ R.T, -np.radians(push), project=True)
    slow = gaussian_filter1d(bend.astype(float), BEND_BLEND / POINT_SPACING)
    speed = SPEED - (SPEED - SPEED_BEND) * slow / slow.max()
    speed += SPEED_WANDER * np.sin(4.0 * math.pi * s / s[-1] + rng.uniform(0, 2 * math.pi))
    positions = transform_points(T_F_CAD, p)

    # ---- the tracker log
    model = TrackerModel(seed=SEED)
    demo = simulate_demonstration(
        s, positions, rotations, speed, problem.frames.source_in_world, problem.tool.sensor_in_tcp, model
    )
    write_liberty_ascii(folder / "demo.liberty", demo.log, units="in", rate_hz=model.rate_hz)
    write_truth_csv(folder / "truth.csv", demo.s, demo.quaternions, demo.speed)
    lo, hi = positions.min(axis=0), positions.max(axis=0)
    print(
        f"seam {s[-1]:.4f} m ({len(s)} points), world x {lo[0]:.3f}..{hi[0]:.3f}, y {lo[1]:.3f}..{hi[1]:.3f}, "
        f"z {lo[2]:.3f} m; push {push.min():.1f}..{push.max():.1f} deg, work-angle wander "
        f"{np.degrees(np.abs(work).max()):.1f} deg, speed {speed.min() * 1000:.1f}..{speed.max() * 1000:.1f} mm/s"
    )
    print(f"demo: {len(demo.log.t)} samples at {model.rate_hz:g} Hz, {demo.duration_s:.1f} s")
    if not args.no_check:
        logging.getLogger("refine.collision").setLevel(logging.ERROR)
        return 0 if check_reachability(problem, positions, rotations) else 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
