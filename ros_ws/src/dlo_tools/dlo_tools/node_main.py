"""The ``main()`` body every dlo node shares: init, build, spin, clean shutdown, clear errors."""

from __future__ import annotations

import os
import sys
from collections.abc import Callable

import rclpy
from rclpy.executors import ExternalShutdownException

from dlo_tools.node_util import NodeStartError, ParameterError

EXIT_BAD_PARAMETER = 2
EXIT_REFUSED = 3


def run_node(make_node: Callable[[], "rclpy.node.Node"], args=None, *, interrupted_rc: int = 0) -> int:
    """Spin the node ``make_node()`` builds until SIGINT/SIGTERM (exit code ``interrupted_rc``).

    Exit code 2 and one line on a bad parameter, 3 and one line when the node refuses to start or
    go on (:class:`NodeStartError`); never a traceback for a signal, also one that arrives while a
    callback runs or while the node is being built.
    """
    rclpy.init(args=args)
    node = None
    name = os.path.basename(sys.argv[0]) or "node"  # the executable, until the node has its name
    rc = 0
    try:
        node = make_node()
        name = node.get_name()
        rclpy.spin(node)
        rc = interrupted_rc  # spin returns when a signal has shut the context down
    except ParameterError as error:
        print(f"[{name}] bad parameter: {error}", file=sys.stderr)
        rc = EXIT_BAD_PARAMETER
    except NodeStartError as error:
        print(f"[{name}] {error}", file=sys.stderr)
        rc = EXIT_REFUSED
    except (KeyboardInterrupt, ExternalShutdownException):
        rc = interrupted_rc
    except Exception:
        if rclpy.ok():
            raise
        rc = interrupted_rc  # the context was shut down by a signal while a callback ran (RCLError)
    finally:
        if node is not None:
            try:
                node.destroy_node()
            except Exception:  # noqa: BLE001 - already torn down by the signal's shutdown
                pass
        rclpy.try_shutdown()
    return rc
