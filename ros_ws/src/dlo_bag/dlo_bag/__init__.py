"""dlo_bag: rosbag2 MCAP recording, playback, recovery, inspection and analysis for the dlo-vitac graph.

Library modules (no rclpy), the bag library one module per concern as rosbag2's: :mod:`dlo_bag.typestore`,
:mod:`dlo_bag.qos`, :mod:`dlo_bag.metadata`, :mod:`dlo_bag.writer` (BagWriter), :mod:`dlo_bag.reader`
(read_messages), :mod:`dlo_bag.info` (bag_info), :mod:`dlo_bag.errors` (BagError, exit codes); then
:mod:`dlo_bag.mcap_file` (crash-safe MCAP writing, scanning damaged files),
:mod:`dlo_bag.recover` (dlo-bag-recover), :mod:`dlo_bag.recording` (Recorder),
:mod:`dlo_bag.playback` (Pacer, message classes), :mod:`dlo_bag.analysis` (dlo-analyze),
:mod:`dlo_bag.episode_series` and :mod:`dlo_bag.video` (an episode's arrays, plots and videos),
:mod:`dlo_bag.outcome_table` (the outcome table of a graph run). Nodes: ``recorder_node``,
``playback_node``; commands: ``dlo-bag-info``, ``dlo-bag-recover``, ``dlo-analyze``.
"""
