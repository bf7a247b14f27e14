"""dlo_tools: rosbag2 MCAP recording, playback and bag inspection for the dlo-vitac graph.

Library modules (no rclpy): :mod:`dlo_tools.bag` (typestore, BagWriter, read_messages,
bag_info), :mod:`dlo_tools.mcap_file` (crash-safe MCAP writing, scanning damaged files),
:mod:`dlo_tools.recover` (dlo-bag-recover), :mod:`dlo_tools.recording` (Recorder),
:mod:`dlo_tools.playback` (Pacer, message classes). Nodes: ``recorder_node``, ``playback_node``;
commands: ``dlo-bag-info``, ``dlo-bag-recover``.
"""
