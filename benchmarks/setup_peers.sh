#!/usr/bin/env bash
# Creates one virtual environment per peer decoder for bench_codec.py.
#
# libasterix and asterix_decoder both install the import name `asterix`, as does our codec,
# so each peer lives in its own venv and is run in a subprocess (peer_decode.py).
#
# asterix_decoder is a C++ extension built from an sdist: it needs g++, the Python headers
# and the libexpat headers. If expat.h is missing, run as root:
#     apt-get update && apt-get install -y libexpat1-dev
#
# Idempotent: a venv whose peer already imports at the pinned version is left alone.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
venvs="$here/.venvs"
python="${PYTHON:-python3}"

# name, pip requirement, distribution name whose version is checked
peers=(
    "libasterix libasterix==0.36.3 libasterix"
    "asterix_decoder asterix_decoder==0.7.11 asterix_decoder"
)

if [[ ! -e /usr/include/expat.h ]]; then
    echo "warning: /usr/include/expat.h not found; asterix_decoder's build may fail." >&2
    echo "         apt-get update && apt-get install -y libexpat1-dev" >&2
fi

mkdir -p "$venvs"
for entry in "${peers[@]}"; do
    read -r name requirement dist <<<"$entry"
    venv="$venvs/$name"
    want="${requirement##*==}"
    # Checked by distribution metadata and a real import, so a half-built venv is redone.
    if [[ -x "$venv/bin/python" ]] &&
        have="$("$venv/bin/python" -c "import importlib.metadata as m, asterix; \
print(m.version('$dist'))" 2>/dev/null)" && [[ "$have" == "$want" ]]; then
        echo "$name: $requirement already installed in $venv"
        continue
    fi
    echo "$name: creating $venv"
    "$python" -m venv --clear "$venv"
    "$venv/bin/python" -m pip install --quiet --upgrade pip
    "$venv/bin/python" -m pip install --quiet "$requirement"
    "$venv/bin/python" -c "import importlib.metadata as m; print('$name:', m.version('$dist'))"
done
