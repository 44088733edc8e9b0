"""A missing prerequisite is a skip with its reason on a workstation and a failure under CI=true."""

from __future__ import annotations

import pytest


@pytest.mark.parametrize("value", ["true", "TRUE", "1", "yes"])
def test_a_missing_path_fails_under_ci(require, monkeypatch, tmp_path, value):
    monkeypatch.setenv("CI", value)
    with pytest.raises(pytest.fail.Exception, match="nothing here not found at .*absent"):
        require.path(tmp_path / "absent", "nothing here")


@pytest.mark.parametrize("value", [None, "", "false", "0"])
def test_a_missing_path_is_a_skip_with_its_reason_elsewhere(require, monkeypatch, tmp_path, value):
    if value is None:
        monkeypatch.delenv("CI", raising=False)
    else:
        monkeypatch.setenv("CI", value)
    with pytest.raises(pytest.skip.Exception, match="the schema not found at .*absent"):
        require.path(tmp_path / "absent", "the schema")


def test_a_missing_module_fails_under_ci_and_names_it(require, monkeypatch):
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match="'refine_no_such_module' is not importable"):
        require.module("refine_no_such_module")
    monkeypatch.setenv("CI", "false")
    with pytest.raises(pytest.skip.Exception, match="'refine_no_such_module' is not importable"):
        require.module("refine_no_such_module")


def test_present_prerequisites_pass_through(require, monkeypatch, tmp_path):
    monkeypatch.setenv("CI", "true")
    assert require.path(tmp_path, "a folder") == tmp_path
    assert require.module("json").dumps([1]) == "[1]"
