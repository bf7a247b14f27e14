#!/bin/bash
# Source ROS 2 Jazzy and the dlo-vitac workspace, then run the given command.
set -e
source /opt/ros/jazzy/setup.bash
source /dlo-vitac/ros_ws/install/setup.bash
exec "$@"
