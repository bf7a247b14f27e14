"""The graph in one process (``scripts/launch_graph.sh --composed``), as ROS 2 composition runs components: every
node of the description (:func:`dlo_bringup.graph.graph_nodes`) built by its own class (``NodeSpec.plugin``) with
the arguments its own process gets (``cli_args``: the same ``--ros-args``, so the same parameters and remappings),
in the same order, all on one executor. The launcher starts it as one process and supervises it as it supervises
the nodes' processes (:mod:`dlo_bringup.launcher`).

    python -m dlo_bringup.composed GRAPH_JSON [STATUS_JSON] [--executor events|single_threaded]

What each node's own process does (``dlo_common.node_main.run_node``, ``dlo_bag.recorder_node.main``), done here
for all of them:

- build the nodes in start order. The sim comes first and, once built, has found itself alone on the domain. A
  node that refuses its parameters (2) or to start (3) ends the graph, as its process ending would have.
- spin them on one executor until the sim ends (its last episode answered: ``SystemExit(0)``), a node fails (a
  callback of the node raises: one line, or a traceback, and its status), a node asks for the stop (the
  recorder after a write error, through its ``stop``), or SIGINT/SIGTERM. Copies of the signal within
  ``FORCE_AFTER`` s change nothing; one later interrupts a callback, a node's building or its ``finish()``
  still running (node_main's promises 3-5), but not the recorder's closing of its bag (its process only notes
  signals).
- then the recorder drains what was delivered to it, every node's ``finish()`` runs in start order (the bag
  closed, an online run saved), and the teardown is bounded by ``TEARDOWN_LIMIT`` (node_main.bounded).
- each node's exit status, as its own process would have given it (the sim 130 when stopped, the recorder's
  from its summary), goes to STATUS_JSON before the teardown: ``{"ended_by": spec name or "signal", "status":
  {spec name: status}, "rc": this process's exit status}``. A node that was never built has no status.

Every line a node logs carries its logger name; the runner's lines on one node start with its ``[name]`` as its own
process prints them, and ``[composed] building NAME`` / ``[composed] built NAME as NODE_NAME`` frame each node's
building, so that :class:`dlo_bringup.composed_logs.LogSplitter` splits this process's output into the nodes' logs.

Executor: rclpy's EventsExecutor (Jazzy's rclpy >= 7.1.4; else the SingleThreadedExecutor), single-threaded in C++:
measured on the step-locked graph, 2.2 ms of CPU per control step against 4.3 ms with the SingleThreadedExecutor,
whose wait set is rebuilt in Python on every wait (benchmarks/bench_composed.py). It spins in
``spin_until_future_complete`` (no Python between two callbacks); the future is done when a node's callback ended it
or, set by a watcher thread, when a signal or a node asked for the stop. One thread is what a step-locked
graph needs: one thing at a time is ready, each node matches its inputs by stamp, so the order of callbacks does
not change an episode, and a second Python thread would only contend for the GIL.
"""

from __future__ import annotations

import importlib
import inspect
import json
import signal
import sys
import threading
import time
import traceback
from pathlib import Path

from dlo_bringup.composed_logs import BUILDING, BUILT, RUNNER

SIGNAL = "signal"  # ended_by: SIGINT or SIGTERM
EXECUTORS = ("events", "single_threaded")  # rclpy's EventsExecutor (the default), its SingleThreadedExecutor
SPIN_TIMEOUT = 0.1  # s: the longest the executor waits for work before the spin loop looks at the context
WATCH_PERIOD = 0.05  # s: how often the watcher thread looks for a stop request
SIM = "sim"  # the spec whose end is the graph's end; stopped, its status is 130 (sim_node's interrupted_rc)
RECORDER = "recorder"  # drains and closes its bag; not interrupted while it does (its process only notes signals)


def factory(plugin: str):
    """The class (or function) ``module:attribute`` that builds a node."""
    module, _, attribute = plugin.partition(":")
    return getattr(importlib.import_module(module), attribute)


def make_executor(kind: str):
    if kind == "events":
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError:  # rclpy before 7.1.4
            pass
        else:
            return EventsExecutor()
    from rclpy.executors import SingleThreadedExecutor

    return SingleThreadedExecutor()


def stopped_status(name: str) -> int:
    """A node's exit status when a signal (or the graph's end) stopped it: sim_node 130, the others 0."""
    return 130 if name == SIM else 0


class Graph:
    """The nodes of one graph in this process: built, spun, stopped; ``status``: their exit statuses by spec name."""

    def __init__(self, specs, executor: str = EXECUTORS[0]):
        from dlo_common.node_main import StopRequests
        from dlo_common.node_util import ShutdownRequest

        self.specs = {spec.name: spec for spec in specs}
        self.executor_kind = executor
        self.executor = None
        self.nodes: dict = {}  # spec name -> node, in start order
        self.status: dict = {}  # spec name -> exit status
        self.ended_by = None  # the spec name whose end (or failure) ended the graph, or SIGNAL
        self.raised = None  # (spec name, what a callback of that node raised)
        self.ended = None  # a Future, done when the spin is to end
        self.ending = threading.Lock()
        self.stops = StopRequests()  # SIGINT / SIGTERM (node_main's promises 3-5)
        self.asked = ShutdownRequest()  # a node's own request to stop (the recorder's after a write error)

    def say(self, name: str, text: str) -> None:
        """A line on the node ``name`` as its own process prints it: ``[node name] text`` (its executable's name
        before it is built)."""
        node = self.nodes.get(name)
        print(f"[{node.get_name() if node is not None else self.specs[name].executable}] {text}", file=sys.stderr, flush=True)

    # ---- the stages -----------------------------------------------------------------------------------------
    def build(self) -> None:
        """Build the nodes in start order; the first that refuses ends the graph (its status set)."""
        for spec in self.specs.values():
            if self.stops.requested:
                self.ended_by = SIGNAL
                return
            print(BUILDING + spec.name, file=sys.stderr, flush=True)
            try:
                make = factory(spec.plugin)
                options = {"cli_args": spec.ros_args()}
                if "stop" in inspect.signature(make).parameters:  # it may ask for the graph's stop (the recorder)
                    options["stop"] = self.asked
                with self.stops.interruptible("build"):
                    node = make(**options)
            except BaseException as error:  # noqa: BLE001 - the node's status, as its own process would end
                self.status[spec.name] = self.failure_status(spec.name, error, "build")
                self.ended_by = spec.name
                print(BUILT + f"{spec.name} failed", file=sys.stderr, flush=True)
                return
            self.nodes[spec.name] = node
            print(BUILT + f"{spec.name} as {node.get_name()}", file=sys.stderr, flush=True)

    def guard(self, name: str, callback):
        """``callback`` of the node ``name``, which notes what it raises (the node's end, and the graph's) instead of
        raising it into the executor, and does nothing once the graph ends."""

        def guarded(*args):
            if self.raised is not None:
                return None
            try:
                return callback(*args)
            except BaseException as error:  # noqa: BLE001 - SystemExit, a SecondInterrupt: the node's end too
                self.raised = (name, error)
                self.end()  # (the executor returns after this callback)
                return None

        return guarded

    def end(self) -> None:
        """The spin ends (once; from a callback or the watcher thread)."""
        with self.ending:
            if not self.ended.done():
                self.ended.set_result(True)

    def watch(self) -> None:
        """(a thread of its own while the nodes spin) Ends the spin once a signal or a node asks for the stop. The
        EventsExecutor's spin_until_future_complete returns at its timeout only when no callback is ready, which
        is never while the graph runs; a signal handler, which runs between two lines of a callback, must not call
        into the executor."""
        while not self.ended.done():
            if self.stops.requested or self.asked.is_set():
                self.end()
            time.sleep(WATCH_PERIOD)

    def spin(self) -> None:
        """Spin every node on one executor until the graph ends (``ended_by``)."""
        import rclpy
        import rclpy.task

        self.executor = make_executor(self.executor_kind)
        self.ended = rclpy.task.Future(executor=self.executor)  # done: the spin ends
        for name, node in self.nodes.items():
            for entity in (*node.subscriptions, *node.timers, *node.services):
                entity.callback = self.guard(name, entity.callback)
            self.executor.add_node(node)
        watcher = threading.Thread(target=self.watch, name="composed_watch", daemon=True)
        watcher.start()
        try:
            with self.stops.interruptible("spin"):
                while rclpy.ok() and not self.ended.done():
                    self.executor.spin_until_future_complete(self.ended, timeout_sec=SPIN_TIMEOUT)
        except KeyboardInterrupt:  # a second signal that found this loop running, not a node's callback
            pass
        except BaseException as error:  # noqa: BLE001 - a callback made later (the recorder's): as a guarded one's
            self.raised = self.raised or (self.owner(error), error)
        finally:
            self.end()
            watcher.join()
        if self.raised is not None:
            name, error = self.raised
            self.status[name] = self.failure_status(name, error, "spin")
            self.ended_by = name
        elif self.asked.is_set():
            self.ended_by = next((n for n, node in self.nodes.items() if getattr(node, "stop", None) is self.asked), SIGNAL)
        else:
            self.ended_by = SIGNAL

    def owner(self, error: BaseException) -> str:
        """The node whose code raised ``error`` (the innermost frame of one of its methods); the sim when none."""
        owner = SIM
        for frame, _ in traceback.walk_tb(error.__traceback__):
            me = frame.f_locals.get("self")
            owner = next((name for name, node in self.nodes.items() if node is me), owner)
        return owner

    def failure_status(self, name: str, error: BaseException, doing: str) -> int:
        """The exit status the node's own process would have ended with on ``error`` (node_main.run_node's; the
        recorder's own for its errors), after the line it would have printed."""
        from dlo_common.node_main import EXIT_BAD_PARAMETER, EXIT_FAILED, EXIT_REFUSED, FORCE_AFTER, INTERRUPTED, SecondInterrupt
        from dlo_common.node_util import NodeStartError, ParameterError, UnknownParameterError

        if isinstance(error, SystemExit):  # sim_node after its last episode
            return error.code if isinstance(error.code, int) else (0 if error.code is None else 1)
        if name == RECORDER:  # recorder_node.main's lines and statuses
            from dlo_bag.errors import BagError
            from dlo_bag.recorder_node import EXIT_RECORDING_FAILED
            from dlo_bag.writer import BagWriteError

            if isinstance(error, BagWriteError):
                print(f"recorder_node: recording failed: {error.cause} ({error})", file=sys.stderr, flush=True)
                return EXIT_RECORDING_FAILED
            if isinstance(error, (ParameterError, BagError)):
                print(f"recorder_node: error: {error}", file=sys.stderr, flush=True)
                return EXIT_BAD_PARAMETER
        if isinstance(error, ParameterError):
            self.say(name, f"{'' if isinstance(error, UnknownParameterError) else 'bad parameter: '}{error}")
            return EXIT_BAD_PARAMETER
        if isinstance(error, NodeStartError):
            self.say(name, str(error))
            return EXIT_REFUSED
        if isinstance(error, SecondInterrupt):
            signame, doing = error.args
            self.say(name, f"stopped by a second {signame}: {INTERRUPTED[doing]} {FORCE_AFTER:g} s after the first")
            return stopped_status(name)
        if isinstance(error, KeyboardInterrupt):
            return stopped_status(name)
        self.say(name, f"failed while it {'was built' if doing == 'build' else 'ran'}:")
        traceback.print_exception(error, file=sys.stderr)
        return EXIT_FAILED

    def finish(self) -> None:
        """Every node's closing work in start order (the recorder: drain, then close its bag); their statuses."""
        for name in self.nodes:
            self.status.setdefault(name, stopped_status(name))
        if self.executor is not None:
            for node in self.nodes.values():
                self.executor.remove_node(node)  # nothing runs now but the closing work
        for name, node in self.nodes.items():
            if name == RECORDER:
                self.close_recording(node)
            elif hasattr(node, "finish"):
                self.finish_node(name, node)

    def close_recording(self, recorder) -> None:
        """recorder_node.main's end: drain what was delivered, close the bag, the status from its summary. Signals
        are only noted meanwhile."""
        from dlo_bag.recorder_node import exit_status
        from rclpy.executors import SingleThreadedExecutor

        if not recorder.recorder.failure:
            why = "a signal" if self.ended_by == SIGNAL else f"{self.ended_by} ended"
            recorder.get_logger().info(f"stopping ({why}): draining and closing the bag")
            drain = SingleThreadedExecutor()
            drain.add_node(recorder)
            recorder.drain(drain)
            drain.remove_node(recorder)
        self.status[RECORDER] = exit_status(recorder.finish(), self.status[RECORDER])

    def finish_node(self, name: str, node) -> None:
        """run_node's finish(): one line and 1 when it fails or a second signal interrupts it."""
        from dlo_common.node_main import EXIT_FAILED, FORCE_AFTER, SecondInterrupt

        try:
            with self.stops.interruptible("finish"):
                node.finish()
        except SecondInterrupt as interrupt:
            self.say(name, f"could not finish: stopped by a second {interrupt.args[0]} {FORCE_AFTER:g} s after the first")
            self.status[name] = EXIT_FAILED
        except Exception as error:  # noqa: BLE001 - one line, as run_node says it
            self.say(name, f"could not finish: {type(error).__name__}: {error}")
            self.status[name] = EXIT_FAILED

    def rc(self) -> int:
        """This process's exit status: the status of the node that ended the graph, else the first other one that
        is not 0 (the sim's 130 when a signal stopped it)."""
        ended = [self.status[self.ended_by]] if self.ended_by in self.status else []
        return next((status for status in ended + list(self.status.values()) if status), 0)

    def tear_down(self) -> None:
        """Destroy every node and shut the context down, within TEARDOWN_LIMIT s (node_main.bounded)."""
        import rclpy
        from dlo_common.node_main import bounded

        with bounded():
            if self.executor is not None:
                self.executor.shutdown()
            for node in reversed(list(self.nodes.values())):
                try:
                    node.destroy_node()
                except Exception:  # noqa: BLE001 - already torn down
                    pass
            rclpy.try_shutdown()


def read_specs(path: str):
    from dlo_bringup.graph import NodeSpec

    return [NodeSpec.from_dict(item) for item in json.loads(Path(path).read_text())]


def run(specs, status_file: str | None = None, executor: str = EXECUTORS[0]) -> int:
    """Run the graph ``specs`` in this process; its exit status (the module docstring)."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    graph = Graph(specs, executor)
    previous = {sig: signal.signal(sig, graph.stops.handle) for sig in (signal.SIGINT, signal.SIGTERM)}
    rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)
    try:
        graph.build()
        if graph.ended_by is None:
            graph.spin()
        graph.finish()
        rc = graph.rc()
        if status_file:
            Path(status_file).write_text(json.dumps({"ended_by": graph.ended_by, "status": graph.status, "rc": rc}) + "\n")
        graph.tear_down()
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return rc


def main(argv=None) -> int:
    import argparse

    parser = argparse.ArgumentParser(
        prog="python -m dlo_bringup.composed",
        description="Run the graph GRAPH_JSON in one process (what scripts/launch_graph.sh --composed starts).",
    )
    parser.add_argument("graph", metavar="GRAPH_JSON", help="the graph's nodes: a list of dlo_bringup.graph.NodeSpec.to_dict()")
    parser.add_argument("status", metavar="STATUS_JSON", nargs="?", help="write the nodes' exit statuses here at the end")
    parser.add_argument("--executor", choices=EXECUTORS, default=EXECUTORS[0], help="the executor (default %(default)s)")
    args = parser.parse_args(argv)
    try:
        specs = read_specs(args.graph)
    except (OSError, ValueError, TypeError, KeyError) as error:
        print(f"dlo_bringup.composed: cannot read {args.graph}: {error}", file=sys.stderr)
        return 2
    started = time.monotonic()
    rc = run(specs, args.status, args.executor)
    print(f"{RUNNER}ended after {time.monotonic() - started:.1f} s (status {rc})", file=sys.stderr, flush=True)
    return rc


if __name__ == "__main__":
    sys.exit(main())
