"""dlo_viz: live view of a running dlo-vitac graph.

:mod:`dlo_viz.foxglove_bridge` (the Foxglove WebSocket server, no rclpy) and its node
``foxglove_bridge`` (:mod:`dlo_viz.foxglove_bridge_node`); :mod:`dlo_viz.foxglove_layout` (the
Foxglove layout ``docs/foxglove/dlo_vitac.json``); :mod:`dlo_viz.graph_monitor` (what the
launcher's status line reads: the nodes' logs, the steps on /clock).
"""
