#!/usr/bin/env bash
# Install the fleetgate gateway as a systemd service from this checkout (Debian 12+, as root):
#
#   sudo deploy/install.sh [GATEWAY_NAME...]
#
# 1. a wheel of this checkout (dist/) installed into a venv under /opt/fleetgate;
# 2. /etc/fleetgate/gateway.toml from deploy/gateway.tls.example.toml with random tokens
#    (kept if it exists; the tokens are printed once);
# 3. /etc/fleetgate/tls/: a throwaway CA, the gateway's certificate for GATEWAY_NAMEs (default:
#    this host's names, localhost, 127.0.0.1) and 3 robot certificates (deploy/make-ca.sh),
#    unless the directory holds a gateway.pem already (your own PKI);
# 4. the unit in /etc/systemd/system/fleetgate.service (then: systemctl enable --now fleetgate).
# PREFIX, ETC and UNIT_DIR override /opt/fleetgate, /etc/fleetgate and /etc/systemd/system.
set -euo pipefail
repo=$(cd "$(dirname "$0")/.." && pwd)
prefix=${PREFIX:-/opt/fleetgate}
etc=${ETC:-/etc/fleetgate}
unit_dir=${UNIT_DIR:-/etc/systemd/system}

if ! python3 -c 'import sys, venv; sys.exit(sys.version_info < (3, 11))' 2>/dev/null \
   || ! command -v openssl >/dev/null; then
  apt-get update -q && DEBIAN_FRONTEND=noninteractive apt-get install -y -q python3-venv openssl
fi

python3 -m venv "$prefix"
"$prefix/bin/pip" install -q --upgrade pip wheel
"$prefix/bin/pip" wheel -q --no-deps -w "$repo/dist" "$repo"
wheel=$(ls -t "$repo"/dist/fleetgate-*.whl | head -n 1)
"$prefix/bin/pip" install -q --force-reinstall --no-deps "$wheel"
"$prefix/bin/pip" install -q "$wheel"
install -d -m 755 "$prefix/share/fleetgate"
install -m 644 "$repo"/deploy/*.md "$repo"/deploy/*.toml "$prefix/share/fleetgate/"

install -d -m 750 "$etc" "$etc/tls"
if [ ! -f "$etc/gateway.toml" ]; then
  "$prefix/bin/python" - "$repo/deploy/gateway.tls.example.toml" "$etc/gateway.toml" <<'PY'
import re, secrets, sys
src, dst = sys.argv[1], sys.argv[2]
text = re.sub(r"CHANGE-ME-[a-z0-9-]+", lambda m: secrets.token_urlsafe(32), open(src).read())
open(dst, "w").write(text)
print(f"wrote {dst}; its tokens:", file=sys.stderr)
for line in text.splitlines():
    if re.search(r'^\s*(operators = |"[A-Za-z0-9_-]{40,}" = )', line):
        print("   ", line.strip(), file=sys.stderr)
PY
  chmod 640 "$etc/gateway.toml"
fi
if [ ! -f "$etc/tls/gateway.pem" ]; then
  if [ $# -eq 0 ]; then set -- "$(hostname -f 2>/dev/null || hostname)" localhost 127.0.0.1; fi
  "$repo/deploy/make-ca.sh" "$etc/tls" 3 "$@"
  echo "throwaway CA in $etc/tls: give robot-<id>.pem/.key and ca.pem to robot <id>" >&2
fi

install -m 644 "$repo/deploy/fleetgate.service" "$unit_dir/fleetgate.service"
if command -v systemctl >/dev/null && [ -d /run/systemd/system ]; then
  systemctl daemon-reload
fi
echo "installed: systemctl enable --now fleetgate; curl --cacert $etc/tls/ca.pem" \
     "https://localhost:8443/readyz" >&2
