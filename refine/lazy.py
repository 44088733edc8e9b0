"""Deferred imports: let a library import a module it only needs for something a run never does.

toppra imports ``matplotlib.pyplot`` at import time for its plotting helpers, which ``refine``
never calls; loading pyplot costs more CPU time than the rest of the timing stage. While
:func:`deferred_modules` is active, an ``import`` of the named modules binds a stand-in; the
stand-in imports the real module the first time one of its attributes is read, so a library
that does plot still works. The stand-ins leave ``sys.modules`` when the block ends, so every
later ``import`` gets the real module.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
import types
from collections.abc import Iterator
from contextlib import contextmanager


class _Deferred(types.ModuleType):
    """Stand-in for a module: imports the real one when an attribute is first read."""

    def __getattr__(self, attribute: str) -> object:
        real = importlib.import_module(self.__name__)
        if real is self:  # still inside the deferred block: nothing to delegate to
            raise AttributeError(f"module {self.__name__!r} is deferred; {attribute!r} is not available yet")
        return getattr(real, attribute)


@contextmanager
def deferred_modules(*names: str) -> Iterator[None]:
    """Inside the block, ``import`` of any of ``names`` (dotted, parents first) binds a stand-in.

    Modules already imported, or not installed, are left alone.
    """
    added: dict[str, _Deferred] = {}
    for name in names:
        if name in sys.modules:
            continue
        parent, _, child = name.rpartition(".")
        if not parent:
            exists = importlib.util.find_spec(name) is not None
        elif parent in added:
            exists = _has_submodule(parent, child)
        elif parent in sys.modules:
            exists = importlib.util.find_spec(name) is not None
        else:  # finding it would import the parent: leave it
            continue
        if not exists:
            continue
        stand_in = _Deferred(name)
        added[name] = stand_in
        if parent in added:
            setattr(added[parent], child, stand_in)
    sys.modules.update(added)
    try:
        yield
    finally:
        for name, stand_in in added.items():
            if sys.modules.get(name) is stand_in:
                del sys.modules[name]


def _has_submodule(parent: str, child: str) -> bool:
    """Whether package ``parent`` (not imported) has a submodule ``child``, without importing it."""
    spec = importlib.util.find_spec(parent)
    if spec is None or not spec.submodule_search_locations:
        return False
    from importlib.machinery import PathFinder

    return PathFinder.find_spec(f"{parent}.{child}", list(spec.submodule_search_locations)) is not None
