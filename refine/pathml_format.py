"""The PathML document's vocabulary, shared by its writer and its reader.

The PathML document's vocabulary, shared by its writer (:mod:`refine.export.pathml`) and its
reader (:mod:`refine.cad.pathml_read`): the CAEX namespace, the Frame attribute's keys and units,
and the values each point carries.
"""

from __future__ import annotations

CAEX_NS = "http://www.dke.de/CAEX"


# (name, unit) of the Frame sub-attributes and of the other values of every Point.
FRAME_KEYS = (("x", "m"), ("y", "m"), ("z", "m"), ("rx", "deg"), ("ry", "deg"), ("rz", "deg"))


POINT_VALUES = (("speed", "m/s"), ("time", "s"), ("arcLength", "m"))


def caex_tag(name: str) -> str:
    """Qualified name ``{http://www.dke.de/CAEX}name`` of a CAEX element."""
    return f"{{{CAEX_NS}}}{name}"
