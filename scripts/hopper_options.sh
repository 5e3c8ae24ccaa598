#!/usr/bin/env bash
# Training options of the hopper field model, chosen by measurement (results/hopper/options/): each variant trains
# experiment=hopper_micro on the same cross-validation fold(s) of hopper_small and is evaluated; the table puts
# them beside the constant and the Gaussian process on the same held-out runs. Options are chosen by the
# validation score (val/practitioner_score of the kept checkpoint), never by the test runs.
#   [JOBS=2] [FOLDS="0"] [VARIANTS="..."] bash scripts/hopper_options.sh STUDY_DIR [overrides for every run...]
# e.g. JOBS=2 FOLDS="0 1" bash scripts/hopper_options.sh $NEURALDEM_DATA/hopper_options data.datamodule.n_sims=60
# Each variant lands in STUDY_DIR/<variant>/ (resumable: evaluated runs are skipped); the table in
# STUDY_DIR/options.md (+ .json).
set -uo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python}
export JOBS=${JOBS:-2} FOLDS=${FOLDS:-0} SPLITS=random EXPERIMENTS=hopper_micro
study=$1; shift
declare -A OPTS=(
  [embed1000]="model.net.time_coord_scale=1000 model.net.scalar_coord_scale=1000"
  [embed_s10]="model.net.time_coord_scale=1000 model.net.scalar_coord_scale=10"
  [embed_t100_s10]="model.net.time_coord_scale=100 model.net.scalar_coord_scale=10"
  [embed_t30_s3]="model.net.time_coord_scale=30 model.net.scalar_coord_scale=3"
  [adamw]="model.net.scalar_coord_scale=10 model.optimizer.name=adamw"
  [ema]="model.net.scalar_coord_scale=10 +callbacks.ema._target_=lightning.pytorch.callbacks.EMAWeightAveraging +callbacks.ema.decay=0.99"
  [uniform_time]="model.net.scalar_coord_scale=10 data.datamodule.tail_share=0.67"
)
VARIANTS=${VARIANTS:-"embed1000 embed_s10 embed_t100_s10 adamw ema uniform_time"}
mkdir -p "$study"
for v in $VARIANTS; do
  [ -n "${OPTS[$v]+x}" ] || { echo "hopper_options: unknown variant $v (known: ${!OPTS[*]})" >&2; exit 2; }
done
# JOBS variants at a time, each training its folds one after another
running=0
for v in $VARIANTS; do
  if [ "$running" -ge "$JOBS" ]; then wait -n; running=$((running - 1)); fi
  # shellcheck disable=SC2086
  JOBS=1 NEURALDEM_NO_TABLE=1 bash scripts/hopper_ablation.sh "$study/$v" ${OPTS[$v]} "$@" > "$study/$v.log" 2>&1 &
  running=$((running + 1))
done
wait
dataset=${NEURALDEM_DATASET:-$("$PY" -c 'from neuraldem.paths import data_dir; print(data_dir() / "datasets" / "hopper_small")')}
grids=()
for v in $VARIANTS; do grids+=("$study/$v"); done
nsims=$(printf '%s\n' "$@" | sed -n 's/^data.datamodule.n_sims=//p' | tail -1)
as_list() { local IFS=,; echo "[$*]"; }  # words as one key=value list: [a,b]
# shellcheck disable=SC2086
"$PY" -m neuraldem report hopper-cv grids="$(as_list "${grids[@]}")" dataset="$dataset" splits=random \
  folds="$(as_list $FOLDS)" ${nsims:+n_sims="$nsims"} out="$study/options.md"
