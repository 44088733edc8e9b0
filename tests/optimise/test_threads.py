"""The thread count of the OpenBLAS under CasADi's IPOPT."""

from __future__ import annotations

import ctypes
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import casadi
import pytest

from refine.errors import InputError
from refine.optimise import threads


def _mapped_openblas() -> Path | None:
    """The file of CasADi's OpenBLAS that this process has mapped once IPOPT's plugin is loaded."""
    casadi.load_nlpsol("ipopt")
    folder = Path(casadi.__file__).parent.resolve()
    for line in Path("/proc/self/maps").read_text().splitlines():
        path = Path(line.split()[-1])
        if path.parent == folder and "openblas" in path.name:
            return path
    return None


def _openblas() -> ctypes.CDLL | None:
    if not Path("/proc/self/maps").exists():
        pytest.skip("no /proc/self/maps to tell which copy of the library is loaded")
    found = _mapped_openblas()
    return ctypes.CDLL(str(found)) if found else None


@pytest.fixture
def openblas(monkeypatch):
    """CasADi's OpenBLAS, its count restored after the test; no ``$REFINE_SOLVER_BLAS_THREADS``."""
    lib = _openblas()
    if lib is None:
        pytest.skip("this CasADi build has no OpenBLAS of its own")
    monkeypatch.delenv(threads.THREADS_ENV, raising=False)
    before = lib.openblas_get_num_threads()
    yield lib
    lib.openblas_set_num_threads(before)


def test_the_solver_blas_runs_on_the_count_set(openblas, monkeypatch):
    """After the limit, OpenBLAS itself reports the count asked for (1 by default, 2 when asked)."""
    assert threads.limit_solver_threads() == 1
    assert openblas.openblas_get_num_threads() == 1
    monkeypatch.setenv(threads.THREADS_ENV, "2")
    assert threads.limit_solver_threads() == 2
    assert openblas.openblas_get_num_threads() == 2


def test_a_count_changed_by_other_code_is_set_again(openblas):
    """Another caller resets OpenBLAS (as a benchmark restoring its own count does): the next limit sets it again."""
    assert threads.limit_solver_threads() == 1
    openblas.openblas_set_num_threads(3)
    assert openblas.openblas_get_num_threads() == 3
    assert threads.limit_solver_threads() == 1
    assert openblas.openblas_get_num_threads() == 1


def test_zero_leaves_the_count_alone(monkeypatch):
    monkeypatch.setenv(threads.THREADS_ENV, "0")
    assert threads.limit_solver_threads() is None


@pytest.mark.parametrize("text", ["-1", "two", "1.5"])
def test_a_bad_count_is_refused_naming_the_variable(monkeypatch, text):
    monkeypatch.setenv(threads.THREADS_ENV, text)
    with pytest.raises(InputError, match=threads.THREADS_ENV):
        threads.limit_solver_threads()


def test_the_count_is_set_on_the_copy_that_mumps_loaded():
    # CasADi's wheel holds the same OpenBLAS under several names (copies); a fresh interpreter with
    # OpenBLAS's own default (a thread per core) sets its solver count, and the copy that the process
    # has mapped after loading IPOPT's plugin (read from /proc/self/maps here) must report it
    if (os.cpu_count() or 1) < 2 or not Path("/proc/self/maps").exists():
        pytest.skip(
            "one core or no /proc: OpenBLAS's default is one thread anyway, or the copy cannot be told"
        )
    script = textwrap.dedent(
        """
        import ctypes
        from pathlib import Path
        import casadi
        from refine.optimise import threads
        casadi.load_nlpsol("ipopt")
        folder = Path(casadi.__file__).parent.resolve()
        mapped = [Path(line.split()[-1]) for line in Path("/proc/self/maps").read_text().splitlines()]
        path = next(p for p in mapped if p.parent == folder and "openblas" in p.name)
        lib = ctypes.CDLL(str(path))
        before = lib.openblas_get_num_threads()
        threads.limit_solver_threads()
        print(before, lib.openblas_get_num_threads(), flush=True)
        """
    )
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", threads.THREADS_ENV)
    }
    done = subprocess.run(
        [sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    before, after = (int(v) for v in done.stdout.split())
    assert before > 1  # the default: a thread per core, so the setting below shows
    assert after == threads.SOLVER_BLAS_THREADS == 1


def test_the_mapped_copy_comes_first(tmp_path):
    names = ["libcasadi-tp-openblas.so", "libcasadi-tp-openblas.so.0", "libcasadi-tp-openblas.so.0.3"]
    files = [tmp_path / n for n in names]
    for f in files:
        f.write_bytes(b"")
    maps = tmp_path / "maps"
    maps.write_text(f"7f00-7f10 r-xp 00000000 fd:01 42 {files[2]}\n7f20-7f30 rw-p 00000000 00:00 0 \n")
    assert threads._loaded_first(files, maps) == [files[2], files[1], files[0]]
    # nothing mapped (or no /proc): the soname-like name (one version number) first
    assert threads._loaded_first(files, tmp_path / "absent")[0] == files[1]


def test_a_mapped_path_that_is_not_utf8_neither_fails_nor_hides_the_mapped_copy(tmp_path):
    """/proc/self/maps holds each file's name as its bytes: another library of the process may live
    under a name that is not UTF-8 (a folder named in Latin-1), or be the very copy sought."""
    folder = tmp_path / os.fsdecode(b"caf\xe9")  # the bytes of a Latin-1 "café"
    folder.mkdir()
    names = ["libcasadi-tp-openblas.so", "libcasadi-tp-openblas.so.0", "libcasadi-tp-openblas.so.0.3"]
    files = [folder / n for n in names]
    for f in files:
        f.write_bytes(b"")
    other = os.fsencode(tmp_path) + b"/lib\xff.so"
    maps = tmp_path / "maps"
    maps.write_bytes(
        b"7f00-7f10 r-xp 00000000 fd:01 41 " + other + b"\n"
        b"7f20-7f30 r-xp 00000000 fd:01 42 " + os.fsencode(files[2]) + b"\n"
    )
    assert threads._loaded_first(files, maps) == [files[2], files[1], files[0]]
