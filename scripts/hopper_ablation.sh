#!/usr/bin/env bash
# The paper's Table 4 on our data: 5 conditionings x 2 splits trained as parallel processes (one per
# experiment; meant for a machine with a GPU and many cores), each evaluated against DEM, then the table.
#   bash scripts/hopper_ablation.sh GRID_DIR [hydra overrides for every run...]
# e.g. bash scripts/hopper_ablation.sh /data/grid trainer=gpu logger=csv trainer.max_steps=3000
# Runs land in GRID_DIR/<experiment>-<split>/ (logs beside them); the table in GRID_DIR/table4.md (+ .json).
# On a CPU-only machine use the sequential sweep instead (README): python -m neuraldem.train -m ...
set -uo pipefail
PY=${PYTHON:-python}
grid=$1; shift
mkdir -p "$grid"
pids=()
for exp in hopper_micro hopper_theta hopper_ffc hopper_macro hopper_all; do
  for split in random band; do
    "$PY" -m neuraldem.train experiment="$exp" data.split="$split" hydra.run.dir="$grid/$exp-$split" \
      callbacks.progress=null "$@" > "$grid/$exp-$split.log" 2>&1 &
    pids+=($!)
  done
done
failed=0
for pid in "${pids[@]}"; do wait "$pid" || failed=$((failed + 1)); done
[ "$failed" -eq 0 ] || echo "hopper_ablation: $failed run(s) failed; see $grid/*.log" >&2
"$PY" -m neuraldem.eval.collect_hopper_table "$grid" --out "$grid/table4.md"
exit "$failed"
