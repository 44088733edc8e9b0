"""The robot's batch kinematics compiled to C: the flange's placements and Jacobians, every joint's placement.

:class:`~refine.robot.chain.BatchChain` costs NumPy about 0.3 ms a batch and 1 µs a row. The same
recursion written for one row on CasADi ``SX`` scalars (:meth:`BatchChain.row_frame`,
:meth:`BatchChain.row_joint_placements`: the chain's own joint placements and axes, not the
optimiser's symbolic kinematics, so the verifier stays independent of the NLP) is written out as C
by CasADi's code generator, with a loop over the rows in C around it, and compiled once per robot
model into a shared library (:mod:`refine.native`: the cache folder, the compiler,
``REFINE_COMPILE=0``). The library is called through :mod:`ctypes` on the NumPy arrays themselves:
the joint rows are read and the answers written in place, nothing is copied or converted.

Three functions: the flange's placement, the flange's placement with its Jacobian (Pinocchio's
``LOCAL_WORLD_ALIGNED``), and every joint's ``data.oMi``. Any number of rows is one call; each
call's work memory is on the C stack, so threads may call at once (:mod:`ctypes` lets go of the
GIL for the call). Any other frame, and :meth:`CompiledChain.axis_frames`, are the NumPy chain's.

When a library is loaded it is checked once against Pinocchio (``forwardKinematics`` and
``computeFrameJacobian``) at :data:`CHECK_ROWS` configurations; a difference above
:data:`CHECK_TOLERANCE` is logged as a warning and the chain stays NumPy's, as it does without a
compiler, with ``REFINE_COMPILE=0`` or when compiling fails. The library is looked for on the
first evaluation (not when the robot is made), once per :class:`CompiledChain`.
"""

from __future__ import annotations

import ctypes
import hashlib
import importlib.metadata
import logging
import os
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from refine.native import (
    COMPILE_FLAGS,
    BoundedCache,
    build_library,
    cache_dir,
    compiler,
    compiler_version,
)
from refine.robot.chain import MIN_ROWS, BatchChain
from refine.types import Array

log = logging.getLogger(__name__)

COMPILED_MIN_ROWS = 8
"""Rows from which the compiled chain beats Pinocchio's row loop: about 10 µs a call plus 0.2 µs a
row against Pinocchio's 6 µs a row with the Jacobian and 3 µs without it
(``benchmarks/batch_kinematics.py``)."""
CHECK_ROWS = 5
"""Configurations at which a loaded library is compared with Pinocchio."""
CHECK_TOLERANCE = 1e-12
"""The largest difference [m, rad, 1] from Pinocchio a loaded library may show in its check."""
FLAGS = (*COMPILE_FLAGS, "-ffp-contract=off")
"""No fused multiply-adds: the pose alone and the pose beside its Jacobian round alike."""
LOADED_MAX = 16
"""Chain libraries kept loaded in one process (one per robot model)."""

_PREFIX = "refine_chain"
_SOURCES = (Path(__file__), Path(__file__).with_name("chain.py"))
_loaded = BoundedCache(LOADED_MAX)

# a loop over the rows around each generated function: pointers moved along, work memory on the stack
_LOOP = """
int {name}_rows(const casadi_real* q, casadi_real* const* out, long long n) {{
  const casadi_real* arg[{sz_arg}];
  casadi_real* res[{sz_res}];
  casadi_int iw[{sz_iw}];
  casadi_real w[{sz_w}];
  long long k;
  int i;
  for (k = 0; k < n; ++k) {{
    arg[0] = q + k * {nq};
{moves}
    if ({name}(arg, res, iw, w, 0)) return 1;
  }}
  return 0;
}}
"""


class CompiledChain:
    """:class:`~refine.robot.chain.BatchChain`'s evaluations of a model, compiled where it can be.

    Answers as the NumPy chain (``frame``, ``joint_placements``, ``axis_frames``), to rounding
    (``tests/test_compiled_chain.py``); :attr:`min_rows` is the batch size from which either
    beats Pinocchio's row loop.
    """

    def __init__(self, model: pin.Model, flange_id: int, chain: BatchChain) -> None:
        self.model = model
        self.flange_id = int(flange_id)
        self.numpy = chain
        self.nq = chain.nq
        self._njoints = int(model.njoints)
        self._lock = threading.Lock()
        self._library: _Library | None = None
        self._resolved = False

    @classmethod
    def from_model(cls, model: pin.Model, flange_id: int) -> CompiledChain | None:
        """The chain of ``model`` (the flange: frame ``flange_id``), or None where BatchChain refuses it."""
        chain = BatchChain.from_model(model)
        return None if chain is None else cls(model, flange_id, chain)

    def __getstate__(self) -> dict[str, Any]:
        # the loaded library and the lock belong to this process; the other side looks again
        return {**self.__dict__, "_lock": None, "_library": None, "_resolved": False}

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

    def _lib(self) -> _Library | None:
        if self._resolved:
            return self._library
        with self._lock:
            if not self._resolved:
                self._library = self._find()
                self._resolved = True
        return self._library

    def _find(self) -> _Library | None:
        """The library of this model (loaded, from the cache folder or compiled), checked; None: NumPy."""
        cc = compiler()
        if cc is None:
            return None
        digest = self._digest(cc)
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

    def _load(self, cc: str, digest: str) -> _Library | bool:
        """Load (compiling first when missing) and check the library; False when it cannot be used."""
        library = cache_dir() / f"{_PREFIX}-{digest}.so"
        try:
            if library.exists() and library.with_suffix(".names").exists():
                os.utime(library)  # recently used: the last to be evicted
            else:
                build_library(cc, self._source(), library, ["fk", "fkj", "joints"], FLAGS)
            lib = _Library(library, self.nq)
        except (OSError, RuntimeError, AttributeError) as e:
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

    def _source(self) -> str:
        """The C of the three functions and their row loops."""
        import casadi as ca  # only when a library is written

        q = ca.SX.sym("q", self.nq)
        qs = [q[i] for i in range(self.nq)]
        chain, fid = self.numpy, self.flange_id

        def flat(*matrices: list) -> list[ca.SX]:
            return [ca.densify(ca.vertcat(*[x for row in m for x in row])) for m in matrices]

        T, J = chain.row_frame(qs, fid, ca.cos, ca.sin)
        oMi = chain.row_joint_placements(qs, ca.cos, ca.sin)
        functions = [
            ca.Function(f"{_PREFIX}_fk", [q], flat(T)),
            ca.Function(f"{_PREFIX}_fkj", [q], flat(T, J)),
            ca.Function(f"{_PREFIX}_joints", [q], [ca.vertcat(*flat(*oMi))]),
        ]
        gen = ca.CodeGenerator(f"{_PREFIX}.c", {"with_header": False})
        for f in functions:
            gen.add(f)
        loops = []
        for f in functions:
            moves = "\n".join(f"    res[{i}] = out[{i}] + k * {f.nnz_out(i)};" for i in range(f.n_out()))
            loops.append(
                _LOOP.format(
                    name=f.name(),
                    sz_arg=max(f.sz_arg(), 1),
                    sz_res=max(f.sz_res(), 1),
                    sz_iw=max(f.sz_iw(), 1),
                    sz_w=max(f.sz_w(), 1),
                    nq=self.nq,
                    moves=moves,
                )
            )
        return gen.dump() + "".join(loops)

    def _check(self, lib: _Library) -> float:
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
        error = 0.0
        for k, q in enumerate(qs):
            pin.forwardKinematics(model, data, q)  # every joint (the Jacobian's pass: only the flange's)
            oMi_pin = np.array([data.oMi[i].homogeneous for i in range(self._njoints)])
            J_pin = pin.computeFrameJacobian(model, data, q, self.flange_id, pin.LOCAL_WORLD_ALIGNED)
            T_pin = pin.updateFramePlacement(model, data, self.flange_id).homogeneous
            for a, b in ((T[k], T_pin), (T_alone[k], T_pin), (J[k], J_pin), (oMi[k], oMi_pin)):
                error = max(error, float(np.abs(a - b).max()))
        return error if np.isfinite(error) else np.inf


class _Library:
    """The loaded library: each function's row loop, called on C-contiguous float64 arrays."""

    def __init__(self, path: Path, nq: int) -> None:
        self._dll = ctypes.CDLL(str(path))
        self.nq = nq
        self._calls = {}
        for name in ("fk", "fkj", "joints"):
            fn = getattr(self._dll, f"{_PREFIX}_{name}_rows")
            fn.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_longlong]
            fn.restype = ctypes.c_int
            self._calls[name] = fn

    def call(self, name: str, qs: Array, *out: Array) -> None:
        """Evaluate ``name`` on the rows ``qs`` (N, nq) into the C-contiguous arrays ``out`` (N, ...)."""
        for a in out:
            assert a.flags.c_contiguous and a.dtype == np.float64 and len(a) == len(qs)
        pointers = (ctypes.c_void_p * len(out))(*(a.ctypes.data for a in out))
        if self._calls[name](qs.ctypes.data, pointers, len(qs)) != 0:
            raise RuntimeError(f"the compiled batch kinematics' {name} failed")
