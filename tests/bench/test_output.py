"""What a contender's C and C++ libraries print to file descriptors 1 and 2 stays off the terminal:
without a log folder the runner says how many lines a contender printed and its last error-like line,
with one the files hold the text."""

from __future__ import annotations

import csv
import os

import pytest

from refine.bench import contenders as contenders_module
from refine.bench.runner import run_suites
from refine.bench.watchdog import can_fork

RUN_LINES = [
    (1, "Warning: Failed vertices:"),
    (1, "17"),
    (2, "Error: LadderGraphSolver failed to build graph."),
    (1, "\x1b[33m[WARN] approximate merit function got worse\x1b[0m"),
    (2, "bye"),
]
"""What the contender writes to each file descriptor in each run, as a C library does (no Python I/O)."""

FORKS = pytest.mark.skipif(not can_fork(), reason="the watchdog's worker forks")

SETUP_LINE = "loading the cell"


def _say(lines: list[tuple[int, str]]) -> None:
    for fd, text in lines:
        os.write(fd, (text + "\n").encode())


def noisy(problem):
    _say(RUN_LINES)
    return contenders_module.Answer("ok", None, {"solve": 0.0}, 0.0)


noisy.setup = lambda problem: _say([(1, SETUP_LINE)])


def _run(tmp_path, monkeypatch, tiny_wave, isolate, log_dir=None):
    suites = tmp_path / "suites.toml"
    suites.write_text(tiny_wave)
    monkeypatch.setitem(contenders_module.CONTENDERS, "noisy", noisy)
    csv_path = tmp_path / "b.csv"
    rows = run_suites(
        ["tiny"], ["noisy"], csv_path, suites_file=suites, warmup=1, repeat=2, isolate=isolate,
        log_dir=log_dir,
    )  # fmt: skip
    with csv_path.open() as f:
        written = list(csv.DictReader(f))
    return rows, written


@pytest.mark.parametrize("isolate", [pytest.param(True, marks=FORKS), False])
def test_without_a_log_folder_the_runner_counts_the_lines_and_names_the_last_error(
    tmp_path, monkeypatch, tiny_wave, capfd, isolate
):
    rows, written = _run(tmp_path, monkeypatch, tiny_wave, isolate)
    out, err = capfd.readouterr()
    assert [r["contender"] for r in written] == ["noisy"] and rows[0]["contender"] == "noisy"
    lines = out.splitlines()
    (at,) = [i for i, line in enumerate(lines) if line.startswith("tiny") and " noisy " in line]
    # three runs (one warm-up, two timed) of five lines each, and the set-up's line
    n = 3 * len(RUN_LINES) + 1
    assert lines[at + 1] == (
        f'  noisy printed {n} line(s) (last: "Error: LadderGraphSolver failed to build graph."); '
        "--log-dir DIR keeps them"
    )
    # the text itself is on neither stream: only the summary names the error
    assert "Failed vertices" not in out + err and "merit function" not in out + err
    assert SETUP_LINE not in out + err and "bye" not in out + err
    assert (out + err).count("LadderGraphSolver") == 1


@pytest.mark.parametrize("isolate", [pytest.param(True, marks=FORKS), False])
def test_with_a_log_folder_the_files_hold_what_the_runs_printed(
    tmp_path, monkeypatch, tiny_wave, capfd, isolate
):
    rows, written = _run(tmp_path, monkeypatch, tiny_wave, isolate, log_dir=tmp_path / "logs")
    out, err = capfd.readouterr()
    assert [r["contender"] for r in written] == ["noisy"]
    assert "printed" not in out and "Failed vertices" not in out + err and "LadderGraphSolver" not in out + err
    folder = tmp_path / "logs" / rows[0]["run_id"] / "tiny" / "wave-20"
    run_text = "".join(text + "\n" for _, text in RUN_LINES)
    for name in ("noisy-warmup-1.log", "noisy-1.log", "noisy-2.log"):
        assert (folder / name).read_text() == run_text
    assert (folder / "noisy-setup.log").read_text() == SETUP_LINE + "\n"


_C_STDIO = """
import ctypes, sys
from pathlib import Path
from refine.bench.watchdog import captured
libc = ctypes.CDLL(None)
libc.printf(b"before the block\\n")
with captured(Path(sys.argv[1])):
    libc.printf(b"Error: printed through the C library's stdout\\n")
libc.printf(b"after the block\\n")
"""


def test_what_the_c_library_buffered_inside_the_block_goes_to_the_log(tmp_path):
    """C's ``printf`` to a pipe or a file is fully buffered (unless Python runs unbuffered, which sets
    C's streams unbuffered too): the text printed inside the block belongs in the log, the rest not."""
    import subprocess
    import sys

    log = tmp_path / "run.log"
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    done = subprocess.run(
        [sys.executable, "-c", _C_STDIO, str(log)], env=env, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    assert log.read_text() == "Error: printed through the C library's stdout\n"
    assert done.stdout == "before the block\nafter the block\n"
