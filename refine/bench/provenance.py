"""Provenance of a benchmark run: the source commit, the solvers' versions and the thread settings.

Written in every row (docs/bench.md, "Provenance"):

* ``git_commit``: the commit of the refine checkout that ran (``git rev-parse HEAD`` in the
  package's folder), with ``-dirty`` when tracked files differ from it; empty outside a checkout.
* ``solver_versions``: CasADi's version and those of the IPOPT and MUMPS it loads, read from the
  line IPOPT prints at the start of every solve (``This is Ipopt version 3.14.19, running with
  linear solver MUMPS 5.8.2.``) of a one-variable problem solved once per process.
* ``blas_threads``: the thread count of every BLAS in the process while the contenders run: the
  OpenBLAS beside CasADi that MUMPS calls (which the refinement also sets, :mod:`refine.optimise.threads`)
  and those threadpoolctl finds (NumPy's, SciPy's), all fixed by :func:`fixed_threads` for the
  runs of each problem and read after them.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import io
import os
import re
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

from threadpoolctl import threadpool_info, threadpool_limits

from refine.errors import InputError

DEFAULT_BLAS_THREADS = 1
"""Threads of every BLAS while the contenders run (``refine bench run --blas-threads``)."""


@functools.cache
def git_commit() -> str:
    """The commit of the refine source that runs, ``-dirty`` when tracked files changed; empty outside git."""
    folder = Path(__file__).resolve().parent
    try:
        head = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=folder, capture_output=True, text=True, timeout=10, check=True
        ).stdout.strip()
        changed = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=folder,
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""
    return f"{head}-dirty" if changed else head


@functools.cache
def solver_versions() -> str:
    """``casadi X; ipopt Y; mumps Z`` (IPOPT's and MUMPS' versions as IPOPT prints them; ``?`` if not found)."""
    import casadi as ca

    x = ca.MX.sym("x")
    options = {"ipopt.print_level": 5, "print_time": False, "ipopt.max_iter": 1, "ipopt.sb": "yes"}
    solver = ca.nlpsol("versions", "ipopt", {"x": x, "f": (x - 1) ** 2}, options)
    printed = io.StringIO()
    libc = ctypes.CDLL(None)
    with tempfile.TemporaryFile() as out:
        sys.stdout.flush()
        saved = os.dup(1)
        os.dup2(out.fileno(), 1)  # IPOPT may write to the C library's stdout, CasADi to Python's
        try:
            with contextlib.redirect_stdout(printed):
                solver(x0=0.0)
        finally:
            libc.fflush(None)
            os.dup2(saved, 1)
            os.close(saved)
        out.seek(0)
        text = out.read().decode(errors="replace") + printed.getvalue()
    ipopt = re.search(r"Ipopt version ([0-9][\w.]*[0-9])", text)
    mumps = re.search(r"MUMPS ([0-9][\w.]*[0-9])", text)
    return (
        f"casadi {ca.__version__}; ipopt {ipopt.group(1) if ipopt else '?'}; "
        f"mumps {mumps.group(1) if mumps else '?'}"
    )


def _casadi_openblas() -> ctypes.CDLL | None:
    """The OpenBLAS beside CasADi that MUMPS calls under IPOPT (the loaded copy), or None where there is none."""
    from refine.optimise.threads import _library

    return _library()


def _casadi_openblas_threads() -> int | None:
    """The thread count of the OpenBLAS beside CasADi, or None where there is none."""
    lib = _casadi_openblas()
    return None if lib is None else int(lib.openblas_get_num_threads())


def blas_threads() -> str:
    """Every BLAS of the process and its thread count, e.g. ``casadi-openblas 1; openblas 1 (libscipy_openblas64_...)``."""
    parts = []
    casadi_threads = _casadi_openblas_threads()
    if casadi_threads is not None:
        parts.append(f"casadi-openblas {casadi_threads}")
    for lib in threadpool_info():
        if lib.get("user_api") == "blas":
            parts.append(f"{lib['internal_api']} {lib['num_threads']} ({Path(lib['filepath']).name})")
    return "; ".join(parts)


LOAD_TIME_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
"""The environment variables a BLAS reads its thread count from when it is loaded (OpenBLAS reads
the first two, in this order; MKL the last), set by :func:`fixed_threads` inside its block."""


@contextlib.contextmanager
def fixed_threads(count: int = DEFAULT_BLAS_THREADS) -> Iterator[str]:
    """Run the block with every BLAS at ``count`` threads; yields :func:`blas_threads` as set.

    CasADi's OpenBLAS is set directly and through refine's own setting (``REFINE_SOLVER_BLAS_THREADS``,
    which the refinement applies before a solve), the others with threadpoolctl; all are restored after.
    A BLAS first loaded inside the block (SciPy's own OpenBLAS, loaded with the first ``scipy.linalg``
    import, in this process or in a run's child process) reads its thread count from the environment
    when it loads, not from threadpoolctl's setting: SciPy's is loaded before the limit is set, and
    :data:`LOAD_TIME_THREAD_VARIABLES` hold ``count`` inside the block for any other (without them, a
    run that first imported ``scipy.linalg`` ran SciPy's OpenBLAS at one thread per core while the
    row recorded ``count``).

    Raises:
        InputError: ``count`` below 1.
    """
    from refine.optimise.threads import THREADS_ENV

    if count < 1:
        raise InputError(f"BLAS threads must be >= 1, got {count}")
    import scipy.linalg  # noqa: F401  (its own OpenBLAS loaded now, so that the limit below covers it)

    names = (THREADS_ENV, *LOAD_TIME_THREAD_VARIABLES)
    before = {name: os.environ.get(name) for name in names}
    lib = _casadi_openblas()
    threads_before = None if lib is None else int(lib.openblas_get_num_threads())
    for name in names:  # THREADS_ENV: what the refinement sets before a solve
        os.environ[name] = str(count)
    try:
        if lib is not None:
            lib.openblas_set_num_threads(ctypes.c_int(count))
        with threadpool_limits(limits=count, user_api="blas"):
            yield blas_threads()
    finally:
        for name, value in before.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
        if lib is not None and threads_before is not None:
            lib.openblas_set_num_threads(ctypes.c_int(threads_before))
