#!/usr/bin/env bash
# Set up mcdp-synth on a fresh Debian 12 machine: system GL libraries, a virtualenv in .venv,
# and the package with its pinned dependencies. Safe to run again (idempotent).
#   bash scripts/setup.sh          # the package + pytest and pytest-xdist (the tests run on two workers)
#   bash scripts/setup.sh --test   # + the optional extras the test suite exercises: nuscenes-devkit
#                                  #   (which pins numpy < 2) and Ray in .venv, and a second environment
#                                  #   .venv-viz with [viz] (rerun-sdk 0.41 requires numpy >= 2); the main
#                                  #   suite runs the viz tests there (tests/test_viz_env.py).
# .venv-viz starts as a hard-linked copy of .venv (cp -al): torch's 5.5 GB are stored once, not twice (a CI
# machine ran out of disk installing them a second time). pip only ever replaces files (new file + rename,
# uninstall = move), so changing one environment never writes through a shared link into the other.
set -euo pipefail
extras="dev"
if [ "${1:-}" = "--test" ]; then extras="dev,nuscenes,cluster"; fi
cd "$(dirname "$0")/.."
SUDO=""
[ "$(id -u)" -ne 0 ] && SUDO="sudo"
pkgs="libegl1 libegl-mesa0 libgl1 libgl1-mesa-dri libosmesa6 libglib2.0-0"
missing=""
for p in $pkgs; do dpkg -s "$p" >/dev/null 2>&1 || missing="$missing $p"; done
python3 -c "import venv, ensurepip" 2>/dev/null || missing="$missing python3-venv"
if [ -n "$missing" ]; then
  echo "setup: installing system packages:$missing"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq $missing >/dev/null
fi
[ -x .venv/bin/python ] || python3 -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e ".[$extras]"
if [ "${1:-}" = "--test" ]; then
  if [ ! -x .venv-viz/bin/python ]; then
    rm -rf .venv-viz.tmp && cp -al .venv .venv-viz.tmp
    # the copied console scripts name .venv's interpreter: point them at their own (sed -i writes a new file)
    grep -lI "^#!$PWD/.venv/bin/python" .venv-viz.tmp/bin/* | xargs -r sed -i "1s|^#!$PWD/.venv/bin/|#!$PWD/.venv-viz/bin/|"
    .venv-viz.tmp/bin/python -m pip uninstall -q -y nuscenes-devkit  # numpy < 2; [viz] needs numpy >= 2
    mv .venv-viz.tmp .venv-viz
  fi
  .venv-viz/bin/python -m pip install -q -e ".[dev,viz]"
fi
echo "setup: done ($(.venv/bin/python -c 'import torch, OpenGL; print("torch", torch.__version__, "PyOpenGL", OpenGL.__version__)'))"
