"""Suite-wide helpers: what a test needs that the repository does not ship.

A test that needs something outside the package (the shared AutomationML schemas in ``../shared``,
an optional module) asks for it through the ``require`` fixture. Where it is missing the test is
skipped with the reason in the summary (``-ra``) on a workstation, and fails under ``CI=true``, so a
CI run can never turn a missing prerequisite into a green line.
"""

from __future__ import annotations

import importlib
import os
from pathlib import Path
from types import ModuleType

import pytest

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
"""The shared read-only folder next to the repository (``../shared``)."""


def in_ci() -> bool:
    """True when the environment says this is a CI run (``CI=true``, ``1`` or ``yes``)."""
    return os.environ.get("CI", "").strip().lower() in ("true", "1", "yes")


def missing(reason: str) -> None:
    """Skip the running test with ``reason``, or fail it under ``CI=true``."""
    if in_ci():
        pytest.fail(f"{reason} (a missing prerequisite fails under CI=true)", pytrace=False)
    pytest.skip(f"{reason} (set CI=true to make this a failure)")


class Require:
    """What a test needs from outside the package; see the module docstring."""

    shared = SHARED

    @staticmethod
    def module(name: str) -> ModuleType:
        """Import ``name``, or skip/fail saying which module and why it did not import."""
        try:
            return importlib.import_module(name)
        except ImportError as e:
            missing(f"module {name!r} is not importable ({e})")
            raise  # unreachable: missing() always raises

    @staticmethod
    def path(path: Path, what: str) -> Path:
        """``path`` when it exists, otherwise skip/fail naming ``what`` it should hold."""
        if not path.exists():
            missing(f"{what} not found at {path}")
        return path


@pytest.fixture(scope="session")
def require() -> Require:
    """``require.module(name)``, ``require.path(path, what)``, ``require.shared`` (``../shared``)."""
    return Require()


TWO_TRACK_PROGRAM = """G21 G90
G0 X600 Y-100 Z310
G1 Z300 F3000
G1 Y-10
G1 Z310
G0 Y10
G1 Z300
G1 Y100
G1 Z310
"""
"""Two feed tracks on the line the generated demonstration follows (x = 600 mm, z = 300 mm, y from
-100 to 100 mm): y -100..-10 mm, then a retract, a rapid and a plunge, then y 10..100 mm."""


@pytest.fixture
def two_track_line_problem(tmp_path: Path) -> Path:
    """The generated line problem (``refine.synthetic.write_line_problem``) with its CAD path given
    as :data:`TWO_TRACK_PROGRAM`, a G-code file; the path of its problem.toml."""
    from refine.synthetic import write_line_problem

    problem = write_line_problem(tmp_path / "line")
    (problem.parent / "path.nc").write_text(TWO_TRACK_PROGRAM)
    toml = problem.read_text()
    assert 'file = "path.csv"' in toml
    problem.write_text(toml.replace('file = "path.csv"', 'file = "path.nc"\nformat = "gcode"'))
    return problem


@pytest.fixture(scope="session")
def glass_shift():
    """The glass cell's first answer (618 waypoints, collision on) and its part moved 2 mm along x and
    turned 0.3 deg about the pane's centre: ``problem``, ``fused``, ``common`` (the ``refine_path``
    arguments of the first answer, its cell included), ``first``, ``positions`` and ``orientations``
    (the moved path) and ``part`` (``common`` with the moved cell)."""
    import dataclasses
    from types import SimpleNamespace

    import numpy as np
    from scipy.spatial.transform import Rotation

    import refine
    from refine.frames import make_transform
    from refine.run.stages import fused_path

    p = refine.load_problem(Path(__file__).resolve().parents[1] / "problems" / "glass_adhesive")
    f = fused_path(p)
    common = {
        "speeds": f.speed,
        "arc_length": f.s,
        "tcp_in_flange": p.tool.tcp_in_flange,
        "base_in_world": p.robot.base_in_world,
        "cell": p.cell,
        "tool_shapes": p.tool.collision,
        "collision": p.collision,
    }
    first = refine.refine_path("abb_irb4600_60_205", f.positions, f.rotations, **common)
    assert first.status == "ok"
    centre = np.array([1.30, 0.0, 0.60])  # the pane's centre [m]
    R = Rotation.from_rotvec(np.radians(0.3) * np.array([0.0, 0.0, 1.0])).as_matrix()
    move = make_transform(p=centre - R @ centre + np.array([0.002, 0.0, 0.0]))
    move[:3, :3] = R
    moved = tuple(dataclasses.replace(o, pose=move @ o.pose) if o.workpiece else o for o in p.cell)
    return SimpleNamespace(
        problem=p,
        fused=f,
        common=common,
        first=first,
        positions=f.positions @ R.T + move[:3, 3],
        orientations=np.einsum("ij,njk->nik", R, f.rotations),
        part={**common, "cell": moved},
    )


@pytest.fixture(scope="module")
def chain_cache(tmp_path_factory):
    """A compiled-library cache folder of the test module's own, so every compiled chain the module loads is
    compiled from the code under test (``REFINE_CACHE_DIR`` and an empty in-process cache)."""
    from refine.robot import compiled_chain as compiled_module

    folder = tmp_path_factory.mktemp("chains")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("REFINE_CACHE_DIR", str(folder))
        mp.setattr(compiled_module, "_loaded", compiled_module.BoundedCache(compiled_module.LOADED_MAX))
        yield folder
