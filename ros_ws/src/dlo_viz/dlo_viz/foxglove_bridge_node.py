"""foxglove_bridge: the graph's topics, live, in Foxglove (WebSocket, CDR, ros2msg schemas).

    ros2run dlo_viz foxglove_bridge [--ros-args -p port:=8765 -p address:=127.0.0.1 \
        -p topics:="['/dlo', '/clock']"]

then open the printed URL (Foxglove web app), or in the Foxglove desktop app: Open connection ->
Foxglove WebSocket -> ``ws://127.0.0.1:8765``; import the layout ``docs/foxglove/dlo_vitac.json``.

The node discovers topics periodically and subscribes to every one that matches ``topics``
(a name or a namespace: ``/dlo`` = every topic under /dlo) once it has a publisher, as raw CDR
(``raw=True``): best effort by default, so that the graph's publishers process no
acknowledgements for the viewer (``reliable:=true`` matches reliable publishers); transient-local
topics (camera_info) reliable and transient-local. The bytes go to the WebSocket clients
unchanged, with the message definitions the recorder writes into bags
(:mod:`dlo_viz.foxglove_bridge`). Topics that appear later are advertised to connected
clients; a topic is subscribed only while a client watches it (``lazy``; transient-local topics
always), so a bridge nobody watches costs the graph nothing; clients may connect and leave at
any time; a slow client loses its oldest queued messages instead of slowing the graph. At shutdown it logs how many
messages it received and forwarded per topic (``summary_file``: the same as JSON).

Clients must offer the WebSocket subprotocol ``foxglove.sdk.v1`` (as foxglove_bridge 3.x): one that offers only
``foxglove.websocket.v1`` (older Foxglove and Lichtblick releases, scripts) is refused with HTTP 400 and one
warning line, and the bridge goes on serving the others.

Exit status: 0 after SIGINT/SIGTERM, 2 = bad parameter, 3 = the address/port cannot be bound.
"""

from __future__ import annotations

import functools
import json
import logging
import os
import sys
import time
from pathlib import Path

from dlo_bag.errors import BagError
from dlo_bag.playback import import_message_class
from dlo_bag.qos import qos_from_profile, subscription_qos
from dlo_common.node_util import NodeStartError, ParameterError, declare_parameters
from dlo_common.params import Param
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import QosDurability, QosReliability

from .foxglove_bridge import DEFAULT_ADDRESS, DEFAULT_CLIENT_BACKLOG, DEFAULT_PORT, DEFAULT_TOPICS, FoxgloveBridge, topic_matches

PARAMETERS = (
    Param(
        "port", DEFAULT_PORT, "TCP port of the WebSocket server (0 = any free port; the log names it).", at_least=0, at_most=65535
    ),
    (
        "address",
        DEFAULT_ADDRESS,
        "Address to bind: 127.0.0.1 (this machine only, default) or "
        "0.0.0.0 (every interface: anyone on the network can connect).",
    ),
    ("topics", list(DEFAULT_TOPICS), "Topics to serve: names or namespaces (a namespace serves every topic under it)."),
    Param(
        "client_backlog",
        DEFAULT_CLIENT_BACKLOG,
        "Messages queued per client; a client that falls further behind loses its oldest queued messages.",
        at_least=1,
    ),
    Param("queue_depth", 100, "Subscription history depth (KEEP_LAST) per topic.", at_least=1),
    (
        "lazy",
        True,
        "Subscribe to a topic only while a client subscribes to it (transient-local topics "
        "always): a bridge nobody watches costs the graph nothing.",
    ),
    (
        "reliable",
        False,
        "Subscribe reliably to topics whose publishers are reliable. Default false: "
        "best effort (no acknowledgements for the graph's publishers to process; "
        "transient-local topics such as camera_info are always reliable).",
    ),
    Param(
        "nice",
        0,
        "Raise this process's nice value by this much at start (0..19) to yield the CPU to "
        "the graph's nodes on a busy machine (measured: no gain in the loop's rate on 2 loaded "
        "cores, latency to the clients x2).",
        at_least=0,
        at_most=19,
    ),
    Param("discovery_period", 0.5, "Seconds between topic discovery passes.", above=0.0),
    Param("stats_period", 30.0, "Seconds between the bridge's one-line statistics in the log (0 = never).", at_least=0.0),
    ("summary_file", "", "If set, write the per-topic counts there as JSON at shutdown."),
)


class FoxgloveBridgeNode(Node):
    """Thin node: discovery and raw subscriptions around :class:`FoxgloveBridge`."""

    def __init__(self, **options) -> None:
        super().__init__("foxglove_bridge", **options)
        self._name = self.get_name()  # for lines after the node is destroyed (the SDK's threads may still log)
        p = declare_parameters(self, PARAMETERS)
        if p["nice"]:
            os.nice(p["nice"])
        self.reliable = p["reliable"]
        self.lazy = p["lazy"]
        self._qos: dict[str, tuple] = {}  # advertised topic -> (message class, QoS, latched)
        self.patterns = [t for t in p["topics"] if t.strip()]
        if not self.patterns:
            raise ParameterError("parameter 'topics': give at least one topic or namespace, e.g. '/dlo'")
        self.queue_depth = p["queue_depth"]
        self.summary_file = p["summary_file"]
        self._served: dict[str, object] = {}
        self._skipped: set[str] = set()
        self._warned: set[tuple[str, str]] = set()
        levels = {logging.DEBUG: "debug", logging.INFO: "info", logging.WARNING: "warning"}
        self.bridge = FoxgloveBridge(
            port=p["port"],
            address=p["address"],
            client_backlog=p["client_backlog"],
            log=lambda level, text: self._say(text, levels.get(level, "error")),
        )
        try:
            self.bridge.start()
        except OSError as err:
            raise NodeStartError(
                f"{err} (another bridge running? choose one with -p port:=N, or port:=0 for any free port)"
            ) from None
        self._started = time.monotonic()
        self._cpu0 = os.times()
        self.get_logger().info(
            f"Foxglove bridge on {self.bridge.ws_url} serving {', '.join(self.patterns)}: open {self.bridge.app_url}"
        )
        self.create_timer(p["discovery_period"], self.discover)
        self.create_timer(0.05, self.sync_subscriptions)
        if p["stats_period"] > 0:
            self.create_timer(p["stats_period"], self.log_stats)
        self.discover()

    def _warn_once(self, topic: str, text: str) -> None:
        if (topic, text) not in self._warned:
            self._warned.add((topic, text))
            self.get_logger().warning(f"{topic}: {text}")

    def discover(self) -> None:
        """Advertise and subscribe to matching topics that have at least one publisher."""
        for topic, types in self.get_topic_names_and_types():
            if topic in self._qos or topic in self._skipped:
                continue
            if not topic_matches(topic, self.patterns):
                continue
            infos = self.get_publishers_info_by_topic(topic)
            if not infos:  # only subscribers so far: wait for a publisher to learn its QoS
                continue
            msgtype = types[0]
            if len(types) > 1:
                self._warn_once(topic, f"several types {types}; serving {msgtype} only")
            offered = [qos_from_profile(i.qos_profile) for i in infos]
            rel, dur = subscription_qos(offered)
            if not self.reliable and dur != QosDurability.TRANSIENT_LOCAL:
                rel = QosReliability.BEST_EFFORT
            try:
                msg_class = import_message_class(msgtype)
                self.bridge.add_topic(topic, msgtype, latched=dur == QosDurability.TRANSIENT_LOCAL)
            except (BagError, ValueError) as err:
                self._skipped.add(topic)
                self.get_logger().error(f"{topic}: not served: {err}")
                continue
            qos = QoSProfile(
                history=HistoryPolicy.KEEP_LAST,
                depth=self.queue_depth,
                reliability=ReliabilityPolicy(rel.value),
                durability=DurabilityPolicy(dur.value),
            )
            self._qos[topic] = (msg_class, qos, dur == QosDurability.TRANSIENT_LOCAL)
            self.get_logger().info(
                f"advertising {topic} [{msgtype}] ({rel.name.lower()}, {dur.name.lower()}"
                f"{', subscribed while watched' if self.lazy else ''})"
            )
            self._update_subscription(topic)

    def _update_subscription(self, topic: str) -> None:
        """Subscribe to ``topic`` while it is wanted (watched, latched, or not lazy), else not."""
        if topic not in self._qos:
            return
        msg_class, qos, latched = self._qos[topic]
        wanted = latched or not self.lazy or self.bridge.watched(topic)
        if wanted and topic not in self._served:
            events = SubscriptionEventCallbacks(message_lost=functools.partial(self._on_lost, topic))
            self._served[topic] = self.create_subscription(
                msg_class, topic, functools.partial(self._on_message, topic), qos, raw=True, event_callbacks=events
            )
        elif not wanted and topic in self._served:
            self.destroy_subscription(self._served.pop(topic))

    def sync_subscriptions(self) -> None:
        """Follow the clients' subscriptions (lazy), advertise again the channels a client lost to the SDK's
        race and resend latched messages to new subscribers (FoxgloveBridge.maintain)."""
        for topic in self.bridge.changed_topics():
            self._update_subscription(topic)
        self.bridge.maintain()

    def _on_message(self, topic: str, data: bytes) -> None:
        self.bridge.forward(topic, data)

    def _on_lost(self, topic: str, info) -> None:
        self.bridge.stats.lost[topic] += int(info.total_count_change)

    def cpu_seconds(self) -> float:
        now = os.times()
        return (now.user - self._cpu0.user) + (now.system - self._cpu0.system)

    def _say(self, text: str, level: str = "info") -> None:
        """Log through ROS while the context lives; after a signal shut it down, to stderr. Never raises: the
        SDK's threads call it (the bridge's lines about clients), and a log line must not end the node.

        rclpy ties a severity to each calling line (a second severity from the same line raises ValueError),
        so every severity has its own call here."""
        try:
            if self.context.ok():
                logger = self.get_logger()
                if level == "debug":
                    logger.debug(text)
                elif level == "info":
                    logger.info(text)
                elif level == "warning":
                    logger.warning(text)
                else:
                    logger.error(text)
                return
        except Exception:  # noqa: BLE001 - the context went down meanwhile, or the logger refused: stderr below
            pass
        try:
            print(f"[{level.upper()}] [{self._name}]: {text}", file=sys.stderr, flush=True)
        except Exception:  # noqa: BLE001 - no stderr left: the line is lost, the node goes on
            pass

    def log_stats(self) -> None:
        s = self.bridge.stats
        self._say(
            f"{len(self._qos)} topics ({len(self._served)} subscribed), {s.clients_now} client(s) connected; received "
            f"{sum(s.received.values())}, forwarded {sum(s.forwarded.values())}"
            + (f", lost before delivery {sum(s.lost.values())}" if s.lost else "")
            + (f", slow clients reported {len(s.slow_client_reports)}" if s.slow_client_reports else "")
            + (f", clients refused {s.clients_refused}" if s.clients_refused else "")
            + (f", channels advertised again {s.readvertised}" if s.readvertised else "")
        )

    def finish(self) -> dict:
        """Stop the server (bounded time) and report the counts (run_node calls this once the node stops)."""
        stopped = self.bridge.stop()
        summary = self.bridge.stats.to_dict()
        summary.update(
            url=self.bridge.ws_url,
            wall_s=round(time.monotonic() - self._started, 3),
            cpu_s=round(self.cpu_seconds(), 3),
            stopped_cleanly=stopped,
        )
        self.log_stats()
        self._say(f"bridge cpu {summary['cpu_s']:.2f} s over {summary['wall_s']:.1f} s")
        if not stopped:
            self._say("a client stopped reading: the server was left to close in the background", "warning")
        if self.summary_file:
            try:
                Path(self.summary_file).write_text(json.dumps(summary) + "\n")
            except OSError as err:
                self._say(f"cannot write summary_file {self.summary_file}: {err}", "error")
        return summary


def main(args=None):
    from dlo_common.node_main import run_node

    return run_node(FoxgloveBridgeNode, args, parameters=PARAMETERS, summary=__doc__)


if __name__ == "__main__":
    raise SystemExit(main())
