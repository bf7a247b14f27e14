#!/usr/bin/env bash
# Copy the small files of every FINISHED run (done.json present) under RUNS into RESULTS, keeping
# the directory layout: config.yaml, eval.csv, done.json, best.json, test*.json. Never checkpoints,
# replay buffers, policies or bags. Prints the run directories it added or updated.
#   scripts/collect_results.sh runs/study results/study
set -euo pipefail
if [ $# -ne 2 ] || [ "$1" = "-h" ] || [ "$1" = "--help" ]; then
  sed -n '2,5p' "$0" | sed 's/^# \{0,1\}//'
  [ $# -eq 2 ] && exit 0 || exit 2
fi
runs=${1%/} results=${2%/}
[ -d "$runs" ] || { echo "collect_results: no directory $runs" >&2; exit 2; }
find "$runs" -name done.json -print0 | sort -z | while IFS= read -r -d '' done; do
  run=$(dirname "$done")
  dest="$results/${run#"$runs"/}"
  mkdir -p "$dest"
  changed=0
  for f in "$run"/config.yaml "$run"/eval.csv "$run"/done.json "$run"/best.json "$run"/test*.json; do
    [ -f "$f" ] || continue
    cmp -s "$f" "$dest/$(basename "$f")" || { cp "$f" "$dest/"; changed=1; }
  done
  [ "$changed" = 1 ] && echo "$dest"
done
exit 0
