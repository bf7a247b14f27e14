"""dlo_tools: rosbag2 MCAP recording, playback and bag inspection for the dlo-vitac graph.

Library modules (no rclpy): :mod:`dlo_tools.bag` (typestore, BagWriter, read_messages,
bag_info), :mod:`dlo_tools.recording` (Recorder), :mod:`dlo_tools.playback` (Pacer, message
classes). Nodes: ``recorder_node``, ``playback_node``; command: ``dlo-bag-info``.
"""
