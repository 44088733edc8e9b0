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
from refine.pipeline import fused_path, solve_problem
from refine.placement import Placement, moved_path, moved_problem
from refine.problem import load_problem
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
        ("{ translate_m = 0.2, turn_deg = 5 }", ["'turn_deg'", "allowed: rotate_deg, translate_m"]),
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
    from refine.placement import repair_by_placement

    asked = repair_by_placement(problem, run.robot, run.first)
    assert asked.status == "infeasible" and asked.placement is None
    assert "without moving the workpiece" in asked.reason and "clearance" in asked.reason


@pytest.mark.slow
def test_the_summary_and_the_report_offer_the_move_beside_the_slack_repair(tmp_path):
    from refine.report.html import write_report
    from refine.result import summary_lines

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
    from refine.placement import repair_by_placement

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
