"""Per-waypoint CasADi functions compiled to machine code once per robot, placement and tool.

The refinement evaluates the same small functions (TCP pose error and orientation measure, their
Jacobians and Hessians, the singularity measure) at every waypoint. CasADi's virtual machine runs them
interpreted; here they are written out as C by CasADi's code generator, compiled with the system's C
compiler into a shared library and loaded with :func:`casadi.external`. The library is cached on
disk under a key derived from the generated source itself (which holds the robot's kinematic
constants, the base placement and the tool), the CasADi version and the compiler, so a later run on
the same robot and tool reuses it and a change to any of them compiles a new one.

Cache folder: ``$REFINE_CACHE_DIR`` when set, else ``$XDG_CACHE_HOME/refine``, else
``~/.cache/refine``. ``REFINE_COMPILE=0`` turns compilation off. Without a C compiler (``$CC``,
else ``cc``, ``gcc`` or ``clang`` on the ``PATH``), or when compiling fails, the same functions run in
CasADi's virtual machine: slower, same results.
"""

from __future__ import annotations

import functools
import hashlib
import logging
import os
import shutil
import subprocess
import tempfile
from collections.abc import Callable
from pathlib import Path

import casadi as ca

log = logging.getLogger(__name__)

CACHE_ENV = "REFINE_CACHE_DIR"
COMPILE_ENV = "REFINE_COMPILE"
COMPILE_FLAGS = ("-O1", "-fPIC", "-shared")
"""-O1: the generated code is straight-line arithmetic; -O2/-O3 compile several times longer for a
few per cent of run time."""

_loaded: dict[str, dict[str, ca.Function]] = {}


def cache_dir() -> Path:
    """The folder holding compiled libraries (see the module docstring for the environment)."""
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV]).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg).expanduser() if xdg else Path.home() / ".cache") / "refine"


def compiler() -> str | None:
    """Path of the C compiler to use, or None when compilation is off or none is installed."""
    return _find_compiler(os.environ.get(COMPILE_ENV, "1"), os.environ.get("CC"), os.environ.get("PATH"))


@functools.cache
def _find_compiler(switch: str, cc: str | None, path: str | None) -> str | None:
    if switch.strip().lower() in {"0", "no", "false", "off"}:
        return None
    for name in (cc, "cc", "gcc", "clang"):
        if name and (found := shutil.which(name, path=path)):
            return found
    return None


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
    if digest in _loaded:
        return _loaded[digest]
    library = cache_dir() / f"{name}-{digest}.so"
    names = library.with_suffix(".names")
    functions: list[ca.Function] | None = None
    try:
        if not (library.exists() and names.exists()):
            functions = make()
            gen = ca.CodeGenerator(f"{name}.c", {"with_header": False})
            for f in functions:
                gen.add(f)
            _build(cc, gen.dump(), library, [f.name() for f in functions])
        loaded = {f: ca.external(f, str(library)) for f in names.read_text().split()}
    except (OSError, RuntimeError) as e:
        log.warning("compiling %s failed (%s); using CasADi's virtual machine", name, e)
        return {f.name(): f for f in (functions or make())}
    _loaded[digest] = loaded
    return loaded


@functools.cache
def _compiler_version(cc: str) -> str:
    proc = subprocess.run([cc, "--version"], capture_output=True, text=True, check=False)
    return proc.stdout.splitlines()[0] if proc.stdout else ""


def _build(cc: str, source: str, library: Path, names: list[str]) -> None:
    """Compile ``source`` into ``library`` atomically (a concurrent run sees all of it or nothing).

    The function names go into a ``.names`` file beside it, written after the library.
    """
    library.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=library.parent) as tmp:
        c_file, so_file = Path(tmp) / "kernels.c", Path(tmp) / library.name
        c_file.write_text(source)
        proc = subprocess.run(
            [cc, *COMPILE_FLAGS, str(c_file), "-o", str(so_file), "-lm"],
            capture_output=True,
            text=True,
            check=False,
        )
        if proc.returncode != 0:
            raise RuntimeError(f"{cc} exited with {proc.returncode}: {proc.stderr.strip()[:500]}")
        os.replace(so_file, library)
        listing = Path(tmp) / "names"
        listing.write_text("\n".join(names) + "\n")
        os.replace(listing, library.with_suffix(".names"))
    log.info("compiled %s", library)
