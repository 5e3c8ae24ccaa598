#!/usr/bin/env bash
# The paper's Table 4 on our data: 5 conditionings x 2 splits, each trained as its own process and evaluated
# against DEM, then the table. JOBS bounds how many run at once (default: all 10, for a GPU machine with
# many cores; on a 2-core CPU use JOBS=2, which also pins each run to one thread).
#   [JOBS=N] bash scripts/hopper_ablation.sh GRID_DIR [hydra overrides for every run...]
# e.g. GPU:  bash scripts/hopper_ablation.sh /data/grid trainer=gpu logger=csv trainer.max_steps=3000
#      CPU:  JOBS=2 bash scripts/hopper_ablation.sh /data/grid model=hopper_base trainer=cpu logger=csv ...
# Runs land in GRID_DIR/<experiment>-<split>/ (logs beside them); the table in GRID_DIR/table4.md (+ .json).
# A run whose folder already holds evaluation/metrics.json is skipped, so a killed grid resumes.
# Cross-validation: FOLDS="0 1 2 3 4" trains every fold (data.datamodule.fold=k, runs in
# GRID_DIR/<experiment>-<split>-f<k>/) and the table is the cross-validated one of `neuraldem report hopper-cv`
# (constant, Gaussian process and field model on the same held-out runs; SEED_FLOOR=FILE adds the LIGGGHTS
# seed-floor row). NEURALDEM_DATASET overrides the dataset dir the table reads (default: hopper_small).
set -uo pipefail
PY=${PYTHON:-python}
JOBS=${JOBS:-10}
SPLITS=${SPLITS:-"random band"}
EXPERIMENTS=${EXPERIMENTS:-"hopper_micro hopper_theta hopper_ffc hopper_macro hopper_all"}
FOLDS=${FOLDS:-}
grid=$1; shift
mkdir -p "$grid"
if [ "$JOBS" -lt 10 ]; then export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}; fi
export OMP_WAIT_POLICY=${OMP_WAIT_POLICY:-PASSIVE}
failed=0
running=0
for split in $SPLITS; do
  for exp in $EXPERIMENTS; do
    for fold in ${FOLDS:-none}; do
      name="$exp-$split"; extra=()
      if [ "$fold" != none ]; then name="$name-f$fold"; extra=(data.datamodule.fold="$fold"); fi
      run="$grid/$name"
      if [ -f "$run/evaluation/metrics.json" ]; then echo "skip $name (evaluated)"; continue; fi
      if [ "$running" -ge "$JOBS" ]; then wait -n || failed=$((failed + 1)); running=$((running - 1)); fi
      echo "start $name"
      rm -rf "$run"
      "$PY" -m neuraldem train experiment="$exp" data.split="$split" hydra.run.dir="$run" \
        callbacks.progress=null "${extra[@]}" "$@" > "$grid/$name.log" 2>&1 &
      running=$((running + 1))
    done
  done
done
while [ "$running" -gt 0 ]; do wait -n || failed=$((failed + 1)); running=$((running - 1)); done
[ "$failed" -eq 0 ] || echo "hopper_ablation: $failed run(s) failed; see $grid/*.log" >&2
if [ -n "${NEURALDEM_NO_TABLE:-}" ]; then
  :  # the caller makes the table (scripts/hopper_options.sh)
elif [ -n "$FOLDS" ]; then
  dataset=${NEURALDEM_DATASET:-$("$PY" -c 'from neuraldem.paths import data_dir; print(data_dir() / "datasets" / "hopper_small")')}
  nsims=$(printf '%s\n' "$@" | sed -n 's/^data.datamodule.n_sims=//p' | tail -1)
  as_list() { local IFS=,; echo "[$*]"; }  # words as one key=value list: [a,b]
  # shellcheck disable=SC2086
  "$PY" -m neuraldem report hopper-cv grids="$grid" dataset="$dataset" splits="$(as_list $SPLITS)" \
    folds="$(as_list $FOLDS)" ${nsims:+n_sims="$nsims"} ${SEED_FLOOR:+seed_floor="$SEED_FLOOR"} \
    out="$grid/table4_cv.md"
else
  "$PY" -m neuraldem report hopper-table folders="$grid" out="$grid/table4.md"
fi
exit "$failed"
