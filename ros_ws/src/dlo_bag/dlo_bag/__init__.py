"""dlo_bag: rosbag2 MCAP recording, playback, recovery, inspection and analysis for the dlo-vitac graph.

Library modules (no rclpy): :mod:`dlo_bag.bag` (typestore, BagWriter, read_messages,
bag_info), :mod:`dlo_bag.mcap_file` (crash-safe MCAP writing, scanning damaged files),
:mod:`dlo_bag.recover` (dlo-bag-recover), :mod:`dlo_bag.recording` (Recorder),
:mod:`dlo_bag.playback` (Pacer, message classes), :mod:`dlo_bag.analysis` (dlo-analyze),
:mod:`dlo_bag.episode_series` and :mod:`dlo_bag.video` (an episode's arrays, plots and videos),
:mod:`dlo_bag.outcome_table` (the outcome table of a graph run). Nodes: ``recorder_node``,
``playback_node``; commands: ``dlo-bag-info``, ``dlo-bag-recover``, ``dlo-analyze``.
"""
