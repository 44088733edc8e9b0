"""The library API: arrays in, the CLI's engine out; validation; warm start and reuse."""

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import refine
from refine.cli import main
from refine.optimise.problem import build_refinement, reuse_for
from refine.run.stages import fused_path

ROOT = Path(__file__).resolve().parents[1]
GLASS = ROOT / "problems" / "glass_adhesive"

N = 25
DOWN = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])


def line(n=N, z=0.3):
    positions = np.column_stack([np.full(n, 0.6), np.linspace(-0.15, 0.15, n), np.full(n, z)])
    # the tool tilted about x along the way, up to 10 deg
    tilt = Rotation.from_euler("x", np.linspace(0.0, 10.0, n)[:, None], degrees=True).as_matrix()
    return positions, DOWN @ tilt


def test_import_refine_loads_no_numerical_library():
    code = (
        "import sys, refine; print(sorted(m for m in ('numpy', 'casadi', 'pinocchio') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    assert out.stdout.strip() == "[]"
    assert refine.refine_path.__module__ == "refine.api"
    with pytest.raises(AttributeError):
        refine.no_such_name  # noqa: B018


@pytest.mark.slow
def test_refine_path_on_the_glass_cell_arrays_gives_the_joints_of_refine_run(tmp_path):
    assert main(["run", str(GLASS), "--out", str(tmp_path), "--no-report"]) == 0
    table = np.genfromtxt(tmp_path / "trajectory.csv", delimiter=",", names=True)
    q_cli = np.column_stack([table[f"q{j}"] for j in range(1, 7)])

    p = refine.load_problem(GLASS)
    f = fused_path(p)
    result = refine.refine_path(
        "abb_irb4600_60_205",
        f.positions,
        Rotation.from_matrix(f.rotations).as_quat(scalar_first=True),  # as quaternions
        speeds=f.speed,
        arc_length=f.s,
        tcp_in_flange=p.tool.tcp_in_flange,
        base_in_world=p.robot.base_in_world,
        tolerances=p.tolerances,
        cell=p.cell,
        tool_shapes=p.tool.collision,
        collision=p.collision,
        name=p.name,
        quaternion_order="wxyz",
    )
    assert result.status == "ok"
    assert result.joints.shape == q_cli.shape
    assert np.abs(result.joints - q_cli).max() < 1e-9
    assert np.allclose(result.times, table["t"], rtol=0, atol=1e-9)
    assert np.allclose(result.speeds, table["speed"], rtol=0, atol=1e-9)
    cli_doc = json.loads((tmp_path / "result.json").read_text())
    assert result.metrics["min_clearance_m"] == pytest.approx(
        cli_doc["metrics"]["min_clearance_m"], abs=1e-12
    )


def test_quaternions_and_matrices_give_the_same_path():
    positions, R = line()
    q_xyzw = Rotation.from_matrix(R).as_quat()
    wxyz = np.column_stack([q_xyzw[:, 3], q_xyzw[:, :3]])
    a = refine.refine_path("ur10e", positions, R, speeds=0.1)
    b = refine.refine_path("ur10e", positions, wxyz, speeds=0.1, quaternion_order="wxyz")
    c = refine.refine_path("ur10e", positions, q_xyzw, speeds=0.1, quaternion_order="xyzw")
    assert a.status == b.status == c.status == "ok"
    assert np.abs(a.joints - b.joints).max() < 1e-9
    assert np.abs(a.joints - c.joints).max() < 1e-9
    # the poses are the robot's forward kinematics of the joints, and on the path
    robot = refine.Robot
    assert robot is a.run.robot.__class__
    fk = a.run.robot.fk_many(a.joints)
    assert np.allclose(fk, a.poses, atol=1e-12)  # identity base and tool
    assert np.abs(a.poses[:, :3, 3] - positions).max() < 1e-6
    # the orientation stays inside the 3 deg cone of the demonstration
    angle = Rotation.from_matrix(np.einsum("nji,njk->nik", R, a.poses[:, :3, :3])).magnitude()
    assert np.degrees(angle).max() <= 3.0 + 1e-6
    assert a.times[0] == 0.0 and np.all(np.diff(a.times) > 0)
    assert len(a.passes) == 1 and a.passes[0].joints.shape == (N, 6)


def test_to_dict_is_the_written_result_json(tmp_path):
    positions, R = line()
    result = refine.refine_path("ur10e", positions, R, speeds=0.1, name="line")
    files = result.write(tmp_path, report=False)
    assert set(files) == {"result", "trajectory", "pathml", "urscript", "motions"}  # the UR's own language
    written = json.loads(files["result"].read_text())
    doc = json.loads(json.dumps(result.to_dict()))
    assert written == doc
    assert written["status"] == "ok" and written["n_waypoints"] == N and written["dof"] == 6
    assert written["metrics"] == result.metrics


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"positions": np.zeros((2, 3))}, "N >= 3"),
        ({"orientations": np.ones((N, 4)), "quaternion_order": "wxyz"}, "unit quaternions"),
        ({"orientations": np.tile([1.0, 0.0, 0.0, 0.0], (N, 1))}, "need quaternion_order='wxyz'"),
        ({"orientations": np.tile([1.0, 0.0, 0.0, 0.0], (N, 1)), "quaternion_order": "qxyz"}, "got 'qxyz'"),
        ({"positions": line()[0] * 1000.0}, "read as millimetres they would be within"),
        ({"speeds": 50.0}, "50 m/s at waypoint 0 is beyond 10 m/s"),
        ({"tolerances": {"orientation": 5.0}}, "tolerances: unknown field(s) 'orientation'; the fields are"),
        ({"tolerances": 5.0}, "tolerances: expected a refine.Tolerances or a mapping"),
        ({"cell": [{"kind": "box"}]}, "cell[0]: expected a refine.Shape, got dict"),
        ({"repair": {"time_limit_s": 0.0}}, "repair.time_limit_s must be a finite number in [0.1, 86400] s"),
        ({"orientations": np.ones((N, 3))}, "(N, 4) quaternions"),
        ({"orientations": np.repeat(np.diag([1.0, 1.0, -1.0])[None], N, 0)}, "reflection"),
        ({"speeds": -0.1}, "> 0 m/s"),
        ({"speeds": np.ones(N - 1)}, f"({N},)"),
        ({"arc_length": np.zeros(N)}, "strictly increase"),
        ({"initial_joints": np.zeros((N, 5))}, f"({N}, 6) [rad]"),
        ({"base_in_world": np.ones((4, 4))}, "base_in_world"),
    ],
)
def test_bad_arrays_are_refused_with_the_argument_named(kwargs, message):
    positions, R = line()
    args = {"positions": positions, "orientations": R, **kwargs}
    with pytest.raises(refine.InputError, match=re.escape(message)):
        refine.refine_path("ur10e", args.pop("positions"), args.pop("orientations"), **args)


def test_an_input_error_carries_the_key_the_value_and_what_is_expected(tmp_path):
    positions, R = line()
    with pytest.raises(refine.InputError) as caught:
        refine.refine_path("ur10e", positions, R, tolerances={"orientation_deg": -1.0})
    e = caught.value
    assert (e.key, e.value, e.file) == ("tolerances.orientation_deg", -1.0, None)
    assert "deg" in e.expected
    shutil.copytree(GLASS, tmp_path / "glass")
    problem = tmp_path / "glass" / "problem.toml"
    text = problem.read_text()
    problem.write_text(re.sub(r"(?m)^orientation_deg\s*=.*$", "orientation_deg = 400.0", text, count=1))
    with pytest.raises(refine.InputError) as caught:
        refine.load_problem(problem)
    e = caught.value
    assert (e.key, e.value, e.file) == ("tolerances.orientation_deg", 400.0, str(problem))


def test_positions_with_nan_are_refused():
    positions, R = line()
    positions[3, 1] = np.nan
    with pytest.raises(refine.InputError, match=r"positions: contains NaN.*\[m\]"):
        refine.refine_path("ur10e", positions, R)


def test_a_reused_problem_equals_a_fresh_build_for_the_new_path_and_tolerances():
    positions, R = line()
    first = refine.refine_path("ur10e", positions, R, speeds=0.1)
    old = first.run.first.nlp
    moved = fused_path_like(old.fused, dz=0.001)
    tol = refine.Tolerances(orientation_deg=2.0, joint_margin_deg=5.0, joint_step_deg=10.0)
    reused = reuse_for(old, moved, tol)
    fresh = build_refinement(
        old.robot,
        moved,
        old.base_in_world,
        old.tcp_in_flange,
        tol,
        weights=old.weights,
        joint_steps=old.joint_steps,
    )
    assert reused is not None and reused.solver is old.solver
    for name in ("params", "lbx", "ubx", "lbg", "ubg"):
        assert np.array_equal(getattr(reused, name), getattr(fresh, name)), name
    # not reusable: another waypoint count, a spacing changed by 1 %
    assert reuse_for(old, fused_path_like(old.fused, n=N - 1), tol) is None
    assert reuse_for(old, fused_path_like(old.fused, stretch=1.01), tol) is None


def fused_path_like(f, dz=0.0, n=None, stretch=1.0):
    from refine.paths import FusedPath

    n = n or len(f)
    p = f.positions[:n] + [0.0, 0.0, dz]
    return FusedPath(f.s[:n] * stretch, p, f.rotations[:n], f.speed[:n], f.t_demo[:n], f.residual[:n])


def test_solving_again_from_the_previous_result_gives_the_cold_answer(monkeypatch):
    import refine.optimise.seed as seed

    positions, R = line()
    first = refine.refine_path("ur10e", positions, R, speeds=0.1)
    tol = {"orientation_deg": 1.5}
    chains = []  # every IK chain starts from the first waypoint's solutions
    solutions = seed.first_solutions
    monkeypatch.setattr(seed, "first_solutions", lambda *a, **k: chains.append(1) or solutions(*a, **k))
    again = refine.refine_path("ur10e", positions, R, speeds=0.1, tolerances=tol, previous=first)
    assert chains == []  # no IK chain: the previous answer seeds it
    cold = refine.refine_path("ur10e", positions, R, speeds=0.1, tolerances=tol)
    assert chains  # the cold solve chains
    assert again.status == cold.status == "ok"
    assert again.run.timings_s["build"] < 1e-3  # nothing built: the previous problem was reused
    assert np.abs(again.joints - cold.joints).max() < 1e-5
    assert again.metrics["max_orientation_deviation_deg"] <= 1.5 + 1e-6


def test_solve_takes_a_folder_and_warm_starts_from_given_joints():
    problem = refine.load_problem(ROOT / "problems" / "unreachable" / "out_of_reach")
    result = refine.solve(problem)
    assert result.status == "infeasible"
    assert result.times is None and result.speeds is None
    assert result.diagnosis and result.diagnosis[0]["status"] == "infeasible"
    assert result.diagnosis == result.to_dict()["diagnosis"]
    assert result.placement is None  # the problem asks for no placement search
    with pytest.raises(refine.InputError, match=r"initial_joints: expected shape \(N, n\)"):
        refine.solve(problem, initial_joints=np.zeros(6))


def test_a_result_writes_the_program_of_the_robots_controller_by_default():
    """The KR arm's result asks for KRL, the LBR iiwa's for Sunrise: the robot says which, not the family."""
    from refine.robot.registry import load_robot

    for name, program in (("kuka_kr8_r1440_2_arc_hw", "krl"), ("kuka_iiwa14_r820", "sunrise")):
        robot = load_robot(name)
        home = np.radians([0, -80, 100, 0, 60, 0]) if robot.nq == 6 else np.radians([0, 40, 0, -80, 0, 60, 0])
        T = robot.fk(home)
        positions = T[:3, 3] + np.outer(np.linspace(0.0, 0.05, 6), [0.0, 1.0, 0.0])
        result = refine.refine_path(robot, positions, np.repeat(T[None, :3, :3], 6, axis=0), speeds=0.05)
        assert result.run.problem.output.programs == (program,), name


def _figures(result):
    """What a caller reads from a result's properties, as JSON values (tuples become lists)."""
    passes = [{"name": p.name, "status": p.status, "metrics": p.metrics} for p in result.passes]
    return json.loads(json.dumps([result.metrics, passes, result.diagnosis, result.placement]))


def _written_figures(path):
    with open(path, encoding="utf-8") as f:
        doc = json.load(f)
    passes = [{k: p[k] for k in ("name", "status", "metrics")} for p in doc["passes"]]
    return [doc["metrics"], passes, doc["diagnosis"], doc["placement"]]


def test_the_figures_of_a_result_are_those_of_its_written_result_json(tmp_path):
    """Read before and after the write, each result's properties are its own result.json's, however
    a caller edits what they returned."""
    infeasible = refine.solve(refine.load_problem(ROOT / "problems" / "unreachable" / "out_of_reach"))
    positions, R = line()
    ok = refine.refine_path("ur10e", positions, R, speeds=0.1, name="line")
    read_first = [_figures(infeasible), _figures(ok)]
    for result in (infeasible, ok):  # a caller's edits of the values it got
        result.metrics["max_orientation_deviation_deg"] = -1.0
        result.passes[0].metrics["max_slack_deg"] = -1.0
        for d in result.diagnosis:
            d["status"] = "edited"
    for result, name, first in zip((infeasible, ok), ("infeasible", "ok"), read_first, strict=True):
        written = _written_figures(result.write(tmp_path / name, report=False)["result"])
        assert first == written
        assert _figures(result) == written
    assert read_first[0][2] and read_first[0][2][0]["status"] == "infeasible"  # a diagnosis to compare
    assert read_first[1][0] != read_first[0][0]
