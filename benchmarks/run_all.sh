#!/bin/sh
# Final figures for benchmarks/NOTES.md: the benchmark, then the 10^6-trajectory sweep.
# Run from the repository root:  nohup sh benchmarks/run_all.sh > /tmp/bench_all.log 2>&1 &
set -x
uptime
python -m stabjax.bench --sizes 256,4096,65536 --t1 1e4 --out results/bench.json
uptime
/usr/bin/time -v python -m stabjax sweep benchmarks/sweep_1e6.toml --out /tmp/sweep_1e6.nc --no-plot --restart
uptime
