"""Reach geometry: the wrist centre and the distances from the shoulder the joints allow.

Reach geometry: the wrist centre of a spherical-wrist arm and the range of distances from its
shoulder that the joints allow (:class:`ReachModel`), used by the seed's tilt, the infeasibility
proof before solving and the diagnosis.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin
import scipy.optimize

from refine.robot.model import Robot
from refine.types import Array

WRIST_TOLERANCE_M = 1e-4
"""The last three joint axes meet within this distance for the wrist to count as spherical [m]."""


@dataclass(frozen=True)
class ReachModel:
    """Where a robot can put its wrist centre (or TCP), measured from its shoulder.

    For a robot whose last three axes meet (a spherical wrist), the wrist centre's distance from the
    shoulder depends only on the arm joints (the elbow), so a pose is out of reach, whatever the
    arm does, when that distance leaves ``[r_min_m, r_max_m]``. The shoulder is the point of axis 2
    closest to axis 1; it turns with axis 1.

    Attributes:
        spherical: the last three axes meet; else the TCP stands in for the wrist centre.
        point_in_flange: the wrist centre in the flange frame [m], (3,) (zeros when not spherical).
        axis1: (unit direction, point) of axis 1 in the robot base frame.
        shoulder_ref: the shoulder point with axis 1 at 0, base frame [m], (3,).
        wrist_ref: the wrist centre with axis 1 at 0 (its azimuth sets the arm plane), base frame [m].
        r_min_m, r_max_m: the range of the wrist-centre distance from the shoulder inside the
            joint limits less the margin [m].
    """

    spherical: bool
    point_in_flange: Array
    axis1: tuple[Array, Array]
    shoulder_ref: Array
    wrist_ref: Array
    r_min_m: float
    r_max_m: float

    @functools.cached_property
    def _plane(self) -> tuple[Array, Array]:
        """Two unit vectors normal to axis 1 and to each other, the azimuth's 0 and 90 deg."""
        w = self.axis1[0]
        e1 = np.cross(w, [1.0, 0.0, 0.0] if abs(w[0]) < 0.9 else [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        return e1, np.cross(w, e1)

    def _azimuth(self, x: Array) -> Array:
        e1, e2 = self._plane
        d = np.atleast_2d(x) - self.axis1[1]
        return np.arctan2(d @ e2, d @ e1)

    @functools.cached_property
    def _wrist_azimuth(self) -> Array:
        return self._azimuth(self.wrist_ref)

    def shoulders(self, points: Array) -> tuple[Array, Array]:
        """The shoulder for each base-frame point (N, 3), arm turned towards it and away from it."""
        w, p = self.axis1
        theta = self._azimuth(points) - self._wrist_azimuth
        out = []
        for t in (theta, theta + math.pi):
            R = rotations_about(w, t)
            out.append(p + np.einsum("nij,j->ni", R, self.shoulder_ref - p))
        return out[0], out[1]

    @functools.cached_property
    def _shoulder_cylinder(self) -> tuple[float, float, float]:
        """The shoulder's height z_s and radius r_s about axis 1 [m], and cos φ (:meth:`distance`)."""
        w, p = self.axis1
        s = self.shoulder_ref - p
        z_s = float(s @ w)
        phi = float(self._azimuth(self.shoulder_ref)[0] - self._azimuth(self.wrist_ref)[0])
        return z_s, math.sqrt(max(float(s @ s) - z_s * z_s, 0.0)), math.cos(phi)

    def distance(self, points: Array) -> Array:
        """Distance from the shoulder [m] for base-frame points (N, 3).

        The arm is turned towards the point, or away from it when that is closer to the range.
        The shoulders of :meth:`shoulders` in cylinder coordinates about axis 1: a point at height
        z and radius r from the axis and a shoulder at z_s, r_s whose azimuth differs from the
        point's by the constant φ (the shoulder's from the wrist centre's, with axis 1 at 0) are
        ``√((z - z_s)² + r² + r_s² ∓ 2 r r_s cos φ)`` apart, turned towards and away.
        """
        w, p = self.axis1
        z_s, r_s, cos_phi = self._shoulder_cylinder
        d = np.atleast_2d(points) - p
        z = d @ w
        rho = d - z[:, None] * w  # off axis 1
        r2 = np.einsum("ki,ki->k", rho, rho)
        base = (z - z_s) ** 2 + r2 + r_s * r_s
        cross = (2.0 * r_s * cos_phi) * np.sqrt(r2)
        d = [np.sqrt(np.maximum(base - cross, 0.0)), np.sqrt(np.maximum(base + cross, 0.0))]
        out = [np.maximum(self.r_min_m - x, 0.0) + np.maximum(x - self.r_max_m, 0.0) for x in d]
        return np.where(out[0] <= out[1], d[0], d[1])


def rotations_about(w: Array, angles: Array) -> Array:
    """Rotation matrices (N, 3, 3) about the unit axis ``w`` by ``angles`` [rad]."""
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    a = np.asarray(angles, dtype=float)[:, None, None]
    return np.eye(3) + np.sin(a) * K + (1.0 - np.cos(a)) * (K @ K)


def _axes(robot: Robot, q: Array) -> list[tuple[Array, Array]]:
    """Every joint's axis (unit direction, a point on it) in the base frame at joints ``q``."""
    model, data = robot.model, robot.model.createData()
    pin.computeJointJacobians(model, data, q)
    out = []
    for j in range(1, model.njoints):
        v, w = data.J[:3, model.joints[j].idx_v], data.J[3:, model.joints[j].idx_v]
        w = w / np.linalg.norm(w)
        out.append((w, np.cross(w, v)))  # v = p x w for p on the axis (WORLD convention)
    return out


def _meeting_point(lines: list[tuple[Array, Array]]) -> tuple[Array, float]:
    """The point closest to every line (least squares) and its largest distance to one [m]."""
    A = sum(np.eye(3) - np.outer(w, w) for w, _ in lines)
    b = sum((np.eye(3) - np.outer(w, w)) @ p for w, p in lines)
    x = np.linalg.lstsq(A, b, rcond=None)[0]
    return x, max(float(np.linalg.norm((np.eye(3) - np.outer(w, w)) @ (x - p))) for w, p in lines)


@functools.lru_cache(maxsize=16)
def reach_model(robot: Robot, joint_margin_rad: float, samples: int = 3000) -> ReachModel:
    """The reach model of ``robot`` with the joints kept ``joint_margin_rad`` inside their limits (sampled)."""
    n = robot.nq
    lower, upper = robot.spec.lower + joint_margin_rad, robot.spec.upper - joint_margin_rad
    rng = np.random.default_rng(1)
    q_ref = 0.5 * (np.clip(lower, -math.pi, math.pi) + np.clip(upper, -math.pi, math.pi))
    q_ref[0] = 0.0 if lower[0] <= 0.0 <= upper[0] else q_ref[0]
    axes = _axes(robot, q_ref + 0.3)  # away from aligned axes
    wc, spread = _meeting_point(axes[-3:]) if n >= 6 else (np.zeros(3), np.inf)
    spherical = spread < WRIST_TOLERANCE_M
    flange = robot.fk(q_ref + 0.3)
    point_in_flange = (np.linalg.inv(flange) @ np.append(wc, 1.0))[:3] if spherical else np.zeros(3)
    axes = _axes(robot, q_ref)
    (w1, p1), (w2, p2) = axes[0], axes[1]
    # the point of axis 2 closest to axis 1
    c = np.cross(w1, w2)
    if np.linalg.norm(c) < 1e-9:
        shoulder = p2
    else:
        t = np.dot(np.cross(p1 - p2, w1), c) / np.dot(c, c)
        shoulder = p2 + t * w2

    def point(q: Array) -> Array:
        T = robot.fk(q)
        return (T @ np.append(point_in_flange, 1.0))[:3]

    def distance_from_shoulder(q: Array) -> float:
        # the shoulder turns with axis 1: measured with axis 1 at q_ref's value
        qq = np.array(q, dtype=float)
        qq[0] = q_ref[0]
        return float(np.linalg.norm(point(qq) - shoulder))

    arm = slice(1, n - 3) if spherical else slice(1, n)
    lo, hi = np.clip(lower, -math.pi, math.pi), np.clip(upper, -math.pi, math.pi)
    qs = np.tile(q_ref, (samples, 1))
    qs[:, arm] = lo[arm] + rng.random((samples, len(range(n)[arm]))) * (hi - lo)[arm]
    at_ref = qs.copy()
    at_ref[:, 0] = q_ref[0]  # distance_from_shoulder of every sample, their poses in one batch
    d = np.linalg.norm((robot.fk_many(at_ref) @ np.append(point_in_flange, 1.0))[:, :3] - shoulder, axis=1)
    r = []
    for sign, k in ((1.0, int(np.argmin(d))), (-1.0, int(np.argmax(d)))):
        res = scipy.optimize.minimize(
            lambda x, s=sign: (
                s * distance_from_shoulder(np.concatenate([q_ref[: arm.start], x, q_ref[arm.stop :]]))
            ),
            qs[k, arm],
            bounds=list(zip(lo[arm], hi[arm], strict=True)),
            method="L-BFGS-B",
        )
        r.append(min(sign * d[k], float(res.fun)) * sign)
    return ReachModel(spherical, point_in_flange, (w1, p1), shoulder, point(q_ref), r[0], r[1])


def reach_bound(
    robot: Robot,
    joint_margin_rad: float,
    base_in_world: Array,
    tcp_in_flange: Array,
    positions: Array,
    lower: Array,
    upper: Array,
) -> Array:
    """A lower bound [m] on how far each TCP position (N, 3) in {F} is from every position the joints reach.

    The bound holds at any tool orientation, for joints inside ``[lower, upper]`` [rad]. With a
    spherical wrist the wrist centre's distance from the shoulder stays inside the reach model's
    ``[r_min_m, r_max_m]`` (:func:`reach_model`, which samples the arm joints inside the limits less
    ``joint_margin_rad``: the bound needs ``[lower, upper]`` inside those, each arm joint's either
    within [-pi, pi] or spanning a full turn), the TCP stays a fixed distance L from the wrist
    centre, and the shoulder turns about axis 1 on a circle; so a TCP position at distances from
    that circle between d_min and d_max is reached only if ``d_min <= r_max_m + L`` and
    ``d_max >= r_min_m - L``. The bound is how far either fails, axis 1 turned anywhere (its
    limits ignored, which only lowers it). Zeros (nothing proven) for a robot without a spherical
    wrist, or bounds the model did not sample. The range is as certain as the reach model's (its
    sampled extremes polished by a local optimiser, which on a bundled arm, whose wrist-centre
    distance turns with the elbow alone, are the extremes: the iiwa's stretched arm agrees to 1e-6 m).
    """
    reach = reach_model(robot, joint_margin_rad)
    out = np.zeros(len(positions))
    n = robot.nq
    if not reach.spherical or n < 6:
        return out
    lo, hi = robot.spec.lower + joint_margin_rad, robot.spec.upper - joint_margin_rad
    arm = slice(1, n - 3)
    full = (lo[arm] <= -math.pi) & (hi[arm] >= math.pi)
    inside = (lower[arm] >= np.clip(lo[arm], -math.pi, math.pi)) & (
        upper[arm] <= np.clip(hi[arm], -math.pi, math.pi)
    )
    if not np.all(full | inside):
        return out
    T_inv = np.linalg.inv(base_in_world)
    p = np.asarray(positions, dtype=float) @ T_inv[:3, :3].T + T_inv[:3, 3]
    L = float(np.linalg.norm((np.linalg.inv(tcp_in_flange) @ np.append(reach.point_in_flange, 1.0))[:3]))
    d_min, d_max = shoulder_circle_distances(reach, p)
    return np.maximum(np.maximum(d_min - reach.r_max_m - L, reach.r_min_m - L - d_max), 0.0)


def shoulder_circle_distances(reach: ReachModel, points: Array) -> tuple[Array, Array]:
    """The least and largest distance [m] of each base-frame point (N, 3) from the shoulder's circle.

    The shoulder turns with axis 1 on a circle (height h along the axis, radius a from it); a point
    at height z and radius rho about the axis is between ``hypot(z - h, rho - a)`` and
    ``hypot(z - h, rho + a)`` from it, whichever way axis 1 is turned.
    """
    w, c = reach.axis1
    s = reach.shoulder_ref - c
    h = float(w @ s)
    a = float(np.linalg.norm(s - h * w))
    v = np.asarray(points, dtype=float) - c
    z = v @ w
    rho = np.linalg.norm(v - z[:, None] * w, axis=1)
    return np.hypot(z - h, rho - a), np.hypot(z - h, rho + a)
