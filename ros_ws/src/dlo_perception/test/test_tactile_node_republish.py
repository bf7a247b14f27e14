"""tactile_node in-process (no graph; issue 14): one noise draw per control step.

A step the sim republishes (same stamp: nobody answered it) gets the SAME tactile reading, noise
included; the next step gets a new draw; the reading carries the input's stamp; the generator is
seeded by the ``seed`` parameter; ``tactile_noise:=none`` is the exact line fit of dlo_perception.tactile.
Its noise parameter ``tactile_noise`` takes a preset or a pair in each ROS form; the names it had before
(``noise``, ``sigma_theta``, ``sigma_y``) are unknown parameters like any other.
"""

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
from dlo_common.params import ParameterError  # noqa: E402
from dlo_msgs.msg import GripperState  # noqa: E402
from dlo_perception import tactile_node as tactile_node_module  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

DECLARE = tactile_node_module.declare_parameters  # the original: every node gets only its own overrides
from dlo_interface.cloud import particle_cloud  # noqa: E402
from dlo_perception.tactile import tactile_pose  # noqa: E402


class Published(list):
    def publish(self, msg):
        self.append(msg)


@pytest.fixture
def make_node(context, monkeypatch):
    nodes = []

    def make(**parameters):
        monkeypatch.setattr(tactile_node_module, "declare_parameters", lambda n, specs: {**DECLARE(n, specs), **parameters})
        init = rclpy.node.Node.__init__
        monkeypatch.setattr(rclpy.node.Node, "__init__", lambda self, *a, **k: init(self, *a, **{"context": context, **k}))
        node = tactile_node_module.TactileNode()
        monkeypatch.setattr(rclpy.node.Node, "__init__", init)
        node.real_publisher = node.publisher
        node.publisher = Published()
        nodes.append(node)
        return node

    yield make
    for node in nodes:
        node.destroy_node()


@pytest.fixture
def node_with(context, monkeypatch):
    """A tactile node given these parameters as ``-p`` would (its real declare_parameters)."""
    nodes = []

    def make(**overrides):
        init = rclpy.node.Node.__init__
        given = [Parameter(name, value=value) for name, value in overrides.items()]
        monkeypatch.setattr(
            rclpy.node.Node,
            "__init__",
            lambda self, *a, **k: init(self, *a, **{"context": context, "parameter_overrides": given, **k}),
        )
        try:
            node = tactile_node_module.TactileNode()
        finally:
            monkeypatch.setattr(rclpy.node.Node, "__init__", init)
        nodes.append(node)
        return node

    yield make
    for node in nodes:
        node.destroy_node()


POSITIONS = np.array(
    [[-0.25, 0.0, 0.1], [0.0, -0.001, 0.085], [0.004, 0.0005, 0.085], [0.008, 0.002, 0.085], [0.05, 0.01, 0.02]], np.float32
)
HELD = np.array([False, True, True, True, False])


def feed(node, step, closure=0.0, gripper_xy=(0.002, 0.0005)):
    """One control step's particles and gripper state, stamped step * 0.08 s."""
    sec, nanosec = divmod(step * 80_000_000, 1_000_000_000)
    cloud = particle_cloud(POSITIONS, HELD)
    state = GripperState(x=gripper_xy[0], y=gripper_xy[1], z=0.1, closure=closure, episode=0, step=step)
    for msg in (cloud, state):
        msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
        msg.header.frame_id = "world"
    node.on_input("particles", cloud)
    node.on_input("gripper", state)
    return sec, nanosec


def reading(msg):
    return (msg.angle, msg.y, msg.contact, msg.contact_count)


def test_a_republished_step_gets_the_same_noisy_reading(make_node):
    node = make_node(tactile_noise="full", seed=3)
    stamp = feed(node, 5)
    feed(node, 5)  # the sim republished step 5
    feed(node, 6)
    first, again, next_step = node.publisher
    assert reading(again) == reading(first)
    assert (again.header.stamp.sec, again.header.stamp.nanosec) == stamp
    assert first.header.frame_id == "gripper"  # the line is fitted in the gripper frame
    assert (next_step.angle, next_step.y) != (first.angle, first.y)  # a new step: a new draw
    exact = tactile_pose(POSITIONS[:, :2], HELD, (0.002, 0.0005), 0.0)
    assert (first.angle, first.y) != pytest.approx((exact.angle, exact.y), abs=1e-6)  # the noise is there
    assert first.contact and first.contact_count == 3


def test_the_noise_generator_follows_the_seed(make_node):
    a, b, c = (
        make_node(tactile_noise="full", seed=3),
        make_node(tactile_noise="full", seed=3),
        make_node(tactile_noise="full", seed=4),
    )
    for node in (a, b, c):
        feed(node, 1)
    assert reading(a.publisher[0]) == reading(b.publisher[0]) != reading(c.publisher[0])


def test_no_noise_is_the_exact_line_fit_and_a_closed_gripper_has_none(make_node):
    exact = tactile_pose(POSITIONS[:, :2], HELD, (0.002, 0.0005), 0.0)
    quiet = make_node(tactile_noise="none")
    feed(quiet, 2)
    assert (quiet.publisher[0].angle, quiet.publisher[0].y) == pytest.approx((exact.angle, exact.y), abs=1e-9)
    closed = make_node(tactile_noise="full", seed=1)
    feed(closed, 2, closure=1.0)  # noise scales with 1 - c_G
    assert (closed.publisher[0].angle, closed.publisher[0].y) == pytest.approx((exact.angle, exact.y), abs=1e-9)
    custom = make_node(tactile_noise=(0.0, 0.001), seed=1)
    feed(custom, 2)
    assert custom.publisher[0].angle == pytest.approx(exact.angle, abs=1e-9)
    assert custom.publisher[0].y != pytest.approx(exact.y, abs=1e-7)


def test_topics_and_parameter_defaults(make_node):
    node = make_node()
    assert node.real_publisher.topic_name == "/dlo/tactile/pose"
    assert sorted(s.topic_name for s in node.subscriptions) == ["/dlo/gripper/state", "/dlo/rope/particles"]
    assert {name: node.get_parameter(name).value for name in ("tactile_noise", "seed")} == {"tactile_noise": "none", "seed": 0}
    assert not any(node.has_parameter(name) for name in ("noise", "sigma_theta", "sigma_y"))  # the names before tactile_noise
    assert node.sigma == (0.0, 0.0)
    default_seed = make_node(tactile_noise="full")
    feed(default_seed, 1)
    seeded = make_node(tactile_noise="full", seed=0)
    feed(seeded, 1)
    assert reading(default_seed.publisher[0]) == reading(seeded.publisher[0])


@pytest.mark.parametrize("value", [[0.1, 0.001], "0.1,0.001", "[0.1,0.001]", [0.1, 1e-3]])
def test_a_pair_in_each_ros_form(node_with, value, capfd):
    node = node_with(tactile_noise=value)
    assert node.sigma == (0.1, 0.001) and node.tactile_noise == (0.1, 0.001)
    assert node.get_parameter("tactile_noise").value == value  # the parameter as given
    assert "tactile noise: sigma_theta 0.1 rad, sigma_y 0.001 m; seed 0" in capfd.readouterr().err


@pytest.mark.parametrize(
    "overrides,message",
    [
        ({"tactile_noise": "loud"}, "parameter 'tactile_noise': expected none, partial, full or a pair"),
        ({"tactile_noise": [0.1, -0.001]}, "parameter 'tactile_noise': expected none, partial, full or a pair"),
        ({"tactile_noise": "custom"}, "parameter 'tactile_noise': expected none, partial, full or a pair"),
        ({"noise": "full"}, "unknown parameter 'noise'; did you mean 'tactile_noise'?"),
        ({"tactile_noise": "full", "sigma_y": 0.001}, "unknown parameter 'sigma_y'; did you mean 'tactile_noise'?"),
    ],
)
def test_bad_noise_parameters_are_refused(node_with, overrides, message):
    with pytest.raises(ParameterError) as error:
        node_with(**overrides)
    assert str(error.value).startswith(message)
