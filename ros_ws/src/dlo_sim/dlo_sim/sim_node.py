"""sim_node: the Taichi rope simulator as a ROS 2 node (DESIGN.md section 6).

Publishes ``/clock`` and, for every control step, the particles, gripper state, top-view image
(+ camera_info), task state and markers, all stamped with the simulation time of that state.
Obeys ``/dlo/gripper/cmd``. Modes:
- ``step_locked``: advance one action only when the command answering the current step arrives
  (deterministic, as fast as the graph runs); with no command for ``step_timeout`` s the current
  state is republished (a restarted policy picks up there) and a warning logged.
- ``real_time``: advance every 0.08 s / ``rate_factor`` of wall time holding the last command; a
  command older than ``command_timeout`` s stops the gripper and holds its closure.
Episodes run back to back; episode k is randomised with seed ``seed + k`` (or a seed given to the
``/dlo/sim/reset`` service). Invalid commands (NaN, out of range) are rejected with a warning and
the gripper holds.
"""

from __future__ import annotations

import json
import time

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from visualization_msgs.msg import Marker, MarkerArray

from dlo_msgs.msg import GripperCommand, GripperState, TaskState
from dlo_msgs.srv import ResetEpisode
from dlo_perception.camera import TopCamera
from dlo_perception.cloud import particle_cloud
from dlo_sim.command import CommandError, command_to_action, hold_action
from dlo_sim.config import DT, FINGER_CLEARANCE, FINGER_HALF_LENGTH, FINGER_RADIUS, SUBSTEPS_PER_ACTION
from dlo_sim.episode import TaskSim
from dlo_sim.task import HORIZON, OUTCOME_NAMES
from dlo_tools.node_util import ParameterError, declare_parameters, require_bounds

CONTROL_PERIOD_NS = int(round(DT * SUBSTEPS_PER_ACTION * 1e9))  # 0.08 s of simulation time per action
MODES = ("step_locked", "real_time")


def to_time(ns: int) -> Time:
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


class SimNode(Node):
    """One simulated environment driven through ROS topics."""

    def __init__(self):
        super().__init__("sim_node")
        p = declare_parameters(self, [
            ("mode", "step_locked", f"clock mode, one of {MODES}"),
            ("seed", 0, "episode k is randomised with seed + k"),
            ("episodes", 0, "episodes to run before the node exits (0 = forever)"),
            ("horizon", HORIZON, "control steps per episode"),
            ("rate_factor", 1.0, "real_time mode: simulation speed relative to wall time"),
            ("command_timeout", 0.5, "real_time mode: a command older than this [s] stops the gripper"),
            ("step_timeout", 1.0, "step_locked mode: republish the state after this long [s] without a command"),
            ("min_subscribers", 0, "wait until /dlo/gripper/state has this many subscribers before the first episode"),
            ("wait_for_recorder", "", "name of a recorder node that must subscribe to every published /dlo topic "
                                      "before the first episode (empty = do not wait)"),
            ("camera_resolution", 128, "top-view image width = height [px]"),
            ("publish_markers", True, "publish /dlo/markers for RViz/Foxglove"),
            ("summary_file", "", "write the per-episode outcomes as JSON lines here (empty = off)"),
        ])
        if p["mode"] not in MODES:
            raise ParameterError(f"parameter 'mode': expected one of {MODES}, got {p['mode']!r}")
        require_bounds(p, at_least={"episodes": 0, "horizon": 1, "camera_resolution": 8, "seed": 0, "min_subscribers": 0},
                       above={"rate_factor": 0, "command_timeout": 0, "step_timeout": 0})
        self.p = p
        self.camera = TopCamera.covering_workspace(p["camera_resolution"])
        self.task = TaskSim(1, horizon=p["horizon"], render=True, camera=self.camera)
        self.episode = 0
        self.episode_seed = p["seed"]
        self.step_index = 0
        self.stamp_ns = 0
        self.last_reward = 0.0
        self.done = False
        self.command = None  # (action, wall time received) for real_time mode
        self.last_publish_wall = time.monotonic()
        self.finished = []
        self.started = False

        qos = QoSProfile(depth=10)
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.pub_clock = self.create_publisher(Clock, "/clock", 10)
        self.pub_particles = self.create_publisher(PointCloud2, "/dlo/rope/particles", qos)
        self.pub_gripper = self.create_publisher(GripperState, "/dlo/gripper/state", qos)
        self.pub_image = self.create_publisher(Image, "/dlo/camera/image", qos)
        self.pub_info = self.create_publisher(CameraInfo, "/dlo/camera/camera_info", latched)
        self.pub_task = self.create_publisher(TaskState, "/dlo/task/state", qos)
        self.pub_markers = self.create_publisher(MarkerArray, "/dlo/markers", qos) if p["publish_markers"] else None
        self.create_subscription(GripperCommand, "/dlo/gripper/cmd", self.on_command, qos)
        self.create_service(ResetEpisode, "/dlo/sim/reset", self.on_reset_service)

        self.pub_info.publish(self.camera_info())
        if p["mode"] == "real_time":
            self.create_timer(DT * SUBSTEPS_PER_ACTION / p["rate_factor"], self.on_real_time_tick)
        self.create_timer(0.05, self.on_watchdog)
        self.get_logger().info(f"{p['mode']} simulation, seed {p['seed']}, "
                               f"{p['episodes'] or 'unlimited'} episodes of {p['horizon']} steps")

    # ------------------------------------------------------------------ episodes
    def start_episode(self, seed: int):
        self.episode_seed = int(seed)
        self.task.reset(np.array([seed]))
        self.step_index = 0
        self.last_reward = 0.0
        self.done = False
        self.command = None
        self.publish_state()

    def advance(self, action):
        reward, terminated, truncated, unstable = self.task.step(action[None, :])
        if unstable[0]:
            self.get_logger().error("the simulation became unstable: the episode is cut")
        self.step_index += 1
        self.last_reward = float(reward[0])
        self.done = bool(terminated[0] or truncated[0])
        self.publish_state()
        if self.done:
            self.finish_episode()

    def finish_episode(self):
        summary = {"episode": self.episode, "seed": self.episode_seed, **self.task.tracker.summary(0)}
        self.finished.append(summary)
        self.get_logger().info(f"episode {self.episode} (seed {self.episode_seed}): {summary['outcome']} "
                               f"(authors' rule: {summary['outcome_authors']}), "
                               f"return {summary['episode_return']:.3f}, time at end {summary['time_at_end']}, "
                               f"{summary['how_far']} particles from the end")
        if self.p["summary_file"]:
            with open(self.p["summary_file"], "a") as f:
                f.write(json.dumps(summary) + "\n")
        self.episode += 1
        if self.p["episodes"] and self.episode >= self.p["episodes"]:
            self.get_logger().info(f"ran {self.episode} episodes: exiting")
            raise SystemExit(0)
        self.start_episode(self.p["seed"] + self.episode)

    # ------------------------------------------------------------------ inputs
    def on_command(self, msg: GripperCommand):
        try:
            action = command_to_action(msg.vx, msg.vy, msg.closure)
        except CommandError as error:
            self.get_logger().warning(f"rejected command: {error}; the gripper holds")
            action = hold_action(self.task.state.gripper[0, 3])
        if self.p["mode"] == "real_time":
            self.command = (action, time.monotonic())
            return
        if not self.started or msg.episode != self.episode or msg.step != self.step_index:
            self.get_logger().debug(f"ignoring command for episode {msg.episode} step {msg.step}")
            return
        self.advance(action)

    def on_real_time_tick(self):
        if not self.started:
            return
        closure = self.task.state.gripper[0, 3]
        if self.command is None or time.monotonic() - self.command[1] > self.p["command_timeout"]:
            if self.command is not None:
                self.get_logger().warning("command timed out: the gripper stops and holds",
                                          throttle_duration_sec=2.0)
            action = hold_action(closure)
        else:
            action = self.command[0]
        self.advance(action)

    def on_watchdog(self):
        """Start once enough subscribers are up; in step_locked mode republish a state nobody answered."""
        if not self.started:
            if self.count_subscribers("/dlo/gripper/state") >= self.p["min_subscribers"] and self.recorder_ready():
                self.started = True
                self.start_episode(self.p["seed"])
            return
        if self.p["mode"] != "step_locked":
            return
        waited = time.monotonic() - self.last_publish_wall
        if self.step_index == 0 and self.episode == 0 and waited > 0.25:  # start-up: nodes still joining
            self.publish_state(new_stamp=False)
        elif waited > self.p["step_timeout"]:
            self.get_logger().warning(f"no command for episode {self.episode} step {self.step_index} in "
                                      f"{self.p['step_timeout']} s: republishing the state", throttle_duration_sec=5.0)
            self.publish_state(new_stamp=False)

    def recorder_ready(self) -> bool:
        """True when ``wait_for_recorder`` is unset or that node subscribes to every /dlo topic with a publisher,
        so the recording misses nothing of the first episode (the graph's other publishers are up by then:
        they create their publishers before their /dlo/gripper/state subscriptions)."""
        recorder = self.p["wait_for_recorder"]
        if not recorder:
            return True
        topics = [t for t, _ in self.get_topic_names_and_types()
                  if t.startswith("/dlo/") and self.count_publishers(t) > 0]
        return all(any(info.node_name == recorder for info in self.get_subscriptions_info_by_topic(t))
                   for t in topics)

    def on_reset_service(self, request, response):
        seed = int(request.seed) if request.seed >= 0 else self.p["seed"] + self.episode + 1
        self.episode += 1
        self.started = True
        self.start_episode(seed)
        response.success, response.message = True, f"episode {self.episode} started with seed {seed}"
        response.episode, response.seed = self.episode, seed
        return response

    # ------------------------------------------------------------------ outputs
    def publish_state(self, new_stamp: bool = True):
        if new_stamp:
            self.stamp_ns += CONTROL_PERIOD_NS
        self.last_publish_wall = time.monotonic()
        sim = self.task.sim
        stamp = to_time(self.stamp_ns)
        self.pub_clock.publish(Clock(clock=stamp))
        n_c = int(sim.num_particles[0])
        snapshot = self.task.state  # read back with the step: no further kernel launches here
        positions = snapshot.positions[0, :n_c]
        held = snapshot.held[0, :n_c]
        gripper = snapshot.gripper[0]

        cloud = particle_cloud(positions, held)
        state = GripperState(x=float(gripper[0]), y=float(gripper[1]), z=float(gripper[2]),
                             closure=float(gripper[3]), episode=self.episode, step=self.step_index)
        pixels = snapshot.image[0]
        image = Image(height=pixels.shape[0], width=pixels.shape[1], encoding="mono8", is_bigendian=0,
                      step=pixels.shape[1], data=pixels.tobytes())
        tracker = self.task.tracker
        held_indices = np.flatnonzero(held).astype(np.int32)
        task = TaskState(episode=self.episode, seed=self.episode_seed, step=self.step_index,
                         held_indices=held_indices.tolist(), n_held=len(held_indices),
                         mean_held_index=float(self.task.mean_held_index[0]),
                         num_particles=n_c, cable_length=float(sim.cable_length[0]), reward=self.last_reward,
                         episode_return=float(tracker.episode_return[0]), done=self.done,
                         outcome=int(tracker.outcome[0]) if self.done else 0,
                         held_indices_authors=np.flatnonzero(self.task.held_authors[0, :n_c]).astype(np.int32).tolist(),
                         mean_held_index_authors=float(self.task.mean_held_index_authors[0]),
                         outcome_authors=int(tracker.outcome_authors[0]) if self.done else 0)
        for msg in (cloud, state, image, task):
            msg.header.stamp = stamp
            msg.header.frame_id = "world"
        self.pub_particles.publish(cloud)
        self.pub_image.publish(image)
        self.pub_task.publish(task)
        if self.pub_markers is not None:
            self.pub_markers.publish(self.markers(positions, gripper, stamp))
        self.pub_gripper.publish(state)  # last: perception/policy react to the complete set

    def camera_info(self) -> CameraInfo:
        info = CameraInfo(width=self.camera.width, height=self.camera.height, distortion_model="plumb_bob")
        info.header.frame_id = "top_camera_optical"
        info.k = self.camera.k_matrix.reshape(-1).tolist()
        info.d = [0.0] * 5
        info.r = np.eye(3).reshape(-1).tolist()
        info.p = np.hstack([self.camera.k_matrix, np.zeros((3, 1))]).reshape(-1).tolist()
        return info

    def markers(self, positions, gripper, stamp) -> MarkerArray:
        cable = Marker(ns="cable", id=0, type=Marker.LINE_STRIP, action=Marker.ADD)
        cable.scale.x = 0.008
        cable.color.r, cable.color.g, cable.color.b, cable.color.a = 0.9, 0.5, 0.1, 1.0
        cable.points = [Point(x=float(x), y=float(y), z=float(z)) for x, y, z in positions]
        fingers = []
        offset = FINGER_RADIUS + FINGER_CLEARANCE / 2
        for i, dz in enumerate((offset, -offset)):
            finger = Marker(ns="fingers", id=i, type=Marker.CYLINDER, action=Marker.ADD)
            finger.pose.position = Point(x=float(gripper[0]), y=float(gripper[1]), z=float(gripper[2] + dz))
            finger.pose.orientation.x = finger.pose.orientation.w = float(np.sqrt(0.5))  # axis along y
            finger.scale.x = finger.scale.y = 2 * FINGER_RADIUS
            finger.scale.z = 2 * (FINGER_HALF_LENGTH + FINGER_RADIUS)
            finger.color.r, finger.color.g, finger.color.b, finger.color.a = 0.2, 0.4, 0.9, 0.8 + 0.2 * gripper[3]
            fingers.append(finger)
        for m in [cable, *fingers]:
            m.header.stamp, m.header.frame_id = stamp, "world"
        return MarkerArray(markers=[cable, *fingers])


def main(args=None):
    from dlo_tools.node_main import run_node

    return run_node(SimNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
