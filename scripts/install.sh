#!/usr/bin/env bash
# Installs spgeo and everything it needs on a fresh Debian/Ubuntu machine with
# Python 3.11, 3.12 or 3.13: the system library open3d needs (libusb-1.0-0) and the
# Python packages at the exact versions of constraints.txt (setup.py itself only
# states ranges).  Usage: [PYTHON=/path/to/python] bash scripts/install.sh [--test]
#   --test  also installs the extras the whole test suite uses: test (pytest, onnx,
#           nbclient, ...), viz (rerun) and distributed (ray).
# PYTHON picks the interpreter (a venv's python installs into that venv); without it the
# first of python3, python3.11, python3.12, python3.13, python in the supported range.
set -euo pipefail
cd "$(dirname "$0")/.."

PY="${PYTHON:-}"
if [ -z "$PY" ]; then
  for cand in python3 python3.11 python3.12 python3.13 python; do
    if command -v "$cand" >/dev/null 2>&1 && "$cand" -c 'import sys; sys.exit(not (3, 11) <= sys.version_info[:2] <= (3, 13))' 2>/dev/null; then
      PY="$cand"; break
    fi
  done
fi
[ -n "$PY" ] || { echo "install.sh: no Python 3.11-3.13 found (set PYTHON=...)" >&2; exit 1; }
"$PY" -c 'import sys; sys.exit(not (3, 11) <= sys.version_info[:2] <= (3, 13))' || {
  echo "install.sh: $PY is Python $("$PY" -c 'import sys; print(sys.version.split()[0])'), spgeo needs 3.11-3.13" >&2; exit 1; }

if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
  SUDO=""
  [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1 && SUDO="sudo"
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get install -y -q libusb-1.0-0 >/dev/null 2>&1 || {
    $SUDO apt-get update -q >/dev/null && $SUDO apt-get install -y -q libusb-1.0-0 >/dev/null; }
fi

EXTRA=""
[ "${1:-}" = "--test" ] && EXTRA="[test,viz,distributed]"
"$PY" -m pip install -q --disable-pip-version-check -c constraints.txt -e ".${EXTRA}"
echo "spgeo installed with $("$PY" --version)"
