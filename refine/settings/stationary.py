"""What a problem with a stationary tool may state, and which programs can carry one.

With ``[tool] tcp_in_world`` the tool stands in the world and the robot holds the part: the path
is given in the held part's frame (``[tool] part_in_flange`` places it on the flange), the
refinement meets each path pose as the tool seen from the part, the part's collision shapes
(``[[tool.collision]]``, poses in the flange frame) move with the flange, and the standing tool is
a cell object (``workpiece = true`` marks it as touched by design).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from refine.errors import InputError

STATIONARY_PROGRAMS = ("rapid", "krl")
"""The program formats written for a stationary tool: RAPID (a stationary TCP, ``tooldata`` with
``robhold`` FALSE, and the held part as a robot-held work object, ``wobjdata`` with ``robhold``
TRUE) and KRL (external TCP, ``$IPO_MODE = #TCP``: the standing tool as the BASE, the held part as
the TOOL). A program written for a tool on the flange would move the wrong frame, so the other formats
are refused before solving, saying what the controller offers."""

_NOT_WRITTEN = {
    "urscript": "URScript has no external-TCP motion (a UR moves its own TCP only)",
    "sunrise": "refine does not write a Sunrise program moving a held workpiece's frame yet",
    "tp": "refine does not write FANUC's remote TCP motions yet",
    "inform": "refine does not write Yaskawa's stationary-tool (external reference point) motions yet",
}


def check_stationary(problem: Any) -> None:
    """A problem with a stationary tool states its path in the held part and nothing it cannot.

    Raises:
        InputError: with a ``[demonstration]`` (a tracked hand tool is not read as a held part), a
            ``[frames] cad_in_world`` other than the identity (the path's frame is the part's,
            placed by ``[tool] part_in_flange``), or a placement repair (which moves a part on a table).
    """
    if problem.demonstration is not None:
        raise InputError(
            "[tool] tcp_in_world (a stationary tool) takes its path from [cad] in the held part's frame; "
            "a [demonstration] is not read for a held part"
        )
    if not np.allclose(problem.frames.cad_in_world, np.eye(4)):
        raise InputError(
            "[frames] cad_in_world: with a stationary tool ([tool] tcp_in_world) the path is in the held "
            "part's frame, which [tool] part_in_flange places on the flange; leave cad_in_world out"
        )
    if problem.repair.placement is not None:
        raise InputError(
            "[repair] placement moves a part on the table; with a stationary tool the robot holds the part: "
            "leave placement out"
        )


def check_stationary_programs(programs: tuple[str, ...]) -> None:
    """Every program format can carry a stationary tool (:data:`STATIONARY_PROGRAMS`).

    Raises:
        InputError: naming the format and what its controller offers.
    """
    for kind in programs:
        if kind not in STATIONARY_PROGRAMS:
            raise InputError(
                f"program format {kind!r} with a stationary tool ([tool] tcp_in_world): {_NOT_WRITTEN[kind]}; "
                f"the formats written for one are {', '.join(STATIONARY_PROGRAMS)}; [output] programs = [] writes "
                "none (the trajectory, PathML and result.json are written)"
            )
