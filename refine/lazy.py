"""Deferred imports: let a library import a module it only needs for something a run never does.

Some libraries import, when they are imported, modules that ``refine`` never uses:

* toppra imports ``matplotlib.pyplot`` for its plotting helpers; loading pyplot costs more CPU
  time than the rest of the timing stage;
* trimesh imports ``networkx`` (about 60 ms) for graph algorithms on meshes that ``refine``'s
  convex pieces and report shapes never call;
* SciPy, the first time any of its subpackages is imported, copies NumPy's namespace, which
  imports ``numpy.f2py`` (the Fortran wrapper generator) and ``numpy.testing`` (about 45 ms).

While :func:`deferred_modules` is active, an ``import`` of the named modules binds a stand-in; the
stand-in imports the real module the first time one of its attributes is read, so a library that
does plot or walk a graph still works. The stand-ins leave ``sys.modules`` (and the attributes of
already imported parents) when the block ends, so every later ``import`` gets the real module.
:func:`lean_imports` is the block ``refine`` wraps around its imports of these libraries, and
:func:`on_first_use` defers the import of a library itself until a call needs it.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
import types
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

#: Modules the libraries ``refine`` uses import at their own import time and a run never uses.
UNUSED_AT_IMPORT = ("matplotlib", "matplotlib.pyplot", "networkx", "numpy.f2py", "numpy.testing")


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

    Modules already imported, or not installed, are left alone. A stand-in whose parent is already
    imported is also bound as the parent's attribute for the duration of the block (NumPy reaches
    its submodules through a module ``__getattr__`` that would otherwise import the real one).
    """
    added: dict[str, _Deferred] = {}
    bound: list[tuple[types.ModuleType, str, _Deferred]] = []
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
        elif parent and child not in vars(sys.modules[parent]):
            setattr(sys.modules[parent], child, stand_in)
            bound.append((sys.modules[parent], child, stand_in))
    sys.modules.update(added)
    try:
        yield
    finally:
        for name, stand_in in added.items():
            if sys.modules.get(name) is stand_in:
                del sys.modules[name]
        for module, child, stand_in in bound:
            if vars(module).get(child) is stand_in:
                delattr(module, child)


@contextmanager
def lean_imports() -> Iterator[None]:
    """Inside the block, the modules of :data:`UNUSED_AT_IMPORT` are deferred.

    Wrap the first import of toppra, trimesh or SciPy in it::

        with lean_imports():
            import trimesh
    """
    import numpy  # noqa: F401  (imported first so its submodules can be deferred)

    with deferred_modules(*UNUSED_AT_IMPORT):
        yield


class _OnFirstUse(types.ModuleType):
    """Stand-in for a module nobody has needed yet: imports it (lean) when an attribute is first read."""

    def __getattr__(self, attribute: str) -> object:
        real = self.__dict__.get("_real")
        if real is None:
            with lean_imports():
                real = importlib.import_module(self.__name__)
            self.__dict__["_real"] = real
        return getattr(real, attribute)


def on_first_use(name: str) -> types.ModuleType:
    """Module ``name`` as a stand-in that imports it under :func:`lean_imports` when first used.

    For a library only some calls need (trimesh: a mesh read, a convex cover, the report's shapes)::

        trimesh = on_first_use("trimesh")

    Once ``name`` is imported, the real module is returned instead.
    """
    return sys.modules.get(name) or _OnFirstUse(name)


def _has_submodule(parent: str, child: str) -> bool:
    """Whether package ``parent`` (not imported) has a submodule ``child``, without importing it."""
    spec = importlib.util.find_spec(parent)
    if spec is None or not spec.submodule_search_locations:
        return False
    from importlib.machinery import PathFinder

    return PathFinder.find_spec(f"{parent}.{child}", list(spec.submodule_search_locations)) is not None


def lazy_names(
    package: str, names: dict[str, str], namespace: dict[str, Any]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """A package's ``__getattr__`` and ``__dir__`` (PEP 562) that import its public names on first use.

    Args:
        package: the package's name, for the error message.
        names: public name -> module that defines it.
        namespace: the package's ``globals()``; a name read once is stored there.
    """

    def __getattr__(name: str) -> Any:
        module = names.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted(set(namespace) | set(names))

    return __getattr__, __dir__
