#!/usr/bin/env bash
# Sets up everything the project needs on a fresh Debian/Ubuntu machine.
#   scripts/setup.sh          the gateway and its offline tools (the demo's emulated board
#                             needs them): a virtual environment in .venv, adxl-gateway[offline]
#   scripts/setup.sh --test   also the test tools: Debian packages (socat, mbpoll,
#                             can-utils, qemu and a guest kernel for SocketCAN tests)
# Idempotent: a second run only checks.
set -euo pipefail
cd "$(dirname "$0")/.."

want_test=0
[ "${1:-}" = "--test" ] && want_test=1

log() { echo "setup: $*" >&2; }

# --- Debian packages ---------------------------------------------------------
apt_install() {
    local missing=()
    for pkg in "$@"; do
        dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
    done
    [ ${#missing[@]} -eq 0 ] && return 0
    local sudo=""
    if [ "$(id -u)" -ne 0 ]; then
        command -v sudo >/dev/null || { log "need root (or sudo) to install: ${missing[*]}"; exit 1; }
        sudo="sudo"
    fi
    log "installing Debian packages: ${missing[*]}"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
}

if [ $want_test -eq 1 ]; then
    # shellcheck disable=SC2046
    apt_install $(grep -v '^#' scripts/apt-test-packages.txt)
    if [ -x scripts/install-vm-deps.sh ]; then
        scripts/install-vm-deps.sh
    fi
fi

# --- Python ------------------------------------------------------------------
PYTHON="${PYTHON:-python3}"
"$PYTHON" - <<'PY' || { log "Python 3.11 or newer is needed (found: $("$PYTHON" --version 2>&1))"; exit 1; }
import sys
sys.exit(0 if sys.version_info >= (3, 11) else 1)
PY
if ! "$PYTHON" -c "import venv, ensurepip" 2>/dev/null; then
    apt_install python3-venv
fi
# a venv left half-made by an interrupted run (no pip in it) is made again
if [ ! -x .venv/bin/python ] || ! .venv/bin/python -m pip --version >/dev/null 2>&1; then
    log "creating .venv"
    rm -rf .venv
    "$PYTHON" -m venv .venv
fi
extras="[offline]"
[ $want_test -eq 1 ] && extras="[offline,test]"
stamp=".venv/.installed$extras"
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ] || [ constraints.txt -nt "$stamp" ]; then
    log "installing adxl-gateway$extras into .venv (the tested versions: constraints.txt)"
    .venv/bin/python -m pip install -q --disable-pip-version-check --upgrade pip >/dev/null
    .venv/bin/python -m pip install -q --disable-pip-version-check -c constraints.txt -e ".$extras"
    touch "$stamp"
fi
log "ready: .venv/bin/adxlgw"
