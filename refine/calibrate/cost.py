"""What calibration errors cost: the frames' uncertainty propagated to the TCP path.

A problem's ``[calibration]`` table gives each frame's standard deviations (translation per axis
[m], rotation per axis [deg], both in the frame's own axes). The TCP path is the planned tool pose
``P_k`` in the world at every waypoint (the fused path, or the refined TCP poses of a
``trajectory.csv``). A frame error ``delta`` makes the true frame ``T_true = T @ delta``; the
robot runs the joints planned with the nominal frames, so (first principles, no linearisation):

* the TCP actually goes to ``B dB B^-1 P_k dX`` (``B`` = ``base_in_world``, ``X`` =
  ``tcp_in_flange``), while the path on the real workpiece is at ``C dC C^-1 p_k`` (``C`` =
  ``cad_in_world``): the **position error** is the distance between the two;
* the worker's real tool orientation was ``S dS S^-1 R_k Y dY^-1 Y^-1`` (``S`` =
  ``source_in_world``, ``Y`` = ``sensor_in_tcp``, rotation parts; ``R_k`` the planned
  orientation), while the robot holds the rotation part of the first pose above: the
  **orientation error** is the angle between the two.

The tracker frames do not move the path (its positions come from the CAD model); their
translation only shifts where the demonstration is matched to the path, which is left out.
Errors are drawn per frame (the others held nominal) and for all frames together, Monte Carlo
with a fixed seed.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from refine.errors import InputError
from refine.frames import invert_transform, make_transform, matrix_from_quaternion, rotation_angle_deg
from refine.settings.calibration import FRAMES, CalibrationSettings, FrameUncertainty
from refine.types import Array

#: Percentile of the sampled path maxima reported as the worst error [%].
WORST_PERCENTILE = 95.0


# ---- propagation --------------------------------------------------------------------------------


def path_errors(
    tcp_poses: ArrayLike, nominal: dict[str, ArrayLike], deltas: dict[str, ArrayLike]
) -> tuple[Array, Array]:
    """Position [m] and orientation [deg] errors along the path, shape (M, N) each.

    Args:
        tcp_poses: planned TCP poses in {F}, shape (N, 4, 4).
        nominal: the nominal frames by name (all of :data:`FRAMES`), each (4, 4).
        deltas: frame errors by name, each (M, 4, 4) or (4, 4) (``T_true = T @ delta``); a
            frame without one is taken as exact.
    """
    P = np.asarray(tcp_poses, dtype=float)[None]  # (1, N, 4, 4)
    m = max((np.asarray(d).reshape(-1, 4, 4).shape[0] for d in deltas.values()), default=1)

    def world_error(name: str) -> Array:
        """``T dT T^-1`` per sample, (M, 1, 4, 4): the frame error seen in the world."""
        T = np.asarray(nominal[name], dtype=float)
        d = np.asarray(deltas.get(name, np.eye(4)), dtype=float).reshape(-1, 4, 4)
        return np.broadcast_to(T @ d @ invert_transform(T), (m, 4, 4))[:, None]

    def local_error(name: str) -> Array:
        d = np.asarray(deltas.get(name, np.eye(4)), dtype=float).reshape(-1, 4, 4)
        return np.broadcast_to(d, (m, 4, 4))[:, None]

    actual = world_error("base_in_world") @ P @ local_error("tcp_in_flange")
    wanted_position = world_error("cad_in_world") @ P
    position_error = np.linalg.norm(actual[..., :3, 3] - wanted_position[..., :3, 3], axis=-1)
    Y = np.asarray(nominal["sensor_in_tcp"], dtype=float)
    dY = local_error("sensor_in_tcp")
    wanted_rotation = (
        world_error("source_in_world")[..., :3, :3]
        @ P[..., :3, :3]
        @ Y[:3, :3]
        @ np.swapaxes(dY[..., :3, :3], -1, -2)
        @ Y[:3, :3].T
    )
    angle_error = rotation_angle_deg(wanted_rotation, actual[..., :3, :3])
    return position_error, angle_error


def sample_deltas(u: FrameUncertainty, samples: int, rng: np.random.Generator) -> Array:
    """Random frame errors (M, 4, 4): normal translation and rotation vector per axis."""
    xyz = rng.normal(size=(samples, 3)) * np.asarray(u.xyz_m)
    rotvec = rng.normal(size=(samples, 3)) * np.radians(u.rpy_deg)
    return make_transform(Rotation.from_rotvec(rotvec).as_matrix(), xyz)


@dataclass(frozen=True)
class PathCost:
    """What one frame's (or all frames') uncertainty costs on the path.

    Attributes:
        frame: frame name, or ``"all"``.
        mean_position_error_m: mean over samples and waypoints [m].
        worst_position_error_m: 95th percentile over samples of the largest error along the path [m].
        mean_orientation_error_deg: mean over samples and waypoints [deg].
        worst_orientation_error_deg: 95th percentile of the path's largest orientation error [deg].
    """

    frame: str
    mean_position_error_m: float
    worst_position_error_m: float
    mean_orientation_error_deg: float
    worst_orientation_error_deg: float

    @staticmethod
    def from_errors(frame: str, position_m: Array, angle_deg: Array) -> PathCost:
        """Summarise errors of shape (M, N) (samples, waypoints)."""
        return PathCost(
            frame=frame,
            mean_position_error_m=float(position_m.mean()),
            worst_position_error_m=float(np.percentile(position_m.max(axis=1), WORST_PERCENTILE)),
            mean_orientation_error_deg=float(angle_deg.mean()),
            worst_orientation_error_deg=float(np.percentile(angle_deg.max(axis=1), WORST_PERCENTILE)),
        )


def _chunked_errors(
    tcp_poses: ArrayLike, nominal: dict[str, ArrayLike], deltas: dict[str, Array], chunk: int = 64
) -> tuple[Array, Array]:
    """:func:`path_errors` over the samples in chunks, so memory stays at chunk x waypoints poses."""
    m = len(next(iter(deltas.values())))
    parts = [
        path_errors(tcp_poses, nominal, {k: d[i : i + chunk] for k, d in deltas.items()})
        for i in range(0, m, chunk)
    ]
    return np.concatenate([q[0] for q in parts]), np.concatenate([q[1] for q in parts])


def calibration_cost(
    tcp_poses: ArrayLike, nominal: dict[str, ArrayLike], settings: CalibrationSettings
) -> list[PathCost]:
    """Monte Carlo cost of each uncertain frame alone, then of all together (last)."""
    rng = np.random.default_rng(settings.seed)
    out, all_deltas = [], {}
    for name in FRAMES:
        if name not in settings.frames:
            continue
        deltas = sample_deltas(settings.frames[name], settings.samples, rng)
        all_deltas[name] = deltas
        out.append(PathCost.from_errors(name, *_chunked_errors(tcp_poses, nominal, {name: deltas})))
    if not out:
        raise InputError("[calibration] gives no frame's uncertainty; nothing to propagate")
    out.append(PathCost.from_errors("all", *_chunked_errors(tcp_poses, nominal, all_deltas)))
    return out


def nominal_frames(problem: Any) -> dict[str, Array]:
    """The five frames of a :class:`~refine.problem.Problem` by name."""
    return {
        "base_in_world": problem.robot.base_in_world,
        "tcp_in_flange": problem.tool.tcp_in_flange,
        "cad_in_world": problem.frames.cad_in_world,
        "source_in_world": problem.frames.source_in_world,
        "sensor_in_tcp": problem.tool.sensor_in_tcp,
    }


def tcp_poses_from_trajectory(path: str | Path) -> Array:
    """Planned TCP poses (N, 4, 4) from the ``x, y, z, qw, qx, qy, qz`` columns of a trajectory.csv."""
    path = Path(path)
    try:
        header = path.read_text(encoding="utf-8").splitlines()[0].split(",")
        cols = [header.index(c) for c in ("x", "y", "z", "qw", "qx", "qy", "qz")]
        data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)[:, cols]
    except (OSError, IndexError, ValueError) as e:
        raise InputError(f"{path}: not a trajectory.csv with x, y, z, qw, qx, qy, qz columns ({e})") from e
    return make_transform(matrix_from_quaternion(data[:, 3:]), data[:, :3])


def deltas_between(nominal: dict[str, ArrayLike], true: dict[str, ArrayLike]) -> dict[str, Array]:
    """Frame errors ``T^-1 T_true`` of known true frames (a simulator's truth), by name."""
    return {
        name: invert_transform(np.asarray(nominal[name], dtype=float)) @ np.asarray(true[name], dtype=float)
        for name in FRAMES
    }


# ---- the table ----------------------------------------------------------------------------------


def cost_lines(costs: list[PathCost], n_waypoints: int, samples: int) -> list[str]:
    """The cost table: one line per frame (mean and worst position and orientation error)."""
    lines = [
        f"calibration cost on {n_waypoints} waypoints, {samples} samples per frame",
        f"{'frame':24s} {'mean pos':>10s} {'worst pos':>10s} {'mean ori':>10s} {'worst ori':>10s}",
    ]
    for c in costs:
        lines.append(
            f"{c.frame:24s} {c.mean_position_error_m * 1000:7.3f} mm {c.worst_position_error_m * 1000:7.3f} mm "
            f"{c.mean_orientation_error_deg:6.3f} deg {c.worst_orientation_error_deg:6.3f} deg"
        )
    lines.append("worst: the 95th percentile over the samples of the largest error along the path")
    return lines


def run_cost_lines(result) -> list[str]:  # noqa: ANN001 - RunResult, imported lazily
    """The cost table of a run's problem ``[calibration]`` on its refined TCP poses (all passes)."""
    problem = result.problem
    poses = np.concatenate(
        [
            p.trajectory.poses
            if p.trajectory is not None
            else make_transform(p.fused.rotations, p.fused.positions)
            for p in result.passes
        ]
    )
    costs = calibration_cost(poses, nominal_frames(problem), problem.calibration)
    return ["", *cost_lines(costs, len(poses), problem.calibration.samples)]
