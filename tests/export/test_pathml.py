from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pytest
from lxml import etree

from refine.cad.pathml_read import read_pathml
from refine.errors import InputError
from refine.export.pathml import LayerLayout, TrackLayout, validate_pathml, write_pathml
from refine.frames import rotation_angle_deg
from refine.pathml_format import CAEX_NS
from refine.problem import ProcessParameter

AML_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "aml"
XSD3 = AML_DIR / "CAEX_ClassModel_V.3.0.xsd"
XSD215 = AML_DIR / "CAEX_ClassModel_V2.15.xsd"


@pytest.fixture(scope="module")
def aml_dir(require) -> Path:
    """The shared AutomationML folder: a skip with its reason on a workstation, a failure under CI=true."""
    return require.path(AML_DIR, "the shared AutomationML folder (CAEX schemas, examples)")


@pytest.fixture()
def written(tmp_path, trajectory, problem) -> Path:
    return write_pathml(tmp_path / "bead.aml", trajectory, problem)


def ns(tag: str) -> str:
    return f"{{{CAEX_NS}}}{tag}"


def test_written_document_validates_against_caex3(aml_dir, written):
    assert validate_pathml(written, XSD3) == []


@pytest.mark.parametrize(
    ("example", "xsd"),
    [
        ("example_empty_caex3.aml", XSD3),
        ("example_suc_caex3.aml", XSD3),
        ("example_robot_caex215.aml", XSD215),
    ],
)
def test_the_published_examples_validate(aml_dir, example, xsd):
    assert validate_pathml(aml_dir / example, xsd) == []


def test_an_element_out_of_schema_order_fails_validation(aml_dir, written, tmp_path):
    tree = etree.parse(str(written))
    point = next(tree.getroot().iter(ns("InternalElement")))
    point = point.find(ns("InternalElement")).find(ns("InternalElement")).find(ns("InternalElement"))
    role = point.find(ns("RoleRequirements"))
    point.remove(role)
    point.insert(0, role)  # RoleRequirements must come after the Attributes
    broken = tmp_path / "broken.aml"
    tree.write(str(broken))
    errors = validate_pathml(broken, XSD3)
    assert errors and any("RoleRequirements" in e or "Attribute" in e for e in errors)


def test_an_attribute_without_name_fails_validation(aml_dir, written, tmp_path):
    text = written.read_text(encoding="utf-8").replace('Attribute Name="speed"', "Attribute", 1)
    broken = tmp_path / "broken.aml"
    broken.write_text(text, encoding="utf-8")
    assert any("Name" in e for e in validate_pathml(broken, XSD3))


def test_a_caex3_document_fails_against_the_caex215_schema(aml_dir, written):
    assert validate_pathml(written, XSD215)


def test_round_trip_recovers_poses_speeds_times_and_parameters(written, trajectory, problem):
    doc = read_pathml(written)
    assert doc.file_name == "bead.aml" and doc.origin_name == "refine"
    (layer,) = doc.layers
    (track,) = layer.tracks
    np.testing.assert_allclose(track.positions, trajectory.poses[:, :3, 3], rtol=0, atol=1e-9)
    angle = rotation_angle_deg(track.rotations, trajectory.poses[:, :3, :3])
    assert float(angle.max()) < 1e-9
    np.testing.assert_array_equal(track.speed, trajectory.speed)
    np.testing.assert_array_equal(track.time, trajectory.t)
    np.testing.assert_array_equal(track.s, trajectory.s)
    assert layer.parameters == problem.process.parameters
    assert track.parameters == problem.process.parameters


def test_header_names_the_writer_and_the_standard(written):
    root = etree.parse(str(written)).getroot()
    assert root.get("SchemaVersion") == "3.0" and root.get("FileName") == "bead.aml"
    assert root.findtext(ns("SuperiorStandardVersion")) == "AutomationML 2.10"
    info = root.find(ns("SourceDocumentInformation"))
    for key in ("OriginName", "OriginID", "OriginVersion", "LastWritingDateTime"):
        assert info.get(key)


def test_every_double_carries_a_unit_and_every_element_a_guid(written):
    root = etree.parse(str(written)).getroot()
    doubles = [a for a in root.iter(ns("Attribute")) if a.get("AttributeDataType") == "xs:double"]
    assert doubles and all(a.get("Unit") for a in doubles)
    ids = [e.get("ID") for e in root.iter(ns("InternalElement"))]
    assert all(len(i) == 36 and i.count("-") == 4 for i in ids)
    assert len(set(ids)) == len(ids)


def test_every_internal_element_requires_a_pathml_role(written):
    root = etree.parse(str(written)).getroot()
    roles = {
        rc.get("Name")
        for lib in root.iter(ns("RoleClassLib"))
        if lib.get("Name") == "PathMLRoleClassLib"
        for rc in lib.iter(ns("RoleClass"))
    }
    assert roles == {"Path", "Layer", "Track", "Point"}
    for el in root.iter(ns("InternalElement")):
        ref = el.find(ns("RoleRequirements")).get("RefBaseRoleClassPath")
        lib, role = ref.split("/")
        assert lib == "PathMLRoleClassLib" and role in roles


def test_writing_twice_gives_identical_files(tmp_path, trajectory, problem):
    stamp = datetime(2024, 5, 1, 12, 0, tzinfo=timezone.utc)
    a = write_pathml(tmp_path / "a" / "bead.aml", trajectory, problem, written_at=stamp)
    b = write_pathml(tmp_path / "b" / "bead.aml", trajectory, problem, written_at=stamp)
    assert a.read_bytes() == b.read_bytes()


def test_several_layers_and_tracks_round_trip(aml_dir, tmp_path, trajectory, problem):
    amps = (ProcessParameter("current", 140.0, "A"),)
    layers = [
        LayerLayout(
            "Pass1",
            (TrackLayout("Root", 0, 20, amps), TrackLayout("Fill", 20, 35)),
            (ProcessParameter("layerHeight", 0.002, "m"),),
        ),
        LayerLayout("Pass2", (TrackLayout("Cap", 35, 60, amps),)),
    ]
    path = write_pathml(tmp_path / "weld.aml", trajectory, problem, layers=layers)
    assert validate_pathml(path, XSD3) == []
    doc = read_pathml(path)
    assert [layer.name for layer in doc.layers] == ["Pass1", "Pass2"]
    assert [t.name for t in doc.layers[0].tracks] == ["Root", "Fill"]
    assert doc.layers[0].tracks[0].parameters == amps
    stacked = np.concatenate([t.positions for layer in doc.layers for t in layer.tracks])
    np.testing.assert_allclose(stacked, trajectory.poses[:, :3, 3], rtol=0, atol=1e-9)


def test_a_track_outside_the_trajectory_is_rejected(tmp_path, trajectory, problem):
    layers = [LayerLayout("L", (TrackLayout("T", 10, 999),))]
    with pytest.raises(InputError, match="T"):
        write_pathml(tmp_path / "x.aml", trajectory, problem, layers=layers)


def test_duplicate_track_names_are_rejected(tmp_path, trajectory, problem):
    layers = [LayerLayout("L", (TrackLayout("T", 0, 10), TrackLayout("T", 10, 20)))]
    with pytest.raises(InputError, match="uniquely named"):
        write_pathml(tmp_path / "x.aml", trajectory, problem, layers=layers)


def test_reader_converts_the_units_other_tools_write(written, tmp_path, trajectory):
    """A point written in mm and radians, and a speed in mm/s, read back in m, deg and m/s."""
    tree = etree.parse(str(written))
    point = next(e for e in tree.getroot().iter(ns("InternalElement")) if e.get("Name") == "P0003")
    frame = {a.get("Name"): a for a in point.find(ns("Attribute")).iter(ns("Attribute"))}
    values = {a.get("Name"): a for a in point.findall(ns("Attribute"))}
    for attr, unit, factor in (
        (frame["x"], "mm", 1e3),
        (frame["rz"], "rad", np.pi / 180.0),
        (values["speed"], "mm/s", 1e3),
    ):
        attr.set("Unit", unit)
        attr.find(ns("Value")).text = repr(float(attr.findtext(ns("Value"))) * factor)
    foreign = tmp_path / "foreign.aml"
    tree.write(str(foreign))
    track = read_pathml(foreign).layers[0].tracks[0]
    assert track.positions[3, 0] == pytest.approx(trajectory.poses[3, 0, 3], abs=1e-12)
    assert track.speed[3] == pytest.approx(trajectory.speed[3], abs=1e-12)
    angle = rotation_angle_deg(track.rotations[3], trajectory.poses[3, :3, :3])
    assert float(angle) < 1e-9


def test_reading_a_document_without_a_path_says_so(aml_dir):
    with pytest.raises(InputError, match="no InternalElement with a Path role"):
        read_pathml(aml_dir / "example_empty_caex3.aml")
