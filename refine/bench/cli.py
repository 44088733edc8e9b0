"""``refine bench``: run benchmark suites (``run``), list them (``list``), write the report (``report``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from refine.bench.outcomes import DEFAULT_TIME_LIMIT_S
from refine.bench.provenance import DEFAULT_BLAS_THREADS
from refine.bench.suites import DEFAULT_SUITES

DEFAULT_CSV = Path("out") / "bench" / "bench.csv"


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add the ``bench`` subcommand and its own subcommands."""
    bench = sub.add_parser("bench", help="benchmark refine against other methods on named suites")
    actions = bench.add_subparsers(dest="bench_command", required=True)
    run = actions.add_parser(
        "run", help="run contenders on suites and append one CSV row per problem and contender"
    )
    run.add_argument("--suite", action="append", default=None, help="suite name (repeatable; default: quick)")
    run.add_argument(
        "--contender",
        action="append",
        default=None,
        help="contender (repeatable; default: all): refine, refine-casadi-ad, refine-fatrop, greedy-ik, drake-ik, trajopt, descartes",
    )
    run.add_argument(
        "--contender-file",
        action="append",
        default=[],
        metavar="FILE.py:NAME",
        help="register the contender NAME defined in FILE.py (repeatable; docs/bench.md)",
    )
    run.add_argument(
        "--solver-option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a solver option for every run, typed int, float or text (repeatable): max_iter=100 "
        "(IPOPT's, ipopt.max_iter), fatrop.tol=1e-8; no round of refine overrides it",
    )
    run.add_argument("--repeat", type=int, default=1, help="runs per problem and contender (median, minimum)")
    run.add_argument(
        "--warmup",
        type=int,
        default=1,
        help="untimed runs per problem and contender before the timed ones (default 1)",
    )
    run.add_argument(
        "--time-limit",
        type=float,
        default=DEFAULT_TIME_LIMIT_S,
        help=f"wall seconds one run may take; a longer run is a timeout, a failed row counts as this "
        f"in time summaries (default {DEFAULT_TIME_LIMIT_S:g})",
    )
    run.add_argument(
        "--csv",
        type=Path,
        default=DEFAULT_CSV,
        help=f"CSV to append to, refused unless its header is this version's (default {DEFAULT_CSV})",
    )
    run.add_argument(
        "--blas-threads",
        type=int,
        default=DEFAULT_BLAS_THREADS,
        help=f"threads of every BLAS (CasADi's OpenBLAS under MUMPS, NumPy's) while contenders run, "
        f"recorded per row (default {DEFAULT_BLAS_THREADS})",
    )
    run.add_argument("--suites-file", type=Path, default=DEFAULT_SUITES, help="the suites' TOML file")
    run.add_argument(
        "--log-dir",
        type=Path,
        default=None,
        help="write each run's log (the solver's iteration log) to DIR/RUN_ID/SUITE/PROBLEM/CONTENDER-K.log; "
        "without it what the runs print goes to temporary files, and after a contender's row one line "
        "says how many lines it printed and its last error-like line",
    )
    listing = actions.add_parser("list", help="list the suites and contenders")
    listing.add_argument("--suites-file", type=Path, default=DEFAULT_SUITES)
    report = actions.add_parser(
        "report",
        help="write report.md from one run of a CSV: success per tolerance profile, times, performance profiles, growth, provenance",
    )
    report.add_argument("csv", type=Path, nargs="?", default=DEFAULT_CSV)
    report.add_argument("--out", type=Path, default=None, help="folder for report.md (default: the CSV's)")
    report.add_argument(
        "--run",
        "--run-id",
        dest="run_ids",
        action="append",
        default=None,
        metavar="ID",
        help="a run to report (repeatable: one section per run, no figure mixes runs; default: the CSV's last run)",
    )
    export = actions.add_parser(
        "export",
        help="write the last round of refine's NLP on a problem (nlp.casadi, bounds.json, instance.json) for any NLP solver",
    )
    export.add_argument(
        "problem",
        nargs="?",
        metavar="PROBLEM",
        help="a problem folder or SUITE/NAME, e.g. glass/glass_adhesive (not with --set)",
    )
    export.add_argument("folder", type=Path, metavar="DIR", help="the folder to write")
    export.add_argument(
        "--set", default=None, help="export every problem of the test set [instances.SET] instead"
    )
    export.add_argument("--suites-file", type=Path, default=DEFAULT_SUITES, help="the suites' TOML file")
    export.add_argument(
        "--solver-option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="an IPOPT option for refine's solve (repeatable, as for run), recorded in instance.json",
    )


def run(args: argparse.Namespace) -> int:
    """Carry out ``refine bench ...``; returns the exit status."""
    from refine.bench import peers  # noqa: F401  (adds trajopt and descartes to CONTENDERS)
    from refine.bench.contenders import (
        CONTENDERS,
        load_contender_file,
        load_entry_points,
        parse_solver_option,
    )
    from refine.bench.suites import describe, load_suites

    load_entry_points()
    for spec in getattr(args, "contender_file", []):
        load_contender_file(spec)

    if args.bench_command == "list":
        for line in describe(load_suites(args.suites_file)):
            print(line)
        print("contenders: " + ", ".join(CONTENDERS))
        return 0
    if args.bench_command == "report":
        from refine.bench.report import write_report

        path = write_report(args.csv, args.out or args.csv.parent, args.run_ids)
        print(f"wrote {path}")
        return 0
    if args.bench_command == "export":
        return _export(args)
    from refine.bench.runner import run_suites
    from refine.bench.table import NOT_POSED

    rows = run_suites(
        args.suite or ["quick"],
        args.contender or list(CONTENDERS),
        args.csv,
        suites_file=args.suites_file,
        repeat=args.repeat,
        warmup=args.warmup,
        time_limit_s=args.time_limit,
        blas_threads=args.blas_threads,
        solver_options=dict(parse_solver_option(text) for text in args.solver_option),
        log_dir=args.log_dir,
    )
    run_id = rows[0]["run_id"] if rows else "-"
    print(f"{len(rows)} row(s) of run {run_id} appended to {args.csv}")
    unavailable = [r for r in rows if r["status"] == "unavailable"]
    absent = sorted({r["contender"] for r in unavailable if not r["note"].startswith(NOT_POSED)})
    if absent:
        print(f"not run here (rows with status unavailable, the reason in note): {', '.join(absent)}")
    for r in unavailable:
        if r["note"].startswith(NOT_POSED):
            reason = r["note"][len(NOT_POSED) :].strip()
            print(f"{r['contender']} did not pose {r['suite']}/{r['problem']} (status unavailable): {reason}")
    return 0


def _export(args: argparse.Namespace) -> int:
    from refine.bench.contenders import parse_solver_option
    from refine.bench.export import export_instance, export_set, find_problem
    from refine.bench.suites import load_suites
    from refine.errors import InputError

    data = load_suites(args.suites_file)
    options = dict(parse_solver_option(text) for text in args.solver_option)
    if args.set is not None:
        if args.problem is not None:
            raise InputError(f"bench export --set {args.set} takes only DIR, not also {args.problem!r}")
        export_set(data, args.set, args.folder, solver_options=options)
        return 0
    if args.problem is None:
        raise InputError("bench export needs PROBLEM and DIR (or --set NAME and DIR)")
    done = export_instance(find_problem(data, args.problem), args.folder, solver_options=options)
    print(
        f"{done.name}: round {done.round} of refine's outer loop, refine {done.status} in {done.iterations} "
        f"IPOPT iterations, objective {done.objective:.13g}; wrote {done.folder}/nlp.casadi, bounds.json, instance.json"
    )
    return 0
