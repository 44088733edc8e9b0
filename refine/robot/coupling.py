"""The controller's joints where they differ from the URDF's: joint couplings and interaction limits.

A URDF states every joint relative to its parent link. Some controllers count a joint otherwise,
and then every joint value a user reads or writes (a home position, a program's joint target, the
joints of ``trajectory.csv`` and the report) must be the controller's:

* ``"fanuc_j2_j3"``: a FANUC arm with a parallel link measures J3 from the horizontal, not from the
  upper arm. With the ROS-Industrial descriptions (J2 about +y, J3 about -y, the forearm horizontal
  at zero) the forearm is horizontal when ``J3_urdf = J2_urdf``, so ``J3_controller = J3_urdf -
  J2_urdf`` and ``J3_urdf = J3_controller + J2_controller`` (J2 and the other joints unchanged).
  This is the ROS-Industrial ``fanuc_driver``'s ``J23_factor = 1``: its state relay adds
  ``J23_factor * J2`` to the controller's J3 to get the URDF's (``fanuc_robot_state_node.cpp``,
  ``fanuc_utils.cpp`` ``linkage_transform``), and its trajectory streamer subtracts it on the way
  back (``fanuc_joint_streamer_node.cpp``, "sending points back to the Fanuc, so invert factor").

Both maps are linear, ``q_controller = C · q_urdf`` (:func:`controller_matrix`).

Interaction limits (:class:`JointInteraction`): a linear constraint on the controller's joints,
``lower <= Σ c_i · J_i <= upper`` [deg], such as FANUC's J2/J3 interaction limit (the J3 range the
controller allows depends on J2). :func:`interaction_rows` turns them into rows on the URDF joints,
which is what the optimiser constrains and the verifier checks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from refine.errors import InputError

JOINT_COUPLINGS = ("fanuc_j2_j3",)
"""The joint couplings a robot can name (``joint_coupling`` in ``robot.toml``)."""


@dataclass(frozen=True)
class JointInteraction:
    """``lower_deg <= Σ coefficients[i] · J_(i+1) <= upper_deg`` on the controller's joints [deg].

    Attributes:
        coefficients: one per joint, shape (n,); zero for the joints it does not involve.
        lower_deg: lower bound [deg].
        upper_deg: upper bound [deg].
        label: what the limit is, for messages (``"J2/J3 interaction"``).
    """

    coefficients: tuple[float, ...]
    lower_deg: float
    upper_deg: float
    label: str = "joint interaction"

    def __post_init__(self) -> None:
        c = np.asarray(self.coefficients, dtype=float)
        if c.ndim != 1 or not np.all(np.isfinite(c)) or not np.any(c != 0.0):
            raise InputError(
                f"{self.label}: coefficients must be finite, not all zero, got {self.coefficients}"
            )
        if not (
            math.isfinite(self.lower_deg)
            and math.isfinite(self.upper_deg)
            and self.lower_deg < self.upper_deg
        ):
            raise InputError(
                f"{self.label}: needs finite lower_deg < upper_deg [deg], got {self.lower_deg}, {self.upper_deg}"
            )


def check_coupling(coupling: str, n_joints: int, where: str) -> None:
    """``coupling`` is ``""`` or one of :data:`JOINT_COUPLINGS` and fits a robot of ``n_joints`` joints."""
    if coupling and coupling not in JOINT_COUPLINGS:
        raise InputError(f"{where}: joint_coupling {coupling!r} is not one of {', '.join(JOINT_COUPLINGS)}")
    if coupling == "fanuc_j2_j3" and n_joints < 3:
        raise InputError(f"{where}: joint_coupling 'fanuc_j2_j3' needs at least 3 joints, got {n_joints}")


def controller_matrix(coupling: str, n_joints: int) -> NDArray[np.float64]:
    """``C`` (n, n) with ``q_controller = C · q_urdf``; the identity without a coupling."""
    check_coupling(coupling, n_joints, "controller joints")
    C = np.eye(n_joints)
    if coupling == "fanuc_j2_j3":
        C[2, 1] = -1.0  # J3_controller = J3_urdf - J2_urdf
    return C


def to_controller(coupling: str, q: Any) -> NDArray[np.float64]:
    """URDF joints (..., n) [rad or deg] as the controller counts them, same unit and shape."""
    q = np.asarray(q, dtype=float)
    out = q.copy()
    if coupling:
        check_coupling(coupling, q.shape[-1], "controller joints")
        out[..., 2] = q[..., 2] - q[..., 1]
    return out


def from_controller(coupling: str, q_controller: Any) -> NDArray[np.float64]:
    """The controller's joints (..., n) [rad or deg] as URDF joints, same unit and shape."""
    q = np.asarray(q_controller, dtype=float)
    out = q.copy()
    if coupling:
        check_coupling(coupling, q.shape[-1], "controller joints")
        out[..., 2] = q[..., 2] + q[..., 1]
    return out


def interaction_rows(
    coupling: str, interactions: tuple[JointInteraction, ...], n_joints: int
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The interaction limits as rows on the URDF joints: ``lower <= A · q_urdf <= upper`` [rad].

    Returns:
        ``A`` (m, n), ``lower`` (m,) and ``upper`` (m,) [rad]; m = 0 without limits.
    """
    if not interactions:
        return np.zeros((0, n_joints)), np.zeros(0), np.zeros(0)
    C = controller_matrix(coupling, n_joints)
    for it in interactions:
        if len(it.coefficients) != n_joints:
            raise InputError(
                f"{it.label}: {len(it.coefficients)} coefficients for a robot of {n_joints} joints"
            )
    A = np.array([it.coefficients for it in interactions], dtype=float) @ C
    lower = np.radians([it.lower_deg for it in interactions])
    upper = np.radians([it.upper_deg for it in interactions])
    return A, lower, upper


def interactions_from_toml(rows: Any, n_joints: int, where: str) -> tuple[JointInteraction, ...]:
    """The ``joint_interaction`` list of a ``robot.toml`` read into limits.

    Each entry is a table ``{joints = [2, 3], coefficients = [1.0, 1.0], lower_deg = .., upper_deg =
    .., label = ".."}``: joints 1-based, on the controller's joints.
    """
    if not isinstance(rows, list):
        raise InputError(f"{where}: joint_interaction must be a list of tables, got {type(rows).__name__}")
    out = []
    for i, row in enumerate(rows):
        if not isinstance(row, dict):
            raise InputError(f"{where}: joint_interaction[{i}] must be a table")
        unknown = sorted(set(row) - {"joints", "coefficients", "lower_deg", "upper_deg", "label"})
        missing = sorted({"joints", "coefficients", "lower_deg", "upper_deg"} - set(row))
        if unknown or missing:
            raise InputError(
                f"{where}: joint_interaction[{i}]: unknown keys {unknown} / missing keys {missing}"
            )
        joints, coefs = list(row["joints"]), list(row["coefficients"])
        if len(joints) != len(coefs) or any(not (isinstance(j, int) and 1 <= j <= n_joints) for j in joints):
            raise InputError(
                f"{where}: joint_interaction[{i}]: joints must be numbers 1..{n_joints}, one coefficient each"
            )
        full = [0.0] * n_joints
        for j, c in zip(joints, coefs, strict=True):
            full[j - 1] = float(c)
        label = str(row.get("label", f"joint interaction {i + 1}"))
        out.append(JointInteraction(tuple(full), float(row["lower_deg"]), float(row["upper_deg"]), label))
    return tuple(out)
