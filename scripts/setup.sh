#!/usr/bin/env bash
# Set up a development/run environment from a clean checkout: a Python virtualenv
# with posefix and its pinned dependencies, and the built front end.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
.venv/bin/python -m pip install --quiet --upgrade pip
.venv/bin/python -m pip install --quiet -e 'backend[dev]'
if [ -f frontend/package.json ]; then
  (cd frontend && { [ -f package-lock.json ] && npm ci --no-audit --no-fund --loglevel=error || npm install --no-audit --no-fund --loglevel=error; } && npm run build --silent)
fi
echo "posefix set up in $(pwd)/.venv"
