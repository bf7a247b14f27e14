"""dlo-driver-check's ROS part (record(), check_alone(), start_episode()) against a driver simulated inside
rclpy.spin_once on a simulated clock: no middleware, no wall time, so each check takes a fraction of a second
and is exact. What it asserts is what the module docstring promises of the checker: it answers every
state with a command stamped with that state's episode, step and header, phase after phase of the schedule,
says nothing during the silence, starts one episode through /dlo/sim/reset, records what the driver
publishes (the image's pixel values without row padding, the cloud's layout problem, camera_info latched),
refuses while another node commands the driver, and gives up (None) when no driver answers.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import rclpy
from dlo_common.topics import Topic
from dlo_driver_kit import driver_check
from dlo_driver_kit.driver_check import DRIVER_TOPICS, RULES, CheckError, Settings, evaluate, schedule
from dlo_interface.cloud import particle_cloud
from dlo_msgs.msg import GripperState, TactilePose
from dlo_msgs.srv import ResetEpisode
from rclpy.qos import DurabilityPolicy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import CameraInfo, Image

PERIOD = 0.08


class Info:
    def __init__(self, name, namespace="/"):
        self.node_name, self.node_namespace = name, namespace


class Future:
    def __init__(self, response, due):
        self.response, self.due, self.cancelled = response, due, False
        self.now = None

    def done(self):
        return self.now is not None and self.now() >= self.due

    def result(self):
        return self.response

    def cancel(self):
        self.cancelled = True


class FakeRos:
    """rclpy as record() uses it, with a 12.5 Hz real-time driver running inside spin_once on a fake clock.

    ``reset``: 'ok', 'refused', 'none' (a None response), 'silent' (never answers), None (no service);
    ``others``: [(from, to, name)]: another node publishes the command topic from..to (fake seconds after start);
    ``state_topic`` etc. follow ``prefix``; ``padding``: bytes of row padding (value 7) in each image; ``extra``:
    (topic, steps late): a TactilePose on one more topic each step, stamped with the state's stamp of that many
    steps before."""

    def __init__(
        self, prefix="", driver=True, reset="ok", others=(), padding=0, listens_after=0.0, image_size_ok=True, extra=None
    ):
        self.t0 = self.now = 1000.0
        self.prefix, self.driver, self.reset_mode, self.others = prefix, driver, reset, list(others)
        self.padding, self.listens_after, self.image_size_ok, self.extra = padding, listens_after, image_size_ok, extra
        self.subs, self.commands, self.resets, self.futures = {}, [], [], []
        self.states_sent = []
        self.init_calls, self.shutdowns, self.destroyed = [], 0, 0
        self.next_tick = self.now
        self.x, self.y, self.closure, self.episode, self.step, self.stamp_ns = -0.1, 0.0, 0.0, 0, 0, 5_000_000_000
        self.vx = self.vy = 0.0
        self.last_command = -math.inf
        self.camera_info_sent = False

    # ---- rclpy
    def init(self, args=None, signal_handler_options=None):
        self.init_calls.append((args, signal_handler_options))

    def create_node(self, name):
        self.node = FakeNode(self, name)
        return self.node

    def spin_once(self, node, timeout_sec=None):
        assert node is self.node
        self.now += timeout_sec
        while self.driver and self.now >= self.next_tick:
            self.tick()
            self.next_tick += PERIOD

    def try_shutdown(self):
        self.shutdowns += 1

    def monotonic(self):
        return self.now

    # ---- the driver
    def topic(self, name):
        return self.prefix + name

    def publish(self, name, msg):
        callback = self.subs.get(self.topic(name))
        if callback is not None:
            callback[0](msg)

    def on_command(self, cmd):
        self.commands.append((self.now, cmd))
        values = (cmd.vx, cmd.vy, cmd.closure)
        if all(math.isfinite(v) for v in values) and abs(cmd.vx) <= 0.25 and abs(cmd.vy) <= 0.25 and 0 <= cmd.closure <= 1:
            self.vx, self.vy, self.closure = cmd.vx, cmd.vy, cmd.closure
            self.last_command = self.now
        else:
            self.vx = self.vy = 0.0  # rejected: hold

    def tick(self):
        if self.now - self.last_command > 0.5:
            self.vx = self.vy = 0.0
        w = driver_check.WORKSPACE_HALF_WIDTH
        self.x = min(max(self.x + self.vx * PERIOD, -w), w)
        self.y = min(max(self.y + self.vy * PERIOD, -w), w)
        self.stamp_ns += int(PERIOD * 1e9)
        sec, nanosec = divmod(self.stamp_ns, 1_000_000_000)
        if not self.camera_info_sent:
            info = CameraInfo(width=64, height=48, k=[80.0, 0.0, 32.0, 0.0, 80.0, 24.0, 0.0, 0.0, 1.0])
            info.header.frame_id = "cam"
            self.publish("/dlo/camera/camera_info", info)
            self.camera_info_sent = True
        step = 64 + self.padding
        pixels = np.zeros((48, step), np.uint8)
        pixels[:, :64:2] = 255
        pixels[0, :4] = 128
        pixels[:, 64:] = 7  # row padding: not part of the image
        image = Image(
            width=64,
            height=48,
            encoding="mono8",
            step=step,
            data=pixels.tobytes() if self.image_size_ok else pixels.tobytes()[:-1],
        )
        cloud = particle_cloud([[self.x, 0.0, 0.1], [self.x + 0.004, 0.0, 0.1]], [False, True])
        touch = TactilePose(angle=0.1, y=0.0, contact=True, contact_count=1)
        state = GripperState(x=self.x, y=self.y, closure=self.closure, episode=self.episode, step=self.step)
        for msg in (image, cloud, touch, state):
            msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
        image.header.frame_id = "cam"
        self.publish("/dlo/camera/image", image)
        self.publish("/dlo/rope/particles", cloud)
        self.publish("/dlo/tactile/pose", touch)
        if self.extra:
            name, late = self.extra
            extra = TactilePose()
            extra.header.stamp.sec, extra.header.stamp.nanosec = divmod(self.stamp_ns - late * int(PERIOD * 1e9), 1_000_000_000)
            self.publish(name, extra)
        self.states_sent.append((self.now, state))
        self.publish("/dlo/gripper/state", state)
        self.step += 1

    def serve_reset(self, request):
        self.resets.append((self.now, request.seed))
        if self.reset_mode == "ok":
            self.episode, self.step, self.x, self.y = self.episode + 1, 0, -0.1, 0.0
            return ResetEpisode.Response(success=True, episode=self.episode), self.now + 0.03
        if self.reset_mode == "refused":
            return ResetEpisode.Response(success=False, message="busy"), self.now + 0.03
        if self.reset_mode == "refused quietly":
            return ResetEpisode.Response(success=False), self.now + 0.03
        if self.reset_mode == "none":
            return None, self.now + 0.03
        return None, math.inf  # never answers


class FakePublisher:
    def __init__(self, ros, topic):
        self.ros, self.topic_name = ros, topic

    def publish(self, msg):
        self.ros.on_command(msg)

    def get_subscription_count(self):
        ros = self.ros
        return int(ros.driver and ros.now - ros.t0 >= ros.listens_after)


class FakeClient:
    def __init__(self, ros, name):
        self.ros, self.name = ros, name

    def service_is_ready(self):
        return self.ros.reset_mode is not None and self.name == self.ros.topic("/dlo/sim/reset")

    def call_async(self, request):
        response, due = self.ros.serve_reset(request)
        future = Future(response, due)
        future.now = self.ros.monotonic
        self.ros.futures.append(future)
        return future


class FakeNode:
    def __init__(self, ros, name):
        self.ros, self.name, self.qos = ros, name, {}

    def get_name(self):
        return self.name

    def create_publisher(self, msg_class, topic, qos):
        self.ros.command_topic = topic
        return FakePublisher(self.ros, topic)

    def create_subscription(self, msg_class, topic, callback, qos):
        self.ros.subs[topic] = (callback, msg_class)
        self.qos[topic] = qos

    def create_client(self, srv_class, name):
        assert srv_class is ResetEpisode
        return FakeClient(self.ros, name)

    def _others(self):
        elapsed = self.ros.now - self.ros.t0
        return [Info(name) for start, end, name in self.ros.others if start <= elapsed < end]

    def count_publishers(self, topic):
        return 1 + len(self._others())

    def get_publishers_info_by_topic(self, topic):
        if topic == self.ros.command_topic:
            return [Info(self.name)] + self._others()
        return [Info("driver")] if self.ros.driver else []

    def destroy_node(self):
        self.ros.destroyed += 1


@pytest.fixture
def fake_ros(monkeypatch):
    def make(**kwargs):
        ros = FakeRos(**kwargs)
        for name in ("init", "create_node", "spin_once", "try_shutdown"):
            monkeypatch.setattr(rclpy, name, getattr(ros, name))

        class Clock:
            monotonic = staticmethod(ros.monotonic)

        monkeypatch.setattr(driver_check, "time", Clock)
        return ros

    return make


def run_record(ros, s=None, namespace="", timeout=10.0):
    lines = []
    rec = driver_check.record(s or Settings(), namespace, timeout, log=lines.append)
    return rec, lines


def test_a_good_driver_is_answered_step_by_step_through_the_schedule_and_passes_every_rule(fake_ros):
    ros = fake_ros()
    s = Settings()
    rec, lines = run_record(ros, s)
    phases = schedule(s)
    assert ros.init_calls == [([], SignalHandlerOptions.NO)]  # Ctrl-C is a KeyboardInterrupt (exit 130)
    assert ros.destroyed == 1 and ros.shutdowns == 1
    assert lines == [
        f"driver found: 1 publisher(s) of /dlo/gripper/state; checking for about {sum(p.duration for p in phases):.0f} s"
    ]
    results = {r.rule: r for r in evaluate(rec, s)}
    assert {rule: r.status for rule, r in results.items()} == dict.fromkeys(RULES, "PASS"), results
    assert "stopped at the boundary" in results["workspace"].reason
    assert "1 new episode(s) from step 0" in results["stamps"].reason
    assert "each with an image and a particle cloud and a tactile pose of its exact stamp" in results["sync"].reason
    # the phases, in order, each for its duration
    assert [name for name, _, _ in rec.phases] == [p.name for p in phases]
    for (name, start, end), phase, nxt in zip(rec.phases, phases, rec.phases[1:] + [None]):
        assert phase.duration <= end - start < phase.duration + 0.02, name
        if nxt is not None:
            assert nxt[1] >= end
    # every state is recorded as the driver sent it (those of the wait before the check left out)
    start, end = rec.phases[0][1], rec.phases[-1][2]
    sent = [(t, m) for t, m in ros.states_sent if t > start]
    assert [(x.wall, x.episode, x.step, x.x, x.y, x.closure) for x in rec.states] == [
        (t, m.episode, m.step, m.x, m.y, m.closure) for t, m in sent
    ]
    assert [x.stamp_ns for x in rec.states] == [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, m in sent]
    assert all(x.stamp == pytest.approx(x.stamp_ns * 1e-9, abs=1e-9) for x in rec.states)
    assert rec.states[-1].wall > end  # it listens 0.2 s more after the schedule...
    # ... and answers only during a phase with a command: each answer names its state, phase by phase
    window = {name: (a, b) for name, a, b in rec.phases}
    answered = {}
    for t, cmd in ros.commands:
        phase = next(p for p in phases if window[p.name][0] <= t <= window[p.name][1])
        assert phase.command is not None, phase.name  # never during the silence
        state = next(m for ts, m in ros.states_sent if ts == t)
        assert (cmd.episode, cmd.step, cmd.header.stamp, cmd.header.frame_id) == (
            state.episode,
            state.step,
            state.header.stamp,
            state.header.frame_id,
        )
        got, want = (cmd.vx, cmd.vy, cmd.closure), tuple(float(v) for v in phase.command)
        assert all(a == b or (math.isnan(a) and math.isnan(b)) for a, b in zip(got, want)), (phase.name, got)
        answered[(cmd.episode, cmd.step)] = phase.name
    assert rec.answered == answered
    assert {p.name for p in phases if p.command is not None} == set(answered.values())
    in_window = [x for x in rec.states if x.wall <= end]
    assert len(answered) == len([x for x in in_window if not window["silent"][0] <= x.wall <= window["silent"][1]])
    # the silence starts after the last command of the lead phase, which the stale rule measures from
    lead_end = window["lead-stale"][1]
    assert rec.last_command_wall == max(t for t, _ in ros.commands if t <= lead_end)
    # one new episode, asked for at the start of the 'reset' phase
    assert ros.resets == [(window["reset"][0], -1)] and rec.reset == "started"
    # what else the driver published
    assert len(rec.images) == len(rec.clouds) == len(rec.tactile_stamps) == len(rec.tactile_walls) >= len(rec.states)
    assert [(i.width, i.height, i.k, i.frame_id) for i in rec.infos] == [
        (64, 48, (80.0, 0.0, 32.0, 0.0, 80.0, 24.0, 0.0, 0.0, 1.0), "cam")
    ]
    image = rec.images[-1]
    assert (image.width, image.height, image.encoding, image.step, image.size, image.frame_id, image.values) == (
        64,
        48,
        "mono8",
        64,
        64 * 48,
        "cam",
        (0, 128, 255),
    )
    assert image.stamp_ns == rec.states[-1].stamp_ns and image.wall == rec.states[-1].wall
    cloud = rec.clouds[-1]
    assert (cloud.stamp_ns, cloud.fields, cloud.problem, cloud.wall) == (
        rec.states[-1].stamp_ns,
        ["x", "y", "z", "held"],
        None,
        rec.states[-1].wall,
    )
    assert rec.tactile_stamps[-1] == rec.states[-1].stamp_ns and rec.tactile_walls[-1] == rec.states[-1].wall
    # camera_info is subscribed latched (it is published once), the rest with a deep queue
    qos = ros.node.qos
    assert qos["/dlo/camera/camera_info"].durability == DurabilityPolicy.TRANSIENT_LOCAL
    assert qos["/dlo/camera/camera_info"].depth == 1
    assert {t: q for t, q in qos.items() if t != "/dlo/camera/camera_info"} == dict.fromkeys(
        [t.name for t in DRIVER_TOPICS if t.rate != "latched"], 100
    )


def test_the_pixel_values_leave_the_row_padding_out(fake_ros):
    rec, _ = run_record(fake_ros(padding=3))
    image = rec.images[-1]
    assert (image.step, image.size, image.values) == (67, 67 * 48, (0, 128, 255))
    rec, _ = run_record(fake_ros(padding=3, image_size_ok=False))  # data not height x step: all of it counted
    assert rec.images[-1].values == (0, 7, 128, 255)


def test_a_namespace_prefixes_every_topic_and_the_service(fake_ros):
    for namespace in ("robot1", "/robot1/"):
        ros = fake_ros(prefix="/robot1")
        rec, lines = run_record(ros, namespace=namespace)
        assert ros.command_topic == "/robot1/dlo/gripper/cmd"
        assert set(ros.node.qos) == {f"/robot1{t.name}" for t in DRIVER_TOPICS}
        assert "of /robot1/dlo/gripper/state;" in lines[0] and rec.reset == "started"
    ros = fake_ros()
    rec, _ = run_record(ros, namespace="/")
    assert ros.command_topic == "/dlo/gripper/cmd" and rec.reset == "started"


def test_a_driver_topic_without_a_recorder_here_is_recorded_and_judged_by_sync(fake_ros, monkeypatch):
    """A topic with a driver's part that the checker has no recorder of its own for (a modality added to
    dlo_common.topics) does not crash it: its stamps and arrivals are recorded and 'sync' judges them as it judges
    the image's: every state's exact stamp, in the state's step."""
    wrist = Topic("/dlo/wrist/force", "dlo_msgs/msg/TactilePose", "sim_node", "observation", "made up", key="w", driver="x")
    monkeypatch.setattr(driver_check, "DRIVER_TOPICS", DRIVER_TOPICS + (wrist,))
    ros = fake_ros(extra=(wrist.name, 0))
    rec, _ = run_record(ros)
    assert ros.node.qos[wrist.name] == driver_check.QUEUE_DEPTH
    stamps, arrivals = rec.others[wrist.name]
    assert stamps[-1] == rec.states[-1].stamp_ns and arrivals[-1] == rec.states[-1].wall
    results = {r.rule: r for r in evaluate(rec, Settings())}
    assert {rule: r.status for rule, r in results.items()} == dict.fromkeys(RULES, "PASS"), results
    assert "a tactile pose and a /dlo/wrist/force message of its exact stamp" in results["sync"].reason
    rec, _ = run_record(fake_ros(extra=(wrist.name, 1)))  # stamped with the step before: the nodes would mismatch
    sync = next(r for r in evaluate(rec, Settings()) if r.rule == "sync")
    assert sync.status == "FAIL" and "get the /dlo/wrist/force message carrying their stamp a step away" in sync.reason


def test_no_driver_gives_none_after_the_timeout_and_a_driver_not_yet_listening_is_waited_for(fake_ros):
    ros = fake_ros(driver=False)
    rec, lines = run_record(ros, timeout=3.0)
    assert rec is None and lines == [] and ros.commands == []
    assert 3.0 <= ros.now - ros.t0 < 3.1 and ros.destroyed == 1 and ros.shutdowns == 1
    ros = fake_ros(listens_after=1.0)  # states at once, the command subscription a second later
    rec, _ = run_record(ros)
    assert rec.phases[0][1] - ros.t0 >= 1.0
    assert rec.states and all(x.wall >= rec.phases[0][1] for x in rec.states)


def test_the_reset_service_outcomes(fake_ros):
    for mode, expected in (
        ("refused", "refused (busy)"),
        ("refused quietly", "refused (no reason given)"),
        ("none", "refused (no reason given)"),
        ("silent", "no answer within 5 s"),
        (None, None),
    ):
        ros = fake_ros(reset=mode)
        rec, _ = run_record(ros)
        assert rec.reset == expected, mode
        if mode == "silent":
            assert ros.futures[0].cancelled
            reset = next((a, b) for name, a, b in rec.phases if name == "reset")
            assert 5.0 <= reset[1] - reset[0] < 5.1  # it waited 5 s for the answer, answering states meanwhile
            assert any(reset[0] < t < reset[0] + 5.0 for t, _ in ros.commands)
        if mode is None:
            assert ros.resets == []
        results = {r.rule: r for r in evaluate(rec, Settings())}
        assert results["stamps"].status == ("PASS" if mode is None else "FAIL"), (mode, results["stamps"])


def test_the_check_refuses_while_another_node_commands_the_driver(fake_ros):
    ros = fake_ros(others=[(0.0, 1e9, "fake_policy")])
    with pytest.raises(
        CheckError,
        match=r"^another node commands the driver \(/fake_policy publishes "
        r"/dlo/gripper/cmd\): stop it \(the policy\) before the check$",
    ):
        run_record(ros)
    assert ros.commands == [] and ros.destroyed == 1 and ros.shutdowns == 1
    # a policy that starts mid-check is found after the phase it joined in
    ros = fake_ros(others=[(4.0, 1e9, "late_policy")])
    with pytest.raises(CheckError, match="late_policy"):
        run_record(ros)
    assert ros.commands and ros.now - ros.t0 < 6.0


def test_a_publisher_whose_name_is_not_yet_known_is_named_once_discovery_has_it(fake_ros):
    ros = fake_ros(others=[(0.0, 0.5, "_UNKNOWN_"), (0.5, 1e9, "fake_policy")])
    with pytest.raises(CheckError, match=r"\(/fake_policy publishes"):
        run_record(ros)
    assert 0.5 <= ros.now - ros.t0 < 0.7
    ros = fake_ros(others=[(0.0, 1e9, "_UNKNOWN_")])  # never named: refused after 2 s all the same
    with pytest.raises(CheckError, match=r"\(/_UNKNOWN_ publishes"):
        run_record(ros)
    assert 2.0 <= ros.now - ros.t0 < 2.2
    ros = fake_ros(others=[(0.0, 1.0, "_UNKNOWN_")])  # an endpoint that goes away before it is named: no refusal
    rec, _ = run_record(ros)
    assert rec.reset == "started"


def test_the_check_waits_while_any_publisher_is_unnamed_and_then_names_them_all(fake_ros):
    ros = fake_ros(others=[(0.0, 0.5, "_UNKNOWN_"), (0.5, 1e9, "p2"), (0.0, 1e9, "p1")])
    with pytest.raises(CheckError, match=r"\(/p2, /p1 publishes /dlo/gripper/cmd\)"):
        run_record(ros)
    assert 0.5 <= ros.now - ros.t0 < 0.7
