"""A contender that cannot pose one problem: its row there says so, its other rows stand, and the
report leaves the row out of every table and average."""

from __future__ import annotations

import csv

import pytest

from refine.bench import contenders as contenders_module
from refine.bench.contenders import NotPosed
from refine.bench.report import write_report
from refine.bench.runner import run_suites

REASON = "the fake does not pose a path of 20 waypoints"


def greedy_unless_twenty(problem):
    """Greedy IK, except on the 20-waypoint path, which it does not pose."""
    if problem.n_waypoints == 20:
        raise NotPosed(REASON)
    return contenders_module.greedy_ik(problem)


@pytest.mark.parametrize("isolate", [True, False])
def test_a_contender_that_does_not_pose_a_problem_leaves_an_unavailable_row_there_only(
    tmp_path, monkeypatch, tiny_wave_with, isolate
):
    suites = tmp_path / "suites.toml"
    suites.write_text(tiny_wave_with(["wave"], [20, 24, 28]))
    monkeypatch.setitem(contenders_module.CONTENDERS, "drake-ik", greedy_unless_twenty)
    messages: list[str] = []
    out = tmp_path / "bench.csv"
    rows = run_suites(
        ["tiny"], ["greedy-ik", "drake-ik"], out, suites_file=suites, repeat=2, warmup=1,
        echo=messages.append, isolate=isolate,
    )  # fmt: skip
    by = {(r["contender"], r["n_waypoints"]): r for r in rows}
    assert len(rows) == 6
    row = by[("drake-ik", 20)]
    assert row["status"] == "unavailable" and row["note"] == f"not posed: {REASON}"
    assert not row["success"] and row["repeats"] == 0
    # it is not dropped from the run: the problems after it have its answers
    for n in (24, 28):
        assert by[("drake-ik", n)]["status"] == "ok" and by[("drake-ik", n)]["success"]
        assert by[("drake-ik", n)]["repeats"] == 2
    assert any(f"drake-ik does not pose wave-20: {REASON}" in m for m in messages)
    assert not any("skipping drake-ik" in m for m in messages)
    with out.open() as f:
        table = list(csv.DictReader(f))
    assert [r["status"] for r in table if r["contender"] == "drake-ik"] == ["unavailable", "ok", "ok"]

    text = write_report(out, tmp_path / "report").read_text()
    assert f"- not posed: drake-ik on tiny/wave-20, {REASON}" in text
    assert "- not run here: drake-ik" not in text
    # its success table counts the two problems it posed, not three: the row enters no average
    assert "| tiny | drake-ik | 2 | 2/2 |" in text and "| tiny | greedy-ik | 3 | 3/3 |" in text


def _row(problem: str, contender: str, cpu: float, status: str = "ok", note: str = "") -> dict:
    from refine.bench.table import COLUMNS, SCHEMA_VERSION

    posed = status != "unavailable"
    row = dict.fromkeys(COLUMNS, "")
    row.update(
        schema=SCHEMA_VERSION, run_id="20260101T000000Z-aaaaaa", suite="s", problem=problem,
        robot="abb_irb4600_60_205", n_waypoints="50", obstacles="False", expected="", contender=contender,
        status=status, verified=str(posed), success=str(posed), detected_infeasible="False",
        timed_out="False", time_limit_s="300", total_s=str(cpu) if posed else "", cpu_s=str(cpu) if posed else "",
        min_total_s=str(cpu), max_total_s=str(cpu), penalised_total_s=str(cpu if posed else 300.0),
        penalised_cpu_s=str(cpu if posed else 300.0), repeats="1" if posed else "0", note=note,
        date="20260101", machine="m", max_orientation_deviation_deg="1.0",
    )  # fmt: skip
    return row


def test_a_ratio_compares_a_contender_with_the_others_on_the_problems_it_posed(tmp_path, write_rows):
    from refine.bench.figures import performance_ratios

    rows = [
        _row("p1", "refine", 1.0),
        _row("p2", "refine", 4.0),
        _row("p1", "peer", 0.0, "unavailable", "not posed: the peer does not pose p1"),
        _row("p2", "peer", 8.0),
    ]
    path = write_rows(tmp_path / "bench.csv", rows)
    text = write_report(path, tmp_path / "report").read_text()
    assert "- not posed: peer on s/p1, the peer does not pose p1" in text
    # shifted geometric means (shift 0.1 s) by hand: refine's of 1 s and 4 s is
    # sqrt(1.1 * 4.1) - 0.1 = 2.024 s, the peer's of its one problem 8.000 s. The peer's ratio is
    # taken against refine on p2 alone (4 s): 2.00, not against refine's mean over p1 and p2
    # (3.95); no contender but refine posed both, so refine's is 1.00
    assert "| s | peer | 1 | 8.000 | 2.00 |" in text
    assert "| s | refine | 2 | 2.024 | 1.00 |" in text
    assert "| s | peer | 1 | 1/1 |" in text
    # the performance profile: the peer has a ratio on p2 only (8 s against refine's 4 s there)
    ratios = performance_ratios([r for r in rows if r["status"] != "unavailable"])
    assert ratios == {"peer": [2.0], "refine": [1.0, 1.0]}
