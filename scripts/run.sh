#!/usr/bin/env bash
# One command: install what is needed, then open Motion Composer on the bundled demo project.
# Extra arguments go to motion-composer (e.g. a project file instead of the demo).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
args=("$@")
[ ${#args[@]} -eq 0 ] && args=(--demo)
if [ -z "${DISPLAY:-}" ] && [ -z "${WAYLAND_DISPLAY:-}" ]; then
  # no screen (a server, CI): draw the window on a virtual one and keep a picture of it
  echo "run: no display; opening the window under Xvfb and saving a picture to demo-window.png"
  exec xvfb-run -a -s "-screen 0 1600x1000x24" .venv/bin/motion-composer "${args[@]}" \
    --screenshot demo-window.png
fi
exec .venv/bin/motion-composer "${args[@]}"
