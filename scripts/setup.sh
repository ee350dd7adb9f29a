#!/usr/bin/env bash
# Installs everything Motion Composer needs on a Debian machine: system packages (Qt's X11
# platform libraries, Xvfb, and with --test Blender as an independent file reader), then a
# virtual environment in .venv with the project installed in editable mode.
# Idempotent: packages already present are not fetched again.
#   bash scripts/setup.sh          # the application
#   bash scripts/setup.sh --test   # the application and the test suite's needs
set -euo pipefail
cd "$(dirname "$0")/.."

want_test=0
[ "${1:-}" = "--test" ] && want_test=1

packages=(python3 python3-venv python3-pip
          libgl1 libegl1 libglib2.0-0 libdbus-1-3 libfontconfig1 libxkbcommon0
          libxkbcommon-x11-0 libxcb-cursor0 libxcb-icccm4 libxcb-image0 libxcb-keysyms1
          libxcb-randr0 libxcb-render-util0 libxcb-shape0 libxcb-xkb1 xvfb xauth)
if [ "$want_test" = 1 ] && [ "${MC_SKIP_BLENDER:-0}" != 1 ]; then
  # Blender reads our BVH and glTF output in the tests, as a reader we did not write
  packages+=(blender python3-numpy)
fi

if command -v dpkg-query >/dev/null 2>&1; then
  missing=()
  for p in "${packages[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  if [ ${#missing[@]} -gt 0 ]; then
    echo "setup: installing system packages: ${missing[*]}"
    sudo_cmd=()
    [ "$(id -u)" -ne 0 ] && sudo_cmd=(sudo)
    "${sudo_cmd[@]}" apt-get update -qq
    DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y -qq \
      --no-install-recommends "${missing[@]}" >/dev/null
  fi
else
  echo "setup: not a Debian system; install Python 3.10+, Qt's X11 libraries and Xvfb yourself" >&2
fi

python=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv"
  "$python" -m venv .venv
fi
extras="gui"
[ "$want_test" = 1 ] && extras="gui,test"
.venv/bin/python -m pip install -q --upgrade pip >/dev/null
.venv/bin/python -m pip install -q -e ".[$extras]"
echo "setup: ready (.venv)"
