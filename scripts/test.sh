#!/usr/bin/env bash
# README command 2: install what is missing (scripts/setup.sh), then run the whole test suite.
# Extra arguments go to pytest (e.g. scripts/test.sh -k tactile -x). Exit code = test result.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/setup.sh"
# shellcheck source=/dev/null
source "$ROOT/scripts/env.sh"
cd "$ROOT"
echo "[test] running pytest over tests/ and ros_ws/src/*/test"
exec python -m pytest "$@"
