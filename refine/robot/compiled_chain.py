"""The robot's batch kinematics compiled to C: flange and TCP poses and Jacobians, every joint's placement.

:class:`~refine.robot.chain.BatchChain` costs NumPy about 0.3 ms a batch and 1 µs a row. The same
recursion written for one row on CasADi ``SX`` scalars (:meth:`BatchChain.row_frame`,
:meth:`BatchChain.row_joint_placements`: the chain's own joint placements and axes, not the
optimiser's symbolic kinematics, so the verifier stays independent of the NLP) is written out as C
by CasADi's code generator, with a loop over the rows in C around it, and compiled once per robot
model into a shared library (:mod:`refine.native`: the cache folder, the compiler,
``REFINE_COMPILE=0``). The library is called through :mod:`ctypes` on the NumPy arrays themselves:
the joint rows are read and the answers written in place, nothing is copied or converted.

The functions (:mod:`refine.robot.chain_source` writes them): the flange's placement, the
flange's placement with its Jacobian (Pinocchio's ``LOCAL_WORLD_ALIGNED``), every joint's
``data.oMi``, the TCP's pose in the world (the robot placed by ``T_world_base``, the tool by
``T_flange_TCP``, both arguments of the call) with and without its Jacobian (what
:class:`~refine.robot.kinematics.TcpKinematics` composes in NumPy otherwise), and bodies fixed on
the joints placed in the world (the collision model's moving shapes); a stationary tool's TCP
seen from the part the robot holds, with its Jacobian (``tcp_frames(..., tool_in_world)``); a
damped least-squares IK step toward TCP targets (:meth:`CompiledChain.ik_steps`), the whole
iterated IK of each row (:meth:`CompiledChain.ik_solve`: a redundant arm's null-space pull, a
stationary tool) and determinants of 6 × 6 matrices (:meth:`CompiledChain.dets6`). Any number of rows is one
call; each call's work memory is on the C stack, so threads may call at once (:mod:`ctypes` lets
go of the GIL for the call). Any other frame, and :meth:`CompiledChain.axis_frames`, are the NumPy
chain's.

When a library is loaded it is checked once against Pinocchio (``forwardKinematics`` and
``computeFrameJacobian``; the IK step's error against ``log3`` and its step against NumPy's solve,
one iteration of the whole IK with its pull against NumPy's, the determinants against NumPy's) at :data:`CHECK_ROWS` configurations; a difference above
:data:`CHECK_TOLERANCE` is logged as a warning and the chain stays NumPy's, as it does without a
compiler, with ``REFINE_COMPILE=0`` or when compiling fails. The library is looked for on the
first evaluation (not when the robot is made), once per :class:`CompiledChain`.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import logging
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from refine.native import (
    BoundedCache,
    cache_dir,
    cached_library,
    compiler,
    compiler_version,
)
from refine.robot.chain import MIN_ROWS, BatchChain
from refine.robot.chain_library import FUNCTIONS, ChainLibrary
from refine.robot.chain_source import PREFIX, chain_source
from refine.types import Array

log = logging.getLogger(__name__)

COMPILED_MIN_ROWS = 4
"""Rows from which the compiled chain beats Pinocchio's row loop: about 7 µs a call plus 0.2-0.3 µs a
row, against Pinocchio's 3.5 µs a row with the Jacobian and 2 µs without it
(``benchmarks/batch_kinematics.py``)."""
CHECK_ROWS = 5
"""Configurations at which a loaded library is compared with Pinocchio."""
CHECK_TOLERANCE = 1e-12
"""The largest difference [m, rad, 1] from Pinocchio a loaded library may show in its check."""
FLAGS = ("-O3", "-fPIC", "-shared", "-ffp-contract=off")
"""-O3: the bodies' 4 × 4 products vectorised (3x faster than -O1, compiling about as long: 0.3-1 s);
no fused multiply-adds: the pose alone and the pose beside its Jacobian round alike. Nothing
reassociates a sum (no -ffast-math)."""
LOADED_MAX = 16
"""Chain libraries kept loaded in one process (one per robot model)."""

_SOURCES = tuple(
    Path(__file__).with_name(n)
    for n in ("compiled_chain.py", "chain_source.py", "chain_library.py", "chain.py")
)
_loaded = BoundedCache(LOADED_MAX)
# a base and a tool placement of no special orientation, for the load check [m]
_CHECK_BASE = pin.SE3(pin.exp3(np.array([0.3, -0.2, 0.9])), np.array([0.4, -0.3, 0.2])).homogeneous
_CHECK_TCP = pin.SE3(pin.exp3(np.array([-0.5, 0.1, 0.25])), np.array([0.02, -0.01, 0.3])).homogeneous
_CHECK_WORLD = pin.SE3(pin.exp3(np.array([1.2, -0.4, 0.3])), np.array([0.5, 0.6, 0.7])).homogeneous


class CompiledChain:
    """:class:`~refine.robot.chain.BatchChain`'s evaluations of a model, compiled where it can be.

    Answers as the NumPy chain (``frame``, ``joint_placements``, ``axis_frames``), to rounding
    (``tests/test_compiled_chain.py``); :attr:`min_rows` is the batch size from which either
    beats Pinocchio's row loop.
    """

    def __init__(self, model: pin.Model, flange_id: int, chain: BatchChain, compile: bool = True) -> None:
        self.model = model
        self.flange_id = int(flange_id)
        self.numpy = chain
        self.nq = chain.nq
        self._njoints = int(model.njoints)
        self._lock = threading.Lock()
        self._library: ChainLibrary | None = None
        self._compile = compile
        self._resolved = not compile  # without compiling: NumPy's chain from the start

    @classmethod
    def from_model(cls, model: pin.Model, flange_id: int, compile: bool = True) -> CompiledChain | None:
        """The chain of ``model`` (the flange: frame ``flange_id``), or None where BatchChain refuses it.

        ``compile=False``: NumPy's evaluations whatever the compiler (for comparisons).
        """
        chain = BatchChain.from_model(model)
        return None if chain is None else cls(model, flange_id, chain, compile)

    def __getstate__(self) -> dict[str, Any]:
        # the loaded library and the lock belong to this process; the other side looks again
        return {**self.__dict__, "_lock": None, "_library": None, "_resolved": not self._compile}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._lock = threading.Lock()

    @property
    def compiled(self) -> bool:
        """Whether the evaluations run compiled (found or built on first use), else in NumPy."""
        return self._lib() is not None

    @property
    def min_rows(self) -> int:
        """Rows from which this chain beats Pinocchio's row loop (:data:`COMPILED_MIN_ROWS` or ``MIN_ROWS``)."""
        return COMPILED_MIN_ROWS if self._lib() is not None else MIN_ROWS

    def frame(self, qs: Array, frame_id: int, jacobian: bool = True) -> tuple[Array, Array | None]:
        """:meth:`BatchChain.frame`: placements (N, 4, 4) [m] and, with ``jacobian``, Jacobians (N, 6, nv)."""
        lib = self._lib()
        if lib is None or frame_id != self.flange_id:
            return self.numpy.frame(qs, frame_id, jacobian)
        qs = self._rows(qs)
        T = np.empty((len(qs), 4, 4))
        if not jacobian:
            lib.call("fk", qs, T)
            return T, None
        J = np.empty((len(qs), 6, self.nq))
        lib.call("fkj", qs, T, J)
        return T, J

    def tcp_frames(
        self,
        qs: Array,
        base_in_world: Array,
        tcp_in_flange: Array,
        jacobian: bool = True,
        tool_in_world: Array | None = None,
    ) -> tuple[Array, Array | None] | None:
        """The TCP's poses ``T_world_base · T_base_flange(q) · T_flange_TCP`` (N, 4, 4) [m] and Jacobians.

        The Jacobian (N, 6, nv) as ``TcpKinematics.jacobian``: the TCP's linear velocity and the
        angular velocity, world axes, linear rows first. With ``tool_in_world`` (a stationary
        tool's ``T_world_TCP``; ``tcp_in_flange`` then places the held part) the tool's TCP seen
        from the part, ``(T_world_base · T_base_flange · T_flange_part)⁻¹ · T_world_TCP``, and its
        Jacobian in the part's frame (:func:`refine.robot.chain_source.stationary`). None when
        the chain runs in NumPy (the caller then composes :meth:`frame`'s flange).
        """
        lib = self._lib()
        if lib is None:
            return None
        qs = self._rows(qs)
        fixed = self._placements(base_in_world, tcp_in_flange, tool_in_world)
        name = "tcp" if tool_in_world is None else "stat"
        T = np.empty((len(qs), 4, 4))
        if not jacobian:
            lib.call(name, qs, T, fixed=fixed)
            return T, None
        J = np.empty((len(qs), 6, self.nq))
        lib.call(name + "j", qs, T, J, fixed=fixed)
        return T, J

    @staticmethod
    def _placements(*placements: Array | None) -> tuple[Array, ...]:
        """The given (4, 4) placements as C-contiguous float64 arrays (the Nones left out)."""
        fixed = tuple(np.ascontiguousarray(a, dtype=float) for a in placements if a is not None)
        if any(a.shape != (4, 4) for a in fixed):
            raise ValueError(f"placements: expected (4, 4) each, got {[a.shape for a in fixed]}")
        return fixed

    def body_poses(self, qs: Array, base_in_world: Array, joints: Array, joint_T_body: Array) -> Array | None:
        """World poses (N, M, 4, 4) [m] of M bodies fixed on joints: ``T_world_base · oMi[joints[m]] · joint_T_body[m]``.

        ``joints``: each body's joint index (M,); ``joint_T_body``: its placement on the joint
        (M, 4, 4). None when the chain runs in NumPy (the caller composes :meth:`joint_placements`).
        """
        lib = self._lib()
        if lib is None:
            return None
        qs = self._rows(qs)
        joints = np.ascontiguousarray(joints, dtype=np.int64)
        local = np.ascontiguousarray(joint_T_body, dtype=float)
        base = np.ascontiguousarray(base_in_world, dtype=float)
        if joints.ndim != 1 or local.shape != (len(joints), 4, 4) or base.shape != (4, 4):
            raise ValueError(
                f"bodies: expected (M,), (M, 4, 4), (4, 4), got {joints.shape}, {local.shape}, {base.shape}"
            )
        if len(joints) and not (0 <= joints.min() and joints.max() < self._njoints):
            raise ValueError(f"bodies: joint indices 0..{self._njoints - 1}, got {joints.tolist()}")
        out = np.empty((len(qs), len(joints), 4, 4))
        lib.bodies(qs, base, joints, local, out)
        return out

    def ik_steps(
        self,
        qs: Array,
        base_in_world: Array,
        tcp_in_flange: Array,
        targets: Array,
        damping: float,
        T: Array,
        J: Array,
        given: bool = False,
        tol: float = 0.0,
    ) -> tuple[Array, Array, Array, Array] | None:
        """One damped least-squares IK step per row toward TCP targets, or None when the chain runs in NumPy.

        Per row of ``qs`` (N, nv) [rad]: the TCP pose ``T`` (N, 4, 4) and Jacobian ``J`` (N, 6, nv)
        as :meth:`tcp_frames` (written into the given C-contiguous arrays; with ``given`` read from
        them instead), the pose error ``e`` (N, 6) toward ``targets`` (N, 4, 4) [m, rad] as
        :func:`refine.robot.kinematics.solve_ik_batch` forms it (the position difference and the
        rotation vector of ``R_target Rᵀ`` by :func:`refine.robot.kinematics.rotation_vectors`'
        formula, without its branch near π), its norm (N,), the step ``Jᵀ (J Jᵀ + λ² I)⁻¹ e``
        (N, nv) [rad] with ``λ = damping`` (> 0; 0 where the norm is under ``tol``, a row the
        caller stops) and the rotation angle of ``R_target Rᵀ`` (N,)
        [rad] (where it exceeds ``π - 1e-3`` the caller takes the rotation vector otherwise).

        Returns:
            ``e``, the norms, the steps and the angles.
        """
        lib = self._lib()
        if lib is None:
            return None
        qs = self._rows(qs)
        fixed = [np.ascontiguousarray(a, dtype=float) for a in (base_in_world, tcp_in_flange, targets)]
        n = len(qs)
        if fixed[0].shape != (4, 4) or fixed[1].shape != (4, 4) or fixed[2].shape != (n, 4, 4):
            raise ValueError(f"ik_steps: placements (4, 4), (4, 4) and targets ({n}, 4, 4) expected")
        if T.shape != (n, 4, 4) or J.shape != (n, 6, self.nq) or not damping > 0.0:
            raise ValueError(f"ik_steps: T ({n}, 4, 4), J ({n}, 6, {self.nq}) and damping > 0 expected")
        e, norm, dq, theta = np.empty((n, 6)), np.empty(n), np.empty((n, self.nq)), np.empty(n)
        lib.ik(qs, *fixed, float(damping), float(tol), bool(given), T, J, e, norm, dq, theta)
        return e, norm, dq, theta

    def ik_solve(
        self,
        qs: Array,
        kinematics: tuple[Array, Array, Array | None],
        targets: Array,
        bounds: tuple[Array, Array],
        damping: float,
        tol: float,
        gain: float,
        max_iterations: int,
        stall: tuple[int, float] | None,
        chained: tuple[float, float, Array, Array, int] | None = None,
        axis_only: bool = False,
    ) -> tuple[Array, Array, Array, Array, Array] | None:
        """Damped least-squares IK toward TCP targets, every row iterated in C; None in NumPy.

        Per start row of ``qs`` (N, nv) [rad], clipped to ``bounds`` (lower, upper (nv,) [rad],
        infinite for none): ``solve_ik``'s iterations (``stall`` None) or ``solve_ik_batch``'s
        (``stall = (iterations, keep)``: a row stops once its error has not fallen under ``keep``
        times its best for that many iterations) of :mod:`refine.robot.kinematics`, the error as
        :meth:`ik_steps` forms it, the step ``Jᵀ (J Jᵀ + λ² I)⁻¹ e`` (``λ = damping`` > 0) plus
        ``gain`` times the pull to mid-range ``(mid - q) / half²`` (0 unbounded) less its part in
        the task, scaled to at most 0.3 rad, clipped. ``kinematics``: ``T_world_base``,
        ``T_flange_TCP``, a stationary tool's ``T_world_TCP`` or None (:meth:`tcp_frames`).
        ``axis_only``: the position and the tool's z axis alone are asked for, the error and the
        Jacobian's angular rows as :func:`refine.robot.kinematics.axis_error` forms them (the spin
        about the current axis free); the angle flagged near π is the one between the axes.

        ``chained``: ``(predict, give_up, q, err, first)`` to chain ``solve_ik`` along the targets
        (N, 4, 4) instead, ``qs`` (1, nv) the first row's start: rows ``first`` to N - 1 in turn
        into ``q`` (N, nv) and ``err`` (N,) (C-contiguous float64; the rows before ``first``
        solved already), each from the last answer plus the last step where no joint moved more
        than ``predict`` [rad] in it; the chain stops at a flagged row (1), or after a row whose
        joints moved more than ``give_up`` [rad] from the row before (flag 2).

        Returns:
            the joints (N, nv) [rad], the last pose error norms (N,), the TCP poses (N, 4, 4) and
            Jacobians (N, 6, nv, the whole, also with ``axis_only``) at those joints, and a flag per row (N,), 1 where the rotation
            error came within 1e-3 rad of π: that row's answer is not to be used (chained, the
            rows after a flagged one are not solved).
        """
        lib = self._lib()
        if lib is None:
            return None
        qs = self._rows(qs)
        fixed = self._placements(*kinematics)
        world = None if kinematics[2] is None else fixed[2]
        targets = np.ascontiguousarray(targets, dtype=float)
        n = len(targets) if chained is not None else len(qs)
        predict, give_up, q, err, first = (
            (0.0, 0.0, np.empty((n, self.nq)), np.empty(n), 0) if chained is None else chained
        )
        if not (
            len(qs) in (1, n) and 0 <= first <= n and _writable(q, (n, self.nq)) and _writable(err, (n,))
        ):
            raise ValueError(
                f"ik_solve: one start, joints ({n}, {self.nq}), errors ({n},), a first row 0..{n}"
            )
        lower, upper = (np.ascontiguousarray(np.broadcast_to(b, (self.nq,)), dtype=float) for b in bounds)
        if targets.shape != (n, 4, 4) or not damping > 0.0 or max_iterations < 0:
            raise ValueError(f"ik_solve: targets ({n}, 4, 4), damping > 0 and max_iterations >= 0 expected")
        with np.errstate(invalid="ignore"):  # unbounded joints have no mid-range
            mid, half = 0.5 * (lower + upper), 0.5 * (upper - lower)
        its, keep = (0, 0.0) if stall is None else stall
        opts = np.array([damping, tol, gain, keep, predict, give_up], dtype=float)
        iopts = np.array([max_iterations, its, chained is not None, first, axis_only], dtype=np.int64)
        flag = np.zeros(n, dtype=np.int64)
        T, J = np.empty((n, 4, 4)), np.empty((n, 6, self.nq))
        lib.solve(
            qs, fixed[0], fixed[1], world, targets, lower, upper, mid, half, opts, iopts, q, err, T, J, flag
        )
        return q, err, T, J, flag

    def line_starts(
        self,
        qs: Array,
        kinematics: tuple[Array, Array, Array | None],
        targets: Array,
        P: Array,
        segment: Array,
        t: Array,
        step_max: float,
        lines: Array | None = None,
        step: bool = True,
    ) -> tuple[Array, Array, Array, Array] | None:
        """The controller line's IK starts in one pass, or None when the chain runs in NumPy.

        With ``lines`` (K, 36) (:func:`refine.optimise.line_ik.segment_lines`) the targets (N, 4, 4)
        are written into ``targets`` first, as :func:`refine.optimise.line_ik.line_poses` forms them.
        Per joint-linear row of ``qs`` (N, nv) [rad], returned: the TCP pose (N, 4, 4) (``kinematics``
        as :meth:`ik_solve`'s), the pose error (N, 6) as :meth:`ik_steps` forms it, the angle of
        ``R_target Rᵀ`` (N,) [rad] (above ``π - 1e-3`` take the rotation vector otherwise), the start
        ``q + P[segment] [e, t e]`` (N, nv) [rad] (``P`` (K, nv, 12): :func:`refine.optimise.line_start.start_matrices`),
        ``q`` where a joint's step exceeds ``step_max`` [rad] (or NaN) and without ``step``.
        """
        lib = self._lib()
        if lib is None:
            return None
        qs = self._rows(qs)
        fixed = self._placements(*kinematics)
        world = None if kinematics[2] is None else fixed[2]
        n = len(qs)
        if lines is not None:
            lines = np.ascontiguousarray(lines, dtype=float)
            if lines.shape != (len(P), 36) or not _writable(targets, (n, 4, 4)):
                raise ValueError(f"line_starts: lines ({len(P)}, 36) and writable targets ({n}, 4, 4)")
        targets = np.ascontiguousarray(targets, dtype=float)
        segment = np.ascontiguousarray(segment, dtype=np.int64)
        t = np.ascontiguousarray(t, dtype=float)
        if (
            targets.shape != (n, 4, 4)
            or segment.shape != (n,)
            or t.shape != (n,)
            or P.shape[1:] != (self.nq, 12)
        ):
            raise ValueError(f"line_starts: targets ({n}, 4, 4), segments and t ({n},), P (K, {self.nq}, 12)")
        if n and not (0 <= segment.min() and segment.max() < len(P)):
            raise ValueError(f"line_starts: segments 0..{len(P) - 1}")
        P = np.ascontiguousarray(P, dtype=float) if step else None
        T, e, theta, start = np.empty((n, 4, 4)), np.empty((n, 6)), np.empty(n), np.empty((n, self.nq))
        lib.start(
            qs, fixed[0], fixed[1], world, lines, targets, P, segment, t, float(step_max), T, e, theta, start
        )
        return T, e, theta, start

    def damped_inverses(self, J: Array, damping: float) -> Array | None:
        """``Jᵀ (J Jᵀ + λ² I)⁻¹`` (N, nv, 6) of Jacobians ``J`` (N, 6, nv), ``λ = damping`` > 0; None in NumPy."""
        lib, J = self._lib(), np.ascontiguousarray(J, dtype=float)
        if lib is not None and (J.ndim != 3 or J.shape[1:] != (6, self.nq) or not damping > 0.0):
            raise ValueError(f"damped_inverses: (N, 6, {self.nq}) and damping > 0 expected, got {J.shape}")
        if lib is not None:
            lib.pinv(J, float(damping), out := np.empty((len(J), self.nq, 6)))
        return None if lib is None else out

    def dets6(self, matrices: Array) -> Array | None:
        """Determinants (N,) of 6 × 6 matrices (N, 6, 6) (LU with partial pivoting), or None in NumPy."""
        lib = self._lib()
        if lib is None:
            return None
        a = np.ascontiguousarray(matrices, dtype=float)
        if a.ndim != 3 or a.shape[1:] != (6, 6):
            raise ValueError(f"dets6: expected (N, 6, 6), got {a.shape}")
        out = np.empty(len(a))
        lib.det6(a, out)
        return out

    def joint_placements(self, qs: Array, joints: Array | None = None) -> Array:
        """:meth:`BatchChain.joint_placements`: ``data.oMi`` (N, K, 4, 4) of ``joints`` (default all)."""
        lib = self._lib()
        if lib is None:
            return self.numpy.joint_placements(qs, joints)
        qs = self._rows(qs)
        out = np.empty((len(qs), self._njoints, 4, 4))
        lib.call("joints", qs, out)
        return out if joints is None else out[:, np.asarray(joints, dtype=int)]

    def axis_frames(self, qs: Array) -> tuple[list[Array], list[Array]]:
        """:meth:`BatchChain.axis_frames` (NumPy's)."""
        return self.numpy.axis_frames(qs)

    def _rows(self, qs: Array) -> Array:
        qs = np.ascontiguousarray(qs, dtype=float)
        if qs.ndim != 2 or qs.shape[1] != self.nq:
            raise ValueError(f"qs: expected shape (N, {self.nq}) [rad], got {qs.shape}")
        return qs

    def _lib(self) -> ChainLibrary | None:
        if self._resolved:
            return self._library
        with self._lock:
            if not self._resolved:
                self._library = self._find()
                self._resolved = True
        return self._library

    def _find(self) -> ChainLibrary | None:
        """The library of this model (loaded, from the cache folder or compiled), checked; None: NumPy."""
        cc = compiler()
        if cc is None:
            return None
        try:
            digest = self._digest(cc)
        except (OSError, ImportError) as e:  # a source file or CasADi's version not to be read
            log.warning("the batch kinematics cannot be keyed (%s); using NumPy's", e)
            return None
        with _loaded.lock:  # one thread at a time looks up, compiles and loads
            hit = _loaded.get(digest)
            if hit is None:
                hit = self._load(cc, digest)
                _loaded.put(digest, hit)
        return hit or None

    def _digest(self, cc: str) -> str:
        """The library's key: the code that writes it, CasADi, the compiler and the model's constants."""
        h = hashlib.sha256()
        for part in (importlib.metadata.version("casadi"), cc, compiler_version(cc), *FLAGS):
            h.update(part.encode() + b"\0")
        for source in _SOURCES:
            h.update(source.read_bytes())
        h.update(repr((self.nq, self._njoints, self.flange_id)).encode())
        for i in range(1, self._njoints):
            jm = self.model.joints[i]
            h.update(f"{jm.shortname()} {int(self.model.parents[i])} {jm.idx_q}".encode())
            h.update(self.model.jointPlacements[i].homogeneous.tobytes())
            if "Unaligned" in jm.shortname():
                h.update(np.asarray(jm.extract().axis, dtype=float).tobytes())
        frame = self.model.frames[self.flange_id]
        h.update(f"{int(frame.parentJoint)}".encode() + frame.placement.homogeneous.tobytes())
        return h.hexdigest()[:24]

    def _load(self, cc: str, digest: str) -> ChainLibrary | bool:
        """Load (compiling first when missing) and check the library; False when it cannot be used."""
        library = cache_dir() / f"{PREFIX}-{digest}.so"
        try:
            cached_library(
                cc, lambda: chain_source(self.numpy, self.flange_id, PREFIX), library, list(FUNCTIONS), FLAGS
            )
            lib = ChainLibrary(library, self.nq)
        except (OSError, RuntimeError, AttributeError, ImportError) as e:
            log.warning("compiling the batch kinematics failed (%s); using NumPy's", e)
            return False
        error = self._check(lib)
        if not error <= CHECK_TOLERANCE:
            log.warning(
                "the compiled batch kinematics %s differ from Pinocchio by %.3g (> %g); using NumPy's",
                library,
                error,
                CHECK_TOLERANCE,
            )
            return False
        return lib

    def _check(self, lib: ChainLibrary) -> float:
        """The largest difference of ``lib``'s answers from Pinocchio's at :data:`CHECK_ROWS` rows."""
        model, data = self.model, self.model.createData()
        lower = np.maximum(model.lowerPositionLimit, -np.pi)
        upper = np.minimum(model.upperPositionLimit, np.pi)
        qs = np.random.default_rng(0).uniform(lower, upper, (CHECK_ROWS, self.nq))
        qs[0] = 0.0
        T, J, T_alone = (
            np.empty((CHECK_ROWS, 4, 4)),
            np.empty((CHECK_ROWS, 6, self.nq)),
            np.empty((CHECK_ROWS, 4, 4)),
        )
        oMi = np.empty((CHECK_ROWS, self._njoints, 4, 4))
        lib.call("fkj", qs, T, J)
        lib.call("fk", qs, T_alone)
        lib.call("joints", qs, oMi)
        B, X = _CHECK_BASE, _CHECK_TCP
        T_tcp, J_tcp, T_tcp_alone = np.empty_like(T), np.empty_like(J), np.empty_like(T)
        lib.call("tcpj", qs, T_tcp, J_tcp, fixed=(B, X))
        lib.call("tcp", qs, T_tcp_alone, fixed=(B, X))
        body_joints = np.array([self._njoints - 1, 0, 1, self._njoints - 1], dtype=np.int64)
        local = np.ascontiguousarray(np.stack([X, B, X @ B, np.eye(4)]))
        bodies = np.empty((CHECK_ROWS, len(body_joints), 4, 4))
        lib.bodies(qs, B, body_joints, local, bodies)
        # the IK step toward targets turned and shifted off the TCP, and the determinants of 6 × 6 rows
        targets = np.array([pin.SE3(pin.exp3(0.1 * w), 0.01 * w).homogeneous for w in qs[:, :3]])
        targets = np.ascontiguousarray(T_tcp @ targets)
        T_ik, J_ik = np.empty_like(T), np.empty_like(J)
        e, norm, dq, theta = (
            np.empty((CHECK_ROWS, 6)),
            np.empty(CHECK_ROWS),
            np.empty((CHECK_ROWS, self.nq)),
            np.empty(CHECK_ROWS),
        )
        lib.ik(qs, B, X, targets, 0.01, 0.0, False, T_ik, J_ik, e, norm, dq, theta)
        square = np.ascontiguousarray(J_tcp[:, :, :6]) if self.nq >= 6 else np.zeros((CHECK_ROWS, 6, 6))
        dets = np.empty(CHECK_ROWS)
        lib.det6(square, dets)
        # a stationary tool, and one iteration of the whole solve (with the pull of a redundant arm), the
        # whole pose's and the tool axis'
        W = _CHECK_WORLD
        T_st, J_st, T_st_alone = np.empty_like(T), np.empty_like(J), np.empty_like(T)
        lib.call("statj", qs, T_st, J_st, fixed=(B, X, W))
        lib.call("stat", qs, T_st_alone, fixed=(B, X, W))
        gain, q_one = (0.05 if self.nq > 6 else 0.0), np.empty_like(qs)
        one = [
            lower,
            upper,
            0.5 * (lower + upper),
            0.5 * (upper - lower),
            np.array([0.01, 0, gain, 0, 0, 0.0]),
        ]
        q_axis = np.empty_like(qs)
        for counts, out in ((np.array([1, 0, 0, 0, 0]), q_one), (np.array([1, 0, 0, 0, 1]), q_axis)):
            lib.solve(qs, B, X, None, targets, *one, counts, out, np.empty(CHECK_ROWS), T_ik.copy(),
                      J_ik.copy(), np.empty(CHECK_ROWS, dtype=np.int64))  # fmt: skip
        error = 0.0
        for k, q in enumerate(qs):
            pin.forwardKinematics(model, data, q)  # every joint (the Jacobian's pass: only the flange's)
            oMi_pin = np.array([data.oMi[i].homogeneous for i in range(self._njoints)])
            J_pin = pin.computeFrameJacobian(model, data, q, self.flange_id, pin.LOCAL_WORLD_ALIGNED)
            T_pin = pin.updateFramePlacement(model, data, self.flange_id).homogeneous
            # the TCP: v = R_B (v_flange + ω × (p_TCP - p_flange)), ω = R_B ω_flange
            T_tcp_pin = B @ T_pin @ X
            arm = T_pin[:3, :3] @ X[:3, 3]
            J_tcp_pin = np.vstack(
                [B[:3, :3] @ (J_pin[:3] - np.cross(arm, J_pin[3:].T).T), B[:3, :3] @ J_pin[3:]]
            )
            pairs = [(T[k], T_pin), (T_alone[k], T_pin), (J[k], J_pin), (oMi[k], oMi_pin)]
            pairs += [(T_tcp[k], T_tcp_pin), (T_tcp_alone[k], T_tcp_pin), (J_tcp[k], J_tcp_pin)]
            pairs += [(bodies[k, m], B @ oMi_pin[j] @ local[m]) for m, j in enumerate(body_joints)]
            e_pin = np.concatenate(
                [targets[k, :3, 3] - T_tcp_pin[:3, 3], pin.log3(targets[k, :3, :3] @ T_tcp_pin[:3, :3].T)]
            )
            A = J_tcp_pin @ J_tcp_pin.T + 1e-4 * np.eye(6)
            dq_pin = J_tcp_pin.T @ np.linalg.solve(A, e_pin)
            pairs += [
                (T_ik[k], T_tcp_pin),
                (J_ik[k], J_tcp_pin),
                (e[k], e_pin),
                (norm[k], np.linalg.norm(e_pin)),
            ]
            pairs += [(dq[k] / max(1.0, np.abs(dq_pin).max()), dq_pin / max(1.0, np.abs(dq_pin).max()))]
            det = np.linalg.det(square[k])
            pairs += [(dets[k] / max(1.0, abs(det)), det / max(1.0, abs(det)))]
            T_wf, R_b = B @ T_pin, B[:3, :3]
            T_wp = T_wf @ X
            Jw = R_b @ J_pin[3:]
            point = R_b @ J_pin[:3] - np.cross(W[:3, 3] - T_wf[:3, 3], Jw.T).T
            J_st_pin = -np.vstack([T_wp[:3, :3].T @ point, T_wp[:3, :3].T @ Jw])
            pairs += [(T_st[k], np.linalg.inv(T_wp) @ W), (T_st_alone[k], np.linalg.inv(T_wp) @ W)]
            pairs += [(J_st[k], J_st_pin)]
            pull = (0.5 * (lower + upper) - q) / (0.5 * (upper - lower)) ** 2
            step = dq_pin + gain * (pull - J_tcp_pin.T @ np.linalg.solve(A, J_tcp_pin @ pull))
            step *= min(1.0, 0.3 / np.abs(step).max())
            pairs += [(q_one[k], np.clip(q + step, lower, upper))]
            # the tool axis alone: z turned onto the target's, the Jacobian's spin about z taken out
            z, zt = T_tcp_pin[:3, 2], targets[k, :3, 2]
            turn = np.cross(z, zt)
            sin = float(np.linalg.norm(turn))
            turn *= np.arctan2(sin, z @ zt) / sin if sin > 1e-12 else 0.0  # row 0: at its target
            e_axis = np.concatenate([e_pin[:3], turn])
            J_axis = np.vstack([J_tcp_pin[:3], J_tcp_pin[3:] - np.outer(z, z @ J_tcp_pin[3:])])
            A = J_axis @ J_axis.T + 1e-4 * np.eye(6)
            step = J_axis.T @ np.linalg.solve(A, e_axis)
            step += gain * (pull - J_axis.T @ np.linalg.solve(A, J_axis @ pull))
            step *= min(1.0, 0.3 / max(float(np.abs(step).max()), 1e-300))  # row 0's may be 0
            pairs += [(q_axis[k], np.clip(q + step, lower, upper))]
            for a, b in pairs:
                error = max(error, float(np.abs(a - b).max()))
        return error if np.isfinite(error) else np.inf


def _writable(a: Array | None, shape: tuple[int, ...]) -> bool:
    """Whether ``a`` is a C-contiguous float64 array of ``shape`` to be written into."""
    return a is not None and a.shape == shape and a.dtype == np.float64 and a.flags.c_contiguous
