"""Why a segment of a path needed orientation slack or has no answer: the root cause, with its figure.

A refinement that is ``repaired`` or ``infeasible`` is explained here segment by segment. For each
segment the candidate causes are measured independently of the optimiser's own bookkeeping (reach
of the wrist centre or TCP, joint limits and multi-turn joints, the singularity measure, the
clearance of the dense check) and ordered by how much of the needed slack each explains. The
entries are what ``result.json`` reports under ``diagnosis`` (schema in
``docs/diagnosis.schema.json``); the ``repairs`` list and the texts are derived from them.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def closest_pair_text(clearance: Any, cell_names: set[str], margin_m: float, self_margin_m: float) -> str:
    """The pair with the least clearance along a checked path, saying whether it is a cell or a self pair.

    Args:
        clearance: a :class:`refine.collision.PathClearance`.
        cell_names: the names of the cell's objects (any other name is a robot link or tool shape).
        margin_m: the cell margin [m].
        self_margin_m: the self margin [m] (robot links and tool shapes among themselves).

    Returns:
        e.g. ``"least clearance link_5/link_5 vs link_7/link_7 (self pair, self margin 5 mm) at 6.2 mm"``,
        or an empty string for a path of one waypoint.
    """
    if not len(clearance.segment_clearance_m):
        return ""
    k = int(np.argmin(clearance.segment_clearance_m))
    body, other = clearance.segment_pair[k]
    if other in cell_names:
        kind, margin = "cell pair, margin", margin_m
    else:
        kind, margin = "self pair, self margin", self_margin_m
    distance = float(clearance.segment_clearance_m[k]) + margin  # that pair's own distance
    return f"least clearance {body} vs {other} ({kind} {margin * 1e3:g} mm) at {distance * 1e3:.1f} mm"
