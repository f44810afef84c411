#!/usr/bin/env bash
# Installs spgeo and everything it needs on a fresh Debian/Ubuntu machine with
# Python 3.11: the system library open3d needs (libusb-1.0-0) and the pinned
# Python packages.  Usage: bash scripts/install.sh [--test]
#   --test  also installs the test extras (pytest, onnx, nbclient, ...).
set -euo pipefail
cd "$(dirname "$0")/.."

PY="${PYTHON:-}"
if [ -z "$PY" ]; then
  for cand in python3.11 python3 python; do
    if command -v "$cand" >/dev/null 2>&1 && "$cand" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
      PY="$cand"; break
    fi
  done
fi
[ -n "$PY" ] || { echo "install.sh: Python 3.11 not found (set PYTHON=...)" >&2; exit 1; }

if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
  SUDO=""
  [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1 && SUDO="sudo"
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get install -y -q libusb-1.0-0 >/dev/null 2>&1 || {
    $SUDO apt-get update -q >/dev/null && $SUDO apt-get install -y -q libusb-1.0-0 >/dev/null; }
fi

EXTRA=""
[ "${1:-}" = "--test" ] && EXTRA="[test]"
"$PY" -m pip install -q --disable-pip-version-check -e ".${EXTRA}"
echo "spgeo installed with $("$PY" --version)"
