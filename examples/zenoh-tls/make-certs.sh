#!/bin/sh
# Certificates for examples/zenoh-tls (mutual TLS): a CA of your own, the plant's certificate for the address the
# node connects to, and one client certificate per peer, each named by its common name (CN), which plant.json5's
# access control matches. Needs the openssl command. Run it in this folder:
#   sh make-certs.sh PLANT_ADDRESS [PEER ...]     e.g.  sh make-certs.sh 192.168.1.10 node viewer
# PLANT_ADDRESS: the IP address or host name in the node's --connect tls/PLANT_ADDRESS:7447. PEERs default to
# "node viewer". Keep ca.key off the robot (it signs certificates); each *.key stays with its own process.
set -eu
host=${1:?usage: sh make-certs.sh PLANT_ADDRESS [PEER ...]}
shift
[ $# -gt 0 ] || set -- node viewer
case "$host" in
  *[!0-9.]*) san="DNS:$host" ;;
  *) san="IP:$host" ;;
esac
umask 077
key() { openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$1.key" 2>/dev/null; }
sign() {  # name, common name, subjectAltName
  key "$1"
  openssl req -new -key "$1.key" -subj "/CN=$2" -out "$1.csr"
  printf 'subjectAltName=%s\n' "$3" > "$1.ext"
  openssl x509 -req -in "$1.csr" -CA ca.pem -CAkey ca.key -CAcreateserial -days 365 -extfile "$1.ext" \
    -out "$1.pem" 2>/dev/null
  rm -f "$1.csr" "$1.ext"
}
if [ ! -f ca.pem ]; then
  key ca
  openssl req -x509 -new -key ca.key -subj "/CN=omnirotor CA" -days 3650 -out ca.pem
fi
sign plant plant "$san"
for peer in "$@"; do
  sign "$peer" "$peer" "DNS:$peer"
done
echo "made: ca.pem, plant.pem/.key ($san), and for $*: NAME.pem/.key"
