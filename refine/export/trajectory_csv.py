"""``trajectory.csv``: one row per waypoint, SI units, world frame {F}.

Columns, in this order (an exact interface, see DESIGN.md)::

    t, s, q1, ..., qn, x_ref, y_ref, z_ref, x, y, z, qw, qx, qy, qz, qw_demo, qx_demo, qy_demo,
    qz_demo, speed

``t`` time [s], ``s`` arc length along the CAD path [m], ``q*`` joints [rad], ``*_ref`` the CAD
target [m], ``x y z qw..qz`` the TCP pose reached, ``*_demo`` the fused demonstrated orientation,
``speed`` the planned TCP speed [m/s]. The header has no spaces. Numbers are Python ``repr`` of the
float (shortest form that reads back to the same double). Quaternions are scalar first; the reached
ones have continuous signs along the path (consecutive dot products >= 0, the first with qw >= 0),
and the demonstrated ones too, with the first row's sign matching the reached quaternion.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from refine.errors import InputError
from refine.export.sink import put_text
from refine.frames import (
    continuous_quaternions,
    make_transform,
    matrix_from_quaternion,
    quaternion_from_matrix,
)
from refine.paths import Trajectory

log = logging.getLogger(__name__)

_BEFORE_Q = ["t", "s"]
_AFTER_Q = [
    "x_ref",
    "y_ref",
    "z_ref",
    "x",
    "y",
    "z",
    "qw",
    "qx",
    "qy",
    "qz",
    "qw_demo",
    "qx_demo",
    "qy_demo",
    "qz_demo",
    "speed",
]


def trajectory_columns(n_joints: int) -> list[str]:
    """Column names of ``trajectory.csv`` for a robot with ``n_joints`` joints."""
    return [*_BEFORE_Q, *(f"q{i}" for i in range(1, n_joints + 1)), *_AFTER_Q]


def _quaternion_columns(trajectory: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    quat = continuous_quaternions(quaternion_from_matrix(trajectory.poses[:, :3, :3]))
    demo = continuous_quaternions(quaternion_from_matrix(trajectory.rotations_demo))
    if len(demo) and float(np.dot(demo[0], quat[0])) < 0.0:
        demo = -demo
    return quat, demo


def write_trajectory_csv(path: str | Path, trajectory: Trajectory) -> Path:
    """Write ``trajectory.csv``.

    Args:
        path: output file.
        trajectory: the refined, timed path.

    Returns:
        The path written.
    """
    path = Path(path)
    quat, demo = _quaternion_columns(trajectory)
    table = np.column_stack(
        [
            trajectory.t,
            trajectory.s,
            trajectory.q,
            trajectory.positions_ref,
            trajectory.poses[:, :3, 3],
            quat,
            demo,
            trajectory.speed,
        ]
    )
    lines = [",".join(trajectory_columns(trajectory.q.shape[1]))]
    lines += [",".join(map(repr, row)) for row in table.tolist()]
    put_text(path, "\n".join(lines) + "\n")
    log.info("wrote %s: %d rows", path, len(trajectory))
    return path


def read_trajectory_csv(path: str | Path) -> Trajectory:
    """Read ``trajectory.csv`` back into a :class:`Trajectory`.

    The reached pose is rebuilt from position and quaternion, the demonstrated orientation from its
    quaternion (both normalised).

    Raises:
        InputError: missing file, a header that is not the documented one, or bad numbers.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise InputError(f"cannot read trajectory CSV {path}: {e}") from e
    lines = text.splitlines()
    if not lines:
        raise InputError(f"trajectory CSV {path}: empty file")
    header = [h.strip() for h in lines[0].split(",")]
    n_joints = len(header) - len(_BEFORE_Q) - len(_AFTER_Q)
    if n_joints < 1 or header != trajectory_columns(n_joints):
        raise InputError(f"trajectory CSV {path}: header {header} is not t, s, q1..qn, {', '.join(_AFTER_Q)}")
    rows = []
    for number, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        try:
            row = [float(v) for v in line.split(",")]
        except ValueError as e:
            raise InputError(f"trajectory CSV {path}, line {number}: {e}") from e
        if len(row) != len(header):
            raise InputError(
                f"trajectory CSV {path}, line {number}: {len(row)} values, expected {len(header)}"
            )
        rows.append(row)
    data = np.array(rows, dtype=float).reshape(-1, len(header))
    c = {name: i for i, name in enumerate(header)}
    q = data[:, c["q1"] : c["q1"] + n_joints]
    poses = make_transform(
        matrix_from_quaternion(data[:, c["qw"] : c["qz"] + 1]), data[:, c["x"] : c["z"] + 1]
    )
    return Trajectory(
        t=data[:, c["t"]].copy(),
        s=data[:, c["s"]].copy(),
        q=q.copy(),
        positions_ref=data[:, c["x_ref"] : c["z_ref"] + 1].copy(),
        poses=poses,
        rotations_demo=matrix_from_quaternion(data[:, c["qw_demo"] : c["qz_demo"] + 1]),
        speed=data[:, c["speed"]].copy(),
    )
