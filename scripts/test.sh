#!/usr/bin/env bash
# One command: install what is needed, then run the whole test suite headless.
# Extra arguments go to pytest (e.g. bash scripts/test.sh -k bvh -x).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh --test
exec .venv/bin/python -m pytest "$@"
