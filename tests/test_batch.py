"""refine batch: a process pool and a real dask.distributed LocalCluster, failures, resume, summaries."""

import csv
import json
from pathlib import Path

import pytest

from refine.cli import main
from refine.errors import InputError
from refine.run.batch import collect, run_batch
from refine.synthetic import write_line_problem

# a 0.2 m line resampled every 5 mm: 40 segments, 41 waypoints
LINE_M, SPACING_M = 0.2, 0.005
WAYPOINTS = round(LINE_M / SPACING_M) + 1


def make_problems(root: Path, n: int) -> Path:
    folder = root / "problems"
    for k in range(n):
        y0 = -0.1 + 0.03 * k
        write_line_problem(
            folder / f"line_{k:02d}",
            start=(0.6, y0, 0.3),
            end=(0.6, y0 + LINE_M, 0.3),
            tilt_deg=4.0 + 2.0 * k,
            spacing_m=SPACING_M,
        )
    broken = folder / "broken"
    broken.mkdir()
    (broken / "problem.toml").write_text('name = "broken"\n[robot]\nmodel = "no_such_robot"\n')
    return folder


def read_summary(out: Path) -> dict[str, dict[str, str]]:
    with (out / "summary.csv").open() as f:
        return {r["problem"]: r for r in csv.DictReader(f)}


def test_a_local_batch_runs_every_problem_despite_a_failure_and_resumes(tmp_path, capsys):
    problems = make_problems(tmp_path, 2)
    out = tmp_path / "out"
    code = main(["batch", str(problems), "--out", str(out), "--workers", "2", "--no-report", "--no-progress"])
    assert code == 2  # one problem failed
    rows = read_summary(out)
    assert set(rows) == {"broken", "line_00", "line_01"}
    assert rows["broken"]["status"] == "failed" and "missing required table" in rows["broken"]["reason"]
    assert (out / "broken" / "error.txt").is_file()
    for key in ("line_00", "line_01"):
        doc = json.loads((out / key / "result.json").read_text())
        assert rows[key]["status"] == doc["status"] == "ok"
        assert int(rows[key]["n_waypoints"]) == doc["n_waypoints"] == WAYPOINTS
        assert (out / key / f"{key}.script").is_file()  # the UR's program
        assert rows[key]["run"] == "this batch"
    md = (out / "summary.md").read_text()
    assert "3 problems: 2 ok, 1 failed" in md and "| line_01 | ok | 41 |" in md
    assert "# Batch summary" in capsys.readouterr().out

    # resume: the finished problems are skipped (their files untouched), the failed one runs again
    stamp = {k: (out / k / "result.json").stat().st_mtime_ns for k in ("line_00", "line_01")}
    seen = []
    summary = run_batch(
        [problems], out, workers=1, resume=True, report=False, progress=False, on_result=seen.append
    )
    assert [r["problem"] for r in seen] == ["broken"]
    assert summary.skipped == 2
    assert {k: (out / k / "result.json").stat().st_mtime_ns for k in stamp} == stamp
    rows = read_summary(out)
    assert rows["line_00"]["run"] == rows["line_01"]["run"] == "earlier"
    assert rows["line_00"]["status"] == "ok"


@pytest.mark.slow
def test_a_batch_on_a_dask_local_cluster_with_two_workers(tmp_path):
    distributed = pytest.importorskip("distributed")
    problems = make_problems(tmp_path, 3)
    out = tmp_path / "out"
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        summary = run_batch(
            [problems], out, scheduler=cluster.scheduler_address, report=False, progress=False
        )
        assert summary.workers == 2
        with distributed.Client(cluster) as client:
            ran_on = client.run(lambda: "worker alive")
        assert len(ran_on) == 2
    assert summary.exit_status() == 2
    rows = {r["problem"]: r for r in summary.rows}
    assert [r["problem"] for r in summary.rows] == ["broken", "line_00", "line_01", "line_02"]
    assert rows["broken"]["status"] == "failed"
    for key in ("line_00", "line_01", "line_02"):
        doc = json.loads((out / key / "result.json").read_text())
        assert rows[key]["status"] == doc["status"] == "ok"
        assert doc["metrics"]["max_orientation_deviation_deg"] == rows[key]["max_orientation_deviation_deg"]
    assert read_summary(out).keys() == rows.keys()


def test_problems_are_collected_from_folders_and_clashing_names_refused(tmp_path):
    problems = make_problems(tmp_path, 1)
    items = collect([problems], tmp_path / "out")
    assert [i.key for i in items] == ["broken", "line_00"]
    assert items[1].out_dir == tmp_path / "out" / "line_00"
    with pytest.raises(InputError, match="share the folder name 'line_00'"):
        collect([problems / "line_00", problems / "line_00" / "problem.toml"], tmp_path / "out")
    with pytest.raises(InputError, match="no such problem folder"):
        collect([tmp_path / "nowhere"], tmp_path / "out")
    assert main(["batch", str(tmp_path / "nowhere"), "--out", str(tmp_path / "o")]) == 2


def test_a_problem_s_result_json_is_computed_once_and_holds_the_run_s_wall_time(tmp_path, monkeypatch):
    """The run's wall time is added to the written result.json without computing it again: the
    files are hashed once, and the document still lists them with their true size and SHA-256."""
    import hashlib

    import refine.export.result_json as result_json
    from refine.run.batch import run_one

    problems = make_problems(tmp_path, 1)
    hashed = []
    describe = result_json.describe_files
    monkeypatch.setattr(result_json, "describe_files", lambda outputs: hashed.append(1) or describe(outputs))
    out = tmp_path / "out" / "line_00"
    row = run_one("line_00", str(problems / "line_00"), str(out), None, False)
    with open(out / "result.json", encoding="utf-8") as f:
        doc = json.load(f)
    assert len(hashed) == 1
    assert row["status"] == doc["status"] == "ok" and row["n_waypoints"] == doc["n_waypoints"] == WAYPOINTS
    assert row["min_clearance_m"] == doc["metrics"]["min_clearance_m"]
    assert list(doc["timings_s"])[-1] == "run" and doc["timings_s"]["run"] == round(row["wall_s"], 6)
    assert doc["timings_s"]["run"] >= sum(v for k, v in doc["timings_s"].items() if k != "run") - 1e-3
    assert set(doc["files"]) == {p.name for p in out.iterdir()} - {"result.json"}
    for name, entry in doc["files"].items():
        data = (out / name).read_bytes()
        assert entry == {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}
