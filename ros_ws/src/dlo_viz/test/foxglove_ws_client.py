"""A minimal Foxglove WebSocket client, written from the protocol specification (not the SDK's).

Protocol (https://github.com/foxglove/ws-protocol, docs/spec.md; foxglove-sdk servers speak it
under the subprotocol ``foxglove.sdk.v1``): the server sends JSON text messages with an ``op``
field (``serverInfo`` first, then ``advertise`` / ``unadvertise`` with channels ``{id, topic,
encoding, schemaName, schema, schemaEncoding}``); the client sends ``{"op": "subscribe",
"subscriptions": [{"id", "channelId"}]}`` and receives binary Message Data frames:
``0x01 | uint32 subscription id | uint64 receive timestamp [ns] | payload`` (little endian).

Payloads are decoded with a typestore built only from the advertised ``ros2msg`` schema text
(rosbags ``get_types_from_msg`` on an empty store), so a decoded message proves that the
advertised schema describes the bytes.

``eager=True`` makes a client that subscribes to each channel the moment its advertisement arrives
(from the reader thread, as scripts and step-locked tools do); after an ``unadvertise`` its
subscriptions of those channels are gone (the server drops them), so an eager client subscribes
again when the topic is advertised again. ``subprotocols`` chooses what the handshake offers
(``("foxglove.websocket.v1",)``: an older client); :meth:`FoxgloveTestClient.drop` leaves without
a closing handshake, as a crashed or disconnected client does.
"""

from __future__ import annotations

import json
import struct
import threading
import time
from dataclasses import dataclass, field
from typing import Any

SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")  # what current Foxglove releases offer
OLD_SUBPROTOCOLS = ("foxglove.websocket.v1",)  # older Foxglove and Lichtblick releases, older scripts
# The tests' waits are liveness bounds: a wait fails after its timeout times this. A passing wait returns as soon as its
# condition holds, so a larger value costs nothing there; it keeps a machine whose cores are busy with training (a CI
# run beside it) from failing a test that only waited its turn.
PATIENCE = 6
OP_MESSAGE_DATA = 0x01
OP_TIME = 0x02


@dataclass
class Received:
    topic: str
    channel_id: int
    log_time: int  # the server's timestamp [ns]
    recv_time: int  # time.time_ns() when this client read the frame
    payload: bytes


@dataclass
class FoxgloveTestClient:
    """Connects, records advertisements, subscribes, collects Message Data frames (in a thread)."""

    url: str
    eager: bool = False  # subscribe to every channel as soon as it is advertised
    subprotocols: tuple[str, ...] = SUBPROTOCOLS
    channels: dict[int, dict] = field(default_factory=dict)  # channel id -> advertised channel
    removed: list[int] = field(default_factory=list)
    server_info: dict | None = None
    messages: list[Received] = field(default_factory=list)
    statuses: list[dict] = field(default_factory=list)
    ops: list[str] = field(default_factory=list)  # every JSON op in arrival order
    _subs: dict[int, int] = field(default_factory=dict)  # subscription id -> channel id
    _next_sub: int = 1
    _ws: Any = None
    _thread: threading.Thread | None = None
    _lock: threading.Lock = field(default_factory=threading.Lock)
    _stores: dict[int, Any] = field(default_factory=dict)
    error: BaseException | None = None

    def connect(self, timeout: float = 10.0) -> FoxgloveTestClient:
        from websockets.sync.client import connect

        assert self.url.startswith("ws://127.0.0.1:"), "tests connect to 127.0.0.1 only"
        self._ws = connect(self.url, subprotocols=list(self.subprotocols), max_size=None, open_timeout=timeout)
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        self.wait(lambda: self.server_info is not None, timeout, "serverInfo")
        return self

    @property
    def subprotocol(self) -> str | None:
        return self._ws.subprotocol if self._ws is not None else None

    def _run(self) -> None:
        try:
            for frame in self._ws:
                now = time.time_ns()
                if isinstance(frame, str):
                    self._on_json(json.loads(frame))
                elif frame and frame[0] == OP_MESSAGE_DATA:
                    sub_id, log_time = struct.unpack_from("<IQ", frame, 1)
                    with self._lock:
                        channel_id = self._subs.get(sub_id)
                        topic = self.channels.get(channel_id, {}).get("topic", "?")
                        self.messages.append(Received(topic, channel_id, log_time, now, bytes(frame[13:])))
        except Exception as err:  # noqa: BLE001 - connection closed by the server or by close()
            from websockets.exceptions import ConnectionClosedOK

            if not isinstance(err, ConnectionClosedOK):
                self.error = err

    def _on_json(self, msg: dict) -> None:
        op = msg.get("op")
        with self._lock:
            self.ops.append(op)
            if op == "serverInfo":
                self.server_info = msg
            elif op == "advertise":
                for ch in msg["channels"]:
                    self.channels[int(ch["id"])] = ch
            elif op == "unadvertise":
                for cid in msg["channelIds"]:
                    self.channels.pop(int(cid), None)
                    self.removed.append(int(cid))
                    for sub_id in [s for s, c in self._subs.items() if c == int(cid)]:
                        del self._subs[sub_id]  # the server dropped it with the channel
            elif op == "status":
                self.statuses.append(msg)
        if op == "advertise" and self.eager:
            self.subscribe_ids([int(ch["id"]) for ch in msg["channels"]])

    def subscribe_ids(self, channel_ids: list[int]) -> None:
        """Subscribe to these advertised channels (those not subscribed yet), in one request."""
        with self._lock:
            subs = []
            for cid in channel_ids:
                if cid in self.channels and cid not in self._subs.values():
                    sub_id, self._next_sub = self._next_sub, self._next_sub + 1
                    self._subs[sub_id] = cid
                    subs.append({"id": sub_id, "channelId": cid})
        if subs:
            self._ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def wait(self, condition, timeout: float, what: str = "condition") -> None:
        """Poll until ``condition()`` holds; fail after ``timeout`` s times PATIENCE."""
        timeout *= PATIENCE
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if condition():
                return
            if self.error is not None:
                raise AssertionError(f"client failed while waiting for {what}: {self.error!r}")
            time.sleep(0.02)
        raise AssertionError(
            f"timed out after {timeout} s waiting for {what}; received "
            f"{len(self.messages)} messages on {sorted(self.topics_received())}; advertised: "
            f"{sorted(c['topic'] for c in self.channels.values())}"
        )

    def channel_by_topic(self, topic: str) -> dict | None:
        with self._lock:
            return next((c for c in self.channels.values() if c["topic"] == topic), None)

    def subscribe(self, topics: list[str] | None = None) -> list[str]:
        """Subscribe to the advertised channels of ``topics`` (None = all not yet subscribed)."""
        with self._lock:
            chosen = [
                c
                for c in self.channels.values()
                if (topics is None or c["topic"] in topics) and int(c["id"]) not in self._subs.values()
            ]
            subs = []
            for c in chosen:
                sub_id, self._next_sub = self._next_sub, self._next_sub + 1
                self._subs[sub_id] = int(c["id"])
                subs.append({"id": sub_id, "channelId": int(c["id"])})
        if subs:
            self._ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
        return [c["topic"] for c in chosen]

    def unsubscribe_all(self) -> None:
        with self._lock:
            ids, self._subs = list(self._subs), {}
        if ids:
            self._ws.send(json.dumps({"op": "unsubscribe", "subscriptionIds": ids}))

    def topics_received(self) -> set[str]:
        with self._lock:
            return {m.topic for m in self.messages}

    def decode(self, item: Received) -> Any:
        """The message, decoded with a typestore made from the channel's advertised schema only."""
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        channel = self.channels[item.channel_id]
        assert channel["encoding"] == "cdr", channel
        assert channel["schemaEncoding"] == "ros2msg", channel
        store = self._stores.get(item.channel_id)
        if store is None:
            store = get_typestore(Stores.EMPTY)
            store.register(get_types_from_msg(channel["schema"], channel["schemaName"]))
            self._stores[item.channel_id] = store
        return store.deserialize_cdr(item.payload, channel["schemaName"])

    def subscribed_topics(self) -> set[str]:
        """The topics of the advertised channels this client subscribes to now."""
        with self._lock:
            return {self.channels[c]["topic"] for c in self._subs.values() if c in self.channels}

    def errors(self) -> list[str]:
        """The messages of the error statuses (level 2) the server sent."""
        with self._lock:
            return [s.get("message", "") for s in self.statuses if s.get("level") == 2]

    def drop(self) -> None:
        """Leave without a closing handshake (a crashed client, a cable pulled): the socket just closes."""
        import socket

        if self._ws is not None:
            try:
                self._ws.socket.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            self._ws.socket.close()
        if self._thread is not None:
            self._thread.join(5)

    def close(self) -> None:
        if self._ws is not None:
            try:
                self._ws.close()
            except Exception:  # noqa: BLE001
                pass
        if self._thread is not None:
            self._thread.join(5)
