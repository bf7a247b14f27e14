#!/usr/bin/env bash
# Mutation testing of the result- and safety-critical modules (issue 14; not in CI: slow).
# Applies one small bug at a time to a COPY of the source tree ($DLO_MUTATION_DIR, default
# /tmp/dlo-mutation), runs that module's fast unit tests against it and prints the score per module
# and every surviving mutant. Configuration: tools/mutation.toml. The live tree is never written.
#   tools/mutation_check.sh                      # every module
#   tools/mutation_check.sh --module dlo_interface.task --module dlo_interface.command
#   tools/mutation_check.sh --list               # the mutants only
# Runs at low priority (nice 15) and one test process at a time. Exit 0 = every module >= target.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
if [ ! -f "$ROOT/scripts/env.sh" ]; then
  echo "mutation_check: scripts/env.sh missing: run scripts/setup.sh first" >&2
  exit 2
fi
# shellcheck source=/dev/null
source "$ROOT/scripts/env.sh"
cd "$ROOT"
exec nice -n "${DLO_MUTATION_NICE:-15}" python "$ROOT/tools/mutation_check.py" "$@"
