"""Collision model of the cell: signed distances, witness points, their Jacobians, the dense check.

* :class:`CollisionModel` (``model.py``): robot link primitives, tool shapes and cell objects as
  FCL objects; :meth:`~CollisionModel.contacts` lists the close pairs at a configuration,
  :meth:`~CollisionModel.point_jacobian` and :func:`linearised_distance` turn a contact into a
  linear constraint on the joints.
* Which pairs are checked: ``pairs.py``. One pair's signed distance and witness points, with
  python-fcl's mesh pitfalls worked around: ``distance.py``. Bodies and bounds: ``geometry.py``.
* :func:`check_path_clearance` (``check.py``): the dense final check between waypoints;
  :func:`margins_proved` its proof alone, without the figures; the conservative advancement both
  build on: ``advance.py``. What a model takes from the model built before it: ``kept.py``.
"""

from refine.collision.check import (
    ClearanceRun,
    PathClearance,
    check_path_clearance,
    joint_reach,
    margins_proved,
)
from refine.collision.contact import Contact, linearised_distance
from refine.collision.model import CollisionModel

__all__ = [
    "ClearanceRun",
    "CollisionModel",
    "Contact",
    "PathClearance",
    "check_path_clearance",
    "joint_reach",
    "linearised_distance",
    "margins_proved",
]
