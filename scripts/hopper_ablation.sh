#!/usr/bin/env bash
# The paper's Table 4 on our data: 5 conditionings x 2 splits, each trained as its own process and evaluated
# against DEM, then the table. JOBS bounds how many run at once (default: all 10, for a GPU machine with
# many cores; on a 2-core CPU use JOBS=2, which also pins each run to one thread).
#   [JOBS=N] bash scripts/hopper_ablation.sh GRID_DIR [hydra overrides for every run...]
# e.g. GPU:  bash scripts/hopper_ablation.sh /data/grid trainer=gpu logger=csv trainer.max_steps=3000
#      CPU:  JOBS=2 bash scripts/hopper_ablation.sh /data/grid model=hopper_base trainer=cpu logger=csv ...
# Runs land in GRID_DIR/<experiment>-<split>/ (logs beside them); the table in GRID_DIR/table4.md (+ .json).
# A run whose folder already holds evaluation/metrics.json is skipped, so a killed grid resumes.
set -uo pipefail
PY=${PYTHON:-python}
JOBS=${JOBS:-10}
SPLITS=${SPLITS:-"random band"}
EXPERIMENTS=${EXPERIMENTS:-"hopper_micro hopper_theta hopper_ffc hopper_macro hopper_all"}
grid=$1; shift
mkdir -p "$grid"
if [ "$JOBS" -lt 10 ]; then export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}; fi
export OMP_WAIT_POLICY=${OMP_WAIT_POLICY:-PASSIVE}
failed=0
running=0
for split in $SPLITS; do
  for exp in $EXPERIMENTS; do
    run="$grid/$exp-$split"
    if [ -f "$run/evaluation/metrics.json" ]; then echo "skip $exp-$split (evaluated)"; continue; fi
    if [ "$running" -ge "$JOBS" ]; then wait -n || failed=$((failed + 1)); running=$((running - 1)); fi
    echo "start $exp-$split"
    rm -rf "$run"
    "$PY" -m neuraldem.train experiment="$exp" data.split="$split" hydra.run.dir="$run" \
      callbacks.progress=null "$@" > "$grid/$exp-$split.log" 2>&1 &
    running=$((running + 1))
  done
done
while [ "$running" -gt 0 ]; do wait -n || failed=$((failed + 1)); running=$((running - 1)); done
[ "$failed" -eq 0 ] || echo "hopper_ablation: $failed run(s) failed; see $grid/*.log" >&2
"$PY" -m neuraldem.eval.collect_hopper_table "$grid" --out "$grid/table4.md"
exit "$failed"
