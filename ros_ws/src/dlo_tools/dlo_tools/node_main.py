"""The ``main()`` body every dlo node shares: init, build, spin, clean shutdown, clear errors."""

from __future__ import annotations

import sys
from collections.abc import Callable

import rclpy
from rclpy.executors import ExternalShutdownException

from dlo_tools.node_util import ParameterError


def run_node(make_node: Callable[[], "rclpy.node.Node"], args=None) -> int:
    """Spin the node ``make_node()`` builds until SIGINT/SIGTERM; exit code 2 on a bad parameter."""
    rclpy.init(args=args)
    node = None
    try:
        node = make_node()
        rclpy.spin(node)
    except ParameterError as error:
        print(f"[{getattr(node, 'get_name', lambda: 'node')()}] bad parameter: {error}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
