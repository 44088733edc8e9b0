"""``refine bench report``: a Markdown report with tables, plots and provenance, from the CSV alone.

Every table, figure and ratio comes from the rows of one run (:func:`refine.bench.table.read_runs`:
the last run of the file, or the ones asked for, each in its own section), and within the run,
figures that pair or fit rows (the glass ratios, a family's growth exponent, a performance
profile) take them from one suite. The figures themselves are :mod:`refine.bench.figures`'.
"""

from __future__ import annotations

import json
import math
import statistics
from collections import defaultdict
from pathlib import Path

import numpy as np

from refine.bench.figures import (
    PROFILES,
    SHIFT_S,
    growth,
    plot_growth,
    plot_profile,
    shifted_geometric_mean,
    solved,
)
from refine.bench.figures import number as _f
from refine.bench.figures import yes as _yes
from refine.bench.rules import RULES, UNSTATED
from refine.bench.table import NOT_POSED, Row, read_runs


def _fmt(x: float, digits: int = 3) -> str:
    return "–" if math.isnan(x) else f"{x:.{digits}f}"


def _exponent(fit: dict) -> str:
    """``0.72, 95 % interval 0.65 to 0.79, local slopes 0.61 to 0.80`` (what the fit has points for)."""
    text = _fmt(fit["exponent"], 2)
    if not math.isnan(fit["low"]):
        text += f", 95 % interval {_fmt(fit['low'], 2)} to {_fmt(fit['high'], 2)}"
    local = fit["local"]
    if len(local) > 1:
        text += f", local slopes {_fmt(min(local), 2)} to {_fmt(max(local), 2)}"
    return text


def _latest(rows: list[Row]) -> list[Row]:
    """The last row of each (suite, problem, contender): a CSV may hold several runs appended."""
    last: dict[tuple[str, str, str], Row] = {}
    for row in rows:
        last[(row["suite"], row["problem"], row["contender"])] = row
    return list(last.values())


def targets(rows: list[Row]) -> list[str]:
    """The figures the benchmark is judged by, as Markdown lines (those the rows have data for).

    ``rows``: one run's. Rows are paired (glass ratios) and fitted (growth exponents) within a suite.
    """
    lines = []
    for suite in sorted({r["suite"] for r in rows}):
        lines += _suite_targets(suite, [r for r in rows if r["suite"] == suite])
    return lines


def _suite_targets(suite: str, rows: list[Row]) -> list[str]:
    """The target lines of one suite's rows of one run."""
    by = {(r["problem"], r["contender"]): r for r in rows}
    lines = []
    glass = by.get(("glass_adhesive", "refine"))
    if glass:
        total = _f(glass, "total_s")
        checked = _f(glass, "cpu_s") + _f(glass, "verify_cpu_s")  # the goal's span: its own check too
        line = (
            f"- Glass cell (suite `{suite}`), refine build + seed + solve: {_fmt(total)} s wall ({_fmt(_f(glass, 'cpu_s'))} s CPU), "
            f"with its own verification {_fmt(total + _f(glass, 'verify_s'))} s wall ({_fmt(checked)} s CPU), "
            f"verified {'yes' if _yes(glass, 'verified') else 'no'}, largest deviation "
            f"{_fmt(_f(glass, 'max_orientation_deviation_deg'), 2)} deg, largest joint step "
            f"{_fmt(_f(glass, 'max_joint_step_deg'), 2)} deg"
        )
        for other in ("trajopt", "descartes", "drake-ik", "greedy-ik", "refine-casadi-ad", "refine-fatrop"):
            peer = by.get(("glass_adhesive", other))
            if peer:
                line += (
                    f"; {other} {_fmt(_f(peer, 'total_s'))} s wall ({_fmt(_f(peer, 'cpu_s'))} s CPU), ratio refine / "
                    f"{other} {_fmt(total / _f(peer, 'total_s'), 2)} (wall), "
                    f"{_fmt(_f(glass, 'cpu_s') / _f(peer, 'cpu_s'), 2)} (CPU), "
                    f"{_fmt(checked / _f(peer, 'cpu_s'), 2)} (CPU, refine's own verification in), deviation "
                    f"{_fmt(_f(peer, 'max_orientation_deviation_deg'), 2)} deg, largest joint step "
                    f"{_fmt(_f(peer, 'max_joint_step_deg'), 2)} deg, verified "
                    f"{'yes' if _yes(peer, 'verified') else 'no'}"
                )
        if glass.get("load_1min"):
            line += f" (medians of {glass.get('repeats', '?')} turns, load average {glass['load_1min']})"
        lines.append(line)
    families: dict[str, list[Row]] = defaultdict(list)
    for r in rows:
        if r["contender"] == "refine" and "-" in r["problem"] and r["suite"] != "unreachable":
            families[r["problem"].rsplit("-", 1)[0]].append(r)
    for family, rs in sorted(families.items()):
        rs.sort(key=lambda r: int(r["n_waypoints"]))
        fitted = [r for r in rs if _yes(r, "success")]  # a failed row's time is no point of the curve
        n = np.array([int(r["n_waypoints"]) for r in fitted])
        t = np.array([_f(r, "total_s") for r in fitted])
        c = np.array([_f(r, "cpu_s") for r in fitted])
        at = {int(r["n_waypoints"]): r for r in rs}
        span = f"{n.min()}-{n.max()}" if len(n) else "no"
        wall, cpu = growth(list(n), list(t)), growth(list(n), list(c))
        parts = [
            f"- {family} (suite `{suite}`): growth exponent of build + seed + solve "
            f"{_fmt(wall['exponent'], 2)} (wall), {_fmt(cpu['exponent'], 2)} (CPU) over the "
            f"{len(fitted)} successful rows, {span} waypoints (CPU: {_exponent(cpu)})"
        ]
        if 6400 in at:
            parts.append(
                f"; 6,400 waypoints {_fmt(_f(at[6400], 'total_s'))} s wall, {_fmt(_f(at[6400], 'cpu_s'))} s CPU"
            )
        verified = sum(_yes(r, "verified") for r in rs)
        parts.append(f"; {verified}/{len(rs)} verified")
        lines.append("".join(parts))
    if suite == "unreachable":
        score: dict[str, list[int]] = defaultdict(lambda: [0, 0, 0, 0])
        for r in rows:
            stated = r["expected"] == "infeasible"
            score[r["contender"]][0] += _yes(r, "success") and not stated
            score[r["contender"]][1] += not stated
            score[r["contender"]][2] += _yes(r, "detected_infeasible")
            score[r["contender"]][3] += stated
        lines.append(
            "- Unreachable family: "
            + ", ".join(
                f"{c} {s}/{n} successes, {d}/{m} stated infeasibilities detected"
                for c, (s, n, d, m) in sorted(score.items())
            )
        )
    return lines


def _distinct(rows: list[Row], key: str) -> str:
    values = list(dict.fromkeys(r.get(key, "") for r in rows if r.get(key, "")))
    return " / ".join(values) if values else "not recorded"


def provenance(run_id: str, rows: list[Row]) -> list[str]:
    """The provenance block of one run's rows: what ran, where, with which settings."""
    first = rows[0]
    dates = sorted(r.get("date", "") for r in rows)
    lines = [
        f"- run `{run_id}`, started {dates[0]}"
        + (f" (rows dated to {dates[-1]})" if dates[-1] != dates[0] else "")
        + f", {len(rows)} rows, schema {first['schema']}",
        f"- refine {first.get('refine', '?')}, commit `{_distinct(rows, 'git_commit')}`",
        f"- solvers: {_distinct(rows, 'solver_versions')}; Pinocchio {first.get('pinocchio', '?')}, "
        f"Drake {first.get('drake') or 'not installed'}; Python {first.get('python', '?')}",
        f"- machine: {first.get('machine', '?')}, {first.get('cpu', '?')}, {first.get('cores', '?')} cores; "
        f"1-minute load during the runs {_distinct(rows, 'load_1min')}",
        f"- BLAS threads: {_distinct(rows, 'blas_threads')}",
        f"- time limit per run {_distinct(rows, 'time_limit_s')} s; timed runs per row "
        f"{_distinct(rows, 'repeats')}, untimed warm-up runs {_distinct(rows, 'warmup')}",
    ]
    for contender in sorted({r["contender"] for r in rows}):
        options = {r.get("solver_options", "") for r in rows if r["contender"] == contender}
        options.discard("")
        options.discard("{}")
        if options:
            shown = "; ".join(_options(o) for o in sorted(options))
            lines.append(f"- solver options of {contender} (the last solve's): {shown}")
    return lines


def _options(text: str) -> str:
    try:
        options = json.loads(text)
    except ValueError:
        return text
    return ", ".join(f"`{k}={v}`" for k, v in sorted(options.items()))


def _profiles_table(groups: dict[tuple[str, str], list[Row]]) -> list[str]:
    names = list(PROFILES)
    lines = [
        "| suite | contender | problems | "
        + " | ".join(f"success `{n}`" for n in names)
        + " | detected infeasible | failed | timed out |",
        "|---|---|---:|" + "---:|" * len(names) + "---:|---:|---:|",
    ]
    for (suite, contender), rs in sorted(groups.items()):
        stated = sum(r["expected"] == "infeasible" for r in rs)
        cells = [f"{sum(PROFILES[n][1](r) for r in rs)}/{len(rs)}" for n in names]
        lines.append(
            f"| {suite} | {contender} | {len(rs)} | " + " | ".join(cells) + " | "
            f"{sum(_yes(r, 'detected_infeasible') for r in rs)}/{stated} | "
            f"{sum(not solved(r) for r in rs)} | {sum(_yes(r, 'timed_out') for r in rs)} |"
        )
    return lines


def _best_on(groups: dict[tuple[str, str], list[Row]], suite: str, problems: set[str]) -> float:
    """The least shifted geometric mean of penalised CPU times on ``problems`` [s].

    Of the contenders of ``suite`` that posed every one of ``problems``: a contender's ratio is
    taken on its own problems only.
    """
    means = []
    for (s, _), rs in groups.items():
        mine = [r for r in rs if r["problem"] in problems]
        if s == suite and {r["problem"] for r in mine} == problems:
            means.append(shifted_geometric_mean([_f(r, "penalised_cpu_s") for r in mine]))
    return min(means)


def _times_table(groups: dict[tuple[str, str], list[Row]]) -> list[str]:
    lines = [
        "| suite | contender | problems | shifted geometric mean CPU s (penalised) | ratio to the best on its problems | "
        "shifted geometric mean wall s (penalised) | median wall s (penalised) | least CPU s of a solved row | "
        "median spread of repeats |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    sgm = {k: shifted_geometric_mean([_f(r, "penalised_cpu_s") for r in rs]) for k, rs in groups.items()}
    for (suite, contender), rs in sorted(groups.items()):
        best = _best_on(groups, suite, {r["problem"] for r in rs})
        spreads = [
            (_f(r, "max_total_s") - _f(r, "min_total_s")) / _f(r, "total_s")
            for r in rs
            if _f(r, "total_s") > 0 and int(r.get("repeats") or 1) > 1
        ]
        least = [_f(r, "cpu_s") for r in rs if solved(r)]
        lines.append(
            f"| {suite} | {contender} | {len(rs)} | {_fmt(sgm[(suite, contender)])} | "
            f"{_fmt(sgm[(suite, contender)] / best, 2) if best > 0 else '–'} | "
            f"{_fmt(shifted_geometric_mean([_f(r, 'penalised_total_s') for r in rs]))} | "
            f"{_fmt(statistics.median(_f(r, 'penalised_total_s') for r in rs))} | "
            f"{_fmt(min(least)) if least else '–'} | "
            f"{_fmt(100 * statistics.median(spreads), 0) + ' %' if spreads else '–'} |"
        )
    return lines


def _growth_table(rows: list[Row]) -> list[str]:
    lines = [
        "| suite | family | contender | sizes fitted | exponent of CPU time | exponent of wall time |",
        "|---|---|---|---|---|---|",
    ]
    count = 0
    keys = sorted(
        {(r["suite"], r["problem"].rsplit("-", 1)[0], r["contender"]) for r in rows if "-" in r["problem"]}
    )
    for suite, family, contender in keys:
        rs = [
            r for r in rows
            if (r["suite"], r["problem"].rsplit("-", 1)[0], r["contender"]) == (suite, family, contender)
            and _yes(r, "success")
        ]  # fmt: skip
        n = [int(r["n_waypoints"]) for r in rs]
        if len(set(n)) < 2:
            continue
        count += 1
        lines.append(
            f"| {suite} | {family} | {contender} | {', '.join(map(str, sorted(n)))} | "
            f"{_exponent(growth(n, [_f(r, 'cpu_s') for r in rs]))} | "
            f"{_exponent(growth(n, [_f(r, 'total_s') for r in rs]))} |"
        )
    return lines if count else []


def _absent_lines(absent: list[Row]) -> list[str]:
    """One provenance line per contender that could not run here, and per problem a contender did not pose."""
    lines = []
    posed = [r for r in absent if not r["note"].startswith(NOT_POSED)]
    for c in sorted({r["contender"] for r in posed}):
        mine = [r for r in posed if r["contender"] == c]
        lines.append(f"- not run here: {c} on {len(mine)} problem(s), {mine[0]['note']}")
    for r in sorted((r for r in absent if r["note"].startswith(NOT_POSED)), key=lambda r: r["contender"]):
        lines.append(
            f"- not posed: {r['contender']} on {r['suite']}/{r['problem']}, {r['note'][len(NOT_POSED) :].strip()}"
        )
    return lines


def run_section(run_id: str, rows: list[Row], out_dir: Path, prefix: str = "") -> list[str]:
    """The Markdown of one run's rows (plots written into ``out_dir``, names starting ``prefix``).

    Rows of a contender that could not run here, or did not pose the problem (status
    ``unavailable``), are listed in the provenance block and enter no table, figure, average or ratio.
    """
    rows = _latest(rows)
    absent = [r for r in rows if r["status"] == "unavailable"]
    rows = [r for r in rows if r["status"] != "unavailable"]
    if not rows:
        return ["No contender ran: " + "; ".join(sorted({f"{r['contender']} ({r['note']})" for r in absent}))]
    limits = sorted({r["time_limit_s"] for r in rows}, key=float)
    lines = [
        "Times are build + seed + solve of each contender (verification excluded, the same for all); "
        "wall time is the median over repeats, CPU time the process's. refine's own verification of "
        "its answers (and diagnosis of a repair) is the column `own check CPU s`, apart; the peers "
        "have none. Every answer of every timed "
        "run is verified by the same check: TCP position, orientation cone, joint limits, "
        "singularity margin, and clearance (dense check) where the problem has a cell.",
        "",
        "Verified: of the timed runs whose answer claims a path, how many keep what they claim: an "
        "`ok` answer every tolerance, a `repaired` one every tolerance with the orientation slack it "
        "reports and no more. An `infeasible` (or failed) answer claims no path: `–`; whether it "
        "detected a stated infeasibility is the column `detected`.",
        "",
        "Success: a claimed answer (`ok`, `repaired`) of a solver that converged, passing that check, "
        "within the time limit, in every timed run. Detected: on a problem stated infeasible, an "
        "`infeasible` answer with joints for every waypoint that the check rejects in the stated "
        "stretch (docs/bench.md). A row with neither is failed and counts as the time limit, "
        f"{' / '.join(limits)} s, in the penalised times; a crash is status `error`, a run over the "
        "limit `timeout`.",
        "",
        "### Provenance",
        "",
        *provenance(run_id, rows),
        *_absent_lines(absent),
        "",
        "### Targets",
        "",
        *targets(rows),
        "",
        "### Success per tolerance profile",
        "",
        *(f"- `{name}`: {text}" for name, (text, _) in PROFILES.items()),
        "- residuals: the objective and KKT residuals of the answer on the refinement NLP, the same "
        'evaluation for every contender (docs/bench.md, "Quality columns"); the KKT profiles ask for '
        "an optimum of refine's cost, so a contender that minimises another cost fails them by design",
        "",
    ]
    groups: dict[tuple[str, str], list[Row]] = defaultdict(list)
    for r in rows:
        groups[(r["suite"], r["contender"])].append(r)
    lines += _profiles_table(groups)
    lines += ["", "### Rules kept", "", *rules_table(rows)]
    lines += [
        "",
        "### Times",
        "",
        f"Shifted geometric means (shift {SHIFT_S:g} s) and medians of the penalised times: a failed row "
        "counts as the time limit. The spread of a row is (slowest - fastest) / median of its timed runs.",
        "",
        *_times_table(groups),
    ]
    grown = _growth_table(rows)
    if grown:
        lines += ["", "### Growth (successful rows, log-log least squares)", "", *grown]
    for suite in sorted({r["suite"] for r in rows}):
        srows = sorted(
            (r for r in rows if r["suite"] == suite),
            key=lambda r: (r["problem"].rsplit("-", 1)[0], int(r["n_waypoints"]), r["contender"]),
        )
        lines += ["", f"### Suite `{suite}`", ""]
        if len({r["contender"] for r in srows}) > 1 and len({r["problem"] for r in srows}) > 1:
            paths = plot_profile(srows, f"suite {suite} (CPU time)", out_dir / f"{prefix}{suite}-profile")
            lines += [
                f"![performance profiles of suite {suite}]({paths[0].name}) ([SVG]({paths[1].name})): "
                "one panel per tolerance profile, each the share of the suite's problems a contender "
                "passed within τ times the CPU time of the fastest contender that passed it in that "
                "profile (Dolan and Moré); `verified` counts successes and detections, a KKT profile "
                "its successes within the residuals; a failed row is never within.",
                "",
            ]
        lines += [
            "| problem | N | contender | status | solver status | verified | success | detected | total s | "
            "CPU s | own check CPU s | iter | objective | primal res. | dual res. | max dev deg | max step deg | min clearance mm | "
            "rules not kept | note |",
            "|---|---:|---|---|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---|",
        ]
        for r in srows:
            clearance = _f(r, "min_clearance_m") * 1e3
            lines.append(
                f"| {r['problem']} | {r['n_waypoints']} | {r['contender']} | {r['status']} | "
                f"{r.get('solver_status') or '–'} | {verified_cell(r)} | "
                f"{'yes' if _yes(r, 'success') else 'no'} | "
                f"{'yes' if _yes(r, 'detected_infeasible') else ('no' if r['expected'] == 'infeasible' else '–')} | "
                f"{_fmt(_f(r, 'total_s'))} | {_fmt(_f(r, 'cpu_s'))} | {_fmt(_f(r, 'verify_cpu_s'))} | "
                f"{r.get('iterations', '')} | "
                f"{_sci(_f(r, 'objective'), 6)} | {_sci(_f(r, 'primal_residual'))} | {_sci(_f(r, 'dual_residual'))} | "
                f"{_fmt(_f(r, 'max_orientation_deviation_deg'), 2)} | {_fmt(_f(r, 'max_joint_step_deg'), 2)} | "
                f"{_fmt(clearance, 1)} | {(r.get('rules_not_kept') or '–').replace(';', ', ')} | "
                f"{_remark(r)} |"
            )
        families = sorted({r["problem"].rsplit("-", 1)[0] for r in srows if "-" in r["problem"]})
        for family in families:
            frows = [r for r in srows if r["problem"].rsplit("-", 1)[0] == family]
            if len({r["n_waypoints"] for r in frows}) < 2:
                continue
            png = out_dir / f"{prefix}{suite}-{family}.png"
            plot_growth(frows, family, png)
            lines += ["", f"![{family}: time against waypoints, log-log]({png.name})"]
    return lines


def _remark(row: Row) -> str:
    """The note cell: the first tolerance the strict check finds broken, else the contender's note.

    A repaired answer verified with its slack breaks the strict cone where it used the slack: then
    the cell says so (``within its slack; strict: ...``), so it does not read as a failure.
    """
    reason = row.get("reason", "")
    if reason and row["status"] == "repaired" and _yes(row, "verified"):
        return f"within its slack; strict: {reason}"[:80]
    return (reason or row.get("note", ""))[:60]


def verified_cell(row: Row) -> str:
    """The report's ``verified`` of a row: ``kept/claimed`` runs, ``of R`` when not every run claimed.

    A run claims a path when it answers ``ok`` or ``repaired``; a row without one is ``–``.
    """
    claimed = int(row.get("claimed_runs") or 0)
    if not claimed:
        return "–"
    repeats = int(row.get("repeats") or claimed)
    return f"{row['verified_runs']}/{claimed}" + (f" of {repeats}" if claimed < repeats else "")


def rules_table(rows: list[Row]) -> list[str]:
    """Which of refine's rules each contender of ``rows`` poses (the verification checks them all)."""
    lines = [
        'What each contender poses (docs/bench.md, "Rules kept"); the verification checks every rule '
        "of every answer, so a rule a contender does not pose is one its answers may break: "
        + "; ".join(f"`{k}`: {v}" for k, v in RULES.items())
        + ".",
        "",
        "| contender | keeps | does not keep |",
        "|---|---|---|",
    ]
    for name in sorted({r["contender"] for r in rows}):
        r = next(r for r in rows if r["contender"] == name)
        kept, missing = r.get("rules_kept", UNSTATED), r.get("rules_not_kept", UNSTATED)
        lines.append(f"| {name} | {kept.replace(';', ', ') or '–'} | {missing.replace(';', ', ') or '–'} |")
    return lines


def _sci(x: float, digits: int = 1) -> str:
    return "–" if math.isnan(x) else f"{x:.{digits}e}"


def write_report(csv_path: Path, out_dir: Path, run_ids: list[str] | str | None = None) -> Path:
    """Write ``report.md`` (and its plots) into ``out_dir`` from runs of the CSV; returns its path.

    ``run_ids``: the runs to report, each in its own section (default: the file's last run).
    """
    if isinstance(run_ids, str):
        run_ids = [run_ids]
    runs = read_runs(csv_path, run_ids)
    out_dir.mkdir(parents=True, exist_ok=True)
    name = Path(csv_path).name
    if len(runs) == 1:
        run_id, rows = runs[0]
        head = f"Run `{run_id}` of `{name}`: {len(rows)} rows; no row of another run is used."
    else:
        head = (
            f"Runs {', '.join(f'`{r}`' for r, _ in runs)} of `{name}`, one section each: no table, "
            "ratio, fit or profile combines rows of two runs."
        )
    lines = ["# refine benchmark", "", head]
    for i, (run_id, rows) in enumerate(runs):
        title = f"## Run `{run_id}`" if len(runs) > 1 else "## The run"
        prefix = f"run{i + 1}-" if len(runs) > 1 else ""
        lines += ["", title, "", *run_section(run_id, rows, out_dir, prefix)]
    report = out_dir / "report.md"
    report.write_text("\n".join(lines) + "\n")
    return report
