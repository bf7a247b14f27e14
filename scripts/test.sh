#!/usr/bin/env bash
# README command 2: install what is missing (scripts/setup.sh), then run the whole test suite.
# Extra arguments go to pytest (e.g. scripts/test.sh -k tactile -x). Exit code = test result.
# Tests run in DLO_TEST_WORKERS pytest-xdist workers (default 2, a file's tests in one worker: module
# fixtures such as a launched graph are shared as without workers); DLO_TEST_WORKERS=0 or `-n 0`: one process.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/setup.sh"
# shellcheck source=/dev/null
source "$ROOT/scripts/env.sh"
cd "$ROOT"
workers="${DLO_TEST_WORKERS:-2}"
[[ "$workers" =~ ^[0-9]+$ ]] || { echo "scripts/test.sh: DLO_TEST_WORKERS must be a number >= 0, got '$workers'" >&2; exit 2; }
echo "[test] running pytest over tests/ and ros_ws/src/*/test ($workers workers)"
exec python -m pytest -n "$workers" --dist loadfile "$@"
