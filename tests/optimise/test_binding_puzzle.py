"""The repair of the puzzle piece under a guard plate names every constraint at its bound in the answer.

A plate (a cell object) is put under the held part, 2 mm above the lowest point that refine's
answer without it gives the part on some waypoints: within the 3 deg cone the part cannot keep the
10 mm cell margin there, so the refinement is repaired with extra slack. The expectations are
measured on the repaired answer's joints with Pinocchio (the flange pose) and python-fcl (the part's
and mount's meshes against the plate's box), the part's pose on the flange from the problem file's
numbers through SciPy, not from refine's collision model or its figures.
"""

import math
import shutil
from dataclasses import replace
from pathlib import Path

import fcl
import numpy as np
import pinocchio as pin
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from refine.bench.contenders import solve_as_refine
from refine.bench.suites import bundled_problem
from refine.paths import FusedPath

PUZZLE = Path(__file__).resolve().parents[2] / "problems" / "puzzle_piece"
GUARD_TOP_M = 0.662  # the part's lowest point on the path is 0.656 m without the plate
GUARD_HALF_M = 0.2
GUARD_THICKNESS_M = 0.01
MARGIN_M = 0.01  # the default [collision] margin_m
BIND_M = 0.001  # a pair within 1 mm above its margin is at its bound (docs/repair.md)
STEP_DEG = 20.0  # the problem's joint-step bound (problems/puzzle_piece/README.md)
JOINT_MARGIN_DEG = 2.0
WAYPOINTS = slice(290, 400)  # the stretch of the toolpath the plate constrains, to keep the solve short


def _pose(xyz, rpy_deg):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", rpy_deg, degrees=True).as_matrix()  # fixed axes, as URDF's rpy
    T[:3, 3] = xyz
    return T


PART_IN_FLANGE = _pose([0.016887, 0.007326, 0.075648], [119.147590, 7.435636, -43.064335])
MOUNT_IN_FLANGE = _pose([0.0, 0.0, 0.0], [90.0, 0.0, 0.0])
BASE_IN_WORLD = _pose([0.0, 0.0, 0.5], [0.0, 0.0, 0.0])


@pytest.fixture(scope="module")
def repaired(tmp_path_factory):
    folder = tmp_path_factory.mktemp("guarded") / "puzzle_piece"
    shutil.copytree(PUZZLE, folder)
    toml = folder / "problem.toml"
    z = GUARD_TOP_M - GUARD_THICKNESS_M / 2
    toml.write_text(
        toml.read_text()
        + f"""
[[cell.objects]]
name = "guard"
shape = "box"
size_m = [{2 * GUARD_HALF_M}, {2 * GUARD_HALF_M}, {GUARD_THICKNESS_M}]
pose = {{ xyz = [0.35, -0.35, {z}], rpy_deg = [0.0, 0.0, 0.0] }}
"""
    )
    bp = bundled_problem("t", folder)
    f, i = bp.fused, WAYPOINTS
    bp = replace(bp, fused=FusedPath(f.s[i], f.positions[i], f.rotations[i], f.speed[i], f.t_demo[i], f.residual[i]))
    result, _, _, _ = solve_as_refine(bp, "assembled")
    return bp, result


def _meshes():
    out = {}
    for name, file, pose in (
        ("tool:part", "puzzle_bent.dae", PART_IN_FLANGE),
        ("tool:mount", "puzzle_mount.stl", MOUNT_IN_FLANGE),
    ):
        mesh = trimesh.load(PUZZLE / file, force="mesh")
        bvh = fcl.BVHModel()
        bvh.beginModel(len(mesh.vertices), len(mesh.faces))
        bvh.addSubModel(np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int32))
        bvh.endModel()
        out[name] = (bvh, pose)
    return out


def _guard_distances(robot, q):
    """Each held body's FCL distance to the plate [m] per waypoint of ``q`` (N, n)."""
    model, data = robot.model, robot.model.createData()
    flange = model.getFrameId(robot.spec.flange_frame)
    guard = fcl.CollisionObject(
        fcl.Box(2 * GUARD_HALF_M, 2 * GUARD_HALF_M, GUARD_THICKNESS_M),
        fcl.Transform(np.array([0.35, -0.35, GUARD_TOP_M - GUARD_THICKNESS_M / 2])),
    )
    out = {}
    for name, (bvh, pose) in _meshes().items():
        d = []
        for qk in q:
            pin.framesForwardKinematics(model, data, qk)
            T = BASE_IN_WORLD @ data.oMf[flange].homogeneous @ pose
            body = fcl.CollisionObject(bvh, fcl.Transform(T[:3, :3], T[:3, 3]))
            d.append(fcl.distance(body, guard, fcl.DistanceRequest(), fcl.DistanceResult()))
        out[name] = np.array(d)
    return out


def _runs(mask, first):
    idx = np.flatnonzero(mask)
    if not idx.size:
        return ()
    cuts = np.flatnonzero(np.diff(idx) > 1)
    return tuple(
        (first + int(a), first + int(b))
        for a, b in zip(np.r_[idx[0], idx[cuts + 1]], np.r_[idx[cuts], idx[-1]], strict=True)
    )


def test_the_guard_forces_a_repair_whose_answer_keeps_the_margin(repaired):
    bp, result = repaired
    assert result.status == "repaired"
    assert result.diagnosis and all(f.slack_deg > 0.5 for f in result.diagnosis)
    d = _guard_distances(bp.robot, result.q)
    assert min(x.min() for x in d.values()) >= MARGIN_M - 1e-4  # the repaired answer keeps the margin


def test_every_pair_joint_and_step_at_its_bound_is_named_with_its_waypoints(repaired):
    bp, result = repaired
    q = result.q
    d = _guard_distances(bp.robot, q)
    model = bp.robot.model
    margin = math.radians(JOINT_MARGIN_DEG)
    lower, upper = model.lowerPositionLimit + margin, model.upperPositionLimit - margin
    step = math.radians(STEP_DEG)
    for f in result.diagnosis:
        a, b = f.index_start, f.index_end
        named = {(c.cause, c.objects, c.joint): c for c in f.causes if c.in_answer and c.cause != "singularity"}
        expected = {}
        for body, dist in d.items():
            seg = dist[a : b + 1]
            if seg.min() < MARGIN_M + BIND_M:
                expected[("collision", (body, "guard"), None)] = (seg.min(), _runs(seg < MARGIN_M + BIND_M, a))
        seg = q[a : b + 1]
        for j in range(q.shape[1]):
            near = np.minimum(seg[:, j] - lower[j], upper[j] - seg[:, j]) <= 1e-4
            if near.any():
                expected[("joint limit", (), j + 1)] = (None, _runs(near, a))
        lo, hi = max(a - 1, 0), min(b + 1, len(q) - 1)
        steps = np.abs(np.diff(q[lo : hi + 1], axis=0))
        for j in range(q.shape[1]):
            at = np.zeros(hi - lo + 1, dtype=bool)
            for i in np.flatnonzero(steps[:, j] >= step - 1e-4):
                at[i : i + 2] = True
            if at.any():
                expected[("joint step", (), j + 1)] = (math.degrees(steps[:, j].max()), _runs(at, lo))
        assert set(named) == set(expected), f"waypoints {a}-{b}"
        assert any(k[0] == "collision" for k in expected)  # the plate holds every repaired segment
        text = f.describe()
        for key, (figure, spans) in expected.items():
            c = named[key]
            assert c.waypoints == spans, key
            assert c.as_json()["waypoints"] == [list(s) for s in spans] and c.as_json()["in_answer"] is True
            words = ", ".join(f"{i}" if i == j else f"{i}-{j}" for i, j in spans)
            if key[0] == "collision":
                assert c.limit == MARGIN_M
                assert math.isclose(c.figure, figure, abs_tol=1e-6)
                assert (
                    f"clearance {key[1][0]}<->guard at its 10 mm margin ({figure * 1e3:.1f} mm) over waypoint"
                ) in text
            if key[0] == "joint step":
                assert math.isclose(c.figure, figure, abs_tol=1e-9)
            assert words in text
        assert text in result.reason
