"""The constraints at their bound in an answer (refine.optimise.binding), as the repair names them."""

import math

import numpy as np

from refine.optimise.binding import binding_at
from refine.optimise.diagnosis import Cause, Finding
from refine.robot.kinematics import TcpKinematics
from refine.robot.registry import load_robot
from refine.settings import Tolerances


def test_a_joint_at_its_limit_and_a_step_at_its_bound_are_named_and_nothing_else():
    robot = load_robot("ur10e")
    tol = Tolerances(joint_step_deg=10.0, singularity_margin=0.0)
    margin = math.radians(tol.joint_margin_deg)
    lower, upper = robot.spec.lower + margin, robot.spec.upper - margin
    q = np.tile(np.radians([10.0, -100.0, 90.0, -80.0, -90.0, 20.0]), (6, 1))
    q[:, 0] += np.radians(np.arange(6) * 0.5)  # small steps of joint 1
    q[:, 1] = lower[1] + math.radians(0.1)  # joint 2 near its bound (limit less margin) all along,
    q[3, 1] = lower[1]  # and on it at waypoint 3
    q[4:, 3] += math.radians(10.0)  # joint 4 moves the whole 10 deg bound from waypoint 3 to 4
    kin = TcpKinematics(robot, np.eye(4), np.eye(4))
    found = binding_at(kin, q, 2, 4, tol, lower, upper)
    assert [(f["cause"], f["joint"]) for f in found] == [("joint limit", 2), ("joint step", 4)]
    assert math.isclose(found[0]["limit"], math.degrees(lower[1]))
    assert math.isclose(found[1]["figure"], 10.0, abs_tol=1e-9)
    # joint 2 is on its bound at waypoint 3 only (0.1 deg off elsewhere); the 10 deg step joins 3 and 4
    assert found[0]["waypoints"] == ((3, 3),) and found[1]["waypoints"] == ((3, 4),)
    # outside the segment (waypoints 0-1, whose steps in and out are 0.5 deg) nothing binds
    assert binding_at(kin, q, 0, 1, tol, lower, upper) == []


def test_the_repair_text_names_what_binds_in_the_answer_after_the_first_cause():
    first = Cause("reach", 0.84, 0.82, "m", explains_deg=5.6, suggestion="tilt the tool")
    held = Cause(
        "collision", 0.0105, 0.01, "m", objects=("link_6", "post"), in_answer=True, waypoints=((3, 5), (8, 8))
    )
    step = Cause("joint step", 20.0, 20.0, "deg", joint=4, in_answer=True, waypoints=((6, 7),))
    text = Finding("repaired", 3, 9, 0.1, 0.2, (first, held, step), 2.5).describe()
    assert text.endswith(
        "reach: tilt the tool; at its bound in the answer: clearance link_6<->post at its 10 mm margin "
        "(10.5 mm) over waypoints 3-5, 8; joint 4 step at its 20 deg bound (20.00 deg) over waypoints 6-7"
    )
    assert held.as_json()["waypoints"] == [[3, 5], [8, 8]] and held.as_json()["in_answer"] is True
    assert first.as_json()["waypoints"] == [] and first.as_json()["in_answer"] is False
