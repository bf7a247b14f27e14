"""Test helper processes for the dlo_bag tests (run as ``python dlo_bag_graph_helper.py pub|sub ...``).

pub: publishes ``--count`` messages on each of the /dlo test topics (every dlo_msgs type +
     PointCloud2 + Image), sequence number i in header.frame_id and header.stamp.nanosec.
     Prints ``HASHES {json}`` (rclpy's type hashes of its own publishers) and
     ``PUBLISHED {json counts}``; then exits (--then exit), idles until signalled (hold), or
     keeps publishing ``--stream-topic`` (default GripperState) until signalled (stream).
     ``--latched``: first publish one CameraInfo on /dlo/camera/camera_info (transient local,
     depth 1) and print ``LATCHED``, before waiting for subscribers.
sub: subscribes raw to the given topics and, when every topic reached ``--expect`` messages
     (or on SIGINT/timeout), prints ``RECEIVED {json: topic -> [raw CDR hex of each message]}``.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import time

import rclpy
from dlo_common.node_main import shut_down
from dlo_common.topics import topic as topic_record
from dlo_msgs.msg import GripperCommand, GripperState, TactilePose, TaskState, VisualPose
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import CameraInfo, Image, PointCloud2, PointField

TOPICS = {
    "/dlo/gripper/state": GripperState,
    "/dlo/gripper/cmd": GripperCommand,
    "/dlo/tactile/pose": TactilePose,
    "/dlo/vision/pose": VisualPose,
    "/dlo/task/state": TaskState,
    "/dlo/rope/particles": PointCloud2,
    "/dlo/camera/image": Image,
}
TYPE_NAMES = {name: topic_record(name).type for name in TOPICS}  # as the graph's topic registry names them
QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE
)
LATCHED_TOPIC = "/dlo/camera/camera_info"
LATCHED_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)


def latched_message() -> CameraInfo:
    info = CameraInfo(width=128, height=96, distortion_model="plumb_bob")
    info.header.frame_id = "top_camera_optical"
    info.k = [100.0, 0.0, 64.0, 0.0, 100.0, 48.0, 0.0, 0.0, 1.0]
    return info


def make_message(topic: str, i: int, episode_every: int = 0):
    """Deterministic message number ``i`` for ``topic``."""
    msg = TOPICS[topic]()
    msg.header.stamp.sec = 1
    msg.header.stamp.nanosec = i
    msg.header.frame_id = str(i)
    if topic == "/dlo/gripper/state":
        msg.x, msg.y, msg.z, msg.closure, msg.step = 0.001 * i, -0.002 * i, 0.01, 0.5, i
    elif topic == "/dlo/gripper/cmd":
        msg.vx, msg.vy, msg.closure, msg.step = 0.1, -0.05, 1.0, i
    elif topic == "/dlo/tactile/pose":
        msg.angle, msg.y, msg.contact, msg.contact_count = 0.1, 0.002, True, 3
    elif topic == "/dlo/vision/pose":
        msg.visible, msg.confidence, msg.angle, msg.y = True, 0.8, -0.2, 0.004
    elif topic == "/dlo/task/state":
        msg.episode = i // episode_every if episode_every else 0
        msg.step, msg.seed = (i % episode_every if episode_every else i), 42  # each episode from step 0
        msg.held_indices = [3, 4, 5]
        msg.n_held, msg.mean_held_index = 3, 4.0
        msg.num_particles, msg.cable_length = 40, 0.4
        msg.reward, msg.done, msg.outcome = 0.5, False, 0
    elif topic == "/dlo/rope/particles":
        msg.height, msg.width = 1, 40
        msg.fields = [PointField(name=n, offset=4 * k, datatype=PointField.FLOAT32, count=1) for k, n in enumerate("xyz")]
        msg.point_step, msg.row_step, msg.is_dense = 12, 12 * 40, True
        msg.data = bytes((i + k) % 256 for k in range(12 * 40))
    elif topic == "/dlo/camera/image":
        msg.height, msg.width, msg.encoding, msg.step = 24, 32, "rgb8", 96
        msg.data = bytes((i * 7 + k) % 256 for k in range(24 * 96))
    return msg


def run_pub(args, stop) -> int:
    node = Node("test_pub")
    topics = args.topics or list(TOPICS)
    pubs = {t: node.create_publisher(TOPICS[t], t, QOS) for t in topics}
    if args.latched:
        latched = node.create_publisher(CameraInfo, LATCHED_TOPIC, LATCHED_QOS)
        latched.publish(latched_message())
        print("LATCHED", flush=True)
    end = time.monotonic() + args.timeout
    while args.wait_subs and time.monotonic() < end and not stop[0]:
        if all(p.get_subscription_count() >= args.wait_subs for p in pubs.values()):
            break
        rclpy.spin_once(node, timeout_sec=0.05)
    else:
        if args.wait_subs:
            print("TIMEOUT waiting for subscribers", flush=True)
            return 3
    hashes = {}
    for t in topics:
        infos = node.get_publishers_info_by_topic(t)
        mine = [i for i in infos if i.node_name == "test_pub"]
        hashes[t] = str(mine[0].topic_type_hash) if mine else ""
    print("HASHES " + json.dumps(hashes), flush=True)
    counts = dict.fromkeys(topics, 0)
    for i in range(args.start, args.start + args.count):
        for t in topics:
            pubs[t].publish(make_message(t, i, args.episode_every))
            counts[t] += 1
        time.sleep(0.001)
    for p in pubs.values():
        p.wait_for_all_acked(rclpy.duration.Duration(seconds=10))
    print("PUBLISHED " + json.dumps(counts), flush=True)
    if args.then == "hold":
        while not stop[0]:
            rclpy.spin_once(node, timeout_sec=0.05)
    elif args.then == "stream":
        i = args.start + args.count
        t = args.stream_topic
        if t not in pubs:
            pubs[t] = node.create_publisher(TOPICS[t], t, QOS)
        while not stop[0]:
            pubs[t].publish(make_message(t, i))
            i += 1
            time.sleep(0.005)
        print(f"STREAMED {i}", flush=True)
    shut_down(node)  # (Fast DDS can deadlock here: cut after node_main.TEARDOWN_LIMIT s)
    return 0


def run_sub(args, stop) -> int:
    node = Node("test_sub")
    received: dict[str, list[str]] = {t: [] for t in args.topics}  # raw CDR, hex

    def cb(topic, data):
        received[topic].append(data.hex())

    subs = [node.create_subscription(TOPICS[t], t, lambda d, t=t: cb(t, d), QOS, raw=True) for t in args.topics]
    print("SUBSCRIBED", flush=True)
    end = time.monotonic() + args.timeout
    while not stop[0] and time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
        if args.expect and all(len(v) >= args.expect for v in received.values()):
            break
    print("RECEIVED " + json.dumps(received), flush=True)
    del subs
    shut_down(node)  # (Fast DDS can deadlock here: cut after node_main.TEARDOWN_LIMIT s)
    return 0


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("mode", choices=["pub", "sub"])
    ap.add_argument("--topics", nargs="*", default=[])
    ap.add_argument("--count", type=int, default=10)
    ap.add_argument("--start", type=int, default=0)
    ap.add_argument("--episode-every", type=int, default=0)
    ap.add_argument("--wait-subs", type=int, default=1)
    ap.add_argument("--then", choices=["exit", "hold", "stream"], default="exit")
    ap.add_argument("--stream-topic", default="/dlo/gripper/state", choices=sorted(TOPICS))
    ap.add_argument("--latched", action="store_true")
    ap.add_argument("--expect", type=int, default=0)
    ap.add_argument("--timeout", type=float, default=30.0)
    args = ap.parse_args()
    stop = [False]

    def handler(*_):
        stop[0] = True

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    try:
        return run_pub(args, stop) if args.mode == "pub" else run_sub(args, stop)
    finally:
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
