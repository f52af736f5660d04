#!/usr/bin/env bash
# Peer comparison: `fpm reconstruct` against the published Python FPM packages
# fpm-rs and fpm-py, on one dataset with the same frames, wave vectors, upsampling
# and pass count. Creates (or reuses) a venv outside the repository, installs the
# pinned versions in requirements.txt, then runs compare.py with the arguments given.
#
#   tools/peers/compare.sh DATASET_DIR [--passes N] [--json OUT.json] [...]
#   tools/peers/compare.py --help   lists every option
#
# Environment:
#   FPM_PEERS_VENV    venv directory (default ${XDG_CACHE_HOME:-~/.cache}/fpm-peers/venv)
#   FPM_PEERS_PYTHON  Python 3.12 interpreter used to create the venv
#                     (default: pyenv's newest 3.12.x, else python3.12 on PATH)
#
# Does not build anything: it uses target/release/fpm as built (or --fpm PATH).
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
venv="${FPM_PEERS_VENV:-${XDG_CACHE_HOME:-$HOME/.cache}/fpm-peers/venv}"
req="$here/requirements.txt"

find_python() {
    if [ -n "${FPM_PEERS_PYTHON:-}" ]; then
        echo "$FPM_PEERS_PYTHON"
        return
    fi
    local root cand
    if command -v pyenv >/dev/null 2>&1; then
        root="$(pyenv root)"
        cand="$(ls -d "$root"/versions/3.12.* 2>/dev/null | sort -V | tail -n 1 || true)"
        if [ -n "$cand" ] && [ -x "$cand/bin/python3" ]; then
            echo "$cand/bin/python3"
            return
        fi
    fi
    if command -v python3.12 >/dev/null 2>&1; then
        command -v python3.12
        return
    fi
    echo "error: no Python 3.12 found; set FPM_PEERS_PYTHON" >&2
    exit 1
}

stamp="$venv/.fpm-peers-requirements"
if [ ! -x "$venv/bin/python" ] || ! cmp -s "$req" "$stamp"; then
    py="$(find_python)"
    ver="$("$py" -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
    if [ "$ver" != "3.12" ]; then
        echo "error: $py is Python $ver; the pinned peers need 3.12 (fpm-py < 3.13)" >&2
        exit 1
    fi
    echo "setting up $venv with $py (Python $ver)" >&2
    [ -x "$venv/bin/python" ] || "$py" -m venv "$venv"
    "$venv/bin/python" -m pip install --quiet -r "$req"
    cp "$req" "$stamp"
fi

exec "$venv/bin/python" "$here/compare.py" "$@"
