#!/usr/bin/env bash
# Start the whole dlo-vitac graph (sim, tactile, vision, policy [, recorder]) as separate processes
# on a DDS domain of its own, wait until the sim has run its episodes (or Ctrl-C) while printing one
# line per finished episode and a periodic status line (dlo_viz.graph_monitor), stop every
# process it started, print the outcome table headed by what produced it; fail loudly (exit codes in --help) when a node dies
# or the recording fails. Uses `ros2 run` on a real ROS 2 install, scripts/ros2run with the wheels.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
EXIT_USAGE=2 EXIT_NODE_FAILED=3 EXIT_RECORDING_FAILED=4 EXIT_INTERRUPTED=130
usage() {
  cat <<EOF
usage: scripts/launch_graph.sh [options]
  --episodes N         episodes to run (default 5; 0 = until Ctrl-C)
  --seed S             episode k uses seed S + k (default 0)
  --mode MODE          step_locked (default, deterministic) or real_time
  --rate-factor F      real_time: simulation speed relative to wall time (default 1.0)
  --policy P           sac (default: the shipped All policy), tactile_reactive, oracle or random
  --checkpoint PATH    policy file for --policy sac (default: the shipped policy)
  --without M          test-time ablation: zero modality M (T or V) for the policy
  --train-out DIR      learn online (SAC) while running; checkpoints and policy.pt go to DIR
  --train-config YAML  online training: dlo-train config file (SAC hyperparameters)
  --tactile-noise N    tactile noise (the tactile node's tactile_noise parameter): none (default),
                       partial, full, or sigma_theta,sigma_y [rad, m] such as 0.1,0.001 (or [0.1,0.001])
  --task-rules R       authors_code or paper_text: the held set the reward, the episode's end and
                       the tactile input use (the sim's task_rules parameter). Default: what the
                       --policy sac checkpoint was trained on (its run's config.yaml), else authors_code
  --single-particle-grip [true|false]  the grip carries one particle, as the authors' code did (the
                       sim's single_particle_grip parameter; alone = true). Default: what the --policy sac
                       checkpoint was trained on (env_options.single_particle_grip), else false.
  --carry-law L        paper or authors: how the grip carries the cable (the sim's carry_law parameter)
  --contact-radius R   the cable's contact half-thickness [m], up to 0.006 (the sim's contact_radius)
  --vision-source S    image or particles: where the vision node's O_V comes from (its vision_source)
  --start-pose P       ours or authors: where the gripper starts (the sim's start_pose)
                       These four default to what the --policy sac checkpoint was trained on (its
                       env_options), else paper, 0.004, image and ours.
                       Settings that differ from the checkpoint's training are run as asked, with a note
  --record DIR         record every /dlo topic to the rosbag2 (MCAP) directory DIR
  --foxglove [PORT]    live view: also start the Foxglove bridge (dlo_viz foxglove_bridge) on
                       127.0.0.1:PORT (default 8765; 0 = any free port) and print the URL to open;
                       layout to import: docs/foxglove/dlo_vitac.json
  --logs DIR           node logs and the outcome file go here (default: a new temp dir)
  --status-period S    seconds between status lines while the graph runs (default 10; 0 = none)
  --domain-id N        run on ROS_DOMAIN_ID N (default: a free domain of its own, so that two
                       graphs on one machine never see each other; the chosen id is printed)
  --namespace NS       put every topic of the graph under /NS (/NS/dlo/..., /NS/clock): several
                       graphs can then share a domain deliberately (with --domain-id)
  -h, --help           this help

output (stdout): the chosen domain and each node's pid and log; while the graph runs one line per
finished episode ("[launch] episode 1/5 (seed 0): hold_the_end, authors' rule hold_the_end; return
4.321, 97 steps, 0 particles from the end") and every S s a status line ("[launch] status: 11.8
steps/s (sim time x0.94), 1/5 episodes done, nodes alive 4/4; policy: no tactile input"); at the end
a header naming the policy, checkpoint, ablation, tactile noise, mode, task rules and seeds, then the outcome
table (both outcome rules).

exit status:
  0    every episode ran (and the bag, with --record, is complete)
  2    bad option, or a node rejected its parameters
  3    a node died or exited early (also the sim interrupted on its own, or the sim refusing to
       start because another simulator publishes on the domain); the graph was stopped
  4    the recording failed (a write error such as a full disk, or the recorder died or dropped
       messages); the graph was stopped and the cause printed
  130  interrupted (Ctrl-C or SIGTERM to this script)
EOF
}

episodes=5 seed=0 mode=step_locked rate=1.0 policy=sac checkpoint="" without="" noise=none record="" logs=""
task_rules="" single_grip=""  # "" = as the sac checkpoint was trained (else authors_code, false)
carry_law="" contact_radius="" vision_source="" start_pose=""  # "" = as the sac checkpoint was trained
train_out="" train_config="" domain="" namespace="" foxglove="" status_period=10
while [ $# -gt 0 ]; do
  case "$1" in
    --episodes|--seed|--mode|--rate-factor|--policy|--checkpoint|--without|--tactile-noise|--record|\
    --task-rules|--train-out|--train-config|--logs|--domain-id|--namespace|--status-period|--carry-law|\
    --contact-radius|--vision-source|--start-pose)
      [ $# -ge 2 ] || { echo "launch_graph: $1 needs a value (options: scripts/launch_graph.sh --help)" >&2
                        exit $EXIT_USAGE; } ;;
  esac
  case "$1" in
    --episodes) episodes="$2"; shift 2 ;;
    --seed) seed="$2"; shift 2 ;;
    --mode) mode="$2"; shift 2 ;;
    --rate-factor) rate="$2"; shift 2 ;;
    --policy) policy="$2"; shift 2 ;;
    --checkpoint) checkpoint="$2"; shift 2 ;;
    --without) without="$2"; shift 2 ;;
    --tactile-noise) noise="$2"; shift 2 ;;
    --task-rules) task_rules="$2"; shift 2 ;;
    --carry-law) carry_law="$2"; shift 2 ;;
    --contact-radius) contact_radius="$2"; shift 2 ;;
    --vision-source) vision_source="$2"; shift 2 ;;
    --start-pose) start_pose="$2"; shift 2 ;;
    --single-particle-grip)
      if [[ "${2:-}" =~ ^(true|false)$ ]]; then single_grip="$2"; shift 2; else single_grip=true; shift; fi ;;
    --record) record="$2"; shift 2 ;;
    --train-out) train_out="$2"; shift 2 ;;
    --train-config) train_config="$2"; shift 2 ;;
    --logs) logs="$2"; shift 2 ;;
    --domain-id) domain="$2"; shift 2 ;;
    --namespace) namespace="$2"; shift 2 ;;
    --status-period) status_period="$2"; shift 2 ;;
    --foxglove)
      if [[ "${2:-}" =~ ^[0-9]+$ ]]; then foxglove="$2"; shift 2; else foxglove=8765; shift; fi ;;
    -h|--help) usage; exit 0 ;;
    *) echo "launch_graph: unknown option '$1' (options: scripts/launch_graph.sh --help)" >&2; exit $EXIT_USAGE ;;
  esac
done
bad() { echo "launch_graph: $*" >&2; exit $EXIT_USAGE; }
[[ "$episodes" =~ ^[0-9]+$ ]] || bad "--episodes must be a number >= 0, got '$episodes'"
[[ "$seed" =~ ^[0-9]+$ ]] || bad "--seed must be a number >= 0, got '$seed'"
case "$mode" in step_locked|real_time) ;; *) bad "--mode must be step_locked or real_time" ;; esac
case "$task_rules" in ""|paper_text|authors_code) ;; *) bad "--task-rules must be paper_text or authors_code, got '$task_rules'" ;; esac
case "$carry_law" in ""|paper|authors) ;; *) bad "--carry-law must be paper or authors, got '$carry_law'" ;; esac
case "$start_pose" in ""|ours|authors) ;; *) bad "--start-pose must be ours or authors, got '$start_pose'" ;; esac
case "$vision_source" in ""|image|particles) ;; *) bad "--vision-source must be image or particles, got '$vision_source'" ;; esac
if [ -n "$contact_radius" ] && ! awk -v r="$contact_radius" 'BEGIN { exit !(r ~ /^[0-9]*[.]?[0-9]+$/ && r + 0 > 0 && r + 0 <= 0.006) }'; then
  bad "--contact-radius must be a number in (0, 0.006] m, got '$contact_radius'"
fi
case "$policy" in sac|tactile_reactive|oracle|random) ;;
  *) bad "--policy must be one of sac, tactile_reactive, oracle, random, got '$policy'" ;; esac
if [ -n "$checkpoint" ] && [ ! -f "$checkpoint" ]; then bad "--checkpoint $checkpoint: no such file"; fi
[[ "$status_period" =~ ^[0-9]+([.][0-9]+)?$ ]] || bad "--status-period must be a number of seconds >= 0, got '$status_period'"
if [ -n "$domain" ]; then
  [[ "$domain" =~ ^[0-9]+$ ]] && [ "$domain" -le 232 ] || bad "--domain-id must be a number in 0..232, got '$domain'"
fi
namespace="${namespace#/}" namespace="${namespace%/}"
if [ -n "$namespace" ] && ! [[ "$namespace" =~ ^[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*$ ]]; then
  bad "--namespace must be a ROS name like 'robot1' or 'lab/robot1', got '$namespace'"
fi
if [ -n "$foxglove" ] && [ "$foxglove" -gt 65535 ]; then
  bad "--foxglove PORT must be in 0..65535, got '$foxglove'"
fi
if [ -n "$record" ] && [ -e "$record" ]; then
  bad "--record $record already exists; choose a new directory"
fi

if command -v ros2 >/dev/null 2>&1 && [ -z "${DLO_USE_ROS2RUN:-}" ]; then
  RUN=(ros2 run)
else
  [ -n "${DLO_ROOT:-}" ] || { set +u; source "$ROOT/scripts/env.sh"; set -u; }
  RUN=("$ROOT/scripts/ros2run")
fi
PY="$(command -v python || command -v python3)"
# the tactile noise as the env and the tactile node read it (dlo_perception.tactile.noise_setting), checked
# before anything starts; its -p form goes to the node, and names it in the run header
if ! noise_check="$("$PY" -m dlo_perception.tactile --check-noise="$noise" 2>&1)"; then
  noise_check="${noise_check##*$'\n'}"
  bad "--tactile-noise: ${noise_check#tactile noise: }"
fi
noise="${noise_check##*$'\n'}"  # its last line (stdout comes last)
# --without: modalities of the registry (dlo_policy.modalities) joined by '+', checked before anything starts
if [ -n "$without" ] && ! without_check="$("$PY" -m dlo_policy.modalities --check-without="$without" 2>&1)"; then
  bad "${without_check##*$'\n'}"
fi
# --policy sac: the sim runs the task the checkpoint was trained on (task rules, grip: its run's config.yaml)
# unless told otherwise; a setting that differs from its training is run as asked and said
if [ "$policy" = sac ] && [ -z "$train_out" ]; then
  trained="$("$PY" -m dlo_policy.rundir --sim-settings "$checkpoint" 2>&1)" || bad "--checkpoint: ${trained##*$'\n'}"
  trained="${trained##*$'\n'}"
  if [ "$trained" != unknown ]; then
    read -r trained_rules trained_grip trained_carry trained_contact trained_vision trained_start <<<"$trained"
    task_rules="${task_rules:-$trained_rules}" single_grip="${single_grip:-$trained_grip}"
    carry_law="${carry_law:-$trained_carry}" contact_radius="${contact_radius:-$trained_contact}"
    vision_source="${vision_source:-$trained_vision}" start_pose="${start_pose:-$trained_start}"
    if [ "$carry_law" != "$trained_carry" ] || [ "$contact_radius" != "$trained_contact" ] || [ "$vision_source" != "$trained_vision" ] || [ "$start_pose" != "$trained_start" ]; then
      echo "[launch] note: the policy was trained with carry_law=$trained_carry, contact_radius=$trained_contact, vision_source=$trained_vision, start_pose=$trained_start; this graph runs carry_law=$carry_law, contact_radius=$contact_radius, vision_source=$vision_source, start_pose=$start_pose (as asked)" >&2
    fi
    if [ "$task_rules" != "$trained_rules" ] || [ "$single_grip" != "$trained_grip" ]; then
      echo "[launch] note: the policy was trained with task_rules=$trained_rules, single_particle_grip=$trained_grip; this graph runs task_rules=$task_rules, single_particle_grip=$single_grip (as asked)" >&2
    fi
  fi
fi
task_rules="${task_rules:-authors_code}" single_grip="${single_grip:-false}"
carry_law="${carry_law:-paper}" contact_radius="${contact_radius:-0.004}" vision_source="${vision_source:-image}"
start_pose="${start_pose:-ours}"
monitor_pid=""
logs="${logs:-$(mktemp -d -t dlo-graph-XXXXXX)}"
mkdir -p "$logs"
outcomes="$logs/outcomes.jsonl"
rm -f "$outcomes"

# ---- a DDS domain of its own ---------------------------------------------------------------
# A domain is busy when a participant on this machine has bound one of its UDP ports (RTPS:
# 7400 + 250 * domain + 0..249); a lock per domain keeps two launchers starting at the same
# moment apart. The lock is held (inherited by the nodes) while the graph runs. Tests lock theirs
# in the same directory (dlo_common.testing.reserve_domains, domains 100..232).
domain_busy() {
  local lo=$((7400 + 250 * $1)) hi=$((7400 + 250 * $1 + 249)) f local_address port
  for f in /proc/net/udp /proc/net/udp6; do
    [ -r "$f" ] || continue
    while read -r _ local_address _; do
      port="${local_address##*:}"
      [[ "$port" =~ ^[0-9A-Fa-f]{4}$ ]] || continue
      port=$((16#$port))
      if [ "$port" -ge "$lo" ] && [ "$port" -le "$hi" ]; then return 0; fi
    done < "$f"
  done
  return 1
}
lockdir="${XDG_RUNTIME_DIR:-/tmp}/dlo-vitac-domains-$(id -u)"
lock_domain() {  # lock_domain N: hold the lock of domain N (false if another launcher holds it)
  command -v flock >/dev/null 2>&1 || return 0
  mkdir -p "$lockdir" 2>/dev/null || return 0
  exec {domain_lock}>>"$lockdir/$1.lock"
  if flock -n "$domain_lock"; then return 0; fi
  exec {domain_lock}>&-
  return 1
}
if [ -n "$domain" ]; then
  lock_domain "$domain" || echo "[launch] warning: ROS_DOMAIN_ID=$domain is held by another launch_graph.sh or test run" >&2
  [ -n "$namespace" ] || ! domain_busy "$domain" || \
    echo "[launch] warning: ROS_DOMAIN_ID=$domain is in use on this machine; without --namespace the graphs' topics mix (the sim refuses to start next to another simulator)" >&2
else
  start_at=$((RANDOM % 90))
  for ((i = 0; i < 90; i++)); do
    d=$(( (start_at + i) % 90 + 10 ))  # 10..99: not 0 (the default), below the ephemeral ports
    if ! domain_busy "$d" && lock_domain "$d"; then domain="$d"; break; fi
  done
  [ -n "$domain" ] || { echo "launch_graph: no free ROS_DOMAIN_ID in 10..99 on this machine; give --domain-id N" >&2; exit $EXIT_USAGE; }
fi
export ROS_DOMAIN_ID="$domain"
prefix="${namespace:+/$namespace}"
echo "[launch] ROS_DOMAIN_ID=$domain${namespace:+, topics under $prefix/} (to watch: ROS_DOMAIN_ID=$domain ros2 topic list)"

remap=()
if [ -n "$namespace" ]; then
  # every topic and service of the graph (the registry, dlo_common.topics)
  mapfile -t graph_names < <("$PY" -m dlo_common.topics --names)
  [ "${#graph_names[@]}" -gt 0 ] || { echo "launch_graph: python -m dlo_common.topics --names gave no names" >&2; exit 1; }
  for t in "${graph_names[@]}"; do
    remap+=(-r "$t:=$prefix$t")
  done
fi

# ---- processes -----------------------------------------------------------------------------
pids=() names=()
declare -A status=()
# A node gets SIGINT (and closes cleanly) if this script dies without stopping it (e.g. SIGKILL).
ORPHAN=()
if command -v setpriv >/dev/null 2>&1 && setpriv --pdeathsig INT true 2>/dev/null; then ORPHAN=(setpriv --pdeathsig INT --); fi
# A background job of this script starts with SIGINT ignored, and a node keeps it so until rclpy.init sets its
# handlers: a Ctrl-C while a node still starts (imports) would be lost and the node killed 10 s later. Each node
# starts with SIGINT at its default instead (GNU env >= 8.31): interrupted while it imports, it ends there.
SIGINT_DEFAULT=()
if env --default-signal=INT true 2>/dev/null; then SIGINT_DEFAULT=(env --default-signal=INT); fi
start() {  # start <name> <pkg> <exe> [ros args...]
  local name="$1"; shift
  ${ORPHAN[@]+"${ORPHAN[@]}"} ${SIGINT_DEFAULT[@]+"${SIGINT_DEFAULT[@]}"} "${RUN[@]}" "$@" > "$logs/$name.log" 2>&1 &
  pids+=("$!") names+=("$name")
  echo "[launch] $name (pid $!) -> $logs/$name.log"
}
describe() {  # describe <exit status>: 130 is what a node returns when interrupted, or SIGINT's status
  local sig
  case "$1" in
    130) echo "status 130: interrupted by SIGINT" ;;
    13[1-9]|1[4-9][0-9]|2[0-5][0-9])
      sig="$(kill -l $(($1 - 128)) 2>/dev/null || echo $(($1 - 128)))"
      echo "status $1: killed by SIG$sig" ;;
    *) echo "status $1" ;;
  esac
}
show_log_end() {  # show_log_end <name>
  local log="$logs/$1.log"
  if [ -s "$log" ]; then tail -n 8 "$log" | sed 's/^/    /' >&2
  else echo "    (its log $log is empty)" >&2; fi
}
reap() {  # reap <index>: record the exit status of a process that ended
  local name="${names[$1]}"
  if [ -z "${status[$name]+x}" ]; then
    wait "${pids[$1]}" 2>/dev/null && status[$name]=0 || status[$name]=$?
  fi
}
stop_all() {
  trap - INT TERM
  local i pid
  for pid in "${pids[@]}"; do kill -INT "$pid" 2>/dev/null || true; done
  for i in "${!pids[@]}"; do
    pid="${pids[$i]}"
    for _ in $(seq 1 100); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
    if kill -0 "$pid" 2>/dev/null; then
      echo "[launch] ${names[$i]} did not stop within 10 s of SIGINT: killing it" >&2
      kill -KILL "$pid" 2>/dev/null || true
    fi
    reap "$i"
  done
}
# The monitor stops first: it prints the episodes that finished meanwhile and no status line about nodes
# being stopped.
stop_monitor() {
  [ -n "$monitor_pid" ] || return 0
  kill -TERM "$monitor_pid" 2>/dev/null || true
  for _ in $(seq 1 50); do kill -0 "$monitor_pid" 2>/dev/null || break; sleep 0.1; done
  kill -KILL "$monitor_pid" 2>/dev/null || true
  wait "$monitor_pid" 2>/dev/null || true
  monitor_pid=""
}
# The sim first (no episode runs on while the monitor stops: a failed recorder loses nothing more),
# then the monitor, then every node.
stop_graph() {
  [ -z "${sim_pid:-}" ] || kill -INT "$sim_pid" 2>/dev/null
  stop_monitor
  stop_all
}
trap 'echo "[launch] interrupted: stopping the graph"; stop_graph; interrupted=1' INT TERM
interrupted=0

subscribers=3 sim_extra=()
[ -z "$record" ] || subscribers=4 sim_extra=(-p wait_for_recorder:=recorder)  # the first episode is recorded whole
# The sim first: it refuses to start next to another simulator on this domain; nothing else of this graph
# starts before it has looked (no second graph's nodes answering, publishing or recording into the first).
start sim dlo_sim sim_node --ros-args -p mode:="$mode" -p seed:="$seed" -p episodes:="$episodes" \
  -p rate_factor:="$rate" -p min_subscribers:="$subscribers" -p summary_file:="$outcomes" -p task_rules:="$task_rules" \
  -p single_particle_grip:="$single_grip" -p carry_law:="$carry_law" -p contact_radius:="$contact_radius" \
  -p start_pose:="$start_pose" \
  ${sim_extra[@]+"${sim_extra[@]}"} ${remap[@]+"${remap[@]}"}
sim_index=0
sim_pid="${pids[0]}"
for _ in $(seq 1 1200); do
  grep -q "alone on ROS_DOMAIN_ID" "$logs/sim.log" 2>/dev/null && break
  kill -0 "$sim_pid" 2>/dev/null || break
  [ "$interrupted" = 0 ] || break
  sleep 0.1
done
if kill -0 "$sim_pid" 2>/dev/null && [ "$interrupted" = 0 ]; then
if [ -n "$record" ]; then
  if [ -n "$namespace" ]; then rec_topics=(-p namespace:="$prefix"); else rec_topics=(-p record_clock:=true); fi
  start recorder dlo_bag recorder_node --ros-args -p output:="$record" "${rec_topics[@]}" \
    -p summary_file:="$logs/recorder_summary.json" ${remap[@]+"${remap[@]}"}
fi
if [ -n "$foxglove" ]; then
  start foxglove dlo_viz foxglove_bridge --ros-args -p port:="$foxglove" -p address:=127.0.0.1 \
    -p topics:="$prefix/dlo,$prefix/clock"
  for _ in $(seq 1 300); do  # its first lines name the URL (a port in use ends it: reported below)
    grep -q "Foxglove bridge on ws://" "$logs/foxglove.log" 2>/dev/null && break
    kill -0 "${pids[-1]}" 2>/dev/null || break
    sleep 0.1
  done
  url="$(grep -m1 -o "open https://[^ ]*" "$logs/foxglove.log" 2>/dev/null | cut -c6- || true)"
  ws="$(grep -m1 -o "ws://[0-9.]*:[0-9]*" "$logs/foxglove.log" 2>/dev/null || true)"
  if [ -n "$url" ]; then
    echo "[launch] Foxglove live view: open $url"
    echo "[launch]   (Foxglove app: Open connection -> Foxglove WebSocket -> $ws; layout: $ROOT/docs/foxglove/dlo_vitac.json)"
  fi
fi
start tactile dlo_perception tactile_node --ros-args -p tactile_noise:="$noise" -p seed:="$seed" ${remap[@]+"${remap[@]}"}
start vision dlo_perception vision_node --ros-args -p vision_source:="$vision_source" ${remap[@]+"${remap[@]}"}
policy_args=(-p policy:="$policy")
[ -n "$checkpoint" ] && policy_args+=(-p checkpoint:="$checkpoint")
[ -n "$without" ] && policy_args+=(-p without:="$without")
[ -n "$train_out" ] && policy_args+=(-p train:=true -p train_out:="$train_out" -p seed:="$seed")
[ -n "$train_config" ] && policy_args+=(-p train_config:="$train_config")
start policy dlo_policy policy_node --ros-args "${policy_args[@]}" ${remap[@]+"${remap[@]}"}
# finished episodes and a status line while the graph runs (not a node of the graph: its end fails nothing)
monitor_args=(--logs "$logs" --episodes "$episodes" --status-period "$status_period" --clock-topic "$prefix/clock")
for i in "${!pids[@]}"; do monitor_args+=(--node "${names[$i]}=${pids[$i]}"); done
${ORPHAN[@]+"${ORPHAN[@]}"} "$PY" -m dlo_viz.graph_monitor "$outcomes" "${monitor_args[@]}" &
monitor_pid=$!
fi

# ---- watch ---------------------------------------------------------------------------------
set +e
failed_node="" rc=0
while kill -0 "$sim_pid" 2>/dev/null && [ "$interrupted" = 0 ] && [ -z "$failed_node" ]; do
  for i in "${!pids[@]}"; do
    [ "$i" = "$sim_index" ] && continue
    if ! kill -0 "${pids[$i]}" 2>/dev/null; then
      reap "$i"
      failed_node="${names[$i]}"
      break
    fi
  done
  [ -n "$failed_node" ] || sleep 0.2
done
kill -0 "$sim_pid" 2>/dev/null || reap "$sim_index"  # (a sim still running is stopped and reaped by stop_all)
[ "$interrupted" = 1 ] || stop_graph

done_episodes=0
[ -f "$outcomes" ] && done_episodes=$(grep -c . "$outcomes")
recorder_failure() {  # the one-line cause the recorder logged, if any
  grep -m1 -o "recording failed: [^(;]*" "$logs/recorder.log" 2>/dev/null | sed 's/ *$//'
}
if [ "$interrupted" = 1 ]; then
  rc=$EXIT_INTERRUPTED
elif [ -n "$failed_node" ]; then
  st="${status[$failed_node]}"
  if [ "$failed_node" = recorder ] && [ -n "$(recorder_failure)" ]; then
    echo "[launch] $(recorder_failure): the recorder stopped ($(describe "$st")); graph stopped" >&2
    rc=$EXIT_RECORDING_FAILED
  else
    echo "[launch] $failed_node exited early ($(describe "$st")); the end of its log:" >&2
    show_log_end "$failed_node"
    if [ "$failed_node" = recorder ]; then rc=$EXIT_RECORDING_FAILED
    elif [ "$st" = 2 ]; then rc=$EXIT_USAGE
    else rc=$EXIT_NODE_FAILED; fi
  fi
else
  st="${status[sim]}"
  if [ "$st" = 0 ] && [ "$episodes" != 0 ] && [ "$done_episodes" -ge "$episodes" ]; then
    rc=0
  else
    of="$episodes"; [ "$episodes" != 0 ] || of="unlimited"
    echo "[launch] sim exited early ($(describe "$st"), $done_episodes of $of episodes done); the end of its log:" >&2
    show_log_end sim
    if [ "$st" = 2 ]; then rc=$EXIT_USAGE; else rc=$EXIT_NODE_FAILED; fi
  fi
fi

policy_line="$(grep -m1 -o "policy [a-z_]* on [^;]*" "$logs/policy.log" 2>/dev/null || true)"
"$PY" -m dlo_bag.outcome_table "$outcomes" --policy "$policy" --checkpoint "$checkpoint" --without "$without" \
  --tactile-noise "$noise" --mode "$mode" --train-out "$train_out" --policy-line "$policy_line" || true
if [ -n "$record" ]; then
  rst="${status[recorder]:-}"
  cause="$(recorder_failure)"
  if [ -n "$cause" ]; then
    [ "$failed_node" = recorder ] || echo "[launch] $cause (see $logs/recorder.log)" >&2
    [ "$rc" = "$EXIT_INTERRUPTED" ] || rc=$EXIT_RECORDING_FAILED
  elif [ "$rst" = 1 ]; then
    echo "[launch] recording incomplete: the recorder dropped messages (see $logs/recorder.log)" >&2
    [ "$rc" = "$EXIT_INTERRUPTED" ] || rc=$EXIT_RECORDING_FAILED
  elif [ -n "$rst" ] && [ "$rst" != 0 ] && [ "$failed_node" != recorder ] \
      && ! { [ "$rc" = "$EXIT_INTERRUPTED" ] && [ "$rst" = 130 ]; }; then  # (130 when interrupted: still starting)
    echo "[launch] the recorder ended with $(describe "$rst"); the end of its log:" >&2
    show_log_end recorder
    [ "$rc" = "$EXIT_INTERRUPTED" ] || rc=$EXIT_RECORDING_FAILED
  fi
  if [ -f "$record/metadata.yaml" ] || compgen -G "$record/*/metadata.yaml" >/dev/null; then
    echo "[launch] bag: $record (inspect: dlo-bag-info $record)"
  elif [ -e "$record" ]; then
    echo "[launch] the bag $record is incomplete: recover it with: dlo-bag-recover $record" >&2
    [ "$rc" = "$EXIT_INTERRUPTED" ] || rc=$EXIT_RECORDING_FAILED
  fi
fi
exit "$rc"
