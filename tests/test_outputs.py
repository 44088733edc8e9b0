"""Outputs are all or nothing: a finished set replaces the previous one whole, a failure leaves it."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from refine.errors import InputError
from refine.run.outputs import PREVIOUS, StagedOutputs


def _write_result(outputs: dict[str, Path]):
    def write(path: Path) -> None:
        from refine.run.outputs import describe_files

        doc = {
            "schema_version": 1,
            "outputs": {k: p.name for k, p in outputs.items()},
            "files": describe_files(outputs),
        }
        path.write_text(json.dumps(doc))

    return write


def _commit(out: Path, files: dict[str, str], protected=()) -> dict[str, Path]:
    with StagedOutputs(out, protected) as stage:
        outputs = {}
        for name, text in files.items():
            (stage.dir / name).write_text(text)
            outputs[name.split(".")[0]] = stage.dir / name
        return stage.commit(outputs, _write_result(outputs))


def _claims_hold(out: Path) -> bool:
    doc = json.loads((out / "result.json").read_text())
    return all(
        hashlib.sha256((out / n).read_bytes()).hexdigest() == m["sha256"] for n, m in doc["files"].items()
    )


def test_a_set_lands_whole_with_result_json_describing_it(tmp_path):
    out = tmp_path / "out"
    final = _commit(out, {"trajectory.csv": "a", "p.mod": "b"})
    assert sorted(p.name for p in out.iterdir()) == ["p.mod", "result.json", "trajectory.csv"]
    assert final["result"] == out / "result.json" and _claims_hold(out)


def test_a_new_set_removes_the_old_sets_other_files_but_not_the_users(tmp_path):
    out = tmp_path / "out"
    _commit(out, {"trajectory.csv": "a", "p.mod": "b", "report.html": "c"})
    (out / "notes.txt").write_text("mine")
    _commit(out, {"trajectory.csv": "new"})
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt", "result.json", "trajectory.csv"]
    assert (out / "trajectory.csv").read_text() == "new" and _claims_hold(out)


def test_a_failure_before_the_commit_leaves_the_previous_set_untouched(tmp_path):
    out = tmp_path / "out"
    _commit(out, {"trajectory.csv": "a", "p.mod": "b"})
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    with pytest.raises(RuntimeError), StagedOutputs(out) as stage:
        (stage.dir / "trajectory.csv").write_text("half")
        raise RuntimeError("solver died")
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_a_failed_first_run_leaves_no_folder(tmp_path):
    out = tmp_path / "a" / "out"
    with pytest.raises(KeyboardInterrupt), StagedOutputs(out):
        raise KeyboardInterrupt
    assert not out.exists()


def test_an_input_is_never_replaced(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "p.mod").write_text("input")
    with pytest.raises(InputError, match="p.mod"):
        _commit(out, {"p.mod": "output"}, protected=(out / "p.mod",))
    assert (out / "p.mod").read_text() == "input" and not (out / "result.json").exists()


def test_leftovers_of_a_killed_run_are_cleaned_by_the_next(tmp_path):
    out = tmp_path / "out"
    _commit(out, {"trajectory.csv": "a", "p.mod": "b"})
    # a run killed between renaming the old result.json and moving the new one in
    os.replace(out / "result.json", out / PREVIOUS)
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    )
    stale = out / f".refine-staging-{int(dead.stdout)}-abcd"
    stale.mkdir()
    (stale / "x.csv").write_text("partial")
    _commit(out, {"trajectory.csv": "c"})
    assert sorted(p.name for p in out.iterdir()) == ["result.json", "trajectory.csv"]


CHILD = textwrap.dedent(
    """
    import sys, time
    import casadi as ca
    import numpy as np
    from refine.interrupt import stoppable

    n = 3000
    x = ca.SX.sym("x", n)
    nlp = {"x": x, "f": ca.sumsqr(x[1:] - x[:-1] ** 2) + ca.sumsqr(1 - x), "g": ca.sin(x[1:]) * ca.cos(x[:-1])}
    solver = ca.nlpsol("s", "ipopt", nlp, {"ipopt.print_level": 0, "print_time": 0, "ipopt.sb": "yes",
                                           "ipopt.max_iter": 100000, "ipopt.tol": 1e-300})
    try:
        with stoppable():
            print("solving", flush=True)
            solver(x0=np.zeros(n), lbg=-0.5, ubg=0.5)
            print(solver.stats()["return_status"], flush=True)
            time.sleep(2.0)
        sys.exit(0)
    except KeyboardInterrupt:
        sys.exit(130)
    """
)


def test_ctrl_c_during_ipopt_stops_the_program(tmp_path):
    script = tmp_path / "child.py"
    script.write_text(CHILD)
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    p = subprocess.Popen(
        [sys.executable, str(script)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    assert p.stdout.readline().strip() == "solving"
    import time

    time.sleep(1.5)  # inside IPOPT: it would run for minutes
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=60)
    assert p.returncode == 130, (out, err)
    assert "Traceback" not in err
