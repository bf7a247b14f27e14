#!/usr/bin/env bash
# Rehearse a new user's fresh machine: clone the committed HEAD into a new folder, give it a fresh
# HOME, TMPDIR and caches (no venv, no pip/Ray/Taichi/torch caches, no ROS state), run the README's
# test command there, then list what the run left outside its folder (/tmp, /dev/shm) and in its own
# TMPDIR besides pytest's basetemp.
#
#   tools/rehearse_fresh_machine.sh [--keep] [pytest args ...]
#
# Exit status: the test command's. The clone lives in a new folder under /tmp (printed); --keep
# keeps it, otherwise it is removed at the end. Packages still come from the registries and the
# machine's own package files (that is what a fresh machine has too).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
KEEP=0
if [ "${1:-}" = "--keep" ]; then KEEP=1; shift; fi
if [ "${1:-}" = "-h" ] || [ "${1:-}" = "--help" ]; then sed -n '2,11p' "$0" | sed 's/^# \{0,1\}//'; exit 0; fi

BASE="$(mktemp -d /tmp/dlo-fresh-XXXXXX)"
mkdir -p "$BASE/home" "$BASE/tmp"
say() { printf '[fresh] %s\n' "$*"; }
snapshot() { { ls -A /tmp; ls -A /dev/shm 2>/dev/null | sed 's#^#/dev/shm/#'; } | sort; }
before="$(snapshot)"
say "cloning $(git -C "$ROOT" rev-parse --short HEAD) into $BASE/repo"
git clone --quiet --no-hardlinks "$ROOT" "$BASE/repo"
start=$(date +%s)
set +e
PY="$("${DLO_PYTHON:-python3.11}" -c 'import sys; print(sys.executable)')"  # the real interpreter, not a shim
env -i PATH="$(dirname "$PY"):/usr/local/bin:/usr/bin:/bin" DLO_PYTHON="$PY" \
  HOME="$BASE/home" TMPDIR="$BASE/tmp" LANG=C.UTF-8 TERM=dumb \
  bash -c 'cd "$0/repo" && bash scripts/test.sh "$@"' "$BASE" "$@" 2>&1 | tee "$BASE/test.log"
status=${PIPESTATUS[0]}
set -e
say "test command exit $status after $(( $(date +%s) - start )) s (log: $BASE/test.log)"
left="$(comm -13 <(echo "$before") <(snapshot) | grep -v "^$(basename "$BASE")\$" || true)"
if [ -n "$left" ]; then
  say "new entries outside the clone (left by this run or by other processes meanwhile):"
  echo "$left" | sed 's/^/  /'
else
  say "nothing new in /tmp or /dev/shm"
fi
# the run's own TMPDIR: what tests leave there accumulates in a user's /tmp (pytest's basetemp is expected)
own="$(ls -A "$BASE/tmp" | grep -v '^pytest-of-' || true)"
if [ -n "$own" ]; then
  say "left in the run's own TMPDIR besides pytest's basetemp:"
  echo "$own" | sed 's/^/  /'
else
  say "nothing left in the run's own TMPDIR besides pytest's basetemp"
fi
if [ "$KEEP" = 0 ] && [ "$status" = 0 ]; then rm -rf "$BASE"; else say "kept $BASE"; fi
exit "$status"
