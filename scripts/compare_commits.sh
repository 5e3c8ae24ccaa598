#!/usr/bin/env bash
# Behaviour check for a refactor: the same seeded training runs, evaluations, a benchmark and the dataset reports
# with the code of two commits, on the tiny real datasets of the test suite; then every number compared.
#   bash scripts/compare_commits.sh BEFORE AFTER OUT_DIR [DATASETS_DIR]
# DATASETS_DIR holds fb_tiny, hopper_tiny and hopper_refill_tiny (default: $NEURALDEM_TEST_DATA/datasets, which the test suite
# fills). Each commit runs from its own git worktree under OUT_DIR; OUT_DIR/compare.txt says what differs
# (dates, commands, paths, timings and machine load are left out). Both commits must read the key=value command
# line (docs/cli.md).
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
before=$1 after=$2 out=$(mkdir -p "$3" && cd "$3" && pwd)
datasets=${4:-${NEURALDEM_TEST_DATA:?give DATASETS_DIR or set NEURALDEM_TEST_DATA}/datasets}
PY=${PYTHON:-$ROOT/.venv/bin/python}
export OMP_WAIT_POLICY=PASSIVE OMP_NUM_THREADS=1 WANDB_MODE=offline NEURALDEM_DATA=$out/data
mkdir -p "$out/data" && ln -sfn "$(cd "$datasets" && pwd)" "$out/data/datasets"
for tag in before after; do
  rev=${!tag}
  wt=$out/src-$tag
  [ -d "$wt" ] || git -C "$ROOT" worktree add -q --detach "$wt" "$rev"
  (
    cd "$wt" && export PYTHONPATH=$wt/src
    for exp in fb_quick hopper_quickstart hopper_refill; do
      extra=()  # the refilling hopper on its tiny dataset: 20 steps (its experiment trains on hopper_refill)
      [ "$exp" = hopper_refill ] && extra=(data=hopper_refill_tiny trainer=cpu logger=csv trainer.max_steps=20
        trainer.val_check_interval=10 data.datamodule.n_queries=64 data.datamodule.batch_size=2)
      [ -f "$out/$tag/$exp/evaluation/metrics.json" ] || "$PY" -m neuraldem train experiment=$exp seed=0 \
        "${extra[@]}" hydra.run.dir="$out/$tag/$exp" > "$out/$tag-$exp.log" 2>&1
    done
    ckpt=$(ls "$out/$tag/fb_quick/checkpoints/"*.ckpt | grep -v latest | head -1)
    "$PY" -m neuraldem bench fb_stability ckpt="$ckpt" n_velocities=3 steps=60 \
      out="$out/$tag/bench/fb_stability.json" > "$out/$tag-bench.log" 2>&1
    "$PY" -m neuraldem report fb-dataset dataset="$out/data/datasets/fb_tiny" out="$out/$tag/fb_report" \
      > /dev/null 2>&1
    "$PY" -m neuraldem report dataset dataset="$out/data/datasets/hopper_tiny" out="$out/$tag/dataset_report" \
      > /dev/null 2>&1
  )
  echo "$tag ($rev): done"
done
"$PY" "$ROOT/scripts/compare_outputs.py" "$out/before" "$out/after" | tee "$out/compare.txt"
