#!/usr/bin/env bash
# Start the whole dlo-vitac graph (sim, tactile, vision, policy [, recorder]) as separate processes,
# wait until the sim has run its episodes (or Ctrl-C), stop every process it started, print the
# outcome table. Uses `ros2 run` on a real ROS 2 install, scripts/ros2run with the PyPI wheels.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
usage() {
  cat <<EOF
usage: scripts/launch_graph.sh [options]
  --episodes N         episodes to run (default 5; 0 = until Ctrl-C)
  --seed S             episode k uses seed S + k (default 0)
  --mode MODE          step_locked (default, deterministic) or real_time
  --rate-factor F      real_time: simulation speed relative to wall time (default 1.0)
  --policy P           sac (default: the shipped All policy), tactile_reactive or random
  --checkpoint PATH    policy file for --policy sac (default: the shipped policy)
  --without M          test-time ablation: zero modality M (T or V) for the policy
  --train-out DIR      learn online (SAC) while running; checkpoints and policy.pt go to DIR
  --train-config YAML  online training: dlo-train config file (SAC hyperparameters)
  --tactile-noise N    tactile sensitivity: none (default), partial or full
  --record DIR         record every /dlo topic to the rosbag2 (MCAP) directory DIR
  --logs DIR           node logs and the outcome file go here (default: a new temp dir)
  -h, --help           this help
EOF
}

episodes=5 seed=0 mode=step_locked rate=1.0 policy=sac checkpoint="" without="" noise=none record="" logs=""
train_out="" train_config=""
while [ $# -gt 0 ]; do
  case "$1" in
    --episodes) episodes="$2"; shift 2 ;;
    --seed) seed="$2"; shift 2 ;;
    --mode) mode="$2"; shift 2 ;;
    --rate-factor) rate="$2"; shift 2 ;;
    --policy) policy="$2"; shift 2 ;;
    --checkpoint) checkpoint="$2"; shift 2 ;;
    --without) without="$2"; shift 2 ;;
    --tactile-noise) noise="$2"; shift 2 ;;
    --record) record="$2"; shift 2 ;;
    --train-out) train_out="$2"; shift 2 ;;
    --train-config) train_config="$2"; shift 2 ;;
    --logs) logs="$2"; shift 2 ;;
    -h|--help) usage; exit 0 ;;
    *) echo "launch_graph: unknown option '$1'" >&2; usage >&2; exit 2 ;;
  esac
done
[[ "$episodes" =~ ^[0-9]+$ ]] || { echo "launch_graph: --episodes must be a number >= 0, got '$episodes'" >&2; exit 2; }
[[ "$seed" =~ ^[0-9]+$ ]] || { echo "launch_graph: --seed must be a number >= 0, got '$seed'" >&2; exit 2; }
case "$mode" in step_locked|real_time) ;; *) echo "launch_graph: --mode must be step_locked or real_time" >&2; exit 2 ;; esac
if [ -n "$record" ] && [ -e "$record" ]; then
  echo "launch_graph: --record $record already exists; choose a new directory" >&2; exit 2
fi

if command -v ros2 >/dev/null 2>&1 && [ -z "${DLO_USE_ROS2RUN:-}" ]; then
  RUN=(ros2 run)
else
  [ -n "${DLO_ROOT:-}" ] || { set +u; source "$ROOT/scripts/env.sh"; set -u; }
  RUN=("$ROOT/scripts/ros2run")
fi
logs="${logs:-$(mktemp -d -t dlo-graph-XXXXXX)}"
mkdir -p "$logs"
outcomes="$logs/outcomes.jsonl"
rm -f "$outcomes"

pids=() names=()
start() {  # start <name> <pkg> <exe> [ros args...]
  local name="$1"; shift
  "${RUN[@]}" "$@" > "$logs/$name.log" 2>&1 &
  pids+=("$!") names+=("$name")
  echo "[launch] $name (pid $!) -> $logs/$name.log"
}
stop_all() {
  trap - INT TERM
  for pid in "${pids[@]}"; do kill -INT "$pid" 2>/dev/null || true; done
  for pid in "${pids[@]}"; do
    for _ in $(seq 1 100); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
    kill -KILL "$pid" 2>/dev/null || true
    wait "$pid" 2>/dev/null || true
  done
}
trap 'echo "[launch] interrupted: stopping the graph"; stop_all; interrupted=1' INT TERM
interrupted=0

subscribers=3 sim_extra=()
if [ -n "$record" ]; then
  start recorder dlo_tools recorder_node --ros-args -p output:="$record" -p record_clock:=true \
    -p summary_file:="$logs/recorder_summary.json"
  subscribers=4 sim_extra=(-p wait_for_recorder:=recorder)  # the first episode is recorded whole
fi
start tactile dlo_perception tactile_node --ros-args -p noise:="$noise" -p seed:="$seed"
start vision dlo_perception vision_node
policy_args=(-p policy:="$policy")
[ -n "$checkpoint" ] && policy_args+=(-p checkpoint:="$checkpoint")
[ -n "$without" ] && policy_args+=(-p without:="$without")
[ -n "$train_out" ] && policy_args+=(-p train:=true -p train_out:="$train_out" -p seed:="$seed")
[ -n "$train_config" ] && policy_args+=(-p train_config:="$train_config")
start policy dlo_policy policy_node --ros-args "${policy_args[@]}"
start sim dlo_sim sim_node --ros-args -p mode:="$mode" -p seed:="$seed" -p episodes:="$episodes" \
  -p rate_factor:="$rate" -p min_subscribers:="$subscribers" -p summary_file:="$outcomes" \
  "${sim_extra[@]}"
sim_pid="${pids[-1]}"

set +e
while kill -0 "$sim_pid" 2>/dev/null && [ "$interrupted" = 0 ]; do
  for i in "${!pids[@]}"; do
    if ! kill -0 "${pids[$i]}" 2>/dev/null && [ "${pids[$i]}" != "$sim_pid" ]; then
      echo "[launch] ${names[$i]} exited early; the end of its log:" >&2
      tail -5 "$logs/${names[$i]}.log" >&2
      stop_all; interrupted=1; break
    fi
  done
  sleep 0.2
done
wait "$sim_pid" 2>/dev/null
sim_status=$?
set -e
[ "$interrupted" = 1 ] || stop_all

python -m dlo_tools.outcome_table "$outcomes"
[ -n "$record" ] && [ -f "$record/metadata.yaml" ] && echo "[launch] bag: $record (inspect: dlo-bag-info $record)"
[ "$interrupted" = 0 ] && exit "$sim_status" || exit 130
