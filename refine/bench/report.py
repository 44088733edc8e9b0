"""``refine bench report``: a Markdown report with tables and log-log plots, from the CSV alone.

Every table, figure and ratio comes from the rows of one run (:func:`refine.bench.table.read_run`:
the last run of the file, or the one asked for), and within the run, figures that pair or fit rows
(the glass ratios, a family's growth exponent) take them from one suite.
"""

from __future__ import annotations

import math
import statistics
from collections import defaultdict
from pathlib import Path

import numpy as np

from refine.bench.suites import growth_exponent
from refine.bench.table import Row, read_run


def _f(row: Row, key: str) -> float:
    try:
        return float(row.get(key, "") or "nan")
    except ValueError:
        return math.nan


def _yes(row: Row, key: str) -> bool:
    return row.get(key, "") == "True"


def _fmt(x: float, digits: int = 3) -> str:
    return "–" if math.isnan(x) else f"{x:.{digits}f}"


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
        line = (
            f"- Glass cell (suite `{suite}`), refine build + seed + solve: {_fmt(total)} s wall ({_fmt(_f(glass, 'cpu_s'))} s CPU), "
            f"verified {'yes' if _yes(glass, 'verified') else 'no'}, largest deviation "
            f"{_fmt(_f(glass, 'max_orientation_deviation_deg'), 2)} deg"
        )
        for other in ("drake-ik", "greedy-ik", "refine-casadi-ad", "refine-fatrop"):
            peer = by.get(("glass_adhesive", other))
            if peer:
                line += (
                    f"; {other} {_fmt(_f(peer, 'total_s'))} s wall ({_fmt(_f(peer, 'cpu_s'))} s CPU), ratio refine / "
                    f"{other} {_fmt(total / _f(peer, 'total_s'), 2)} (wall), "
                    f"{_fmt(_f(glass, 'cpu_s') / _f(peer, 'cpu_s'), 2)} (CPU), deviation "
                    f"{_fmt(_f(peer, 'max_orientation_deviation_deg'), 2)} deg, verified "
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
        parts = [
            f"- {family} (suite `{suite}`): growth exponent of build + seed + solve "
            f"{_fmt(growth_exponent(n, t), 2)} (wall), {_fmt(growth_exponent(n, c), 2)} (CPU) over the "
            f"{len(fitted)} successful rows, {span} waypoints"
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


def _plot(rows: list[Row], family: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_wall, ax_cpu) = plt.subplots(1, 2, figsize=(9, 3.6))
    contenders = sorted({r["contender"] for r in rows})
    for contender in contenders:
        rs = sorted((r for r in rows if r["contender"] == contender), key=lambda r: int(r["n_waypoints"]))
        n = [int(r["n_waypoints"]) for r in rs]
        for ax, key in ((ax_wall, "total_s"), (ax_cpu, "cpu_s")):
            ax.loglog(n, [_f(r, key) for r in rs], "o-", label=contender)
    for ax, title in ((ax_wall, "wall time [s]"), (ax_cpu, "CPU time [s]")):
        ax.set_xlabel("waypoints")
        ax.set_title(f"{family}: {title}")
        ax.grid(True, which="both", alpha=0.3)
    ax_wall.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_report(csv_path: Path, out_dir: Path, run_id: str | None = None) -> Path:
    """Write ``report.md`` (and its plots) into ``out_dir`` from one run of the CSV; returns its path.

    ``run_id``: the run to report (default: the file's last run).
    """
    run_id, rows = read_run(csv_path, run_id)
    rows = _latest(rows)
    out_dir.mkdir(parents=True, exist_ok=True)
    first = rows[0]
    dates = sorted(r.get("date", "") for r in rows)
    limits = sorted({r["time_limit_s"] for r in rows}, key=float)
    lines = [
        "# refine benchmark",
        "",
        f"Run `{run_id}` of `{Path(csv_path).name}`: {len(rows)} rows, {dates[0]} to {dates[-1]} "
        f"(schema {first['schema']}); no row of another run is used.",
        "",
        f"Machine: {first.get('machine', '?')}, {first.get('cpu', '?')}, {first.get('cores', '?')} cores. "
        f"Python {first.get('python', '?')}, refine {first.get('refine', '?')}, CasADi {first.get('casadi', '?')}, "
        f"Pinocchio {first.get('pinocchio', '?')}, Drake {first.get('drake') or 'not installed'}.",
        "",
        "Times are build + seed + solve of each contender (verification excluded, the same for all); "
        "wall time is the median over repeats, CPU time the process's. Every answer is verified by the "
        "same check: TCP position, orientation cone, joint limits, singularity margin, and clearance "
        "(dense check) where the problem has a cell.",
        "",
        "Success: a claimed answer (`ok`, `repaired`) that passes that check, within the time limit. "
        "Detected: on a problem stated infeasible, an `infeasible` answer with joints for every "
        "waypoint that the check rejects in the stated stretch (docs/bench.md). A row with neither "
        f"is failed and counts as the time limit, {' / '.join(limits)} s, in the summary's medians "
        "(penalised); a crash is status `error`, a run over the limit `timeout`.",
        "",
        "## Targets",
        "",
        *targets(rows),
        "",
        "## Summary",
        "",
        "| suite | contender | problems | success | verified | detected infeasible | failed | timed out | "
        "median wall s (penalised) | median CPU s (penalised) |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    groups: dict[tuple[str, str], list[Row]] = defaultdict(list)
    for r in rows:
        groups[(r["suite"], r["contender"])].append(r)
    for (suite, contender), rs in sorted(groups.items()):
        lines.append(
            f"| {suite} | {contender} | {len(rs)} | {sum(_yes(r, 'success') for r in rs)} | "
            f"{sum(_yes(r, 'verified') for r in rs)} | {sum(_yes(r, 'detected_infeasible') for r in rs)} | "
            f"{sum(not (_yes(r, 'success') or _yes(r, 'detected_infeasible')) for r in rs)} | "
            f"{sum(_yes(r, 'timed_out') for r in rs)} | "
            f"{_fmt(statistics.median(_f(r, 'penalised_total_s') for r in rs))} | "
            f"{_fmt(statistics.median(_f(r, 'penalised_cpu_s') for r in rs))} |"
        )
    for suite in sorted({r["suite"] for r in rows}):
        srows = sorted(
            (r for r in rows if r["suite"] == suite),
            key=lambda r: (r["problem"].rsplit("-", 1)[0], int(r["n_waypoints"]), r["contender"]),
        )
        lines += [
            "",
            f"## Suite `{suite}`",
            "",
            "| problem | N | contender | status | verified | success | detected | build s | seed s | solve s | total s | "
            "CPU s | iter | max dev deg | min clearance mm | peak RSS MB | note |",
            "|---|---:|---|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|",
        ]
        for r in srows:
            clearance = _f(r, "min_clearance_m") * 1e3
            lines.append(
                f"| {r['problem']} | {r['n_waypoints']} | {r['contender']} | {r['status']} | "
                f"{'yes' if _yes(r, 'verified') else 'no'} | {'yes' if _yes(r, 'success') else 'no'} | "
                f"{'yes' if _yes(r, 'detected_infeasible') else ('no' if r['expected'] == 'infeasible' else '–')} | "
                f"{_fmt(_f(r, 'build_s'))} | {_fmt(_f(r, 'seed_s'))} | {_fmt(_f(r, 'solve_s'))} | "
                f"{_fmt(_f(r, 'total_s'))} | {_fmt(_f(r, 'cpu_s'))} | {r.get('iterations', '')} | "
                f"{_fmt(_f(r, 'max_orientation_deviation_deg'), 2)} | {_fmt(clearance, 1)} | "
                f"{_fmt(_f(r, 'peak_rss_mb'), 0)} | {(r.get('reason') or r.get('note', ''))[:60]} |"
            )
        families = sorted({r["problem"].rsplit("-", 1)[0] for r in srows if "-" in r["problem"]})
        for family in families:
            frows = [r for r in srows if r["problem"].rsplit("-", 1)[0] == family]
            if len({r["n_waypoints"] for r in frows}) < 2:
                continue
            png = out_dir / f"{suite}-{family}.png"
            _plot(frows, family, png)
            lines += ["", f"![{family}: time against waypoints, log-log]({png.name})"]
    report = out_dir / "report.md"
    report.write_text("\n".join(lines) + "\n")
    return report
