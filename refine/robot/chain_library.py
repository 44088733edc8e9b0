"""The compiled batch kinematics' shared library as loaded: its functions called through :mod:`ctypes`.

:class:`ChainLibrary` binds the row loops :mod:`refine.robot.chain_source` writes (their names
:data:`FUNCTIONS`, each ``<PREFIX>_<name>_rows``) and calls them on NumPy arrays in place;
:class:`refine.robot.compiled_chain.CompiledChain` checks the arguments and the answers.
"""

from __future__ import annotations

import ctypes
from pathlib import Path
from typing import Any

import numpy as np

from refine.robot.chain_source import PREFIX
from refine.types import Array

GENERATED = ("fk", "fkj", "joints", "tcp", "tcpj", "stat", "statj")
"""The functions CasADi writes, each with a row loop ``(q, fixed, out, n)``."""
FUNCTIONS = (*GENERATED, "bodies", "ik", "det6", "solve", "start", "pinv")
"""Every function of a chain library (the hand-written ones after CasADi's)."""


class ChainLibrary:
    """The loaded library: each function's row loop, called on C-contiguous float64 arrays."""

    def __init__(self, path: Path, nq: int) -> None:
        self._dll = ctypes.CDLL(str(path))
        self.nq = nq
        self._calls = {}
        self._bodies = self._dll[f"{PREFIX}_bodies_rows"]
        pointer, count = ctypes.c_void_p, ctypes.c_longlong
        self._bodies.argtypes = [pointer, pointer, pointer, pointer, count, pointer, count]
        self._bodies.restype = ctypes.c_int
        self._ik = self._dll[f"{PREFIX}_ik_rows"]
        self._ik.argtypes = (
            [pointer] * 4 + [ctypes.c_double, ctypes.c_double, count] + [pointer] * 6 + [count]
        )
        self._ik.restype = ctypes.c_int
        self._det6 = self._dll[f"{PREFIX}_det6_rows"]
        self._det6.argtypes = [pointer, pointer, count]
        self._det6.restype = ctypes.c_int
        self._solve = self._dll[f"{PREFIX}_solve_rows"]
        self._solve.argtypes = [pointer] * 16 + [count]
        self._solve.restype = ctypes.c_int
        self._start = self._dll[f"{PREFIX}_start_rows"]
        self._start.argtypes = [pointer] * 9 + [ctypes.c_double] + [pointer] * 4 + [count]
        self._start.restype = ctypes.c_int
        self._pinv = self._dll[f"{PREFIX}_pinv_rows"]
        self._pinv.argtypes = [pointer, ctypes.c_double, pointer, count]
        self._pinv.restype = ctypes.c_int
        for name in GENERATED:
            fn = getattr(self._dll, f"{PREFIX}_{name}_rows")
            fn.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_longlong]
            fn.restype = ctypes.c_int
            self._calls[name] = fn

    def call(self, name: str, qs: Array, *out: Array, fixed: tuple[Array, ...] = ()) -> None:
        """Evaluate ``name`` on the rows ``qs`` (N, nq) into the C-contiguous arrays ``out`` (N, ...).

        ``fixed``: the arguments the same for every row (C-contiguous float64, read only).
        """
        for a in (qs, *out, *fixed):
            if not (a.flags.c_contiguous and a.dtype == np.float64):
                raise ValueError("the compiled batch kinematics take C-contiguous float64 arrays")
        if any(len(a) != len(qs) for a in out):
            raise ValueError("the compiled batch kinematics write one row of each output per joint row")
        pointers = (ctypes.c_void_p * len(out))(*(a.ctypes.data for a in out))
        given = (ctypes.c_void_p * max(len(fixed), 1))(*(a.ctypes.data for a in fixed))
        if self._calls[name](qs.ctypes.data, given, pointers, len(qs)) != 0:
            raise RuntimeError(f"the compiled batch kinematics' {name} failed")

    def bodies(self, qs: Array, base: Array, joints: Array, local: Array, out: Array) -> None:
        """Bodies' world poses into ``out`` (N, M, 4, 4) (:meth:`CompiledChain.body_poses`, arguments checked there)."""
        for a in (qs, base, local, out):
            if not (a.flags.c_contiguous and a.dtype == np.float64):
                raise ValueError("the compiled batch kinematics take C-contiguous float64 arrays")
        shape = (len(qs), len(joints))
        if not (joints.flags.c_contiguous and joints.dtype == np.int64) or out.shape[:2] != shape:
            raise ValueError("the compiled batch kinematics' bodies: int64 joints and (N, M, 4, 4) poses")
        code = self._bodies(
            qs.ctypes.data,
            base.ctypes.data,
            joints.ctypes.data,
            local.ctypes.data,
            len(joints),
            out.ctypes.data,
            len(qs),
        )
        if code != 0:
            raise RuntimeError(f"the compiled batch kinematics' bodies failed ({code})")

    def ik(self, qs: Array, *arrays: Any) -> None:
        """:meth:`CompiledChain.ik_steps` into its arrays (checked there).

        ``arrays``: base, tool, targets, damping, tol, given, T, J, e, norms, steps, angles.
        """
        base, tool, targets, damping, tol, given, *out = arrays
        for a in (qs, base, tool, targets, *out):
            if not (a.flags.c_contiguous and a.dtype == np.float64):
                raise ValueError("the compiled batch kinematics take C-contiguous float64 arrays")
        pointers = [a.ctypes.data for a in (qs, base, tool, targets)]
        code = self._ik(*pointers, damping, tol, int(given), *(a.ctypes.data for a in out), len(qs))
        if code != 0:
            raise RuntimeError(f"the compiled IK step failed ({code})")

    def solve(self, *arrays: Array | None) -> None:
        """:meth:`CompiledChain.ik_solve` into its arrays (checked there; the world tool may be None).

        ``arrays``: starts, base, tool, world, targets, the bounds, mid-range, half ranges, options,
        counts, then the joints, errors, poses, Jacobians and flags written.
        """
        pointers = []
        for a in arrays:
            if a is not None and not (a.flags.c_contiguous and a.dtype in (np.float64, np.int64)):
                raise ValueError("the compiled IK takes C-contiguous float64 and int64 arrays")
            pointers.append(None if a is None else a.ctypes.data)
        code = self._solve(*pointers, len(arrays[4]))  # a row per target
        if code != 0:
            raise RuntimeError(f"the compiled IK failed ({code})")

    def det6(self, a: Array, out: Array) -> None:
        """Determinants of C-contiguous (N, 6, 6) float64 matrices into ``out`` (N,)."""
        if self._det6(a.ctypes.data, out.ctypes.data, len(a)) != 0:
            raise RuntimeError("the compiled determinants failed")

    def start(self, *arrays: Any) -> None:
        """:meth:`CompiledChain.line_starts` into its arrays (checked there; the world tool may be None).

        ``arrays``: joints, base, tool, world, the segments' lines (or None), targets, per-segment
        matrices, segments, parameters,
        the step bound, then the poses, errors, angles and starts written.
        """
        pointers = []
        for a in arrays:
            if isinstance(a, float):
                pointers.append(a)
            elif a is None or (a.flags.c_contiguous and a.dtype in (np.float64, np.int64)):
                pointers.append(None if a is None else a.ctypes.data)
            else:
                raise ValueError("the compiled line starts take C-contiguous float64 and int64 arrays")
        if self._start(*pointers, len(arrays[0])) != 0:
            raise RuntimeError("the compiled line starts failed")

    def pinv(self, J: Array, damping: float, out: Array) -> None:
        """Damped inverses ``Jᵀ (J Jᵀ + λ² I)⁻¹`` of C-contiguous (N, 6, nv) float64 Jacobians into ``out`` (N, nv, 6)."""
        if self._pinv(J.ctypes.data, damping, out.ctypes.data, len(J)) != 0:
            raise RuntimeError("the compiled damped inverses failed")
