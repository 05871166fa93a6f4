#!/usr/bin/env bash
# Idempotent set-up for a fresh Debian/Ubuntu machine: the system libraries IPOPT needs, a virtualenv in .venv,
# and myriad installed in editable mode with the pinned versions of constraints.txt.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
VENV=${VENV:-.venv}

need_apt=()
command -v pkg-config >/dev/null 2>&1 || need_apt+=(pkg-config)
if ! pkg-config --exists ipopt 2>/dev/null; then need_apt+=(coinor-libipopt-dev libblas-dev liblapack-dev); fi
# IPOPT's MUMPS factorises with the system BLAS; Debian's default is the reference BLAS. OpenBLAS (serial: no
# threads fighting the JAX callbacks for the cores) measured 15-20 % faster warm solves on the larger dense
# single-shooting problems (Rocket Landing 583 -> 482 ms, Cart-Pole 272 -> 238 ms, Bear Populations 92 -> 78 ms).
dpkg -s libopenblas0-serial >/dev/null 2>&1 || need_apt+=(libopenblas0-serial)
"$PYTHON" -c 'import venv, ensurepip' 2>/dev/null || need_apt+=(python3-venv)
command -v gcc >/dev/null 2>&1 || need_apt+=(gcc)
"$PYTHON" -c 'import sysconfig, os, sys; sys.exit(not os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h")))' \
  || need_apt+=(python3-dev)
if [ ${#need_apt[@]} -gt 0 ]; then
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  echo "setup: installing Debian packages: ${need_apt[*]}"
  $SUDO apt-get update -q
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q "${need_apt[@]}"
fi

stamp="$VENV/.installed"
if [ -f "$stamp" ] && [ "$stamp" -nt pyproject.toml ] && [ "$stamp" -nt constraints.txt ]; then exit 0; fi
[ -x "$VENV/bin/python" ] || "$PYTHON" -m venv "$VENV"
"$VENV/bin/python" -m pip install -q --upgrade pip setuptools wheel
# The distribution was called `myriad` before `myriad-control`; left installed, its editable finder and console
# scripts would sit beside the new ones (removed first: uninstalling it afterwards would delete the new scripts).
if "$VENV/bin/python" -m pip show -q myriad >/dev/null 2>&1; then
  "$VENV/bin/python" -m pip uninstall -q -y myriad && rm -rf myriad.egg-info
fi
"$VENV/bin/python" -m pip install -q -c constraints.txt -e ".[test,bench,ray,docs]"  # docs: tests/test_docs.py builds the site
touch "$stamp"
