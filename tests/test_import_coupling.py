"""``refine robots import`` decides the joint coupling from what a support package says.

The expectations come from the packages' own files as read by hand: ``fanuc_m20ia_support``'s
launch files give the FANUC driver ``J23_factor`` default 1 (``robot_interface_streaming_m20ia.launch``,
line 15) and its macro turns joint 2 about +y and joint 3 about -y; ``motoman_gp12_support`` has no
``J23_factor`` anywhere.
"""

from pathlib import Path

import pytest

from refine.errors import InputError
from refine.robot.description import resolve_description
from refine.robot.importer import detect_joint_coupling, driver_j23_factors, find_description
from refine.robot.spec import build_model


def _shared_package(require, name: str) -> Path:
    return require.path(require.shared / "robot-descriptions" / name, f"the support package {name}")


def _model(package: Path, xacro: str | None = None):
    source = find_description(package, xacro)
    return source, build_model(resolve_description(source, None))


def test_the_m20ia_package_says_fanuc_j2_j3_and_the_gp12_package_none(require):
    m20ia = _shared_package(require, "fanuc_m20ia_support")
    source, model = _model(m20ia, "urdf/m20ia.xacro")
    assert driver_j23_factors(m20ia, "m20ia") == [
        ("robot_interface_streaming_m20ia.launch", 1),
        ("robot_state_visualize_m20ia.launch", 1),
    ]
    assert detect_joint_coupling(m20ia, source, model, "fanuc").name == "fanuc_j2_j3"
    assert detect_joint_coupling(m20ia, source, model, "fanuc", "none").name == ""
    gp12 = _shared_package(require, "motoman_gp12_support")
    source, model = _model(gp12)
    assert driver_j23_factors(gp12, "gp12") == []
    assert detect_joint_coupling(gp12, source, model, "yaskawa").name == ""
    # even named a FANUC arm, a package without the driver's J23_factor gets no coupling unless asked
    assert detect_joint_coupling(gp12, source, model, "fanuc").name == ""
    assert detect_joint_coupling(gp12, source, model, "fanuc", "fanuc_j2_j3").name == "fanuc_j2_j3"


def _arm_package(folder: Path, factor: str, axis3: str) -> Path:
    """A three-joint package ``arm_support`` with a driver launch file giving ``J23_factor``."""
    pkg = folder / "arm_support"
    (pkg / "urdf").mkdir(parents=True)
    (pkg / "launch").mkdir()
    (pkg / "package.xml").write_text(
        '<?xml version="1.0"?><package format="2"><name>arm_support</name><version>1.0.0</version>'
        "<license>MIT</license></package>"
    )
    (pkg / "launch" / "robot_interface_streaming_arm.launch").write_text(
        f'<launch><arg name="J23_factor" default="{factor}" doc="coupling"/></launch>'
    )
    joints = [("j1", "0 0 1"), ("j2", "0 1 0"), ("j3", axis3)]
    links = "".join(f'<link name="l{i}"/>' for i in range(4))
    body = "".join(
        f'<joint name="{n}" type="revolute"><parent link="l{i}"/><child link="l{i + 1}"/>'
        f'<origin xyz="0 0 0.3"/><axis xyz="{a}"/><limit lower="-2" upper="2" effort="1" velocity="1"/></joint>'
        for i, (n, a) in enumerate(joints)
    )
    (pkg / "urdf" / "arm.urdf").write_text(f'<robot name="arm">{links}{body}</robot>')
    return pkg


@pytest.mark.parametrize(
    ("factor", "axis3", "expected"),
    [
        ("1", "0 -1 0", "fanuc_j2_j3"),  # opposite axes: J3 counted from the horizontal
        ("0", "0 -1 0", ""),  # the driver adds nothing
        ("1", "0 1 0", InputError),  # the factor contradicts the axes: J3_c would be J3_u + J2_u
        ("-1", "0 -1 0", InputError),  # a factor refine does not model
    ],
)
def test_the_launch_files_factor_and_the_joint_axes_decide(tmp_path, factor, axis3, expected):
    pkg = _arm_package(tmp_path, factor, axis3)
    source, model = _model(pkg)
    if expected is InputError:
        with pytest.raises(InputError, match="--joint-coupling"):
            detect_joint_coupling(pkg, source, model, "fanuc")
    else:
        assert detect_joint_coupling(pkg, source, model, "fanuc").name == expected
    # a Yaskawa controller never couples, whatever the launch files say
    assert detect_joint_coupling(pkg, source, model, "yaskawa").name == ""
    with pytest.raises(InputError, match="not one of"):
        detect_joint_coupling(pkg, source, model, "fanuc", "j2_j3")


@pytest.mark.slow
def test_the_imported_m20ia_writes_its_coupling_and_loads_with_it(require, tmp_path, monkeypatch, capsys):
    from refine.cli import main
    from refine.robot.registry import load_robot

    m20ia = _shared_package(require, "fanuc_m20ia_support")
    argv = ["robots", "import", str(m20ia), "--name", "m20ia", "--xacro", "urdf/m20ia.xacro"]
    argv += ["--controller", "fanuc", "--samples", "40", "--registry", str(tmp_path)]
    assert main(argv) == 0
    assert "joint coupling fanuc_j2_j3: J23_factor = 1" in capsys.readouterr().out
    bundled = load_robot("fanuc_m20ia").spec
    monkeypatch.setenv("REFINE_ROBOTS_DIR", str(tmp_path))
    spec = load_robot("m20ia").spec
    assert spec.joint_coupling == "fanuc_j2_j3" and spec.controller_frame == "base"
    (row,) = spec.joint_interaction
    # the macro's joint_3 limits, -185 and 273.1 deg, on the controller's J3 alone
    assert row.coefficients == (0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
    assert (row.lower_deg, row.upper_deg) == (-185.0, 273.1)
    assert "fanuc_j2_j3" in (tmp_path / "m20ia" / "README.md").read_text()
    # the bundled entry, imported from the same package, says the same
    assert (bundled.joint_coupling, bundled.joint_interaction) == (
        spec.joint_coupling,
        spec.joint_interaction,
    )
