"""The collision model of a robot cell: signed distances, witness points and their Jacobians.

The model holds one FCL object per robot link primitive (from the URDF), per tool shape (on the
flange link) and per cell object (box, cylinder, sphere or mesh). Which pairs it checks is decided
once, by the rules of :mod:`refine.collision.pairs`. A query at joints q places the moving bodies,
runs a broad phase (world-aligned boxes around every body, compared in one vectorised step, so a
pair farther apart than the query distance costs no FCL call), and asks FCL only for the pairs left.

FCL is not differentiable inside CasADi; the optimiser linearises instead: at a witness point pair
the signed distance changes as ``n^T (J_body - J_other) dq`` (:func:`linearised_distance`), with
``J`` the Jacobian of the witness point as a point fixed to its link (:meth:`point_jacobian`).
"""

from __future__ import annotations

import logging
import math
import threading
from typing import TYPE_CHECKING

import numpy as np
import pinocchio as pin
from numpy.typing import ArrayLike, NDArray

from refine.collision.contact import Contact, linearised_distance
from refine.collision.distance import hull_bound, place, signed_distance
from refine.collision.geometry import Body, check_body_names, link_body, shape_body, world_aabb
from refine.collision.kept import Kept, indexed_pairs, recall, remember, structure_key
from refine.collision.motion import joint_reach, pair_reach
from refine.collision.native_bounds import box_gaps
from refine.collision.pairs import exclusion, joint_axes
from refine.errors import InputError
from refine.frames import check_transform
from refine.robot.model import Robot
from refine.settings import Shape
from refine.types import Array

if TYPE_CHECKING:
    from refine.problem import Problem

log = logging.getLogger(__name__)

RECENT_PATHS = 4
"""Joint paths whose moving-body poses and box bounds a model keeps for the next calls with them."""


class CollisionModel:
    """Robot, tool and cell as FCL objects, with the pairs to check.

    Attributes:
        robot: the robot model.
        base_in_world: T_F_R, (4, 4).
        tcp_in_flange: T_flange_TCP, (4, 4).
        margin_m: clearance kept between robot or tool and the cell [m].
        self_margin_m: clearance kept between the robot's own bodies and the tool [m].
        bodies: every body, the moving ones (links, then tool shapes) first.
        pairs: the checked shape pairs as (body, other) labels: ``"<link>/<shape>"`` for link
            shapes, the name for tool shapes and cell objects.
        excluded: the shape pairs not checked, as (body, other, reason) labels
            (the reasons are those of :mod:`refine.collision.pairs`).
        queries: narrow-phase (FCL) pair queries made so far.
        kept_hulls: the moving bodies' hull corners by label, shared by every model of the same robot,
            base, moving bodies and self margin (:func:`refine.collision.carry.hull_corners`).
    """

    def __init__(
        self,
        robot: Robot,
        base_in_world: ArrayLike,
        tcp_in_flange: ArrayLike,
        tool_shapes: tuple[Shape, ...],
        cell: tuple[Shape, ...],
        *,
        margin_m: float,
        self_margin_m: float,
    ) -> None:
        for key, value in (("margin_m", margin_m), ("self_margin_m", self_margin_m)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0.0):
                raise InputError(f"collision model: {key} must be a finite number >= 0, got {value!r}")
        self.robot = robot
        self.base_in_world = check_transform(base_in_world, "collision model: base_in_world").copy()
        self.tcp_in_flange = check_transform(tcp_in_flange, "collision model: tcp_in_flange").copy()
        self.margin_m, self.self_margin_m = float(margin_m), float(self_margin_m)
        self._model = robot.model
        self._local = threading.local()  # per thread: its own Pinocchio data (see _data)
        self.bodies: list[Body] = self._robot_bodies() + self._tool_bodies(tool_shapes)
        self._n_moving = len(self.bodies)
        self.bodies += self._cell_bodies(cell)
        check_body_names(self.bodies)
        moving = self.bodies[: self._n_moving]
        self._joints = sorted({b.joint for b in moving})
        self._joint_slot = np.array([self._joints.index(b.joint) for b in moving], dtype=int)
        self._body_joints = np.array([b.joint for b in moving], dtype=np.int64)  # Pinocchio's joint index
        self._joint_T_shape = np.array(  # shape pose in its joint's frame: frame placement, then shape
            [self._model.frames[b.frame_id].placement.homogeneous @ b.link_T_shape for b in moving]
        )
        self._centre = np.array([b.centre for b in self.bodies])
        self._half = np.array([b.half_extent for b in self.bodies])
        self._poses = np.array([b.link_T_shape for b in self.bodies])  # cell poses are final
        self._aabb_c, self._aabb_h = world_aabb(self._poses, self._centre, self._half)
        self._select_pairs()
        self.queries = 0
        self._q: Array | None = None
        self._exact: dict[int, Contact] = {}  # pairs measured at the current configuration
        self._motion: Array | None = None
        self._recent_poses: dict[bytes, Array] = {}  # moving_poses of the last few joint paths
        self._recent_boxes: list[tuple[Array, Array]] = []  # box_bounds of those poses, by identity
        self._recent_lock = threading.Lock()  # held while _recent_poses or _recent_boxes is read or changed

    # ---- building ----------------------------------------------------------------------------

    @classmethod
    def for_problem(cls, problem: Problem, robot: Robot) -> CollisionModel:
        """The model of a problem's robot placement, tool shapes, cell and ``[collision]`` margins."""
        return cls(
            robot,
            problem.robot.base_in_world,
            problem.tool.tcp_in_flange,
            problem.tool.collision,
            problem.cell,
            margin_m=problem.collision.margin_m,
            self_margin_m=problem.collision.self_margin_m,
        )

    def _robot_bodies(self) -> list[Body]:
        where = f"robot {self.robot.spec.name!r}"
        bodies = []
        for s in self.robot.collision_shapes():
            fid = self.robot.frame_id(s.link)
            bodies.append(link_body(s, fid, int(self._model.frames[fid].parentJoint), where))
        return bodies

    def _tool_bodies(self, shapes: tuple[Shape, ...]) -> list[Body]:
        fid = self.robot.flange_id
        link = self.robot.spec.flange_frame
        joint = int(self._model.frames[fid].parentJoint)
        return [
            shape_body(s, name=f"tool:{s.name}", kind="tool", link=link, frame_id=fid, joint=joint)
            for s in shapes
        ]

    def _cell_bodies(self, shapes: tuple[Shape, ...]) -> list[Body]:
        return [shape_body(s, name=s.name, kind="cell", link=None, frame_id=-1, joint=-1) for s in shapes]

    def _select_pairs(self) -> None:
        key = structure_key(self.robot, self.base_in_world, self.self_margin_m, self.bodies)
        known = recall(key)
        if known is not None and known.robot is self.robot and known.pin_model is self._model:
            for level, msg, args in known.notes:
                log.log(level, msg, *args)
        else:
            known = self._selection()
            remember(key, known)
        self._kept = known
        self.kept_hulls = known.hulls
        kept = known.kept
        self._pa, self._pb, self._self, self.pairs = indexed_pairs(known, self.bodies)
        self._margin = np.where(self._self, self.self_margin_m, self.margin_m)
        hulled = np.array([b.hull is not None and b.kind == "cell" for b in self.bodies], dtype=bool)
        mesh = np.array([b.is_mesh for b in self.bodies], dtype=bool)
        self._hulled = hulled[self._pb]
        self._normals = np.full((len(kept), 3), np.nan)  # last witness normal per pair, world
        self._bounded = ~(mesh[self._pa] | mesh[self._pb])
        self.excluded = known.excluded

    def _selection(self) -> Kept:
        """The pairs to check by the rules of :mod:`refine.collision.pairs`, and the others with their reasons."""
        self._place_all(pin.neutral(self._model))
        axes = joint_axes(self._model, self.base_in_world)
        matrix = self.robot.self_collision()
        kept: list[tuple[int, int]] = []
        excluded: list[tuple[str, str, str]] = []
        notes: list[tuple[int, str, tuple]] = []
        for i in range(self._n_moving):
            for j in range(i + 1, len(self.bodies)):
                a, b = self._order(i, j)
                A, B = self.bodies[a], self.bodies[b]
                why = exclusion(
                    A, B, self._poses[a], self._poses[b], self._model, axes, self.self_margin_m, matrix
                )
                if why is None:
                    kept.append((a, b))
                    continue
                excluded.append((A.label, B.label, why))
                notes.append((logging.DEBUG, "not checking %s vs %s: %s", (A.label, B.label, why)))
                if why == "constant distance":
                    d = signed_distance(A, self._poses[a], B, self._poses[b])[0]
                    level = logging.WARNING if d < self.self_margin_m else logging.INFO
                    msg = "%s and %s are %.1f mm apart at every configuration (self margin %.1f mm): not checked"
                    notes.append((level, msg, (A.label, B.label, d * 1e3, self.self_margin_m * 1e3)))
        for level, msg, args in notes:
            log.log(level, msg, *args)
        return Kept(self.robot, self._model, kept, tuple(excluded), notes)

    def _order(self, i: int, j: int) -> tuple[int, int]:
        """Body first: the tool before links, the distal link before the proximal one."""
        bi, bj = self.bodies[i], self.bodies[j]
        if bj.kind == "cell" or bi.kind == "tool":
            return i, j
        if bj.kind == "tool" or bj.joint > bi.joint:
            return j, i
        return i, j

    # ---- placing -----------------------------------------------------------------------------

    def _check_q(self, q: ArrayLike) -> Array:
        q = np.asarray(q, dtype=float)
        if q.shape != (self.robot.nq,) or not np.all(np.isfinite(q)):
            raise InputError(f"collision model: q must be {self.robot.nq} finite joint values [rad], got {q}")
        return q

    def _update(self, q: ArrayLike, poses: Array | None = None) -> None:
        q = np.asarray(q, dtype=float)
        if self._q is not None and q.shape == self._q.shape and bool((q == self._q).all()):
            return  # checked when it was set
        q = self._check_q(q)
        n = self._n_moving
        self._poses[:n] = self.moving_poses(q[None])[0] if poses is None else poses
        self._boxed = False  # the moving bodies' world-aligned boxes, placed when needed
        self._placed = np.zeros(len(self.bodies), dtype=bool)
        self._placed[n:] = True
        self._q = q.copy()
        self._exact = {}

    def moving_poses(self, qs: ArrayLike) -> Array:
        """World poses (N, M, 4, 4) of the M moving bodies' shape frames for joint rows qs (N, n).

        The answer for a path of several rows is kept for the next few calls with the same joints
        (the proof, the check and the figures of one path each ask for them), read-only. Threads
        may call it at once: the kept answers are locked, and each thread has its own Pinocchio data.
        """
        qs = np.asarray(qs, dtype=float)
        key = qs.shape[0].to_bytes(8, "little") + qs.tobytes() if qs.ndim == 2 and len(qs) > 1 else None
        if key is not None:
            with self._recent_lock:
                known = self._recent_poses.get(key)
            if known is not None:
                return known
        poses = self._moving_poses(qs)
        if key is not None:
            poses.flags.writeable = False
            with self._recent_lock:
                self._recent_poses[key] = poses
                while len(self._recent_poses) > RECENT_PATHS:
                    del self._recent_poses[next(iter(self._recent_poses))]
        return poses

    @property
    def _data(self) -> pin.Data:
        """This thread's Pinocchio data of the robot's model (made on its first use in the thread)."""
        data = getattr(self._local, "data", None)
        if data is None:
            data = self._local.data = self._model.createData()
        return data

    def _moving_poses(self, qs: Array) -> Array:
        chain = getattr(self.robot, "chain", None)
        if chain is not None and len(qs) >= chain.min_rows:
            placed = chain.body_poses(qs, self.base_in_world, self._body_joints, self._joint_T_shape)
            if placed is not None:  # compiled: the placement on the joints done with the joints
                return placed
            T_joint = chain.joint_placements(qs, self._joints)
            return self.base_in_world @ T_joint[:, self._joint_slot] @ self._joint_T_shape
        T_joint = np.empty((len(qs), len(self._joints), 4, 4))
        for k, q in enumerate(qs):
            pin.forwardKinematics(self._model, self._data, q)
            oMi = self._data.oMi
            T_joint[k] = [oMi[j].homogeneous for j in self._joints]
        return self.base_in_world @ T_joint[:, self._joint_slot] @ self._joint_T_shape

    def box_bounds(self, poses: Array, columns: ArrayLike | None = None) -> Array:
        """Per row of moving-body poses (N, M, 4, 4), lower bounds [m] on every pair's distance, (N, P).

        The gap between the world-aligned boxes of the two bodies; ``-inf`` where they overlap
        (the bodies may then penetrate). ``columns``: the pairs to bound (indices into
        :attr:`pairs`), (C,), for an answer (N, C); all if None. For poses kept by
        :meth:`moving_poses` (read-only: the same array for the same joints) the answer for every
        pair is kept beside them and returned again, read-only, so the check, the proof and the
        figures of one path box it once.
        """
        if columns is not None:
            columns = np.asarray(columns, dtype=int)
            return self._box_bounds(poses, self._pa[columns], self._pb[columns])
        if poses.flags.writeable:
            return self._box_bounds(poses, self._pa, self._pb)
        with self._recent_lock:
            known = next((boxes for kept, boxes in self._recent_boxes if kept is poses), None)
        if known is not None:
            return known
        boxes = self._box_bounds(poses, self._pa, self._pb)
        boxes.flags.writeable = False
        with self._recent_lock:  # the poses are held, so their identity stays theirs
            self._recent_boxes.append((poses, boxes))
            del self._recent_boxes[:-RECENT_PATHS]
        return boxes

    def _box_bounds(self, poses: Array, pa: Array, pb: Array) -> Array:
        """The box gaps (N, len(pa)) [m] of the body pairs (pa, pb) at poses (N, M, 4, 4), -inf for none."""
        return box_gaps(poses, self._centre, self._half, self._aabb_c, self._aabb_h, pa, pb)

    def _place_all(self, q: Array) -> None:
        self._q = None
        self._update(q)
        for k in range(self._n_moving):
            self._ensure_placed(k)

    def _ensure_placed(self, k: int) -> None:
        if not self._placed[k]:
            place(self.bodies[k], self._poses[k])
            self._placed[k] = True

    def _gaps(self) -> Array:
        """Lower bounds [m] on the distance of every checked pair, from the world-aligned boxes."""
        if not self._boxed:
            n = self._n_moving
            self._aabb_c[:n], self._aabb_h[:n] = world_aabb(self._poses[:n], self._centre[:n], self._half[:n])
            self._boxed = True
        c, h = self._aabb_c, self._aabb_h
        d = np.maximum(np.abs(c[self._pa] - c[self._pb]) - h[self._pa] - h[self._pb], 0.0)
        return np.sqrt(np.einsum("ij,ij->i", d, d))

    def _pair(self, k: int) -> Contact:
        if k in self._exact:  # measured at this configuration already
            return self._exact[k]
        a, b = int(self._pa[k]), int(self._pb[k])
        self._ensure_placed(a)
        self._ensure_placed(b)
        A, B = self.bodies[a], self.bodies[b]
        d, p_a, p_b, n = signed_distance(A, self._poses[a], B, self._poses[b])
        self.queries += 1
        self._normals[k] = n
        self._exact[k] = Contact(
            body=A.name,
            other=B.name,
            distance_m=d,
            point_body=p_a,
            point_other=p_b,
            normal=n,
            link=str(A.link),
            self_pair=bool(self._self[k]),
            other_link=B.link,
            margin_m=float(self._margin[k]),
            body_shape=A.shape,
            other_shape=B.shape,
        )
        return self._exact[k]

    # ---- per-pair figures (the dense check's conservative advancement) ------------------------

    @property
    def pair_margins(self) -> Array:
        """The margin [m] of every checked pair, in the order of :attr:`pairs`, (P,)."""
        return self._margin.copy()

    @property
    def pair_motion(self) -> Array:
        """Per checked pair and joint, the motion bound R [m/rad], (P, n): see :mod:`refine.collision.motion`.

        Along a joint segment ``dq`` no point of either body of pair p moves further relative to
        the other body than ``|dq| @ pair_motion[p]``.
        """
        if self._motion is None:
            if self._kept.motion is None:  # the first model of its robot, moving bodies and pairs
                pairs = [(self.bodies[a], self.bodies[b]) for a, b in zip(self._pa, self._pb, strict=True)]
                self._kept.motion = pair_reach(self._model, pairs)
                self._kept.motion.flags.writeable = False
            self._motion = self._kept.motion
        return self._motion

    @property
    def joint_reach(self) -> Array:
        """:func:`refine.collision.motion.joint_reach` [m] (n,), read-only: once per robot and moving bodies."""
        if self._kept.reach is None:  # the first model of its robot and moving bodies (see ``kept.py``)
            self._kept.reach = joint_reach(self)
            self._kept.reach.flags.writeable = False
        return self._kept.reach

    def pair_bound(
        self, q: ArrayLike, k: int, poses: Array | None = None, *, plane: bool = False
    ) -> tuple[float, bool]:
        """A lower bound [m] on pair k's signed distance at joints q, and whether it is the distance.

        A pair against a cell mesh is first bounded by the distance to the mesh's convex hull (a
        fraction of the cost of the mesh query); with ``plane``, a pair of primitives by the gap
        along the last witness normal it had (no FCL call). Any other pair, or one whose bound is
        not positive, is measured.
        """
        self._update(q, poses)
        if k not in self._exact:
            bound = self._hull_bound(k) if self._hulled[k] else -math.inf
            if bound <= 0.0 and plane:
                bound = self._plane_bound(k)
            if bound > 0.0:
                return bound, False
        return self._pair(k).distance_m, True

    def measured(self) -> dict[int, float]:
        """Signed distances [m] of the pairs measured at the current configuration, by pair index."""
        return {k: c.distance_m for k, c in self._exact.items()}

    def witnesses(self, q: Array) -> dict[int, tuple[float, Array]]:
        """The pairs measured at joints q (n,) so far, by pair index: signed distance [m] and unit normal.

        Empty when the model has been placed elsewhere since (nothing measured at q is then known).
        """
        if self._q is None or not np.array_equal(self._q, q):
            return {}
        return {k: (c.distance_m, c.normal) for k, c in self._exact.items()}

    def take_witnesses(self, found: dict[int, tuple[float, Array]]) -> None:
        """Take the unit normals of ``found`` (:meth:`witnesses` at joints measured before) as the last.

        The pairs' last witness normals (what :meth:`plane_bounds` reads) as measuring them there
        again would leave them, without the FCL calls.
        """
        for k, (_, n) in found.items():
            self._normals[k] = n

    def pair_distance(self, q: ArrayLike, k: int, poses: Array | None = None) -> float:
        """The signed distance [m] of checked pair k (index into :attr:`pairs`) at joints q [rad] (n,).

        ``poses``: the moving bodies' poses at q from :meth:`moving_poses`, (M, 4, 4), or None.
        """
        self._update(q, poses)
        return self._pair(k).distance_m

    # ---- queries -----------------------------------------------------------------------------

    def contacts(self, q: ArrayLike, query_distance_m: float) -> list[Contact]:
        """Every checked pair closer than ``query_distance_m`` at joints q, nearest first.

        Args:
            q: joints [rad], shape (n,).
            query_distance_m: report pairs whose signed distance is below this [m]; ``inf`` for all
                checked pairs, 0 for the pairs in contact, -0.01 for those 1 cm deep or more.
        """
        if math.isnan(query_distance_m):
            raise InputError("contacts: query_distance_m must be a number [m], got nan")
        self._update(q)
        near = [int(k) for k in np.flatnonzero(self._gaps() <= max(query_distance_m, 0.0))]
        near = [k for k in near if not (self._hulled[k] and self._hull_bound(k) >= query_distance_m)]
        found = [c for c in (self._pair(k) for k in near) if c.distance_m < query_distance_m]
        return sorted(found, key=lambda c: c.distance_m)

    def _plane_bound(self, k: int) -> float:
        """A lower bound [m] on pair k's distance from the last witness normal it had.

        For any unit n, two bodies are at least as far apart as the gap between them along n
        (``-reach_A(-n) - reach_B(n)``); between close samples the last normal keeps that gap near
        the distance, so a far pair needs no FCL call. ``-inf`` for meshes and unqueried pairs.
        """
        n = self._normals[k]
        if not self._bounded[k] or np.isnan(n[0]):
            return -math.inf
        a, b = int(self._pa[k]), int(self._pb[k])
        return -self.bodies[a].reach(self._poses[a], -n) - self.bodies[b].reach(self._poses[b], n)

    def plane_bounds(
        self, k: int, poses: Array, normals: Array | None = None, rows: NDArray[np.intp] | None = None
    ) -> Array | None:
        """Lower bounds [m] on pair k's distance at rows of moving-body poses (K, M, 4, 4), (K,).

        The gap along the pair's last witness normal (:meth:`_plane_bound`) at every row at once,
        or along ``normals``: one unit vector (3,) or one per row (K, 3) (any unit vector gives a
        lower bound); None for a pair with a mesh or, without ``normals``, one never measured.
        ``rows``: the rows of ``poses`` to bound (all if None), one per normal; only the pair's
        two bodies' poses are read there, not every body's.
        """
        n = self._normals[k] if normals is None else np.asarray(normals, dtype=float)
        if not self._bounded[k] or np.isnan(n).any():
            return None
        a, b = int(self._pa[k]), int(self._pb[k])
        m, at = self._n_moving, slice(None) if rows is None else rows
        count = len(poses) if rows is None else len(rows)
        Ta = poses[at, a] if a < m else np.broadcast_to(self._poses[a], (count, 4, 4))
        Tb = poses[at, b] if b < m else np.broadcast_to(self._poses[b], (count, 4, 4))
        return -self.bodies[a].reach_many(Ta, -n) - self.bodies[b].reach_many(Tb, n)

    @property
    def self_pairs(self) -> NDArray[np.bool_]:
        """Which checked pairs are of two of the robot's own bodies (links, tool shapes), (P,)."""
        return self._self.copy()

    def pair_bodies(self, k: int) -> tuple[int, int]:
        """Pair k's two bodies as indices into :attr:`bodies` (the moving ones first, as in the poses)."""
        return int(self._pa[k]), int(self._pb[k])

    def _hull_bound(self, k: int) -> float:
        a, b = int(self._pa[k]), int(self._pb[k])
        self._ensure_placed(a)
        return hull_bound(self.bodies[a], self._poses[a], self.bodies[b], self._poses[b])

    def nearest_pairs(
        self, q: ArrayLike, poses: Array | None = None, bounds: Array | None = None
    ) -> tuple[Contact | None, Contact | None]:
        """The pair with the least distance and the pair with the least clearance at joints q.

        Pairs are visited by their broad-phase lower bound, and the search stops once no bound left
        could beat either answer, so far pairs cost no FCL call; pairs already measured at q are
        not measured again. None, None when nothing is checked.

        Args:
            q: joints [rad], (n,).
            poses: the moving bodies' poses at q from :meth:`moving_poses`, (M, 4, 4), or None.
            bounds: the pairs' box bounds at q from :meth:`box_bounds` (P,), or None.
        """
        self._update(q, poses)
        if len(self._pa) == 0:
            return None, None
        gaps = self._gaps() if bounds is None else np.maximum(bounds, 0.0)
        bound = np.where(gaps > 0.0, gaps, -np.inf)  # boxes that overlap bound nothing: may penetrate
        top_margin = float(self._margin.max())
        known = list(self._exact.values())
        by_distance = min(known, key=lambda c: c.distance_m, default=None)
        by_clearance = min(known, key=lambda c: c.clearance_m, default=None)

        def hopeless(lower: float, margin: float) -> bool:
            return (
                by_distance is not None
                and by_clearance is not None
                and lower >= by_distance.distance_m
                and lower - margin >= by_clearance.clearance_m
            )

        # as Python floats and bools: the loop reads them quicker than numpy scalars
        lowers, margins, hulled = bound.tolist(), self._margin.tolist(), self._hulled.tolist()
        for k in np.argsort(gaps).tolist():
            if hopeless(lowers[k], top_margin):
                break  # visited by bound: no pair left can beat either answer
            if k in self._exact:
                continue
            if (
                hopeless(lowers[k], margins[k])
                or (hulled[k] and hopeless(self._hull_bound(k), margins[k]))
                or hopeless(self._plane_bound(k), margins[k])
            ):
                continue
            c = self._pair(k)
            if by_distance is None or c.distance_m < by_distance.distance_m:
                by_distance = c
            if by_clearance is None or c.clearance_m < by_clearance.clearance_m:
                by_clearance = c
        return by_distance, by_clearance

    def min_distance(self, q: ArrayLike) -> tuple[float, str, str]:
        """Smallest signed distance [m] over the checked pairs at joints q, and the pair's names."""
        c = self.nearest_pairs(q)[0]
        return (math.inf, "", "") if c is None else (c.distance_m, c.body, c.other)

    def point_jacobian(self, q: ArrayLike, link: str, point_world: ArrayLike) -> Array:
        """Jacobian (3, n) of a point fixed to ``link``, world axes: d(point) / dq [m/rad]."""
        q = self._check_q(q)
        pin.computeJointJacobians(self._model, self._data, q)
        return self._point_jacobian(link, point_world)

    def _point_jacobian(self, link: str, point_world: ArrayLike) -> Array:
        if not self._model.existFrame(link):
            names = sorted({b.link for b in self.bodies if b.link})
            raise InputError(f"point_jacobian: no link {link!r}; links with collision bodies: {names}")
        fid = self._model.getFrameId(link)
        oMf = pin.updateFramePlacement(self._model, self._data, fid)
        J = pin.getFrameJacobian(self._model, self._data, fid, pin.LOCAL_WORLD_ALIGNED)
        R_wb = self.base_in_world[:3, :3]
        p_base = R_wb.T @ (np.asarray(point_world, dtype=float) - self.base_in_world[:3, 3])
        r = p_base - oMf.translation
        return R_wb @ (J[:3] - np.cross(r, J[3:].T).T)

    def distance_gradients(self, q: ArrayLike, contacts: list[Contact]) -> Array:
        """Gradients (m, n) of the contacts' signed distances w.r.t. q [m/rad], one row each."""
        q = self._check_q(q)
        pin.computeJointJacobians(self._model, self._data, q)
        rows = np.zeros((len(contacts), self.robot.nq))
        for i, c in enumerate(contacts):
            J_other = self._point_jacobian(c.other_link, c.point_other) if c.other_link else None
            rows[i] = linearised_distance(c, self._point_jacobian(c.link, c.point_body), J_other)
        return rows
