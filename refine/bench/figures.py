"""The report's figures: tolerance profiles, shifted geometric means, performance profiles, growth.

Performance profiles are Dolan and Moré's (2002); growth is fitted log-log with local slopes.

All of it works on CSV rows (strings), so a report is regenerated from the file alone
(docs/bench.md, "The report").
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from refine.bench.table import Row

SHIFT_S = 0.1
"""Shift of the shifted geometric mean of times [s]: about the shortest runs of the suites (greedy
IK of a short path), so runs far below it weigh as little as their absolute difference."""


def number(row: Row, key: str) -> float:
    """A numeric column, NaN when empty or not a number."""
    try:
        return float(row.get(key, "") or "nan")
    except ValueError:
        return math.nan


def yes(row: Row, key: str) -> bool:
    """A boolean column."""
    return row.get(key, "") == "True"


def solved(row: Row) -> bool:
    """A success or, on a problem stated infeasible, a detection: the rows not penalised."""
    return yes(row, "success") or yes(row, "detected_infeasible")


def _kkt(primal_max: float, dual_max: float) -> Callable[[Row], bool]:
    def passes(row: Row) -> bool:
        return (
            yes(row, "success")
            and number(row, "primal_residual") <= primal_max
            and number(row, "dual_residual") <= dual_max
        )

    return passes


PROFILES: dict[str, tuple[str, Callable[[Row], bool]]] = {
    "verified": (
        "a success: converged, verified with the problem's tolerances (a repair on a problem built "
        "for one: with the slack it reports)",
        lambda r: yes(r, "success"),
    ),
    "kkt-1e-4": ("a success with primal residual <= 1e-6 and dual residual <= 1e-4", _kkt(1e-6, 1e-4)),
    "kkt-1e-6": ("a success with primal residual <= 1e-8 and dual residual <= 1e-6", _kkt(1e-8, 1e-6)),
}
"""Tolerance profiles: name -> (what a row must be to count, the test). The residuals are those of
:mod:`refine.bench.quality`; an empty residual (no shared NLP) passes no KKT profile."""


def shifted_geometric_mean(values: list[float], shift: float = SHIFT_S) -> float:
    """``exp(mean(log(v + shift))) - shift``: NaN for no values."""
    v = np.asarray(values, dtype=float)
    if v.size == 0:
        return math.nan
    return float(np.exp(np.mean(np.log(v + shift))) - shift)


def performance_ratios(
    rows: list[Row], key: str = "cpu_s", passes: Callable[[Row], bool] | None = None
) -> dict[str, list[float]]:
    """Dolan-Moré ratios per contender: its time on a problem over the least of any contender's.

    Only a row that ``passes`` (default :func:`solved`; a tolerance profile's test, see
    :data:`PROFILE_TESTS`) has a time; any other, or a problem no contender passed, gives ``inf``.
    One ratio per problem a contender has a row on: a problem it has no row on (one it did not
    pose, whose ``unavailable`` row the report leaves out) is left out of its ratios, so its curve
    is the share of the problems it posed.
    """
    passes = solved if passes is None else passes
    problems = sorted({r["problem"] for r in rows})
    contenders = sorted({r["contender"] for r in rows})
    times = {(r["problem"], r["contender"]): (number(r, key) if passes(r) else math.inf) for r in rows}
    ratios: dict[str, list[float]] = {c: [] for c in contenders}
    for p in problems:
        best = min((times.get((p, c), math.inf) for c in contenders), default=math.inf)
        for c in contenders:
            if (p, c) not in times:
                continue
            t = times[(p, c)]
            ratios[c].append(
                t / best if math.isfinite(t) and best > 0 else (1.0 if t == best == 0 else math.inf)
            )
    return ratios


def profile_curve(ratios: list[float], taus: np.ndarray) -> np.ndarray:
    """ρ(τ): the share of problems with a ratio <= τ, for each τ."""
    r = np.asarray(ratios, dtype=float)
    if r.size == 0:
        return np.zeros_like(taus)
    return np.array([(r <= tau).mean() for tau in taus])


PROFILE_TESTS: dict[str, Callable[[Row], bool]] = {
    "verified": solved,
    **{name: test for name, (_, test) in PROFILES.items() if name != "verified"},
}
"""The rows that count in each tolerance profile's performance profile: for ``verified`` a success or
a detection (the rows the time summaries do not penalise), for a KKT profile its test."""


def plot_profile(
    rows: list[Row], title: str, path: Path, key: str = "cpu_s", profiles: tuple[str, ...] | None = None
) -> list[Path]:
    """Draw the performance profiles of ``rows`` into ``path`` (PNG) and beside it as SVG; the files.

    One panel per tolerance profile of ``profiles`` (default: every one of :data:`PROFILE_TESTS`),
    the ratios of each taken against the best contender *within that profile*.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    names = tuple(PROFILE_TESTS) if profiles is None else profiles
    fig, axes = plt.subplots(len(names), 1, figsize=(8.4, 0.6 + 3.0 * len(names)), squeeze=False)
    styles = ["-", "--", "-.", ":"]
    for ax, name in zip(axes[:, 0], names, strict=True):
        ratios = performance_ratios(rows, key, PROFILE_TESTS[name])
        finite = [x for rs in ratios.values() for x in rs if math.isfinite(x)]
        top = max(2.0, max(finite, default=2.0) * 1.5)
        taus = np.logspace(0.0, math.log10(top), 400)
        for i, (contender, rs) in enumerate(ratios.items()):
            count = sum(map(math.isfinite, rs))
            ax.step(
                taus,
                profile_curve(rs, taus),
                where="post",
                linestyle=styles[(i // 10) % len(styles)] if count else ":",
                linewidth=1.8 if count else 1.0,
                label=f"{contender} ({count}/{len(rs)})",
                color=f"C{i % 10}",
            )
        ax.set_xscale("log", base=2)
        ax.xaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:g}"))
        ax.set_xlim(1.0, top)
        ax.set_ylim(-0.02, 1.02)
        ax.set_ylabel("share of problems within τ")
        ax.set_title(f"{title}: profile {name}", fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(
            fontsize=8,
            loc="upper left",
            bbox_to_anchor=(1.01, 1.0),
            title="counted / problems",
            title_fontsize=8,
        )
    axes[-1, 0].set_xlabel(
        f"τ: {'CPU' if key == 'cpu_s' else 'wall'} time over the best contender's on the problem (in the profile)"
    )
    fig.tight_layout()
    paths = [path.with_suffix(".png"), path.with_suffix(".svg")]
    fig.savefig(paths[0], dpi=110)
    fig.savefig(paths[1])
    plt.close(fig)
    return paths


def growth(n: list[int], t: list[float]) -> dict[str, float | list[float]]:
    """Log-log growth of times ``t`` [s] over sizes ``n``.

    Returns ``exponent`` (least-squares slope of log t on log n), ``low`` and ``high`` (its 95 %
    interval from the slope's standard error, Student's t; NaN below 3 points), and ``local``, the
    slope between each pair of consecutive sizes. NaN exponent below 2 points.
    """
    from scipy import stats

    order = np.argsort(n)
    x = np.log(np.asarray(n, dtype=float)[order])
    y = np.log(np.asarray(t, dtype=float)[order])
    local = [float(v) for v in np.diff(y) / np.diff(x)] if len(x) > 1 else []
    if len(x) < 2 or np.ptp(x) == 0:
        return {"exponent": math.nan, "low": math.nan, "high": math.nan, "local": local}
    fit = stats.linregress(x, y)
    if len(x) < 3:
        return {"exponent": float(fit.slope), "low": math.nan, "high": math.nan, "local": local}
    half = float(stats.t.ppf(0.975, len(x) - 2) * fit.stderr)
    return {"exponent": float(fit.slope), "low": fit.slope - half, "high": fit.slope + half, "local": local}


def plot_growth(rows: list[Row], family: str, path: Path) -> None:
    """Wall and CPU time against waypoints, log-log, one line per contender (successful rows marked)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_wall, ax_cpu) = plt.subplots(1, 2, figsize=(9, 3.6))
    for contender in sorted({r["contender"] for r in rows}):
        rs = sorted((r for r in rows if r["contender"] == contender), key=lambda r: int(r["n_waypoints"]))
        n = [int(r["n_waypoints"]) for r in rs]
        for ax, key in ((ax_wall, "total_s"), (ax_cpu, "cpu_s")):
            (line,) = ax.loglog(n, [number(r, key) for r in rs], "-", label=contender)
            ok = [(k, number(r, key)) for k, r in zip(n, rs, strict=True) if yes(r, "success")]
            bad = [(k, number(r, key)) for k, r in zip(n, rs, strict=True) if not yes(r, "success")]
            if ok:
                ax.plot(*zip(*ok, strict=True), "o", color=line.get_color())
            if bad:
                ax.plot(*zip(*bad, strict=True), "x", color=line.get_color(), markersize=8)
    for ax, title in ((ax_wall, "wall time [s]"), (ax_cpu, "CPU time [s]")):
        ax.set_xlabel("waypoints")
        ax.set_title(f"{family}: {title} (x: not a success)", fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    ax_wall.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
