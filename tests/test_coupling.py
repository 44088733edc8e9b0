"""The controller's joints of a FANUC arm: J3 counted from the horizontal, read from robot.toml."""

import math
import re
import shutil
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from refine.errors import InputError
from refine.robot.coupling import from_controller, interaction_rows, to_controller
from refine.robot.registry import load_robot

XACRO = (
    Path(__file__).resolve().parents[1]
    / "../shared/robot-descriptions/fanuc_m20ia_support/urdf/m20ia_macro.xacro"
)


def _m20ia_arm_urdf() -> str:
    """Joints 1..4 of the M-20iA as its ROS-Industrial macro states them (origins, axes)."""
    text = XACRO.read_text(encoding="utf-8")
    joints = []
    for i in (1, 2, 3, 4):
        m = re.search(
            rf'<joint name="\${{prefix}}joint_{i}" type="revolute">\s*<origin xyz="([^"]+)" rpy="([^"]+)"/>'
            rf'.*?<axis xyz="([^"]+)"/>',
            text,
            re.DOTALL,
        )
        joints.append(m.groups())
    links = "".join(f'<link name="l{i}"/>' for i in range(5))
    body = "".join(
        f'<joint name="j{i + 1}" type="revolute"><origin xyz="{xyz}" rpy="{rpy}"/><parent link="l{i}"/>'
        f'<child link="l{i + 1}"/><axis xyz="{axis}"/><limit lower="-6" upper="6" effort="0" velocity="1"/></joint>'
        for i, (xyz, rpy, axis) in enumerate(joints)
    )
    return f'<robot name="m20ia_arm">{links}{body}</robot>'


@pytest.mark.skipif(not XACRO.is_file(), reason="needs ../shared/robot-descriptions")
def test_controller_j3_is_zero_exactly_when_the_forearm_is_horizontal():
    model = pin.buildModelFromXML(_m20ia_arm_urdf())
    data = model.createData()
    rng = np.random.default_rng(3)
    for _ in range(20):
        j2, j3_controller = rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0)
        q_urdf = from_controller("fanuc_j2_j3", [0.3, j2, j3_controller, 0.0])
        pin.forwardKinematics(model, data, q_urdf)
        forearm = data.oMi[4].translation - data.oMi[3].translation  # elbow -> wrist along the forearm
        along = data.oMi[3].rotation[:, 0]  # the forearm's own x axis (horizontal at zero)
        elevation = math.atan2(along[2], math.hypot(along[0], along[1]))
        # J3 as the controller counts it: the forearm's angle to the horizontal, positive up (about -y)
        assert elevation == pytest.approx(j3_controller, abs=1e-9)
        assert np.linalg.norm(forearm) > 0.2
        np.testing.assert_allclose(
            to_controller("fanuc_j2_j3", q_urdf), [0.3, j2, j3_controller, 0.0], atol=1e-12
        )


def test_interaction_limits_become_rows_on_the_urdf_joints():
    from refine.robot.coupling import JointInteraction

    # lower <= J3_controller + J2_controller <= upper, i.e. J3_urdf itself
    it = JointInteraction((0.0, 1.0, 1.0, 0.0, 0.0, 0.0), -100.0, 150.0)
    A, lo, hi = interaction_rows("fanuc_j2_j3", (it,), 6)
    np.testing.assert_allclose(A, [[0.0, 0.0, 1.0, 0.0, 0.0, 0.0]])
    np.testing.assert_allclose([lo[0], hi[0]], np.radians([-100.0, 150.0]))


def test_robot_toml_names_the_coupling_and_the_interaction_limits(tmp_path, monkeypatch):
    src = Path(__file__).resolve().parents[1] / "robots" / "abb_irb4600_60_205"
    dst = tmp_path / "fanuc_like"
    shutil.copytree(src, dst)
    toml = (
        (dst / "robot.toml").read_text(encoding="utf-8").replace('controller = "abb"', 'controller = "fanuc"')
    )
    toml += (
        'joint_coupling = "fanuc_j2_j3"\n'
        "joint_interaction = [{ joints = [2, 3], coefficients = [1.0, 1.0], lower_deg = -80.0, upper_deg = 200.0 }]\n"
    )
    (dst / "robot.toml").write_text(toml, encoding="utf-8")
    monkeypatch.setenv("REFINE_ROBOTS_DIR", str(tmp_path))
    robot = load_robot("fanuc_like")
    assert robot.spec.joint_coupling == "fanuc_j2_j3" and robot.spec.default_program == "tp"
    (it,) = robot.spec.joint_interaction
    assert it.coefficients == (0.0, 1.0, 1.0, 0.0, 0.0, 0.0) and (it.lower_deg, it.upper_deg) == (
        -80.0,
        200.0,
    )
    bad = tmp_path / "fanuc_bad"
    shutil.copytree(dst, bad)
    (bad / "robot.toml").write_text(toml.replace('"fanuc_j2_j3"', '"fanuc_j9"'), encoding="utf-8")
    with pytest.raises(InputError, match="joint_coupling 'fanuc_j9'"):
        load_robot("fanuc_bad")
