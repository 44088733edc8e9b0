"""Shared libraries compiled from generated C: the compiler, the cache folder, building and eviction.

The optimiser's per-waypoint kernels (:mod:`refine.optimise.compiled`) and the robot's compiled
batch kinematics (:mod:`refine.robot.compiled_chain`) are C written out by CasADi's code generator,
compiled once with the system's C compiler into a shared library and kept in a cache folder under
a key derived from what the code is made of, so a later run reuses the library.

Cache folder: ``$REFINE_CACHE_DIR`` when set, else ``$XDG_CACHE_HOME/refine``, else
``~/.cache/refine``. It holds ``<name>-<digest>.so`` and ``.names`` pairs and nothing else; after each
new library the least recently used pairs are removed (:func:`evict`) until the folder holds at most
``$REFINE_CACHE_MAX_MB`` megabytes (default :data:`DEFAULT_CACHE_MAX_MB`; a library in use stays
loaded). ``REFINE_COMPILE=0`` turns compilation off (nothing is written at all); so does the lack
of a C compiler (``$CC``, else ``cc``, ``gcc`` or ``clang`` on the ``PATH``): :func:`compiler` is
then None and the callers evaluate the same functions another way.
"""

from __future__ import annotations

import functools
import logging
import os
import shutil
import subprocess
import tempfile
import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable, Sequence
from pathlib import Path
from typing import Any

from refine.errors import InputError

log = logging.getLogger(__name__)

CACHE_ENV = "REFINE_CACHE_DIR"
CACHE_MAX_ENV = "REFINE_CACHE_MAX_MB"
DEFAULT_CACHE_MAX_MB = 256.0
"""The cache folder's default bound [MB]: some hundred robot, base and tool combinations."""
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
def compiler_version(cc: str) -> str:
    """The first line of ``cc --version`` (part of every library's key)."""
    proc = subprocess.run([cc, "--version"], capture_output=True, text=True, check=False)
    return proc.stdout.splitlines()[0] if proc.stdout else ""


def build_library(
    cc: str, source: str, library: Path, names: list[str], flags: Sequence[str] = COMPILE_FLAGS
) -> None:
    """Compile ``source`` into ``library`` atomically (a concurrent run sees all of it or nothing).

    The function names go into a ``.names`` file beside it, written after the library; the cache
    folder is then brought back under its bound (:func:`evict`, keeping ``library``).

    Raises:
        OSError: the folder or a file could not be written.
        RuntimeError: the compiler failed (its exit status and the start of its messages).
    """
    library.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=library.parent) as tmp:
        c_file, so_file = Path(tmp) / "kernels.c", Path(tmp) / library.name
        c_file.write_text(source)
        proc = subprocess.run(
            [cc, *flags, str(c_file), "-o", str(so_file), "-lm"],
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
    evict(library.parent, cache_max_bytes(), keep=library)


def cached_library(
    cc: str, source: Callable[[], str], library: Path, names: list[str], flags: Sequence[str]
) -> None:
    """Make sure ``library`` is in the cache folder, compiling ``source()`` only where it is missing.

    Where it and its ``.names`` are there, it is marked recently used (the last to be evicted);
    else it is compiled (:func:`build_library`).

    Raises:
        OSError, RuntimeError: as :func:`build_library`.
    """
    if library.exists() and library.with_suffix(".names").exists():
        os.utime(library)
    else:
        build_library(cc, source(), library, names, flags)
