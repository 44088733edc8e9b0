"""The robot registry, the URDFs in robots/ and the Pinocchio kinematics of refine.robot.model."""

from __future__ import annotations

import shutil

import fcl
import numpy as np
import pytest
import trimesh

from refine.errors import InputError
from refine.frames import make_transform, rotation_about
from refine.robot.geometry import collision_shapes_from_urdf
from refine.robot.model import Robot
from refine.robot.registry import available_robots, load_robot, robots_dir
from refine.robot.spec import CONTROLLERS, RobotSpec

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

NAMES = ["abb_irb4600_60_205", "kuka_iiwa14_r820", "kuka_kr8_r1440_2_arc_hw", "ur10e"]

# data-sheet limits from shared/ROBOTS.md: (lower, upper, speed) [deg, deg, deg/s]
DATA_SHEET = {
    "abb_irb4600_60_205": [
        (-180, 180, 175),
        (-90, 150, 175),
        (-180, 75, 175),
        (-400, 400, 250),
        (-125, 120, 250),
        (-400, 400, 360),
    ],
    "kuka_iiwa14_r820": [
        (-170, 170, 85),
        (-120, 120, 85),
        (-170, 170, 100),
        (-120, 120, 75),
        (-170, 170, 130),
        (-120, 120, 135),
        (-175, 175, 135),
    ],
    # KUKA's own description of the arm (axis ranges and speeds marked verified by KUKA)
    "kuka_kr8_r1440_2_arc_hw": [
        (-170, 170, 220),
        (-185, 65, 210),
        (-119, 181, 270),
        (-165, 165, 430),
        (-115, 140, 430),
        (-350, 350, 4400 / 7),
    ],
    "ur10e": [
        (-360, 360, 120),
        (-360, 360, 120),
        (-360, 360, 180),
        (-360, 360, 180),
        (-360, 360, 180),
        (-360, 360, 180),
    ],
}

UR_A = [0.0, -0.6127, -0.57155, 0.0, 0.0, 0.0]
UR_D = [0.1807, 0.0, 0.0, 0.17415, 0.11985, 0.11655]
UR_ALPHA = [np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0]


@pytest.fixture(scope="session")
def robots() -> dict[str, Robot]:
    return {name: load_robot(name) for name in NAMES}


def _from_deg(*angles: float) -> np.ndarray:
    return np.radians(angles)


# ---- registry and folder layout ---------------------------------------------------------------


def test_registry_lists_the_bundled_robots():
    # the four described here, and the two imported from their support packages
    # (tests/test_robot_descriptions.py)
    assert available_robots() == sorted([*NAMES, "fanuc_m20ia", "motoman_gp12"])


@pytest.mark.parametrize("name", NAMES)
def test_each_robot_folder_has_urdf_toml_and_readme(name):
    folder = robots_dir() / name
    assert {"robot.urdf", "robot.toml", "README.md"} <= {p.name for p in folder.iterdir()}
    meta = tomllib.loads((folder / "robot.toml").read_text())
    assert (folder / meta["urdf"]).is_file()
    assert meta["flange_frame"] == "tool0"
    assert meta["controller"] in CONTROLLERS
    assert len(meta["joint_acceleration_deg_s2"]) == len(DATA_SHEET[name])


def test_unknown_robot_error_lists_the_valid_names():
    with pytest.raises(InputError, match="unknown robot 'irb9999'") as info:
        load_robot("irb9999")
    for name in NAMES:
        assert name in str(info.value)


def test_load_robot_is_cached(robots):
    assert load_robot("ur10e") is robots["ur10e"]


def test_robots_dir_can_be_overridden(tmp_path, monkeypatch):
    shutil.copytree(robots_dir() / "ur10e", tmp_path / "my_ur")
    monkeypatch.setenv("REFINE_ROBOTS_DIR", str(tmp_path))
    assert robots_dir() == tmp_path
    assert available_robots() == ["my_ur"]
    assert load_robot("my_ur").spec.name == "my_ur"


def test_unknown_key_in_robot_toml_is_an_error(tmp_path, monkeypatch):
    shutil.copytree(robots_dir() / "ur10e", tmp_path / "typo")
    toml = tmp_path / "typo" / "robot.toml"
    toml.write_text(toml.read_text() + 'flange_fram = "tool0"\n')
    monkeypatch.setenv("REFINE_ROBOTS_DIR", str(tmp_path))
    with pytest.raises(InputError, match="flange_fram"):
        load_robot("typo")


# ---- limits and the spec ----------------------------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
def test_limits_match_the_data_sheet(robots, name):
    spec = robots[name].spec
    lower, upper, speed = np.array(DATA_SHEET[name], dtype=float).T
    assert robots[name].nq == spec.dof == len(lower)
    np.testing.assert_allclose(np.degrees(spec.lower), lower, atol=1e-9)
    np.testing.assert_allclose(np.degrees(spec.upper), upper, atol=1e-9)
    np.testing.assert_allclose(np.degrees(spec.velocity), speed, atol=1e-9)
    assert np.all(spec.acceleration > 0.0)
    assert spec.flange_frame == "tool0" and spec.urdf.is_file()


def test_industrial_arm_accelerates_to_full_speed_in_half_a_second(robots):
    spec = robots["abb_irb4600_60_205"].spec
    np.testing.assert_allclose(spec.acceleration, 2.0 * spec.velocity)


def test_spec_arrays_are_read_only(robots):
    with pytest.raises(ValueError):
        robots["ur10e"].spec.lower[0] = 0.0


def test_spec_rejects_inverted_limits_and_unknown_controller(robots):
    spec = robots["ur10e"].spec
    kwargs = {k: getattr(spec, k) for k in spec.__dataclass_fields__}
    with pytest.raises(InputError, match="lower limit"):
        RobotSpec(**{**kwargs, "lower": spec.upper, "upper": spec.lower})
    with pytest.raises(InputError, match="controller 'staubli' is not one of abb, kuka, ur, fanuc, yaskawa"):
        RobotSpec(**{**kwargs, "controller": "staubli"})
    with pytest.raises(InputError, match="velocity must be 6"):
        RobotSpec(**{**kwargs, "velocity": spec.velocity[:3]})


# ---- forward kinematics against the data-sheet geometry ---------------------------------------


def test_irb4600_flange_at_zero_is_1270_0_1570_pointing_along_x(robots):
    T = robots["abb_irb4600_60_205"].fk(np.zeros(6))
    np.testing.assert_allclose(T[:3, 3], [0.175 + 0.960 + 0.135, 0.0, 0.495 + 0.900 + 0.175])
    np.testing.assert_allclose(T[:3, :3], rotation_about("y", np.pi / 2), atol=1e-15)


@pytest.mark.parametrize(
    ("q_deg", "position", "tool_z"),
    [
        ((90, 0, 0, 0, 0, 0), (0.0, 1.270, 1.570), (0, 1, 0)),  # axis 1 turns left
        ((0, 90, 0, 0, 0, 0), (1.250, 0.0, -0.600), (0, 0, -1)),  # axis 2 leans forward
        ((0, 0, 0, 0, 90, 0), (1.135, 0.0, 1.435), (0, 0, -1)),  # wrist bends the tool down
        ((0, 0, 0, 90, 0, 0), (1.270, 0.0, 1.570), (1, 0, 0)),  # axis 4 rolls about the tool axis
    ],
)
def test_irb4600_hand_computed_poses(robots, q_deg, position, tool_z):
    T = robots["abb_irb4600_60_205"].fk(_from_deg(*q_deg))
    np.testing.assert_allclose(T[:3, 3], position, atol=1e-12)
    np.testing.assert_allclose(T[:3, 2], tool_z, atol=1e-12)


def test_iiwa_flange_at_zero_is_1306_above_the_base(robots):
    T = robots["kuka_iiwa14_r820"].fk(np.zeros(7))
    np.testing.assert_allclose(T, make_transform(p=[0.0, 0.0, 0.36 + 0.42 + 0.40 + 0.126]), atol=1e-15)


def test_iiwa_axis_4_turns_opposite_to_axis_2(robots):
    iiwa = robots["kuka_iiwa14_r820"]
    np.testing.assert_allclose(
        iiwa.fk(_from_deg(0, 90, 0, 0, 0, 0, 0))[:3, 3], [0.946, 0.0, 0.36], atol=1e-12
    )
    np.testing.assert_allclose(
        iiwa.fk(_from_deg(0, 0, 0, 90, 0, 0, 0))[:3, 3], [-0.526, 0.0, 0.78], atol=1e-12
    )


def _dh_product(q: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    for theta, d, a, alpha in zip(q, UR_D, UR_A, UR_ALPHA, strict=True):
        ct, st, ca, sa = np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha)
        T = T @ np.array(
            [
                [ct, -st * ca, st * sa, a * ct],
                [st, ct * ca, -ct * sa, a * st],
                [0.0, sa, ca, d],
                [0.0, 0.0, 0.0, 1.0],
            ]
        )
    return T


def test_ur10e_fk_equals_the_dh_product(robots):
    ur = robots["ur10e"]
    rng = np.random.default_rng(7)
    qs = np.vstack([np.zeros(6), rng.uniform(ur.spec.lower, ur.spec.upper, size=(20, 6))])
    for q in qs:
        np.testing.assert_allclose(ur.fk(q), _dh_product(q), atol=1e-12)
    # all zero: arm stretched along -x (a2 + a3), wrist offsets d4 + d6 along -y, d5 down from d1
    expected = [UR_A[1] + UR_A[2], -(UR_D[3] + UR_D[5]), UR_D[0] - UR_D[4]]
    np.testing.assert_allclose(ur.fk(np.zeros(6))[:3, 3], expected, atol=1e-12)


def test_reach_matches_the_data_sheet(robots):
    abb = robots["abb_irb4600_60_205"]
    stretched = np.array([0.0, np.pi / 2, np.arctan2(0.175, 0.960) - np.pi / 2, 0.0, 0.0, 0.0])
    wrist = abb.frame_pose(stretched, "link_5")[:3, 3]
    assert np.hypot(wrist[0], wrist[1]) == pytest.approx(abb.spec.reach_m, abs=0.005)

    iiwa = robots["kuka_iiwa14_r820"]
    poses = iiwa.link_poses(np.zeros(7))
    span = np.linalg.norm(poses["link_6"][:3, 3] - poses["link_2"][:3, 3])
    assert span == pytest.approx(iiwa.spec.reach_m, abs=1e-9)

    ur = robots["ur10e"]
    assert -ur.fk(_from_deg(0, 0, 0, -90, 0, 0))[0, 3] == pytest.approx(ur.spec.reach_m, abs=0.005)


@pytest.mark.parametrize("name", NAMES)
def test_no_configuration_reaches_much_beyond_the_nominal_reach(robots, name):
    robot = robots[name]
    qs = np.random.default_rng(3).uniform(robot.spec.lower, robot.spec.upper, size=(500, robot.nq))
    shoulder = np.array([robot.frame_pose(q, "link_2")[:3, 3] for q in qs])
    distance = np.linalg.norm(robot.fk_many(qs)[:, :3, 3] - shoulder, axis=1)
    assert 0.8 * robot.spec.reach_m < distance.max() < 1.2 * robot.spec.reach_m


# ---- the Robot methods --------------------------------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
def test_fk_many_link_poses_and_frame_pose_agree_with_fk(robots, name):
    robot = robots[name]
    qs = np.random.default_rng(11).uniform(robot.spec.lower, robot.spec.upper, size=(5, robot.nq))
    Ts = robot.fk_many(qs)
    assert Ts.shape == (5, 4, 4)
    for q, T in zip(qs, Ts, strict=True):
        np.testing.assert_allclose(T, robot.fk(q), atol=1e-15)
        np.testing.assert_allclose(robot.frame_pose(q, "tool0"), T, atol=1e-15)
        poses = robot.link_poses(q)
        np.testing.assert_allclose(poses["tool0"], T, atol=1e-15)
        assert {"base_link", "link_1", "tool0"} <= set(poses)


@pytest.mark.parametrize("name", NAMES)
def test_jacobian_matches_finite_differences_of_fk(robots, name):
    robot = robots[name]
    q = np.random.default_rng(5).uniform(robot.spec.lower, robot.spec.upper) * 0.5
    J, h = robot.jacobian(q), 1e-6
    for k in range(robot.nq):
        dq = np.zeros(robot.nq)
        dq[k] = h
        Tp, Tm = robot.fk(q + dq), robot.fk(q - dq)
        np.testing.assert_allclose(J[:3, k], (Tp[:3, 3] - Tm[:3, 3]) / (2 * h), atol=1e-7)
        W = (Tp[:3, :3] - Tm[:3, :3]) / (2 * h) @ robot.fk(q)[:3, :3].T
        np.testing.assert_allclose(J[3:, k], [W[2, 1], W[0, 2], W[1, 0]], atol=1e-7)


def test_wrong_joint_vector_and_unknown_frame_are_input_errors(robots):
    ur = robots["ur10e"]
    with pytest.raises(InputError, match=r"expected shape \(6,\)"):
        ur.fk(np.zeros(7))
    with pytest.raises(InputError, match=r"expected shape \(N, 6\)"):
        ur.fk_many(np.zeros(6))
    with pytest.raises(InputError, match="no frame 'flange'.*tool0"):
        ur.frame_pose(np.zeros(6), "flange")


# ---- collision geometry -------------------------------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
def test_every_link_has_convex_shapes_of_few_dozen_faces(robots, name):
    robot = robots[name]
    shapes = robot.collision_shapes()
    links = {s.link for s in shapes}
    assert {"base_link"} | {f"link_{i}" for i in range(1, robot.nq + 1)} <= links
    for s in shapes:
        assert isinstance(s.geometry, fcl.Convex)
        assert s.link_T_shape.shape == (4, 4)
        assert s.convex.mesh.is_watertight and s.convex.plane_count <= 48


@pytest.mark.parametrize("name", NAMES)
def test_fcl_distance_from_the_flange_shape_to_a_box(robots, name):
    robot = robots[name]
    q = np.zeros(robot.nq)
    poses = robot.link_poses(q)
    flange_shape = [s for s in robot.collision_shapes() if s.link == f"link_{robot.nq}"][0]
    tip = robot.fk(q)[:3, 3]
    box = fcl.CollisionObject(fcl.Box(0.2, 0.2, 0.2), fcl.Transform(tip + [0.0, 0.0, 1.1]))
    result = fcl.DistanceResult()
    d = fcl.distance(
        flange_shape.collision_object(poses[flange_shape.link]), box, fcl.DistanceRequest(), result
    )
    assert 0.0 < d < 1.0
    far = fcl.CollisionObject(fcl.Box(0.2, 0.2, 0.2), fcl.Transform(tip + [0.0, 0.0, 3.1]))
    assert fcl.distance(
        flange_shape.collision_object(poses[flange_shape.link]),
        far,
        fcl.DistanceRequest(),
        fcl.DistanceResult(),
    ) == pytest.approx(d + 2.0)


@pytest.mark.parametrize("name", NAMES)
def test_checked_link_pairs_are_clear_at_zero(robots, name):
    """Every pair the self-collision matrix checks is apart at the zero configuration."""
    robot = robots[name]
    poses = robot.link_poses(np.zeros(robot.nq))
    disabled = robot.self_collision()
    shapes = robot.collision_shapes()
    for i, a in enumerate(shapes):
        for b in shapes[i + 1 :]:
            if a.link == b.link or frozenset((a.link, b.link)) in disabled:
                continue
            d = fcl.distance(
                a.collision_object(poses[a.link]),
                b.collision_object(poses[b.link]),
                fcl.DistanceRequest(),
                fcl.DistanceResult(),
            )
            assert d > 0.0, (a.link, a.name, b.link, b.name)


def test_unknown_collision_geometry_is_rejected(tmp_path):
    urdf = tmp_path / "r.urdf"
    urdf.write_text(
        '<robot name="r"><link name="a"><collision><geometry>'
        '<capsule radius="0.1" length="0.2"/></geometry></collision></link></robot>'
    )
    with pytest.raises(InputError, match="<capsule> is not supported; allowed: box, cylinder, sphere, mesh"):
        collision_shapes_from_urdf(urdf)


def test_missing_mesh_file_is_an_input_error(tmp_path):
    urdf = tmp_path / "r.urdf"
    urdf.write_text(
        '<robot name="r"><link name="a"><collision><geometry>'
        '<mesh filename="a.stl"/></geometry></collision></link></robot>'
    )
    with pytest.raises(InputError, match="mesh file .*a.stl not found"):
        collision_shapes_from_urdf(urdf)


def test_mesh_collision_is_its_convex_hull_scaled_and_placed(tmp_path):
    # an L-shaped (concave) solid in millimetres: its hull adds the corner at (40, 40, *)
    box_a = trimesh.creation.box([40.0, 10.0, 10.0])
    box_a.apply_translation([20.0, 5.0, 5.0])
    box_b = trimesh.creation.box([10.0, 40.0, 10.0])
    box_b.apply_translation([5.0, 20.0, 5.0])
    trimesh.util.concatenate([box_a, box_b]).export(tmp_path / "l.stl")
    urdf = tmp_path / "r.urdf"
    urdf.write_text(
        '<robot name="r"><link name="a"><collision><origin xyz="1 0 0" rpy="0 0 1.5707963267948966"/>'
        '<geometry><mesh filename="l.stl" scale="0.001 0.001 0.001"/></geometry></collision></link></robot>'
    )
    (shape,) = collision_shapes_from_urdf(urdf)
    assert isinstance(shape.geometry, fcl.Convex)
    assert shape.convex.mesh.volume == pytest.approx(0.04 * 0.04 * 0.01 - 0.5 * 0.03 * 0.03 * 0.01)
    # placed at the origin turned 90 deg about z: shape x is link y
    obj = shape.collision_object(np.eye(4))
    probe = fcl.CollisionObject(fcl.Sphere(0.001), fcl.Transform(np.array([1.0, 0.1, 0.005])))
    assert fcl.distance(obj, probe, fcl.DistanceRequest(), fcl.DistanceResult()) == pytest.approx(
        0.059, abs=1e-5
    )  # GJK


def test_each_robot_names_the_program_its_controller_runs(robots):
    """KUKA's KR arms run KRL on a KR C controller, the LBR iiwa Sunrise Java on its cabinet."""
    programs = {name: robots[name].spec.default_program for name in NAMES}
    assert programs == {
        "abb_irb4600_60_205": "rapid",
        "kuka_iiwa14_r820": "sunrise",
        "kuka_kr8_r1440_2_arc_hw": "krl",
        "ur10e": "urscript",
    }
    spec = robots["kuka_kr8_r1440_2_arc_hw"].spec
    with pytest.raises(InputError, match="program 'rapid' does not run on a kuka controller"):
        RobotSpec(**{**spec.__dict__, "program": "rapid"})
    assert RobotSpec(**{**spec.__dict__, "program": ""}).default_program == "krl"  # the family's default
    abb = robots["abb_irb4600_60_205"].spec
    assert RobotSpec(**{**abb.__dict__, "controller": "kuka"}).default_program == "krl"
