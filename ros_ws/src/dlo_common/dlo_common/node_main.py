"""The ``main()`` body every dlo node shares: ``--help``, init, build, spin, clean shutdown, clear errors.

What :func:`run_node` promises (each promise has a test in ``test/test_node_main.py`` that names its number):

1. Before anything starts, ``-h``/``--help`` prints the node's parameters and returns 0; a stray argument before
   ``--ros-args`` and ROS arguments that rcl would refuse are one line on stderr and 2 (:func:`handle_help`).
2. rclpy's default context is initialised with ``args`` (not ``sys.argv``) and ``make_node()`` builds the node in
   it. A :class:`ParameterError` is one line and 2, a :class:`NodeStartError` one line and 3 (also one a callback
   raises later). Any other error is a traceback and 1, also one raised by a callback.
3. The first SIGINT or SIGTERM requests the stop and raises nothing: the callback running then finishes, with the
   node and the context still up (what it publishes is published), no other callback starts, and run_node returns
   ``interrupted_rc`` without a word on stderr. A request that comes while ``make_node()`` runs stops the node
   before it spins. The spin loop looks at least every ``SPIN_TIMEOUT`` s whether it was asked to stop or the
   context went down (shut down by someone else: also ``interrupted_rc``), also when nothing wakes it.
4. Copies of the signal within ``FORCE_AFTER`` s of the first (a terminal's Ctrl-C and a launcher passing it on
   deliver two together) change nothing.
5. A SIGINT or SIGTERM ``FORCE_AFTER`` s or more after the first interrupts the node's own code that still runs
   then: a callback, ``make_node()`` or ``finish()`` that has not returned. :class:`SecondInterrupt` is raised at
   once where the signal finds code other than rclpy's and run_node's running (the node's own, or a library's it
   called: a sleep, a wait on a lock, a read); where it finds rclpy's code running, it waits and is raised at the
   next line of the node's own code that runs after rclpy has returned to it. So never inside rclpy (a
   KeyboardInterrupt raised in rclpy's ``Task`` constructor left a half-built task whose ``Future.__del__`` printed
   "Exception ignored ..."), never through a call the node's code made into rclpy that was running then, never in
   run_node's own steps (making the executor, the teardown). One line on stderr says what was interrupted; an
   interrupted callback or ``make_node()`` ends with ``interrupted_rc``, an interrupted ``finish()`` (its closing
   work left undone) with 1.
6. Once the node stops spinning, its ``finish()`` (when it has one: saving a run, closing files, a last report) runs
   first, before anything is torn down, with the node and the context still up, for as long as it takes. A
   ``finish()`` that raises is one line and 1; the node is torn down all the same.
7. Then :func:`shut_down` destroys the node and shuts rclpy's default context down, the context run_node
   initialised and built the node in, within ``TEARDOWN_LIMIT`` s: a teardown still running then (Fast DDS's
   deadlock, in C code that holds the GIL) ends the process with 1 after faulthandler's ``Timeout`` line and every
   thread's stack. No other context of the process is shut down, neither by a signal (one run_node handles: 9)
   nor by the teardown. A SIGINT or SIGTERM during the teardown is only noted, however late: the limit ends a
   teardown that hangs.
8. When run_node returns, SIGINT and SIGTERM are handled as before it was called (its handlers are put back; rclpy's
   were not installed for them): a later SIGINT is the caller's again (KeyboardInterrupt by default), a later SIGTERM
   ends the process (by default) instead of being swallowed by rclpy's handler for a context long shut down.
9. Where run_node cannot or should not set its handlers, rclpy's own handler takes the signal, as it always did:
   in a thread other than the main one (only the main thread may set handlers), for a SIGINT ignored at the start
   (a background job of a shell) and for a signal that already had a handler of the caller's. rclpy's handler shuts
   every context down; the spin loop then ends, and an rclpy error that a callback gets from the context so shut
   down is the signal's (``interrupted_rc``), not a bug.
10. Exit codes, as ``--help`` says them (:data:`EXIT_CODES`): 0 done (also for ``--help``) or stopped by a signal
    (``interrupted_rc`` when a node gives one: sim_node 130); 1 failed: a traceback, a ``finish()`` that failed or
    was interrupted, a teardown past its limit; 2 bad parameter; 3 refused to start. A ``SystemExit`` raised by the
    node's code (sim_node after its last episode) passes through, after ``finish()`` and the teardown.
"""

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
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args

from dlo_common.node_util import NodeStartError, ParameterError, UnknownParameterError
from dlo_common.params import Param, help_requested, help_text, unexpected_arguments, yaml_problem

EXIT_FAILED = 1  # an error the node did not expect (a traceback), or a middleware teardown cut short (stacks)
EXIT_BAD_PARAMETER = 2
EXIT_REFUSED = 3
EXIT_CODES = "0 done or stopped by a signal, 1 failed (see stderr), 2 bad parameter, 3 refused to start"
TEARDOWN_LIMIT = 10.0  # s: a middleware teardown (DDS participant destruction) still running this long ends the process
FORCE_AFTER = 2.0  # s: a SIGINT or SIGTERM this long after the first interrupts the node's code still running
SPIN_TIMEOUT = 0.1  # s: the longest a node waits for work before it looks whether it was told to stop


class SecondInterrupt(KeyboardInterrupt):
    """A SIGINT or SIGTERM ``FORCE_AFTER`` s or more after the first, raised in the node's own code that still runs
    (promise 5); ``args``: the signal's name and what was running ("build", "spin" or "finish")."""


INTERRUPTED = {"build": "the node was not built", "spin": "a callback had not finished"}  # SecondInterrupt.doing


def _in_rclpy(frame) -> bool:
    name = frame.f_globals.get("__name__") or ""
    return name == "rclpy" or name.startswith("rclpy.")


def _in_run_node(frame) -> bool:  # this module's own steps
    return frame.f_globals.get("__name__") == __name__


class _Waiting:
    """A SecondInterrupt that waits for the node's own code: the signal found rclpy's code running."""

    def __init__(self, interrupt: SecondInterrupt, landing: list, trace) -> None:
        self.interrupt = interrupt
        self.landing = landing  # the node's frames that called into rclpy, outermost first
        self.trace = trace  # the trace function before (a debugger's, coverage's)
        self.f_traces = [(frame, frame.f_trace) for frame in landing]

    def tracer(self, frame, event, arg):
        """The trace function while the interrupt waits: raises it at the next line a landing frame runs (only they
        have this as their ``f_trace``: rclpy returned to one) or at the call of a function that a landing frame
        called not through rclpy. Python turns tracing off when it raises."""
        if event == "line":
            raise self.interrupt
        if event == "call" and not _in_rclpy(frame) and not _in_run_node(frame):
            caller = frame.f_back
            while caller is not None and not _in_rclpy(caller) and not _in_run_node(caller):
                if any(caller is f for f in self.landing):
                    raise self.interrupt
                caller = caller.f_back
        return None


class StopRequests:
    """SIGINT and SIGTERM while :func:`run_node` runs (promises 3, 4, 5, 7): each is noted; one ``FORCE_AFTER`` s or
    more after the first raises :class:`SecondInterrupt` in the node's own code while that runs (``doing``).

    Python calls the handler between two bytecodes of the main thread, with the frame that runs then. Raising there
    could land inside rclpy (a half-built ``Task``): where the frame is rclpy's (or run_node's), the interrupt waits
    instead, traced (``sys.settrace`` and ``f_trace``), until a frame of the node's own code that called into rclpy
    runs its next line."""

    def __init__(self) -> None:
        self.times: list[float] = []  # time.monotonic() of each signal
        self.doing = ""  # "build", "spin" or "finish" while the node's own code runs; "" while run_node's steps do
        self._waiting: _Waiting | None = None

    @property
    def requested(self) -> bool:
        return bool(self.times)

    def handle(self, signum: int, frame) -> None:
        self.times.append(time.monotonic())
        if not self.doing or self.times[-1] - self.times[0] < FORCE_AFTER:
            return
        interrupt = SecondInterrupt(signal.Signals(signum).name, self.doing)
        if frame is not None and not _in_rclpy(frame) and not _in_run_node(frame):
            self.stop_waiting()  # (one that waits for a landing frame would be raised again in its finally blocks)
            raise interrupt
        if self._waiting is None:
            self._wait_for_node_code(frame, interrupt)

    def _wait_for_node_code(self, frame, interrupt: SecondInterrupt) -> None:
        chain = []  # the frames from the one run_node called (the executor, make_node, finish) to the running one
        while frame is not None and not _in_run_node(frame):
            chain.append(frame)
            frame = frame.f_back
        chain.reverse()
        first = next((i for i, f in enumerate(chain) if not _in_rclpy(f)), len(chain))  # past the executor's frames
        last = next((i for i in range(first, len(chain)) if _in_rclpy(chain[i])), len(chain))
        self._waiting = _Waiting(interrupt, chain[first:last], sys.gettrace())
        for f in self._waiting.landing:
            f.f_trace = self._waiting.tracer
        sys.settrace(self._waiting.tracer)

    def stop_waiting(self) -> None:
        """Forget an interrupt still waiting and put tracing back as it was (main thread)."""
        waiting, self._waiting = self._waiting, None
        if waiting is not None:
            for frame, f_trace in waiting.f_traces:
                frame.f_trace = f_trace
            sys.settrace(waiting.trace)

    @contextmanager
    def interruptible(self, doing: str) -> Iterator[None]:
        """While the block runs the node's own code (``doing``), a late signal interrupts it (promise 5)."""
        self.doing = doing
        try:
            yield
        finally:
            self.doing = ""
            self.stop_waiting()


def _take_signals(handler) -> dict:
    """Set ``handler`` for the signals run_node handles itself (promise 9: in the main thread, SIGINT at Python's
    default, SIGTERM at the system's); {signal: the handler it replaced}."""
    if threading.current_thread() is not threading.main_thread():
        return {}
    taken = {}
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        taken[signal.SIGINT] = signal.signal(signal.SIGINT, handler)
    if signal.getsignal(signal.SIGTERM) == signal.SIG_DFL:
        taken[signal.SIGTERM] = signal.signal(signal.SIGTERM, handler)
    return taken


def _rclpy_handlers(taken: dict) -> SignalHandlerOptions:
    """rclpy's own handlers for the signals run_node did not take (promise 9)."""
    if signal.SIGINT in taken:
        return SignalHandlerOptions.NO if signal.SIGTERM in taken else SignalHandlerOptions.SIGTERM
    return SignalHandlerOptions.SIGINT if signal.SIGTERM in taken else SignalHandlerOptions.ALL


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
            return (
                f"wrong layout ('{empty}: ros__parameters:' holds no parameters: add '    NAME: VALUE' under it "
                "or leave the section out)"
            )
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
        return (
            f"unknown ROS argument {unknown} after --ros-args (there: -p NAME:=VALUE, --params-file FILE, "
            "-r FROM:=TO, --log-level LEVEL)"
        )
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
        return f"cannot read {found.group(1)!r}: expected -p NAME:=VALUE (VALUE in YAML, e.g. 3, 0.5, true, text, [1.0,2.0])"
    return text.removeprefix("Failed to parse ROS arguments: ")


def handle_help(
    package: str,
    parameters: Sequence[Param | tuple],
    summary: str = "",
    args: Sequence[str] | None = None,
    exit_codes: str = EXIT_CODES,
) -> int | None:
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
        sys.stdout.write(
            help_text(package, executable, parameters, summary, exit_codes, installed_params_file(package, executable))
        )
        sys.stdout.flush()
        return 0
    stray = unexpected_arguments(argv) if args is None else []  # explicit args may start with a program name
    if stray:
        print(
            f"{executable}: unexpected argument {stray[0]!r} (parameters go after --ros-args: "
            f"-p NAME:=VALUE; see '{executable} --help')",
            file=sys.stderr,
        )
        return EXIT_BAD_PARAMETER
    problem = ros_arguments_problem(argv)
    if problem:
        print(f"{executable}: {problem}", file=sys.stderr)
        return EXIT_BAD_PARAMETER
    return None


def run_node(
    make_node: Callable[[], "rclpy.node.Node"],
    args=None,
    *,
    interrupted_rc: int = 0,
    parameters: Sequence[Param | tuple] | None = None,
    summary: str = "",
) -> int:
    """Spin the node ``make_node()`` builds until SIGINT/SIGTERM (exit code ``interrupted_rc``); the module's
    docstring lists what it promises.

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
    # rclpy's own handlers (rclpy.init sets them) shut every context down on SIGINT/SIGTERM, under a running callback
    # (whose next rclpy call fails) and before finish(). run_node's own handlers only note the request (promise 3),
    # set before rclpy.init, so that a signal while it initialises is noted too; rclpy's take the signals run_node
    # does not (promise 9). rclpy's handler also wakes a waiting executor before it shuts the context down, and one
    # that looked in between waited again, for good when no message came (an idle node hung so): the spin loop waits
    # at most SPIN_TIMEOUT, and so notices a request (which wakes nothing) as well.
    stop = StopRequests()
    taken = _take_signals(stop.handle)
    rclpy.init(args=args, signal_handler_options=_rclpy_handlers(taken))
    node = None
    name = executable_name()  # the executable, until the node has its name
    try:
        with stop.interruptible("build"):
            node = make_node()
        name = node.get_name()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        with stop.interruptible("spin"):
            while rclpy.ok() and not stop.requested:  # (a request during make_node: no spin)
                executor.spin_once(timeout_sec=SPIN_TIMEOUT)
        rc = interrupted_rc
    except ParameterError as error:
        what = "" if isinstance(error, UnknownParameterError) else "bad parameter: "
        print(f"[{name}] {what}{error}", file=sys.stderr)
        rc = EXIT_BAD_PARAMETER
    except NodeStartError as error:
        print(f"[{name}] {error}", file=sys.stderr)
        rc = EXIT_REFUSED
    except SecondInterrupt as interrupt:
        signame, doing = interrupt.args
        print(f"[{name}] stopped by a second {signame}: {INTERRUPTED[doing]} {FORCE_AFTER:g} s after the first", file=sys.stderr)
        rc = interrupted_rc
    except (KeyboardInterrupt, ExternalShutdownException):
        rc = interrupted_rc
    except Exception:
        if rclpy.ok():
            raise
        rc = interrupted_rc  # rclpy's handler shut the context down under a callback or the node's making (RCLError)
    finally:
        if node is not None and hasattr(node, "finish"):
            try:
                with stop.interruptible("finish"):
                    node.finish()  # the node's own closing work (save, close, report): not bounded
            except SecondInterrupt as interrupt:
                print(
                    f"[{name}] could not finish: stopped by a second {interrupt.args[0]} {FORCE_AFTER:g} s after the first",
                    file=sys.stderr,
                )
                rc = EXIT_FAILED
            except Exception as error:  # noqa: BLE001 - one line, not a traceback over the exit code
                print(f"[{name}] could not finish: {type(error).__name__}: {error}", file=sys.stderr)
                rc = EXIT_FAILED
        shut_down(node)  # (a signal now is only noted: stop.doing is "")
        for signum, handler in taken.items():
            signal.signal(signum, handler)
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
