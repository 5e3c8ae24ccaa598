#!/usr/bin/env bash
# README command 1: set everything up, check the machine, answer a what-if with the shipped model and check it
# with LIGGGHTS, then run the main job on its small built-in default: generate the tiny LIGGGHTS hopper dataset,
# train the hopper surrogate, evaluate it against DEM and write the plots (a few CPU minutes after the
# install). Safe to run again: every step resumes.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
VENV=${NEURALDEM_VENV:-$(pwd)/.venv}
export OMP_WAIT_POLICY=PASSIVE WANDB_MODE=offline
PY="$VENV/bin/python"
"$PY" -m neuraldem doctor
# a what-if from the shipped model in seconds, then LIGGGHTS on the same hopper (~2 CPU minutes) beside it
"$PY" -m neuraldem predict hopper alpha=45 mu_s=0.4 mu_r=0.1 verify=true
WORKERS=$("$PY" -c 'import os; print(max(1, min(2, len(os.sched_getaffinity(0)))))')
"$PY" -m neuraldem datagen data=hopper_tiny workers="$WORKERS"
"$PY" -m neuraldem train experiment=hopper_quickstart
