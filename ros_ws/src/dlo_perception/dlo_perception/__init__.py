"""Tactile and top-view vision distillation of the cable pose, and their ROS 2 nodes."""
