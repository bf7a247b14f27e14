"""Gymnasium environment, Soft Actor-Critic training and evaluation, scripted baselines, and the ROS 2 policy node."""
