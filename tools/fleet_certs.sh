#!/usr/bin/env bash
# The certificates of a fleet over Zenoh TLS with client certificates
# (docs/ZENOH.md), made with the openssl command, EC P-256:
#
#   tools/fleet_certs.sh DIR STATION_SAN [ROBOT ...]
#
#   DIR          folder of the files; created if missing
#   STATION_SAN  the names robots connect to the station by, as openssl's
#                subjectAltName, e.g. "DNS:station.lan,IP:192.168.1.10"
#   ROBOT        a robot id: makes DIR/ROBOT.pem and DIR/ROBOT.key
#
# Writes DIR/ca.pem and DIR/ca.key (the fleet's CA) and DIR/station.pem
# and DIR/station.key, each only where DIR has none (robots are added
# later with the same CA and station; delete station.pem to remake it for
# other names), and one certificate and key per robot. Keys are written readable by the owner only. Validity: CA 3650
# days, station and robots 825 days (INSUWB_CERT_DAYS overrides both, as
# the tests do).
set -euo pipefail
if [ "$#" -lt 2 ]; then
  echo "usage: $0 DIR STATION_SAN [ROBOT ...]" >&2
  exit 2
fi
dir=$1
san=$2
shift 2
for robot in "$@"; do
  case $robot in
    station | ca | '' | *[!A-Za-z0-9_-]*)
      echo "$0: robot id '$robot': use letters, digits, '_' and '-', not 'station' or 'ca'" >&2
      exit 2
      ;;
  esac
done
ca_days=${INSUWB_CERT_DAYS:-3650}
days=${INSUWB_CERT_DAYS:-825}
mkdir -p "$dir"
cd "$dir"
umask 077
ec=(-newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes)

# quiet CMD...: runs openssl CMD, printing its output only when it fails.
quiet() {
  local out
  if ! out=$(openssl "$@" 2>&1); then
    printf "%s\nopenssl %s failed:\n%s\n" "$0" "$1" "$out" >&2
    exit 1
  fi
}

if [ ! -f ca.pem ] || [ ! -f ca.key ]; then
  quiet req -x509 "${ec[@]}" -days "$ca_days" -keyout ca.key -out ca.pem \
    -subj "/CN=insuwb fleet CA"
fi

# sign NAME SAN: NAME.key and NAME.pem, signed by ca.pem.
sign() {
  quiet req "${ec[@]}" -keyout "$1.key" -out "$1.csr" -subj "/CN=$1"
  printf "subjectAltName=%s\n" "$2" > "$1.ext"
  quiet x509 -req -in "$1.csr" -CA ca.pem -CAkey ca.key -CAcreateserial \
    -days "$days" -out "$1.pem" -extfile "$1.ext"
  rm -f "$1.csr" "$1.ext"
  chmod 644 "$1.pem"
}

if [ ! -f station.pem ] || [ ! -f station.key ]; then
  sign station "$san"
fi
for robot in "$@"; do
  sign "$robot" "DNS:$robot"
done
chmod 644 ca.pem
echo "$dir: ca.pem, station.pem${*:+, robots: }$*" >&2
