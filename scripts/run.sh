#!/usr/bin/env bash
# README command 1 (the main job): install what is missing, then run the ROS 2 graph (sim, tactile,
# vision, policy with the shipped All-modalities SAC policy, recorder) for a few step-locked
# episodes, record every /dlo topic to an MCAP bag under bags/, and print the outcome table.
# Options go to scripts/launch_graph.sh (e.g. --episodes 10 --mode real_time); --help lists them.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
for arg in "$@"; do case "$arg" in -h|--help) exec bash "$ROOT/scripts/launch_graph.sh" --help ;; esac; done
bash "$ROOT/scripts/setup.sh"
set +u; source "$ROOT/scripts/env.sh"; set -u
bag="$ROOT/bags/run_$(date +%Y%m%d_%H%M%S)"
mkdir -p "$ROOT/bags"
echo "[run] graph: 5 step-locked episodes (seeds 1000..1004) with the shipped policy; recording to $bag"
exec bash "$ROOT/scripts/launch_graph.sh" --episodes 5 --seed 1000 --record "$bag" "$@"
