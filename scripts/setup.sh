#!/usr/bin/env bash
# Idempotent setup: venv + neuraldem (pinned CPU torch, torch-cluster) + the real solvers (LIGGGHTS, OpenFOAM).
# Safe to run again: every step checks first and says what it did.
#   NEURALDEM_VENV      venv folder (default: .venv in the checkout)
#   NEURALDEM_NO_SOLVERS=1  skip the apt-get step (e.g. solvers installed another way)
#   NEURALDEM_NO_BROWSER=1  skip installing chromium + chromium-driver (the explorer's browser tests then skip)
#   TORCH_INDEX_URL     where to get torch 2.13.0 when no local wheel exists
#                       (default https://download.pytorch.org/whl/cpu: the CPU build, not the multi-GB CUDA one)
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
VENV=${NEURALDEM_VENV:-$ROOT/.venv}
PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null 2>&1 || PY=python3
say() { printf '[setup] %s\n' "$*"; }
# apt_install WHY PACKAGE...: system packages with apt-get (sudo when not root), saying what and why
apt_install() {
  local why=$1; shift
  local SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  say "installing $* with apt-get ($why)"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "$@" >/dev/null
  say "installed $*"
}

# ---- solvers (system packages)
need_apt=()
command -v liggghts >/dev/null 2>&1 || need_apt+=(liggghts)
command -v DPMFoam >/dev/null 2>&1 || need_apt+=(openfoam)
if [ "${NEURALDEM_NO_SOLVERS:-0}" = 1 ]; then
  say "skipping solver install (NEURALDEM_NO_SOLVERS=1)"
elif [ ${#need_apt[@]} -eq 0 ]; then
  say "solvers present: $(command -v liggghts), $(command -v DPMFoam)"
elif command -v apt-get >/dev/null 2>&1; then
  apt_install "LIGGGHTS 3.8 and OpenFOAM v1912 on Debian 12; a few minutes" "${need_apt[@]}"
else
  say "WARNING: no apt-get here: install LIGGGHTS 3.8 and OpenFOAM v1912 yourself (see README); continuing"
fi

# ---- headless browser (system packages): `neuraldem serve`'s tests and latency benchmark drive Chromium
need_browser=()
command -v chromium >/dev/null 2>&1 || need_browser+=(chromium)
command -v chromedriver >/dev/null 2>&1 || need_browser+=(chromium-driver)
if [ "${NEURALDEM_NO_BROWSER:-0}" = 1 ]; then
  say "skipping chromium install (NEURALDEM_NO_BROWSER=1)"
elif [ ${#need_browser[@]} -eq 0 ]; then
  say "browser present: $(command -v chromium), $(command -v chromedriver)"
elif command -v apt-get >/dev/null 2>&1; then
  apt_install "headless Chromium for the explorer's tests" "${need_browser[@]}"
else
  say "WARNING: no apt-get here: install chromium and chromedriver yourself for the explorer's tests; continuing"
fi

# ---- venv
if [ -x "$VENV/bin/python" ]; then
  say "venv exists: $VENV"
else
  "$PY" -m venv "$VENV"
  say "created venv $VENV ($("$VENV/bin/python" --version))"
fi
PIP=("$VENV/bin/python" -m pip --disable-pip-version-check -q)

# ---- torch 2.13.0, CPU build (an unpinned torch pulls a multi-GB CUDA build)
if "$VENV/bin/python" -c 'import torch, sys; sys.exit(torch.__version__.split("+")[0] != "2.13.0")' 2>/dev/null; then
  say "torch 2.13.0 present"
else
  local_wheel=""
  for d in ${PIP_FIND_LINKS:-} /opt/wheels; do
    ls "$d"/torch-2.13.0*cp311*.whl >/dev/null 2>&1 && local_wheel="$d" && break
  done
  if [ -n "$local_wheel" ]; then
    "${PIP[@]}" install torch==2.13.0 --find-links "$local_wheel"
    say "installed torch 2.13.0 from $local_wheel"
  else
    "${PIP[@]}" install torch==2.13.0 --index-url "${TORCH_INDEX_URL:-https://download.pytorch.org/whl/cpu}"
    say "installed torch 2.13.0 from ${TORCH_INDEX_URL:-https://download.pytorch.org/whl/cpu}"
  fi
fi

# ---- torch-cluster 1.6.3 (no PyPI wheel: a local wheel folder, else a source build)
WHEELS="$ROOT/../shared/wheels/cpu-py311-torch2.13.0"
if "$VENV/bin/python" -c 'import torch_cluster' 2>/dev/null; then
  say "torch-cluster present"
elif [ -d "$WHEELS" ]; then
  "${PIP[@]}" install torch-cluster==1.6.3 --find-links "$WHEELS"
  say "installed torch-cluster 1.6.3 from $WHEELS"
else
  say "building torch-cluster 1.6.3 from source (several minutes; needs a C++ compiler)"
  "${PIP[@]}" install --no-build-isolation torch-cluster==1.6.3
  say "built and installed torch-cluster 1.6.3"
fi

# ---- neuraldem itself (editable) with test, sweep and serve (the explorer) extras
"${PIP[@]}" install -e "$ROOT[test,sweep,serve]" 2> >(grep -v "^WARNING: Location" >&2)
say "installed neuraldem (editable) into $VENV"
say "done: activate with 'source $VENV/bin/activate'"
