"""recorder_node: records every /dlo topic (raw CDR) into a rosbag2 MCAP bag.

    ros2run dlo_bag recorder_node --ros-args -p output:=bags/run1 [-p split_episodes:=10]

Topics are discovered periodically; each is subscribed with ``raw=True`` once it has a
publisher, with the reliability/durability its publishers offer. What is received goes to disk
every ``flush_period`` seconds (a SIGKILL loses at most that; ``dlo-bag-recover`` restores the
rest). SIGINT/SIGTERM/SIGHUP stop the node after draining what has already arrived, and the bag
is closed (metadata.yaml) on every exit path. At shutdown it logs received/written/dropped
counts (dropped must be 0).

Exit status: 0 = complete bag, 1 = messages were dropped, 2 = bad parameter or output,
3 = the recording failed (a write error: disk full, permission, I/O; logged once as
``recording failed: <cause>``); the bag then holds everything written before the failure.
"""

from __future__ import annotations

import functools
import json
import sys
import time
from pathlib import Path

import rclpy
from dlo_common.node_main import handle_help, shut_down
from dlo_common.node_util import ParameterError, ShutdownRequest, declare_parameters
from dlo_common.params import Param
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

from .errors import BagError
from .playback import import_message_class
from .qos import qos_from_profile, subscription_qos
from .recording import TASK_TOPIC, Recorder, RecordSummary, default_output, topic_selected
from .writer import BagWriteError

PARAMETERS = (
    ("output", "", "Bag directory to create (must not exist). Empty: bags/rosbag2_<date-time> in the working directory."),
    ("namespace", "/dlo", "Record every topic in this namespace ('/' = all topics)."),
    ("record_clock", False, "Also record /clock."),
    ("extra_topics", [], "Further topics to record (string list)."),
    Param(
        "split_episodes",
        0,
        "0: one bag per run. N > 0: 'output' becomes a directory of bags, a new "
        "one every N episodes (by the episode of task_topic).",
        at_least=0,
    ),
    ("task_topic", TASK_TOPIC, "dlo_msgs/TaskState topic that marks episodes for split_episodes."),
    Param("discovery_period", 0.25, "Seconds between topic discovery passes.", above=0.0),
    Param("queue_depth", 1000, "Subscription history depth (KEEP_LAST) per topic.", at_least=1),
    ("summary_file", "", "If set, write the received/written/dropped counts there as JSON at shutdown."),
    Param(
        "drain_timeout",
        2.0,
        "On shutdown, keep taking already-delivered messages for at most this "
        "many seconds (stops earlier once nothing arrives for 0.2 s).",
        at_least=0.0,
    ),
    Param(
        "flush_period",
        0.5,
        "Seconds between writes of what was received to disk (a killed recorder loses at most this much).",
        above=0.0,
    ),
    ("fsync", True, "fsync the bag on every flush (survives a power loss, not only a kill)."),
)

EXIT_DROPPED, EXIT_BAD_PARAMETER, EXIT_RECORDING_FAILED = 1, 2, 3
EXIT_CODES = (
    "0 complete bag (also after a signal), 1 messages were dropped (or, after the bag was closed, the "
    "middleware's teardown hung: see stderr), 2 bad parameter or output, 3 recording failed"
)


class RecorderNode(Node):
    """Thin node around :class:`dlo_bag.recording.Recorder`."""

    def __init__(self, stop: ShutdownRequest | None = None, **options) -> None:
        super().__init__("recorder", **options)
        self.stop = stop
        p = declare_parameters(self, PARAMETERS)
        self.namespace = p["namespace"] or "/"
        self.record_clock = p["record_clock"]
        self.extra_topics = [t for t in p["extra_topics"] if t]
        self.queue_depth = p["queue_depth"]
        self.drain_timeout = p["drain_timeout"]
        self.summary_file = p["summary_file"]
        output = p["output"] or str(default_output())
        self.recorder = Recorder(output, split_episodes=p["split_episodes"], task_topic=p["task_topic"], fsync=p["fsync"])
        self._recorded: dict[str, object] = {}
        self._reliability: dict[str, object] = {}
        self._skipped: set[str] = set()
        self._warned: set[tuple[str, str]] = set()
        self._error_logged = 0.0
        self.get_logger().info(
            f"recording '{self.namespace}'{' + /clock' if self.record_clock else ''}"
            f"{' + ' + ', '.join(self.extra_topics) if self.extra_topics else ''} "
            f"to {self.recorder.path}"
        )
        self.create_timer(p["discovery_period"], self.discover)
        self.create_timer(p["flush_period"], self.flush)
        self._failure_logged = False

    def _warn_once(self, topic: str, text: str) -> None:
        if (topic, text) not in self._warned:
            self._warned.add((topic, text))
            self.get_logger().warning(f"{topic}: {text}")

    def discover(self) -> None:
        """Subscribe to new topics that have at least one publisher."""
        for topic, types in self.get_topic_names_and_types():
            if topic in self._skipped or not topic_selected(
                topic, self.namespace, clock=self.record_clock, extra=self.extra_topics
            ):
                continue
            infos = self.get_publishers_info_by_topic(topic)
            if not infos:  # only subscribers so far: wait for a publisher to learn its QoS
                continue
            offered = [qos_from_profile(i.qos_profile) for i in infos]
            if topic in self._recorded:
                rel, _ = subscription_qos(offered)
                if rel.value != self._reliability[topic]:
                    self._warn_once(
                        topic, "a publisher now offers best-effort QoS; the reliable subscription cannot receive from it"
                    )
                continue
            msgtype = types[0]
            if len(types) > 1:
                self._warn_once(topic, f"several types {types}; recording {msgtype} only")
            try:
                spec = self.recorder.add_topic(topic, msgtype, offered)
                msg_class = import_message_class(msgtype)
            except (BagError, ValueError) as err:
                self._skipped.add(topic)
                self.get_logger().error(f"{topic}: not recorded: {err}")
                continue
            for info in infos:
                graph_hash = str(info.topic_type_hash)
                if graph_hash.startswith("RIHS01_") and graph_hash != spec.rihs01:
                    self._warn_once(
                        topic, f"publisher type hash {graph_hash} differs from the installed definition's {spec.rihs01}"
                    )
            rel, dur = subscription_qos(offered)
            qos = QoSProfile(
                history=HistoryPolicy.KEEP_LAST,
                depth=self.queue_depth,
                reliability=ReliabilityPolicy(rel.value),
                durability=DurabilityPolicy(dur.value),
            )
            events = SubscriptionEventCallbacks(
                message_lost=functools.partial(self._on_lost, topic),
                incompatible_qos=functools.partial(self._on_incompatible, topic),
            )
            self._recorded[topic] = self.create_subscription(
                msg_class, topic, functools.partial(self._on_message, topic), qos, raw=True, event_callbacks=events
            )
            self._reliability[topic] = rel.value
            self.get_logger().info(f"recording {topic} [{msgtype}] ({rel.name.lower()}, {dur.name.lower()})")

    def _on_message(self, topic: str, data: bytes) -> None:
        error = self.recorder.on_message(topic, data, self.get_clock().now().nanoseconds)
        if self.recorder.failure:
            self._on_failure()
        elif error is not None and time.monotonic() - self._error_logged > 1.0:
            self._error_logged = time.monotonic()
            self.get_logger().error(f"write failed ({self.recorder.errors} so far): {error}")

    def flush(self) -> None:
        self.recorder.flush()
        if self.recorder.failure:
            self._on_failure()

    def _on_failure(self) -> None:
        """A write error is fatal: log the cause once and stop (the bag is closed in finish())."""
        if self._failure_logged:
            return
        self._failure_logged = True
        self.get_logger().error(
            f"recording failed: {self.recorder.failure} ({self.recorder.last_error}); "
            "stopping and closing the bag with what was written"
        )
        if self.stop is not None:
            self.stop.request()

    def _on_lost(self, topic: str, info) -> None:
        self.recorder.on_lost(topic, int(info.total_count_change))
        self.get_logger().error(
            f"{topic}: the middleware lost {info.total_count_change} message(s) before delivery ({info.total_count} so far)"
        )

    def _on_incompatible(self, topic: str, info) -> None:
        self._warn_once(
            topic,
            f"a publisher's QoS is incompatible with the recorder's subscription (policy {info.last_policy_kind}); not recorded",
        )

    @property
    def received(self) -> int:
        return sum(self.recorder.received.values())

    def drain(self, executor: SingleThreadedExecutor) -> None:
        """Take messages that were delivered before the stop request (bounded time)."""
        end = time.monotonic() + self.drain_timeout
        quiet_since = time.monotonic()
        last = self.received
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
            now = time.monotonic()
            if self.received != last:
                last, quiet_since = self.received, now
            elif now - quiet_since >= 0.2:
                break

    def finish(self) -> RecordSummary:
        """Close the bag and log the counts."""
        summary = self.recorder.close()
        log = self.get_logger()
        for line in summary.lines():
            (log.error if line.startswith("recording failed") else log.info)(line)
        if summary.failure and not self._failure_logged:
            self._failure_logged = True
            log.error(f"recording failed: {summary.failure} ({summary.last_error})")
        if summary.dropped:
            log.error(f"{summary.dropped} messages were not written")
        if self.summary_file:
            try:
                Path(self.summary_file).write_text(json.dumps(summary.to_dict()) + "\n")
            except OSError as err:
                log.error(f"cannot write summary_file {self.summary_file}: {err}")
        return summary


def exit_status(summary: RecordSummary, rc: int = 0) -> int:
    """The recorder's exit status once its bag is closed (EXIT_CODES): 3 when the recording failed, else ``rc`` (a
    bad parameter or output), else 1 when messages were dropped, else 0."""
    if summary.failure:
        return EXIT_RECORDING_FAILED
    return rc or (EXIT_DROPPED if summary.dropped else 0)


def main(args: list[str] | None = None) -> int:
    answered = handle_help("dlo_bag", PARAMETERS, __doc__, args, EXIT_CODES)
    if answered is not None:
        return answered
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = ShutdownRequest().install()
    node = None
    rc = 0
    try:
        node = RecorderNode(stop)
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        node.discover()
        while not stop.is_set() and rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
        if not node.recorder.failure:
            node.get_logger().info(f"stopping ({stop.name}): draining and closing the bag")
            node.drain(executor)
    except BagWriteError as err:  # the bag cannot even be created (disk full, permission)
        print(f"recorder_node: recording failed: {err.cause} ({err})", file=sys.stderr)
        rc = EXIT_RECORDING_FAILED
    except (ParameterError, BagError) as err:
        print(f"recorder_node: error: {err}", file=sys.stderr)
        rc = EXIT_BAD_PARAMETER
    finally:
        if node is not None:
            rc = exit_status(node.finish(), rc)
        shut_down(node)  # the bag is closed: a middleware teardown that hangs is cut (exit 1, stacks on stderr)
        stop.restore()
    return rc


if __name__ == "__main__":
    sys.exit(main())
