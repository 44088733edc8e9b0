"""The thread count of the OpenBLAS under CasADi's IPOPT."""

from __future__ import annotations

import ctypes
from pathlib import Path

import casadi
import pytest

from refine.errors import InputError
from refine.optimise import threads


def _openblas() -> ctypes.CDLL | None:
    found = sorted(Path(casadi.__file__).parent.glob("libcasadi-tp-openblas.so*"))
    return ctypes.CDLL(str(found[0])) if found else None


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
