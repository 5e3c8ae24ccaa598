#!/usr/bin/env bash
# README command 1: set everything up, check the machine, then run the main job on its small default.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
VENV=${NEURALDEM_VENV:-$(pwd)/.venv}
export OMP_WAIT_POLICY=PASSIVE WANDB_MODE=offline
"$VENV/bin/python" -m neuraldem.doctor
