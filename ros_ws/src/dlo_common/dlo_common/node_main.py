"""The ``main()`` body every dlo node shares: ``--help``, init, build, spin, clean shutdown, clear errors."""

from __future__ import annotations

import faulthandler
import os
import re
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.utilities import remove_ros_args

from dlo_common.node_util import NodeStartError, ParameterError, UnknownParameterError
from dlo_common.params import Param, help_requested, help_text, unexpected_arguments, yaml_problem

EXIT_FAILED = 1  # an error the node did not expect (a traceback), or a middleware teardown cut short (stacks)
EXIT_BAD_PARAMETER = 2
EXIT_REFUSED = 3
EXIT_CODES = "0 done or stopped by a signal, 1 failed (see stderr), 2 bad parameter, 3 refused to start"
TEARDOWN_LIMIT = 10.0  # s: a middleware teardown (DDS participant destruction) still running this long ends the process
FORCE_AFTER = 2.0  # s: a SIGINT this long after the first interrupts a callback that is still running
SPIN_TIMEOUT = 0.1  # s: the longest a node waits for work before it looks whether it was told to stop


class SecondInterrupt(KeyboardInterrupt):
    """A SIGINT ``FORCE_AFTER`` s or more after the first, raised where the node is stuck."""


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


PARAMS_FILE_LAYOUT = "expected '/**:' (or the node's name), then '  ros__parameters:', then '    NAME: VALUE'"
_RCL_LOCATION = re.compile(r",? at /\S+:\d+")  # rcl's ", at /project/src/parse.c:806" source locations
_LINE = re.compile(r" (?:at|near) line(?:_num)? \d+")  # rcl's " at line 3" / " at line_num 3"


def params_files(argv: Sequence[str]) -> list[str]:
    """The files of ``--params-file FILE`` in the ``--ros-args`` parts of ``argv``."""
    files, in_ros = [], False
    for i, arg in enumerate(argv):
        if arg == "--ros-args":
            in_ros = True
        elif arg == "--":
            in_ros = False
        elif in_ros and arg == "--params-file" and i + 1 < len(argv):
            files.append(argv[i + 1])
    return files


def params_file_problem(path: str) -> str:
    """What is wrong with a params file before rcl reads it (missing, unreadable, not YAML, not a
    mapping), in a few words; '' when rcl may read it."""
    if not os.path.exists(path):
        return "not found"
    if os.path.isdir(path):
        return "is a directory"
    try:
        with open(path, encoding="utf-8") as f:
            text = f.read()
    except (OSError, UnicodeDecodeError) as error:
        return f"cannot read it ({getattr(error, 'strerror', None) or error})"
    try:
        import yaml
    except ImportError:  # rcl's own parser still reads it below
        return ""
    try:
        documents = list(yaml.safe_load_all(text))  # (rcl reads every '---' document of a file)
    except yaml.YAMLError as error:
        return "YAML syntax error" + _yaml_error(error, text)
    for document in documents:
        if document is not None and not isinstance(document, dict):
            what = "a list" if isinstance(document, list) else "a single value"
            return f"wrong layout (the file holds {what}); {PARAMS_FILE_LAYOUT}"
        empty = _empty_parameter_section(document or {})
        if empty:
            return (f"wrong layout ('{empty}: ros__parameters:' holds no parameters: add '    NAME: VALUE' under it "
                    "or leave the section out)")
    return ""


def _yaml_error(error: Exception, text: str) -> str:
    """' at line N: what' of a PyYAML error raised on ``text`` (dlo_common.params.yaml_problem)."""
    found = yaml_problem(error, text)
    return f"{'' if found.line is None else f' at line {found.line}'}: {found.problem}"


def _empty_parameter_section(mapping: dict, path: str = "") -> str:
    """The node key of the first ``ros__parameters:`` with nothing under it (rcl refuses it); ''."""
    for key, value in mapping.items():
        if key == "ros__parameters" and value is None:
            return path or "?"
        if isinstance(value, dict):
            found = _empty_parameter_section(value, f"{path}/{key}".lstrip("/") if path else str(key))
            if found:
                return found
    return ""


def ros_arguments_problem(argv: Sequence[str]) -> str:
    """One line on what rcl would refuse in ``argv``'s ``--ros-args`` (a params file that is missing,
    not YAML or laid out wrongly, a malformed ``-p``, an unknown ROS flag); '' when nothing.

    rcl reports these from ``rclpy.init`` as a multi-line RCLError traceback; here they are found
    first, with rcl's own argument parser (no context, no node, nothing started)."""
    for path in params_files(argv):
        problem = params_file_problem(path)
        if problem:
            return f"params file {path}: {problem}"
    try:
        remove_ros_args(list(argv))
    except RuntimeError as error:  # RCLInvalidROSArgsError, UnknownROSArgsError
        return _rcl_argument_error(error)
    return ""


def _rcl_argument_error(error: Exception) -> str:
    text = _RCL_LOCATION.sub("", str(error)).strip()
    if type(error).__name__ == "UnknownROSArgsError":  # str(error) is the list of them: "['--bogus']"
        unknown = ", ".join(re.findall(r"'([^']*)'", text)) or text
        return (f"unknown ROS argument {unknown} after --ros-args (there: -p NAME:=VALUE, --params-file FILE, "
                "-r FROM:=TO, --log-level LEVEL)")
    found = re.search(r"Couldn't parse params file: '--params-file (.*?)'\. Error: (.*)", text)
    if found:
        path, problem = found.groups()
        line = re.search(r"line(?:_num)? (\d+)", problem)  # the first line rcl names
        where = f" at line {line.group(1)}" if line else ""
        if "no node names before ros__parameters" in problem:
            what = "'ros__parameters:' without a node name above it"
        elif "before ros__parameters" in problem:
            what = "a value outside 'ros__parameters:'"
        else:  # e.g. "Sequence should be of same type": a value rcl cannot take
            problem = _LINE.sub("", problem)
            return f"params file {path}: rcl cannot read it{where}: {problem}"
        return f"params file {path}: wrong layout{where} ({what}); {PARAMS_FILE_LAYOUT}"
    found = re.search(r"Couldn't parse parameter override rule: '(.*?)'", text)
    if found:
        return (f"cannot read {found.group(1)!r}: expected -p NAME:=VALUE (VALUE in YAML, e.g. 3, 0.5, true, text, "
                "[1.0,2.0])")
    return text.removeprefix("Failed to parse ROS arguments: ")


def handle_help(package: str, parameters: Sequence[Param | tuple], summary: str = "",
                args: Sequence[str] | None = None, exit_codes: str = EXIT_CODES) -> int | None:
    """Answer ``-h``/``--help`` (print the parameters, return 0), a stray argument before
    ``--ros-args`` or ROS arguments that rcl would refuse (one line, return 2: see
    :func:`ros_arguments_problem`); None when the node should start.

    Call it first in a node's ``main()``: it needs no ``rclpy.init``, creates no node and no file.
    ``args`` defaults to ``sys.argv[1:]`` (stray arguments are only checked there); ``summary`` is what the
    node does (its module docstring).
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
    problem = ros_arguments_problem(argv)
    if problem:
        print(f"{executable}: {problem}", file=sys.stderr)
        return EXIT_BAD_PARAMETER
    return None


def run_node(make_node: Callable[[], "rclpy.node.Node"], args=None, *, interrupted_rc: int = 0,
             parameters: Sequence[Param | tuple] | None = None, summary: str = "") -> int:
    """Spin the node ``make_node()`` builds until SIGINT/SIGTERM (exit code ``interrupted_rc``).

    With ``parameters`` (the node module's ``PARAMETERS``), ``-h``/``--help`` first prints them
    and returns 0 before anything starts (:func:`handle_help`; ``summary``: the module docstring).

    Exit code 2 and one line on a bad parameter, 3 and one line when the node refuses to start or
    go on (:class:`NodeStartError`); never a traceback for a signal, also one that arrives while a
    callback runs (the callback finishes first) or while the node is being built.

    Once it stops spinning, the node's ``finish()`` (when it has one: saving, closing files, a last report)
    runs, then :func:`shut_down` tears the middleware down within ``TEARDOWN_LIMIT`` s.
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
    # rclpy's own handler (set by rclpy.init) shuts the context down on SIGINT, but wakes a waiting executor first:
    # one that looks in between waits again, for good when no message comes (an idle node hung so). So the spin
    # loop below waits at most SPIN_TIMEOUT and stops once the context is down or a SIGINT was noted. This handler,
    # set before rclpy's (which calls it afterwards), only notes the signal: raising KeyboardInterrupt would land
    # wherever Python runs, also inside rclpy (a half-built executor Task whose __del__ complains, a message being
    # converted, which rclpy turns into a RuntimeError) and halfway through a callback. So a callback running when
    # the signal comes finishes, then the node stops, also when the signal came before rclpy's handler was there;
    # an error once the context is shut down is the signal's, not a bug. A callback that never finishes (a driver
    # waiting on hardware) is interrupted by a SIGINT sent again later (FORCE_AFTER); the copies that a terminal's
    # Ctrl-C and a launcher passing it on deliver together do not.
    interrupts: list[float] = []

    def note_interrupt(signum, frame):
        interrupts.append(time.monotonic())
        if interrupts[-1] - interrupts[0] >= FORCE_AFTER:
            raise SecondInterrupt

    main_thread = threading.current_thread() is threading.main_thread()  # (only it may set handlers)
    previous = signal.getsignal(signal.SIGINT) if main_thread else None
    if previous is signal.default_int_handler:  # (an ignored SIGINT, as in a background job, stays ignored)
        signal.signal(signal.SIGINT, note_interrupt)
    rclpy.init(args=args)
    node = None
    name = executable_name()  # the executable, until the node has its name
    try:
        node = make_node()
        name = node.get_name()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        while rclpy.ok() and not interrupts:  # (also a signal noted before rclpy's handler was there: no spin)
            executor.spin_once(timeout_sec=SPIN_TIMEOUT)
        rc = interrupted_rc
    except ParameterError as error:
        what = "" if isinstance(error, UnknownParameterError) else "bad parameter: "
        print(f"[{name}] {what}{error}", file=sys.stderr)
        rc = EXIT_BAD_PARAMETER
    except NodeStartError as error:
        print(f"[{name}] {error}", file=sys.stderr)
        rc = EXIT_REFUSED
    except SecondInterrupt:
        print(f"[{name}] stopped by a second SIGINT: a callback had not finished {FORCE_AFTER:g} s after the first",
              file=sys.stderr)
        rc = interrupted_rc
    except (KeyboardInterrupt, ExternalShutdownException):
        rc = interrupted_rc
    except Exception:
        if rclpy.ok():
            raise
        rc = interrupted_rc  # a signal shut the context down under a callback or the node's making (RCLError)
    finally:
        if node is not None and hasattr(node, "finish"):
            try:
                node.finish()  # the node's own closing work (save, close, report): not bounded
            except Exception as error:  # noqa: BLE001 - one line, not a traceback over the exit code
                print(f"[{name}] could not finish: {type(error).__name__}: {error}", file=sys.stderr)
                rc = EXIT_FAILED
        shut_down(node)
        if previous is signal.default_int_handler:
            signal.signal(signal.SIGINT, previous)
    return rc


def _stderr_fd() -> int:
    try:
        return sys.stderr.fileno()
    except (AttributeError, ValueError, OSError):  # replaced by an object without a descriptor (a test's capture)
        return 2


@contextmanager
def bounded() -> Iterator[None]:
    """Ends the process with exit code 1 when the block runs longer than ``TEARDOWN_LIMIT`` s, after faulthandler's
    "Timeout (0:00:10)!" line and every thread's Python stack on stderr.

    The watchdog is faulthandler's C thread: it needs no GIL, so it also ends a block stuck in C code that holds
    the GIL (rclpy's ``destroy_node`` and ``try_shutdown`` do: no Python thread, signal handler or second
    Ctrl-C runs then). One such timer exists per process; this one replaces any other and is cancelled on exit.
    The stacks go to file descriptor 2 when ``sys.stderr`` has none (replaced by a test's capture).
    """
    faulthandler.dump_traceback_later(TEARDOWN_LIMIT, exit=True, file=_stderr_fd())
    try:
        yield
    finally:
        faulthandler.cancel_dump_traceback_later()


def shut_down(node: "rclpy.node.Node | None" = None) -> None:
    """Destroy ``node`` (if any) and shut rclpy's default context down within ``TEARDOWN_LIMIT`` s (:func:`bounded`).

    Fast DDS 2.14 (Jazzy) can deadlock while it destroys a participant whose peers leave at the same moment
    (``DomainParticipant::set_listener`` waits for a discovery callback that waits for a lock it holds): seen
    about once in 100 stops of a whole graph by one SIGINT. The node's work is done by then; without a bound it
    would never exit. Run the node's own closing work (saving, closing a bag) BEFORE this, outside the bound.
    """
    with bounded():
        if node is not None:
            try:
                node.destroy_node()
            except Exception:  # noqa: BLE001 - already torn down by the signal's shutdown
                pass
        rclpy.try_shutdown()
