#!/usr/bin/env bash
# One command: install what is needed, then run the whole test suite headless.
# Extra arguments go to pytest (e.g. bash scripts/test.sh -k bvh -x).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh --test
# the venv's commands first on PATH: the tests run the installed motion-composer script too
export PATH="$PWD/.venv/bin:$PATH"
exec .venv/bin/python -m pytest "$@"
