"""dlo_bringup.composed with stand-in nodes (no simulator): each node's exit status is the one its own process would
have had (node_main.run_node's statuses and lines), the node whose end ended the graph is named, a signal stops
every node, and the nodes' lines reach their own logs (dlo_bringup.composed_logs)."""

from __future__ import annotations

import json
import os
import pathlib
import signal
import subprocess
import sys
import time

import pytest

STANDINS = """
import os
import signal

from dlo_common.node_util import NodeStartError, declare_parameters
from dlo_common.params import Param
from rclpy.node import Node
from std_msgs.msg import Int32

PARAMETERS = (
    Param("ticks", 0, "sim: ticks before it ends as sim_node after its episodes (0 = never)", at_least=0),
    Param("fail_at", 0, "worker: the tick at which it fails (0 = never)", at_least=0),
    Param("failure", "refuse", "worker: refuse (NodeStartError) or crash (RuntimeError)"),
    Param("finish_fails", False, "worker: its finish() raises"),
    Param("signal_at", 0, "worker: the tick at which it sends its process SIGINT (0 = never)", at_least=0),
    Param("busy", False, "both: ping-pong (the sim ticks again as soon as the worker answered): never idle"),
)


class Sim(Node):
    def __init__(self, **options):
        super().__init__("sim_node", **options)
        self.p = declare_parameters(self, PARAMETERS)
        self.tick = 0
        self.pub = self.create_publisher(Int32, "/standin/tick", 10)
        self.get_logger().info("alone on ROS_DOMAIN_ID")
        self.create_timer(0.02, self.on_timer)
        self.create_subscription(Int32, "/standin/answer", lambda msg: self.on_timer(), 10)

    def on_timer(self):
        self.tick += 1
        self.pub.publish(Int32(data=self.tick))
        if self.p["ticks"] and self.tick >= self.p["ticks"]:
            self.get_logger().info("ran its episodes: exiting")
            raise SystemExit(0)


class Worker(Node):
    def __init__(self, **options):
        super().__init__("worker_node", **options)
        self.p = declare_parameters(self, PARAMETERS)
        self.create_subscription(Int32, "/standin/tick", self.on_tick, 10)
        self.answer = self.create_publisher(Int32, "/standin/answer", 10)
        self.get_logger().info("worker up")

    def on_tick(self, msg):
        if self.p["busy"]:
            self.answer.publish(msg)
        if msg.data == self.p["signal_at"]:
            os.kill(os.getpid(), signal.SIGINT)
        if msg.data == self.p["fail_at"]:
            if self.p["failure"] == "refuse":
                raise NodeStartError("the hardware went away")
            raise RuntimeError("a bug in the worker")

    def finish(self):
        self.get_logger().info("worker finished")
        if self.p["finish_fails"]:
            raise OSError("disk full")
"""

# case: (sim parameters, worker parameters, ended_by, {node: status}, process exit status, lines in the output)
CASES = {
    "the_sim_ends": ({"ticks": 10}, {}, "sim", {"sim": 0, "worker": 0}, 0, ["[INFO]", "worker finished"]),
    "a_callback_refuses": (
        {},
        {"fail_at": 3},
        "worker",
        {"sim": 130, "worker": 3},
        3,
        ["[worker_node] the hardware went away"],
    ),
    "a_callback_crashes": (
        {},
        {"fail_at": 3, "failure": "crash"},
        "worker",
        {"sim": 130, "worker": 1},
        1,
        ["[worker_node] failed while it ran:", "RuntimeError: a bug in the worker"],
    ),
    "a_bad_parameter": (
        {},
        {"nosuch": 1},
        "worker",
        {"sim": 130, "worker": 2},
        2,
        ["[worker_node] unknown parameter 'nosuch'"],
    ),
    "a_finish_fails": (
        {"ticks": 10},
        {"finish_fails": True},
        "sim",
        {"sim": 0, "worker": 1},
        1,
        ["[worker_node] could not finish: OSError: disk full"],
    ),
    "a_signal": ({}, {"signal_at": 5}, "signal", {"sim": 130, "worker": 0}, 130, ["worker finished"]),
}


def spec(name, plugin, parameters):
    return {
        "name": name,
        "package": "standins",
        "executable": f"{name}_node",
        "parameters": [[key, value] for key, value in parameters.items()],
        "remappings": [],
        "ready_line": "",
        "plugin": plugin,
    }


@pytest.mark.parametrize("case", sorted(CASES))
def test_each_node_ends_with_its_own_status(case, tmp_path, own_groups):
    sim, worker, ended_by, status, rc, lines = CASES[case]
    (tmp_path / "standins.py").write_text(STANDINS)
    graph, report, log = tmp_path / "graph.json", tmp_path / "status.json", tmp_path / "composed.log"
    graph.write_text(json.dumps([spec("sim", "standins:Sim", sim), spec("worker", "standins:Worker", worker)]))
    env = {**os.environ, "PYTHONPATH": f"{tmp_path}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    with log.open("w") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "dlo_bringup.composed", str(graph), str(report)],
            stdout=out,
            stderr=subprocess.STDOUT,
            env=env,
            start_new_session=True,
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
        )
    own_groups(proc.pid)
    assert proc.wait(timeout=120) == rc, log.read_text()
    text = log.read_text()
    assert json.loads(report.read_text()) == {"ended_by": ended_by, "status": status, "rc": rc}, text
    for line in lines:
        assert line in text, text
    assert ("Traceback" in text) == (case == "a_callback_crashes"), text


@pytest.mark.parametrize("busy", [False, True])
def test_a_sigint_stops_it_and_a_second_soon_after_the_first_changes_nothing(busy, tmp_path, own_groups):
    """Ctrl-C in a terminal reaches the process twice (its own and the launcher's): one stop, statuses as for one;
    also while a callback is always ready (a step-locked graph at full speed: the executor is never idle)."""
    (tmp_path / "standins.py").write_text(STANDINS)
    graph, report, log = tmp_path / "graph.json", tmp_path / "status.json", tmp_path / "composed.log"
    graph.write_text(json.dumps([spec("sim", "standins:Sim", {"busy": busy}), spec("worker", "standins:Worker", {"busy": busy})]))
    env = {**os.environ, "PYTHONPATH": f"{tmp_path}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    with log.open("w") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "dlo_bringup.composed", str(graph), str(report)],
            stdout=out,
            stderr=subprocess.STDOUT,
            env=env,
            start_new_session=True,
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
        )
    own_groups(proc.pid)
    deadline = time.monotonic() + 60
    while "[composed] built worker" not in log.read_text() and time.monotonic() < deadline:
        time.sleep(0.1)
    time.sleep(0.5)  # (busy: ticking)
    proc.send_signal(signal.SIGINT)
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=20) == 130, log.read_text()
    assert json.loads(report.read_text()) == {"ended_by": "signal", "status": {"sim": 130, "worker": 0}, "rc": 130}
    assert "stopped by a second" not in log.read_text()


def test_the_launcher_reads_the_nodes_statuses_as_their_processes():
    """A node's view in the launcher: running while the process runs, then its reported status; the process's own
    status where it reported none for the node (killed) or its teardown was cut (status 0 reported, 1 exited)."""
    from dlo_bringup.launcher import ComposedNode, ComposedProcess

    class Proc:
        def __init__(self, rc):
            self.rc, self.pid = rc, 1

        def poll(self):
            return self.rc

    def view(name, rc, report):
        path = pathlib.Path(os.devnull)
        process = ComposedProcess(Proc(rc), path, path, None)
        process._report = report
        return ComposedNode(name, process, path)

    report = {"ended_by": "policy", "status": {"sim": 130, "policy": 2}, "rc": 2}
    assert view("policy", None, report).status is None and view("policy", None, report).running()
    assert view("policy", 2, report).status == 2 and view("sim", 2, report).status == 130
    assert view("sim", -9, {}).status == 137  # killed: no report, every node the process's status
    cut = {"ended_by": "sim", "status": {"sim": 0, "recorder": 0}, "rc": 0}
    assert view("sim", 1, cut).status == 1 and view("recorder", 1, cut).status == 1  # the teardown was cut
