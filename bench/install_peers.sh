#!/usr/bin/env bash
# Installs the tools `fascicle bench tracking` and `scale` compare against (never needed by `./run test`):
#   MRtrix3 3.0.3 (Debian package mrtrix3: tckgen, tckinfo, mrinfo, ...) and DIPY 1.12.1 in a virtual environment.
# Usage: bench/install_peers.sh [VENV_DIR]   (default ~/.cache/fascicle/dipy-venv); prints the Python to pass as --python.
set -euo pipefail
venv="${1:-$HOME/.cache/fascicle/dipy-venv}"
if ! command -v tckgen >/dev/null; then
  if [ "$(id -u)" = 0 ]; then
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq mrtrix3 >&2
  else
    sudo apt-get update -qq && sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq mrtrix3 >&2
  fi
fi
if [ ! -x "$venv/bin/python" ]; then
  python3 -m venv "$venv"
fi
"$venv/bin/python" -c 'import dipy, sys; sys.exit(dipy.__version__ != "1.12.1")' 2>/dev/null \
  || "$venv/bin/pip" install -q 'dipy==1.12.1' >&2
# nibabel (with DIPY) and trx-python: the loaders `fascicle-bench scale` compares against.
"$venv/bin/python" -c 'import nibabel, trx.trx_file_memmap' 2>/dev/null || "$venv/bin/pip" install -q nibabel trx-python >&2
echo "$venv/bin/python"
