#!/bin/sh
# Makes the certificates of the mTLS example (config/zenoh/*.json5): a CA, the service's
# certificate (CN tracker-service) and one subscriber's (CN tracker-subscriber), each
# with its private key (EC P-256, PKCS#8, readable by its owner only).
#
#   config/zenoh/make-certs.sh DIR [HOST...]
#
# HOST: the names and addresses subscribers use in their endpoint to reach the service
# (tls/HOST:7447); each goes into the service certificate's subjectAltName, which
# subscribers check (default: localhost 127.0.0.1). The CA key stays in DIR/ca.key: keep
# it offline once the certificates are made. Existing files are never overwritten:
# rotation is a new DIR (docs/security.md).
#
# Environment: CA=DIR issues from the CA of an earlier run (DIR/ca.crt, DIR/ca.key)
# instead of making a new one (renewing certificates under the same CA);
# SUBSCRIBER=NAME gives the subscriber certificate that common name (one name per
# subscriber lets the service's access control drop one of them); CERT_DAYS (365).
set -eu

if [ $# -lt 1 ]; then
    echo "usage: $0 DIR [HOST...]" >&2
    exit 2
fi
dir=$1
shift
[ $# -gt 0 ] || set -- localhost 127.0.0.1
days=${CERT_DAYS:-365}
subscriber=${SUBSCRIBER:-tracker-subscriber}

for name in ca service subscriber; do
    for ext in crt key; do
        if [ -e "$dir/$name.$ext" ]; then
            echo "$0: $dir/$name.$ext exists; give a new directory" >&2
            exit 1
        fi
    done
done
mkdir -p "$dir"
umask 077

san=""
for host in "$@"; do
    case $host in
        *[!0-9.]* ) entry="DNS:$host" ;;  # a name (or an IPv6 address: give it as a name)
        * ) entry="IP:$host" ;;
    esac
    san="${san:+$san,}$entry"
done

key() {
    openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$1" 2>/dev/null
}

ca_key=$dir/ca.key
if [ -n "${CA:-}" ]; then
    # The CA's key stays where it is (no second copy); its certificate comes along.
    ca_key=$CA/ca.key
    cp "$CA/ca.crt" "$dir/"
else
    key "$dir/ca.key"
    openssl req -x509 -new -key "$dir/ca.key" -sha256 -days "$days" -subj "/CN=tracker-ca" \
        -addext "basicConstraints=critical,CA:TRUE" \
        -addext "keyUsage=critical,keyCertSign,cRLSign" \
        -out "$dir/ca.crt"
fi

# issue NAME CN EXTENSIONS
issue() {
    key "$dir/$1.key"
    openssl req -new -key "$dir/$1.key" -subj "/CN=$2" -out "$dir/$1.csr"
    printf '%s\n' "basicConstraints=critical,CA:FALSE" \
        "keyUsage=critical,digitalSignature" "$3" >"$dir/$1.ext"
    openssl x509 -req -in "$dir/$1.csr" -CA "$dir/ca.crt" -CAkey "$ca_key" \
        -CAcreateserial -CAserial "$dir/ca.srl" -sha256 -days "$days" -extfile "$dir/$1.ext" \
        -out "$dir/$1.crt" 2>/dev/null
    rm -f "$dir/$1.csr" "$dir/$1.ext"
}

# The service listens (server) and may connect to routers (client); a subscriber connects.
issue service tracker-service "extendedKeyUsage=serverAuth,clientAuth
subjectAltName=$san"
issue subscriber "$subscriber" "extendedKeyUsage=clientAuth
subjectAltName=DNS:$subscriber"
rm -f "$dir/ca.srl"
chmod 644 "$dir/ca.crt" "$dir/service.crt" "$dir/subscriber.crt"
echo "$dir: ca.crt, service.crt/.key ($san), subscriber.crt/.key ($subscriber); keep $ca_key offline"
