"""Errors a host can show: every mistake through the API is a RefineError with key, value and expected.

One case per mistake the library's users made (a misspelt keyword, a wrong type, a dict where a
Shape goes, a format the controller does not run), each checked for its class, its ``key`` and the
absence of command-line words (``--programs``, ``--out``) in the message.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest

import refine

N = 8
POSITIONS = np.column_stack([np.full(N, 0.6), np.linspace(-0.05, 0.05, N), np.full(N, 0.3)])  # [m]
DOWN = np.repeat(np.diag([1.0, -1.0, -1.0])[None], N, axis=0)  # tool z pointing down


def _path(**kwargs):
    args = {"robot": "ur10e", "positions": POSITIONS, "orientations": DOWN, "speeds": 0.1, **kwargs}
    return refine.refine_path(args.pop("robot"), args.pop("positions"), args.pop("orientations"), **args)


@pytest.fixture(scope="module")
def result():
    return _path()


CASES = [  # (what was given, keyword arguments, error class, key)
    ("misspelt keyword", {"tolerance": {"orientation_deg": 3.0}}, refine.ArgumentError, "tolerance"),
    (
        "misspelt tolerance field",
        {"tolerances": {"orientation": 3.0}},
        refine.InputError,
        "tolerances.orientation",
    ),
    (
        "tolerance of the wrong type",
        {"tolerances": {"orientation_deg": "3"}},
        refine.InputError,
        "tolerances.orientation_deg",
    ),
    ("a dict as the cell", {"cell": {"name": "table"}}, refine.InputError, "cell"),
    ("a dict inside the cell", {"cell": [{"name": "table"}]}, refine.InputError, "cell[0]"),
    ("a robot that is a number", {"robot": 5}, refine.ArgumentError, "robot"),
    ("cancel that is a number", {"cancel": 5}, refine.ArgumentError, "cancel"),
    ("progress that is a number", {"progress": 5}, refine.ArgumentError, "progress"),
    ("a name that is a number", {"name": 5}, refine.ArgumentError, "name"),
    ("axisymmetric as a word", {"axisymmetric": "no"}, refine.ArgumentError, "axisymmetric"),
    ("home with two angles", {"home_deg": [0.0, 1.0]}, refine.InputError, "home_deg"),
    ("previous that is not a result", {"previous": 5}, refine.ArgumentError, "previous"),
    ("an unknown quaternion order", {"quaternion_order": "zyxw"}, refine.InputError, "quaternion_order"),
    ("programs as one string", {"programs": "rapid"}, refine.InputError, "programs"),
    ("positions of two columns", {"positions": POSITIONS[:, :2]}, refine.InputError, "positions"),
    ("speeds as a word", {"speeds": "fast"}, refine.InputError, "speeds"),
    ("speeds no tool reaches", {"speeds": 50.0}, refine.InputError, None),
    ("positions in millimetres", {"positions": POSITIONS * 1000.0}, refine.InputError, None),
    (
        "quaternions without their order",
        {"orientations": np.tile([0.0, 1.0, 0.0, 0.0], (N, 1))},
        refine.InputError,
        "quaternion_order",
    ),
    ("a time limit as a word", {"time_limit_s": "1"}, refine.InputError, "time_limit_s"),
]


@pytest.mark.parametrize(("what", "kwargs", "kind", "key"), CASES, ids=[c[0] for c in CASES])
def test_each_mistake_through_refine_path_is_a_refine_error_naming_its_key(what, kwargs, kind, key):
    with pytest.raises(kind) as e:
        _path(**kwargs)
    assert isinstance(e.value, refine.RefineError)
    if key is not None:
        assert e.value.key == key, str(e.value)
        assert e.value.expected, str(e.value)
    assert "--" not in str(e.value)


def test_a_misspelt_keyword_is_also_a_type_error_and_names_the_nearest():
    with pytest.raises(TypeError) as e:  # what a host catching TypeError already catches
        _path(orientation_tolerance=3.0, tolerance=None)
    assert isinstance(e.value, refine.ArgumentError)
    with pytest.raises(refine.ArgumentError, match="did you mean 'time_limit_s'"):
        refine.solve("problems/glass_adhesive", time_limit=3.0)
    with pytest.raises(refine.ArgumentError, match="did you mean 'orientation_deg'") as e:
        refine.Tolerances(orientation=3.0)
    assert e.value.key == "orientation"
    with pytest.raises(refine.ArgumentError, match="did you mean 'size_m'"):
        refine.Shape("table", "box", size=(1.0, 1.0, 0.1))
    with pytest.raises(refine.ArgumentError, match="did you mean 'joint_lower_deg'"):
        refine.Robot.from_urdf("robots/ur10e/robot.urdf", controller="ur", joint_lower=[0.0] * 6)
    with pytest.raises(refine.ArgumentError) as e:
        refine.Robot.from_urdf(5, controller="ur")
    assert e.value.key == "urdf"


def test_solve_and_load_problem_refuse_what_is_not_a_problem():
    for call in (lambda: refine.solve(5), lambda: refine.load_problem(5)):
        with pytest.raises(refine.ArgumentError):
            call()
    with pytest.raises(refine.InputError) as e:
        refine.load_problem("problems/no_such_problem")
    assert e.value.key == "path"
    with pytest.raises(refine.ArgumentError) as e:
        refine.solve("problems/glass_adhesive", cancel=threading.Event, progress=3)  # the class, not an Event
    assert e.value.key == "progress"


def test_write_and_program_speak_of_the_api_not_the_command_line(result, tmp_path):
    with pytest.raises(refine.InputError) as e:
        result.write(tmp_path / "out", programs=["krl"], report=False)  # a UR controller runs URScript
    assert e.value.key == "programs" and e.value.value == "krl" and "--" not in str(e.value)
    (tmp_path / "a_file").write_text("")
    with pytest.raises(refine.InputError) as e:
        result.write(tmp_path / "a_file", report=False)
    assert e.value.key == "out_dir" and "--out" not in str(e.value)
    with pytest.raises(refine.ArgumentError) as e:
        result.write(5)
    assert e.value.key == "out_dir"
    with pytest.raises(refine.ArgumentError) as e:
        result.write(tmp_path / "out", program=["urscript"])
    assert e.value.key == "program" and "programs" in str(e.value)
    with pytest.raises(refine.InputError) as e:
        result.write(tmp_path / "out", programs=["gcode"], report=False)
    assert e.value.key == "programs[0]"
    with pytest.raises(refine.ArgumentError):
        result.to_dict(content=True)


def test_a_type_error_from_inside_a_checked_call_is_raised_as_it_was():
    """Arguments that bind run the call; a TypeError it raises itself is not an argument error."""

    @refine.errors.checked_call
    def takes(a, *, b=1):
        return [] + a  # a TypeError inside, for a that is not a list

    assert takes([1], b=2) == [1]
    with pytest.raises(TypeError) as e:
        takes(3)
    assert not isinstance(e.value, refine.ArgumentError)
    with pytest.raises(refine.ArgumentError, match="did you mean 'b'") as e:
        takes([1], bb=2)
    assert e.value.key == "bb"
    with pytest.raises(refine.ArgumentError, match="missing a required argument: 'a'"):
        takes(b=2)
