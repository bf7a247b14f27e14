#!/usr/bin/env bash
# Start the whole dlo-vitac graph (sim, tactile, vision, policy [, recorder, Foxglove bridge]) on a DDS domain of its
# own, print its episodes and status while it runs, stop it, print the outcome table; exit codes and options in
# --help. The launcher is Python: dlo_bringup.launcher (ros2 run dlo_bringup launch_graph), the graph it starts
# dlo_bringup.graph (also behind `ros2 launch dlo_bringup graph.launch.py`). This sets up the environment for it.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
# The wheels (no ros2 on PATH, or DLO_USE_ROS2RUN set: nodes run with scripts/ros2run): python, rclpy and the
# workspace come from scripts/env.sh. A real ROS 2 install has them from its setup.bash.
if [ -z "${DLO_ROOT:-}" ] && [ -f "$ROOT/scripts/env.sh" ] \
    && { ! command -v ros2 >/dev/null 2>&1 || [ -n "${DLO_USE_ROS2RUN:-}" ]; }; then
  set +u; source "$ROOT/scripts/env.sh"; set -u
fi
export DLO_ROOT="${DLO_ROOT:-$ROOT}"
# its sources first: --help and a bad option are answered also before scripts/setup.sh has run
export PYTHONPATH="$ROOT/ros_ws/src/dlo_bringup${PYTHONPATH:+:$PYTHONPATH}"
exec "$(command -v python || command -v python3)" -m dlo_bringup.launcher "$@"
