"""``refine bench``: named benchmark suites, contenders run in one process, a CSV and its report.

* :mod:`refine.bench.suites`: the suites, read from ``benchmarks/suites.toml`` (data);
* :mod:`refine.bench.contenders`: refine (each derivative mode), greedy IK, Drake's chained IK, and
  the verification every answer goes through;
* :mod:`refine.bench.outcomes`: what counts as a success, a detected infeasibility, the time penalty;
* :mod:`refine.bench.table`: the CSV's columns and schema version, run ids, the header check;
* :mod:`refine.bench.runner`: one CSV row per problem and contender;
* :mod:`refine.bench.report`: Markdown with tables and log-log plots from one run of the CSV;
* :mod:`refine.bench.cli`: the ``refine bench run | list | report`` command.
"""
