"""playback_node: republishes a recorded bag into a live graph, keeping its relative timing.

    ros2run dlo_bag playback_node --ros-args -p bag:=bags/run1 [-p rate:=4.0] \
        [-p topics:="['/dlo/camera/image']"] [-p loop:=true]

Messages are published as the recorded CDR bytes (no deserialisation) on publishers of the
recorded types and QoS. ``rate`` 1.0 = recorded speed, N = N times faster, 0 = no waiting.
"""

from __future__ import annotations

import sys
import time

import rclpy
from dlo_common.node_main import handle_help, shut_down
from dlo_common.node_util import ParameterError, ShutdownRequest, declare_parameters
from dlo_common.params import Param
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rosbags.interfaces import QosDurability, QosReliability

from .errors import BagError
from .info import bag_info
from .playback import Pacer, import_message_class, playback_qos
from .reader import read_messages

PARAMETERS = (
    ("bag", "", "Bag directory to play (a rosbag2 bag, or a directory of rolled parts). Required."),
    Param("rate", 1.0, "Rate factor: 1.0 = recorded speed, 2.0 = twice as fast, 0 = as fast as possible.", at_least=0.0),
    ("topics", [], "Topics to play (string list); empty = every topic of the bag."),
    ("loop", False, "Play the bag again and again until stopped."),
    (
        "wait_for_subscribers",
        0,
        "Before playing, wait until every publisher has at least this many matched subscriptions (0 = do not wait).",
    ),
    ("wait_timeout", 10.0, "Give up waiting for subscribers after this many seconds (then play)."),
    Param("queue_depth", 1000, "Publisher history depth for volatile topics.", at_least=1),
    Param(
        "linger",
        2.0,
        "After the last message, wait up to this many seconds for reliable subscribers to "
        "acknowledge every message (what a busy subscriber has not received when the node exits is lost; a "
        "warning names such topics).",
        at_least=0.0,
    ),
)

EXIT_CODES = "0 played (also when stopped by a signal), 1 failed (see stderr), 2 bad parameter or unreadable bag"


class PlaybackNode(Node):
    """Thin node: publishers for the bag's topics, paced by :class:`dlo_bag.playback.Pacer`."""

    def __init__(self) -> None:
        super().__init__("playback")
        p = declare_parameters(self, PARAMETERS)
        if not p["bag"]:
            raise ParameterError("parameter 'bag' is required: -p bag:=<bag directory>")
        self.bag = p["bag"]
        self.pacer = Pacer(p["rate"])
        self.loop = p["loop"]
        self.wait_count = p["wait_for_subscribers"]
        self.wait_timeout = p["wait_timeout"]
        self.linger = p["linger"]
        info = bag_info(self.bag)
        wanted = [t for t in p["topics"] if t]
        missing = [t for t in wanted if t not in info.topics]
        if missing:
            raise ParameterError(f"parameter 'topics': {missing} not in the bag; it has {sorted(info.topics)}")
        self.topics = wanted or sorted(info.topics)
        self._pubs: dict[str, object] = {}
        self.reliable: list[object] = []
        for topic in self.topics:
            t = info.topics[topic]
            rel, dur = playback_qos(t.qos)
            depth = p["queue_depth"]
            if dur == QosDurability.TRANSIENT_LOCAL:
                depth = max([q.depth for q in t.qos if q.depth > 0] or [1])
            qos = QoSProfile(
                history=HistoryPolicy.KEEP_LAST,
                depth=depth,
                reliability=ReliabilityPolicy(rel.value),
                durability=DurabilityPolicy(dur.value),
            )
            try:
                msg_class = import_message_class(t.msgtype)
            except ValueError as err:
                raise BagError(f"{topic}: {err}") from None
            pub = self.create_publisher(msg_class, topic, qos)
            self._pubs[topic] = pub
            if rel == QosReliability.RELIABLE:
                self.reliable.append(pub)
        self.count = 0
        self.get_logger().info(
            f"playing {self.bag} ({info.message_count} messages, "
            f"{info.duration_ns / 1e9:.3f} s) at rate {self.pacer.rate:g}: "
            f"{', '.join(self.topics)}"
        )

    def wait_for_subscribers(self, executor: SingleThreadedExecutor, stop: ShutdownRequest) -> None:
        if self.wait_count <= 0:
            return
        end = time.monotonic() + self.wait_timeout
        while not stop.is_set() and time.monotonic() < end:
            if all(p.get_subscription_count() >= self.wait_count for p in self._pubs.values()):
                self.get_logger().info(f"every topic has {self.wait_count} subscriber(s): playing")
                return
            executor.spin_once(timeout_sec=0.05)
        if not stop.is_set():
            self.get_logger().warning(
                f"not every topic has {self.wait_count} subscriber(s) after {self.wait_timeout:g} s; playing anyway"
            )

    def play_once(self, executor: SingleThreadedExecutor, stop: ShutdownRequest) -> None:
        started = False
        for m in read_messages(self.bag, self.topics, raw=True):
            if not started:
                self.pacer.start(m.timestamp, time.monotonic())
                started = True
            deadline = self.pacer.deadline(m.timestamp)
            while not stop.is_set():
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                executor.spin_once(timeout_sec=min(left, 0.05))
            if stop.is_set():
                return
            self._pubs[m.topic].publish(bytes(m.msg))
            self.count += 1

    def finish(self) -> None:
        """Wait up to ``linger`` s for the reliable subscribers to acknowledge every message; once this node
        exits, what a busy subscriber (a node starved of CPU) has not received yet is lost: a warning names
        the topics whose subscribers had not acknowledged everything."""
        end = time.monotonic() + self.linger
        # a topic without subscribers (none came, or they left once served) has nothing left to acknowledge
        waiting = [pub for pub in self.reliable if not pub.wait_for_all_acked(Duration(nanoseconds=0))]
        if waiting:
            self.get_logger().info(
                f"played; waiting up to {self.linger:g} s for the subscribers of "
                f"{', '.join(p.topic_name for p in waiting)} to acknowledge every message"
            )
        unacked = [
            pub.topic_name
            for pub in waiting
            if not pub.wait_for_all_acked(Duration(nanoseconds=int(max(end - time.monotonic(), 0.0) * 1e9)))
        ]
        if unacked:
            self.get_logger().warning(
                f"not every subscriber of {', '.join(unacked)} acknowledged the last messages "
                f"within linger {self.linger:g} s: a busy subscriber may miss them "
                "(raise -p linger:=<seconds>)"
            )


def main(args: list[str] | None = None) -> int:
    answered = handle_help("dlo_bag", PARAMETERS, __doc__, args, EXIT_CODES)
    if answered is not None:
        return answered
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = ShutdownRequest().install()
    node = None
    rc = 0
    try:
        node = PlaybackNode()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        node.wait_for_subscribers(executor, stop)
        while not stop.is_set():
            node.play_once(executor, stop)
            if not node.loop:
                break
        node.finish()
        node.get_logger().info(f"published {node.count} messages" + (f" (stopped by {stop.name})" if stop.is_set() else ""))
    except (ParameterError, BagError) as err:
        print(f"playback_node: error: {err}", file=sys.stderr)
        rc = 2
    finally:
        shut_down(node)  # a middleware teardown that hangs is cut (exit 1, stacks on stderr)
        stop.restore()
    return rc


if __name__ == "__main__":
    sys.exit(main())
