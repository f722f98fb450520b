#!/usr/bin/env bash
# The one-command demo: gateway + 10 simulated robots + the operator GUI on http://127.0.0.1:8080/
# Usage: bash scripts/demo.sh [fleetgate demo options, e.g. --speed 2 --port 8081]
set -euo pipefail
cd "$(dirname "$0")/.."
if [ ! -x .venv/bin/fleetgate ]; then
  # first run: install quietly (pip's and the build's warnings go to the log, not the screen)
  echo "fleetgate demo: first run, installing into .venv (a minute or two; log: .venv/install.log)" >&2
  python3 -m venv .venv
  if ! { .venv/bin/python -m pip install -q --upgrade pip &&
         .venv/bin/python -m pip install -q -e .; } > .venv/install.log 2>&1; then
    tail -n 15 .venv/install.log >&2
    echo "fleetgate demo: the install failed (the whole log: .venv/install.log)" >&2
    exit 1
  fi
fi
exec .venv/bin/fleetgate demo "$@"
