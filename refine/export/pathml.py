"""PathML: the refined path as a CAEX 3.0 (AutomationML 2.10) document, and its validation.

Layout of the document (child order as ``CAEX_ClassModel_V.3.0.xsd`` requires)::

    CAEXFile SchemaVersion="3.0" FileName=...
      SuperiorStandardVersion  AutomationML 2.10
      SourceDocumentInformation OriginName="refine" ...
      InstanceHierarchy <problem name>
        InternalElement "Path"             role PathMLRoleClassLib/Path
          InternalElement "Layer1"         role .../Layer, process parameters as attributes
            InternalElement "Track1"       role .../Track, process parameters as attributes
              InternalElement "P0000" ...  role .../Point: Frame, speed, time, arcLength
      RoleClassLib PathMLRoleClassLib      Path, Layer, Track, Point
      RoleClassLib AutomationMLBaseRoleClassLib   (the subset the roles derive from)
      AttributeTypeLib AutomationMLBaseAttributeTypeLib   (Frame)

A point's ``Frame`` is the TCP pose reached in the world frame {F} (Path, Layers and Tracks carry no
frame, so {F} is the frame of the hierarchy): x, y, z [m] and rx, ry, rz [deg] about the fixed x,
y, z axes (``R = Rz(rz)·Ry(ry)·Rx(rx)``). Every number is ``xs:double`` with a ``Unit`` and is
written with Python's ``repr`` (shortest round-tripping form, no locale).

IDs are name-based GUIDs (UUID version 5) from the problem name and the element's path in the
hierarchy, so writing the same problem twice gives the same IDs and the files diff cleanly. A track's
parameters refine its layer's: a reader takes the track value where both give one.

:func:`refine.cad.pathml_read.read_pathml` reads such documents back.
"""

from __future__ import annotations

import logging
import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

import numpy as np
from lxml import etree

from refine.errors import InputError
from refine.export.sink import put_bytes
from refine.export.sink import stamp as sink_stamp
from refine.frames import fixed_xyz_from_matrix
from refine.pathml_format import CAEX_NS, FRAME_KEYS, POINT_VALUES, caex_tag
from refine.paths import Trajectory
from refine.problem import Problem
from refine.settings import ProcessParameter
from refine.version import __version__

log = logging.getLogger(__name__)

_XSI_NS = "http://www.w3.org/2001/XMLSchema-instance"
ROLE_LIB = "PathMLRoleClassLib"
_BASE_ROLE = "AutomationMLBaseRoleClassLib/AutomationMLBaseRole"
_FRAME_TYPE = "AutomationMLBaseAttributeTypeLib/Frame"
_GUID_NAMESPACE = uuid.uuid5(uuid.NAMESPACE_DNS, "pathml.refine")


_IE, _ATTR, _VALUE, _ROLE_REQ = (
    caex_tag("InternalElement"),
    caex_tag("Attribute"),
    caex_tag("Value"),
    caex_tag("RoleRequirements"),
)


@dataclass(frozen=True)
class TrackLayout:
    """One track to write: the waypoints ``start <= k < stop`` of the trajectory.

    Attributes:
        name: element name, e.g. ``"Track1"``.
        start: first waypoint index.
        stop: one past the last waypoint index.
        parameters: process values of this track (override the layer's).
    """

    name: str
    start: int
    stop: int
    parameters: tuple[ProcessParameter, ...] = ()


@dataclass(frozen=True)
class LayerLayout:
    """One layer to write (a pass of a multi-pass weld, a bead of glue): its tracks, in order."""

    name: str
    tracks: tuple[TrackLayout, ...]
    parameters: tuple[ProcessParameter, ...] = ()


def default_layers(trajectory: Trajectory, problem: Problem) -> list[LayerLayout]:
    """One layer holding one track over all waypoints, both with the problem's process parameters."""
    params = problem.process.parameters
    track = TrackLayout("Track1", 0, len(trajectory), params)
    return [LayerLayout("Layer1", (track,), params)]


def _check_layers(layers: Sequence[LayerLayout], n: int) -> None:
    if not layers:
        raise InputError("PathML layers: need at least one layer")
    names = [layer.name for layer in layers]
    if len(set(names)) != len(names):
        raise InputError(f"PathML layers: names must be unique (they key the GUIDs), got {names}")
    for layer in layers:
        if not layer.tracks or len({t.name for t in layer.tracks}) != len(layer.tracks):
            raise InputError(f"PathML layer {layer.name!r}: needs one or more uniquely named tracks")
        for tr in layer.tracks:
            if not 0 <= tr.start < tr.stop <= n:
                raise InputError(
                    f"PathML track {layer.name}/{tr.name}: waypoints [{tr.start}, "
                    f"{tr.stop}) must be a non-empty range inside [0, {n})"
                )


# ---- writing ----------------------------------------------------------------------------------


class _Writer:
    """Builds the element tree; GUIDs come from the problem name and the element path."""

    def __init__(self, problem_name: str) -> None:
        self.prefix = problem_name

    def guid(self, key: str) -> str:
        return str(uuid.uuid5(_GUID_NAMESPACE, f"{self.prefix}/{key}"))

    def element(self, parent: etree._Element, name: str, key: str) -> etree._Element:
        return etree.SubElement(parent, _IE, Name=name, ID=self.guid(key))


def _value(
    parent: etree._Element, name: str, text: str, unit: str | None, data_type: str = "xs:double"
) -> etree._Element:
    attrib = {"Name": name, "AttributeDataType": data_type}
    if unit is not None:
        attrib["Unit"] = unit
    a = etree.SubElement(parent, _ATTR, attrib)
    etree.SubElement(a, _VALUE).text = text
    return a


def _role(parent: etree._Element, role: str) -> None:
    etree.SubElement(parent, _ROLE_REQ, RefBaseRoleClassPath=f"{ROLE_LIB}/{role}")


def _parameters(parent: etree._Element, params: Sequence[ProcessParameter]) -> None:
    for p in params:
        _value(parent, p.name, repr(float(p.value)), p.unit)


def _write_points(w: _Writer, track_el: etree._Element, key: str, rows: list[list[float]]) -> None:
    width = max(4, len(str(len(rows) - 1)))
    for i, row in enumerate(rows):
        name = f"P{i:0{width}d}"
        point = w.element(track_el, name, f"{key}/{name}")
        frame = etree.SubElement(point, _ATTR, Name="Frame", RefAttributeType=_FRAME_TYPE)
        for (sub, unit), v in zip(FRAME_KEYS, row[:6], strict=True):
            _value(frame, sub, repr(v), unit)
        for (attr, unit), v in zip(POINT_VALUES, row[6:], strict=True):
            _value(point, attr, repr(v), unit)
        _role(point, "Point")


def _role_library(root: etree._Element, w: _Writer) -> None:
    lib = etree.SubElement(root, caex_tag("RoleClassLib"), Name=ROLE_LIB)
    etree.SubElement(
        lib, caex_tag("Description")
    ).text = "PathML roles: a process Path made of Layers, a Layer of Tracks, a Track of Points"
    etree.SubElement(lib, caex_tag("Version")).text = "1.0.0"
    for role in ("Path", "Layer", "Track", "Point"):
        rc = etree.SubElement(
            lib,
            caex_tag("RoleClass"),
            Name=role,
            ID=w.guid(f"{ROLE_LIB}/{role}"),
            RefBaseClassPath=_BASE_ROLE,
        )
        if role == "Point":
            frame = etree.SubElement(rc, _ATTR, Name="Frame", RefAttributeType=_FRAME_TYPE)
            for sub, unit in FRAME_KEYS:
                etree.SubElement(frame, _ATTR, Name=sub, AttributeDataType="xs:double", Unit=unit)
            for attr, unit in POINT_VALUES:
                etree.SubElement(rc, _ATTR, Name=attr, AttributeDataType="xs:double", Unit=unit)
    base = etree.SubElement(root, caex_tag("RoleClassLib"), Name="AutomationMLBaseRoleClassLib")
    etree.SubElement(base, caex_tag("Version")).text = "2.10.0"
    etree.SubElement(base, caex_tag("RoleClass"), Name="AutomationMLBaseRole")
    types = etree.SubElement(root, caex_tag("AttributeTypeLib"), Name="AutomationMLBaseAttributeTypeLib")
    etree.SubElement(types, caex_tag("Version")).text = "2.10.0"
    frame_type = etree.SubElement(types, caex_tag("AttributeType"), Name="Frame")
    for sub, unit in FRAME_KEYS:
        a = etree.SubElement(frame_type, _ATTR, Name=sub, AttributeDataType="xs:double", Unit=unit)
        etree.SubElement(a, caex_tag("DefaultValue")).text = "0.0"


def write_pathml(
    path: str | Path,
    trajectory: Trajectory,
    problem: Problem,
    *,
    layers: Sequence[LayerLayout] | None = None,
    written_at: datetime | None = None,
) -> Path:
    """Write the trajectory as a PathML (CAEX 3.0) document.

    Args:
        path: output file, conventionally ``<problem name>.aml``.
        trajectory: the refined, timed path; points are ``trajectory.poses`` in {F}.
        problem: gives the document name, the process kind and parameters, robot and tool names.
        layers: how waypoints group into layers and tracks; default one layer with one track.
        written_at: time stamp for ``LastWritingDateTime``; default now (UTC).

    Returns:
        The path written.
    """
    path = Path(path)
    layers = list(layers) if layers is not None else default_layers(trajectory, problem)
    _check_layers(layers, len(trajectory))
    w = _Writer(problem.name)
    stamp = (written_at or sink_stamp()).isoformat()

    root = etree.Element(
        caex_tag("CAEXFile"), nsmap={None: CAEX_NS, "xsi": _XSI_NS}, SchemaVersion="3.0", FileName=path.name
    )
    root.set(f"{{{_XSI_NS}}}schemaLocation", f"{CAEX_NS} CAEX_ClassModel_V.3.0.xsd")
    etree.SubElement(root, caex_tag("SuperiorStandardVersion")).text = "AutomationML 2.10"
    etree.SubElement(
        root,
        caex_tag("SourceDocumentInformation"),
        OriginName="refine",
        OriginID=str(uuid.uuid5(_GUID_NAMESPACE, "refine")),
        OriginVersion=__version__,
        OriginRelease=__version__,
        LastWritingDateTime=stamp,
        OriginProjectTitle=problem.name,
        OriginProjectID=w.guid("project"),
    )
    hierarchy = etree.SubElement(
        root, caex_tag("InstanceHierarchy"), Name=problem.name, ID=w.guid("InstanceHierarchy")
    )

    path_el = w.element(hierarchy, "Path", "Path")
    etree.SubElement(
        path_el, caex_tag("Description")
    ).text = "TCP path in the world frame {F}: Frame x, y, z [m], rx, ry, rz [deg] about fixed x, y, z"
    _value(path_el, "processKind", problem.process.kind, None, "xs:string")
    _value(path_el, "robot", problem.robot.model, None, "xs:string")
    _value(path_el, "tool", problem.tool.name, None, "xs:string")

    angles = fixed_xyz_from_matrix(trajectory.poses[:, :3, :3])
    table = np.column_stack(
        [trajectory.poses[:, :3, 3], angles, trajectory.speed, trajectory.t, trajectory.s]
    ).tolist()
    for layer in layers:
        layer_el = w.element(path_el, layer.name, f"Path/{layer.name}")
        _parameters(layer_el, layer.parameters)
        for tr in layer.tracks:
            key = f"Path/{layer.name}/{tr.name}"
            track_el = w.element(layer_el, tr.name, key)
            _parameters(track_el, tr.parameters)
            _write_points(w, track_el, key, table[tr.start : tr.stop])
            _role(track_el, "Track")
        _role(layer_el, "Layer")
    _role(path_el, "Path")
    _role_library(root, w)

    body = etree.tostring(root, encoding="utf-8", pretty_print=True)
    put_bytes(path, b'<?xml version="1.0" encoding="utf-8"?>\n' + body)
    log.info("wrote PathML %s: %d layer(s), %d points", path, len(layers), len(trajectory))
    return path


# ---- validating -------------------------------------------------------------------------------


def validate_pathml(path: str | Path, xsd_path: str | Path) -> list[str]:
    """Validate a CAEX document against an XML schema.

    Args:
        path: the document (``.aml``).
        xsd_path: the schema, e.g. ``CAEX_ClassModel_V.3.0.xsd``.

    Returns:
        One message per error (``"<file>:<line>: <message>"``); empty when the document is valid.

    Raises:
        InputError: the schema itself cannot be read.
    """
    try:
        schema = etree.XMLSchema(etree.parse(str(xsd_path)))
    except (OSError, etree.XMLSchemaParseError, etree.XMLSyntaxError) as e:
        raise InputError(f"cannot read XML schema {xsd_path}: {e}") from e
    try:
        doc = etree.parse(str(path))
    except (OSError, etree.XMLSyntaxError) as e:
        return [f"{path}: not well-formed XML: {e}"]
    if schema.validate(doc):
        return []
    return [f"{Path(path).name}:{err.line}: {err.message}" for err in schema.error_log]
