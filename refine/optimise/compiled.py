"""Per-waypoint CasADi functions compiled to machine code once per robot, placement and tool.

The refinement evaluates the same small functions (TCP pose error and orientation measure, their
Jacobians and Hessians, the singularity measure) at every waypoint. CasADi's virtual machine runs them
interpreted; here they are written out as C by CasADi's code generator, compiled with the system's C
compiler into a shared library and loaded with :func:`casadi.external`. The library is cached on
disk under a key derived from the generated source itself (which holds the robot's kinematic
constants, the base placement and the tool), the CasADi version and the compiler, so a later run on
the same robot and tool reuses it and a change to any of them compiles a new one.

Cache folder: ``$REFINE_CACHE_DIR`` when set, else ``$XDG_CACHE_HOME/refine``, else
``~/.cache/refine``. It holds ``<name>-<digest>.so`` and ``.names`` pairs and nothing else; after each
new library the least recently used pairs are removed until the folder holds at most
``$REFINE_CACHE_MAX_MB`` megabytes (default :data:`DEFAULT_CACHE_MAX_MB`; a library in use stays
loaded). In the process, at most :data:`LOADED_MAX` libraries stay loaded, least recently used
dropped first (a :class:`BoundedCache`, safe to use from several threads: a lock guards each
look-up and each insertion, and one per cache serialises building what is missing, so two threads
that want the same library compile it once). ``REFINE_COMPILE=0`` turns compilation off (nothing is written at all). Without a C compiler (``$CC``,
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
import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from pathlib import Path
from typing import Any

import casadi as ca

from refine.errors import InputError

log = logging.getLogger(__name__)

CACHE_ENV = "REFINE_CACHE_DIR"
CACHE_MAX_ENV = "REFINE_CACHE_MAX_MB"
DEFAULT_CACHE_MAX_MB = 256.0
"""The cache folder's default bound [MB]: some hundred robot, base and tool combinations."""
LOADED_MAX = 64
"""Libraries kept loaded in one process (each is a robot, base placement and tool)."""
COMPILE_ENV = "REFINE_COMPILE"
COMPILE_FLAGS = ("-O1", "-fPIC", "-shared")
"""-O1: the generated code is straight-line arithmetic; -O2/-O3 compile several times longer for a
few per cent of run time."""


class BoundedCache:
    """A least-recently-used map of at most ``max_entries`` entries, safe to share between threads.

    :meth:`get` and :meth:`put` each hold the cache's lock; :meth:`get_or_make` holds it while it
    looks up, makes and inserts an entry, so a value is made once however many threads ask for it
    at the same time, and making is serialised (kernels are built and compiled one at a time).
    The lock (:attr:`lock`) is re-entrant: ``make`` may use this cache again.
    """

    def __init__(self, max_entries: int) -> None:
        self.max_entries = max_entries
        self._entries: OrderedDict[Hashable, Any] = OrderedDict()
        self.lock = threading.RLock()

    def get(self, key: Hashable) -> Any:
        """The value under ``key`` (now the most recently used), or None."""
        with self.lock:
            if key not in self._entries:
                return None
            self._entries.move_to_end(key)
            return self._entries[key]

    def put(self, key: Hashable, value: Any) -> None:
        """Keep ``value`` under ``key``, dropping the least recently used entries past the bound."""
        with self.lock:
            self._entries[key] = value
            self._entries.move_to_end(key)
            while len(self._entries) > self.max_entries:
                self._entries.popitem(last=False)

    def get_or_make(self, key: Hashable, make: Callable[[], Any]) -> Any:
        """The value under ``key``, made by ``make()`` and kept when it is not there yet."""
        with self.lock:
            if key in self._entries:
                return self.get(key)
            value = make()
            self.put(key, value)
            return value

    def __len__(self) -> int:
        with self.lock:
            return len(self._entries)

    def clear(self) -> None:
        """Drop every entry."""
        with self.lock:
            self._entries.clear()


_loaded = BoundedCache(LOADED_MAX)


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
            evict(library.parent, cache_max_bytes(), keep=library)
        loaded = {f: ca.external(f, str(library)) for f in names.read_text().split()}
    except (OSError, RuntimeError) as e:
        log.warning("compiling %s failed (%s); using CasADi's virtual machine", name, e)
        return {f.name(): f for f in (functions or make())}
    _loaded.put(digest, loaded)
    return loaded


def cache_max_bytes() -> float:
    """The cache folder's bound [bytes], from ``$REFINE_CACHE_MAX_MB`` (module docstring).

    Raises:
        InputError: the variable is not a number >= 0.
    """
    raw = os.environ.get(CACHE_MAX_ENV)
    if raw is None or not raw.strip():
        return DEFAULT_CACHE_MAX_MB * 1e6
    try:
        value = float(raw)
    except ValueError:
        value = -1.0
    if not value >= 0.0:
        raise InputError(f"${CACHE_MAX_ENV} must be a number of megabytes >= 0, got {raw!r}")
    return value * 1e6


def evict(folder: Path, max_bytes: float, keep: Path | None = None) -> list[Path]:
    """Remove the least recently used libraries of ``folder`` until it holds at most ``max_bytes``.

    A library and its ``.names`` file go together; ``keep`` (the one just built) stays whatever its
    size. Only ``*.so`` / ``*.names`` pairs are touched, nothing else in the folder.

    Returns:
        The libraries removed, oldest first.
    """
    entries = []
    for so in folder.glob("*.so"):
        try:
            stat = so.stat()
            names = so.with_suffix(".names")
            size = stat.st_size + (names.stat().st_size if names.exists() else 0)
        except FileNotFoundError:  # removed by a concurrent run
            continue
        entries.append((stat.st_mtime, so, size))
    entries.sort()
    total = sum(size for _, _, size in entries)
    removed = []
    for _, so, size in entries:
        if total <= max_bytes:
            break
        if keep is not None and so == keep:
            continue
        for f in (so, so.with_suffix(".names")):
            f.unlink(missing_ok=True)
        total -= size
        removed.append(so)
    if removed:
        log.info("cache %s: removed %d least recently used libraries", folder, len(removed))
    return removed


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
