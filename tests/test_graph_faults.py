"""Faults and modes of the graph: bad, foreign and stale commands (step-locked and real-time), real-time
rate and command timeout, a policy node killed and restarted mid-episode, missing perception, a second
simulator on the same domain, a recorder that lacks a topic, perception nodes interrupted mid-stream,
malformed parameters."""

import os
import pathlib
import signal
import subprocess
import time

import pytest
import rclpy
from dlo_msgs.msg import GripperCommand, GripperState, TactilePose, TaskState, VisualPose
from harness import stop_all_or_explain
from rosgraph_msgs.msg import Clock

ROOT = pathlib.Path(__file__).resolve().parents[1]
ROS2RUN = str(ROOT / "scripts" / "ros2run")


def start(pkg, exe, *params, log=None):
    """A node of the graph (PYTHONFAULTHANDLER: its Python stacks, should it hang at stop), output to ``log``."""
    args = [ROS2RUN, pkg, exe, "--ros-args"] + [a for p in params for a in ("-p", p)]
    proc = subprocess.Popen(
        args, stdout=log or subprocess.DEVNULL, stderr=subprocess.STDOUT, env={**os.environ, "PYTHONFAULTHANDLER": "1"}
    )
    proc.log = pathlib.Path(log.name) if log is not None else None
    return proc


def log_text(path):
    return path.read_text(errors="replace") if path.exists() else ""


def stop(*procs, timeout=30):
    """SIGINT the nodes; one that does not stop within ``timeout`` s fails the test with its stacks."""
    stop_all_or_explain(
        [
            (proc, proc.args[2], lambda proc=proc: log_text(proc.log) if proc.log is not None else "(started without a log)")
            for proc in procs
        ],
        timeout,
    )


class Probe:
    """A test-side node that watches the sim's outputs and can send commands."""

    def __init__(self):
        rclpy.init()
        self.node = rclpy.create_node("fault_probe")
        self.states, self.tasks, self.clock, self.tactile, self.vision = [], [], [], [], []
        self.node.create_subscription(GripperState, "/dlo/gripper/state", self.states.append, 100)
        self.node.create_subscription(TactilePose, "/dlo/tactile/pose", self.tactile.append, 100)
        self.node.create_subscription(VisualPose, "/dlo/vision/pose", self.vision.append, 100)
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

    def send(self, state, vx, vy, closure, episode=None, step=None):
        msg = GripperCommand(
            vx=vx,
            vy=vy,
            closure=closure,
            episode=state.episode if episode is None else episode,
            step=state.step if step is None else step,
        )
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
            assert probe.spin_until(lambda state=state: probe.states[-1].step == state.step + 1, 20)
            after = probe.states[-1]
            assert (after.x, after.y, after.closure) == pytest.approx((state.x, state.y, state.closure), abs=1e-6)
        # step-locked: a command for an old step, a future step or another episode does not advance the sim
        state = probe.states[-1]
        for episode, step in (
            (state.episode, state.step - 1),
            (state.episode, state.step + 1),
            (999, 99999),
            (state.episode + 1, state.step),
        ):
            probe.send(state, 0.25, 0.0, 0.6, episode=episode, step=step)
        probe.spin_for(1.5)  # (a republished state keeps its step)
        assert probe.states[-1].step == state.step and probe.states[-1].episode == state.episode
        assert (probe.states[-1].x, probe.states[-1].closure) == pytest.approx((state.x, state.closure), abs=1e-9)
        probe.send(state, 0.25, 0.0, 0.6)  # the answer to the current step does
        assert probe.spin_until(lambda state=state: probe.states[-1].step == state.step + 1, 20)
        # the two "episode" rejections share a line a second: the second is logged (counted) once 1 s has passed
        assert probe.spin_until(lambda: log_text(tmp_path / "sim.log").count("rejected command") >= 7, 20)
    finally:
        stop(sim)
    text = (tmp_path / "sim.log").read_text()
    assert text.count("rejected command") == 7 and "Traceback" not in text, text
    for cause in (
        "non-finite",
        "speed out of range",
        "closure out of range",
        "not the current step",
        "ahead of the current step",
        "for episode 999",
        f"for episode {state.episode + 1}",
    ):
        assert cause in text, cause


def test_real_time_mode_holds_its_rate_and_stops_on_stale_commands(probe, tmp_path):
    sim = start(
        "dlo_sim",
        "sim_node",
        "mode:=real_time",
        "command_timeout:=0.3",
        "publish_markers:=false",
        "horizon:=1000",
        log=open(tmp_path / "sim.log", "w"),
    )  # one episode for the whole test
    try:
        assert probe.spin_until(lambda: len(probe.clock) > 5, 120)
        probe.clock.clear()
        probe.spin_for(3.0)
        (w0, c0), (w1, c1) = probe.clock[0], probe.clock[-1]
        sim_seconds = (c1.clock.sec - c0.clock.sec) + (c1.clock.nanosec - c0.clock.nanosec) / 1e9
        assert 0.6 < sim_seconds / (w1 - w0) < 1.4  # simulated time advances at the wall-clock rate
        start_x, episode = probe.states[-1].x, probe.states[-1].episode
        answered = 0
        while answered < 3:  # a live controller answers 3 states (not further: at the cable's end the episode ends)
            state = probe.states[-1]
            # sliding grip (a firm one stalls on the taut cable; at 0.6 the stopped gripper loses the cable)
            probe.send(state, 0.1, 0.0, 0.7)
            answered += 1
            assert probe.spin_until(lambda state=state: probe.states[-1].step > state.step, 10)
        # commands stop: after the timeout (0.3 s) the gripper stands still, in the same episode (6 states alike)
        assert probe.spin_until(
            lambda state=state: probe.states[-6].step > state.step and len({s.x for s in probe.states[-6:]}) == 1, 10
        )
        x_after_timeout, closure = probe.states[-1].x, probe.states[-1].closure
        assert x_after_timeout > start_x + 0.02  # it did follow the live commands
        probe.spin_for(1.0)
        assert probe.states[-1].x == pytest.approx(x_after_timeout, abs=1e-6)
        assert probe.states[-1].closure == pytest.approx(closure, abs=1e-6) and probe.states[-1].episode == episode
        # commands for another episode, for a far future step or for a step older than command_timeout
        # (0.3 s = 3.75 steps) are not obeyed: the gripper keeps standing still
        for stamp in ((999, 99999), (episode, None), (episode, 10**6)):
            deadline = time.monotonic() + 1.0
            while time.monotonic() < deadline:
                state = probe.states[-1]
                step = state.step - 6 if stamp[1] is None else stamp[1]
                probe.send(state, 0.25, 0.0, 0.7, episode=stamp[0], step=step)
                probe.spin_for(0.01)
            assert probe.states[-1].x == pytest.approx(x_after_timeout, abs=1e-6), stamp
            assert probe.states[-1].episode == episode
    finally:
        stop(sim)
    text = (tmp_path / "sim.log").read_text()
    for cause in ("for episode 999", "old (current step", "ahead of the current step"):
        lines = [line for line in text.splitlines() if "rejected command" in line and cause in line]
        # ~100 rejections sent in 1 s: a line about once a second (the log's own stamps, taken a little after the
        # throttle's clock: 0.5 s of slack), not one per rejection; a loaded machine may spread them over more seconds
        stamps = [float(line.split("] [")[1]) for line in lines]
        assert 1 <= len(lines) <= 5 and all(b - a >= 0.5 for a, b in zip(stamps, stamps[1:])), (cause, lines)
    assert "such commands in" in text and "Traceback" not in text


def test_policy_restart_mid_episode_resumes_the_graph(probe, tmp_path):
    sim = start(
        "dlo_sim", "sim_node", "episodes:=1", "horizon:=40", "min_subscribers:=4", "seed:=3", log=open(tmp_path / "sim.log", "w")
    )
    perception = [start("dlo_perception", "tactile_node"), start("dlo_perception", "vision_node")]
    policy = start("dlo_policy", "policy_node", "policy:=tactile_reactive")
    try:
        assert probe.spin_until(lambda: probe.tasks and probe.tasks[-1].step >= 10, 180), [
            (t.step, t.done) for t in probe.tasks[-3:]
        ]
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
    policy = start(
        "dlo_policy", "policy_node", "policy:=random", "modalities:=All", "input_timeout:=0.5", log=open(policy_log, "w")
    )
    tactile = None
    try:
        assert probe.spin_until(lambda: "no tactile input" in policy_log.read_text(), 180), policy_log.read_text()
        assert probe.tasks and probe.tasks[-1].step == 0
        tactile = start("dlo_perception", "tactile_node")  # the missing node comes up: the graph proceeds
        assert sim.wait(timeout=120) == 0
    finally:
        stop(*(p for p in (policy, vision, tactile, sim) if p is not None))


@pytest.mark.parametrize(
    "pkg,exe,param,expected",
    [
        ("dlo_sim", "sim_node", "mode:=warp_speed", "parameter 'mode'"),
        ("dlo_sim", "sim_node", "horizon:=-3", "parameter 'horizon'"),
        ("dlo_perception", "tactile_node", "tactile_noise:=loud", "parameter 'tactile_noise'"),
        ("dlo_policy", "policy_node", "checkpoint:=/nonexistent/policy.pt", "does not exist"),
        ("dlo_policy", "policy_node", "policy:=magic", "parameter 'policy'"),
    ],
)
def test_malformed_parameters_give_a_clear_message(pkg, exe, param, expected):
    result = subprocess.run([ROS2RUN, pkg, exe, "--ros-args", "-p", param], capture_output=True, text=True, timeout=120)
    output = result.stdout + result.stderr
    assert result.returncode == 2, output
    assert expected in output and "Traceback" not in output


def test_a_second_simulator_started_by_hand_refuses_in_one_line(probe, tmp_path):
    first = start(
        "dlo_sim", "sim_node", "min_subscribers:=99", "publish_markers:=false", log=open(tmp_path / "first.log", "w")
    )  # waits for subscribers forever: it only sits there
    second = None
    try:
        assert probe.spin_until(lambda: "alone on ROS_DOMAIN_ID" in (tmp_path / "first.log").read_text(), 120)
        second = subprocess.run(
            [ROS2RUN, "dlo_sim", "sim_node", "--ros-args", "-p", "publish_markers:=false"],
            capture_output=True,
            text=True,
            timeout=180,
        )
        lines = [line for line in (second.stdout + second.stderr).splitlines() if "another" in line and "ROS_DOMAIN_ID" in line]
        assert second.returncode == 3 and len(lines) == 1, second.stdout + second.stderr
        assert "Traceback" not in second.stdout + second.stderr
        assert first.poll() is None  # the first one goes on
        assert not probe.tasks  # and nobody ran an episode meanwhile
    finally:
        stop(first)


def test_the_sim_names_the_topics_a_recorder_lacks(probe, tmp_path):
    """A recorder that does not subscribe to every topic must not leave the sim waiting silently."""
    sim_log = tmp_path / "sim.log"
    recorder = start("dlo_bag", "recorder_node", f"output:={tmp_path / 'bag'}", "namespace:=/dlo/camera")
    sim = start("dlo_sim", "sim_node", "wait_for_recorder:=recorder", "publish_markers:=false", log=open(sim_log, "w"))
    try:

        def waiting_lines():  # once the sim sees the recorder node (before that it lists every topic: "no node")
            return [
                line
                for line in sim_log.read_text().splitlines()
                if "waiting for the recorder 'recorder' to subscribe to" in line and "no node 'recorder'" not in line
            ]

        def settled():  # the recorder's own subscription discovered too: a line without the topic it records
            lines = waiting_lines()
            return bool(lines) and "/dlo/camera/image" not in lines[-1]

        # the first lines after the node appears may still name /dlo/camera/image (its subscription not yet
        # discovered); the sim re-names what is missing every few seconds, and must stop naming that one
        assert probe.spin_until(settled, 120), sim_log.read_text()
        waiting = waiting_lines()[-1]
        for topic in ("/dlo/gripper/state", "/dlo/task/state", "/dlo/rope/particles"):
            assert topic in waiting
        assert not probe.tasks  # the sim has not started
    finally:
        stop(sim, recorder)


def test_perception_nodes_stop_cleanly_on_sigint_mid_stream(probe, tmp_path):
    sim = start("dlo_sim", "sim_node", "mode:=real_time", "rate_factor:=4.0", "publish_markers:=false")
    logs = {name: tmp_path / f"{name}.log" for name in ("tactile", "vision")}
    nodes = {name: start("dlo_perception", f"{name}_node", log=open(log, "w")) for name, log in logs.items()}
    try:
        assert probe.spin_until(lambda: len(probe.tactile) > 5 and len(probe.vision) > 5, 180)
        for node in nodes.values():  # interrupted while processing frames (50 a second)
            node.send_signal(signal.SIGINT)
        for name, node in nodes.items():
            assert node.wait(timeout=60) == 0, logs[name].read_text()
            text = logs[name].read_text()
            assert "Traceback" not in text and "RCLError" not in text, text
    finally:
        stop(*nodes.values(), sim)
