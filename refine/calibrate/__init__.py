"""Frame calibration from measured points: ``refine calibrate KIND ...``.

One module per measurement, all returning a :class:`~refine.calibrate.result.Calibration`:

* ``pivot``: the hand tool's tip in the tracker sensor frame, from a pivoting swing;
* ``receiver``: the tracker receiver in the world (``source_in_world``), from touched points or
  from a demonstration traced along the CAD path;
* ``robot_touch``: the robot's TCP in the flange frame (``tcp_in_flange``, four- and six-point
  methods) and the workpiece in the world (``cad_in_world``), from robot readings;
* ``rigid``: the rigid-transform solver (Kabsch/Umeyama by SVD) and its RANSAC, shared;
* ``zfield``: the tracker's distance-dependent z error, estimated alongside the frames;
* ``cost``: what the frames' uncertainty costs on the TCP path;
* ``simulate``: simulated measurements with a known truth, for tests and examples;
* ``files``: the measurement files (points, robot readings) and the problem-file snippets.
"""

from refine.calibrate.result import Calibration

__all__ = ["Calibration"]
