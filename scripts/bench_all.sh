#!/usr/bin/env bash
# Every benchmark chart and table (docs/benchmarks.md), with the thread settings the numbers are quoted at:
# torch, LIGGGHTS and DPMFoam on one thread each (fb_speed also times the rollout on every core), passive
# OpenMP waiting. Run it on a quiet machine.
#   bash scripts/bench_all.sh runs=GRID_DIR ckpt=GRID_DIR/hopper_micro-random/checkpoints/last.ckpt [...]
#   ... fb_ckpt=[FB_RUN/checkpoints/last.ckpt,FB_ABLATION/checkpoints/last.ckpt]   (the fluidized bed)
# The arguments go to `neuraldem bench all` (e.g. no_solver=true repeats=5 out_dir=DIR); without out_dir each
# file goes to the results/ folder of its question (results/README.md).
set -euo pipefail
PY=${PYTHON:-python}
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 OMP_WAIT_POLICY=PASSIVE WANDB_MODE=offline
load=$(cut -d' ' -f1 /proc/loadavg 2>/dev/null || echo 0)
echo "1-minute load average before the benchmarks: $load (should be near 0)"
"$PY" -m neuraldem bench all "$@"
echo "redraw the charts and tables without measuring: neuraldem bench render [out_dir=DIR]"
