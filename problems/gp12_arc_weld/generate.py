"""Generate the data of the ``gp12_arc_weld`` problem: ``seam.dxf``, ``demo.liberty``, ``truth.csv``.

The fillet weld of ``kr8_arc_weld`` (the same seam, cell, welder and tracker) done by a Yaskawa Motoman GP12:
``problems/kr8_arc_weld/generate.py`` writes the files into this folder, and its reach and clearance
check runs on this problem's robot, tool and home.

Usage (from the repository root)::

    python problems/gp12_arc_weld/generate.py            # writes the files, checks reach and clearance
    python problems/gp12_arc_weld/generate.py --no-check # skip the IK and clearance check
"""

import runpy
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent

if __name__ == "__main__":
    generator = runpy.run_path(str(HERE.parent / "kr8_arc_weld" / "generate.py"))
    sys.exit(generator["main"](sys.argv[1:], folder=HERE))
