"""The launcher: ``scripts/launch_graph.sh`` (``ros2 run dlo_bringup launch_graph``).

Starts the graph that :func:`dlo_bringup.graph.graph_nodes` describes as separate processes on a DDS domain of
its own, prints one line per finished episode and a periodic status line while it runs, stops every process it
started, prints the outcome table headed by what produced it, and fails loudly (exit codes in ``--help``) when a
node dies or the recording fails. Nodes run with ``ros2 run`` on a real ROS 2 install, with scripts/ros2run on
the wheels (or when DLO_USE_ROS2RUN is set).

It signals only its own children that still run (a pid of a child it has reaped may belong to another process
by now), waits :data:`dlo_bringup.graph.STOP_LIMIT` s after SIGINT before it kills a node, and tells a recorder
whose middleware teardown was cut after it closed a complete bag from a failed recording.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from dlo_bringup.options import GraphOptions, UsageError, parse_args

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_NODE_FAILED, EXIT_RECORDING_FAILED, EXIT_INTERRUPTED = 0, 1, 2, 3, 4, 130
POLL = 0.2  # s between looks at the graph while it runs
SIM_START_LIMIT = 120.0  # s for the sim to say it is alone on its domain
FOXGLOVE_START_LIMIT = 30.0  # s for another node with a ready line (the Foxglove bridge: its URL) to say it
MONITOR_STOP_LIMIT = 5.0  # s for the /clock counter to stop after SIGTERM
# an example of the lines the graph prints while it runs (tests/test_launch_graph_exit_codes.py: as printed)
EPISODE_EXAMPLE = (
    "[launch] episode 0 (seed 0; 1/5 done): hold_the_end, authors' rule hold_the_end; return 4.321, "
    "97 steps, 0 particles from the end"
)
STATUS_EXAMPLE = "[launch] status: 11.8 steps/s (sim time x0.94), 1/5 episodes done, nodes alive 4/4; policy: no tactile input"


def usage() -> str:
    import textwrap

    from dlo_bringup.options import OPTIONS

    lines = ["usage: scripts/launch_graph.sh [options]   (or: ros2 run dlo_bringup launch_graph [options])"]
    for name, metavar, _, text in OPTIONS:
        head = f"  --{name} {metavar}"
        head = head.ljust(23) if len(head) < 23 else head + "  "
        lines += textwrap.wrap(text, 112, initial_indent=head, subsequent_indent=" " * 23)
    lines.append("  -h, --help           this help")
    lines += [
        "",
        *textwrap.wrap(
            "output (stdout): the chosen domain and how to watch it, each node's pid and log; while the graph runs one "
            "line per finished episode, e.g.",
            112,
        ),
        EPISODE_EXAMPLE,
        "and every S s a status line, e.g.",
        STATUS_EXAMPLE,
        *textwrap.wrap(
            "at the end a header naming the policy, checkpoint, ablation, tactile noise, mode, task rules and seeds, "
            "then the outcome table under both outcome rules (time at end: control steps; from end: particles), and "
            "where the logs are when they are kept.",
            112,
        ),
        "",
        *textwrap.wrap(
            "The same graph on a real ROS 2 install: ros2 launch dlo_bringup graph.launch.py episodes:=5 ... (each "
            "option as an argument, --task-rules R as task_rules:=R; --show-args lists them).",
            112,
        ),
        "",
        "exit status:",
        "  0    every episode ran (and the bag, with --record, is complete)",
        "  2    bad option, or a node rejected its parameters",
        "  3    a node died or exited early (also the sim interrupted on its own, or the sim refusing to",
        "       start because another simulator publishes on the domain); the graph was stopped",
        "  4    the recording failed (a write error such as a full disk, or the recorder died or dropped",
        "       messages); the graph was stopped and the cause printed",
        "  130  interrupted (Ctrl-C or SIGTERM to the launcher)",
    ]
    return "\n".join(lines)


def say(line: str) -> None:
    """A line on stdout; once its reader has gone (``| head``), the rest goes nowhere and the run goes on."""
    try:
        print(line, flush=True)
    except BrokenPipeError:
        sys.stdout = open(os.devnull, "w")


def describe(status: int) -> str:
    """An exit status in words: 130 is what a node returns when interrupted, or SIGINT's status."""
    if status == 130:
        return "status 130: interrupted by SIGINT"
    if 131 <= status <= 255:
        try:
            name = signal.Signals(status - 128).name
        except ValueError:
            name = f"SIG{status - 128}"
        return f"status {status}: killed by {name}"
    return f"status {status}"


def watch_hint(domain: int) -> str:
    """How to list the graph's topics from another terminal, with what this machine has: ``ros2 topic list`` on
    a ROS 2 install, dlo_bringup's topic_list on the wheels (no ros2 command there)."""
    if shutil.which("ros2"):
        return f"ROS_DOMAIN_ID={domain} ros2 topic list"
    root = repository_root()
    ros2run = "scripts/ros2run" if root is None or Path.cwd() == root.resolve() else f"{root}/scripts/ros2run"
    return f"ROS_DOMAIN_ID={domain} {ros2run} dlo_bringup topic_list"


def repository_root() -> Path | None:
    """The dlo-vitac checkout (scripts/ros2run, docs/): DLO_ROOT, or the source tree this module is in."""
    if os.environ.get("DLO_ROOT"):
        return Path(os.environ["DLO_ROOT"])
    here = Path(__file__).resolve()
    root = here.parents[4] if len(here.parents) > 4 else None
    return root if root is not None and (root / "scripts" / "ros2run").exists() else None


class Child:
    """A process the launcher started. Its exit status is read with ``poll`` (which reaps it): once it is known,
    the process is no longer signalled (its pid may be another process's by then)."""

    def __init__(self, name: str, proc: subprocess.Popen, log: Path):
        self.name, self.proc, self.log = name, proc, log
        self.signalled = False

    @property
    def status(self) -> int | None:
        """Its exit status as a shell gives it (128 + N when killed by signal N), None while it runs."""
        rc = self.proc.poll()
        return None if rc is None else rc if rc >= 0 else 128 - rc

    def running(self) -> bool:
        return self.status is None

    def signal(self, sig: int) -> None:
        """Send ``sig`` if it still runs (Popen.send_signal looks first, and a child not yet reaped keeps its pid)."""
        if self.running():
            self.proc.send_signal(sig)


class ComposedProcess:
    """The one process of ``--composed`` (:mod:`dlo_bringup.composed`): its output in ``log`` (split into the nodes'
    logs by a :class:`dlo_bringup.composed_logs.LogSplitter`), the nodes' exit statuses in ``status_file``."""

    def __init__(self, proc: subprocess.Popen, log: Path, status_file: Path, splitter):
        self.proc, self.log, self.status_file, self.splitter = proc, log, status_file, splitter
        self.sent: set = set()
        self._report = None

    def report(self) -> dict | None:
        """What the process wrote on its nodes once it ended (``ended_by``, ``status``, ``rc``), None while it runs
        or when it wrote nothing (killed)."""
        if self._report is None and self.proc.poll() is not None:
            try:
                self._report = json.loads(self.status_file.read_text())
            except (OSError, ValueError):
                self._report = {}
        return self._report or None

    def signal(self, sig: int) -> None:
        """``sig`` once (every node of it gets it: one SIGINT stops them all) while it runs."""
        if sig not in self.sent and self.proc.poll() is None:
            self.sent.add(sig)
            self.proc.send_signal(sig)


class ComposedNode(Child):
    """A node of the ``--composed`` process, as the launcher sees a node's process: running while the process runs,
    then the status the process gave it (the process's own when it reported none: killed, or its teardown cut)."""

    def __init__(self, name: str, process: ComposedProcess, log: Path):
        super().__init__(name, process.proc, log)
        self.process = process

    @property
    def status(self) -> int | None:
        rc = Child.status.fget(self)
        report = self.process.report() if rc is not None else None
        if report is None or self.name not in report["status"]:
            return rc
        status = report["status"][self.name]
        return rc if status == 0 and rc != report["rc"] else status  # (0, but the teardown was cut: its 1)

    def signal(self, sig: int) -> None:
        self.process.signal(sig)


class Launcher:
    def __init__(self, options: GraphOptions):
        self.o = options
        self.children: list[Child] = []
        self.failed: Child | None = None  # the node (not the sim) whose end stopped the graph
        self.said_interrupted = False
        self.problems = 0  # failures reported: the temp logs stay
        self.monitor = None
        self.clock_child = None
        self.composed: ComposedProcess | None = None  # --composed: the one process of every node
        self.lock_fd = None
        root = repository_root()
        self.root = root
        if shutil.which("ros2") and not os.environ.get("DLO_USE_ROS2RUN"):
            self.run_cmd = ["ros2", "run"]
        elif root is not None:
            self.run_cmd = [str(root / "scripts" / "ros2run")]
        else:
            raise UsageError("no `ros2` on PATH and no scripts/ros2run (set DLO_ROOT to the dlo-vitac checkout)")
        self.prefix = []
        setpriv = shutil.which("setpriv")
        # A node gets SIGINT (and closes cleanly) if the launcher dies without stopping it (e.g. SIGKILL).
        if setpriv and subprocess.run([setpriv, "--pdeathsig", "INT", "true"], capture_output=True).returncode == 0:
            self.prefix = [setpriv, "--pdeathsig", "INT", "--"]

    # ---- output -----------------------------------------------------------------------------------------------
    @staticmethod
    def say(line: str) -> None:
        say(line)

    def warn(self, line: str, problem: bool = True) -> None:
        print(line, file=sys.stderr, flush=True)
        self.problems += problem

    def show_log_end(self, child: Child) -> None:
        text = child.log.read_text(errors="replace") if child.log.exists() else ""
        if text.strip():
            for line in text.splitlines()[-8:]:
                print(f"    {line}", file=sys.stderr)
        else:
            print(f"    (its log {child.log} is empty)", file=sys.stderr)
        sys.stderr.flush()

    # ---- signals ----------------------------------------------------------------------------------------------
    @property
    def interrupted(self) -> bool:
        return bool(INTERRUPTS)

    def check_interrupt(self) -> bool:
        if self.interrupted and not self.said_interrupted:
            self.said_interrupted = True
            self.say("[launch] interrupted: stopping the graph")
        return self.interrupted

    # ---- processes --------------------------------------------------------------------------------------------
    def inherited_fds(self) -> tuple:
        """The domain's lock: the nodes hold it too, until the last of them has stopped."""
        return (self.lock_fd,) if self.lock_fd is not None and self.lock_fd >= 0 else ()

    def command(self, spec) -> list[str]:
        """The command line that starts the node ``spec`` (a dlo_bringup.graph.NodeSpec)."""
        return [*self.prefix, *self.run_cmd, spec.package, spec.executable, *spec.ros_args()]

    def start(self, spec) -> Child:
        log = self.logs / f"{spec.name}.log"
        with open(log, "w") as out:
            proc = subprocess.Popen(
                self.command(spec),
                stdout=out,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                env=self.env,
                pass_fds=self.inherited_fds(),
            )
        child = Child(spec.name, proc, log)
        self.children.append(child)
        self.say(f"[launch] {spec.name} (pid {proc.pid}) -> {log}")
        return child

    def start_composed(self, specs) -> list[ComposedNode]:
        """--composed: every node of ``specs`` in one process (dlo_bringup.composed), which builds them in their
        order; a view of each node, as its process would be, its lines in its own log."""
        from dlo_bringup.composed_logs import LogSplitter

        graph, status = self.logs / "composed_graph.json", self.logs / "composed_status.json"
        graph.write_text(json.dumps([spec.to_dict() for spec in specs], indent=1) + "\n")
        status.unlink(missing_ok=True)
        log = self.logs / "composed.log"
        logs = {spec.name: self.logs / f"{spec.name}.log" for spec in specs}
        for path in logs.values():
            path.write_text("")
        with open(log, "w") as out:
            proc = subprocess.Popen(
                [*self.prefix, sys.executable, "-m", "dlo_bringup.composed", str(graph), str(status)],
                stdout=out,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                env=self.env,
                pass_fds=self.inherited_fds(),
            )
        self.composed = ComposedProcess(proc, log, status, LogSplitter(log, logs).start())
        self.say(f"[launch] {', '.join(logs)}: one process (pid {proc.pid}, --composed) -> {log}")
        for name, path in logs.items():
            self.children.append(ComposedNode(name, self.composed, path))
            self.say(f"[launch] {name} (pid {proc.pid}) -> {path}")
        return self.children

    def wait_for_line(self, child: Child, line: str, limit: float) -> None:
        """Until ``child`` has printed ``line``, ended, or ``limit`` s passed, or the launcher is interrupted."""
        deadline = time.monotonic() + limit
        while time.monotonic() < deadline and child.running() and not self.check_interrupt():
            if child.log.exists() and line in child.log.read_text(errors="replace"):
                return
            time.sleep(0.1)

    def start_monitor(self, nodes) -> None:
        from dlo_bringup.graph_monitor import ClockReader, Monitor

        clock = None
        period = float(self.o.status_period)
        if period > 0:
            with open(self.logs / "graph_monitor.log", "w") as err:
                self.clock_child = subprocess.Popen(
                    [*self.prefix, sys.executable, "-m", "dlo_bringup.graph_monitor", "--clock-topic", f"{self.o.prefix}/clock"],
                    stdout=subprocess.PIPE,
                    stderr=err,
                    stdin=subprocess.DEVNULL,
                    env=self.env,
                    text=True,
                )
            clock = ClockReader(self.clock_child.stdout)
        by_name = {c.name: c for c in self.children}
        self.monitor = Monitor(
            self.logs / "outcomes.jsonl",
            self.logs,
            int(self.o.episodes),
            period,
            alive=lambda: {name: by_name[name].running() for name in nodes},
            clock=clock,
            say=self.say,
        )

    def stop_clock_child(self) -> None:
        proc = self.clock_child
        if proc is None:
            return
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=MONITOR_STOP_LIMIT)
        except subprocess.TimeoutExpired:
            proc.kill()  # (a hung middleware teardown: it only counted steps)
            proc.wait()

    def stop_graph(self) -> None:
        """SIGINT to every node that still runs, the sim first; the /clock counter stops meanwhile. A node that has
        not stopped STOP_LIMIT s later is killed."""
        from dlo_bringup.graph import STOP_LIMIT

        for child in self.children:
            if not child.signalled:
                child.signal(signal.SIGINT)
                child.signalled = True
        self.stop_clock_child()
        deadline = time.monotonic() + STOP_LIMIT
        while any(c.running() for c in self.children) and time.monotonic() < deadline:
            time.sleep(0.1)
        for child in self.children:
            if child.running():
                self.warn(f"[launch] {child.name} did not stop within {STOP_LIMIT:g} s of SIGINT: killing it")
                child.signal(signal.SIGKILL)
                child.proc.wait()
        if self.composed is not None:
            self.composed.splitter.stop()  # (every line in the nodes' logs)
            report = self.composed.report()
            if report is not None:  # a node it never built is no child, as when it would have had a process
                self.children = [c for c in self.children if c.name in report["status"]]

    # ---- the run ----------------------------------------------------------------------------------------------
    def choose_domain(self) -> int:
        from dlo_bringup.domain import domain_busy, free_domain, lock_domain

        if self.o.domain_id:
            domain = int(self.o.domain_id)
            self.lock_fd = lock_domain(domain)
            if self.lock_fd is None:
                self.warn(
                    f"[launch] warning: ROS_DOMAIN_ID={domain} is held by another launch_graph.sh or test run", problem=False
                )
            if not self.o.namespace and domain_busy(domain):
                self.warn(
                    f"[launch] warning: ROS_DOMAIN_ID={domain} is in use on this machine; without --namespace "
                    "the graphs' topics mix (the sim refuses to start next to another simulator)",
                    problem=False,
                )
            return domain
        found = free_domain()
        if found is None:
            raise UsageError("no free ROS_DOMAIN_ID in 10..99 on this machine; give --domain-id N")
        domain, self.lock_fd = found
        return domain

    def run(self) -> int:
        from dlo_bringup.graph import graph_nodes

        o = self.o
        for note in o.notes:
            print(f"[launch] note: {note}", file=sys.stderr, flush=True)
        domain = self.choose_domain()
        self.temporary = not o.logs
        self.logs = Path(o.logs) if o.logs else Path(tempfile.mkdtemp(prefix="dlo-graph-"))
        self.logs.mkdir(parents=True, exist_ok=True)
        outcomes = self.logs / "outcomes.jsonl"
        outcomes.unlink(missing_ok=True)
        os.environ["ROS_DOMAIN_ID"] = str(domain)
        self.env = dict(os.environ)
        under = f", topics under {o.prefix}/" if o.prefix else ""
        self.say(f"[launch] ROS_DOMAIN_ID={domain}{under} (to watch: {watch_hint(domain)})")
        specs = graph_nodes(o, self.logs)
        try:
            rc = self.supervise(specs, outcomes)
        finally:
            for child in self.children:  # (an error in the launcher itself: no node outlives it)
                if child.running():
                    child.signal(signal.SIGINT)
            self.stop_clock_child()
        rc = self.report(rc, outcomes)
        self.finish_logs(rc)
        return rc

    def supervise(self, specs, outcomes: Path) -> int:
        """Start the graph, watch it, stop it: the exit status before the recording's is looked at."""
        composed = self.o.composed == "true"
        sim = self.start_composed(specs)[0] if composed else self.start(specs[0])
        self.wait_for_line(sim, specs[0].ready_line, SIM_START_LIMIT)
        if sim.running() and not self.check_interrupt():
            for spec in specs[1:]:
                child = self.child(spec.name) if composed else self.start(spec)  # (--composed: built in turn)
                if spec.ready_line:  # (the Foxglove bridge: its URL is printed before the rest starts)
                    self.wait_for_line(child, spec.ready_line, FOXGLOVE_START_LIMIT)
                if spec.name == "foxglove":
                    self.show_foxglove_url(child)
                if self.check_interrupt():
                    break
            else:
                self.start_monitor([spec.name for spec in specs])
        failed = None
        while sim.running() and not self.check_interrupt() and failed is None:
            failed = self.ended_early()
            if self.monitor is not None:
                self.monitor.tick()
            if failed is None:
                time.sleep(POLL)
        failed = failed or (self.ended_early() if composed else None)  # (its nodes end together)
        self.stop_graph()
        if self.monitor is not None:
            self.monitor.report_episodes()  # those that finished while the graph stopped
        self.failed = failed
        done = len([line for line in outcomes.read_text().splitlines() if line.strip()]) if outcomes.exists() else 0
        if self.check_interrupt():
            return EXIT_INTERRUPTED
        if failed is not None:
            status = failed.status
            cause = self.recorder_failure() if failed.name == "recorder" else ""
            if cause:
                self.warn(f"[launch] {cause}: the recorder stopped ({describe(status)}); graph stopped")
                return EXIT_RECORDING_FAILED
            self.warn(f"[launch] {failed.name} exited early ({describe(status)}); the end of its log:")
            self.show_log_end(failed)
            if failed.name == "recorder":
                return EXIT_RECORDING_FAILED
            return EXIT_USAGE if status == 2 else EXIT_NODE_FAILED
        episodes = int(self.o.episodes)
        if sim.status == 0 and episodes != 0 and done >= episodes:
            return EXIT_OK
        self.warn(
            f"[launch] sim exited early ({describe(sim.status)}, {done} of {episodes or 'unlimited'} episodes "
            "done); the end of its log:"
        )
        self.show_log_end(sim)
        return EXIT_USAGE if sim.status == 2 else EXIT_NODE_FAILED

    def ended_early(self) -> Child | None:
        """The node (not the sim) that has ended while the graph runs; --composed: the one whose end ended the
        process, as it reported (the others only stopped with it)."""
        if self.composed is None:
            return next((c for c in self.children[1:] if not c.running()), None)
        report = self.composed.report()
        ended_by = report.get("ended_by") if report else None
        return next((c for c in self.children[1:] if c.name == ended_by), None)

    def show_foxglove_url(self, child: Child) -> None:
        text = child.log.read_text(errors="replace") if child.log.exists() else ""
        url = re.search(r"open (https://[^ \n]*)", text)
        ws = re.search(r"ws://[0-9.]*:[0-9]*", text)
        if url:
            layout = self.root / "docs" / "foxglove" / "dlo_vitac.json" if self.root else "docs/foxglove/dlo_vitac.json"
            self.say(f"[launch] Foxglove live view: open {url.group(1)}")
            self.say(
                f"[launch]   (Foxglove app: Open connection -> Foxglove WebSocket -> {ws.group(0) if ws else '?'}; "
                f"layout: {layout})"
            )

    def child(self, name: str) -> Child | None:
        return next((c for c in self.children if c.name == name), None)

    def recorder_failure(self) -> str:
        """The one-line cause the recorder logged, if any."""
        recorder = self.child("recorder")
        if recorder is None or not recorder.log.exists():
            return ""
        found = re.search(r"recording failed: [^(;\n]*", recorder.log.read_text(errors="replace"))
        return found.group(0).rstrip() if found else ""

    def complete_recording(self) -> dict | None:
        """The recorder's summary when it says the bag is complete (every message written, every part closed,
        no write error), else None."""
        try:
            summary = json.loads((self.logs / "recorder_summary.json").read_text())
        except (OSError, ValueError):
            return None
        if summary.get("dropped") == 0 and summary.get("complete") and not summary.get("failure"):
            return summary
        return None

    def report(self, rc: int, outcomes: Path) -> int:
        """The outcome table, then what the recording left: the exit status."""
        from dlo_bag.outcome_table import outcome_table, read_episodes, run_header

        o = self.o
        policy = self.child("policy")
        policy_line = ""
        if policy is not None and policy.log.exists():
            found = re.search(r"policy [a-z_]* on [^;\n]*", policy.log.read_text(errors="replace"))
            policy_line = found.group(0) if found else ""
        try:
            episodes = read_episodes(str(outcomes))
        except FileNotFoundError:
            print(f"no finished episodes ({outcomes} does not exist)", file=sys.stderr, flush=True)
        except (OSError, ValueError) as error:
            print(f"[launch] cannot read {outcomes}: {error}", file=sys.stderr, flush=True)
        else:
            self.say(
                run_header(
                    episodes,
                    o.policy,
                    o.checkpoint,
                    o.without,
                    o.tactile_noise,
                    o.mode,
                    policy_line,
                    o.train_out,
                    o.perturbations,
                )
            )
            self.say(outcome_table(episodes))
        if not o.record:
            return rc
        recorder = self.child("recorder")
        status = recorder.status if recorder is not None else None
        failed_recorder = self.failed is not None and self.failed.name == "recorder"
        cause = self.recorder_failure()
        interrupted = rc == EXIT_INTERRUPTED  # stays the exit status whatever else failed
        if cause:
            if not failed_recorder:
                self.warn(f"[launch] {cause} (see {recorder.log})")
            rc = rc if interrupted else EXIT_RECORDING_FAILED
        elif status == 1:
            summary = self.complete_recording()
            if summary is not None and bag_closed(Path(o.record)):
                self.warn(
                    f"[launch] the recorder's middleware teardown was cut short after it had closed the bag "
                    f"(status 1; its stacks: {recorder.log}); the recording is complete: "
                    f"{summary.get('written')} messages written, none dropped",
                    problem=False,
                )
            else:
                self.warn(f"[launch] recording incomplete: the recorder dropped messages (see {recorder.log})")
                rc = rc if interrupted else EXIT_RECORDING_FAILED
        elif status not in (None, 0) and not failed_recorder and not (interrupted and status == 130):
            # (130 when interrupted: it was still starting)
            self.warn(f"[launch] the recorder ended with {describe(status)}; the end of its log:")
            self.show_log_end(recorder)
            rc = rc if interrupted else EXIT_RECORDING_FAILED
        if bag_closed(Path(o.record)):
            self.say(f"[launch] bag: {o.record} (inspect: dlo-bag-info {o.record})")
        elif os.path.exists(o.record):
            self.warn(f"[launch] the bag {o.record} is incomplete: recover it with: dlo-bag-recover {o.record}")
            rc = rc if interrupted else EXIT_RECORDING_FAILED
        return rc

    def finish_logs(self, rc: int) -> None:
        """A temp logs directory goes when the run went well (every episode, or interrupted with nothing else
        wrong); kept, it is named."""
        failed = rc not in (EXIT_OK, EXIT_INTERRUPTED) or self.problems
        if self.temporary and not failed:
            shutil.rmtree(self.logs, ignore_errors=True)
        elif self.temporary:
            self.say(f"[launch] logs kept (the run failed): {self.logs}")


def bag_closed(record: Path) -> bool:
    """A bag (or every part of a split one) closed with its metadata.yaml."""
    return (record / "metadata.yaml").is_file() or any(record.glob("*/metadata.yaml"))


INTERRUPTS: list[int] = []  # SIGINT / SIGTERM received: the graph is stopped, exit 130


def main(argv=None) -> int:
    sys.stdout.reconfigure(line_buffering=True)
    INTERRUPTS.clear()
    for sig in (signal.SIGINT, signal.SIGTERM):  # (its nodes start with both at their default)
        signal.signal(sig, lambda signum, frame: INTERRUPTS.append(signum))
    try:
        options = parse_args(sys.argv[1:] if argv is None else argv)
        if options.help:
            say(usage())
            return EXIT_OK
        from dlo_bringup.options import resolve

        options = resolve(options)
        launcher = Launcher(options)
    except UsageError as error:
        print(f"launch_graph: {error}", file=sys.stderr, flush=True)
        return EXIT_USAGE
    if INTERRUPTS:
        return EXIT_INTERRUPTED
    try:
        return launcher.run()
    except UsageError as error:  # (no free domain)
        print(f"launch_graph: {error}", file=sys.stderr, flush=True)
        return EXIT_USAGE


if __name__ == "__main__":
    sys.exit(main())
