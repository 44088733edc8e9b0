"""A whole run, and its outputs written all-or-nothing.

A whole run: load, preflight, solve (:func:`run`), and the outputs written all-or-nothing
(:func:`write_run`: ``result.json``, trajectory, PathML, programs and the report).
"""

from __future__ import annotations

import time
from pathlib import Path

from refine.problem import Problem
from refine.run.result import RunResult
from refine.run.solve import solve_problem


def run(
    problem: Problem,
    out_dir: Path,
    programs: tuple[str, ...] | None = None,
    *,
    report: bool = True,
    accept_frame_error: bool = False,
) -> RunResult:
    """Solve ``problem`` and write every output into ``out_dir``.

    Args:
        problem: the loaded problem.
        out_dir: folder for ``result.json``, ``trajectory.csv``, ``<name>.aml`` and programs.
        programs: program formats overriding ``[output] programs``.
        report: also write ``report.html``.
        accept_frame_error: warn instead of stopping when the tracker frame looks wrong.

    Returns:
        The run's result, with ``outputs`` naming the files written.
    """
    from refine.run.preflight import preflight

    preflight(problem, out_dir, programs, report=report)  # refuse before spending time on the solve
    return write_run(
        solve_problem(problem, accept_frame_error=accept_frame_error), out_dir, programs, report=report
    )


def write_run(
    result: RunResult, out_dir: Path, programs: tuple[str, ...] | None = None, *, report: bool = True
) -> RunResult:
    """Write every output of a solved run into ``out_dir`` (what :func:`run` does after solving).

    Args:
        result: the solved run.
        out_dir: folder for ``result.json``, ``trajectory.csv``, ``<name>.aml`` and programs.
        programs: program formats overriding ``[output] programs``.
        report: also write ``report.html``.

    Returns:
        ``result``, with ``outputs`` naming the files written.
    """
    from refine.export.result_json import write_result_json
    from refine.export.writers import write_outputs
    from refine.run.outputs import StagedOutputs
    from refine.run.preflight import preflight

    problem = result.problem
    checked = preflight(problem, out_dir, programs, report=report, robot=result.robot)
    t0 = time.perf_counter()
    protected = (*problem.input_files, *([problem.source] if problem.source else []))
    with StagedOutputs(out_dir, protected) as stage:  # all or nothing: see refine.run.outputs
        result.outputs.update(write_outputs(result, stage.dir, checked.programs))
        result.timings_s["export"] = time.perf_counter() - t0
        if report:
            from refine.report.html import write_report

            t0 = time.perf_counter()
            result.outputs["report"] = write_report(stage.dir / "report.html", result)
            result.timings_s["report"] = time.perf_counter() - t0
        result.outputs["result"] = stage.dir / "result.json"
        final = stage.commit(result.outputs, lambda path: write_result_json(path, result))
    result.outputs.update(final)
    return result
