"""dlo_common: what every dlo-vitac node shares (the lowest dlo_* package; imports no other).

- :mod:`dlo_common.params`: the parameter declaration record :class:`Param` and what is rendered
  from it (``--help`` text, a ROS 2 parameters YAML, a Markdown table); no ROS imports.
- :mod:`dlo_common.node_util`: declaring checked parameters on an rclpy node, start errors,
  signal handling.
- :mod:`dlo_common.node_main`: the shared ``main()`` body (``--help``, init, spin, shutdown, exit codes).
- :mod:`dlo_common.taichi_runtime`: the process's one Taichi runtime (backend choice, ``ti.init`` once),
  shared by the vision kernel and the simulator; Taichi is imported only when it starts.
- :mod:`dlo_common.topics`: the registry of the graph's topics and services (name, type, publisher,
  role, ...) that nodes and tools read instead of lists of their own; plain data, no ROS imports.
- :mod:`dlo_common.console`: what the console commands (dlo-train, dlo-evaluate, dlo-bag-info, ...) share about
  their output: a quiet end on a broken pipe or Ctrl-C (``console_main``), progress on stderr as a bar on a
  terminal and plain lines elsewhere (``Progress``); standard library only.
- :mod:`dlo_common.domains`: the DDS domains of this machine (busy ports, the directory of their locks) that the
  launcher and the tests share; standard library only. (The test harness is not here: tests/support/harness.py.)
"""
