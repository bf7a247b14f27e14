"""Many Foxglove clients against one bridge: the scenarios of test_foxglove_bridge.py's stress tests, also
runnable by hand against a running bridge.

- :func:`step_locked_sessions` (library, no ROS): sessions of a fresh :class:`FoxgloveBridge` each, with
  eager clients connected before the topics appear; the topics are added one at a time, each once
  every client has seen the last advertisement (step-locked), while a "graph" thread forwards a
  message per topic and calls ``maintain()`` as the node does. Every client must receive every topic.
- :func:`client_session` (any bridge at a URL, e.g. the node): ``clients`` Foxglove clients, some
  offering only the old subprotocol (each must get HTTP 400), the others eager: some connected from
  the start, some joining while topics still appear, some dropping mid-stream without a closing
  handshake. Every client that stayed must receive every expected topic.
- ``publish`` (a process on a ROS domain): publishes one default message of each given graph topic at
  a rate, the topics appearing one after the other (so that the bridge advertises them to connected
  clients).

By hand, with a bridge and a publisher running on the same ROS domain::

    python ros_ws/src/dlo_viz/test/foxglove_stress.py publish --topics /dlo/gripper/state /clock &
    python ros_ws/src/dlo_viz/test/foxglove_stress.py clients --url ws://127.0.0.1:8765 \\
        --clients 50 --topics /dlo/gripper/state /clock            # exit 0: every client got every topic
"""

from __future__ import annotations

import argparse
import random
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from foxglove_ws_client import OLD_SUBPROTOCOLS, FoxgloveTestClient  # noqa: E402


def wait_until(condition, timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > end:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.01)


@dataclass
class SessionReport:
    """What a session saw; ``missing``: client name -> the expected topics it never received."""

    refused: list[int] = field(default_factory=list)  # HTTP status each old-subprotocol client got
    refused_bodies: list[str] = field(default_factory=list)
    missing: dict[str, list[str]] = field(default_factory=dict)
    failed: dict[str, str] = field(default_factory=dict)  # client name -> its reader thread's error
    errors: list[str] = field(default_factory=list)  # error statuses the staying clients got
    stayed: int = 0
    dropped: int = 0

    @property
    def ok(self) -> bool:
        return not self.missing and not self.failed and all(status == 400 for status in self.refused)

    def describe(self) -> str:
        return (
            f"{self.stayed} clients stayed, {self.dropped} dropped mid-stream, {len(self.refused)} refused "
            f"(HTTP {sorted(set(self.refused))}); missing topics: {self.missing or 'none'}; failed: "
            f"{self.failed or 'none'}; error statuses: {len(self.errors)} ({sorted(set(self.errors))[:5]})"
        )


def refused_status(url: str, timeout: float = 10.0) -> tuple[int, str]:
    """Connect offering only the old subprotocol; the HTTP status and body of the refusal (101: accepted)."""
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    try:
        ws = connect(url, subprotocols=list(OLD_SUBPROTOCOLS), open_timeout=timeout)
    except InvalidStatus as err:
        return err.response.status_code, bytes(err.response.body or b"").decode(errors="replace")
    ws.close()
    return 101, ""


def step_locked_sessions(
    typestore,
    topics: dict[str, str],
    payloads: dict[str, bytes],
    *,
    sessions: int,
    clients: int,
    timeout: float = 30.0,
    maintain: bool = True,
) -> list[SessionReport]:
    """``sessions`` fresh bridges, each with ``clients`` eager clients connected before any topic exists;
    ``topics`` (name -> type) added one at a time, each once every client has its advertisement; a graph
    thread forwards ``payloads`` (one per topic) every 20 ms and calls ``maintain()`` (only
    ``resend_latched()`` when ``maintain`` is False, as the node did before). A report per session: which
    client missed which topic within ``timeout``."""
    return [_step_locked_session(typestore, topics, payloads, clients, timeout, maintain) for _ in range(sessions)]


def _step_locked_session(
    typestore, topics: dict[str, str], payloads: dict[str, bytes], clients: int, timeout: float, maintain: bool
) -> SessionReport:
    from dlo_viz.foxglove_bridge import FoxgloveBridge

    bridge = FoxgloveBridge(port=0, typestore=typestore).start()
    stop = threading.Event()

    def graph() -> None:
        while not stop.wait(0.02):
            for topic in list(bridge.channels):
                bridge.forward(topic, payloads[topic])
            if maintain:
                bridge.maintain()
            else:
                bridge.resend_latched()

    conns = [FoxgloveTestClient(bridge.ws_url, eager=True) for _ in range(clients)]
    thread = threading.Thread(target=graph, name="graph", daemon=True)
    try:
        for c in conns:
            c.connect()
        thread.start()
        for topic, msgtype in topics.items():
            bridge.add_topic(topic, msgtype)
            wait_until(
                lambda t=topic: all(c.channel_by_topic(t) is not None for c in conns),
                timeout,
                f"the advertisement of {topic} at every client",
            )
        return _report(conns, set(topics), timeout)
    finally:
        stop.set()
        thread.join(5)
        for c in conns:
            c.close()
        bridge.stop()


def _report(staying: list[FoxgloveTestClient], topics: set[str], timeout: float) -> SessionReport:
    """Wait up to ``timeout`` for every client to have received every topic; what each missed."""
    end = time.monotonic() + timeout
    while time.monotonic() < end and not all(topics <= c.topics_received() for c in staying):
        time.sleep(0.05)
    report = SessionReport(stayed=len(staying))
    for i, c in enumerate(staying):
        missing = sorted(topics - c.topics_received())
        if missing:
            report.missing[f"client {i}"] = missing
        if c.error is not None:
            report.failed[f"client {i}"] = repr(c.error)
        report.errors += c.errors()
    return report


def client_session(
    url: str,
    topics: list[str],
    *,
    clients: int = 50,
    old_share: float = 0.2,
    drop_share: float = 0.2,
    late_share: float = 0.2,
    timeout: float = 60.0,
    seed: int = 0,
    started=None,
) -> SessionReport:
    """``clients`` Foxglove clients against the bridge at ``url`` while the ``topics`` appear: ``old_share``
    offer only ``foxglove.websocket.v1`` (each must be refused with HTTP 400, at times spread over the
    session), ``drop_share`` are eager and leave without a closing handshake once they received a few
    messages, ``late_share`` connect while the topics still appear, the rest connect first. Every eager
    client that stays must receive every one of ``topics`` within ``timeout``. ``started`` (if given) is
    called once the first clients are connected (e.g. to start the publisher then)."""
    rng = random.Random(seed)
    n_old = round(clients * old_share)
    n_drop = round(clients * drop_share)
    n_late = round(clients * late_share)
    n_first = clients - n_old - n_drop - n_late
    report = SessionReport()
    report_lock = threading.Lock()
    first = [FoxgloveTestClient(url, eager=True).connect() for _ in range(n_first)]
    droppers = [FoxgloveTestClient(url, eager=True).connect() for _ in range(n_drop)]
    if started is not None:
        started()
    late: list[FoxgloveTestClient] = []
    threads = []

    def old_client(delay: float) -> None:
        time.sleep(delay)
        status, body = refused_status(url)
        with report_lock:
            report.refused.append(status)
            report.refused_bodies.append(body)

    def dropper(c: FoxgloveTestClient, after: int) -> None:
        end = time.monotonic() + timeout
        while len(c.messages) < after and time.monotonic() < end:
            time.sleep(0.01)
        c.drop()

    def late_client(delay: float) -> None:
        time.sleep(delay)
        c = FoxgloveTestClient(url, eager=True).connect()
        with report_lock:
            late.append(c)

    for _ in range(n_old):
        threads.append(threading.Thread(target=old_client, args=(rng.uniform(0, 3),), daemon=True))
    for c in droppers:
        threads.append(threading.Thread(target=dropper, args=(c, rng.randint(1, 20)), daemon=True))
    for _ in range(n_late):
        threads.append(threading.Thread(target=late_client, args=(rng.uniform(0.2, 3),), daemon=True))
    for t in threads:
        t.start()
    try:
        for t in threads:
            t.join(timeout)
        result = _report(first + late, set(topics), timeout)
        report.stayed, report.dropped = result.stayed, len(droppers)
        report.missing, report.failed, report.errors = result.missing, result.failed, result.errors
        if len(late) < n_late:
            report.failed["late clients"] = f"{len(late)} of {n_late} connected"
        return report
    finally:
        for c in first + late + droppers:
            c.close()


def publish(topics: list[str], rate: float, appear_every: float) -> int:
    """Publish a default message of each of ``topics`` (types from the graph's topic registry) at ``rate``
    Hz, the topics appearing ``appear_every`` s apart, until SIGINT/SIGTERM."""
    import signal

    import rclpy
    from dlo_bag.playback import import_message_class
    from dlo_common.topics import TOPICS
    from rclpy.qos import DurabilityPolicy, QoSProfile

    types = {t.name: t.type for t in TOPICS}
    rclpy.init()
    node = rclpy.create_node("foxglove_stress_publisher")
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    pubs = []
    start = time.monotonic()
    try:
        while not stop.wait(1.0 / rate):
            if len(pubs) < len(topics) and time.monotonic() - start >= len(pubs) * appear_every:
                topic = topics[len(pubs)]
                cls = import_message_class(types[topic])
                latched = topic.endswith("camera_info")
                qos = QoSProfile(depth=10, durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)
                pubs.append((node.create_publisher(cls, topic, qos), cls()))
                print(f"[publish] {topic}", flush=True)
            for pub, msg in pubs:
                pub.publish(msg)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("clients", help="a session of Foxglove clients against a running bridge")
    p.add_argument("--url", default="ws://127.0.0.1:8765")
    p.add_argument("--clients", type=int, default=50)
    p.add_argument("--topics", nargs="+", required=True)
    p.add_argument("--timeout", type=float, default=60.0)
    p.add_argument("--seed", type=int, default=0)
    p = sub.add_parser("publish", help="publish graph topics, appearing one after the other")
    p.add_argument("--topics", nargs="+", required=True)
    p.add_argument("--rate", type=float, default=20.0)
    p.add_argument("--appear-every", type=float, default=0.3)
    args = parser.parse_args(argv)
    if args.command == "publish":
        return publish(args.topics, args.rate, args.appear_every)
    report = client_session(args.url, args.topics, clients=args.clients, timeout=args.timeout, seed=args.seed)
    print(f"[clients] {report.describe()}", flush=True)
    return 0 if report.ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
