"""Per-waypoint CasADi functions compiled to machine code once per robot, placement and tool.

The refinement evaluates the same small functions (TCP pose error and orientation measure, their
Jacobians and Hessians, the singularity measure) at every waypoint. CasADi's virtual machine runs them
interpreted; here they are written out as C by CasADi's code generator, compiled with the system's C
compiler into a shared library and loaded with :func:`casadi.external`. The library is cached on
disk under a key derived from the generated source itself (which holds the robot's kinematic
constants, the base placement and the tool), the CasADi version and the compiler, so a later run on
the same robot and tool reuses it and a change to any of them compiles a new one.

The compiler, the cache folder and its bound, building and eviction are
:mod:`refine.native`'s (its names are re-exported here). In the process, at most :data:`LOADED_MAX`
libraries stay loaded, least recently used dropped first (a :class:`BoundedCache`, safe to use from
several threads: a lock guards each look-up and each insertion, and one per cache serialises
building what is missing, so two threads that want the same library compile it once).
``REFINE_COMPILE=0`` turns compilation off (nothing is written at all). Without a C compiler, or
when compiling fails, the same functions run in CasADi's virtual machine: slower, same results.
"""

from __future__ import annotations

import hashlib
import logging
import os
from collections.abc import Callable

import casadi as ca

from refine.native import (
    CACHE_ENV,
    CACHE_MAX_ENV,
    COMPILE_ENV,
    COMPILE_FLAGS,
    DEFAULT_CACHE_MAX_MB,
    BoundedCache,
    build_library,
    cache_dir,
    cache_max_bytes,
    compiler,
    compiler_version,
    evict,
)

__all__ = [
    "CACHE_ENV",
    "CACHE_MAX_ENV",
    "COMPILE_ENV",
    "COMPILE_FLAGS",
    "DEFAULT_CACHE_MAX_MB",
    "LOADED_MAX",
    "BoundedCache",
    "cache_dir",
    "cache_max_bytes",
    "compiled",
    "compiler",
    "evict",
]

log = logging.getLogger(__name__)

LOADED_MAX = 64
"""Libraries kept loaded in one process (each is a robot, base placement and tool)."""

_loaded = BoundedCache(LOADED_MAX)
_compiler_version = compiler_version
_build = build_library


def compiled(name: str, key: str, make: Callable[[], list[ca.Function]]) -> dict[str, ca.Function]:
    """Compiled externals for the functions ``make()`` returns, by name, or those functions themselves.

    The library is looked up by ``key`` first, so a cache hit costs neither building the functions
    nor generating their code; ``key`` must therefore determine the functions completely (the
    caller hashes what they are made from). The CasADi version, the compiler and its flags are
    added to it here.

    Args:
        name: a short prefix for the library file, a C identifier, e.g. ``"kernels"``.
        key: a digest of everything the functions depend on.
        make: builds the CasADi functions, with distinct names; derivatives CasADi may ask for
            later are looked up in the same library by CasADi's naming (``jac_<name>``...), so
            add those that are wanted as functions of their own.

    Returns:
        Function name -> callable CasADi function with the same inputs and outputs.
    """
    cc = compiler()
    if cc is None:
        return {f.name(): f for f in make()}
    version = _compiler_version(cc)
    digest = hashlib.sha256(
        "\n".join([ca.__version__, cc, version, *COMPILE_FLAGS, key]).encode()
    ).hexdigest()[:24]
    with _loaded.lock:  # one thread at a time looks up, compiles and loads (BoundedCache)
        hit = _loaded.get(digest)
        return hit if hit is not None else _load(name, cc, digest, make)


def _load(name: str, cc: str, digest: str, make: Callable[[], list[ca.Function]]) -> dict[str, ca.Function]:
    """The library ``digest`` from the cache folder, compiled first when it is not there; kept loaded."""
    library = cache_dir() / f"{name}-{digest}.so"
    names = library.with_suffix(".names")
    functions: list[ca.Function] | None = None
    try:
        if library.exists() and names.exists():
            os.utime(library)  # recently used: the last to be evicted
        else:
            functions = make()
            gen = ca.CodeGenerator(f"{name}.c", {"with_header": False})
            for f in functions:
                gen.add(f)
            _build(cc, gen.dump(), library, [f.name() for f in functions])
        loaded = {f: ca.external(f, str(library)) for f in names.read_text().split()}
    except (OSError, RuntimeError) as e:
        log.warning("compiling %s failed (%s); using CasADi's virtual machine", name, e)
        return {f.name(): f for f in (functions or make())}
    _loaded.put(digest, loaded)
    return loaded
