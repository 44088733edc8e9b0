"""Results that travel: a ``Result`` pickles, and comes back from another process whole."""

from __future__ import annotations

import dataclasses
import json
import multiprocessing
import pickle
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import refine


def _line(n: int = 12) -> tuple[np.ndarray, np.ndarray]:
    positions = np.column_stack([np.full(n, 0.6), np.linspace(-0.1, 0.1, n), np.full(n, 0.3)])
    down = Rotation.from_euler("x", 180.0, degrees=True).as_matrix()  # tool z pointing down
    return positions, np.repeat(down[None], n, axis=0)


def _solve_line(shift_m: float) -> refine.Result:
    positions, R = _line()
    return refine.refine_path("ur10e", positions + [0.0, 0.0, shift_m], R, speeds=0.1, name="line")


def test_a_result_pickles_with_everything_but_its_built_problem(tmp_path):
    result = _solve_line(0.0)
    result.run.robot.collision_shapes()  # the robot's cached FCL shapes, as any collision run leaves them
    back = pickle.loads(pickle.dumps(result))
    assert back.status == result.status == "ok"
    np.testing.assert_array_equal(back.joints, result.joints)
    np.testing.assert_array_equal(back.times, result.times)
    assert back.to_dict()["metrics"] == result.to_dict()["metrics"]
    assert back.run.first.nlp is None and result.run.first.nlp is not None
    # the copy writes like the original, and serves as the start of a re-solve
    files = back.write(tmp_path / "copy", report=False)
    assert files["result"].is_file()
    positions, R = _line()
    again = refine.refine_path("ur10e", positions + [0.0, 0.0, 0.002], R, speeds=0.1, previous=back)
    assert again.status == "ok"


def test_a_result_comes_back_from_a_process_pool():
    with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
        remote = pool.submit(_solve_line, 0.001).result(timeout=300)
    local = _solve_line(0.001)
    assert remote.status == local.status == "ok"
    np.testing.assert_allclose(remote.joints, local.joints, atol=1e-9)


@pytest.fixture(scope="module")
def line_result():
    return _solve_line(0.0)


def test_program_and_pathml_in_memory_are_the_written_files_byte_for_byte(line_result, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    text, aml = line_result.program("urscript"), line_result.pathml()
    texts = line_result.contents()
    assert list(tmp_path.iterdir()) == []  # nothing touched the disk
    files = line_result.write(tmp_path / "out", report=False)
    assert files["urscript"].read_bytes() == text.encode("utf-8")
    assert files["pathml"].read_bytes() == aml.encode("utf-8")
    written = {p.name for p in files.values()} - {"result.json"}
    assert set(texts) == written
    for name, body in texts.items():
        assert (tmp_path / "out" / name).read_bytes() == body.encode("utf-8"), name
    assert text.startswith(("def ", "#")) and "movel" in text  # a URScript program, not some other file


def test_a_program_the_robot_cannot_run_or_an_unknown_kind_is_an_input_error(line_result, tmp_path):
    with pytest.raises(refine.InputError) as e:
        line_result.program("rapid")  # a UR controller runs URScript only
    assert (e.value.key, e.value.value, e.value.expected) == ("programs", "rapid", "one of urscript")
    with pytest.raises(refine.InputError) as e:
        line_result.write(tmp_path / "o", programs=["rapid"], report=False)
    assert "--" not in str(e.value) and e.value.key == "programs"
    with pytest.raises(refine.InputError) as e:
        line_result.program("gcode")
    assert e.value.key == "kind" and e.value.value == "gcode"
    (tmp_path / "a_file").write_text("")
    with pytest.raises(refine.InputError) as e:
        line_result.write(tmp_path / "a_file" / "out", report=False)
    assert str(e.value).startswith("out_dir ") and e.value.key == "out_dir"


def test_from_dict_rebuilds_a_result_through_json(line_result):
    doc = json.loads(json.dumps(line_result.to_dict(contents=True)))  # across a process boundary as JSON
    back = refine.Result.from_dict(doc)
    assert back.run is None and back.status == "ok"
    assert back.to_dict(contents=True) == doc
    assert back.program("urscript") == line_result.program("urscript")
    assert back.pathml() == line_result.pathml()
    np.testing.assert_array_equal(back.joints, line_result.joints)
    np.testing.assert_array_equal(back.poses, line_result.poses)
    np.testing.assert_array_equal(back.times, line_result.times)
    assert back.figures == line_result.figures and back.findings == ()
    assert back.passes[0].metrics == line_result.passes[0].metrics

    plain = refine.Result.from_dict(line_result.to_dict())  # the result.json document alone
    assert plain.to_dict() == line_result.to_dict()
    assert plain.metrics == line_result.metrics and plain.status == "ok"
    with pytest.raises(refine.NotExecutable) as e:
        plain.program("urscript")
    assert e.value.key == "contents"
    with pytest.raises(refine.InputError):
        refine.Result.from_dict({"status": "ok"})


def test_typed_metrics_have_every_figure_of_the_document(line_result):
    metrics = line_result.to_dict()["metrics"]
    typed = line_result.figures
    assert {f.name for f in dataclasses.fields(typed)} == set(metrics)
    assert typed.max_position_error_m == metrics["max_position_error_m"] <= 1e-6
    assert 0.2 / 0.1 <= typed.cycle_time_s <= 1.5 * 0.2 / 0.1  # 0.2 m at no more than 0.1 m/s, and ramps
    with pytest.raises(refine.InputError) as e:
        refine.Metrics.from_dict({**metrics, "max_speed": 1.0})
    assert e.value.key == "metrics.max_speed"


def test_a_diagnosis_entry_reads_as_dataclasses():
    entry = {  # the shape of docs/diagnosis.schema.json, written out by hand
        "pass": "pass 1",
        "status": "repaired",
        "index_start": 3,
        "index_end": 9,
        "s_start_m": 0.03,
        "s_end_m": 0.09,
        "cause": "joint limit",
        "figure": 181.0,
        "limit": 175.0,
        "unit": "deg",
        "objects": [],
        "joint": 5,
        "slack_deg": 2.5,
        "suggestion": "turn the part 6 deg",
        "causes": [
            {
                "cause": "joint limit",
                "figure": 181.0,
                "limit": 175.0,
                "unit": "deg",
                "objects": [],
                "joint": 5,
                "explains_deg": 6.0,
                "suggestion": "turn the part 6 deg",
            },
            {
                "cause": "collision",
                "figure": 0.004,
                "limit": 0.01,
                "unit": "m",
                "objects": ["link_6", "table"],
                "joint": None,
                "explains_deg": None,
                "suggestion": "",
            },
        ],
    }
    d = refine.Diagnosis.from_dict(entry)
    assert (d.pass_name, d.index_start, d.index_end, d.slack_deg) == ("pass 1", 3, 9, 2.5)
    assert d.cause.joint == 5 and d.cause.explains_deg == 6.0
    assert d.causes[1].objects == ("link_6", "table") and d.causes[1].explains_deg is None


@pytest.mark.slow
def test_a_repaired_problem_folder_travels_with_its_diagnosis_and_program(tmp_path):
    repaired = refine.solve("problems/unreachable/joint_limit")  # joint 5 past its limit: repaired
    assert repaired.status == "repaired"
    (finding,) = repaired.findings
    entry = repaired.diagnosis[0]
    assert (
        (finding.cause.cause, finding.cause.joint) == ("joint limit", 5) == (entry["cause"], entry["joint"])
    )
    assert finding.slack_deg == entry["slack_deg"] > 0.0
    files = repaired.write(tmp_path / "out", report=False)  # the problem's own programs: RAPID
    assert files["rapid"].read_bytes() == repaired.program("rapid").encode("utf-8")
    back = refine.Result.from_dict(json.loads(json.dumps(repaired.to_dict(contents=True))))
    assert back.findings == repaired.findings and back.status == "repaired"
    assert back.program("rapid") == repaired.program("rapid")
    assert back.passes[0].reason == repaired.passes[0].reason != ""
