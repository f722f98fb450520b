#!/usr/bin/env bash
# The one-command demo: gateway + 10 simulated robots + the operator GUI on http://127.0.0.1:8080/
# Usage: bash scripts/demo.sh [fleetgate demo options, e.g. --speed 2 --port 8081]
set -euo pipefail
cd "$(dirname "$0")/.."
if [ ! -x .venv/bin/fleetgate ]; then
  python3 -m venv .venv
  .venv/bin/python -m pip install -q --upgrade pip
  .venv/bin/python -m pip install -q -e .
fi
exec .venv/bin/fleetgate demo "$@"
