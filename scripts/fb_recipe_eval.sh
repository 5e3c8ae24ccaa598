#!/usr/bin/env bash
# A bed recipe's whole evaluation in one resumable command, for its seeds: train each seed (experiment=fb, every
# validated checkpoint kept), choose each net's checkpoint on validation (3-s validation velocities + the 30-s
# long validation trajectory of fb_small_longval) under the rollout options it is used with, score the chosen
# one once on the test part (the 30-s test trajectories included), then the baselines, the tables, the stability
# map and the speed ratio against DPMFoam. Nothing here chooses anything on test runs.
#   [SEEDS="0 1"] [BASE=full] [OPTIONS=rollout.rollout_noise=3+rollout.advection_correction=1+...] [SELECT_FROM=4500] \
#     [LONG_VAL=DIR] [FINE_STEP=0.005] bash scripts/fb_recipe_eval.sh RUNS_DIR [train overrides...]
# e.g. bash scripts/fb_recipe_eval.sh $NEURALDEM_DATA/fb_recipe trainer=cpu logger=csv
# BASE is the trained variant of scripts/fb_ablation.sh (full = experiment=fb; cond10 = the velocity embedding at
# scale 10, which experiment=fb has). OPTIONS are the rollout options the nets are chosen, scored, mapped and timed
# with, as every command takes them (rollout.<option>=VALUE, conf/rollout/), joined by + (default: rollout noise 3,
# advection correction 1, mirror-alternating steps). The stability map is drawn twice: RUNS_DIR/fb_stability.json
# (7 velocities from 0.8x to 1.2x the trained range, 3000 steps) and RUNS_DIR/fb_stability_fine.json (every
# FINE_STEP m/s across the trained range, 500 steps, bed height against CFD-DEM's: a net with the velocity embedded
# at scale 1000 collapsed 0.002 m/s away from a training velocity, results/fluidized_bed/options/
# velocity_embedding_scale1000_scan.png).
# Needs the data first (resumable, background, one job per core):
#   neuraldem datagen data=fb_small workers=2; neuraldem datagen data=fb_small_longval
# Layout: RUNS_DIR/seedS/ (scripts/fb_ablation.sh runs: full = the net and its checkpoint kept by the training's own
# rollout validation, full+OPTIONS+sel = the one fb-select chose, in fb_ablation.sh's folder for it (OPTIONS without
# "rollout." and with - for =, e.g. full+rollout_noise-3+advection_correction-1+mirror_alternate-true+sel), each
# scored on val and test; their tables),
# RUNS_DIR/baselines/ and RUNS_DIR/baselines-val/ (constant / nearest / interpolated CFD-DEM, another packing),
# RUNS_DIR/table.md (test), RUNS_DIR/table-val.md, RUNS_DIR/fb_stability{,_fine}.json (+ .png), RUNS_DIR/fb_speed.json.
# Cost on a 2-core Xeon: ~50 min training (seeds in parallel), ~35 min selection per seed (15 checkpoints x 2
# rollout seeds), ~10 min test per seed, ~15 min stability map, ~25 min fine map, ~5 min speed. Killed, it resumes.
set -uo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
PY=${PYTHON:-python}
SEEDS=${SEEDS:-"0 1"}
OPTIONS=${OPTIONS:-rollout.rollout_noise=3+rollout.advection_correction=1+rollout.mirror_alternate=true}
DATA=${NEURALDEM_DATA:-$HOME/.local/share/neuraldem}
LONG_VAL=${LONG_VAL-$DATA/datasets/fb_small_longval}
[ $# -ge 1 ] || { echo "usage: bash scripts/fb_recipe_eval.sh RUNS_DIR [train overrides...]" >&2; exit 2; }
runs=$1; shift
if [ -n "$LONG_VAL" ] && [ ! -f "$LONG_VAL/manifest.json" ]; then
  echo "fb_recipe_eval: no long validation set at $LONG_VAL: generate it (neuraldem datagen" \
       "data=fb_small_longval) or set LONG_VAL= to choose on the 3-s validation part alone" >&2
  exit 2
fi
BASE=${BASE:-full}
case "$BASE" in *+*|*/*|"") echo "fb_recipe_eval: BASE=$BASE: give one trained variant of scripts/fb_ablation.sh (full, cond10, ...)" >&2; exit 2 ;; esac
chosen="$BASE+$OPTIONS+sel"  # the variant each seed's chosen checkpoint is scored as (scripts/fb_ablation.sh)
CHECK=1 VARIANTS="$BASE $chosen" bash "$ROOT/scripts/fb_ablation.sh" "$runs" || { echo "fb_recipe_eval: OPTIONS=$OPTIONS" >&2; exit 2; }
chosen_dir=${chosen//rollout./}; chosen_dir=${chosen_dir//=/-}  # its folder, as scripts/fb_ablation.sh names it
options=${OPTIONS//+/ }  # what fb-select and fb_stability are given
speed_options=""  # fb_speed times the net's steps: of the rollout options it takes those that change a step's cost
for o in $options; do
  case "$o" in rollout.rollout_noise=*|rollout.mirror_alternate=*) speed_options="$speed_options $o" ;; esac
done
mkdir -p "$runs"
failed=0
pids=()
for S in $SEEDS; do  # one process per seed: the seeds train side by side, one core each
  JOBS=1 VAL=1 TEST=1 VARIANTS="$BASE $chosen" SELECT_FROM="${SELECT_FROM:-4500}" SELECT_SEEDS="0 1" \
    LONG_VAL="$LONG_VAL" PYTHON="$PY" bash "$ROOT/scripts/fb_ablation.sh" "$runs/seed$S" seed="$S" "$@" \
    > "$runs/seed$S.log" 2>&1 &
  pids+=($!)
done
for p in "${pids[@]}"; do wait "$p" || failed=$((failed + 1)); done
[ -f "$runs/baselines/baseline_constant/evaluation/metrics.json" ] \
  || "$PY" -m neuraldem.scenes.fluidized_bed.analysis.baselines fb_small --part test --out "$runs/baselines" || failed=$((failed + 1))
[ -f "$runs/baselines-val/baseline_constant/evaluation/metrics.json" ] \
  || "$PY" -m neuraldem.scenes.fluidized_bed.analysis.baselines fb_small --part val --out "$runs/baselines-val" || failed=$((failed + 1))
tests=() vals=() ckpts=() labels=()
for S in $SEEDS; do
  tests+=("$runs/seed$S"); vals+=("$runs/seed$S-val")
  ckpts+=("$runs/seed$S/$chosen_dir/selected.ckpt"); labels+=("seed$S")
done
"$PY" -m neuraldem.scenes.fluidized_bed.analysis.table "${tests[@]}" "$runs/baselines" --out "$runs/table.md" || failed=$((failed + 1))
"$PY" -m neuraldem.scenes.fluidized_bed.analysis.table "${vals[@]}" "$runs/baselines-val" --out "$runs/table-val.md" \
  || failed=$((failed + 1))
# shellcheck disable=SC2086
[ -f "$runs/fb_stability.json" ] || "$PY" -m neuraldem.bench fb_stability --ckpt "${ckpts[@]}" --labels "${labels[@]}" \
  $options --n-velocities 5 --steps 3000 --out "$runs/fb_stability.json" || failed=$((failed + 1))
# shellcheck disable=SC2086
[ -f "$runs/fb_stability_fine.json" ] || "$PY" -m neuraldem.bench fb_stability --ckpt "${ckpts[@]}" \
  --labels "${labels[@]}" $options --velocity-step "${FINE_STEP:-0.005}" --steps 500 \
  --out "$runs/fb_stability_fine.json" || failed=$((failed + 1))
# shellcheck disable=SC2086
[ -f "$runs/fb_speed.json" ] || "$PY" -m neuraldem.bench fb_speed --ckpt "${ckpts[0]}" --reuse-dataset --threads 1 \
  --repeats 5 $speed_options --out "$runs/fb_speed.json" || failed=$((failed + 1))
[ "$failed" -eq 0 ] || echo "fb_recipe_eval: $failed step(s) failed; see $runs/seed*.log and $runs/seed*/*.log" >&2
exit "$failed"
