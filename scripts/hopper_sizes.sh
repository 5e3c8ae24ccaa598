#!/usr/bin/env bash
# The hopper checkpoints behind the speed-accuracy chart and right-sizing (docs/benchmarks.md): the
# micro-conditioned field model at four sizes and SEEDS seeds (default "0 1"), trained and evaluated one after
# another on one core, and the particle-based GNS baseline on the other core at the same time.
#   bash scripts/hopper_sizes.sh OUT_DIR [hydra overrides for the field models...]
# Field runs land in OUT_DIR/fields/<size>[_seed<N>]/ (evaluated: `neuraldem bench speed_accuracy runs=OUT_DIR/fields`), the GNS
# in OUT_DIR/gns/ (`gns_ckpt=OUT_DIR/gns/checkpoints/last.ckpt`); logs beside them. A field run whose folder
# holds evaluation/metrics.json, or a GNS with its last.ckpt, is skipped, so a killed sweep resumes.
# FIELD_STEPS (default 2000) and GNS_STEPS (default 700) set the training steps; GNS=0 trains the field models
# only; SIZES (default "hopper_tiny hopper_base hopper_base_tok32 hopper_small") picks the sizes.
set -uo pipefail
PY=${PYTHON:-python}
out=$1; shift
FIELD_STEPS=${FIELD_STEPS:-2000}
GNS_STEPS=${GNS_STEPS:-700}
SEEDS=${SEEDS:-"0 1"}
GNS=${GNS:-1}  # GNS=0: the field models only
SIZES=${SIZES:-"hopper_tiny hopper_base hopper_base_tok32 hopper_small"}
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 OMP_WAIT_POLICY=PASSIVE WANDB_MODE=offline
mkdir -p "$out/fields"
common=(trainer=cpu logger=csv callbacks.progress=null)

field() {  # name, then overrides of that size
  local name=$1; shift
  local run="$out/fields/$name"
  if [ -f "$run/evaluation/metrics.json" ]; then echo "skip $name (evaluated)"; return 0; fi
  rm -rf "$run"
  echo "start $name"
  "$PY" -m neuraldem train experiment=hopper_micro "$@" "${common[@]}" data.datamodule.batch_size=8 \
    data.datamodule.n_queries=512 trainer.max_steps="$FIELD_STEPS" trainer.val_check_interval=500 \
    hydra.run.dir="$run" "${EXTRA[@]}" > "$out/fields/$name.log" 2>&1
}

EXTRA=("$@")
overrides() {  # the model overrides of a size name
  case $1 in
    hopper_tiny) echo "model=hopper_tiny" ;;
    hopper_base) echo "model=hopper_base" ;;
    hopper_base_tok32) echo "model=hopper_base model.net.n_latent_tokens=32" ;;
    hopper_small) echo "model=hopper_small" ;;
    *) echo "hopper_sizes: unknown size $1 (SIZES takes hopper_tiny hopper_base hopper_base_tok32 hopper_small)" >&2
       return 1 ;;
  esac
}
sizes() {  # every size of SIZES at one seed (folder suffix _seed<N> except for seed 0)
  local sfx="" name ov
  [ "$1" != 0 ] && sfx="_seed$1"
  for name in $SIZES; do
    ov=$(overrides "$name") || return 1
    # shellcheck disable=SC2086  # the overrides are separate words
    field "$name$sfx" $ov seed="$1" || return 1
  done
}
(
  for s in $SEEDS; do sizes "$s" || exit 1; done
) &
fields=$!
if [ "$GNS" = 0 ]; then
  echo "gns not asked for (GNS=0)"
elif [ -f "$out/gns/checkpoints/last.ckpt" ]; then
  echo "skip gns (trained)"
else
  rm -rf "$out/gns"
  echo "start gns"
  "$PY" -m neuraldem train experiment=gns_hopper "${common[@]}" trainer.max_steps="$GNS_STEPS" \
    trainer.val_check_interval=$((GNS_STEPS / 2)) model.scheduler.warmup_steps=50 hydra.run.dir="$out/gns" \
    > "$out/gns.log" 2>&1 || { echo "gns failed: see $out/gns.log" >&2; wait "$fields"; exit 1; }
fi
wait "$fields" || { echo "a field run failed: see $out/fields/*.log" >&2; exit 1; }
echo "done: $out/fields (evaluated), $out/gns"
