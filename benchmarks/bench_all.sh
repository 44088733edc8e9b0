#!/bin/sh
# Every suite of benchmarks/suites.toml with every contender, then the report from the CSV alone.
#   sh benchmarks/bench_all.sh [REPEAT]      (results in out/bench/)
set -e
cd "$(dirname "$0")/.."
refine bench run --suite bundled --suite unreachable --suite scaling --repeat "${1:-1}" --csv out/bench/bench.csv
refine bench report out/bench/bench.csv --out out/bench
