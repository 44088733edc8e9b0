"""The demonstrations of ``problems/unreachable``: each is repaired, or reported infeasible, for its reason.

Every folder under ``problems/unreachable`` with a ``problem.toml`` is run through
:func:`refine.run.solve.solve_problem` once and checked against its ``[expected]`` table: the status,
the reason (in a repair's reason when repaired, in the refinement's reason when infeasible), the
slack a repair used, the arc-length range the reported segment must overlap, and that nothing fails
silently. Cases with collision shapes import ``refine.optimise.clearance``: an import error fails
them, it never skips them.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import json
import math
from pathlib import Path

import numpy as np
import pytest

from refine.demo import read_tracker_log
from refine.demo.liberty import write_liberty_ascii
from refine.demo.simulate import TrackerModel, perturb_log
from refine.export.result_json import result_dict
from refine.frames import rotation_angle_deg
from refine.problem import load_problem
from refine.robot.kinematics import TcpKinematics
from refine.run.solve import solve_problem

pytestmark = pytest.mark.slow

FOLDER = Path(__file__).resolve().parents[1] / "problems" / "unreachable"
CASES = sorted(p.parent.name for p in FOLDER.glob("*/problem.toml"))

REPAIR_REASONS = (
    "joint limit (joint",
    "joint wrap (joint",
    "reach",
    "singularity",
    "collision",
    "self-collision",
    "orientation",
)
"""What ``Repair.reason`` may say (docs/outputs.md)."""

KNOWN_GAPS: dict[tuple[str, str], str] = {}
"""(case, check) pairs refine does not meet yet, and why (strict xfail: a fix shows as XPASS)."""


def _known_gap(request, name: str, check: str) -> None:
    if (name, check) in KNOWN_GAPS:
        request.applymarker(pytest.mark.xfail(reason=KNOWN_GAPS[name, check], strict=True))


def _same_status(problem, result) -> None:
    assert result.status == problem.expected.status, (
        f"status {result.status}, not {problem.expected.status}: {result.refinement.reason}"
    )


def _uses_collision(problem) -> bool:
    return problem.collision.enabled and bool(problem.cell or problem.tool.collision)


PROBLEMS = {name: load_problem(FOLDER / name) for name in CASES}


def _cases(applies) -> list[str]:
    """The cases a check applies to, so that no case is collected only to be skipped."""
    return [name for name in CASES if applies(PROBLEMS[name])]


COLLISION_CASES = _cases(lambda p: "collision" in p.expected.reason)
REPAIR_CASES = _cases(lambda p: p.expected.status == "repaired")
REPAIRED_IN_A_CELL = _cases(lambda p: p.expected.status == "repaired" and _uses_collision(p))
CAUSE_CASES = _cases(lambda p: bool(p.expected.cause))


@functools.cache
def _solved(name: str):
    """The problem and its result, solved once per case for the whole module."""
    problem = PROBLEMS[name]
    if _uses_collision(problem):
        # part of the package, not optional: an ImportError here is an error of every case, never a skip
        importlib.import_module("refine.optimise.clearance")
    return problem, solve_problem(problem)


@pytest.fixture(params=CASES)
def run(request):
    """The problem and its result; a test that applies to some cases only narrows ``params``."""
    return _solved(request.param)


def _overlaps(a: float, b: float, lo_hi: tuple[float, float]) -> bool:
    return a <= lo_hi[1] and b >= lo_hi[0]


def test_the_suite_covers_every_failure_kind():
    """At least six problems, and each states its expected outcome completely."""
    assert len(CASES) >= 6, CASES
    for name in CASES:
        problem = load_problem(FOLDER / name)
        e = problem.expected
        assert e is not None, f"{name}: no [expected]"
        assert e.status in ("repaired", "infeasible") and e.reason and e.s_range_m is not None, name
        assert e.status != "repaired" or e.max_slack_deg is not None, f"{name}: repaired needs max_slack_deg"
        assert (FOLDER / name / "README.md").is_file(), f"{name}: no README.md"


def test_status_is_the_expected_one(run, request):
    problem, result = run
    _known_gap(request, problem.name, "status")
    refinement = result.refinement
    assert result.status == problem.expected.status, refinement.reason


def test_reason_names_the_constraint_that_forced_it(run, request):
    problem, result = run
    _same_status(problem, result)
    _known_gap(request, problem.name, "reason")
    e, refinement = problem.expected, result.refinement
    if e.status == "repaired":
        reasons = [r.reason for r in refinement.repairs]
        assert any(e.reason in r for r in reasons), f"expected {e.reason!r} in a repair, got {reasons}"
    else:
        assert e.reason in refinement.reason, refinement.reason


@pytest.mark.parametrize("run", COLLISION_CASES, indirect=True)
def test_a_collision_names_the_object(run):
    """A collision repair or infeasibility names the cell object it is about."""
    problem, result = run
    _same_status(problem, result)
    names = [o.name for o in problem.cell if not o.workpiece]
    refinement = result.refinement
    if problem.expected.status == "repaired":
        objects = " ".join(o for r in refinement.repairs if "collision" in r.reason for o in r.objects)
    else:
        objects = refinement.reason
    assert any(n in objects for n in names), f"none of {names} named in {objects!r}"


@pytest.mark.parametrize("run", REPAIR_CASES, indirect=True)
def test_a_repair_stays_within_its_slack_and_the_path_is_verified(run):
    """Repaired means: verified against the widened tolerances, with no more slack than allowed."""
    problem, result = run
    _same_status(problem, result)
    refinement, tol = result.refinement, problem.tolerances
    assert refinement.check.ok, [v.describe() for v in refinement.check.violations]
    assert refinement.repairs
    assert max(r.slack_deg for r in refinement.repairs) <= problem.expected.max_slack_deg
    assert refinement.slack_deg.max() <= problem.expected.max_slack_deg
    # recomputed here from the joints, independently of the result's own check
    fused = result.fused
    kin = TcpKinematics(result.robot, problem.robot.base_in_world, problem.tool.tcp_in_flange)
    poses = kin.poses(refinement.q)
    assert np.linalg.norm(poses[:, :3, 3] - fused.positions, axis=1).max() <= tol.position_m
    if problem.tool.axisymmetric:
        cosines = np.einsum("ij,ij->i", poses[:, :3, 2], fused.rotations[:, :, 2])
        deviation = np.degrees(np.arccos(np.clip(cosines, -1.0, 1.0)))
    else:
        deviation = rotation_angle_deg(poses[:, :3, :3], fused.rotations)
    assert np.all(deviation <= tol.orientation_deg + refinement.slack_deg + 1e-6)
    spec, margin = result.robot.spec, math.radians(tol.joint_margin_deg)
    assert np.all(refinement.q >= spec.lower + margin - 1e-7) and np.all(
        refinement.q <= spec.upper - margin + 1e-7
    )
    assert np.abs(np.diff(refinement.q, axis=0)).max() <= math.radians(tol.joint_step_deg) + 1e-9
    assert result.trajectory is not None and result.timing is not None


def test_the_reported_segment_is_where_the_defect_is(run):
    problem, result = run
    _same_status(problem, result)
    e, refinement = problem.expected, result.refinement
    if e.status == "repaired":
        segments = [(r.s_start_m, r.s_end_m) for r in refinement.repairs if e.reason in r.reason]
        segments = segments or [(r.s_start_m, r.s_end_m) for r in refinement.repairs]
    else:
        violations = refinement.check.violations
        segments = [(v.s_start_m, v.s_end_m) for v in violations if e.reason in v.reason]
        segments = segments or [(v.s_start_m, v.s_end_m) for v in violations]
    assert any(_overlaps(a, b, e.s_range_m) for a, b in segments), f"{segments} vs {e.s_range_m}"


def test_nothing_fails_silently(run):
    """An infeasible result says why and where; a repaired one lists what it changed."""
    _, result = run
    refinement = result.refinement
    if refinement.status == "infeasible":
        assert refinement.reason.strip()
        assert "waypoints" in refinement.reason
        assert refinement.check.violations
        assert result.trajectory is None
    elif refinement.status == "repaired":
        assert refinement.repairs and refinement.reason.strip()
        for r in refinement.repairs:
            assert r.reason.startswith(REPAIR_REASONS), r.reason
            assert r.slack_deg > 0 and r.index_start <= r.index_end and r.s_start_m <= r.s_end_m


@pytest.mark.parametrize("run", REPAIRED_IN_A_CELL, indirect=True)
def test_a_repaired_path_in_a_cell_keeps_at_least_the_margin_everywhere(run):
    """Checked densely between waypoints: the smallest distance to the cell is at least the margin."""
    problem, result = run
    _same_status(problem, result)
    for p in result.passes:
        assert p.clearance is not None and p.clearance.ok
        assert p.clearance.min_clearance_m >= 0.0, p.clearance.summary()


@pytest.mark.parametrize("run", CAUSE_CASES, indirect=True)
def test_the_diagnosis_names_the_cause_built_into_the_case(run):
    """The segment over the defect names, first, the cause the case was built with."""
    problem, result = run
    e = problem.expected
    findings = [f for f in result.refinement.diagnosis if _overlaps(f.s_start_m, f.s_end_m, e.s_range_m)]
    assert findings, f"no diagnosis entry over s = {e.s_range_m}: {result.refinement.diagnosis}"
    assert all(f.status == result.refinement.status for f in findings)
    named = [f.cause.cause for f in findings]
    assert e.cause in named, f"expected {e.cause!r} first, got {[f.describe() for f in findings]}"


def test_result_json_diagnosis_follows_its_schema_and_repairs_follow_from_it(run, require):
    jsonschema = require.module("jsonschema")
    _, result = run
    schema = json.loads((FOLDER.parents[1] / "docs" / "diagnosis.schema.json").read_text())
    doc = json.loads(json.dumps(result_dict(result)))  # through JSON, as a caller reads it
    jsonschema.validate(doc["diagnosis"], schema)
    assert doc["diagnosis"], "a repaired or infeasible result must have diagnosis entries"
    repaired = [d for d in doc["diagnosis"] if d["status"] == "repaired"]
    assert [(r["index_start"], r["index_end"], r["slack_deg"]) for r in doc["repairs"]] == [
        (d["index_start"], d["index_end"], d["slack_deg"]) for d in repaired
    ]
    for d in doc["diagnosis"]:
        assert (d["slack_deg"] is not None) == (d["status"] == "repaired")
        explains = [c["explains_deg"] for c in d["causes"]]
        order = [math.inf if x is None else x for x in explains]
        assert order == sorted(order, reverse=True), explains


STABILITY_CASE = "reach_tilt"
"""The case given in all three formats (its ``demo.lbin`` and ``demo.csv`` are the ASCII log's
samples rounded as each format stores them); ``benchmarks/stability.py`` runs 20 perturbations."""

STABILITY_SEEDS = (1005, 1010, 1015, 1016)
"""Noise seeds of ``benchmarks/stability.py``'s perturbations 6, 11, 16 and 17: the copies on which
a single local solve once stalled (infeasible) or fell back to another IK branch (7.8 deg instead of
2.5 deg)."""


def test_the_same_demonstration_gets_the_same_verdict_through_every_reader_and_its_noise(tmp_path):
    """One demonstration as Liberty ASCII, Liberty binary and CSV, and 4 copies with the tracker's white
    noise added: one status, and the repair slack within 0.5 deg."""
    problem = load_problem(FOLDER / STABILITY_CASE)
    demo = problem.demonstration
    log = read_tracker_log(demo)
    variants = [
        demo,
        dataclasses.replace(demo, file=problem.root / "demo.lbin", format="liberty_binary", units="in"),
        dataclasses.replace(demo, file=problem.root / "demo.csv", format="csv", units="mm"),
    ]
    rate_hz = 1.0 / float(np.median(np.diff(log.t)))
    for seed in STABILITY_SEEDS:
        path = tmp_path / f"perturbed_{seed}.liberty"
        write_liberty_ascii(path, perturb_log(log, TrackerModel(), seed), units="in", rate_hz=rate_hz)
        variants.append(dataclasses.replace(demo, file=path))
    outcomes = []
    for d in variants:
        refinement = solve_problem(dataclasses.replace(problem, demonstration=d)).refinement
        outcomes.append((refinement.status, float(refinement.slack_deg.max())))
    assert {s for s, _ in outcomes} == {problem.expected.status}, outcomes
    slack = [x for _, x in outcomes]
    assert max(slack) - min(slack) <= 0.5, outcomes
