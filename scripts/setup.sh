#!/usr/bin/env bash
# One-shot set-up on a fresh Debian machine: system libraries, .venv, every Python dependency.
# Idempotent: re-running only installs what is missing.
set -euo pipefail
cd "$(dirname "$0")/.."

# open3d needs these Debian libraries to import (libusb, GL/EGL); the crane-side codec test
# (tests/field/test_link_c_codec.py) compiles the C code cantools generates from the DBC (gcc, libc6-dev).
need=()
for pkg in libusb-1.0-0 libgl1 libegl1 gcc libc6-dev; do
  dpkg -s "$pkg" >/dev/null 2>&1 || need+=("$pkg")
done
if [ ${#need[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ]; then SUDO=""; elif command -v sudo >/dev/null; then SUDO="sudo"; else
    echo "error: missing system packages ${need[*]}; install them (apt-get install ${need[*]}) and re-run" >&2; exit 1
  fi
  echo "installing system packages: ${need[*]}"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${need[@]}" >/dev/null
fi

PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
stamp=.venv/.loggrasp-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ] || [ constraints.txt -nt "$stamp" ]; then
  .venv/bin/python -m pip install -q --upgrade pip
  # torch first, pinned: the CPU build (2.13.0) — never let a resolver pull a CUDA build.
  .venv/bin/python -m pip install -q "torch==2.13.0"
  # every other package at the release in constraints.txt (what the suite was last run with)
  .venv/bin/python -m pip install -q -e ".[test]" -c constraints.txt
  touch "$stamp"
fi
.venv/bin/loggrasp --help >/dev/null
echo "ready: .venv/bin/loggrasp"
