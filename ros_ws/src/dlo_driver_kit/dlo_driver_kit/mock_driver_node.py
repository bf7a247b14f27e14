"""mock_driver_node: the reference driver skeleton for a real robot (a kinematic stand-in, not the simulator).

Copy this file to write the driver of a real gripper (guide: docs/WRITE_YOUR_DRIVER.md); the places
to change are marked ``# ROBOT:``. It does what the rest of the graph relies on (docs/ARCHITECTURE.md#topics;
``dlo-driver-check`` verifies it rule by rule):

- publishes, once per control period (``rate``, 12.5 Hz = 0.08 s), ``/dlo/gripper/state``
  (x, y, z [m] in frame ``world``, closure [0, 1], episode, step +1 per state), the top camera's
  ``/dlo/camera/image`` (frame ``top_camera_optical``) with a latched ``/dlo/camera/camera_info``
  (same frame and size), and a tactile source: here ``/dlo/rope/particles`` with the contact points
  between the fingers flagged ``held`` (the tactile node turns them into ``/dlo/tactile/pose``; a
  real tactile sensor's driver publishes ``/dlo/tactile/pose`` itself). All messages of one state
  carry the same stamp: the time the state was measured;
- obeys ``/dlo/gripper/cmd`` (vx, vy [m/s], |v| <= 0.25; closure [0, 1]) when it answers the
  current episode and a step not older than ``command_timeout`` (``dlo_interface.command``, the sim's rules);
- rejects invalid commands (NaN/inf, speed or closure out of range): the gripper stops and holds
  its closure, with a warning at most once a second per cause (with the count);
- stops the gripper (and holds the closure) when the last command is older than ``command_timeout``;
- keeps the gripper inside the workspace |x|, |y| <= 0.3 m (``dlo_interface.world.WORKSPACE_HALF_WIDTH``):
  commanded beyond it, it stops at the boundary;
- has the gripper's force limit the policy relies on (the sim's finite grip, ``dlo_interface.grip.stall_firm_grip``):
  a firm grip (closure >= 0.9) carries the cable points between the fingers but does not pull one
  further from the fixed end than its rest length along the cable: at the end of the cable, closed
  firmly, the gripper stalls (back it still moves, and sideways it swings about the fixed end until
  the cable is straight; a sliding grip slides on);
- serves ``/dlo/sim/reset`` (dlo_msgs/srv/ResetEpisode, the sim's name, so the same clients work):
  back to the start pose, next episode from step 0.

Modes: ``real_time`` (default, what a robot does: a timer at ``rate`` moves the gripper with the
latest valid command over the measured time since the last tick) or ``step_locked`` (a state is
answered before the next one: one command = one step of 1/``rate`` s, the state republished every
0.25 s until answered; for replaying the sim's deterministic graph with a kinematic stand-in).

The mock "cable" is an S-curve at the gripper's height starting at the sim's fixed end, its points
the sim's rest spacing apart in x, so each lies at least its rest length along the cable from the
fixed end: the cable is taut, and a firm grip anywhere on it stalls the motion away from the fixed
end. Only a firm grip moves points of it (those between the fingers, kinematically); a reset lays it
out again. The image is drawn with numpy. It exits after ``steps`` states (0 = run until stopped),
printing where the gripper ended.
"""

from __future__ import annotations

import time

import numpy as np
from builtin_interfaces.msg import Time
from dlo_common.node_util import declare_parameters
from dlo_common.params import Param
from dlo_interface.camera import CAMERA_FRAME, TopCamera, camera_info
from dlo_interface.cloud import particle_cloud
from dlo_interface.command import CommandError, RejectionLog, command_mismatch, command_to_action
from dlo_interface.grip import carried_fraction, stall_firm_grip
from dlo_interface.sim_config import SimConfig
from dlo_interface.world import (
    CONTROL_PERIOD,
    FINGER_RADIUS,
    FIXED_END,
    GRIPPER_HEIGHT,
    GRIPPER_START_BEHIND,
    MAX_DISPLACEMENT,
    PARTICLE_RADIUS,
    REST_SPACING,
    WORKSPACE_HALF_WIDTH,
)
from dlo_msgs.msg import GripperCommand, GripperState
from dlo_msgs.srv import ResetEpisode
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

MODES = ("real_time", "step_locked")
CONTROL_RATE = 1.0 / CONTROL_PERIOD  # Hz: one command per 0.08 s, like the sim
FINGER_REACH = FINGER_RADIUS + REST_SPACING  # m, a point this close to the gripper centre (in x-y) is in contact
CABLE_RADIUS = PARTICLE_RADIUS  # m, drawn width (as the sim renders the cable)
START_CLOSURE = 0.7  # closure at the start of an episode (sliding grip)
SUBSTEP = MAX_DISPLACEMENT / SimConfig().substeps  # m, the sim's largest gripper sub-step: the stall's resolution
REPUBLISH_PERIOD = 0.25  # s, step_locked: republish an unanswered state this often

PARAMETERS = (
    Param(
        "mode",
        "real_time",
        "real_time: a timer at 'rate' moves the gripper with the latest command; step_locked: one answered state = one step",
        choices=MODES,
    ),
    Param("rate", CONTROL_RATE, "control rate [Hz]: one state per 1/rate s", above=0.0),
    Param(
        "command_timeout",
        0.5,
        "a command older than this [s] stops the gripper and holds the closure (real_time), or is rejected as stale",
        above=0.0,
    ),
    Param("steps", 0, "control steps before the driver exits (0 = run until stopped)", at_least=0),
    Param("cable_length", 0.2, "length of the mock cable [m]", at_least=0.05, at_most=0.5),
    Param("amplitude", 0.02, "lateral amplitude of the mock cable's S-curve [m]", at_least=0.0, at_most=0.1),
    Param("camera_resolution", 128, "top-view image width = height [px]", at_least=8),
)


def mock_cable(length: float, amplitude: float, spacing: float = REST_SPACING, height: float = GRIPPER_HEIGHT) -> np.ndarray:
    """(P, 3) points of a gentle S-curve starting at the sim's fixed end (-0.25, 0, height) along +x [m]."""
    x = FIXED_END[0] + np.arange(0.0, length, spacing)
    y = amplitude * np.sin(2 * np.pi * (x - FIXED_END[0]) / max(length, 1e-6))
    return np.stack([x, y, np.full_like(x, height)], axis=1)


def touching(cable: np.ndarray, gripper) -> np.ndarray:
    """(P,) bool: the cable points between the fingers (within FINGER_REACH of the gripper centre in x-y)."""
    return np.linalg.norm(cable[:, :2] - np.asarray(gripper)[:2], axis=1) <= FINGER_REACH


def kinematic_move(gripper, cable: np.ndarray, vx: float, vy: float, closure: float, dt: float):
    """Move the mock gripper with (vx, vy) [m/s] for ``dt`` s at ``closure`` -> (its new x, y [m], the cable).

    Stopped at the workspace boundary, and by the sim's force limit (``dlo_interface.grip.stall_firm_grip``, per
    sub-step of at most SUBSTEP as in the sim): a firm grip carries the points between the fingers (the
    grip law's carried fraction 1) but never beyond their rest length from the fixed end. A lighter grip
    slides over the cable and leaves it where it is."""
    gripper = np.asarray(gripper, dtype=np.float64)
    target = np.clip(gripper + dt * np.array([vx, vy]), -WORKSPACE_HALF_WIDTH, WORKSPACE_HALF_WIDTH)
    held = touching(cable, gripper)  # the held set at the start of the step, as in the sim
    carried = np.where(held, carried_fraction(closure), 0.0)  # the grip law
    firm = held & (carried >= 1.0)
    if not firm.any():
        return target, cable
    moved = cable.copy()
    substeps = max(1, int(np.ceil(np.linalg.norm(target - gripper) / SUBSTEP)))
    step = np.array([*(target - gripper) / substeps, 0.0])
    for _ in range(substeps):
        dg = stall_firm_grip(moved, carried, step)
        gripper = gripper + dg[:2]
        moved[firm] += dg  # carried with the gripper
    return gripper, (moved if np.any(moved != cable) else cable)  # the same object when nothing moved


def draw_cable(points: np.ndarray, camera: TopCamera) -> np.ndarray:
    """Top-view segmentation image (255 = cable) of the points, like a segmented camera frame."""
    v, u = np.mgrid[0 : camera.height, 0 : camera.width]
    world = camera.pixel_to_world(np.stack([u + 0.5, v + 0.5], axis=-1), points[0, 2])
    near = np.min(np.linalg.norm(world[:, :, None, :] - points[None, None, :, :2], axis=-1), axis=2)
    return np.where(near <= CABLE_RADIUS, 255, 0).astype(np.uint8)


class MockDriver(Node):
    """Kinematic gripper over a fixed cable, with the timing, checks and limits of a real driver."""

    def __init__(self):
        super().__init__("mock_driver")
        p = declare_parameters(self, PARAMETERS)
        self.mode, self.period, self.timeout, self.max_steps = p["mode"], 1.0 / p["rate"], p["command_timeout"], p["steps"]
        self.laid_cable = mock_cable(p["cable_length"], p["amplitude"])
        self.cable = self.laid_cable
        self.camera = TopCamera.covering_workspace(p["camera_resolution"])
        self.cable_image = draw_cable(self.cable, self.camera)  # drawn again only when a firm grip moved it
        self.drawn_cable = self.cable
        self.episode, self.step, self.steps_done = 0, 0, 0
        self.previous_final = None  # (episode, step) of the last state of the previous episode
        self.command = None  # (vx, vy, closure, monotonic time received) of the latest valid command
        self.timed_out = False
        self.rejections = RejectionLog(interval=1.0)
        self.stamp_ns = 0  # step_locked: driver time advances one period per step
        self.last_tick = None
        self.last_publish = time.monotonic()
        self.move_to_start()

        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.pub_cloud = self.create_publisher(PointCloud2, "/dlo/rope/particles", 10)
        self.pub_image = self.create_publisher(Image, "/dlo/camera/image", 10)
        self.pub_info = self.create_publisher(CameraInfo, "/dlo/camera/camera_info", latched)
        self.pub_state = self.create_publisher(GripperState, "/dlo/gripper/state", 10)
        self.pub_info.publish(camera_info(self.camera))
        self.create_subscription(GripperCommand, "/dlo/gripper/cmd", self.on_command, 10)
        self.create_service(ResetEpisode, "/dlo/sim/reset", self.on_reset)
        if self.mode == "real_time":
            self.create_timer(self.period, self.on_tick)
        self.create_timer(0.05, self.on_watchdog)
        self.get_logger().info(
            f"{self.mode} driver at {p['rate']:g} Hz, command_timeout {self.timeout:g} s, "
            f"workspace |x|, |y| <= {WORKSPACE_HALF_WIDTH} m"
        )
        if self.mode == "step_locked":
            self.publish_state()

    # ------------------------------------------------------------------ the robot
    def move_to_start(self):
        # ROBOT: replace this with your hardware call: move to the start pose (behind the cable's fixed end) and
        # set the start closure; block until it is there.
        self.gripper = np.array([FIXED_END[0] - GRIPPER_START_BEHIND, FIXED_END[1]])
        self.closure = START_CLOSURE
        self.cable = self.laid_cable  # the mock cable: laid out again

    def move(self, vx: float, vy: float, closure: float, dt: float):
        """Move with velocity (vx, vy) [m/s] for ``dt`` s and set the closure, inside the workspace; a firm
        grip on the taut cable stalls (the force limit)."""
        # ROBOT: replace this with your hardware call: send the velocity and the closure to the controller (and
        # enforce the workspace there too, and a force/torque limit: closed firmly (closure >= 0.9) on a taut
        # cable, the gripper must stall or stop, not drag the cable on). Here: integrate, stop at the workspace
        # boundary, and stall as the sim does (dlo_interface.grip.stall_firm_grip).
        self.gripper, self.cable = kinematic_move(self.gripper, self.cable, vx, vy, closure, dt)
        self.closure = float(closure)

    def read_sensors(self):
        """The measured gripper (x, y, z) [m], closure, top-view image (H, W) uint8, contact points (P, 3) + flags."""
        # ROBOT: replace this with your hardware calls: the measured pose and closure, the camera frame (segmented:
        # 255 = cable, 128 = gripper), and the cable points the tactile sensor touches (or publish
        # /dlo/tactile/pose from your tactile driver and drop the particle cloud).
        if self.drawn_cable is not self.cable:
            self.cable_image, self.drawn_cable = draw_cable(self.cable, self.camera), self.cable
        image = self.cable_image.copy()
        v, u = np.mgrid[0 : self.camera.height, 0 : self.camera.width]
        world = self.camera.pixel_to_world(np.stack([u + 0.5, v + 0.5], axis=-1), GRIPPER_HEIGHT)
        image[np.linalg.norm(world - self.gripper, axis=-1) <= FINGER_RADIUS] = 128
        contact = touching(self.cable, self.gripper)
        return (float(self.gripper[0]), float(self.gripper[1]), GRIPPER_HEIGHT), self.closure, image, self.cable, contact

    def state_stamp(self) -> Time:
        """The stamp of the state being published: when it was measured."""
        if self.mode == "step_locked":  # driver time: one period per step, like the sim's simulation time
            return Time(sec=self.stamp_ns // 1_000_000_000, nanosec=self.stamp_ns % 1_000_000_000)
        # ROBOT: the time your sensors measured the state (the controller's timestamp), in ROS time
        return self.get_clock().now().to_msg()

    # ------------------------------------------------------------------ commands
    def on_command(self, msg: GripperCommand):
        mismatch = command_mismatch(
            self.mode,
            self.episode,
            self.step,
            int(msg.episode),
            int(msg.step),
            period=self.period,
            command_timeout=self.timeout,
            previous_final=self.previous_final,
        )
        if mismatch is not None:
            cause, text = mismatch
            if cause != "previous episode":  # an answer to the previous episode's final state is expected
                self.reject(cause, f"{text}: ignored")
            return
        try:
            command_to_action(msg.vx, msg.vy, msg.closure)  # the sim's checks: finite, |v| <= 0.25 m/s, closure in [0, 1]
            vx, vy, closure = float(msg.vx), float(msg.vy), float(msg.closure)
        except CommandError as error:
            self.reject(error.cause, f"{error}; the gripper holds")
            vx, vy, closure = 0.0, 0.0, self.closure
        if self.mode == "step_locked":
            self.move(vx, vy, closure, self.period)
            self.advance()
        else:
            self.command = (vx, vy, closure, time.monotonic())
            self.timed_out = False

    def reject(self, cause: str, text: str):
        """A warning at most once a second per cause, with the count of rejections since."""
        line = self.rejections.note(cause, text, time.monotonic())
        if line is not None:
            self.get_logger().warning(line)

    def on_tick(self):
        """real_time: every period, move with the latest valid command (or stop when it is stale), then publish."""
        now = time.monotonic()
        if self.last_tick is not None:
            dt = min(now - self.last_tick, 2 * self.period)  # the measured time since the last state
            if self.command is None or now - self.command[3] > self.timeout:
                if self.command is not None and not self.timed_out:
                    self.get_logger().warning(
                        f"command timed out (older than {self.timeout:g} s): the gripper stops and holds its closure"
                    )
                    self.timed_out = True
                self.move(0.0, 0.0, self.closure, dt)
            else:
                self.move(*self.command[:3], dt)
            self.step += 1
            self.publish_state()
            self.check_done()
        else:
            self.publish_state()
        self.last_tick = now

    def advance(self):
        """step_locked: one step done."""
        self.step += 1
        self.stamp_ns += int(round(self.period * 1e9))
        self.publish_state()
        self.check_done()

    def check_done(self):
        self.steps_done += 1
        if self.max_steps and self.steps_done >= self.max_steps:
            self.get_logger().info(f"mock driver done at x = {self.gripper[0]:.3f} m, y = {self.gripper[1]:.4f} m")
            raise SystemExit(0)

    def on_watchdog(self):
        for line in self.rejections.due(time.monotonic()):
            self.get_logger().warning(line)
        if self.mode == "step_locked" and time.monotonic() - self.last_publish > REPUBLISH_PERIOD:
            self.publish_state()  # nobody answered: (re)publish until the step is answered

    def on_reset(self, request, response):
        self.previous_final = (self.episode, self.step)
        self.episode += 1
        self.step = 0
        self.command = None
        self.move_to_start()
        seed = int(request.seed) if request.seed >= 0 else self.episode
        response.success, response.message = True, f"episode {self.episode} started at the start pose"
        response.episode, response.seed = self.episode, seed
        if self.mode == "step_locked":
            self.stamp_ns += int(round(self.period * 1e9))
        else:
            self.last_tick = time.monotonic()  # the next tick moves from here
        self.publish_state()  # step 0 of the new episode, like the sim
        return response

    # ------------------------------------------------------------------ outputs
    def publish_state(self):
        (x, y, z), closure, pixels, points, contact = self.read_sensors()
        stamp = self.state_stamp()
        cloud = particle_cloud(points, contact)
        image = Image(
            height=pixels.shape[0], width=pixels.shape[1], encoding="mono8", step=pixels.shape[1], data=pixels.tobytes()
        )
        state = GripperState(x=x, y=y, z=z, closure=closure, episode=self.episode, step=self.step)
        for msg in (cloud, image, state):
            msg.header.stamp, msg.header.frame_id = stamp, "world"
        image.header.frame_id = CAMERA_FRAME  # shared with camera_info
        self.pub_cloud.publish(cloud)
        self.pub_image.publish(image)
        self.pub_state.publish(state)  # last: perception and policy react to the complete set
        self.last_publish = time.monotonic()


def main(args=None):
    from dlo_common.node_main import run_node

    return run_node(MockDriver, args, parameters=PARAMETERS, summary=__doc__)


if __name__ == "__main__":
    raise SystemExit(main())
