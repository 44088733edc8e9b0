"""The wheel is the product: built, installed into a fresh environment outside the source tree, run.

The wheel is built from this checkout (``pip wheel``), installed with ``--no-deps`` into a new
virtual environment that sees the test environment's packages (the dependencies) but not the source
tree, and run from a folder outside it: every example of docs/api.md, and ``refine run`` on a
bundled problem. The robot registry must come from the wheel itself.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import sysconfig
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(cmd: list[str], cwd: Path, timeout: float = 600.0) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "REFINE_ROBOTS_DIR")}
    done = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, (
        f"{' '.join(map(str, cmd))} exited {done.returncode}:\n{done.stdout}\n{done.stderr}"
    )
    return done


@pytest.mark.slow
def test_an_installed_wheel_runs_the_api_examples_and_a_bundled_problem(tmp_path):
    _run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "-q",
            str(ROOT),
            "-w",
            str(tmp_path / "dist"),
        ],
        tmp_path,
    )
    (wheel,) = (tmp_path / "dist").glob("refine-*.whl")
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", "--system-site-packages", str(venv)], tmp_path)
    python = venv / "bin" / "python"
    # the dependencies: the test environment's packages, also when it is itself a virtual environment
    # (--system-site-packages then sees the base interpreter's only); a plain path entry, so that
    # no .pth of the test environment (an editable install of refine) is run
    site = _run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], tmp_path)
    roots = tuple(sysconfig.get_paths()[k] for k in ("purelib", "platlib"))
    here = [p for p in sys.path if p.startswith(roots)]  # site-packages and what its .pth files added
    (Path(site.stdout.strip()) / "test_environment.pth").write_text("\n".join(here) + "\n")
    _run([str(python), "-m", "pip", "install", "-q", "--no-deps", str(wheel)], tmp_path)

    work = tmp_path / "work"  # the user's folder: the bundled problems beside it, no source tree, no robots/
    work.mkdir()
    (work / "problems").symlink_to(ROOT / "problems")
    script = work / "examples.py"
    script.write_text(
        textwrap.dedent(
            f"""
            import re, sys
            from pathlib import Path
            import refine
            from refine.robot.registry import robots_dir
            print("refine from", refine.__file__)
            print("robots from", robots_dir())
            doc = Path({str(ROOT / "docs" / "api.md")!r}).read_text()
            blocks = re.findall(r"^```python\\n(.*?)^```", doc, flags=re.S | re.M)
            namespace = {{"__name__": "api_doc"}}
            for k, block in enumerate(blocks):
                exec(compile(block, f"docs/api.md block {{k + 1}}", "exec"), namespace)
            print("examples run:", len(blocks))
            """
        )
    )
    # -P: the script's folder is not put on sys.path (nor is anything of the source tree)
    done = _run([str(python), "-P", str(script)], work)
    site = venv / "lib"
    installed = [ln for ln in done.stdout.splitlines() if ln.startswith(("refine from", "robots from"))]
    assert all(str(site) in ln for ln in installed), installed
    assert "examples run:" in done.stdout

    out = tmp_path / "out"
    _run([str(venv / "bin" / "refine"), "run", "problems/glass_adhesive", "--out", str(out)], work)
    result = json.loads((out / "result.json").read_text())
    assert result["status"] == "ok"
    assert result["robot"]["urdf"] == "robots/abb_irb4600_60_205/robot.urdf"
    assert (out / "glass_adhesive.mod").is_file()
