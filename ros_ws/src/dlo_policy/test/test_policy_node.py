"""dlo_policy.policy_node in-process with a stub policy that records what it sees (no graph).

- ``without``: the ablated modality's entries are zeros in the observation the policy gets, the
  other entries are the received values, and the node does not wait for the ablated input;
- the command answers the step it was computed from (episode, step, stamp), and a republished step
  gets the same command without asking the policy again;
- online training: the task's end of an episode reaches the learner as terminal only when the
  cable was dropped (n_held = 0), never on a horizon cut-off;
- its topics, timer and parameters, and the parameters it refuses;
- an incomplete step names its missing input once; steps whose inputs never meet by stamp are reported
  about once a second with the stamps seen.
"""

import os
import re

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
from dlo_common.params import as_params, check_value  # noqa: E402
from dlo_msgs.msg import GripperState, TactilePose, TaskState, VisualPose  # noqa: E402
from dlo_policy import policy_node as policy_node_module  # noqa: E402
from harness import LogLines, reserved_domain  # noqa: E402

DECLARE = policy_node_module.declare_parameters  # the original: every node gets only its own overrides
SPECS = {param.name: param for param in as_params(policy_node_module.PARAMETERS)}

K = (0.012, -0.004, 0.7)
T = (0.3, 0.0042)
V = (True, 0.5, -0.2, 0.011)


@pytest.fixture(scope="module")
def context():
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    context = rclpy.Context()
    with reserved_domain() as domain:  # harness: no other test or graph on this machine uses it meanwhile
        rclpy.init(context=context, domain_id=domain)
        yield context
        rclpy.shutdown(context=context)


class Published(list):
    def publish(self, msg):
        self.append(msg)


class RecordingPolicy:
    def __init__(self):
        self.seen, self.new_episode = [], []

    def __call__(self, obs, new_episode, truth):
        self.seen.append(np.array(obs, copy=True))
        self.new_episode.append(new_episode)
        return np.array([[0.4, -0.2, 0.6]], np.float32)


class RecordingLearner:
    def __init__(self):
        self.calls = []
        self.saved = 0
        self.agent = type("Agent", (), {"num_env_steps": 0})()
        self.run_dir = "nowhere"

    def save(self):
        self.saved += 1

    def act(self, observation, reward, done, dropped, episode, step):
        self.calls.append(dict(reward=reward, done=done, dropped=dropped, episode=episode, step=step))
        return np.zeros(3, np.float32)


@pytest.fixture
def make_node(context, monkeypatch):
    nodes = []

    def make(act=None, learner=None, trained_on="All", previous_action=False, **parameters):
        checked = {name: check_value(SPECS[name], value) for name, value in parameters.items()}  # range, choices
        monkeypatch.setattr(policy_node_module, "declare_parameters", lambda n, specs: {**DECLARE(n, specs), **checked})
        monkeypatch.setattr(
            policy_node_module, "load_policy", lambda kind, checkpoint, modalities, seed: (act, trained_on, previous_action)
        )

        def make_learner(p, config=None):
            assert learner is not None, "a learner was made without train:=true"
            return learner

        monkeypatch.setattr(policy_node_module.PolicyNode, "make_learner", staticmethod(make_learner))
        init = rclpy.node.Node.__init__
        monkeypatch.setattr(rclpy.node.Node, "__init__", lambda self, *a, **k: init(self, *a, **{"context": context, **k}))
        try:
            node = policy_node_module.PolicyNode()
        finally:
            monkeypatch.setattr(rclpy.node.Node, "__init__", init)
        node.real_publisher = node.publisher
        node.publisher = Published()
        nodes.append(node)
        return node

    yield make
    for node in nodes:
        node.destroy_node()


def stamped(msg, step):
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(step * 80_000_000, 1_000_000_000)
    msg.header.frame_id = "world"
    return msg


def feed(node, step, episode=2, task=None):
    """Every input the node listens to, for one step (the gripper state last, as the sim does)."""
    inputs = {
        "tactile": TactilePose(angle=T[0], y=T[1], contact=True, contact_count=4),
        "vision": VisualPose(visible=V[0], confidence=V[1], angle=V[2], y=V[3]),
        "task": task,
        "gripper": GripperState(x=K[0], y=K[1], z=0.1, closure=K[2], episode=episode, step=step),
    }
    for key in ("tactile", "vision", "task", "gripper"):
        if key in node.sync.keys:
            node.on_input(key, stamped(inputs[key], step))


@pytest.mark.parametrize(
    "without, inputs, zero",
    [
        ("", ("gripper", "tactile", "vision"), []),
        ("T", ("gripper", "vision"), [3, 4]),
        ("V", ("gripper", "tactile"), [5, 6, 7, 8]),
        ("K", ("gripper", "tactile", "vision"), [0, 1, 2]),
        ("T+V", ("gripper",), [3, 4, 5, 6, 7, 8]),
    ],
)
def test_without_blanks_the_modality_the_policy_sees(make_node, without, inputs, zero):
    policy = RecordingPolicy()
    node = make_node(act=policy, without=without)
    assert node.sync.keys == inputs  # an ablated input is not waited for
    feed(node, step=7)
    (seen,) = policy.seen
    full = np.array([[*K, *T, float(V[0]), *V[1:]]], np.float32)
    keep = [c for c in range(9) if c not in zero]
    assert seen.shape == (1, 9)
    assert np.all(seen[:, zero] == 0.0)
    np.testing.assert_allclose(seen[:, keep], full[:, keep], rtol=1e-6)


def test_the_command_answers_its_step_and_a_republished_step_gets_the_same_one(make_node):
    policy = RecordingPolicy()
    node = make_node(act=policy)
    feed(node, step=0, episode=4)
    feed(node, step=0, episode=4)  # republished: answered again, the policy is not asked again
    feed(node, step=1, episode=4)
    first, again, second = node.publisher
    assert len(policy.seen) == 2 and policy.new_episode == [True, False]
    assert (first.episode, first.step, second.step) == (4, 0, 1)
    assert (first.header.stamp.sec, first.header.stamp.nanosec) == (0, 0)
    assert (second.header.stamp.sec, second.header.stamp.nanosec) == (0, 80_000_000)
    assert (first.vx, first.vy, first.closure) == pytest.approx((0.1, -0.05, 0.8))
    assert (again.vx, again.vy, again.closure, again.step) == (first.vx, first.vy, first.closure, first.step)


@pytest.mark.parametrize("n_held, dropped", [(3, False), (0, True)])
def test_online_training_gets_a_terminal_flag_only_for_a_drop(make_node, n_held, dropped):
    learner = RecordingLearner()
    node = make_node(learner=learner, train=True, policy="sac", modalities="T+K")  # trains on its own modalities
    assert node.sync.keys == ("gripper", "tactile", "task")
    feed(node, step=5, task=TaskState(episode=2, step=5, n_held=3, reward=0.25, done=False))
    feed(node, step=6, task=TaskState(episode=2, step=6, n_held=n_held, reward=-0.5, done=True))
    assert learner.calls == [
        dict(reward=0.25, done=False, dropped=False, episode=2, step=5),
        dict(reward=-0.5, done=True, dropped=dropped, episode=2, step=6),
    ]
    node.finish()  # saves the online run once (run_node calls it when the node stops)
    assert learner.saved == 1


def test_topics_timer_and_parameters(make_node):
    node = make_node(act=RecordingPolicy())
    assert node.real_publisher.topic_name == "/dlo/gripper/cmd"
    assert sorted(s.topic_name for s in node.subscriptions) == ["/dlo/gripper/state", "/dlo/tactile/pose", "/dlo/vision/pose"]
    assert [t.timer_period_ns for t in node.timers] == [250_000_000]
    assert {n: node.get_parameter(n).value for n in ("input_timeout", "seed", "checkpoint_every", "without")} == {
        "input_timeout": 1.0,
        "seed": 0,
        "checkpoint_every": 1000,
        "without": "",
    }
    ablated = make_node(act=RecordingPolicy(), without="V")
    assert sorted(s.topic_name for s in ablated.subscriptions) == ["/dlo/gripper/state", "/dlo/tactile/pose"]
    oracle = make_node(act=RecordingPolicy(), policy="oracle", trained_on="K")
    assert oracle.sync.keys == ("gripper", "particles")
    assert sorted(s.topic_name for s in oracle.subscriptions) == ["/dlo/gripper/state", "/dlo/rope/particles"]
    learner = make_node(learner=RecordingLearner(), train=True, modalities="K")
    assert sorted(s.topic_name for s in learner.subscriptions) == ["/dlo/gripper/state", "/dlo/task/state"]


def test_a_policy_that_takes_its_previous_action_gets_it_after_the_observation(make_node):
    """load_policy says the policy takes its previous action (a checkpoint 3 longer): the node appends the action it
    gave at the step before, zeros at a new episode's first step, and also when the new episode's step 0 never came."""
    policy = RecordingPolicy()
    node = make_node(act=policy, previous_action=True)
    feed(node, step=0, episode=4)
    feed(node, step=1, episode=4)
    feed(node, step=2, episode=5)  # episode 5's steps 0 and 1 were missed: a new episode all the same
    first, second, third = policy.seen
    assert first.shape == (1, 12) and (first[0, 9:] == 0).all()
    assert np.array_equal(second[:, :9], first[:, :9]) and second[0, 9:].tolist() == pytest.approx([0.4, -0.2, 0.6])
    assert (third[0, 9:] == 0).all() and policy.new_episode == [True, False, True]


def test_online_training_checks_the_configs_env_options_as_dlo_train(make_node, tmp_path):
    from dlo_common.node_util import ParameterError

    config = tmp_path / "online.yaml"
    config.write_text("env_options:\n  previous_action: 'no'\n")
    with pytest.raises(ParameterError, match=r"env_options: previous_action: expected true or false, got 'no'"):
        make_node(learner=RecordingLearner(), train=True, policy="sac", train_config=str(config))


@pytest.mark.parametrize(
    "parameters, message",
    [
        (dict(policy="neural"), "parameter 'policy'"),
        (dict(policy="random", train=True), "online training needs policy:=sac"),
        (dict(without="V", trained_on="T+K"), "cannot ablate"),
    ],
)
def test_bad_parameters_are_refused(make_node, parameters, message):
    from dlo_common.node_util import ParameterError

    with pytest.raises(ParameterError, match=message):
        make_node(act=RecordingPolicy(), **parameters)


def test_an_incomplete_step_names_the_missing_input_once(make_node, monkeypatch):
    node = make_node(act=RecordingPolicy(), input_timeout=0.5)
    log = LogLines()
    monkeypatch.setattr(node, "get_logger", lambda: log)
    clock = [100.0]
    monkeypatch.setattr(policy_node_module, "time", type("Clock", (), {"monotonic": staticmethod(lambda: clock[0])}))
    feed(node, step=1)  # complete: nothing to report later
    node.on_input("gripper", stamped(GripperState(episode=2, step=2), 2))
    node.on_input("vision", stamped(VisualPose(), 2))
    clock[0] += 0.4
    node.check_missing_inputs()
    assert log.of("error") == []
    clock[0] += 0.2
    node.check_missing_inputs()
    node.check_missing_inputs()
    assert len(log.of("error")) == 1 and "no tactile input after 0.5 s" in log.of("error")[0] and "t=0.16 s" in log.of("error")[0]


def test_incomplete_steps_are_reported_once_a_second_with_the_stamps_seen(make_node, monkeypatch):
    """A driver whose state is stamped apart from its image and cloud: the perception outputs carry the
    image's and cloud's stamps, the policy never gets a complete step; it says so about once a second,
    naming the missing inputs and the stamps they carry (not one error per step)."""
    node = make_node(act=RecordingPolicy())
    log = LogLines()
    monkeypatch.setattr(node, "get_logger", lambda: log)
    clock = [100.0]
    monkeypatch.setattr(policy_node_module, "time", type("Clock", (), {"monotonic": staticmethod(lambda: clock[0])}))
    for step in range(16, 66):  # 4 s of steps from t = 1.28 s, the timer every 0.25 s
        node.on_input("tactile", stamped(TactilePose(), step))
        node.on_input("vision", stamped(VisualPose(), step))
        state = stamped(GripperState(episode=0, step=step), step)
        state.header.stamp.nanosec += 400  # the driver's own clock reading for the state
        node.on_input("gripper", state)
        clock[0] += 0.08
        if step % 3 == 0:
            node.check_missing_inputs()
    assert node.publisher == []
    assert 2 <= len(log.of("error")) <= 4, log.of("error")  # 50 incomplete steps, about one line a second
    first = log.of("error")[0]  # the latest incomplete step when it is due, e.g. the one at 1.44 s
    found = re.match(
        r"step at t=(\S+) s: no tactile, vision input after 1.0 s; gripper state at (\S+)00004; tactile has "
        r"stamps (\S+), \S+ nearby; vision has stamps (\S+), \S+ nearby",
        first,
    )
    assert found and found.group(1) == found.group(2) == found.group(3) == found.group(4), first
    assert "(the tactile's nearest stamp is 0.4 us earlier: every input of a step must carry the state's exact stamp)" in first
    assert "other incomplete steps since the last report" in log.of("error")[1]


def test_ablating_a_modality_the_policy_does_not_observe_is_one_error_naming_the_parameter(make_node):
    """The node's own check, before any observation is built: the parameter, what it cannot ablate and
    what the policy observes (not build_observation's tuple-worded error)."""
    from dlo_common.node_util import ParameterError

    with pytest.raises(ParameterError) as error:
        make_node(act=RecordingPolicy(), without="V", trained_on="T+K")
    assert str(error.value) == "parameter 'without': cannot ablate V: the policy observes only K+T"
    with pytest.raises(ParameterError) as error:
        make_node(act=RecordingPolicy(), without="T+V", trained_on="K")
    assert str(error.value) == "parameter 'without': cannot ablate T+V: the policy observes only K"


def test_a_modality_that_cannot_read_its_message_stops_the_node_at_start(make_node, monkeypatch):
    """The node builds one observation from empty messages when it starts (``# it builds``): a modality
    record whose ``from_message`` fails is a ParameterError then, not an exception at the first step."""
    import dataclasses

    from dlo_common.node_util import ParameterError

    def unreadable(msg):
        raise ValueError("tactile message has no field 'angle'")

    broken = dataclasses.replace(policy_node_module.by_name("T"), from_message=unreadable)
    real = policy_node_module.by_name
    monkeypatch.setattr(policy_node_module, "by_name", lambda name: broken if name == "T" else real(name))
    with pytest.raises(ParameterError, match="^tactile message has no field 'angle'$"):
        make_node(act=RecordingPolicy())
    node = make_node(act=RecordingPolicy(), without="T")  # the ablated modality is never read
    assert node.sync.keys == ("gripper", "vision")


class CountingPolicy(RecordingPolicy):
    """Records what it sees; its action at the n-th call is [0.1 n, -0.05 n, 0.5 - 0.1 n]."""

    def __call__(self, obs, new_episode, truth):
        super().__call__(obs, new_episode, truth)
        n = len(self.seen)
        return np.array([[0.1 * n, -0.05 * n, 0.5 - 0.1 * n]], np.float32)


def feed_moving(node, step, episode=3, seed=70):
    """One step whose gripper sits 1 mm further along x each step, with the task state carrying the episode's seed."""
    task = TaskState(episode=episode, step=step, seed=seed, n_held=3)
    for key, msg in (
        ("tactile", TactilePose(angle=T[0], y=T[1], contact=True, contact_count=4)),
        ("vision", VisualPose(visible=V[0], confidence=V[1], angle=V[2], y=V[3])),
        ("task", task),
        ("gripper", GripperState(x=0.001 * step, y=K[1], z=0.1, closure=K[2], episode=episode, step=step)),
    ):
        if key in node.sync.keys:
            node.on_input(key, stamped(msg, step))


def test_perturbations_delay_what_the_policy_sees_and_what_it_commands(make_node):
    """observation_delay and action_delay in the node: the policy sees the observation of one step before (the
    episode's first at its start), the command carries its action of one step before; a new episode starts afresh."""
    from dlo_interface.command import action_to_command

    policy = CountingPolicy()
    node = make_node(act=policy, perturbations="observation_delay=1,action_delay=1")
    assert node.sync.keys == ("gripper", "tactile", "vision", "task")  # the task state: the episode's seed
    for step in range(3):
        feed_moving(node, step)
    assert [float(seen[0, 0]) for seen in policy.seen] == pytest.approx([0.0, 0.0, 0.001])
    commanded = [(c.vx, c.vy, c.closure) for c in node.publisher]
    expected = [action_to_command(np.float32([0.1 * n, -0.05 * n, 0.5 - 0.1 * n])) for n in (1, 1, 2)]
    assert commanded == expected
    feed_moving(node, 0, episode=4, seed=71)  # the next episode: its first observation and action, undelayed
    assert float(policy.seen[-1][0, 0]) == 0.0
    assert (node.publisher[-1].vx, node.publisher[-1].episode) == (
        pytest.approx(action_to_command(np.float32([0.4, -0.2, 0.1]))[0]),
        4,
    )
    assert node.record["perturbations"] == "observation_delay=1,action_delay=1"  # on /dlo/policy/info too


def test_perturbation_noise_in_the_node_is_the_env_perturber_of_the_episode_seed(make_node):
    """The node's noise is dlo_policy.perturbations.Perturber's, started on the seed /dlo/task/state carries (as
    the gym env starts it on the episode's seed): the same numbers, step by step."""
    from dlo_interface.command import action_to_command
    from dlo_policy.perturbations import Perturber

    setting = "gripper_position_noise=2,vision_angle_noise=5,tactile_offset_noise=1,closure_lag=0.1"
    policy = CountingPolicy()
    node = make_node(act=policy, perturbations=setting)
    env_side = Perturber(setting, "All")
    env_side.start([0], [70])
    for step in range(4):
        feed_moving(node, step)
        clean = np.array([[0.001 * step, K[1], K[2], *T, float(V[0]), *V[1:]]], np.float32)
        np.testing.assert_array_equal(policy.seen[-1], env_side.observe(clean))
        action = env_side.act(np.float32([[0.1 * (step + 1), -0.05 * (step + 1), 0.5 - 0.1 * (step + 1)]]))[0]
        assert (node.publisher[-1].vx, node.publisher[-1].vy, node.publisher[-1].closure) == pytest.approx(
            action_to_command(action)
        )
    assert not np.array_equal(policy.seen[-1][0, :2], [0.003, K[1]])  # noise was added


@pytest.mark.parametrize(
    "value, message",
    [
        ("friction=0.6", "friction: physics and camera perturbations belong to the simulator"),
        ("camera_yaw=2", "camera_yaw: physics and camera"),
        ("obs_delay=1", "did you mean 'observation_delay'"),
        ("action_delay=-1", "action_delay: expected an integer"),
    ],
)
def test_perturbations_the_node_does_not_own_or_cannot_read_are_one_line(make_node, value, message):
    from dlo_common.node_util import ParameterError

    with pytest.raises(ParameterError, match="^parameter 'perturbations': .*" + message) as error:
        make_node(act=RecordingPolicy(), perturbations=value)
    assert "\n" not in str(error.value)
