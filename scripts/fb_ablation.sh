#!/usr/bin/env bash
# The fluidized-bed surrogate and its stability options, measured rather than assumed: one `fb` training run
# per variant (each its own process, then rollouts of 10x the training horizon for every held-out velocity,
# scored against CFD-DEM), then the side-by-side table. JOBS bounds how many run at once (default 2, one
# thread each on a 2-core CPU).
#   [JOBS=N] [VARIANTS="full no_unroll"] bash scripts/fb_ablation.sh RUNS_DIR [hydra overrides...]
# e.g. JOBS=2 VARIANTS="full noise" bash scripts/fb_ablation.sh $NEURALDEM_DATA/fb_ablation \
#        trainer=cpu logger=csv trainer.max_steps=2000 trainer.val_check_interval=500
# Variants of the default recipe (experiment=fb), one change left out each: full (the default), no_unroll
# (one-step training only), fixed_noise (input noise 0.01 instead of the running one-step error), no_flux (no
# solids-flux channels, mixing re-predicted absolutely), no_conserve (no volume projection), stochastic (+ latent
# noise, CRPS over 2 members), no_ema (the training weights instead of their moving average), mirror (+ half the
# training samples mirrored in x), continuity (+ the continuity loss on the predicted solids flux, weight 0.2),
# long (16000 training steps, twice the default 8000), short (4000, the shipped fb_small model's length),
# mirror_alt (rollouts alternate with the mirror image,
# rollout.mirror_alternate, in the run's rollout validation and evaluation too), mirror_both (mirrored
# training samples + alternating rollouts), noise_sel (rollout noise 3, rollout.rollout_noise, in the run's
# rollout validation, so the checkpoint is chosen on noisy rollouts, and in its evaluation), noise_pooled (noise_sel
# + that validation scored against every CFD-DEM run at the velocity, callbacks.rollout_validation.reference=pooled),
# cond10 (the inlet velocity's sin-cos embedding at scale 10 instead of the positions' 1000,
# model.net.scalar_coord_scale=10: nearby velocities get nearby conditioning; experiment=fb has it, so cond10 =
# full), cond1000 (scale 1000, the positions' scale: the recipe as the shipped fb_small was trained).
# The one-step options (one-step training, absolute mixing, no projection,
# no flux channels): base (no noise), noise (input noise 0.01), grid_only (no particle branch), residual (the grid
# branches predict the scaled change per step), grid_residual (both). Push-forward scored only at t + k (the old
# `pf`) is refused: it never trains the one-step map from data.
# A variant may name a model config: "fb_base/full" trains model=fb_base (sizes side by side for
# right-sizing: VARIANTS="fb_tiny/full fb_base/full fb_small/full").
# A variant with rollout options after a + trains nothing: it scores the kept checkpoint of the variant before the
# first + again, after the trainings, with those rollout options, each spelled as every command takes it
# (rollout.<option>=VALUE, conf/rollout/) and passed on unchanged: "full+rollout.mirror_alternate=true" (mirror-
# alternating rollouts), "full+rollout.rollout_noise=1" (the net reads each state + noise of 1 times its one-step
# error), "full+rollout.advection_correction=1+rollout.rollout_noise=0.5" (the mixing advection's flux correction
# in [0, 1]; 1 = full FCT, the least numerical mixing). The same net with and without them, where mirror_alt trains
# a second net (its checkpoint chosen on alternating rollouts). Such a variant's folder is its name without
# "rollout." and with - for = (Hydra reads no = inside a value): RUNS_DIR/full+mirror_alternate-true. sel chooses
# the checkpoint first, under those rollout options (`neuraldem report fb-select`, its ranking in
# RUNS_DIR/<trained variant>/selection/, the winner copied to RUNS_DIR/<variant folder>/selected.ckpt), and scores
# that one: "full+rollout.rollout_noise=3+rollout.advection_correction=1+rollout.mirror_alternate=true+sel";
# SELECT_FROM (training step, default 0), SELECT_SEEDS (rollout seeds, default "0 1") and LONG_VAL (datasets of
# long validation trajectories, e.g. $NEURALDEM_DATA/datasets/fb_small_longval) are passed on as --from-step,
# --seeds and --long-val. CHECK=1 checks VARIANTS and exits (nothing runs; scripts/fb_recipe_eval.sh does so first).
# Runs land in RUNS_DIR/<variant>/ (logs beside them), the table in RUNS_DIR/table.md (+ .json). A finished
# training (RUNS_DIR/<variant>/.trained) is not repeated, a killed one goes on from its checkpoints/latest.ckpt
# (ckpt_path=...) and a finished evaluation is skipped, so a killed sweep resumes.
# VAL=1 also scores each run's kept checkpoint (checkpoints/last.ckpt) on the validation part into
# RUNS_DIR-val/<variant>/evaluation (3000-step rollouts, against each validation trajectory and pooled over every
# run at its velocity) with its own table RUNS_DIR-val/table.md: choose between variants there, not on the test.
# TEST=0 leaves the test part alone (evaluate=false), to score only the variant validation chose, later:
#   neuraldem evaluate ckpt=RUNS_DIR/<variant>/checkpoints/last.ckpt vtk=false hydra.run.dir=RUNS_DIR/<variant>/evaluation
set -uo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
PY=${PYTHON:-python}
JOBS=${JOBS:-2}
VARIANTS=${VARIANTS:-"full no_unroll fixed_noise no_flux no_conserve stochastic noise"}
runs=$1; shift
# the one-step options (one-step training, no flux channels, absolute mixing, no projection)
OLD="model.stability.unroll=[1.0] model.stability.input_noise=0.0 rollout.conserve_volume=false \
rollout.mixing=absolute data.datamodule.solids_flux=false callbacks.ema=null"
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}
export OMP_WAIT_POLICY=${OMP_WAIT_POLICY:-PASSIVE}
overrides() {
  case "$1" in
    */*) local model=${1%%/*} rest
         [ -f "$ROOT/conf/model/$model.yaml" ] || { echo "fb_ablation: unknown model '$model' (no conf/model/$model.yaml)" >&2; return 2; }
         rest=$(overrides "${1#*/}") || return 2
         echo "model=$model $rest" ;;
    base) echo "data.datamodule.input_noise=0.0 data.datamodule.push_forward_steps=1 $OLD" ;;
    noise) echo "data.datamodule.input_noise=0.01 data.datamodule.push_forward_steps=1 $OLD" ;;
    grid_only) echo "data.datamodule.input_noise=0.01 model.net.particle_branch=false $OLD" ;;
    residual) echo "data.datamodule.input_noise=0.01 model.residual=true $OLD" ;;
    grid_residual) echo "data.datamodule.input_noise=0.01 model.residual=true model.net.particle_branch=false $OLD" ;;
    # the default recipe (experiment=fb) and one change left out at a time
    full) echo "" ;;
    no_unroll) echo "model.stability.unroll=[1.0]" ;;
    fixed_noise) echo "model.stability.input_noise=0.01" ;;
    no_flux) echo "data.datamodule.solids_flux=false rollout.mixing=absolute" ;;
    no_conserve) echo "rollout.conserve_volume=false" ;;
    stochastic) echo "model.stability.ensemble=2 model.net.noise_dim=8" ;;
    no_ema) echo "callbacks.ema=null" ;;
    mirror) echo "data.datamodule.mirror=true" ;;
    continuity) echo "model.stability.flux_consistency=0.2" ;;
    long) echo "trainer.max_steps=16000" ;;
    short) echo "trainer.max_steps=4000" ;;
    mirror_alt) echo "rollout.mirror_alternate=true" ;;
    mirror_both) echo "data.datamodule.mirror=true rollout.mirror_alternate=true" ;;
    noise_sel) echo "rollout.rollout_noise=3" ;;
    noise_pooled) echo "rollout.rollout_noise=3 callbacks.rollout_validation.reference=pooled" ;;
    cond10) echo "model.net.scalar_coord_scale=10" ;;
    cond1000) echo "model.net.scalar_coord_scale=1000" ;;
    *) echo "fb_ablation: unknown variant '$1' (known: full no_unroll fixed_noise no_flux no_conserve stochastic no_ema mirror continuity long short mirror_alt mirror_both noise_sel noise_pooled cond10 cond1000 base noise grid_only residual grid_residual)" >&2; return 2 ;;
  esac
}
trained_of() { echo "${1%%+*}"; }
# the rollout options (options.RolloutOptions; a test keeps this list equal to its fields)
ROLLOUT_KEYS="conserve_volume mixing advection_correction advection_flux mirror_alternate rollout_noise"
rollout_options() {  # "full+rollout.rollout_noise=1+sel" -> "rollout.rollout_noise=1": what every command is given
  local rest=${1#*+} opt name out=""
  case "$1" in *+*) ;; *) rest="" ;; esac
  for opt in ${rest//+/ }; do
    name=${opt%%=*}
    name=${name#rollout.}
    case "$opt" in
      sel) continue ;;
      rollout.*=?*) case " $ROLLOUT_KEYS " in *" $name "*) out="$out $opt"; continue ;; esac ;;
    esac
    echo "fb_ablation: unknown rollout option '$opt' in '$1' (give rollout.NAME=VALUE with NAME one of" \
         "$ROLLOUT_KEYS, or sel)" >&2
    return 2
  done
  echo "$out"
}
variant_dir() { local d=${1//rollout./}; echo "${d//=/-}"; }  # full+rollout.rollout_noise=1 -> full+rollout_noise-1
for v in $VARIANTS; do
  overrides "$(trained_of "$v")" > /dev/null || exit 2
  case "$v" in *+*)
    rollout_options "$v" > /dev/null || exit 2
    b=$(trained_of "$v")
    case " $VARIANTS " in *" $b "*) ;; *)
      [ -f "$runs/$b/.trained" ] || { echo "fb_ablation: '$v' scores variant '$b', which is neither in VARIANTS nor trained in $runs/$b" >&2; exit 2; } ;;
    esac ;;
  esac
done
[ "${CHECK:-0}" = 1 ] && exit 0
mkdir -p "$runs"
TEST=${TEST:-1}
test_off=()
[ "$TEST" = 1 ] || test_off=(evaluate=false)
failed=0
running=0
slot() { if [ "$running" -ge "$JOBS" ]; then wait -n || failed=$((failed + 1)); running=$((running - 1)); fi; }
val_eval() {  # $1 variant folder, $2 checkpoint, then extra evaluate overrides
  local v=$1 ckpt=$2; shift 2
  [ "${VAL:-0}" = 1 ] || return 0
  [ -f "$runs-val/$v/evaluation/metrics.json" ] && return 0
  "$PY" -m neuraldem.evaluate ckpt="$ckpt" part=val vtk=false "$@" hydra.run.dir="$runs-val/$v/evaluation"
}
for v in $VARIANTS; do
  case "$v" in *+*) continue ;; esac
  run="$runs/$v"
  if [ -f "$run/evaluation/metrics.json" ] || { [ -f "$run/.trained" ] && [ "$TEST" != 1 ]; }; then
    echo "skip training $v (done)"
    [ "${VAL:-0}" = 1 ] && [ ! -f "$runs-val/$v/evaluation/metrics.json" ] || continue
  fi
  slot
  echo "start $v"
  mkdir -p "$(dirname "$run")"
  # shellcheck disable=SC2046
  (
    if [ ! -f "$run/.trained" ] && [ ! -f "$run/evaluation/metrics.json" ]; then
      resume=()  # a killed training goes on from its newest state (written at every validation)
      if [ -f "$run/checkpoints/latest.ckpt" ]; then resume=(ckpt_path="$run/checkpoints/latest.ckpt"); else rm -rf "$run"; fi
      "$PY" -m neuraldem.train experiment=fb $(overrides "$v") hydra.run.dir="$run" callbacks.progress=null \
        "${test_off[@]}" "$@" "${resume[@]}" || exit 1
      mkdir -p "$run" && touch "$run/.trained"
    elif [ "$TEST" = 1 ] && [ ! -f "$run/evaluation/metrics.json" ]; then
      "$PY" -m neuraldem.evaluate ckpt="$run/checkpoints/last.ckpt" vtk=false hydra.run.dir="$run/evaluation" || exit 1
    fi
    val_eval "$v" "$run/checkpoints/last.ckpt"
  ) >> "$run.log" 2>&1 &
  running=$((running + 1))
done
while [ "$running" -gt 0 ]; do wait -n || failed=$((failed + 1)); running=$((running - 1)); done
for v in $VARIANTS; do  # the trained nets again, with other rollout options
  case "$v" in *+*) ;; *) continue ;; esac
  opts=$(rollout_options "$v")
  b=$(trained_of "$v")
  d=$(variant_dir "$v")
  ckpt="$runs/$b/checkpoints/last.ckpt"
  [ -f "$runs/$b/.trained" ] || [ -f "$ckpt" ] \
    || { echo "fb_ablation: $v: $b was not trained (see its log)" >&2; failed=$((failed + 1)); continue; }
  slot
  echo "start $v"
  (
    case "+${v#*+}+" in *+sel+*)
      ckpt="$runs/$d/selected.ckpt"
      if [ ! -f "$ckpt" ]; then
        # shellcheck disable=SC2086
        "$PY" -m neuraldem.scenes.fluidized_bed.surrogate.selection "$runs/$b" $opts \
          --from-step "${SELECT_FROM:-0}" --seeds ${SELECT_SEEDS:-0 1} ${LONG_VAL:+--long-val $LONG_VAL} \
          --copy-to "$ckpt" || exit 1
      fi ;;
    esac
    if [ "$TEST" = 1 ] && [ ! -f "$runs/$d/evaluation/metrics.json" ]; then
      # shellcheck disable=SC2086
      "$PY" -m neuraldem.evaluate ckpt="$ckpt" vtk=false $opts \
        hydra.run.dir="$runs/$d/evaluation" || exit 1
    fi
    # shellcheck disable=SC2086
    val_eval "$d" "$ckpt" $opts
  ) >> "$runs/$d.log" 2>&1 &
  running=$((running + 1))
done
while [ "$running" -gt 0 ]; do wait -n || failed=$((failed + 1)); running=$((running - 1)); done
[ "$failed" -eq 0 ] || echo "fb_ablation: $failed run(s) failed; see $runs/*.log" >&2
"$PY" -m neuraldem.scenes.fluidized_bed.analysis.table "$runs" --out "$runs/table.md"
if [ "${VAL:-0}" = 1 ]; then "$PY" -m neuraldem.scenes.fluidized_bed.analysis.table "$runs-val" --out "$runs-val/table.md"; fi
exit "$failed"
