"""Ctrl-C at the edges of a run: inside a section that must finish, and after the outputs are complete.

Each case runs a child process and signals it, as a terminal's Ctrl-C would (SIGINT not ignored).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


def _start(script: Path, *args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-u", str(script), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ENV,
        cwd=ROOT,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


DEFERRED_CHILD = textwrap.dedent(
    """
    import threading, time
    from refine.interrupt import deferred

    # a second thread that does not block signals, as CasADi's and BLAS's threads do: the kernel
    # hands a signal the main thread blocks to such a thread
    threading.Thread(target=time.sleep, args=(30,), daemon=True).start()
    try:
        with deferred():
            print("inside", flush=True)
            for _ in range(150):
                sum(range(20000))
                time.sleep(0.01)
            print("section finished", flush=True)
        time.sleep(2.0)
        print("no interrupt", flush=True)
    except KeyboardInterrupt:
        print("interrupted", flush=True)
    """
)


def test_a_deferred_section_finishes_before_the_interrupt_lands(tmp_path):
    script = tmp_path / "child.py"
    script.write_text(DEFERRED_CHILD)
    p = _start(script)
    assert p.stdout.readline().strip() == "inside"
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=60)
    assert out.split() == ["section", "finished", "interrupted"], (out, err)


# The child is named "refine", so refine.cli.main behaves as the program does (exits at once).
PROGRAM_CHILD = textwrap.dedent(
    """
    import json, sys, time
    from pathlib import Path
    import refine.cli as cli
    from refine.run.outputs import StagedOutputs

    PAUSE_BEFORE, PAUSE_AFTER = float(sys.argv[1]), float(sys.argv[2])

    def fake_run(args, problem):
        with StagedOutputs(args.out) as stage:
            (stage.dir / "trajectory.csv").write_text("t\\n0\\n")
            print("staged", flush=True)
            time.sleep(PAUSE_BEFORE)
            def write(path):
                files = {"trajectory.csv": __import__("refine.run.outputs").run.outputs.file_digest(stage.dir / "trajectory.csv")}
                path.write_text(json.dumps({"schema_version": 1, "status": "infeasible", "files": files}))
            stage.commit({"trajectory": stage.dir / "trajectory.csv"}, write)
        print("committed", flush=True)
        time.sleep(PAUSE_AFTER)  # the summary, the second result.json write
        print("summary", flush=True)
        return cli.exit_status("infeasible")

    cli._run = fake_run
    sys.argv = ["refine", "run", "problems/glass_adhesive", "--out", sys.argv[3]]
    sys.exit(cli.main())
    """
)


@pytest.mark.parametrize("moment", ["before the commit", "after the commit"])
def test_ctrl_c_before_the_commit_exits_130_after_it_the_runs_own_status(tmp_path, moment):
    script = tmp_path / "refine"
    script.write_text(PROGRAM_CHILD)
    out = tmp_path / "out"
    out.mkdir()
    (out / "result.json").write_text(json.dumps({"schema_version": 1, "status": "ok", "files": {}}))
    before = moment == "before the commit"
    p = _start(script, "2.0" if before else "0", "0" if before else "2.0", str(out))
    wait_for = "staged" if before else "committed"
    while (line := p.stdout.readline().strip()) != wait_for:
        assert line, p.communicate()
    p.send_signal(signal.SIGINT)
    rest, err = p.communicate(timeout=60)
    assert "Traceback" not in err
    doc = json.loads((out / "result.json").read_text())
    if before:
        assert p.returncode == 130, err
        assert doc["status"] == "ok"  # the previous set
        assert sorted(f.name for f in out.iterdir()) == ["result.json"]
        assert "keeps its previous complete set" in err
    else:
        assert p.returncode == 1, err  # infeasible, as the run decided; never 130, -2 or a traceback
        assert doc["status"] == "infeasible"
        assert "summary" in rest  # the run was not cut short
        assert sorted(f.name for f in out.iterdir()) == ["result.json", "trajectory.csv"]
