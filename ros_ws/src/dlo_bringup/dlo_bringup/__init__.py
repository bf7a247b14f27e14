"""dlo_bringup: starts the dlo-vitac graph.

- :mod:`dlo_bringup.graph`: the one description of the graph (:func:`graph_nodes`: nodes, parameters, remappings,
  start order) for given options.
- :mod:`dlo_bringup.options`: the options (the launcher's command line, the launch file's arguments), checked and
  resolved.
- :mod:`dlo_bringup.launcher`: ``scripts/launch_graph.sh`` (``ros2 run dlo_bringup launch_graph``): a free DDS
  domain of its own, start, supervision and stop of the nodes, episode and status lines, the outcome table, exit
  codes.
- :mod:`dlo_bringup.graph_monitor`: the episode and status lines; the /clock step counter the launcher runs.
- ``launch/graph.launch.py``: the same graph for ``ros2 launch dlo_bringup graph.launch.py`` (a real ROS 2 install).
"""
