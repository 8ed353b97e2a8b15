#!/usr/bin/env bash
# Creates benchmarks/.venvs/stonesoup with Stone Soup 1.9.1 for bench_stonesoup.py.
#
# Stone Soup is a peer to compare with, never a dependency of the project: it lives in a
# venv of its own (git-ignored) and bench_stonesoup.py runs it in a subprocess
# (stonesoup_peer.py), fed the same plot stream as our tracker.
#
# Idempotent: a venv whose stonesoup already imports at the pinned version is left alone.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
venv="$here/.venvs/stonesoup"
python="${PYTHON:-python3}"
want="1.9.1"

if [[ -x "$venv/bin/python" ]] &&
    have="$("$venv/bin/python" -c "import importlib.metadata as m, stonesoup; \
print(m.version('stonesoup'))" 2>/dev/null)" && [[ "$have" == "$want" ]]; then
    echo "stonesoup: $want already installed in $venv"
    exit 0
fi
echo "stonesoup: creating $venv"
mkdir -p "$here/.venvs"
"$python" -m venv --clear "$venv"
"$venv/bin/python" -m pip install --quiet --upgrade pip
"$venv/bin/python" -m pip install --quiet "stonesoup==$want"
"$venv/bin/python" -c "import importlib.metadata as m; print('stonesoup:', m.version('stonesoup'))"
