"""The placement repair: ``[repair] placement``, the workpiece move, and the case built to need it.

The expected figures come from outside the code under test: rotations from scipy, the move of a
problem written into a copy of its ``problem.toml`` by text, and the smallest move a reach problem
can need from the KUKA LBR iiwa 14 R820's data-sheet dimensions.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from refine.errors import InputError
from refine.export.result_json import result_dict
from refine.optimise.moves import Placement, moved_path, moved_problem
from refine.problem import load_problem
from refine.run.solve import solve_problem
from refine.run.stages import fused_path
from refine.settings import PlacementSettings

ROOT = Path(__file__).resolve().parents[1]
CASE = ROOT / "problems" / "unreachable" / "placement_reach"
SCHEMA = ROOT / "docs" / "placement.schema.json"


def _copy(tmp_path: Path, edit) -> Path:
    """A copy of the placement case with its problem.toml text changed by ``edit``."""
    folder = tmp_path / "case"
    shutil.copytree(CASE, folder)
    toml = folder / "problem.toml"
    toml.write_text(edit(toml.read_text()))
    return folder


# ---- the option ---------------------------------------------------------------------------------


def test_the_option_is_read_with_its_bounds():
    p = load_problem(CASE)
    assert p.repair.placement == PlacementSettings(translate_m=0.2, rotate_deg=15.0)
    assert p.repair.placement.free == "plane"  # the default: the part stays on what it rests on
    assert {o.name for o in p.cell if o.workpiece} == {"plate", "fixture"}


def test_without_the_option_there_is_no_placement_search(tmp_path):
    folder = _copy(tmp_path, lambda s: re.sub(r"\[repair\]\nplacement = .*\n", "", s))
    assert load_problem(folder).repair.placement is None


@pytest.mark.parametrize(
    "value, words",
    [
        ("{ translate_m = 1.5, rotate_deg = 15.0 }", ["repair.placement.translate_m", "[0, 1] m", "1.5"]),
        ("{ translate_m = 0.2, rotate_deg = 50 }", ["repair.placement.rotate_deg", "[0, 45] deg", "50"]),
        ("{ translate_m = -0.1 }", ["repair.placement.translate_m", "-0.1"]),
        ("{ translate_m = 0, rotate_deg = 0 }", ["translate_m > 0 m or rotate_deg > 0 deg"]),
        ("{ translate_m = 0.2, turn_deg = 5 }", ["'turn_deg'", "allowed: free, rotate_deg, translate_m"]),
        ('{ translate_m = 0.2, free = "z" }', ["repair.placement.free", "'plane', 'all'", "'z'"]),
        ("{ translate_m = 0.2, free = 1 }", ["repair.placement.free", "string"]),
        ("{ translate_m = true }", ["repair.placement.translate_m", "number"]),
        ("0.2", ["repair.placement must be a table", "translate_m", "rotate_deg"]),
    ],
)
def test_a_bad_placement_option_is_refused_naming_key_value_and_range(tmp_path, value, words):
    folder = _copy(tmp_path, lambda s: re.sub(r"placement = .*\n", f"placement = {value}\n", s))
    with pytest.raises(InputError) as e:
        load_problem(folder)
    for w in words:
        assert w in str(e.value), str(e.value)


# ---- the move -----------------------------------------------------------------------------------


def test_the_move_turns_about_the_centre_then_shifts_as_scipy_says():
    rng = np.random.default_rng(3)
    c, t, r = rng.normal(size=3), rng.normal(size=3) * 0.1, rng.normal(size=3) * 0.2
    move = Placement(c, t, r)
    x = rng.normal(size=(5, 3))
    R = Rotation.from_rotvec(r).as_matrix()
    expected = (x - c) @ R.T + c + t
    D = move.transform
    assert np.allclose(x @ D[:3, :3].T + D[:3, 3], expected, atol=1e-12)
    doc = move.as_json()
    assert np.allclose(doc["rotation"]["rpy_deg"], Rotation.from_rotvec(r).as_euler("xyz", degrees=True))
    assert doc["rotation"]["angle_deg"] == pytest.approx(math.degrees(np.linalg.norm(r)))
    assert np.allclose(np.radians(doc["rotation"]["rotvec_deg"]), r)
    assert doc["distance_m"] == pytest.approx(np.linalg.norm(t))


def test_the_size_of_a_move_is_each_part_against_its_bound():
    # 50 mm of 200 mm and 3 deg of 15 deg: sqrt(0.25² + 0.2²)
    move = Placement(np.zeros(3), np.array([0.03, 0.04, 0.0]), np.radians([0.0, 0.0, 3.0]))
    assert move.norm(PlacementSettings(0.2, 15.0)) == pytest.approx(math.hypot(0.25, 0.2))
    assert move.norm(PlacementSettings(0.0, 15.0)) == math.inf  # a shift where none is allowed
    assert Placement(np.zeros(3), np.zeros(3), np.radians([0, 0, 3.0])).norm(
        PlacementSettings(0.0, 15.0)
    ) == (pytest.approx(0.2))


def test_moving_the_workpiece_moves_cad_demonstration_and_marked_objects_only(tmp_path):
    folder = _copy(
        tmp_path,
        lambda s: s.replace(
            "[expected]",
            '[[cell.objects]]\nname = "wall"\nshape = "box"\nsize_m = [0.1, 1.0, 1.0]\n'
            "pose = { xyz = [-0.5, 0.0, 0.5] }\n\n[expected]",
        ),
    )
    p = load_problem(folder)
    D = Placement(
        np.array([0.85, 0.0, 0.1]), np.array([-0.05, 0.01, 0.0]), np.radians([0, 0, 10.0])
    ).transform
    m = moved_problem(p, D)
    assert np.allclose(m.frames.cad_in_world, D @ p.frames.cad_in_world)
    assert np.allclose(m.frames.source_in_world, D @ p.frames.source_in_world)
    for before, after in zip(p.cell, m.cell, strict=True):
        assert np.allclose(after.pose, D @ before.pose if before.workpiece else before.pose), before.name
    assert m.robot is p.robot and m.repair.placement is None
    assert p.demonstration.truth is not None and m.demonstration.truth is None  # truth is in {F} as placed
    assert m.demonstration.file == p.demonstration.file


def test_fusing_the_moved_problem_gives_the_path_moved(tmp_path):
    """Fusion depends only on the CAD path and the demonstration relative to each other, so the
    placement's verification may move the fused path instead of fusing the moved files again."""
    p = load_problem(CASE)
    D = Placement(
        np.array([0.85, 0.0, 0.1]), np.array([-0.06, 0.02, 0.01]), np.radians([2.0, -3.0, 8.0])
    ).transform
    direct = fused_path(moved_problem(p, D))
    moved = moved_path(fused_path(p), D)
    assert np.allclose(direct.positions, moved.positions, atol=1e-9)
    angle = Rotation.from_matrix(np.einsum("nji,njk->nik", direct.rotations, moved.rotations)).magnitude()
    assert np.degrees(angle).max() < 1e-6
    assert np.allclose(direct.speed, moved.speed) and np.allclose(direct.s, moved.s)
    assert direct.demo_positions is not None  # the demonstration as fused moves with the path
    assert np.allclose(direct.demo_positions, moved.demo_positions, atol=1e-9)


# ---- the case: a part 0.15 m too far ------------------------------------------------------------

IIWA_SHOULDER_M = 0.36  # axis 2 above the mounting flange (KUKA LBR iiwa 14 R820 data sheet)
IIWA_ARM_M = 0.42 + 0.40  # axis 2 -> axis 4 -> axis 6: the wrist centre's largest distance from axis 2
IIWA_WRIST_M = 0.126  # wrist centre (axis 6) behind the flange
GUN_M = 0.20  # the problem's tcp_in_flange: the gun's length along the flange z axis
DEMO_ALLOWANCE_DEG = (
    2.0  # the fused demonstration may lean this far from the true upright gun (tracker noise)
)


def smallest_possible_norm(bounds: PlacementSettings, cone_deg: float) -> float:
    """A lower bound on the size of any move that brings the case's wrist centres into reach.

    The gun is upright, so the wrist centre is ``GUN_M + IIWA_WRIST_M`` above each TCP point. Moved
    by a shift ``t`` and a turn of ``θ`` about the centroid ``c``, with the tool within the cone
    (plus the demonstration's allowance) of the turned gun axis, a wrist centre moves at most
    ``|t| + θ (|p - c| + L) + L α``, L the wrist height. It must come within ``IIWA_ARM_M`` of the
    shoulder, so ``|t| + θ (|p - c| + L) >= D - IIWA_ARM_M - L α = δ``; the least
    ``sqrt((|t| / T)² + (θ / Θ)²)`` over that half-plane is ``δ / sqrt(T² + (|p - c| + L)² Θ²)``
    (Cauchy-Schwarz). Evaluated at the path's two ends, which are waypoints for any spacing.
    """
    T_F_CAD = np.eye(4)
    T_F_CAD[:3, 3] = [0.85, 0.0, 0.10]  # the problem file's cad_in_world (no turn)
    pts = np.loadtxt(CASE / "path.csv", delimiter=",", comments="#", skiprows=2) / 1000.0
    pts = pts @ T_F_CAD[:3, :3].T + T_F_CAD[:3, 3]
    c = 0.5 * (pts[0] + pts[-1])  # the centroid of waypoints evenly spaced along a straight line
    L = GUN_M + IIWA_WRIST_M
    alpha = math.radians(cone_deg + DEMO_ALLOWANCE_DEG)
    best = 0.0
    for p in (pts[0], pts[-1]):
        D = np.linalg.norm(p + [0.0, 0.0, L] - [0.0, 0.0, IIWA_SHOULDER_M])
        delta = D - IIWA_ARM_M - L * alpha
        lever = np.linalg.norm(p - c) + L
        best = max(best, delta / math.hypot(bounds.translate_m, lever * math.radians(bounds.rotate_deg)))
    return best


KNOWN_MOVE_M = 0.15
"""The part sits this much too far along x: 0.15 m nearer the same problem is ok (tested below)."""


@functools.cache
def _solved():
    problem = load_problem(CASE)
    return problem, solve_problem(problem)


@pytest.mark.slow
def test_the_case_is_repaired_by_slack_and_by_a_verified_placement():
    problem, result = _solved()
    assert result.status == "repaired", result.refinement.reason  # the slack repair, as before
    placement = result.placement
    assert placement.status == "ok", placement.reason
    assert placement.result.status == "ok"  # the moved problem's strict run
    assert placement.result.refinement.slack_deg.max() == 0.0
    from refine.api import Result

    public = Result(result).placement  # the library's view is the written document's
    assert public == result_dict(result)["placement"]
    assert public["status"] == "ok" and public["moved_objects"] == ["plate", "fixture"]


@pytest.mark.slow
def test_the_placement_in_result_json_follows_its_schema(require):
    jsonschema = require.module("jsonschema")
    _, result = _solved()
    doc = json.loads(json.dumps(result_dict(result)))["placement"]
    jsonschema.validate(doc, json.loads(SCHEMA.read_text()))
    assert doc["status"] == "ok" and doc["strict_status"] == "ok" and doc["frame"] == "world"
    tol = result.problem.tolerances
    m = doc["metrics"]
    assert m["max_position_error_m"] <= tol.position_m
    assert m["max_orientation_deviation_deg"] <= tol.orientation_deg + 1e-6
    assert m["min_singularity_measure"] >= tol.singularity_margin - 1e-6
    assert m["min_clearance_m"] >= result.problem.collision.margin_m
    assert doc["moved_objects"] == ["plate", "fixture"]


@pytest.mark.slow
def test_the_move_found_is_no_larger_than_the_known_one_nor_smaller_than_reach_allows():
    problem, result = _solved()
    doc = result_dict(result)["placement"]
    bounds = problem.repair.placement
    known = KNOWN_MOVE_M / bounds.translate_m  # the known move: 0.15 m back along x, no turn
    norm = math.hypot(
        doc["distance_m"] / bounds.translate_m, doc["rotation"]["angle_deg"] / bounds.rotate_deg
    )
    assert norm == pytest.approx(doc["norm"])
    assert norm <= known * 1.001
    assert norm >= smallest_possible_norm(bounds, problem.tolerances.orientation_deg)
    assert doc["translation_m"][0] < 0.0  # towards the robot
    assert (
        doc["distance_m"] <= bounds.translate_m + 1e-9
        and doc["rotation"]["angle_deg"] <= bounds.rotate_deg + 1e-9
    )


def _pose_text(xyz, rpy) -> str:
    a, b = (", ".join(f"{v:.12g}" for v in values) for values in (xyz, rpy))
    return f"{{ xyz = [{a}], rpy_deg = [{b}] }}"


def _moved_toml(text: str, R: np.ndarray, shift: np.ndarray, *, repair: bool = False) -> str:
    """``problem.toml`` text with the CAD frame, the receiver and the workpiece objects moved.

    The move is ``x -> R x + shift``, written from scipy's numbers alone; the repair (slack and
    placement) is switched off unless ``repair``.
    """

    def move(match: re.Match) -> str:
        xyz = np.array([float(v) for v in match.group(2).split(",")])
        rpy = np.array([float(v) for v in match.group(3).split(",")])
        rot = Rotation.from_matrix(R @ Rotation.from_euler("xyz", rpy, degrees=True).as_matrix())
        return f"{match.group(1)}{_pose_text(R @ xyz + shift, rot.as_euler('xyz', degrees=True))}"

    pose = r"\{ xyz = \[([^\]]*)\], rpy_deg = \[([^\]]*)\] \}"
    for key in ("cad_in_world", "source_in_world"):
        text = re.sub(rf"({key} = ){pose}", move, text)
    blocks = text.split("[[cell.objects]]")
    for i, block in enumerate(blocks[1:], start=1):
        if "workpiece = true" in block:
            blocks[i] = re.sub(rf"(pose = ){pose}", move, block)
    text = "[[cell.objects]]".join(blocks)
    return (
        text
        if repair
        else text.replace("placement = { translate_m = 0.2, rotate_deg = 15.0 }", "enabled = false")
    )


@pytest.mark.slow
def test_the_problem_moved_by_hand_by_the_move_found_is_ok_without_repair(tmp_path):
    _, result = _solved()
    doc = json.loads(json.dumps(result_dict(result)))["placement"]
    R = Rotation.from_rotvec(np.radians(doc["rotation"]["rotvec_deg"])).as_matrix()
    c, t = np.array(doc["about_m"]), np.array(doc["translation_m"])
    folder = _copy(tmp_path, lambda s: _moved_toml(s, R, c + t - R @ c))
    moved = load_problem(folder)
    assert moved.repair.placement is None and not moved.repair.enabled
    run = solve_problem(moved)
    assert run.status == "ok", run.refinement.reason
    assert run.first.clearance is not None and run.first.clearance.min_distance_m >= moved.collision.margin_m


@pytest.mark.slow
def test_the_part_put_back_by_the_known_move_is_ok_and_needs_no_placement(tmp_path, require):
    jsonschema = require.module("jsonschema")
    folder = _copy(
        tmp_path, lambda s: _moved_toml(s, np.eye(3), np.array([-KNOWN_MOVE_M, 0.0, 0.0]), repair=True)
    )
    problem = load_problem(folder)
    assert problem.frames.cad_in_world[0, 3] == pytest.approx(0.70)
    run = solve_problem(problem)
    assert run.status == "ok", run.refinement.reason
    assert run.placement.status == "not needed"
    doc = json.loads(json.dumps(result_dict(run)))["placement"]
    jsonschema.validate(doc, json.loads(SCHEMA.read_text()))
    assert doc["translation_m"] is None and doc["strict_status"] is None
    # asked anyway, the search finds no move to make and proposes none
    from refine.run.solve import repair_by_placement

    asked = repair_by_placement(problem, run.robot, run.first)
    assert asked.status == "infeasible" and asked.placement is None
    assert "without moving the workpiece" in asked.reason and "clearance" in asked.reason


@pytest.mark.slow
def test_the_summary_and_the_report_offer_the_move_beside_the_slack_repair(tmp_path):
    from refine.report.html import write_report
    from refine.run.result import summary_lines

    _, result = _solved()
    doc = result_dict(result)["placement"]
    shift = f"{doc['distance_m'] * 1e3:.1f} mm"
    line = next(s for s in summary_lines(result) if s.startswith("placement"))
    assert "ok (verified by the strict run)" in line and shift in line, line
    assert f"{doc['rotation']['angle_deg']:.2f} deg" in line, line
    page = write_report(tmp_path / "report.html", result).read_text()
    assert "Or move the workpiece" in page and shift in page


@pytest.mark.slow
def test_bounds_too_small_for_reach_give_an_infeasible_placement_saying_how_far_off():
    """5 mm and 0.5 deg: the data-sheet bound says no such move can bring the wrist centres in."""
    from refine.run.solve import repair_by_placement

    problem, result = _solved()
    small = PlacementSettings(translate_m=0.005, rotate_deg=0.5)
    # the largest move within the bounds has norm sqrt(2) (both parts at their bounds)
    assert smallest_possible_norm(small, problem.tolerances.orientation_deg) > math.sqrt(2.0)
    narrow = dataclasses.replace(problem, repair=dataclasses.replace(problem.repair, placement=small))
    outcome = repair_by_placement(narrow, result.robot, result.first)
    assert outcome.status == "infeasible"
    assert "no workpiece move within 0.005 m and 0.5 deg" in outcome.reason
    assert "beyond the cone" in outcome.reason, outcome.reason
    doc = outcome.as_json()
    assert doc["strict_status"] is None and doc["metrics"] is None


# ---- the part on a table: it slides on the table top, it does not sink into it ------------------

TABLE_SIZE_M = (0.6, 0.8, 0.7)
TABLE_TOP_M = 0.0  # the table box is centred 0.35 m below z = 0 and 0.70 m high: its top is z = 0
FIXTURE_BOTTOM_M = 0.04 - 0.08 / 2  # the fixture box (0.08 m high, centred at z = 0.04) rests on it
BOXES = {  # the workpiece boxes as the case's problem.toml places them (half sizes, centres) [m]
    "plate": (np.array([0.15, 0.15, 0.01]), np.array([0.85, 0.0, 0.09])),
    "fixture": (np.array([0.10, 0.10, 0.04]), np.array([0.85, 0.0, 0.04])),
}
POST = {"size_m": (0.06, 0.10, 0.15), "xyz": (0.73, 0.20, 0.075)}  # on the table, beside the way back
BLOCK = {"size_m": (0.06, 0.10, 0.15), "xyz": (0.73, 0.0, 0.075)}  # on the table, across the way back


def _box_toml(name: str, size, xyz) -> str:
    return (
        f'[[cell.objects]]\nname = "{name}"\nshape = "box"\nsize_m = [{", ".join(map(str, size))}]\n'
        f"pose = {{ xyz = [{', '.join(map(str, xyz))}], rpy_deg = [0.0, 0.0, 0.0] }}\n\n"
    )


def _table_cell(tmp_path: Path, too_far_m: float, free: str = "plane", extra: dict | None = None) -> Path:
    """The case moved ``too_far_m`` farther along x than it is (so 0.15 m + that from where it is ok),
    its fixture on a table whose top is z = 0, with optional other objects on the table."""
    x = 0.85 + too_far_m

    def edit(text: str) -> str:
        text = _moved_toml(text, np.eye(3), np.array([too_far_m, 0.0, 0.0]), repair=True)
        text = text.replace(
            "placement = { translate_m = 0.2, rotate_deg = 15.0 }",
            f'placement = {{ translate_m = 0.3, rotate_deg = 15.0, free = "{free}" }}',
        )
        objects = _box_toml("table", TABLE_SIZE_M, (x, 0.0, TABLE_TOP_M - TABLE_SIZE_M[2] / 2))
        for name, box in (extra or {}).items():
            objects += _box_toml(name, box["size_m"], box["xyz"])
        return text.replace("[expected]", objects + "[expected]")

    folder = tmp_path / f"table_{too_far_m}_{free}_{'_'.join(extra or {})}"
    shutil.copytree(CASE, folder)
    toml = folder / "problem.toml"
    toml.write_text(edit(toml.read_text()))
    return folder


def _corners(name: str, too_far_m: float, transform: np.ndarray) -> np.ndarray:
    """The 8 corners of a workpiece box after the cell's shift and then the placement's move [m]."""
    half, centre = BOXES[name]
    signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], dtype=float)
    points = centre + [too_far_m, 0.0, 0.0] + signs * half
    return points @ transform[:3, :3].T + transform[:3, 3]


def _fcl_distance(name: str, too_far_m: float, transform: np.ndarray, box: dict) -> float:
    """python-fcl's distance between a moved workpiece box and another box of the cell [m]."""
    import fcl

    half, centre = BOXES[name]
    T = transform @ np.block(
        [[np.eye(3), (centre + [too_far_m, 0.0, 0.0])[:, None]], [np.zeros((1, 3)), 1.0]]
    )
    a = fcl.CollisionObject(fcl.Box(*(2 * half)), fcl.Transform(T[:3, :3], T[:3, 3]))
    b = fcl.CollisionObject(fcl.Box(*box["size_m"]), fcl.Transform(np.eye(3), np.array(box["xyz"])))
    return float(fcl.distance(a, b, fcl.DistanceRequest(), fcl.DistanceResult()))


def test_the_support_is_the_table_beneath_or_else_the_world_z_plane(tmp_path):
    from refine.optimise.moves import support_plane

    on_table = support_plane(load_problem(_table_cell(tmp_path, 0.10)))
    assert on_table.support == "table"
    assert np.allclose(on_table.normal, [0.0, 0.0, 1.0]) and on_table.point_m[2] == pytest.approx(TABLE_TOP_M)
    # the case as it is has nothing beneath the fixture: the world z plane through its underside
    alone = support_plane(load_problem(CASE))
    assert alone.support is None and np.allclose(alone.normal, [0.0, 0.0, 1.0])
    assert alone.point_m[2] == pytest.approx(FIXTURE_BOTTOM_M)

    # a table 5 mm below the fixture does not carry it
    def lowered(text: str) -> str:
        return text.replace(
            "[expected]", _box_toml("table", TABLE_SIZE_M, (0.85, 0.0, -0.355)) + "[expected]"
        )

    assert support_plane(load_problem(_copy(tmp_path, lowered))).support is None


def test_a_plane_move_has_no_component_along_the_normal():
    from refine.optimise.moves import SupportPlane, move_basis

    normal = np.array([0.2, -0.3, 0.9]) / np.linalg.norm([0.2, -0.3, 0.9])
    E_t, E_r = move_basis(SupportPlane(normal, np.zeros(3), "tilted"), "plane")
    assert E_t.shape == (3, 2) and np.allclose(E_t.T @ E_t, np.eye(2)) and np.allclose(normal @ E_t, 0.0)
    assert np.allclose(np.cross(E_r[:, 0], normal), 0.0)
    E_t, E_r = move_basis(SupportPlane(normal, np.zeros(3), "tilted"), "all")
    assert np.allclose(E_t, np.eye(3)) and np.allclose(E_r, np.eye(3))


@functools.cache
def _table_run(folder: str):
    problem = load_problem(Path(folder))
    return problem, solve_problem(problem)


def _check_on_table(problem, result, too_far_m: float) -> np.ndarray:
    placement = result.placement
    assert placement.status == "ok", placement.reason
    assert placement.result.status == "ok"  # its verified strict run
    assert placement.support.support == "table"
    D = placement.placement.transform
    for name in BOXES:  # neither box goes below the table top (the table's own geometry)
        assert _corners(name, too_far_m, D)[:, 2].min() >= TABLE_TOP_M - 1e-9, name
    return D


@pytest.mark.slow
@pytest.mark.parametrize("too_far_m", [0.10, 0.20])  # 0.25 m and 0.35 m from where the part is ok
def test_a_part_on_a_table_slides_on_the_table_top(tmp_path, too_far_m):
    problem, result = _table_run(str(_table_cell(tmp_path, too_far_m)))
    D = _check_on_table(problem, result, too_far_m)
    move = result.placement.placement
    assert abs(move.translation_m[2]) <= 1e-9  # the table's normal is world z
    assert np.allclose(np.cross(move.rotvec_rad, [0.0, 0.0, 1.0]), 0.0, atol=1e-12)  # a turn about it
    # the fixture's underside stays on the table top: every bottom corner at z = 0
    assert np.allclose(np.sort(_corners("fixture", too_far_m, D)[:, 2])[:4], TABLE_TOP_M, atol=1e-9)
    assert move.translation_m[0] < -0.05  # back towards the robot
    doc = json.loads(json.dumps(result_dict(result)))["placement"]
    assert doc["support"]["object"] == "table" and doc["bounds"]["free"] == "plane"


@pytest.mark.slow
def test_free_all_moves_out_of_the_plane_but_not_into_the_table(tmp_path, require):
    jsonschema = require.module("jsonschema")
    problem, result = _table_run(str(_table_cell(tmp_path, 0.10, free="all")))
    D = _check_on_table(problem, result, 0.10)
    move = result.placement.placement
    out_of_plane = abs(move.translation_m[2]) + np.linalg.norm(move.rotvec_rad[:2])
    assert out_of_plane > 1e-4  # a shift along z or a tilt: the wrist centre is above the shoulder
    assert _corners("fixture", 0.10, D)[:, 2].min() >= TABLE_TOP_M - 1e-6
    doc = json.loads(json.dumps(result_dict(result)))["placement"]
    jsonschema.validate(doc, json.loads(SCHEMA.read_text()))
    assert doc["bounds"]["free"] == "all"


@pytest.mark.slow
def test_a_post_beside_the_way_back_is_gone_around(tmp_path):
    problem, result = _table_run(str(_table_cell(tmp_path, 0.10, extra={"post": POST})))
    D = _check_on_table(problem, result, 0.10)
    margin = problem.collision.margin_m
    post_y_min = POST["xyz"][1] - POST["size_m"][1] / 2
    for name in BOXES:
        corners = _corners(name, 0.10, D)
        assert corners[:, 1].max() <= post_y_min - margin + 1e-6, name  # past it, margin kept
        assert _fcl_distance(name, 0.10, D, POST) >= margin - 1e-6, name
    # the part ends beside the post (their x ranges overlap): only the shift along y keeps it clear
    assert corners[:, 0].min() < POST["xyz"][0] + POST["size_m"][0] / 2


@pytest.mark.slow
def test_a_block_across_the_way_back_gives_no_move_and_is_named(tmp_path):
    _, result = _table_run(str(_table_cell(tmp_path, 0.10, extra={"block": BLOCK})))
    placement = result.placement
    assert placement.status == "infeasible" and placement.placement is None
    assert "'plate' / 'block'" in placement.reason, placement.reason  # the rows that leave no move
    # without the rows the move goes straight back over the block: the shallowest way out of it is
    # up, from the plate's underside (0.08 m) to the block's top (0.15 m)
    depth_mm = (
        BLOCK["xyz"][2] + BLOCK["size_m"][2] / 2 - (BOXES["plate"][1][2] - BOXES["plate"][0][2])
    ) * 1e3
    assert f"'plate' {depth_mm:.1f} mm inside 'block'" in placement.reason, placement.reason
