#!/usr/bin/env bash
# Container entry point: make ROS 2 Jazzy and the NeHMO workspace available, then run the command.
set -e
# The setup files read unset variables, so they are sourced without `set -u`.
source /opt/ros/jazzy/setup.bash
source /ws/ros_ws/install/setup.bash
exec "$@"
