#!/usr/bin/env bash
# The fluidized-bed surrogate and its stability options, measured rather than assumed: one `fb` training run
# per variant (each its own process, then rollouts of 10x the training horizon for every held-out velocity,
# scored against CFD-DEM), then the side-by-side table. JOBS bounds how many run at once (default 2, one
# thread each on a 2-core CPU).
#   [JOBS=N] [VARIANTS="base noise pf noise_pf"] bash scripts/fb_ablation.sh RUNS_DIR [hydra overrides...]
# e.g. JOBS=2 VARIANTS="base noise_pf" bash scripts/fb_ablation.sh $NEURALDEM_DATA/fb_ablation \
#        trainer=cpu logger=csv trainer.max_steps=3000 trainer.val_check_interval=500
# Variants: base (no noise, k = 1), noise (input_noise 0.01), pf (push_forward_steps 2), noise_pf (both),
# grid_only (noise_pf without the particle branch: the fluid grid is the only main branch), residual (noise_pf,
# the grid branches predict the scaled change per step), grid_residual (both).
# A variant may name a model config: "fb_base/noise_pf" trains model=fb_base (sizes side by side for
# right-sizing: VARIANTS="fb_tiny/noise_pf fb_base/noise_pf fb_small/noise_pf").
# Runs land in RUNS_DIR/<variant>/ (logs beside them), the table in RUNS_DIR/table.md (+ .json). A run whose
# folder already holds evaluation/metrics.json is skipped, so a killed sweep resumes.
set -uo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
PY=${PYTHON:-python}
JOBS=${JOBS:-2}
VARIANTS=${VARIANTS:-"base noise pf noise_pf"}
runs=$1; shift
mkdir -p "$runs"
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}
export OMP_WAIT_POLICY=${OMP_WAIT_POLICY:-PASSIVE}
overrides() {
  case "$1" in
    */*) local model=${1%%/*} rest
         [ -f "$ROOT/conf/model/$model.yaml" ] || { echo "fb_ablation: unknown model '$model' (no conf/model/$model.yaml)" >&2; return 2; }
         rest=$(overrides "${1#*/}") || return 2
         echo "model=$model $rest" ;;
    base) echo "data.datamodule.input_noise=0.0 data.datamodule.push_forward_steps=1" ;;
    noise) echo "data.datamodule.input_noise=0.01 data.datamodule.push_forward_steps=1" ;;
    pf) echo "data.datamodule.input_noise=0.0 data.datamodule.push_forward_steps=2" ;;
    noise_pf) echo "data.datamodule.input_noise=0.01 data.datamodule.push_forward_steps=2" ;;
    grid_only) echo "data.datamodule.input_noise=0.01 data.datamodule.push_forward_steps=2 model.net.particle_branch=false" ;;
    residual) echo "data.datamodule.input_noise=0.01 data.datamodule.push_forward_steps=2 model.residual=true" ;;
    grid_residual) echo "data.datamodule.input_noise=0.01 data.datamodule.push_forward_steps=2 model.residual=true model.net.particle_branch=false" ;;
    *) echo "fb_ablation: unknown variant '$1' (known: base noise pf noise_pf grid_only residual grid_residual)" >&2; return 2 ;;
  esac
}
for v in $VARIANTS; do overrides "$v" > /dev/null || exit 2; done
failed=0
running=0
for v in $VARIANTS; do
  run="$runs/$v"
  if [ -f "$run/evaluation/metrics.json" ]; then echo "skip $v (evaluated)"; continue; fi
  if [ "$running" -ge "$JOBS" ]; then wait -n || failed=$((failed + 1)); running=$((running - 1)); fi
  echo "start $v"
  rm -rf "$run"
  mkdir -p "$(dirname "$run")"
  # shellcheck disable=SC2046
  "$PY" -m neuraldem.train experiment=fb $(overrides "$v") hydra.run.dir="$run" callbacks.progress=null "$@" \
    > "$run.log" 2>&1 &
  running=$((running + 1))
done
while [ "$running" -gt 0 ]; do wait -n || failed=$((failed + 1)); running=$((running - 1)); done
[ "$failed" -eq 0 ] || echo "fb_ablation: $failed run(s) failed; see $runs/*.log" >&2
"$PY" -m neuraldem.eval.collect_fb_table "$runs" --out "$runs/table.md"
exit "$failed"
