#!/usr/bin/env bash
# The test suite as CI runs it: CPU, passive OpenMP threads, a private data dir. Extra args go to pytest
# (e.g. `bash scripts/test.sh -m slow` for the long tests).
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${NEURALDEM_VENV:-$(pwd)/.venv}
export OMP_WAIT_POLICY=PASSIVE OMP_NUM_THREADS=${OMP_NUM_THREADS:-1} MKL_NUM_THREADS=1
export WANDB_MODE=offline WANDB_SILENT=true
exec "$VENV/bin/python" -m pytest "$@"
