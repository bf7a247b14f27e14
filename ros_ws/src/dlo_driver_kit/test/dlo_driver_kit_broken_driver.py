"""Test-only drivers that break one rule of the driver contract each (for test_driver_check.py).

    python dlo_driver_kit_broken_driver.py FAULT [--ros-args ...]

FAULT is one of FAULTS: the reference mock driver (dlo_driver_kit.mock_driver_node) with one defect; or one of
LATE_FAULTS: the mock driver, late.
"""

from __future__ import annotations

import sys

import numpy as np
from dlo_driver_kit import mock_driver_node
from dlo_driver_kit.mock_driver_node import MockDriver

# fault -> the dlo-driver-check rule it must fail (and no other)
FAULTS = {
    "ignores_stale": "stale",  # keeps executing the last command forever
    "accepts_invalid": "invalid",  # executes NaN and out-of-range commands unchecked
    "leaves_workspace": "workspace",  # no workspace limits
    "stamps_back": "stamps",  # every 5th state's stamp goes 1 s back
    "no_camera_info": "camera",  # never publishes camera_info
    "no_touch": "touch",  # no particle cloud, no tactile pose
    "wrong_rate": "rate",  # 20 Hz instead of 12.5 Hz
    "disobeys": "obey",  # moves at half the commanded speed
    "state_own_clock": "sync",  # the state stamped with its own clock reading, image and cloud with the step's time
    "frozen_stamps": "stamps",  # every message of every step carries the first step's stamp
    "color_image": "camera",  # rgb8 images (the same segmentation in three channels)
    "cloud_float64": "touch",  # particle clouds with FLOAT64 fields (32 bytes a point)
    "cloud_one_step_late": "sync",  # each particle cloud stamped with the previous step's stamp
    "image_float_stamp": "sync",  # the image stamp passed through float seconds (off by up to ~0.2 us)
    "state_offset": "sync",  # the state stamped 1 ms after its image and cloud ("latency compensation")
    "stamps_per_episode": "stamps",  # every message stamped with the time since its episode began
}
# fault -> its command-to-state latency [control steps]: drivers that keep every rule of the contract but are late,
# which dlo-driver-check reports against the shipped policy's tolerance
LATE_FAULTS = {
    "one_step_late": 1,  # each tick executes the command that was the latest one tick before
}


# fault -> (the publisher it alters, the alteration made for the node): each message changed just before publishing
ALTERED_PUBLISHERS = {
    # state_own_clock: a few microseconds after the stamp its image and cloud carry
    "state_own_clock": ("pub_state", lambda node: restamp(lambda: node.get_clock().now().to_msg())),
    "cloud_one_step_late": ("pub_cloud", lambda node: one_step_late()),
    "image_float_stamp": ("pub_image", lambda node: through_float),
    "state_offset": ("pub_state", lambda node: shifted(1_000_000)),
    "color_image": ("pub_image", lambda node: to_rgb8),
    "cloud_float64": ("pub_cloud", lambda node: to_float64),
}


def break_publishers(node, fault: str) -> None:
    """The faults in what the driver publishes: a missing publisher or messages altered on their way out."""
    if fault == "no_camera_info":  # the latched message goes with its publisher
        node.destroy_publisher(node.pub_info)
    if fault == "no_touch":
        node.destroy_publisher(node.pub_cloud)
        node.pub_cloud = _Null()
    if fault in ALTERED_PUBLISHERS:
        name, alteration = ALTERED_PUBLISHERS[fault]
        setattr(node, name, _Altered(getattr(node, name), alteration(node)))


def broken_stamp(node, fault: str, stamp):
    """The faults in the state's stamp: ``stamp`` (the mock driver's) as the broken driver stamps it."""
    if fault == "frozen_stamps":
        if node.first_stamp is None:
            node.first_stamp = stamp
        return node.first_stamp
    if fault == "stamps_per_episode":  # 1 s + the time since the episode began: restarts at a reset
        now = stamp.sec * 1_000_000_000 + stamp.nanosec
        if node.episode != node.stamp_episode:
            node.stamp_episode, node.episode_start = node.episode, now
        return ns_stamp(1_000_000_000 + now - node.episode_start)
    if fault == "stamps_back":
        node.states_published += 1
        if node.states_published % 5 == 0:
            stamp.sec -= 1
    return stamp


def broken_driver(fault: str):
    class BrokenDriver(MockDriver):
        first_stamp = None  # frozen_stamps: the stamp of the first state
        stamp_episode, episode_start = -1, 0  # stamps_per_episode: the episode and its first stamp [ns]

        def __init__(self):
            super().__init__()
            self.states_published = 0
            break_publishers(self, fault)

        pending = None  # one_step_late: the command held back for one tick

        def on_tick(self):
            if fault == "one_step_late":  # the latest command acts one tick later: a step of latency
                latest, self.command, self.pending = self.command, self.pending, self.command
                super().on_tick()
                self.command = latest
                return
            super().on_tick()

        def on_reset(self, request, response):
            self.pending = None
            return super().on_reset(request, response)

        def on_command(self, msg):
            if fault == "accepts_invalid" and int(msg.episode) == self.episode:
                self.command = (msg.vx, msg.vy, msg.closure, mock_driver_node.time.monotonic())
                return
            super().on_command(msg)
            if fault == "ignores_stale" and self.command is not None:
                self.command = (*self.command[:3], float("inf"))  # never stale

        def move(self, vx, vy, closure, dt):
            if fault == "disobeys":
                vx, vy = 0.5 * vx, 0.5 * vy
            if fault == "leaves_workspace":
                self.gripper = self.gripper + dt * np.array([vx, vy])
                self.closure = float(closure)
                return
            super().move(vx, vy, closure, dt)

        def state_stamp(self):
            return broken_stamp(self, fault, super().state_stamp())

    return BrokenDriver


class _Null:
    def publish(self, _msg):
        pass


class _Altered:
    """A publisher that changes each message with ``alter(msg)`` just before publishing it."""

    def __init__(self, publisher, alter):
        self.publisher, self.alter = publisher, alter

    def publish(self, msg):
        self.alter(msg)
        self.publisher.publish(msg)


def restamp(stamp):
    def alter(msg):
        msg.header.stamp = stamp()

    return alter


def one_step_late():
    """Stamp each message with the stamp the previous one carried (the first keeps its own)."""
    previous = []

    def alter(msg):
        stamp = msg.header.stamp
        if previous:
            msg.header.stamp = previous.pop()
        previous.append(stamp)

    return alter


def through_float(msg):
    """The stamp as float seconds and back (rclpy.time.Time(seconds=...)): float64 rounds it to ~0.2 us."""
    seconds = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
    msg.header.stamp = ns_stamp(int(seconds * 1e9))  # a new Time: the step's messages share one object


def shifted(offset_ns: int):
    def alter(msg):
        msg.header.stamp = ns_stamp(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec + offset_ns)

    return alter


def ns_stamp(nanoseconds: int):
    from builtin_interfaces.msg import Time

    sec, nanosec = divmod(nanoseconds, 1_000_000_000)
    return Time(sec=sec, nanosec=nanosec)


def to_rgb8(image):
    pixels = np.frombuffer(bytes(image.data), np.uint8).reshape(image.height, image.step)[:, : image.width]
    image.data = np.repeat(pixels, 3, axis=1).tobytes()
    image.encoding, image.step = "rgb8", 3 * image.width


def to_float64(cloud):
    from dlo_interface.cloud import unpack_particles
    from sensor_msgs.msg import PointField

    positions, held = unpack_particles(cloud)
    points = np.concatenate([positions, held[:, None]], axis=1).astype("<f8")
    cloud.fields = [
        PointField(name=f.name, offset=8 * i, datatype=PointField.FLOAT64, count=1) for i, f in enumerate(cloud.fields)
    ]
    cloud.point_step, cloud.row_step, cloud.data = 32, 32 * len(points), points.tobytes()


def main() -> int:
    if len(sys.argv) < 2 or sys.argv[1] not in {**FAULTS, **LATE_FAULTS}:
        print(f"usage: {sys.argv[0]} FAULT [--ros-args ...], FAULT one of {sorted({**FAULTS, **LATE_FAULTS})}", file=sys.stderr)
        return 2
    fault = sys.argv.pop(1)
    args = list(sys.argv)
    if fault == "wrong_rate":
        args += ["--ros-args", "-p", "rate:=20.0"]
    from dlo_common.node_main import run_node

    return run_node(broken_driver(fault), args)


if __name__ == "__main__":
    raise SystemExit(main())
