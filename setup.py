"""Packaging hook: the robot registry (``robots/``) goes into the wheel as ``refine/robots_data``.

Everything else is declared in ``pyproject.toml``. A source checkout and an editable install read
``robots/`` where it is (``refine.robot.registry.robots_dir``); a built wheel carries a copy, made
here, without the folder's maintenance scripts.
"""

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent


class BuildWithRobots(build_py):
    """``build_py`` that also copies the robot registry into the built package."""

    def run(self) -> None:
        """Build the package, then copy ``robots/`` into it (not for an editable install)."""
        super().run()
        if getattr(self, "editable_mode", False):
            return
        target = Path(self.build_lib) / "refine" / "robots_data"
        if target.exists():
            shutil.rmtree(target)
        shutil.copytree(
            ROOT / "robots", target, ignore=shutil.ignore_patterns("*.py", "__pycache__", "*.pyc")
        )


setup(cmdclass={"build_py": BuildWithRobots})
