"""The ``main()`` body every dlo node shares: ``--help``, init, build, spin, clean shutdown, clear errors."""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Sequence

import rclpy
from rclpy.executors import ExternalShutdownException

from dlo_common.node_util import NodeStartError, ParameterError
from dlo_common.params import Param, help_requested, help_text, unexpected_arguments

EXIT_BAD_PARAMETER = 2
EXIT_REFUSED = 3
EXIT_CODES = "0 done or stopped by a signal, 2 bad parameter, 3 refused to start"


def executable_name() -> str:
    """The running executable's name (``sim_node``), also under ``python -m`` (``sim_node.py``)."""
    name = os.path.basename(sys.argv[0]) or "node"
    return name[:-3] if name.endswith(".py") else name


def installed_params_file(package: str, executable: str) -> str:
    """The installed ``share/<package>/config/<executable>.yaml`` (first prefix of AMENT_PREFIX_PATH
    that has it, as ``ros2 run`` finds packages), or '' when it is not installed."""
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        path = os.path.join(prefix, "share", package, "config", f"{executable}.yaml")
        if prefix and os.path.isfile(path):
            return path
    return ""


def handle_help(package: str, parameters: Sequence[Param | tuple], summary: str = "",
                args: Sequence[str] | None = None, exit_codes: str = EXIT_CODES) -> int | None:
    """Answer ``-h``/``--help`` (print the parameters, return 0) or a stray argument before
    ``--ros-args`` (one line, return 2); None when the node should start.

    Call it first in a node's ``main()``: it needs no ``rclpy.init``, creates no node and no file.
    ``args`` defaults to ``sys.argv[1:]`` (stray arguments are only checked there); ``summary`` is what the node does (its module docstring).
    """
    argv = list(sys.argv[1:] if args is None else args)
    executable = executable_name()
    if help_requested(argv):
        sys.stdout.write(help_text(package, executable, parameters, summary, exit_codes,
                                   installed_params_file(package, executable)))
        sys.stdout.flush()
        return 0
    stray = unexpected_arguments(argv) if args is None else []  # explicit args may start with a program name
    if stray:
        print(f"{executable}: unexpected argument {stray[0]!r} (parameters go after --ros-args: "
              f"-p NAME:=VALUE; see '{executable} --help')", file=sys.stderr)
        return EXIT_BAD_PARAMETER
    return None


def run_node(make_node: Callable[[], "rclpy.node.Node"], args=None, *, interrupted_rc: int = 0,
             parameters: Sequence[Param | tuple] | None = None, summary: str = "") -> int:
    """Spin the node ``make_node()`` builds until SIGINT/SIGTERM (exit code ``interrupted_rc``).

    With ``parameters`` (the node module's ``PARAMETERS``), ``-h``/``--help`` first prints them
    and returns 0 before anything starts (:func:`handle_help`; ``summary``: the module docstring).

    Exit code 2 and one line on a bad parameter, 3 and one line when the node refuses to start or
    go on (:class:`NodeStartError`); never a traceback for a signal, also one that arrives while a
    callback runs or while the node is being built.
    """
    if parameters is not None:
        module = getattr(make_node, "__module__", "dlo")
        if module == "__main__":  # python -m dlo_sim.sim_node
            module = getattr(sys.modules["__main__"].__spec__, "name", "dlo")
        package = module.split(".")[0]
        exit_codes = EXIT_CODES.replace("signal", "signal" if interrupted_rc == 0 else f"signal ({interrupted_rc})")
        answered = handle_help(package, parameters, summary, args, exit_codes)
        if answered is not None:
            return answered
    rclpy.init(args=args)
    node = None
    name = executable_name()  # the executable, until the node has its name
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
