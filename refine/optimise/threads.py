"""One thread for the dense linear algebra under IPOPT's linear solver.

CasADi's IPOPT plugin ships its own OpenBLAS, which MUMPS calls for the dense blocks of the KKT
matrix. It starts one worker thread per core, and for the refinement's small, banded blocks these
workers mostly spin: at 6,400 waypoints on 2 cores the build, seed and solve took 1.09 s of process
CPU time with them and 0.69 s without, in the same wall time (0.6 s). On a machine shared with other
work the spinning also slows every other process. So the refinement sets that OpenBLAS to
:data:`SOLVER_BLAS_THREADS` threads before its first solve; the count of NumPy's own BLAS is left
as it is.

``REFINE_SOLVER_BLAS_THREADS`` overrides the count (a positive integer; ``0`` leaves OpenBLAS's own
choice). Where the library is not found (another CasADi build), nothing is changed.
"""

from __future__ import annotations

import ctypes
import functools
import logging
import os
import re
from pathlib import Path

from refine.errors import InputError

log = logging.getLogger(__name__)

SOLVER_BLAS_THREADS = 1
"""Threads of the OpenBLAS that CasADi's IPOPT uses (see the module docstring)."""

THREADS_ENV = "REFINE_SOLVER_BLAS_THREADS"


def solver_blas_threads() -> int:
    """The thread count to set: :data:`SOLVER_BLAS_THREADS` or ``$REFINE_SOLVER_BLAS_THREADS``."""
    text = os.environ.get(THREADS_ENV, "").strip()
    if not text:
        return SOLVER_BLAS_THREADS
    try:
        count = int(text)
    except ValueError:
        count = -1
    if count < 0:
        raise InputError(f"{THREADS_ENV} must be an integer >= 0 (0: OpenBLAS's own choice), got {text!r}")
    return count


def limit_solver_threads() -> int | None:
    """Set the thread count of CasADi's OpenBLAS where it is not that count already; the count, or None.

    The count is read back from OpenBLAS on every call (a cheap call into the library), so a count
    that other code changed in between (a benchmark restoring its own, say) is set again.
    None when the count is 0 (left alone) or the library or its ``openblas_set_num_threads`` is
    not there.
    """
    count = solver_blas_threads()
    if count == 0:
        return None
    lib = _library()
    if lib is None:
        return None
    if int(lib.openblas_get_num_threads()) != count:
        lib.openblas_set_num_threads(ctypes.c_int(count))
        log.debug("CasADi's OpenBLAS: %d thread(s)", count)
    return count


@functools.cache
def _library() -> ctypes.CDLL | None:
    """CasADi's own OpenBLAS as MUMPS loads it, with both thread calls; None where this build has none.

    CasADi's wheel holds the same OpenBLAS under several file names (``libcasadi-tp-openblas.so``,
    ``.so.0``, ``.so.0.3``: copies, not links), and MUMPS loads the one its soname names
    (``.so.0``). Loading another name loads a second copy, whose thread count MUMPS never reads. So
    IPOPT's plugin is loaded first and the copy the process has mapped is taken
    (:func:`_loaded_first`); without ``/proc/self/maps`` the names of one version number come first.
    """
    import casadi

    folder = Path(casadi.__file__).parent
    try:
        casadi.load_nlpsol("ipopt")  # MUMPS and the OpenBLAS it links, as a solve would load them
    except Exception as e:  # another build without the plugin: the names alone decide
        log.debug("could not load CasADi's IPOPT plugin: %s", e)
    candidates = sorted(folder.glob("libcasadi-tp-openblas.so*")) + sorted(folder.glob("libopenblas*.so*"))
    for path in _loaded_first(candidates):
        try:
            lib = ctypes.CDLL(str(path))
            lib.openblas_set_num_threads  # noqa: B018 - both calls must be there
            lib.openblas_get_num_threads  # noqa: B018
        except (OSError, AttributeError) as e:
            log.debug("could not use the thread calls of %s: %s", path, e)
            continue
        return lib
    log.debug("no OpenBLAS beside CasADi in %s; its threads are left as they are", folder)
    return None


def _loaded_first(candidates: list[Path], maps: Path = Path("/proc/self/maps")) -> list[Path]:
    """``candidates`` with those the process has mapped first, then those named ``*.so.N``, then the rest."""
    try:
        text = os.fsdecode(maps.read_bytes())  # the names as the file system's bytes, UTF-8 or not
        mapped = {Path(line.split(maxsplit=5)[5].strip()).resolve() for line in text.split("\n")
                  if len(line.split(maxsplit=5)) == 6}  # fmt: skip
    except OSError:
        mapped = set()

    def rank(path: Path) -> int:
        if path.resolve() in mapped:
            return 0
        return 1 if re.search(r"\.so\.\d+$", path.name) else 2

    return sorted(candidates, key=rank)
