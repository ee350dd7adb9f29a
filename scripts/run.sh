#!/usr/bin/env bash
# One command: install what is needed, then run Motion Composer on the bundled demo clip.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/motion-composer info resources/clips/cmu_131_01_walk.bvh "$@"
