"""Fuzz: every reader and the problem file either read correctly or raise InputError naming the file.

Hypothesis builds inputs from valid material with random damage (lines dropped, duplicated,
truncated, bytes flipped, values replaced by NaN, huge numbers, words) and from random text. For
each example the reader must either return finite data of the right shape or raise ``InputError``
whose message names the file; any other exception (a traceback for the user) fails the test.
Example counts are modest so the suite stays fast; ``FUZZ_EXAMPLES`` (environment) raises them,
and ``FUZZ_DEADLINE_S`` fails any example that takes longer than that (a hang).
"""

from __future__ import annotations

import math
import os
import re
import shutil
import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from refine.cad.csv_ import points_from_csv
from refine.cad.dxf import points_from_dxf
from refine.cad.gcode import points_from_gcode
from refine.cad.mesh import points_from_mesh
from refine.cad.pathml_read import read_pathml
from refine.demo.csv_ import read_demo_csv
from refine.demo.liberty import read_liberty_ascii
from refine.demo.liberty_binary import read_liberty_binary
from refine.demo.quality import gate_dropouts
from refine.errors import InputError
from refine.plausible import CAD_COORDINATE_LIMIT_M, DEMO_POSITION_LIMIT_M
from refine.problem import load_problem
from refine.run.preflight import preflight

ROOT = Path(__file__).resolve().parents[1]
GLASS = ROOT / "problems" / "glass_adhesive"
EXAMPLES = int(os.environ.get("FUZZ_EXAMPLES", "20"))
DEADLINE_S = os.environ.get("FUZZ_DEADLINE_S")
FUZZ = settings(
    max_examples=EXAMPLES,
    deadline=None if DEADLINE_S is None else float(DEADLINE_S) * 1000.0,
    suppress_health_check=[
        HealthCheck.function_scoped_fixture,
        HealthCheck.too_slow,
        HealthCheck.data_too_large,
    ],
)
COUNT = {"examples": 0}

NASTY = [
    "nan",
    "inf",
    "-inf",
    "1e308",
    "-1e300",
    "4e5",
    "1e-320",
    "-0",
    "0x10",
    "1,5",
    "",
    "é",
    "\x00",
    "\x1b[2J",
    "99999999999999999999",
]


def _damage(data, lines: list[str]) -> list[str]:
    """Random edits of a list of lines: drop, duplicate, truncate, replace a token, insert junk."""
    lines = list(lines)
    for _ in range(data.draw(st.integers(0, 6))):
        if not lines:
            break
        k = data.draw(st.integers(0, len(lines) - 1))
        op = data.draw(st.sampled_from(["drop", "dup", "cut", "token", "junk", "swap"]))
        if op == "drop":
            del lines[k]
        elif op == "dup":
            lines.insert(k, lines[k])
        elif op == "cut":
            lines[k] = lines[k][: data.draw(st.integers(0, max(len(lines[k]) - 1, 0)))]
        elif op == "token":
            tokens = re.split(r"([ ,]+)", lines[k])
            j = data.draw(st.integers(0, len(tokens) - 1))
            tokens[j] = data.draw(st.sampled_from(NASTY) | st.text(max_size=8))
            lines[k] = "".join(tokens)
        elif op == "junk":
            lines.insert(k, data.draw(st.text(max_size=40)))
        else:
            j = data.draw(st.integers(0, len(lines) - 1))
            lines[k], lines[j] = lines[j], lines[k]
    return lines


def _write(path: Path, data, lines: list[str]) -> None:
    text = "\n".join(_damage(data, lines)) + "\n"
    raw = text.encode("utf-8", errors="surrogatepass")
    if data.draw(st.booleans()) and raw:  # flip a byte now and then
        k = data.draw(st.integers(0, len(raw) - 1))
        raw = raw[:k] + bytes([data.draw(st.integers(0, 255))]) + raw[k + 1 :]
    path.write_bytes(raw)


def _plausible_log(log) -> None:
    """A log that was read holds only values within the readers' plausibility ranges."""
    assert np.all(np.abs(log.positions) <= DEMO_POSITION_LIMIT_M)
    assert np.all(np.diff(log.t) > 0) and log.t[-1] - log.t[0] <= 86_400.0


def _expect(read, path: Path):
    """Run ``read``; the result is returned, or InputError naming the file; nothing else."""
    COUNT["examples"] += 1
    try:
        return read()
    except InputError as e:
        assert path.name in str(e) or "tracker log" in str(e) or "resample" in str(e), str(e)
        return None


def _expect_cad_points(read, path: Path) -> None:
    """:func:`_expect` for a CAD reader: points (K, 3) within the plausible range, or InputError."""
    points = _expect(read, path)
    if points is not None:
        assert points.ndim == 2 and points.shape[1] == 3 and np.all(np.abs(points) <= CAD_COORDINATE_LIMIT_M)


def _read_damaged_liberty(tmp_path_factory, data, lines: list[str]):
    """A damaged copy of ``lines`` read as a Liberty ASCII log: the file and the log (None if refused)."""
    f = tmp_path_factory.mktemp("lib") / "demo.liberty"
    _write(f, data, lines)
    log = _expect(lambda: read_liberty_ascii(f, units=None), f)
    if log is not None:
        assert np.all(np.isfinite(log.positions)) and log.rotations.shape == (len(log.t), 3, 3)
        _plausible_log(log)
    return f, log


LIBERTY = [
    "# Polhemus Liberty ASCII",
    "# units: in",
    "# rate_hz: 240",
    *(
        f"01P {k:9d} {10 + 0.01 * k:10.4f} {2.0:10.4f} {3 + 0.002 * k:10.4f} {5.0:9.3f} {k * 0.1:9.3f} {1.0:9.3f}"
        for k in range(40)
    ),
]


@FUZZ
@given(data=st.data())
def test_fuzz_liberty_ascii(tmp_path_factory, data):
    _, log = _read_damaged_liberty(tmp_path_factory, data, LIBERTY)
    if log is not None:
        try:
            gate_dropouts(log)
        except InputError as e:
            assert "demo.liberty" in str(e)


# records as the Liberty sends them: station, command, error indicator (blank or a letter), values;
# some with the first value right after the indicator
DEVICE_LIBERTY = [
    f"01C{' ' if k % 7 else 'u'}{10 + 0.01 * k:.4f} {2.0:10.4f} {3 + 0.002 * k:10.4f} {5.0:9.3f} {k * 0.1:9.3f} {1.0:9.3f}"
    for k in range(40)
]


@FUZZ
@given(data=st.data())
def test_fuzz_liberty_ascii_device_records(tmp_path_factory, data):
    _, log = _read_damaged_liberty(tmp_path_factory, data, DEVICE_LIBERTY)
    if log is not None:
        assert log.device_error is None or log.device_error.shape == log.t.shape
        try:
            gate_dropouts(log)
        except InputError as e:
            assert "demo.liberty" in str(e)


@FUZZ
@given(data=st.data())
def test_fuzz_demo_csv(tmp_path_factory, data):
    f = tmp_path_factory.mktemp("csv") / "demo.csv"
    rows = ["t,x,y,z,azimuth,elevation,roll"] + [
        f"{k / 240:.6f},{0.1 * k:.4f},0.2,0.3,10,{k},-5" for k in range(30)
    ]
    _write(f, data, rows)
    log = _expect(lambda: read_demo_csv(f, units="mm"), f)
    if log is not None:
        assert np.all(np.isfinite(log.positions)) and np.all(np.isfinite(log.rotations))
        _plausible_log(log)


@FUZZ
@given(data=st.data())
def test_fuzz_cad_csv(tmp_path_factory, data):
    f = tmp_path_factory.mktemp("cad") / "path.csv"
    _write(f, data, ["x,y,z"] + [f"{k * 10.0},{math.sin(k) * 5:.3f},0" for k in range(30)])
    _expect_cad_points(lambda: points_from_csv(f, units="mm"), f)


@FUZZ
@given(data=st.data())
def test_fuzz_gcode(tmp_path_factory, data):
    f = tmp_path_factory.mktemp("nc") / "seam.nc"
    lines = (ROOT / "tests" / "data" / "seam.nc").read_text().splitlines()
    _write(f, data, lines)
    points = _expect(lambda: points_from_gcode(f, units="mm"), f)
    if points is not None:
        assert points.shape[1] == 3 and np.all(np.isfinite(points))
        assert np.all(np.abs(points) <= CAD_COORDINATE_LIMIT_M)


DXF_LINES = [
    "0",
    "SECTION",
    "2",
    "ENTITIES",
    "0",
    "LINE",
    "8",
    "0",
    "10",
    "0.0",
    "20",
    "0.0",
    "30",
    "0.0",
    "11",
    "100.0",
    "21",
    "0.0",
    "31",
    "0.0",
    "0",
    "LINE",
    "8",
    "0",
    "10",
    "100.0",
    "20",
    "0.0",
    "30",
    "0.0",
    "11",
    "100.0",
    "21",
    "50.0",
    "31",
    "0.0",
    "0",
    "ENDSEC",
    "0",
    "EOF",
]


@FUZZ
@given(data=st.data())
def test_fuzz_dxf(tmp_path_factory, data):
    f = tmp_path_factory.mktemp("dxf") / "path.dxf"
    _write(f, data, DXF_LINES)
    _expect_cad_points(lambda: points_from_dxf(f, units="mm"), f)


@FUZZ
@given(
    vertices=st.lists(
        st.tuples(st.floats(-2e6, 2e6), st.floats(-2e6, 2e6), st.floats(allow_nan=True, allow_infinity=True)),
        min_size=2,
        max_size=5,
    ),
    closed=st.booleans(),
)
def test_fuzz_dxf_polyline_bulges(tmp_path_factory, vertices, closed):
    """Any vertices and bulges (0, tiny, huge, NaN, inf) of an LWPOLYLINE: read, or refused naming the file."""
    import ezdxf

    f = tmp_path_factory.mktemp("dxfb") / "bulge.dxf"
    doc = ezdxf.new()
    doc.modelspace().add_lwpolyline(vertices, format="xyb", close=closed)
    doc.saveas(f)
    _expect_cad_points(lambda: points_from_dxf(f, units="mm"), f)


@FUZZ
@given(
    vertices=st.lists(
        st.tuples(*[st.floats(allow_nan=True, allow_infinity=True, width=32)] * 3), min_size=3, max_size=6
    ),
    boundary=st.booleans(),
)
def test_fuzz_mesh_vertices(tmp_path_factory, vertices, boundary):
    """Any vertex values (huge, NaN, inf) of a small STL: a path within range, or refused naming the file."""
    import trimesh

    f = tmp_path_factory.mktemp("stl") / "part.stl"
    n = len(vertices)
    faces = [[0, k, k + 1] for k in range(1, n - 1)]
    with np.errstate(all="ignore"):  # the writer's normals of NaN triangles
        trimesh.Trimesh(vertices=np.array(vertices, dtype=float), faces=faces, process=False).export(f)
    kwargs = {"boundary": True} if boundary else {"section_origin": (0, 0, 0), "section_normal": (0, 0, 1)}
    _expect_cad_points(lambda: points_from_mesh(f, units="mm", **kwargs), f)


@FUZZ
@given(data=st.data())
def test_fuzz_liberty_binary(tmp_path_factory, data):
    f = tmp_path_factory.mktemp("lyb") / "demo.lyb"
    if data.draw(st.booleans()):
        raw = bytearray((ROOT / "tests" / "data" / "demo.lyb").read_bytes()[:4000])
    else:  # the Liberty's default output list 2,4,1: position, Euler angles, CR LF; some flagged
        raw = bytearray(
            b"".join(
                b"LY"
                + bytes([1, ord("C"), ord("u") if k % 9 == 0 else 0x20, 0])
                + struct.pack("<H", 26)
                + struct.pack("<6f", 10 + 0.01 * k, 2.0, 3.0, 5.0, 0.1 * k, 1.0)
                + b"\r\n"
                for k in range(100)
            )
        )
    for _ in range(data.draw(st.integers(0, 8))):
        k = data.draw(st.integers(0, len(raw) - 1))
        raw[k] = data.draw(st.integers(0, 255))
    raw = raw[: data.draw(st.integers(0, len(raw)))]
    f.write_bytes(bytes(raw))
    log = _expect(lambda: read_liberty_binary(f, units="in"), f)
    if log is not None:
        assert np.all(np.isfinite(log.positions))
        _plausible_log(log)


@FUZZ
@given(data=st.data())
def test_fuzz_pathml(tmp_path_factory, data):
    f = tmp_path_factory.mktemp("aml") / "path.aml"
    src = ROOT / "tests" / "data"
    lines = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        '<CAEXFile xmlns="http://www.dke.de/CAEX" SchemaVersion="3.0" FileName="path.aml">',
        '<InstanceHierarchy Name="x"></InstanceHierarchy>',
        "</CAEXFile>",
    ]
    del src
    _write(f, data, lines)
    _expect(lambda: read_pathml(f), f)


# ---- the problem file ---------------------------------------------------------------------------

TOML_VALUES = st.sampled_from(
    [
        "nan",
        "inf",
        "-inf",
        "1e308",
        "-1",
        "0",
        "true",
        '""',
        '"../../etc/passwd"',
        "[]",
        "[1, 2]",
        "{}",
        '"x\\ny"',
        "1e-300",
        "99999999999999999999",
        '"rapid"',
        "[nan, 0, 0]",
        "{ xyz = [1, 2] }",
    ]
)


@pytest.fixture(scope="module")
def glass_copy(tmp_path_factory):
    dst = tmp_path_factory.mktemp("fuzzproblem") / "glass"
    shutil.copytree(
        GLASS, dst, ignore=shutil.ignore_patterns("generate.py", "README.md", "*.liberty", "*.dxf")
    )
    for name in ("demo.liberty", "bead.dxf"):
        (dst / name).symlink_to(GLASS / name)
    return dst


@FUZZ
@given(data=st.data())
def test_fuzz_problem_file(glass_copy, data):
    toml = glass_copy / "problem.toml"
    lines = (GLASS / "problem.toml").read_text().splitlines()
    value_lines = [i for i, line in enumerate(lines) if re.match(r"^\w+ = ", line)]
    for _ in range(data.draw(st.integers(1, 3))):
        i = data.draw(st.sampled_from(value_lines))
        key = lines[i].split(" = ")[0]
        lines[i] = f"{key} = {data.draw(TOML_VALUES)}"
    _write(toml, data, lines)
    problem = _expect(lambda: load_problem(glass_copy, allow_outside=True), toml)
    if problem is not None:
        _expect(lambda: preflight(problem), toml)
