"""The contract of the dlo-vitac graph, pure Python (no Taichi, no rclpy): ``world``, ``sim_config``, ``command``,
``task``, ``grip``, ``camera``, ``cloud``, ``perturbations`` and ``simulator`` (the README lists what each states)."""
