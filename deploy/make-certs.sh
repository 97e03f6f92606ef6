#!/bin/sh
# Makes a test certificate authority and one certificate per PC (or consumer) for a rig's
# mutual-TLS Zenoh links (docs/deploy.md, "Security"). Needs openssl.
#
#   deploy/make-certs.sh DIR NAME[=ADDRESS[,ADDRESS...]]...
#
#   deploy/make-certs.sh certs capture1=192.168.10.11 capture2=192.168.10.12 \
#       fusion=192.168.10.20 consumer=192.168.10.30
#
# Writes DIR/ca.pem and DIR/ca.key (the authority, made once: an existing one is reused, so
# a PC can be added later) and DIR/NAME.pem, DIR/NAME.key for each NAME. A certificate's
# common name is NAME: for a PC of the rig it must be that PC's [[host]] name, which is what
# the routers' access control gives publishing rights to (what that host's services
# publish); any other name (a consumer) may only read. Each ADDRESS (IP or DNS name) is put
# in the certificate's subject alternative names: a PC's must include every address other
# PCs dial it on (its tls/ADDRESS:PORT endpoints), since the dialling end checks it.
#
# This is for tests and a first deployment. Keep DIR/ca.key off the rig's PCs: copy each PC
# only ca.pem, its own NAME.pem and NAME.key.
set -eu

if [ $# -lt 2 ]; then
  echo "usage: $0 DIR NAME[=ADDRESS[,ADDRESS...]]..." >&2
  exit 2
fi
command -v openssl >/dev/null || { echo "$0: openssl is needed (apt install openssl)" >&2; exit 1; }
dir=$1
shift
mkdir -p "$dir"
days=825

if [ ! -f "$dir/ca.pem" ] || [ ! -f "$dir/ca.key" ]; then
  openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -days "$days" \
    -subj "/CN=Stereoscope rig authority" \
    -addext "basicConstraints=critical,CA:TRUE" \
    -addext "keyUsage=critical,keyCertSign,cRLSign" \
    -keyout "$dir/ca.key" -out "$dir/ca.pem" 2>/dev/null
  chmod 600 "$dir/ca.key"
  echo "made $dir/ca.pem (the rig's authority)"
fi

for spec in "$@"; do
  name=${spec%%=*}
  case "$name" in
    ''|*[!A-Za-z0-9_-]*)
      echo "$0: $name: a name is letters, digits, '_' or '-' (a [[host]] name)" >&2
      exit 2 ;;
  esac
  san="DNS:$name"
  if [ "$spec" != "$name" ]; then
    addresses=${spec#*=}
    old_ifs=$IFS
    IFS=,
    for a in $addresses; do
      case "$a" in
        *[!0-9.]*) case "$a" in *:*) san="$san,IP:$a" ;; *) san="$san,DNS:$a" ;; esac ;;
        *) san="$san,IP:$a" ;;
      esac
    done
    IFS=$old_ifs
  fi
  ext=$(mktemp)
  printf '%s\n' \
    "basicConstraints=critical,CA:FALSE" \
    "keyUsage=critical,digitalSignature" \
    "extendedKeyUsage=serverAuth,clientAuth" \
    "subjectAltName=$san" >"$ext"
  openssl req -new -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes \
    -subj "/CN=$name" -keyout "$dir/$name.key" -out "$dir/$name.csr" 2>/dev/null
  openssl x509 -req -in "$dir/$name.csr" -CA "$dir/ca.pem" -CAkey "$dir/ca.key" \
    -CAcreateserial -days "$days" -extfile "$ext" -out "$dir/$name.pem" 2>/dev/null
  rm -f "$ext" "$dir/$name.csr"
  chmod 600 "$dir/$name.key"
  echo "made $dir/$name.pem ($san)"
done
