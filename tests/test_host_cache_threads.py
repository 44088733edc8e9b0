"""The in-process kernel caches shared by threads: hammered from two threads past their bound.

Building real kernels compiles C, so the builders are replaced by cheap ones whose value is a
known function of the key; the caches' own bookkeeping (look-up, most-recent order, eviction) is
what runs, with Python switching threads as often as it can. Two threads that want the same
missing entry at the same moment (a barrier, and a builder that takes a while, as compiling does)
must build it once.
"""

from __future__ import annotations

import sys
import threading
import time
from collections import Counter

import numpy as np
import pytest

from refine.optimise import compiled as compiled_module
from refine.optimise import derivatives
from refine.optimise.compiled import BoundedCache

KEYS = 12
BOUND = 8
ROUNDS = 5000
"""Look-ups per thread: a key is evicted and made again thousands of times."""


@pytest.fixture
def busy_switching():
    before = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # threads switch between almost every bytecode
    yield
    sys.setswitchinterval(before)


def _fake_load(loads: list, slow: bool = False):
    """In place of loading a library from the cache folder: a dict naming it, kept loaded as the real one."""

    def load(name: str, cc: str, digest: str, make) -> dict:
        library = _slow({"digest": digest}, loads)() if slow else {"digest": digest}
        compiled_module._loaded.put(digest, library)
        return library

    return load


def _hammer(work) -> list[BaseException]:
    errors: list[BaseException] = []

    def run(offset: int) -> None:
        try:
            for i in range(ROUNDS):
                work((i * 7 + offset) % KEYS)
        except BaseException as e:  # noqa: BLE001 - any failure of a thread is the test's failure
            errors.append(e)

    threads = [threading.Thread(target=run, args=(k,)) for k in (0, 1)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return errors


def test_two_threads_past_the_bound_get_the_right_values_and_keep_it(busy_switching):
    cache = BoundedCache(BOUND)
    made: Counter[int] = Counter()

    def work(k: int) -> None:
        def make() -> int:
            made[k] += 1
            return 3 * k + 1

        assert cache.get_or_make(k, make) == 3 * k + 1

    assert _hammer(work) == []
    assert len(cache) <= BOUND
    # each value is made only when it is missing: never twice for one look-up that another made
    assert all(n >= 1 for n in made.values()) and set(made) == set(range(KEYS))


def test_compiled_libraries_from_two_threads(busy_switching, monkeypatch):
    monkeypatch.setattr(compiled_module, "_loaded", BoundedCache(BOUND))
    monkeypatch.setattr(compiled_module, "compiler", lambda: "cc")
    monkeypatch.setattr(compiled_module, "_compiler_version", lambda cc: "test")
    monkeypatch.setattr(compiled_module, "_load", _fake_load([]))

    def work(k: int) -> None:
        a = compiled_module.compiled("t", f"key-{k}", lambda: [])
        b = compiled_module.compiled("t", f"key-{k}", lambda: [])
        assert a is b or a == b  # the same library for the same key, whoever loaded it

    assert _hammer(work) == []
    assert len(compiled_module._loaded) <= BOUND


def test_kernel_sets_from_two_threads(busy_switching, monkeypatch):
    monkeypatch.setattr(derivatives, "_kernel_cache", BoundedCache(BOUND))
    monkeypatch.setattr(derivatives, "compiler", lambda: None)
    monkeypatch.setattr(
        derivatives, "_make_kernels", lambda robot, base, tcp, axisymmetric, tool_in_world: (robot, {"x": float(base[0, 3])})
    )
    robot = object()

    def work(k: int) -> None:
        base = np.eye(4)
        base[0, 3] = k * 1e-3  # a new base placement per key [m]
        assert derivatives.waypoint_kernels(robot, base, np.eye(4), False) == {"x": k * 1e-3}

    assert _hammer(work) == []
    assert len(derivatives._kernel_cache) <= BOUND


def _at_once(ask) -> list:
    """``ask()`` from two threads released together; their answers."""
    barrier = threading.Barrier(2)
    answers: list = []

    def run() -> None:
        barrier.wait()
        answers.append(ask())

    threads = [threading.Thread(target=run) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return answers


def _slow(value, made: list):
    def make():
        made.append(value)
        time.sleep(0.05)  # the other thread asks meanwhile (compiling takes seconds)
        return value

    return make


def test_one_entry_wanted_by_two_threads_at_once_is_made_once(monkeypatch):
    cache = BoundedCache(BOUND)
    made: list = []
    assert _at_once(lambda: cache.get_or_make("k", _slow(7, made))) == [7, 7] and made == [7]

    loads: list = []
    monkeypatch.setattr(compiled_module, "_loaded", BoundedCache(BOUND))
    monkeypatch.setattr(compiled_module, "compiler", lambda: "cc")
    monkeypatch.setattr(compiled_module, "_compiler_version", lambda cc: "test")
    monkeypatch.setattr(compiled_module, "_load", _fake_load(loads, slow=True))
    a, b = _at_once(lambda: compiled_module.compiled("t", "key", lambda: []))
    assert a is b and len(loads) == 1

    sets: list = []
    monkeypatch.setattr(derivatives, "_kernel_cache", BoundedCache(BOUND))
    monkeypatch.setattr(derivatives, "compiler", lambda: None)
    monkeypatch.setattr(derivatives, "_make_kernels", lambda robot, *rest: _slow((robot, {"x": 1.0}), sets)())
    robot = object()
    a, b = _at_once(lambda: derivatives.waypoint_kernels(robot, np.eye(4), np.eye(4), False))
    assert a is b and len(sets) == 1
