#!/usr/bin/env bash
# Installs everything the test suite needs on a fresh machine, then runs it.
# Usage: bash scripts/test.sh [pytest args...]
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m venv .venv
. .venv/bin/activate
python -m pip install -q --upgrade pip
python -m pip install -q -e '.[test]'
# Headless Chromium for the GUI tests and Eclipse Mosquitto for the VDA 5050 tests (a real
# MQTT broker, started by the test fixtures on a free loopback port): Debian packages.
PKGS=""
[ -x /usr/bin/chromium ] || PKGS="$PKGS chromium chromium-driver"
[ -x /usr/sbin/mosquitto ] || PKGS="$PKGS mosquitto"
if [ -n "$PKGS" ]; then
  if [ "$(id -u)" = 0 ]; then SUDO=""; else SUDO="sudo"; fi
  $SUDO apt-get update -q >/dev/null
  # shellcheck disable=SC2086
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q $PKGS >/dev/null
fi
# An independent VDA 5050 implementation for tests/vda5050/test_external.py: the npm package
# vda-5050-lib (MIT), installed outside the repository (never committed); that test skips
# without it.
if command -v npm >/dev/null && [ -z "${FLEETGATE_VDA5050_LIB:-}" ]; then
  VDA_LIB_DIR="${XDG_CACHE_HOME:-$HOME/.cache}/fleetgate/vda-5050-lib"
  mkdir -p "$VDA_LIB_DIR"
  if (cd "$VDA_LIB_DIR" && npm install --no-audit --no-fund --silent vda-5050-lib@1.4.0 \
        >/dev/null 2>&1); then
    export FLEETGATE_VDA5050_LIB="$VDA_LIB_DIR/node_modules"
  else
    echo "vda-5050-lib could not be installed: tests/vda5050/test_external.py skips" >&2
  fi
fi
ruff check .
mypy
mypy bench
# Reproducible property tests: the derandomised hypothesis profile (tests/conftest.py).
export HYPOTHESIS_PROFILE="${HYPOTHESIS_PROFILE:-ci}"
set +e
python -m pytest -n 2 -q "$@"
rc=$?
set -e
if [ "$rc" = 5 ]; then
  echo "pytest collected no tests: failing" >&2
  exit 1
fi
exit "$rc"
