"""Reading PathML back: a CAEX 3.0 document written by :mod:`refine.export.pathml` or another tool.

Elements are found by the last segment of their role requirement (``Path``, ``Layer``, ``Track``,
``Point``), so PathML from another tool that uses the same role names reads too; the common length,
angle, speed and time units are converted to metres, degrees, m/s and seconds. Point frames become
rotation matrices with ``R = Rz(rz)·Ry(ry)·Rx(rx)`` (AutomationML ``Frame``).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from lxml import etree

from refine.errors import InputError
from refine.frames import matrix_from_fixed_xyz
from refine.pathml_format import FRAME_KEYS, POINT_VALUES, caex_tag
from refine.settings import ProcessParameter
from refine.types import Array

log = logging.getLogger(__name__)

_IE, _ATTR, _VALUE = caex_tag("InternalElement"), caex_tag("Attribute"), caex_tag("Value")
_ROLE_REQ = caex_tag("RoleRequirements")
_TO_SI = {"m": 1.0, "mm": 1e-3, "cm": 1e-2, "m/s": 1.0, "mm/s": 1e-3, "s": 1.0, "ms": 1e-3}
_TO_SI |= {"deg": 1.0, "degree": 1.0, "°": 1.0, "rad": 180.0 / math.pi}


@dataclass(frozen=True)
class PathMLTrack:
    """A track read back: points in the frame of the hierarchy ({F} for refine's documents).

    Attributes:
        parameters: the track's ``xs:double`` attributes in their own units.
        positions: TCP positions [m], shape (N, 3).
        rotations: TCP orientations R_F_TCP, shape (N, 3, 3).
        speed: TCP speed [m/s], shape (N,).
        time: time stamps [s], shape (N,).
        s: arc length [m], shape (N,).
    """

    name: str
    id: str
    parameters: tuple[ProcessParameter, ...]
    positions: Array
    rotations: Array
    speed: Array
    time: Array
    s: Array


@dataclass(frozen=True)
class PathMLLayer:
    """A layer read back, with its tracks in document order.

    Attributes:
        parameters: the layer's ``xs:double`` attributes in their own units (tracks may override).
    """

    name: str
    id: str
    parameters: tuple[ProcessParameter, ...]
    tracks: tuple[PathMLTrack, ...]


@dataclass(frozen=True)
class PathMLDocument:
    """A PathML document read back: header facts and the layers of its (first) Path element.

    Attributes:
        file_name: the ``FileName`` the document gives itself.
        origin_name: the writing tool (``SourceDocumentInformation/@OriginName``).
        origin_version: the writing tool's version.
        written_at: ``LastWritingDateTime`` as written (ISO 8601).
        path_name: name of the Path element.
        layers: the layers in document order.
    """

    file_name: str
    origin_name: str
    origin_version: str
    written_at: str
    path_name: str
    layers: tuple[PathMLLayer, ...]


def _role_of(el: etree._Element) -> str:
    req = el.find(_ROLE_REQ)
    return "" if req is None else req.get("RefBaseRoleClassPath", "").rsplit("/", 1)[-1]


def _children(el: etree._Element, role: str) -> list[etree._Element]:
    return [child for child in el.iterchildren(_IE) if _role_of(child) == role]


def _number(attr: etree._Element, where: str, to_si: bool = True) -> float:
    """The attribute's Value (or DefaultValue), converted to SI/degrees when ``to_si``."""
    text = attr.findtext(_VALUE)
    if text is None:
        text = attr.findtext(caex_tag("DefaultValue"))
    unit = attr.get("Unit")
    here = f"PathML {where}/{attr.get('Name')}"
    try:
        value = float(text)  # type: ignore[arg-type]
    except (TypeError, ValueError) as e:
        raise InputError(f"{here}: not a number: {text!r}") from e
    if not to_si or not unit:
        return value
    if unit not in _TO_SI:
        raise InputError(f"{here}: unknown unit {unit!r}; known: {', '.join(_TO_SI)}")
    return value * _TO_SI[unit]


def _read_parameters(el: etree._Element, where: str) -> tuple[ProcessParameter, ...]:
    """The ``xs:double`` attributes of a Layer or Track, in their own units."""
    return tuple(
        ProcessParameter(a.get("Name", ""), _number(a, where, to_si=False), a.get("Unit", ""))
        for a in el.iterchildren(_ATTR)
        if a.get("AttributeDataType") == "xs:double"
    )


def _read_track(el: etree._Element, where: str) -> PathMLTrack:
    points = _children(el, "Point")
    if not points:
        raise InputError(f"PathML {where}: a track without points")
    rows = np.empty((len(points), 9))
    for k, p in enumerate(points):
        attrs = {a.get("Name"): a for a in p.iterchildren(_ATTR)}
        here = f"{where}/{p.get('Name')}"
        if "Frame" not in attrs:
            raise InputError(f"PathML {here}: no Frame attribute")
        frame = {a.get("Name"): a for a in attrs["Frame"].iterchildren(_ATTR)}
        for j, (key, _unit) in enumerate(FRAME_KEYS + POINT_VALUES):
            source = frame if j < 6 else attrs
            rows[k, j] = _number(source[key], here) if key in source else math.nan
        if np.isnan(rows[k, :6]).any():
            raise InputError(f"PathML {here}: Frame needs x, y, z, rx, ry, rz")
    return PathMLTrack(
        el.get("Name", ""),
        el.get("ID", ""),
        _read_parameters(el, where),
        rows[:, :3],
        matrix_from_fixed_xyz(rows[:, 3:6]),
        rows[:, 6],
        rows[:, 7],
        rows[:, 8],
    )


def read_pathml(path: str | Path) -> PathMLDocument:
    """Read a PathML document (ours or another tool's with the same role names).

    Missing ``speed``, ``time`` or ``arcLength`` values read as NaN.

    Raises:
        InputError: not XML, no Path element, or a point without a complete Frame.
    """
    try:
        root = etree.parse(str(path)).getroot()
    except (OSError, etree.XMLSyntaxError) as e:
        raise InputError(f"cannot read PathML {path}: {e}") from e
    paths = [
        el
        for h in root.iterchildren(caex_tag("InstanceHierarchy"))
        for el in h.iter(_IE)
        if _role_of(el) == "Path"
    ]
    if not paths:
        raise InputError(f"PathML {path}: no InternalElement with a Path role requirement")
    if len(paths) > 1:
        log.warning("PathML %s: %d Path elements, reading the first", path, len(paths))
    layers = []
    for layer in _children(paths[0], "Layer"):
        where = f"{paths[0].get('Name')}/{layer.get('Name')}"
        tracks = tuple(_read_track(t, f"{where}/{t.get('Name')}") for t in _children(layer, "Track"))
        layers.append(
            PathMLLayer(layer.get("Name", ""), layer.get("ID", ""), _read_parameters(layer, where), tracks)
        )
    info = root.find(caex_tag("SourceDocumentInformation"))
    info_get = info.get if info is not None else (lambda key, default="": default)
    return PathMLDocument(
        root.get("FileName", ""),
        info_get("OriginName", ""),
        info_get("OriginVersion", ""),
        info_get("LastWritingDateTime", ""),
        paths[0].get("Name", ""),
        tuple(layers),
    )
