"""The fusion stage: demonstration and CAD path into the path the optimiser refines.

The fusion stage: the demonstration matched to the CAD path in the worker's direction and from
the worker's start (:mod:`refine.fuse.order`), aligned (:mod:`refine.fuse.align`), and turned into
the :class:`~refine.paths.FusedPath` the optimiser refines.
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation, Slerp

from refine.frames import transform_points
from refine.fuse.align import align, demo_tcp_poses
from refine.fuse.order import orient, reorder
from refine.paths import CadPath, Demonstration, FusedPath

logger = logging.getLogger(__name__)


def fuse(
    cad: CadPath,
    demo: Demonstration,
    source_in_world: ArrayLike,
    sensor_in_tcp: ArrayLike,
    *,
    speed_smoothing_m: float = 0.03,
    fit_distortion: bool = True,
) -> FusedPath:
    """CAD positions with the demonstrated tool orientation and speed at every waypoint.

    Args:
        cad: the CAD path in {F}.
        demo: the cleaned demonstration (sensor {E} in the receiver {S}).
        source_in_world: receiver pose in the world, T_F_S, shape (4, 4).
        sensor_in_tcp: sensor pose in the tool frame, T_TCP_E, shape (4, 4).
        speed_smoothing_m: half-width of the arc-length window of the speed fit [m].
        fit_distortion: fit and remove a smooth tracker position error; see :func:`align`.

    The waypoints are first put in the worker's order (:func:`orient`): the direction the worker
    went and, on a closed path, the start the worker started from, so every output follows it.

    Returns:
        The fused path in the worker's order (``order`` says which); ``speed`` is floored at 10 %
        of the median demonstrated speed.

    Raises:
        InputError: bad arguments, a direction that cannot be told, or a demonstration that does
            not cover the path.
    """
    reverse, start, order = orient(cad, demo, source_in_world, sensor_in_tcp)
    kwargs = {"speed_smoothing_m": speed_smoothing_m, "fit_distortion": fit_distortion}
    run = reorder(cad, reverse, start)
    a = align(run, demo, source_in_world, sensor_in_tcp, **kwargs)
    if order.start_source == "alignment":  # the corrected demo may start a waypoint or more away
        k = int(np.argmin(np.abs(run.s - a.start_shift_m % run.length))) % (len(run.s) - 1)
        if k:
            logger.info(
                "path start moved by %d waypoints (%.1f mm) after the tracker correction",
                k,
                a.start_shift_m * 1e3,
            )
            run = reorder(cad, reverse, (start + k) % (len(run.s) - 1))
            a = align(run, demo, source_in_world, sensor_in_tcp, **kwargs)
    order = replace(order, start_offset_m=run.start_offset_m)
    cad = run
    T_F_TCP = demo_tcp_poses(demo, source_in_world, sensor_in_tcp)
    slerp = Slerp(demo.t, Rotation.from_matrix(T_F_TCP[:, :3, :3]))
    rotations = slerp(np.clip(a.t, demo.t[0], demo.t[-1])).as_matrix()
    return FusedPath(
        cad.s.copy(),
        cad.positions.copy(),
        rotations,
        a.speed,
        a.t,
        a.residual,
        order,
        exact_s=cad.exact_s,
        exact=cad.exact,
        demo_positions=None if a.corrected is None else transform_points(source_in_world, a.corrected),
    )
