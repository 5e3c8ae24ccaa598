#!/usr/bin/env bash
# The refilling-hopper study (results/refill/README.md): experiment=hopper_refill trained for each
# variant of SIZES (default "hopper_tiny hopper_base"; hopper_tiny_tref = tiny also conditioned on t_ref, the
# conditioning ablation), all at once (one core each), each evaluated after training on
# the held-out runs (transport 5 s after t_ref = the last full window, outlet residence over a reset rollout),
# then SHORT seconds after t_ref = T - SHORT (evaluation_h1, evaluation_h2) and the first SHORT horizon from the
# opening (t_ref = 0, evaluation_tref0: the transient the steady refill state does not show).
#   bash scripts/refill_study.sh OUT_DIR [hydra overrides...]
# Runs land in OUT_DIR/<size>/ (evaluation/, evaluation_h<H>/, evaluation_tref0/), logs beside them. A run whose folder holds
# evaluation_tref0/metrics.json is skipped, so a killed study resumes; REEVALUATE=1 scores trained runs afresh
# (every evaluation, with the current evaluation code) without retraining. STEPS (default: the experiment's 2000)
# sets the training steps, SHORT (default "1 2") the short horizons. Needs the dataset:
# neuraldem datagen data=hopper_refill n_sims=16 workers=2
set -uo pipefail
PY=${PYTHON:-python}
out=$1; shift
SIZES=${SIZES:-"hopper_tiny hopper_base"}
SHORT=${SHORT:-"1 2"}  # [s] the short horizons (evaluation_h<H>); the first one also from the opening
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 OMP_WAIT_POLICY=PASSIVE WANDB_MODE=offline
mkdir -p "$out"
steps=()
[ -n "${STEPS:-}" ] && steps=(trainer.max_steps="$STEPS")

field() {  # key run: a value of the run's first evaluation (the checkpoint it kept, the dataset)
  "$PY" -c "import json,sys; print(json.load(open(sys.argv[1]))[sys.argv[2]])" "$2/evaluation/metrics.json" "$1"
}

evaluation() {  # run ckpt dataset out_dir [overrides...]: one neuraldem evaluate of the run's test runs
  local run=$1 ckpt=$2 data=$3 dir=$4; shift 4
  "$PY" -m neuraldem evaluate ckpt="$ckpt" dataset_dir="$data" hydra.run.dir="$dir" "$@" >> "$run.log" 2>&1 \
    || { echo "$(basename "$run") evaluation $(basename "$dir") failed: $run.log"; return 1; }
}

variant() {  # the overrides of a variant name
  case $1 in
    hopper_tiny|hopper_base|hopper_small) echo "model=$1" ;;
    hopper_tiny_tref) echo "model=hopper_tiny data.conditioning=[dt_ref,t_ref,alpha,mu_s,mu_r]" ;;
    *) echo "refill_study: unknown variant $1 (SIZES takes hopper_tiny hopper_base hopper_small hopper_tiny_tref)" >&2
       return 1 ;;
  esac
}

one() {  # variant [overrides...]
  local name=$1; shift
  local ov
  ov=$(variant "$name") || return 1
  local run="$out/$name"
  if [ "${REEVALUATE:-0}" = 1 ] && [ -f "$run/evaluation/metrics.json" ]; then  # trained: score it afresh
    rm -rf "$run"/evaluation_h* "$run/evaluation_tref0"
    evaluation "$run" "$(field checkpoint "$run")" "$(field dataset "$run")" "$run/evaluation" || return 1
  fi
  if [ -f "$run/evaluation_tref0/metrics.json" ]; then echo "skip $name (evaluated)"; return 0; fi
  if [ ! -f "$run/evaluation/metrics.json" ]; then
    rm -rf "$run"
    echo "start $name"
    # shellcheck disable=SC2086  # the variant's overrides are separate words
    "$PY" -m neuraldem train experiment=hopper_refill $ov trainer=cpu logger=csv callbacks.progress=null \
      "${steps[@]}" hydra.run.dir="$run" "$@" > "$out/$name.log" 2>&1 || { echo "$name failed: $out/$name.log"; return 1; }
  fi
  local ckpt data h first=""  # the checkpoint and dataset the first evaluation used
  ckpt=$(field checkpoint "$run")
  data=$(field dataset "$run")
  # shorter horizons after the last reference times: most material of the 5-s answer has been refilled since
  # (median residence ~1.5 s), so the layers are read at SHORT seconds as well
  for h in $SHORT; do
    first=${first:-$h}
    [ -f "$run/evaluation_h$h/metrics.json" ] && continue
    evaluation "$run" "$ckpt" "$data" "$run/evaluation_h$h" refill.horizon="$h" || return 1
  done
  evaluation "$run" "$ckpt" "$data" "$run/evaluation_tref0" refill.t_ref=0 refill.horizon="$first" || return 1
  echo "done $name"
}

pids=()
for name in $SIZES; do
  one "$name" "$@" &
  pids+=($!)
done
rc=0
for p in "${pids[@]}"; do wait "$p" || rc=1; done
exit $rc
