#!/usr/bin/env bash
# A throwaway certificate authority for a fleetgate lab (mutual TLS), made with openssl.
#
#   deploy/make-ca.sh OUTDIR ROBOTS [GATEWAY_NAME...]
#
# OUTDIR/ca.pem, ca.key          the CA (keep ca.key offline; it signs everything below)
# OUTDIR/gateway.pem, .key       the gateway's certificate for GATEWAY_NAMEs (DNS names or IP
#                                addresses; default: localhost 127.0.0.1)
# OUTDIR/robot-<id>.pem, .key    robot <id>'s client certificate, id 0..ROBOTS-1, naming
#                                fleetgate:robot:<id> (SAN URI and CN): the gateway binds the
#                                connection to that robot id
# OUTDIR/operator.pem, .key      a client certificate with no robot identity (a browser or an
#                                operator tool, if require_client_cert = true)
# Keys are EC P-256, certificates valid 825 days. Re-running overwrites OUTDIR's files.
set -euo pipefail
if [ $# -lt 2 ]; then
  echo "usage: $0 OUTDIR ROBOTS [GATEWAY_NAME...]" >&2
  exit 2
fi
out=$1; robots=$2; shift 2
names=("$@"); [ ${#names[@]} -gt 0 ] || names=(localhost 127.0.0.1)
case $robots in ''|*[!0-9]*) echo "$0: ROBOTS must be a number, got '$robots'" >&2; exit 2;; esac
mkdir -p "$out"
umask 077
days=825

key() { openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$1" 2>/dev/null; }

# sign NAME SUBJECT EXTENSIONS: OUTDIR/NAME.pem signed by the CA
sign() {
  local name=$1 subject=$2 ext=$3
  key "$out/$name.key"
  openssl req -new -key "$out/$name.key" -subj "$subject" -out "$out/$name.csr"
  openssl x509 -req -in "$out/$name.csr" -CA "$out/ca.pem" -CAkey "$out/ca.key" \
    -CAcreateserial -days $days -sha256 -extfile <(printf '%s\n' "$ext") \
    -out "$out/$name.pem" 2>/dev/null
  rm -f "$out/$name.csr"
}

key "$out/ca.key"
openssl req -new -x509 -key "$out/ca.key" -subj "/CN=fleetgate throwaway CA" -days $days \
  -sha256 -addext "basicConstraints=critical,CA:TRUE" \
  -addext "keyUsage=critical,keyCertSign,cRLSign" -out "$out/ca.pem"

san=""
for n in "${names[@]}"; do
  if [[ $n =~ ^[0-9.]+$ || $n == *:* ]]; then san+="IP:$n,"; else san+="DNS:$n,"; fi
done
sign gateway "/CN=${names[0]}" "basicConstraints=CA:FALSE
keyUsage=critical,digitalSignature
extendedKeyUsage=serverAuth
subjectAltName=${san%,}"

for ((r = 0; r < robots; r++)); do
  sign "robot-$r" "/CN=fleetgate:robot:$r" "basicConstraints=CA:FALSE
keyUsage=critical,digitalSignature
extendedKeyUsage=clientAuth
subjectAltName=URI:fleetgate:robot:$r"
done
sign operator "/CN=fleetgate operator" "basicConstraints=CA:FALSE
keyUsage=critical,digitalSignature
extendedKeyUsage=clientAuth"
chmod 644 "$out"/*.pem
echo "made a CA, the gateway's certificate (${names[*]}) and $robots robot certificates in $out" >&2
