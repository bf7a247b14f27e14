"""Live view: serve raw CDR messages over the Foxglove WebSocket protocol (foxglove-sdk, no rclpy).

:class:`FoxgloveBridge` owns a foxglove-sdk WebSocket server. For every topic it is given
(:meth:`FoxgloveBridge.add_topic`) it advertises a channel with ``encoding: cdr`` and a
``schemaEncoding: ros2msg`` schema: the full message definition (every nested type after a
``MSG:`` separator) from :func:`dlo_bag.typestore.message_definition`, the same text the recorder
embeds in its bags, so a live connection and a recorded bag look the same to Foxglove. Messages
are forwarded as the received bytes (:meth:`FoxgloveBridge.forward`): nothing is deserialised.

Clients come and go at any time; topics added later are advertised to every connected client.
A slow client never blocks the caller: the SDK queues at most ``client_backlog`` messages per
client and drops the oldest beyond that (for that client only). Counts per topic (received,
forwarded to at least one client) are kept in :attr:`FoxgloveBridge.stats`.

Topics published with transient-local durability (``camera_info``) are latched: their last
message is sent again when a client subscribes, as a ROS subscriber would receive it.

Clients must offer the WebSocket subprotocol ``foxglove.sdk.v1`` (:data:`SUBPROTOCOL`, what the SDK's
server speaks, as foxglove_bridge 3.x): one that offers only the older ``foxglove.websocket.v1`` is
refused with HTTP 400 by the SDK; the bridge counts it (``clients_refused``), says why in one line and
serves the other clients as before.

A channel created while clients are connected can lose a client's subscription: with the installed
foxglove-sdk a client that subscribes as soon as the advertisement arrives can be answered
``Unknown channel ID`` (the server has not yet registered the channel for that client) and then gets
nothing on that topic. The SDK reports it in its log; the bridge then advertises that topic again
(unadvertise, then a new channel id) from the owner's thread (:meth:`FoxgloveBridge.maintain`), so
every client, the one that lost its subscription included, subscribes again as the protocol
requires. The ROS side sees no change (:meth:`FoxgloveBridge.watched` holds for a grace period).
"""

from __future__ import annotations

import logging
import queue
import re
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from dlo_bag.typestore import make_typestore, message_definition
from rosbags.typesys.store import Typestore

DEFAULT_TOPICS = ("/dlo", "/clock")
DEFAULT_PORT = 8765
DEFAULT_ADDRESS = "127.0.0.1"
DEFAULT_CLIENT_BACKLOG = 1024
SDK_LOGGER = "foxglove"
STOP_TIMEOUT = 2.0  # the SDK's stop() waits for clients that stopped reading; never longer than this
SUBPROTOCOL = "foxglove.sdk.v1"  # the WebSocket subprotocol a client must offer (the SDK also takes foxglove.sdk.v1.1)
OLD_SUBPROTOCOL = "foxglove.websocket.v1"  # older Foxglove/Lichtblick releases and scripts: refused (HTTP 400)
READVERTISE_GRACE = 2.0  # s a watched topic stays watched after it was advertised again (its clients subscribe again)
# No channel is closed (to advertise it again) until the SDK has reported no subscription to an unknown channel for
# this long: the SDK logs that report while it holds the client's channel table, and Python logging needs the GIL,
# which a Python thread closing a channel holds while it waits for that table (a deadlock of the whole process).
UNKNOWN_QUIET = 0.25
UNRESOLVED_WAIT = 1.0  # s a reported channel id may take to become known (created on another thread)


def topic_matches(topic: str, patterns: Iterable[str]) -> bool:
    """True when ``topic`` equals a pattern or lies under it (``/dlo`` matches ``/dlo/a/b``, not ``/dlox``)."""
    for pattern in patterns:
        pattern = "/" + pattern.strip("/") if pattern.strip("/") else "/"
        if pattern == "/" or topic == pattern or topic.startswith(pattern + "/"):
            return True
    return False


def foxglove_url(host: str, port: int) -> str:
    """The Foxglove web app URL that opens ``ws://host:port`` (works with the desktop app's
    'Open connection' too: paste the ws:// part)."""
    from urllib.parse import quote

    host = "127.0.0.1" if host in ("", "0.0.0.0") else host
    ws = f"ws://{host}:{port}"
    return f"https://app.foxglove.dev/?ds=foxglove-websocket&ds.url={quote(ws, safe='')}"


@dataclass
class BridgeStats:
    """What the bridge saw: per topic received / forwarded, clients and SDK reports."""

    received: Counter = field(default_factory=Counter)
    forwarded: Counter = field(default_factory=Counter)  # sent while >= 1 client subscribed (+ latched resends)
    lost: Counter = field(default_factory=Counter)  # reported lost by the middleware before delivery
    clients_connected: int = 0  # connections so far
    clients_now: int = 0
    clients_refused: int = 0  # failed WebSocket handshakes (a client that offers only foxglove.websocket.v1)
    subscriptions: int = 0  # subscribe requests so far
    subscriptions_lost: int = 0  # subscribe requests the SDK refused as 'Unknown channel ID' for a channel of ours
    readvertised: int = 0  # channels advertised again for them
    slow_client_reports: list[str] = field(default_factory=list)  # SDK: a client's outbox overflowed

    def to_dict(self) -> dict:
        return {
            "received": sum(self.received.values()),
            "forwarded": sum(self.forwarded.values()),
            "lost": sum(self.lost.values()),
            "clients_connected": self.clients_connected,
            "clients_now": self.clients_now,
            "clients_refused": self.clients_refused,
            "subscriptions": self.subscriptions,
            "subscriptions_lost": self.subscriptions_lost,
            "readvertised": self.readvertised,
            "slow_client_reports": list(self.slow_client_reports),
            "topics": {
                t: {"received": self.received.get(t, 0), "forwarded": self.forwarded.get(t, 0), "lost": self.lost.get(t, 0)}
                for t in sorted(set(self.received) | set(self.forwarded))
            },
        }


_REGISTERED = re.compile(r"^Registered client (\S+)")
_UNREGISTERED = re.compile(r"^Unregistered client (\S+)")
_OUTBOX_FULL = re.compile(r"^outbox for client (\S+) full")
_HANDSHAKE_FAILED = re.compile(r"^Dropping client (\S+): (?:secure )?handshake failed")
_UNKNOWN_CHANNEL = re.compile(r"^Client (\S+) attempted to subscribe to unknown channel: (\d+)")


class _SdkLogHandler(logging.Handler):
    """Turns the SDK's log records (Rust ``tracing`` through Python logging) into counts and lines."""

    def __init__(self, bridge: FoxgloveBridge) -> None:
        super().__init__(logging.DEBUG)
        self.bridge = bridge

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self.bridge._on_sdk_log(record.levelno, record.getMessage())
        except Exception:  # noqa: BLE001 - logging must never raise into the SDK
            pass


class _Listener:
    """foxglove-sdk ServerListener: subscriptions (runs on the SDK's thread: only queue work)."""

    def __init__(self, bridge: FoxgloveBridge) -> None:
        self.bridge = bridge

    def on_subscribe(self, client: Any, channel: Any) -> None:
        self.bridge._on_subscribe(int(client.id), int(channel.id), str(channel.topic))

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        self.bridge._on_unsubscribe(int(client.id), int(channel.id), str(channel.topic))


class FoxgloveBridge:
    """A foxglove-sdk WebSocket server that forwards raw CDR messages of ROS topics.

    ``log`` receives ``(level, text)`` lines for the caller's logger (client connected/left, slow
    client, errors). :meth:`start` binds the server (``port`` 0 = any free port; :attr:`port` is the
    bound one) and raises ``OSError`` when the address cannot be bound.
    """

    def __init__(
        self,
        *,
        port: int = DEFAULT_PORT,
        address: str = DEFAULT_ADDRESS,
        client_backlog: int = DEFAULT_CLIENT_BACKLOG,
        typestore: Typestore | None = None,
        name: str = "dlo-vitac",
        log: Callable[[int, str], None] | None = None,
    ) -> None:
        if not 0 <= port <= 65535:
            raise ValueError(f"port must be in 0..65535, got {port}")
        if client_backlog < 1:
            raise ValueError(f"client_backlog must be >= 1, got {client_backlog}")
        self.requested_port = port
        self.address = address
        self.client_backlog = client_backlog
        self.typestore = typestore if typestore is not None else make_typestore()
        self.name = name
        self.log = log or (lambda level, text: None)
        self.stats = BridgeStats()
        self.channels: dict[str, Any] = {}  # topic -> foxglove Channel
        self.types: dict[str, str] = {}
        self._schemas: dict[str, bytes] = {}  # topic -> ros2msg definition
        self.latched: dict[str, bytes] = {}  # last message of transient-local topics
        self._latched_topics: set[str] = set()
        self._resend: queue.SimpleQueue[str] = queue.SimpleQueue()
        self.subscribers: Counter = Counter()  # topic -> client subscriptions now
        self._changed: queue.SimpleQueue[str] = queue.SimpleQueue()  # topics whose subscribers changed
        self._topic_of_id: dict[int, str] = {}  # every channel id this bridge advertised (also replaced ones)
        self._lost: queue.SimpleQueue[tuple[str, int, float]] = queue.SimpleQueue()  # SDK: (client, channel id, when)
        self._unresolved: list[tuple[str, int, float]] = []  # such reports not matched to a channel yet
        self._pending: dict[str, set[int]] = {}  # lost channels not yet advertised again (owner's thread)
        self._last_unknown = float("-inf")  # monotonic time of the SDK's last 'unknown channel' report
        self._held: dict[str, float] = {}  # topic -> until when it counts as watched (advertised again)
        self._lock = threading.Lock()
        self._server: Any = None
        self._bound_port: int | None = None
        self._context: Any = None
        self._handler: _SdkLogHandler | None = None

    # ---- server ---------------------------------------------------------------------------
    def start(self) -> FoxgloveBridge:
        import foxglove

        self._handler = _SdkLogHandler(self)
        sdk_logger = logging.getLogger(SDK_LOGGER)
        sdk_logger.addHandler(self._handler)
        sdk_logger.setLevel(logging.INFO)
        sdk_logger.propagate = False  # our handler reports; nothing goes to the root logger
        foxglove.set_log_level("INFO")  # first call per process wins (later bridges share it)
        self._context = foxglove.Context()
        try:
            self._server = foxglove.start_server(
                name=self.name,
                host=self.address,
                port=self.requested_port,
                context=self._context,
                server_listener=_Listener(self),
                message_backlog_size=self.client_backlog,
            )
        except RuntimeError as err:  # FoxgloveError: Failed to bind port: ...
            text = str(err).replace("FoxgloveError: ", "")
            raise OSError(f"cannot serve on {self.address}:{self.requested_port}: {text}") from None
        self._bound_port = int(self._server.port)
        return self

    @property
    def port(self) -> int:
        return self._bound_port if self._bound_port is not None else self.requested_port

    @property
    def ws_url(self) -> str:
        host = "127.0.0.1" if self.address in ("", "0.0.0.0") else self.address
        return f"ws://{host}:{self.port}"

    @property
    def app_url(self) -> str:
        return foxglove_url(self.address, self.port)

    def stop(self, timeout: float = STOP_TIMEOUT) -> bool:
        """Stop the server; True when it stopped within ``timeout`` s (the SDK's stop() waits for
        clients that no longer read: it then finishes in the background, the caller goes on)."""
        server, self._server = self._server, None
        stopped = True
        if server is not None:
            worker = threading.Thread(target=server.stop, name="foxglove-stop", daemon=True)
            worker.start()
            worker.join(timeout)
            stopped = not worker.is_alive()
        if stopped:  # (a client the SDK still serves could hold a channel table while it waits for the GIL)
            for channel in self.channels.values():
                try:
                    channel.close()
                except Exception:  # noqa: BLE001 - already gone with the server
                    pass
        if self._handler is not None:
            logging.getLogger(SDK_LOGGER).removeHandler(self._handler)
            self._handler = None
        return stopped

    # ---- topics and messages -------------------------------------------------------------
    def add_topic(self, topic: str, msgtype: str, *, latched: bool = False) -> Any:
        """Advertise ``topic`` (idempotent) with the ros2msg definition of ``msgtype``.

        Raises :class:`dlo_bag.errors.BagError` for a type that is not installed.
        """
        channel = self.channels.get(topic)
        if channel is not None:
            return channel
        msgdef, _rihs01 = message_definition(self.typestore, msgtype)
        with self._lock:
            self.types[topic] = msgtype
            self._schemas[topic] = msgdef.encode()
            if latched:
                self._latched_topics.add(topic)
        return self._advertise(topic)

    def _advertise(self, topic: str) -> Any:
        """A new channel for ``topic`` (the SDK advertises it to every connected client)."""
        from foxglove import Channel, Schema

        channel = Channel(
            topic,
            schema=Schema(name=self.types[topic], encoding="ros2msg", data=self._schemas[topic]),
            message_encoding="cdr",
            context=self._context,
        )
        with self._lock:
            self._topic_of_id[int(channel.id())] = topic
            self.channels[topic] = channel
        return channel

    def forward(self, topic: str, data: bytes, log_time: int | None = None) -> bool:
        """Send one raw CDR message of ``topic`` to every client subscribed to it (never blocks).

        Returns True when at least one client was subscribed.
        """
        self.stats.received[topic] += 1
        if topic in self._latched_topics:
            self.latched[topic] = bytes(data)
        channel = self.channels.get(topic)
        if channel is None or not channel.has_sinks():
            return False
        channel.log(bytes(data), log_time=log_time if log_time is not None else time.time_ns())
        self.stats.forwarded[topic] += 1
        return True

    def maintain(self) -> None:
        """The bridge's periodic work on the owner's thread (the thread that calls :meth:`forward`; the node:
        every 50 ms): advertise again the channels a client lost (:meth:`readvertise`), then send the latched
        messages new subscribers wait for (:meth:`resend_latched`)."""
        self.readvertise()
        self.resend_latched()

    def readvertise(self) -> int:
        """Advertise again (unadvertise, then a new channel id) each channel whose subscription a client lost
        because it subscribed before the SDK had registered the channel for it (the SDK answered 'Unknown
        channel ID'). Every client subscribes again (as the protocol requires after unadvertise/advertise);
        a watched topic stays :meth:`watched` meanwhile. Waits while the SDK still reports such subscriptions
        (see ``UNKNOWN_QUIET``): they are then done on a later call. Returns how many channels were
        advertised again."""
        while True:
            try:
                self._unresolved.append(self._lost.get_nowait())
            except queue.Empty:
                break
        unresolved, self._unresolved = self._unresolved, []
        for client, channel_id, when in unresolved:
            topic = self._topic_of_id.get(channel_id)
            channel = self.channels.get(topic) if topic is not None else None
            if channel is not None and int(channel.id()) == channel_id:
                if channel_id not in self._pending.get(topic, ()):
                    self.log(
                        logging.INFO,
                        f"{topic}: client {client} subscribed before the server had registered "
                        f"channel {channel_id} for it (foxglove-sdk): advertised again",
                    )
                self.stats.subscriptions_lost += 1
                self._pending.setdefault(topic, set()).add(channel_id)
            elif topic is not None:  # a channel advertised again meanwhile: the client has the new one too
                self.log(logging.DEBUG, f"{topic}: client {client} subscribed to the replaced channel {channel_id}")
            elif time.monotonic() - when < UNRESOLVED_WAIT:  # maybe a channel still being created on another thread
                self._unresolved.append((client, channel_id, when))
            else:
                self.log(
                    logging.WARNING,
                    f"client {client} subscribed to channel {channel_id}, which this bridge "
                    "never advertised (refused; the client is served as before)",
                )
        if not self._pending:
            return 0
        time.sleep(0.005)  # (lets an SDK thread that waits for the GIL to report such a subscription do so)
        if time.monotonic() - self._last_unknown < UNKNOWN_QUIET or self._server is None:
            return 0
        pending, self._pending = self._pending, {}
        lost = [
            topic for topic, ids in pending.items() if topic in self.channels and int(self.channels[topic].id()) in ids
        ]  # not already replaced
        for topic in lost:
            if self.subscribers.get(topic, 0) > 0 or topic in self._held:
                self._held[topic] = time.monotonic() + READVERTISE_GRACE
            self.channels[topic].close()  # unadvertised: the SDK drops the clients' subscriptions of it
        for topic in lost:
            self._advertise(topic)
            self.stats.readvertised += 1
        return len(lost)

    def resend_latched(self) -> int:
        """Send the last message of latched topics that a client subscribed to since the last call
        (call regularly from the owner's thread). Returns how many were sent."""
        sent = 0
        topics: set[str] = set()
        while True:
            try:
                topics.add(self._resend.get_nowait())
            except queue.Empty:
                break
        for topic in topics:
            data = self.latched.get(topic)
            channel = self.channels.get(topic)
            if data is not None and channel is not None:
                channel.log(data, log_time=time.time_ns())
                self.stats.forwarded[topic] += 1
                sent += 1
        return sent

    # ---- SDK callbacks (SDK threads) ------------------------------------------------------
    def _on_subscribe(self, client_id: int, channel_id: int, topic: str) -> None:
        self.stats.subscriptions += 1
        with self._lock:
            self.subscribers[topic] += 1
        self._changed.put(topic)
        if topic in self._latched_topics:
            self._resend.put(topic)

    def _on_unsubscribe(self, client_id: int, channel_id: int, topic: str) -> None:
        with self._lock:
            self.subscribers[topic] = max(0, self.subscribers[topic] - 1)
        self._changed.put(topic)

    def watched(self, topic: str) -> bool:
        """True while at least one client subscribes to ``topic`` (and for ``READVERTISE_GRACE`` s after a
        watched topic was advertised again, while its clients subscribe again)."""
        return self.subscribers.get(topic, 0) > 0 or self._held.get(topic, float("-inf")) > time.monotonic()

    def changed_topics(self) -> set[str]:
        """Topics whose client subscriptions changed since the last call (for the owner's thread), and those
        whose grace period after being advertised again is over."""
        topics: set[str] = set()
        now = time.monotonic()
        for topic, until in list(self._held.items()):
            if until <= now:
                del self._held[topic]
                topics.add(topic)
        while True:
            try:
                topics.add(self._changed.get_nowait())
            except queue.Empty:
                return topics

    def _on_sdk_log(self, level: int, text: str) -> None:
        if m := _REGISTERED.match(text):
            self.stats.clients_connected += 1
            self.stats.clients_now += 1
            self.log(logging.INFO, f"client {m.group(1)} connected ({self.stats.clients_now} now)")
        elif m := _UNREGISTERED.match(text):
            self.stats.clients_now = max(0, self.stats.clients_now - 1)
            self.log(logging.INFO, f"client {m.group(1)} left ({self.stats.clients_now} now)")
        elif m := _OUTBOX_FULL.match(text):
            self.stats.slow_client_reports.append(m.group(1))
            self.log(
                logging.WARNING,
                f"client {m.group(1)} reads slower than the graph publishes: its queue of "
                f"{self.client_backlog} messages is full and its oldest messages are dropped "
                "(the graph is not slowed; the SDK reports this once)",
            )
        elif m := _HANDSHAKE_FAILED.match(text):
            self.stats.clients_refused += 1
            self.log(
                logging.WARNING,
                f"client {m.group(1)} refused: its WebSocket handshake failed (a client must offer the "
                f"subprotocol {SUBPROTOCOL}; one that offers only {OLD_SUBPROTOCOL}, as older Foxglove and "
                "Lichtblick releases do, gets HTTP 400; dlo_viz README); the other clients are served as before",
            )
        elif m := _UNKNOWN_CHANNEL.match(text):
            # (the SDK reports it while it still creates the channel: which topic it is, readvertise() finds out)
            self._last_unknown = time.monotonic()
            self._lost.put((m.group(1), int(m.group(2)), self._last_unknown))
        elif level >= logging.WARNING:
            self.log(level, f"foxglove-sdk: {text}")
