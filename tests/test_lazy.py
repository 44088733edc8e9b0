"""Deferred imports (refine.lazy): a stand-in until first use, the real module afterwards."""

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from refine.lazy import deferred_modules, lazy_names


def _package(tmp_path, name):
    """A package ``name`` with a submodule ``heavy`` that appends to a log file when it is loaded."""
    log = tmp_path / f"{name}.log"
    pkg = tmp_path / name
    pkg.mkdir()
    (pkg / "__init__.py").write_text(f"open({str(log)!r}, 'a').write('pkg\\n')\n")
    (pkg / "heavy.py").write_text(f"open({str(log)!r}, 'a').write('heavy\\n')\nANSWER = 42\n")
    return log


def test_import_inside_the_block_loads_nothing_until_an_attribute_is_read(tmp_path, monkeypatch):
    log = _package(tmp_path, "deferred_pkg_a")
    monkeypatch.syspath_prepend(str(tmp_path))
    with deferred_modules("deferred_pkg_a", "deferred_pkg_a.heavy"):
        import deferred_pkg_a.heavy as heavy
    assert not log.exists()  # neither the package nor its submodule ran
    assert "deferred_pkg_a.heavy" not in sys.modules  # the stand-ins are gone after the block
    assert heavy.ANSWER == 42  # first read: the real module is imported
    assert log.read_text().splitlines() == ["pkg", "heavy"]
    import deferred_pkg_a.heavy as real

    assert real is sys.modules["deferred_pkg_a.heavy"] and real is not heavy
    assert real.ANSWER == 42 and log.read_text().splitlines() == ["pkg", "heavy"]  # loaded once


def test_modules_already_imported_or_missing_are_left_alone(tmp_path, monkeypatch):
    log = _package(tmp_path, "deferred_pkg_b")
    monkeypatch.syspath_prepend(str(tmp_path))
    import deferred_pkg_b.heavy as before

    with deferred_modules("deferred_pkg_b", "deferred_pkg_b.heavy", "no_such_module_anywhere"):
        import deferred_pkg_b.heavy as inside

        assert "no_such_module_anywhere" not in sys.modules
    assert inside is before
    assert log.read_text().splitlines() == ["pkg", "heavy"]


def test_toppra_is_imported_without_pyplot_and_still_works():
    code = textwrap.dedent(
        """
        import sys
        import numpy as np
        from refine.timing import time_parameterise
        s = np.linspace(0.0, 1.0, 50)
        q = np.column_stack([np.sin(s), np.cos(s)])
        t = time_parameterise(s, q, np.full(50, 0.5), np.array([1.0, 1.0]), np.array([2.0, 2.0]))
        assert t.t[-1] > 0
        print("matplotlib.pyplot" in sys.modules)
        import toppra.algorithm.algorithm as a
        a.plt.figure  # toppra's plotting helpers still reach pyplot
        print("matplotlib.pyplot" in sys.modules)
        """
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["False", "True"]


def test_a_submodule_reached_through_the_parents_getattr_is_deferred(tmp_path, monkeypatch):
    """NumPy's way: ``import pkg.sub as sub`` inside the parent's module ``__getattr__``."""
    log = tmp_path / "deferred_pkg_c.log"
    pkg = tmp_path / "deferred_pkg_c"
    pkg.mkdir()
    (pkg / "__init__.py").write_text(
        "__all__ = ['heavy']\n"
        "def __getattr__(name):\n"
        "    if name == 'heavy':\n"
        "        import deferred_pkg_c.heavy as heavy\n"
        "        return heavy\n"
        "    raise AttributeError(name)\n"
    )
    (pkg / "heavy.py").write_text(f"open({str(log)!r}, 'a').write('heavy\\n')\nANSWER = 42\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    import deferred_pkg_c

    namespace: dict = {}
    with deferred_modules("deferred_pkg_c.heavy"):
        exec("from deferred_pkg_c import *", namespace)  # what SciPy does to NumPy
    assert not log.exists()
    assert "heavy" not in vars(deferred_pkg_c)  # the parent is as it was
    assert namespace["heavy"].ANSWER == 42  # the copy still reaches the real module
    assert deferred_pkg_c.heavy.ANSWER == 42
    assert log.read_text().splitlines() == ["heavy"]


def test_a_run_does_not_load_what_its_libraries_import_for_nothing():
    code = textwrap.dedent(
        """
        import sys
        import refine.frames, refine.robot.geometry, refine.report.scene
        print(sorted(m for m in ("networkx", "numpy.f2py", "numpy.testing") if m in sys.modules))
        import trimesh.graph
        print(trimesh.graph.nx.Graph.__name__)  # trimesh's graph helpers still reach networkx
        import scipy._lib.array_api_compat.numpy as compat
        print(compat.testing.assert_allclose.__name__)
        """
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["[]", "Graph", "assert_allclose"]


@pytest.mark.slow
def test_a_whole_run_loads_none_of_the_modules_it_never_uses(tmp_path):
    """The glass cell's run in a fresh process: what libraries import for nothing stays out."""
    root = Path(__file__).resolve().parents[1]
    code = textwrap.dedent(
        f"""
        import sys
        from refine.problem import load_problem
        from refine.run.write import run
        result = run(load_problem({str(root / "problems" / "glass_adhesive")!r}), {str(tmp_path / "out")!r})
        assert result.status == "ok", result.status
        never = ("networkx", "numpy.f2py", "numpy.testing", "matplotlib.pyplot", "scipy.stats")
        print(sorted(m for m in never if m in sys.modules))
        """
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["[]"]


def test_the_cad_stage_imports_only_its_own_format_s_reader(tmp_path):
    csv = tmp_path / "path.csv"
    csv.write_text("x,y,z\n0,0,0\n100,0,0\n100,50,0\n")
    code = textwrap.dedent(
        f"""
        import sys
        import refine.cad
        from refine.cad.csv_ import points_from_csv
        points = points_from_csv({str(csv)!r}, "mm")
        print(len(points), "ezdxf" in sys.modules)
        from refine.cad import points_from_dxf  # the package's names still reach every reader
        print(points_from_dxf.__module__, "ezdxf" in sys.modules)
        """
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["3", "False", "refine.cad.dxf", "True"]


def test_lazy_names_import_a_name_on_first_read_and_keep_it():
    namespace: dict = {"already": 1}
    getattr_, dir_ = lazy_names("pkg", {"dedent": "textwrap"}, namespace)
    assert "dedent" in dir_() and "already" in dir_()
    assert getattr_("dedent") is textwrap.dedent
    assert namespace["dedent"] is textwrap.dedent  # stored: the next read does not come here
    with pytest.raises(AttributeError, match="module 'pkg' has no attribute 'missing'"):
        getattr_("missing")


def test_trimesh_is_imported_by_the_first_mesh_call_not_by_the_modules_that_use_it():
    """The robot, collision, CAD mesh and report modules import without trimesh; their first mesh
    call imports it (with what it imports for nothing deferred) and every module then shares it."""
    code = textwrap.dedent(
        """
        import sys
        import refine.robot.registry, refine.collision, refine.report.scene, refine.cad.mesh
        import refine.robot.convex as convex
        print("trimesh" in sys.modules)
        piece = convex.ConvexPiece.hull_of([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0.1, 0.1, 0.1]])
        print("trimesh" in sys.modules, "networkx" in sys.modules, len(piece.vertices), round(piece.mesh.volume, 6))
        import trimesh
        box = refine.report.scene.mesh_of_geometry(__import__("fcl").Box(1.0, 2.0, 3.0))
        print(isinstance(box, trimesh.Trimesh), round(box.volume, 6))
        """
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    # the unit corner tetrahedron: 4 corners (the inner point dropped), volume 1/6; the box 1 x 2 x 3
    assert out.split() == ["False", "True", "False", "4", "0.166667", "True", "6.0"]
