#!/usr/bin/env bash
# One command: install what is needed, then run the whole test suite headless.
# Extra arguments go to pytest (e.g. bash scripts/test.sh -k bvh -x; -n 0 runs it in this one
# process, for -s or a debugger).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh --test
# the venv's commands first on PATH: the tests run the installed motion-composer script too
export PATH="$PWD/.venv/bin:$PATH"
# one worker per core the process may use (at most 4: beyond that the longest test file sets the
# time); each test file runs whole in one worker, so a file's shared solves are made once
workers=$(.venv/bin/python -c "import os; print(max(1, min(4, len(os.sched_getaffinity(0)))))")
exec .venv/bin/python -m pytest -n "$workers" --dist loadfile "$@"
