#!/usr/bin/env bash
# One command: set up, create the embedded SQLite database with demo data, and serve.
set -euo pipefail
cd "$(dirname "$0")/.."
./scripts/setup.sh
exec .venv/bin/posefix demo "$@"
