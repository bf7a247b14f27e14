"""The sim node's command handling, in-process (no graph, no spinning; issue 14):

- step_locked: only the answer to the current episode and step advances the simulation; an old, a
  future or another episode's command does not (and the gripper stays where it is);
- real_time: the last command acts while it is younger than ``command_timeout``; an older one stops
  the gripper and holds its closure while the episode stays the same (not a restart after a drop);
- the speed limit through the node: 0.25 m/s is executed, 0.2501 m/s on either axis (or a closure
  outside [0, 1], or NaN) makes the gripper hold;
- rejections are logged at once, then at most once a second per cause with a count; real_time warns
  "no command for N s" after a second without one and "command timed out" for a stale one; the age
  limit is the ``command_timeout`` parameter; nothing runs before the start;
- the reset service: seed 0 is a seed, it starts a waiting or finished node, camera_info goes out once.

The node is built once (the simulator compiles its kernels); every test starts a fresh episode.
Each action the node executes is recorded by wrapping its TaskSim's ``step``; time is a fake
monotonic clock.
"""

import json
import math
import os
import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
from dlo_interface.command import MAX_SPEED  # noqa: E402
from dlo_msgs.msg import GripperCommand  # noqa: E402
from dlo_sim import sim_node as sim_node_module  # noqa: E402
from harness import LogLines, release_domains, reserve_domains  # noqa: E402

RATE_FACTOR = 2.0  # wall seconds per step: 0.04 (so a command's age is not the 0.08 s default)
COMMAND_TIMEOUT = 0.5
PARAMETERS = {
    "publish_markers": False,
    "camera_resolution": 32,
    "rate_factor": RATE_FACTOR,
    "command_timeout": COMMAND_TIMEOUT,
    "step_timeout": 30.0,
    "episodes": 0,
}


@pytest.fixture(scope="module")
def node():
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    context = rclpy.Context()
    domain = reserve_domains()  # harness: no other test or graph on this machine uses it meanwhile
    rclpy.init(context=context, domain_id=domain)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(sim_node_module, "DISCOVERY_GRACE", 0.0)
        declare = sim_node_module.declare_parameters
        patch.setattr(sim_node_module, "declare_parameters", lambda n, specs: {**declare(n, specs), **PARAMETERS})
        patch.setattr(rclpy.node.Node, "__init__", _in_context(rclpy.node.Node.__init__, context))
        sim = sim_node_module.SimNode()
    yield sim
    sim.destroy_node()
    rclpy.shutdown(context=context)
    release_domains(domain)


def _in_context(init, context):
    def wrapped(self, *args, **kwargs):
        kwargs.setdefault("context", context)
        return init(self, *args, **kwargs)

    return wrapped


class FakeClock:
    """The node's ``time`` module with a monotonic clock the test moves."""

    def __init__(self):
        self.now = 1000.0

    def monotonic(self):
        return self.now

    def __getattr__(self, name):
        return getattr(time, name)


@pytest.fixture
def clock(monkeypatch):
    fake = FakeClock()
    monkeypatch.setattr(sim_node_module, "time", fake)
    return fake


@pytest.fixture
def executed(node, monkeypatch):
    """The actions the simulator executes, in order (node.task.step wrapped)."""
    actions = []
    step = node.task.step

    def recording(batch):
        actions.append(np.array(batch[0], dtype=np.float64))
        return step(batch)

    monkeypatch.setattr(node.task, "step", recording)
    return actions


def start(node, mode, seed):
    node.p["mode"] = mode
    node.started = True
    node.start_episode(seed)
    return node.episode


def command(node, vx=0.05, vy=0.0, closure=0.7, episode=None, step=None):
    return GripperCommand(
        vx=float(vx),
        vy=float(vy),
        closure=float(closure),
        episode=node.episode if episode is None else episode,
        step=node.step_index if step is None else step,
    )


def gripper(node):
    return node.task.state.gripper[0].astype(np.float64).copy()  # x, y, z, closure


def test_step_locked_obeys_only_the_answer_to_the_current_step(node, clock, executed):
    episode = start(node, "step_locked", seed=0)
    node.on_command(command(node, vx=0.05))  # answers step 0
    assert node.step_index == 1 and len(executed) == 1
    assert executed[0] == pytest.approx([0.05 / MAX_SPEED, 0.0, 0.4])
    moved = gripper(node)
    rejected_before = sum(node.rejections.total.values())
    for stale in (
        command(node, step=0),
        command(node, step=2),
        command(node, episode=episode + 1),
        command(node, episode=episode + 7, step=1),
    ):
        node.on_command(stale)
        assert node.step_index == 1 and node.episode == episode and len(executed) == 1
        np.testing.assert_array_equal(gripper(node), moved)
    assert sum(node.rejections.total.values()) == rejected_before + 4
    node.on_command(command(node, vx=-0.05))  # the current step again: obeyed
    assert node.step_index == 2 and executed[-1][0] == pytest.approx(-0.2)


def test_nothing_is_obeyed_before_the_start(node, clock, executed):
    start(node, "step_locked", seed=0)
    node.started = False
    try:
        node.on_command(command(node))
        assert node.step_index == 0 and executed == []
    finally:
        node.started = True


def test_the_answer_to_the_previous_episodes_final_state_is_ignored_quietly(node, clock, executed):
    start(node, "step_locked", seed=1)
    node.on_command(command(node))
    final = (node.episode, node.step_index)
    node.finish_episode()  # the next episode starts
    assert node.episode == final[0] + 1 and node.step_index == 0
    rejected = dict(node.rejections.total)
    node.on_command(command(node, episode=final[0], step=final[1]))
    assert node.rejections.total == rejected and len(executed) == 1 and node.step_index == 0
    node.on_command(command(node, episode=final[0], step=final[1] - 1))  # any other old command: rejected
    assert sum(node.rejections.total.values()) == sum(rejected.values()) + 1 and len(executed) == 1


@pytest.mark.parametrize("vx, vy", [(0.25, 0.0), (-0.25, 0.0), (0.0, 0.25), (0.0, -0.25), (0.25, -0.25)])
def test_the_speed_limit_itself_is_executed(node, clock, executed, vx, vy):
    start(node, "step_locked", seed=2)
    node.on_command(command(node, vx=vx, vy=vy, closure=0.6))
    assert executed[-1] == pytest.approx([vx / 0.25, vy / 0.25, 0.2], abs=1e-6)


@pytest.mark.parametrize(
    "vx, vy, closure",
    [
        (0.2501, 0.0, 0.6),
        (-0.2501, 0.0, 0.6),
        (0.0, 0.2501, 0.6),
        (0.0, -0.2501, 0.6),
        (2.5, 0.0, 0.6),
        (math.nan, 0.0, 0.6),
        (0.0, 0.0, 1.0001),
        (0.0, 0.0, -0.0001),
    ],
)
def test_an_invalid_command_makes_the_gripper_hold(node, clock, executed, vx, vy, closure):
    start(node, "step_locked", seed=2)
    node.on_command(command(node, vx=0.05, closure=0.8))  # a valid step first: closure 0.8
    before = gripper(node)
    node.on_command(command(node, vx=vx, vy=vy, closure=closure))
    assert executed[-1] == pytest.approx([0.0, 0.0, 2.0 * before[3] - 1.0], abs=1e-6)  # stand still, keep c
    after = gripper(node)
    np.testing.assert_array_equal(after[:2], before[:2])
    assert after[3] == pytest.approx(before[3], abs=1e-6)


def test_real_time_without_a_command_stands_still_and_open(node, clock, executed):
    start(node, "real_time", seed=4)
    node.on_real_time_tick()
    assert executed[-1] == pytest.approx([0.0, 0.0, -1.0])


def test_real_time_acts_on_a_fresh_command_and_stops_on_a_stale_one(node, clock, executed):
    episode = start(node, "real_time", seed=4)
    node.on_command(command(node, vx=0.05, closure=0.7))  # received at t = 1000.0
    clock.now += COMMAND_TIMEOUT  # exactly command_timeout old: still obeyed
    node.on_real_time_tick()
    assert executed[-1] == pytest.approx([0.2, 0.0, 0.4])
    moving = gripper(node)
    clock.now += 0.01  # now older than command_timeout
    node.on_real_time_tick()
    node.on_real_time_tick()
    assert executed[-1] == pytest.approx([0.0, 0.0, 2.0 * moving[3] - 1.0], abs=1e-6)
    assert executed[-2] == pytest.approx(executed[-1])
    stopped = gripper(node)
    np.testing.assert_array_equal(stopped[:2], moving[:2])  # the gripper stopped ...
    assert stopped[3] == pytest.approx(0.7, abs=1e-6)  # ... holding its closure ...
    assert node.episode == episode and node.step_index == 3  # ... in the same episode, which went on
    node.on_command(command(node, vx=-0.05, closure=0.7))  # a new command: moves again
    node.on_real_time_tick()
    assert executed[-1] == pytest.approx([-0.2, 0.0, 0.4])


def test_real_time_obeys_recent_steps_only(node, clock, executed):
    episode = start(node, "real_time", seed=4)
    node.on_command(command(node, vx=0.0, closure=0.8))  # the clock stands still: this command stays fresh
    for _ in range(20):
        node.on_real_time_tick()
    assert node.step_index == 20 and node.episode == episode
    period = 0.08 / RATE_FACTOR  # 12 steps = 0.48 s old: obeyed; 13 steps = 0.52 s: stale
    assert node.period_wall == pytest.approx(period)
    node.on_command(command(node, vx=0.05, step=20 - 12))
    assert node.command is not None and node.command[0][0] == pytest.approx(0.2)
    node.on_command(command(node, vx=-0.05, step=20 - 13))
    node.on_command(command(node, vx=-0.1, step=21))  # a step that does not exist yet
    node.on_command(command(node, vx=-0.1, episode=node.episode + 1))
    node.on_real_time_tick()
    assert executed[-1] == pytest.approx([0.2, 0.0, 0.4])  # only the recent one acted


def test_the_reset_service_starts_the_asked_episode(node, clock, executed):
    from dlo_msgs.srv import ResetEpisode

    start(node, "step_locked", seed=0)
    node.on_command(command(node))
    node.on_command(command(node))
    old = (node.episode, node.step_index)
    response = node.on_reset_service(ResetEpisode.Request(seed=12), ResetEpisode.Response())
    assert (response.success, response.episode, response.seed) == (True, old[0] + 1, 12)
    assert (node.episode, node.episode_seed, node.step_index) == (old[0] + 1, 12, 0)
    assert node.task.sim.params["seed"][0] == 12
    rejected = dict(node.rejections.total)
    node.on_command(command(node, episode=old[0], step=old[1]))  # the old episode's last answer: quietly ignored
    assert node.rejections.total == rejected and node.step_index == 0
    response = node.on_reset_service(ResetEpisode.Request(seed=-1), ResetEpisode.Response())  # the node's sequence
    assert response.seed == node.p["seed"] + old[0] + 2 == node.episode_seed and response.episode == old[0] + 2


def test_step_locked_exits_after_its_last_episode_once_the_final_state_is_answered(node, clock, executed):
    """The graph still works on the last episode's final state when the sim has run its episodes (the tactile
    and vision readings, the policy's last transition for online training, the recorder): in step_locked the
    sim exits once the policy answers that state, or FINAL_ANSWER_WAIT s later without an answer (seen in a
    rehearsal: online training stored 5 of 6 transitions because the graph was stopped before it)."""
    episode = start(node, "step_locked", seed=3)
    node.p["episodes"] = episode + 1  # this episode is the last
    try:
        while node.closing_since is None:
            assert node.step_index < node.p["horizon"]
            node.on_command(command(node, vx=0.0, closure=0.0))  # an open gripper drops the cable
        final = (episode, node.step_index)
        assert node.previous_final == final and node.task.tracker.steps[0] == final[1]
        clock.now += sim_node_module.FINAL_ANSWER_WAIT - 0.5
        node.on_watchdog()  # not answered yet and within the wait: still running, no new episode
        node.on_command(command(node, episode=episode, step=final[1] - 1))  # not the final state's answer
        node.on_command(command(node, episode=episode + 1, step=0))
        assert (node.episode, len(executed)) == (episode + 1, final[1])
        with pytest.raises(SystemExit) as exiting:
            node.on_command(command(node, episode=episode, step=final[1]))
        assert exiting.value.code == 0 and len(executed) == final[1]
        with pytest.raises(SystemExit):  # never answered: it exits after the wait all the same
            clock.now += 1.0
            node.on_watchdog()
    finally:
        node.p["episodes"], node.closing_since = 0, None


def test_a_refusal_names_the_other_publisher_once_discovery_knows_it(monkeypatch):
    """Discovery can show another publisher before its node's name (_NODE_NAME_UNKNOWN_, seen in CI): the
    refusal waits for the name instead of printing the placeholder, and says so if the name never comes."""
    from types import SimpleNamespace

    def info(name, namespace="/"):
        return SimpleNamespace(node_name=name, node_namespace=namespace)

    answers = [[info("sim_node"), info("_NODE_NAME_UNKNOWN_", "_NODE_NAMESPACE_UNKNOWN_")]] * 3 + [
        [info("sim_node"), info("sim_node", "/other")]
    ]
    stub = SimpleNamespace(
        get_namespace=lambda: "/",
        get_name=lambda: "sim_node",
        get_publishers_info_by_topic=lambda topic: answers.pop(0) if len(answers) > 1 else answers[0],
    )
    monkeypatch.setattr(sim_node_module.time, "sleep", lambda s: None)
    assert sim_node_module.SimNode.other_publishers(stub, "/clock") == ["/other/sim_node"]
    stub.get_publishers_info_by_topic = lambda topic: [info("_NODE_NAME_UNKNOWN_", "_NODE_NAMESPACE_UNKNOWN_")]
    assert sim_node_module.SimNode.other_publishers(stub, "/clock", wait_for_names=0.0) == ["a node discovery has not named yet"]
    stub.get_publishers_info_by_topic = lambda topic: [info("sim_node")]
    assert sim_node_module.SimNode.other_publishers(stub, "/clock") == ["unknown"]


@pytest.fixture
def log(node, monkeypatch):
    logger = LogLines()
    monkeypatch.setattr(node, "get_logger", lambda: logger)
    monkeypatch.setattr(node, "rejections", sim_node_module.RejectionLog(interval=1.0))
    return logger


def test_rejected_commands_are_logged_at_once_then_at_most_once_a_second_per_cause_with_a_count(node, clock, executed, log):
    start(node, "step_locked", seed=2)
    node.on_command(command(node, vx=0.3))  # too fast: the gripper holds, logged at once
    assert log.of("warning") == ["rejected command: speed out of range: vx=0.3, vy=0.0 (limit 0.25 m/s); the gripper holds"]
    assert executed[-1] == pytest.approx([0.0, 0.0, -1.0]) and node.step_index == 1
    node.on_command(command(node, step=0))  # another cause: logged at once too
    assert log.of("warning")[1:] == [f"rejected command: for step 0, not the current step 1 of episode {node.episode}: ignored"]
    clock.now += 0.5
    node.on_command(command(node, vx=-0.3))  # within the second: counted, not logged
    assert len(log.of("warning")) == 2 and node.rejections.total == {"speed": 2, "old step": 1}
    clock.now += 0.5
    node.on_command(command(node, vx=0.0, closure=1.5))  # the closure rule: a cause of its own
    node.on_command(command(node, vx=0.4))  # a second after the first speed line: logged with the count
    assert log.of("warning")[2:] == [
        "rejected command: closure out of range: 1.5 (must be in [0, 1]); the gripper holds",
        "rejected command: speed out of range: vx=0.4, vy=0.0 (limit 0.25 m/s); the gripper holds (2 such commands in 0.5 s)",
    ]
    assert node.rejections.total == {"speed": 3, "old step": 1, "closure": 1} and node.step_index == 4


def test_real_time_ticks_do_nothing_before_the_start(node, clock, executed):
    start(node, "real_time", seed=4)
    node.started = False
    try:
        node.on_real_time_tick()
        assert executed == [] and node.step_index == 0
    finally:
        node.started = True


def test_real_time_warns_once_no_command_came_for_a_second_and_when_a_command_times_out(node, clock, executed, log):
    start(node, "real_time", seed=4)
    node.last_command_wall = None  # as built: the episode clock starts with the first tick
    node.on_real_time_tick()  # t = 0
    clock.now += 0.5
    node.on_real_time_tick()  # 0.5 s without a command: quiet
    assert log.of("warning") == [] and executed[-1] == pytest.approx([0.0, 0.0, -1.0])
    clock.now += 0.5
    node.on_real_time_tick()  # a second without a command: warned
    assert log.of("warning") == ["no command for 1 s: is a policy running? (the gripper stands still)"]
    node.on_command(command(node, vx=0.05, closure=0.7))  # t = 1.0
    clock.now += 0.25  # (binary fractions: the clock's sums are exact)
    node.on_real_time_tick()
    assert len(log.of("warning")) == 1 and executed[-1] == pytest.approx([0.2, 0.0, 0.4])
    clock.now += 0.5  # the command is 0.75 s old, the last command 0.75 s ago: timed out, not "no command"
    node.on_real_time_tick()
    assert log.of("warning")[1:] == ["command timed out: the gripper stops and holds"]
    assert executed[-1] == pytest.approx([0.0, 0.0, 0.4], abs=1e-6)
    clock.now += 0.25  # 1.0 s since the last command: "no command" again
    node.on_real_time_tick()
    assert log.of("warning")[2:] == ["no command for 1 s: is a policy running? (the gripper stands still)"]


def test_real_time_command_age_limit_is_the_command_timeout_parameter(node, clock, executed):
    start(node, "real_time", seed=4)
    node.p["command_timeout"] = 0.2  # 5 steps of 0.04 s
    try:
        node.on_command(command(node, vx=0.0, closure=0.8))
        for _ in range(10):
            node.on_real_time_tick()
        node.on_command(command(node, vx=0.05, step=10 - 4))  # 0.16 s old: obeyed
        assert node.command[0][0] == pytest.approx(0.2)
        node.on_command(command(node, vx=-0.05, step=10 - 6))  # 0.24 s old: stale under a 0.2 s timeout
        node.on_real_time_tick()
        assert executed[-1] == pytest.approx([0.2, 0.0, 0.4]) and node.rejections.total.get("stale", 0) >= 1
    finally:
        node.p["command_timeout"] = COMMAND_TIMEOUT


def test_the_reset_service_starts_seed_zero_when_asked_for_it(node, clock, executed):
    from dlo_msgs.srv import ResetEpisode

    start(node, "step_locked", seed=7)
    node.on_command(command(node))
    response = node.on_reset_service(ResetEpisode.Request(seed=0), ResetEpisode.Response())  # 0 is a seed, not "own"
    assert response.seed == 0 == node.episode_seed and node.task.sim.params["seed"][0] == 0


def test_the_reset_service_starts_a_waiting_or_finished_node_and_camera_info_is_published_once(
    node, clock, executed, monkeypatch
):
    from dlo_msgs.srv import ResetEpisode

    published = []
    monkeypatch.setattr(node.pub_info, "publish", published.append)
    start(node, "step_locked", seed=0)
    node.started, node.info_published = False, False  # not started yet: nothing published
    try:
        node.on_reset_service(ResetEpisode.Request(seed=3), ResetEpisode.Response())
        assert node.started and len(published) == 1 and published[0].width == published[0].height == 32
        node.on_command(command(node))  # obeyed: the node runs
        assert node.step_index == 1 and len(executed) == 1
        node.closing_since = clock.now  # the last episode ran: waiting for the answer to its final state
        node.on_reset_service(ResetEpisode.Request(seed=4), ResetEpisode.Response())
        node.on_command(command(node))  # a new episode runs again
        assert node.step_index == 1 and len(executed) == 2 and node.episode_seed == 4
        assert len(published) == 1  # camera_info is latched: published once
    finally:
        node.started, node.info_published, node.closing_since = True, True, None


def test_the_instance_record_carries_the_settings_an_episode_runs_under(node):
    """/dlo/sim/instance (latched, recorded): besides who runs, every parameter that decides what an episode is,
    so a bag says which task rules, move spacing, grip, carry law, contact radius and start pose produced it; the
    task state of every step says the task rules and the move spacing (what dlo-analyze recomputes the episode with)."""
    assert set(node.instance["settings"]) == set(sim_node_module.SETTINGS)
    names = ("task_rules", "move_spacing", "single_particle_grip", "carry_law", "contact_radius", "start_pose", "physics_seed")
    for name in names:
        assert node.instance["settings"][name] == node.p[name]
    json.dumps(node.instance)  # it is sent as JSON
    node.start_episode(0)
    state = node.task_state(node.task.held[0], int(node.task.sim.num_particles[0]))
    assert (state.task_rules, state.move_spacing) == (node.p["task_rules"], node.task.tracker.move_spacing)
    assert node.task.tracker.move_spacing == node.p["move_spacing"]
