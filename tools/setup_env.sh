#!/usr/bin/env bash
# Create or refresh .venv/ for this project on a fresh machine.
#   - installs the system libraries Open3D's wheel needs (apt-get when root; otherwise names them and stops)
#   - (re)creates .venv/ when it is missing or stale against pyproject.toml or constraints.txt
#   - installs the project (editable) with its dependencies at the versions constraints.txt pins
# Idempotent: a second run with nothing changed takes well under a second.
set -euo pipefail
cd "$(dirname "$0")/.."

PY=${PYTHON:-python3}
VENV=.venv
STAMP="$VENV/.bijcr-stamp"

# --- system libraries ------------------------------------------------------------------------------
# Open3D's wheel links against these; PyBullet/OpenCV headless need no more.
declare -A LIB_OF_PKG=(
  [libusb-1.0-0]=libusb-1.0.so.0
  [libgl1]=libGL.so.1
  [libegl1]=libEGL.so.1
  [libx11-6]=libX11.so.6
  [libudev1]=libudev.so.1
)
missing=()
for pkg in "${!LIB_OF_PKG[@]}"; do
  lib=${LIB_OF_PKG[$pkg]}
  if ! ldconfig -p 2>/dev/null | grep -q "$lib"; then missing+=("$pkg"); fi
done
if [ ${#missing[@]} -gt 0 ]; then
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null; then
    echo "[setup] installing system libraries: ${missing[*]}"
    if ! apt-get install -y -q "${missing[@]}" >/tmp/bijcr-apt.log 2>&1; then
      apt-get update -q >>/tmp/bijcr-apt.log 2>&1 || true
      apt-get install -y -q "${missing[@]}" >>/tmp/bijcr-apt.log 2>&1 || {
        echo "[setup] apt-get failed; see /tmp/bijcr-apt.log" >&2; exit 1; }
    fi
  else
    echo "[setup] missing system libraries: ${missing[*]}" >&2
    echo "[setup] install them first, e.g.: sudo apt-get install ${missing[*]}" >&2
    exit 1
  fi
fi

# --- virtual environment ---------------------------------------------------------------------------
want=$(cat pyproject.toml constraints.txt 2>/dev/null | sha256sum | cut -c1-16)-$($PY -c 'import sys;print("%d.%d"%sys.version_info[:2])')
have=$(cat "$STAMP" 2>/dev/null || true)
if [ -x "$VENV/bin/python" ] && [ "$want" = "$have" ]; then
  exit 0
fi
if [ -d "$VENV" ] && [ -n "$have" ]; then
  echo "[setup] .venv is stale against pyproject.toml or constraints.txt; updating it"
else
  echo "[setup] creating $VENV (takes about 2 minutes on a fresh machine)"
  rm -rf "$VENV"
  "$PY" -m venv "$VENV"
fi
"$VENV/bin/python" -m pip install -q --upgrade pip >/dev/null 2>&1 || true
# torch==2.13.0 is pinned in pyproject.toml; pip finds the CPU wheel via the machine's find-links.
# constraints.txt: the exact versions the benches ran with (same numerics on a fresh machine)
pins=()
[ -f constraints.txt ] && pins=(-c constraints.txt)
"$VENV/bin/python" -m pip install -q --disable-pip-version-check "${pins[@]}" -e ".[dev]"
echo "$want" > "$STAMP"
echo "[setup] .venv ready"
