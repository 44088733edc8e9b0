"""A batch of generated problems on a Dask LocalCluster: wall time with 1 and 2 workers, and resume.

Generates ``--n`` small problems (a UR10e following a 0.2 m straight bead, 41 waypoints, each with
its own position and tool tilt; :func:`refine.synthetic.write_line_problem`), then:

1. runs them all on a ``dask.distributed.LocalCluster`` with 1 worker, then with 2 workers
   (one thread each, worker processes started and refine imported in them before the clock
   starts), and prints the wall times;
2. interrupts a fresh 2-worker batch after ``--stop-after`` problems have finished (as Ctrl-C
   would) and resumes it with ``resume=True``, printing how many were skipped and run.

    python3 benchmarks/batch_sweep.py [--n 50] [--stop-after 20] [--dir /tmp/refine-batch]
"""

from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path

from distributed import Client, LocalCluster

from refine.run.batch import run_batch
from refine.synthetic import write_line_problem


def generate(folder: Path, n: int) -> Path:
    for k in range(n):
        y0 = -0.25 + 0.3 * (k % 10) / 9  # 10 positions across the table
        tilt = 2.0 + 2.0 * (k // 10)  # 2, 4, ... deg at the end of the line
        write_line_problem(
            folder / f"line_{k:03d}", start=(0.6, y0, 0.3), end=(0.6, y0 + 0.2, 0.3), tilt_deg=tilt
        )
    return folder


def _warm_up() -> None:
    import refine.export.result_json  # noqa: F401
    import refine.report.html  # noqa: F401
    import refine.run.stages  # noqa: F401


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=50)
    parser.add_argument("--stop-after", type=int, default=20)
    parser.add_argument("--dir", type=Path, default=Path("/tmp/refine-batch"))
    args = parser.parse_args()
    shutil.rmtree(args.dir, ignore_errors=True)
    problems = generate(args.dir / "problems", args.n)
    print(f"{args.n} problems generated in {problems}")
    for workers in (1, 2):
        with LocalCluster(n_workers=workers, threads_per_worker=1, dashboard_address=None) as cluster:
            with Client(cluster) as client:  # imports paid before the clock starts, in every worker
                client.run(_warm_up)
            out = args.dir / f"out_{workers}"
            summary = run_batch(
                [problems], out, scheduler=cluster.scheduler_address, report=False, progress=False
            )
            statuses = [r["status"] for r in summary.rows]
            print(
                f"{workers} worker(s): {len(summary.rows)} problems in {summary.wall_s:.1f} s wall "
                f"({statuses.count('ok')} ok, {statuses.count('repaired')} repaired, "
                f"{statuses.count('infeasible')} infeasible, {statuses.count('failed')} failed); "
                f"summary in {out / 'summary.md'}"
            )

    out = args.dir / "out_resume"
    with LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None) as cluster:
        done = []

        def stop(row: dict) -> None:
            done.append(row["problem"])
            if len(done) >= args.stop_after:
                raise KeyboardInterrupt  # what Ctrl-C does to the batch

        first = run_batch(
            [problems], out, scheduler=cluster.scheduler_address, report=False, progress=False, on_result=stop
        )
        with Client(cluster) as client:  # let tasks already running finish, as a real cluster would
            while client.processing() and any(client.processing().values()):
                time.sleep(0.2)
        finished = sum((out / f"line_{k:03d}" / "result.json").is_file() for k in range(args.n))
        print(
            f"interrupted after {len(done)} results in {first.wall_s:.1f} s "
            f"(interrupted={first.interrupted}, exit {first.exit_status()}); {finished} result.json on disk"
        )
        ran = []
        again = run_batch(
            [problems],
            out,
            scheduler=cluster.scheduler_address,
            resume=True,
            report=False,
            progress=False,
            on_result=lambda r: ran.append(r["problem"]),
        )
    statuses = [r["status"] for r in again.rows]
    print(
        f"resumed: {again.skipped} skipped as finished, {len(ran)} run in {again.wall_s:.1f} s; "
        f"{len(again.rows)} problems in the summary ({statuses.count('ok')} ok), exit {again.exit_status()}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
