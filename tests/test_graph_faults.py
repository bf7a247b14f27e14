"""Faults and modes of the graph: bad commands, real-time rate and command timeout, a policy node
killed and restarted mid-episode, missing perception, malformed parameters."""

import os
import pathlib
import signal
import subprocess
import time

import numpy as np
import pytest
import rclpy
from rosgraph_msgs.msg import Clock

from dlo_msgs.msg import GripperCommand, GripperState, TaskState

ROOT = pathlib.Path(__file__).resolve().parents[1]
ROS2RUN = str(ROOT / "scripts" / "ros2run")


def start(pkg, exe, *params, log=None):
    args = [ROS2RUN, pkg, exe, "--ros-args"] + [a for p in params for a in ("-p", p)]
    return subprocess.Popen(args, stdout=log or subprocess.DEVNULL, stderr=subprocess.STDOUT)


def stop(*procs):
    for proc in procs:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
    for proc in procs:
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


class Probe:
    """A test-side node that watches the sim's outputs and can send commands."""

    def __init__(self):
        rclpy.init()
        self.node = rclpy.create_node("fault_probe")
        self.states, self.tasks, self.clock = [], [], []
        self.node.create_subscription(GripperState, "/dlo/gripper/state", self.states.append, 100)
        self.node.create_subscription(TaskState, "/dlo/task/state", self.tasks.append, 100)
        self.node.create_subscription(Clock, "/clock", lambda m: self.clock.append((time.monotonic(), m)), 100)
        self.cmd = self.node.create_publisher(GripperCommand, "/dlo/gripper/cmd", 10)

    def spin_until(self, condition, timeout):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if condition():
                return True
            rclpy.spin_once(self.node, timeout_sec=0.05)
        return condition()

    def spin_for(self, seconds):
        self.spin_until(lambda: False, seconds)

    def send(self, state, vx, vy, closure):
        msg = GripperCommand(vx=vx, vy=vy, closure=closure, episode=state.episode, step=state.step)
        msg.header = state.header
        self.cmd.publish(msg)

    def close(self):
        self.node.destroy_node()
        rclpy.shutdown()


@pytest.fixture
def probe():
    p = Probe()
    yield p
    p.close()


def test_bad_commands_are_rejected_and_the_gripper_holds(probe, tmp_path):
    log = open(tmp_path / "sim.log", "w")
    sim = start("dlo_sim", "sim_node", "min_subscribers:=1", "publish_markers:=false", log=log)
    try:
        assert probe.spin_until(lambda: probe.states, 120), "sim never published"
        for vx, closure in ((float("nan"), 0.5), (3.0, 0.5), (0.1, 1.7)):
            state = probe.states[-1]
            probe.send(state, vx, 0.0, closure)
            assert probe.spin_until(lambda: probe.states[-1].step == state.step + 1, 20)
            after = probe.states[-1]
            assert (after.x, after.y, after.closure) == pytest.approx((state.x, state.y, state.closure), abs=1e-6)
    finally:
        stop(sim)
    text = (tmp_path / "sim.log").read_text()
    assert text.count("rejected command") == 3 and "Traceback" not in text


def test_real_time_mode_holds_its_rate_and_stops_on_stale_commands(probe):
    sim = start("dlo_sim", "sim_node", "mode:=real_time", "command_timeout:=0.3", "publish_markers:=false")
    try:
        assert probe.spin_until(lambda: len(probe.clock) > 5, 120)
        probe.clock.clear()
        probe.spin_for(3.0)
        (w0, c0), (w1, c1) = probe.clock[0], probe.clock[-1]
        sim_seconds = (c1.clock.sec - c0.clock.sec) + (c1.clock.nanosec - c0.clock.nanosec) / 1e9
        assert 0.6 < sim_seconds / (w1 - w0) < 1.4  # simulated time advances at the wall-clock rate
        start_x = probe.states[-1].x
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline:  # a live controller: drive +x
            probe.send(probe.states[-1], 0.25, 0.0, 0.6)  # sliding grip (a firm one stalls on the taut cable)
            probe.spin_for(0.05)
        assert probe.states[-1].x > start_x + 0.02
        probe.spin_for(0.6)  # commands stop: after the timeout the gripper stands still
        x_after_timeout = probe.states[-1].x
        probe.spin_for(1.0)
        assert probe.states[-1].x == pytest.approx(x_after_timeout, abs=1e-6)
    finally:
        stop(sim)


def test_policy_restart_mid_episode_resumes_the_graph(probe, tmp_path):
    sim = start("dlo_sim", "sim_node", "episodes:=1", "horizon:=40", "min_subscribers:=4", "seed:=3",
                log=open(tmp_path / "sim.log", "w"))
    perception = [start("dlo_perception", "tactile_node"), start("dlo_perception", "vision_node")]
    policy = start("dlo_policy", "policy_node", "policy:=tactile_reactive")
    try:
        assert probe.spin_until(lambda: probe.tasks and probe.tasks[-1].step >= 10, 180), [
            (t.step, t.done) for t in probe.tasks[-3:]]
        policy.kill()
        policy.wait()
        probe.spin_for(1.0)
        paused_at = probe.tasks[-1].step
        probe.spin_for(1.5)
        assert probe.tasks[-1].step == paused_at  # step-locked: the sim waits safely for a command
        assert not probe.tasks[-1].done
        policy = start("dlo_policy", "policy_node", "policy:=tactile_reactive")
        assert sim.wait(timeout=120) == 0  # the episode completes and the sim exits
        assert any(t.done for t in probe.tasks) or probe.spin_until(lambda: any(t.done for t in probe.tasks), 5)
    finally:
        stop(policy, *perception, sim)


def test_missing_perception_is_reported_without_deadlock(probe, tmp_path):
    policy_log = tmp_path / "policy.log"
    sim = start("dlo_sim", "sim_node", "episodes:=1", "horizon:=15", "min_subscribers:=3", "publish_markers:=false")
    vision = start("dlo_perception", "vision_node")
    policy = start("dlo_policy", "policy_node", "policy:=random", "modalities:=All", "input_timeout:=0.5",
                   log=open(policy_log, "w"))
    tactile = None
    try:
        assert probe.spin_until(lambda: "no tactile input" in policy_log.read_text(), 180), policy_log.read_text()
        assert probe.tasks and probe.tasks[-1].step == 0
        tactile = start("dlo_perception", "tactile_node")  # the missing node comes up: the graph proceeds
        assert sim.wait(timeout=120) == 0
    finally:
        stop(*(p for p in (policy, vision, tactile, sim) if p is not None))


@pytest.mark.parametrize("pkg,exe,param,expected", [
    ("dlo_sim", "sim_node", "mode:=warp_speed", "parameter 'mode'"),
    ("dlo_sim", "sim_node", "horizon:=-3", "parameter 'horizon'"),
    ("dlo_perception", "tactile_node", "noise:=loud", "unknown tactile noise preset"),
    ("dlo_policy", "policy_node", "checkpoint:=/nonexistent/policy.pt", "does not exist"),
    ("dlo_policy", "policy_node", "policy:=magic", "parameter 'policy'"),
])
def test_malformed_parameters_give_a_clear_message(pkg, exe, param, expected):
    result = subprocess.run([ROS2RUN, pkg, exe, "--ros-args", "-p", param], capture_output=True, text=True, timeout=120)
    output = result.stdout + result.stderr
    assert result.returncode == 2, output
    assert expected in output and "Traceback" not in output
