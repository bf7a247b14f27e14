"""sim_node: the Taichi rope simulator as a ROS 2 node (docs/ARCHITECTURE.md#topics, docs/INTERFACES.md).

Publishes ``/clock`` and, for every control step, the particles, gripper state, top-view image
(+ camera_info), task state and markers, all stamped with the simulation time of that state.
Obeys ``/dlo/gripper/cmd``. Modes:
- ``step_locked``: advance one action only when the command answering the current step arrives
  (deterministic, as fast as the graph runs); with no command for ``step_timeout`` s the current
  state is republished (a restarted policy picks up there) and a warning logged.
- ``real_time``: advance every 0.08 s / ``rate_factor`` of wall time holding the last command; a
  command older than ``command_timeout`` s stops the gripper and holds its closure.
Episodes run back to back; episode k is randomised with seed ``seed + k`` (or a seed given to the
``/dlo/sim/reset`` service). Invalid commands (NaN, out of range) are rejected and the gripper
holds; in both modes a command acts only if it answers the current episode and the current step
(step_locked) or a step not older than ``command_timeout`` (real_time). Rejections are logged at
most once a second per cause, with a count.

It starts only when it is the only publisher of its topics (another simulator or driver on the
same DDS domain would mix two graphs: it exits with a one-line reason), at least
``min_subscribers`` subscribe to the gripper state, ``wait_for_recorder`` subscribes to every
published /dlo topic (the topics it still lacks are named while it waits) and, in real_time, a node
publishes ``/dlo/gripper/cmd`` (warned once a second until one does; later, once a second while no
command arrives: "no command for N s"). Exit status: 0 after
``episodes`` episodes (in step_locked once the policy has answered the final state, so every node has
handled it; at most 10 s later), 130 when interrupted (SIGINT/SIGTERM), 2 bad parameter, 3 refused to start.
"""

from __future__ import annotations

import json
import os
import socket
import time

import numpy as np
from builtin_interfaces.msg import Time
from dlo_common.node_util import NodeStartError, declare_parameters
from dlo_common.params import Param
from dlo_common.topics import message_class, select, topic
from dlo_interface import perturbations
from dlo_interface.camera import CAMERA_FRAME, TopCamera, camera_info
from dlo_interface.cloud import particle_cloud
from dlo_interface.command import CommandError, RejectionLog, command_mismatch, command_to_action, hold_action
from dlo_interface.grip import CARRY_LAWS
from dlo_interface.sim_config import MAX_CONTACT_RADIUS, SimConfig
from dlo_interface.task import (
    AUTHORS_MOVE_SPACING,
    DEFAULT_MOVE_SPACING,
    DEFAULT_TASK_RULES,
    HORIZON,
    MAX_MOVE_SPACING,
    TASK_RULES,
)
from dlo_interface.world import CONTROL_PERIOD, FINGER_CLEARANCE, FINGER_HALF_LENGTH, FINGER_RADIUS, START_POSES
from dlo_msgs.msg import GripperCommand, GripperState, TaskState
from dlo_msgs.srv import ResetEpisode
from geometry_msgs.msg import Point
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Image
from std_msgs.msg import String
from visualization_msgs.msg import Marker, MarkerArray

from dlo_sim.episode import TaskSim

# the parameters that decide what an episode is (the task and the physics), published with the instance record
SETTINGS = (
    "mode",
    "seed",
    "horizon",
    "task_rules",
    "move_spacing",
    "single_particle_grip",
    "physics_seed",
    "carry_law",
    "contact_radius",
    "start_pose",
    "camera_resolution",
    "perturbations",
)
CONTROL_PERIOD_NS = int(round(CONTROL_PERIOD * 1e9))  # 0.08 s of simulation time per action


def node_perturbations(value) -> str:
    """The ``perturbations`` parameter (text, dlo_interface.perturbations.parse): the physics and camera families the
    node applies, as canonical text (recorded with the instance); ValueError in one line for anything else,
    observation and action families included (the policy node's)."""
    return perturbations.text(perturbations.owned(value, "simulator"))


MODES = ("step_locked", "real_time")
PARAMETERS = (
    Param("mode", "step_locked", f"clock mode, one of {MODES}", choices=MODES),
    Param("seed", 0, "episode k is randomised with seed + k", at_least=0),
    Param("episodes", 0, "episodes to run before the node exits (0 = forever)", at_least=0),
    Param("horizon", HORIZON, "control steps per episode", at_least=1),
    Param(
        "task_rules",
        DEFAULT_TASK_RULES,
        "which held set the reward, the episode's end and the tactile input (the "
        "particles' held flags) use, one of " + str(TASK_RULES),
        choices=TASK_RULES,
    ),
    Param(
        "move_spacing",
        DEFAULT_MOVE_SPACING,
        "the particle spacing [m] of the move reward under either task rule: 0 = the cable's own, "
        f"{AUTHORS_MOVE_SPACING} = the authors' fixed 4 mm (docs/FIDELITY.md)",
        at_least=0.0,
        at_most=MAX_MOVE_SPACING,
    ),
    Param(
        "single_particle_grip",
        False,
        "the grip carries ONE particle, the held one nearest the finger axis (never "
        "particle 0), as the authors' code did (docs/FIDELITY.md row 5); false: "
        "every held particle",
    ),
    Param(
        "physics_seed",
        -1,
        "-1: stretch, bending and friction drawn per episode; >= 0: every episode gets those "
        "drawn from this seed (the authors' one physics draw, docs/FIDELITY.md row 8)",
        at_least=-1,
    ),
    Param(
        "carry_law",
        "paper",
        "how the grip carries the cable: paper (the paper's law on the held set) or authors "
        "(their carry law: one particle moved by the whole displacement above closure 0.5; "
        "docs/FIDELITY.md rows 5-6)",
        choices=CARRY_LAWS,
    ),
    Param(
        "contact_radius",
        SimConfig.contact_radius,
        "the cable's contact half-thickness [m]; above half the finger "
        f"gap ({FINGER_CLEARANCE / 2}) the fingers pinch the cable, as Flex's 5 mm collision distance does",
        above=0.0,
        at_most=MAX_CONTACT_RADIUS,
    ),
    Param(
        "start_pose",
        "ours",
        "where the gripper starts: ours (5 mm behind the fixed end, at its height) or authors "
        "(8 mm behind, 2.25 mm lower, as the authors' code)",
        choices=tuple(START_POSES),
    ),
    Param("rate_factor", 1.0, "real_time mode: simulation speed relative to wall time", above=0.0),
    Param("command_timeout", 0.5, "real_time mode: a command older than this [s] stops the gripper", above=0.0),
    Param("step_timeout", 1.0, "step_locked mode: republish the state after this long [s] without a command", above=0.0),
    Param("min_subscribers", 0, "wait until /dlo/gripper/state has this many subscribers before the first episode", at_least=0),
    Param(
        "wait_for_recorder",
        "",
        "name of a recorder node that must subscribe to every published /dlo topic "
        "before the first episode (empty = do not wait)",
    ),
    Param("camera_resolution", 128, "top-view image width = height [px]", at_least=8),
    Param(
        "perturbations",
        "",
        "physics and camera perturbations (dlo_interface.perturbations, as the gym env's option), e.g. "
        "'friction=0.6,camera_yaw=2': the physics ranges every episode draws from, the camera that renders "
        "(camera_info stays the nominal camera's); empty = none",
        check=node_perturbations,
        types="string",
        accepts="name=value pairs of physics and camera families joined by ','",
    ),
    Param("publish_markers", True, "publish /dlo/markers for RViz/Foxglove"),
    Param("summary_file", "", "write the per-episode outcomes as JSON lines here (empty = off)"),
)
FINAL_ANSWER_WAIT = 10.0  # s: step_locked, after the last episode: wait this long at most for the final answer
DISCOVERY_GRACE = 1.0  # s: look for another simulator on the domain this long before building the simulation
INSTANCE_TOPIC = topic("instance").name  # latched: who runs here since when (the later of two simulators leaves)
WAIT_REPORT_PERIOD = 5.0  # s between "waiting for ..." lines
NO_COMMAND_WARNING = 1.0  # s: real_time warns this often while no command (or no command publisher) is there


def to_time(ns: int) -> Time:
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


class SimNode(Node):
    """One simulated environment driven through ROS topics."""

    def __init__(self, **options):
        super().__init__("sim_node", **options)
        p = declare_parameters(self, PARAMETERS)
        self.p = p
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
        self.created_wall = time.monotonic()
        self.info_published = False
        self.previous_final = None  # (episode, step) of the last state of the previous episode
        self.closing_since = None  # step_locked, last episode done: waiting for the answer to its final state
        self.rejections = RejectionLog(interval=1.0)
        self.period_wall = CONTROL_PERIOD / p["rate_factor"]

        qos = QoSProfile(depth=10)
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        # one publisher per topic of the registry that sim_node publishes (dlo_common.topics), by its key
        self.pubs = {
            t.key: self.create_publisher(message_class(t.type), t.name, latched if t.rate == "latched" else qos)
            for t in select(publisher="sim_node")
            if t.key != "markers" or p["publish_markers"]
        }
        self.pub_clock, self.pub_particles, self.pub_gripper, self.pub_image, self.pub_info, self.pub_task = (
            self.pubs[key] for key in ("clock", "particles", "gripper", "image", "camera_info", "task")
        )
        self.pub_markers, self.pub_instance = self.pubs.get("markers"), self.pubs["instance"]
        self.sub_command = self.create_subscription(GripperCommand, topic("command").name, self.on_command, qos)
        self.last_command_wall = None  # real_time: when the last command arrived (or the episode clock started)
        self.create_service(ResetEpisode, "/dlo/sim/reset", self.on_reset_service)
        self.instance = {
            "host": socket.gethostname(),
            "pid": os.getpid(),
            "started_ns": time.time_ns(),
            # what the episodes run under: latched and recorded, so a bag says it (dlo-analyze)
            "settings": {name: p[name] for name in SETTINGS},
        }
        self.create_subscription(
            String,
            INSTANCE_TOPIC,
            self.on_instance,  # several publishers: more than 1 deep
            QoSProfile(depth=10, durability=DurabilityPolicy.TRANSIENT_LOCAL),
        )

        # Another simulator or driver on this DDS domain would mix two graphs: look before building (slow) and
        # publishing anything (discovery runs meanwhile); looked at again until the first episode starts.
        time.sleep(DISCOVERY_GRACE)
        self.check_alone()
        self.pub_instance.publish(String(data=json.dumps(self.instance)))
        self.get_logger().info(
            f"alone on ROS_DOMAIN_ID={os.environ.get('ROS_DOMAIN_ID') or '0'}: no other publisher "
            f"of {self.pub_gripper.topic_name}; building the simulation"
        )
        # the physics and camera perturbations as the gym env applies them: the physics ranges every episode draws
        # from, and the camera that renders; camera_info stays the nominal camera's (what the vision assumes)
        setting = perturbations.parse(p["perturbations"])
        rendering, self.camera = perturbations.cameras(setting, TopCamera.covering_workspace(p["camera_resolution"]))
        config = SimConfig(
            single_particle_grip=p["single_particle_grip"],
            physics_seed=p["physics_seed"],
            carry_law=p["carry_law"],
            contact_radius=p["contact_radius"],
            start_pose=p["start_pose"],
        )
        self.task = TaskSim(
            1,
            horizon=p["horizon"],
            render=True,
            camera=rendering,
            task_rules=p["task_rules"],
            move_spacing=p["move_spacing"],
            config=perturbations.sim_config(setting, config),
        )

        if p["mode"] == "real_time":
            self.create_timer(CONTROL_PERIOD / p["rate_factor"], self.on_real_time_tick)
        self.create_timer(0.05, self.on_watchdog)
        self.get_logger().info(
            f"{p['mode']} simulation, seed {p['seed']}, task rules {p['task_rules']}, "
            f"{'move spacing %s m, ' % p['move_spacing'] if p['move_spacing'] > 0 else ''}"
            f"{'single-particle grip, ' if p['single_particle_grip'] else ''}"
            f"{'the authors carry law, ' if p['carry_law'] == 'authors' else ''}"
            f"contact radius {p['contact_radius']} m, "
            f"{'one physics draw (seed %d), ' % p['physics_seed'] if p['physics_seed'] >= 0 else ''}"
            f"{'perturbations %s, ' % p['perturbations'] if p['perturbations'] else ''}"
            f"{p['episodes'] or 'unlimited'} episodes of {p['horizon']} steps"
        )

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
        summary = {
            "episode": self.episode,
            "seed": self.episode_seed,
            **self.task.tracker.summary(0),
            "single_particle_grip": self.p["single_particle_grip"],
            "carry_law": self.p["carry_law"],
            "contact_radius": self.p["contact_radius"],
            "start_pose": self.p["start_pose"],
        }
        self.finished.append(summary)
        self.get_logger().info(
            f"episode {self.episode} (seed {self.episode_seed}): {summary['outcome']} "
            f"(authors' rule: {summary['outcome_authors']}), "
            f"return {summary['episode_return']:.3f}, time at end {summary['time_at_end']}, "
            f"{summary['how_far']} particles from the end"
        )
        if self.p["summary_file"]:
            with open(self.p["summary_file"], "a") as f:
                f.write(json.dumps(summary) + "\n")
        self.previous_final = (self.episode, self.step_index)
        self.episode += 1
        if self.p["episodes"] and self.episode >= self.p["episodes"]:
            if self.p["mode"] != "step_locked":
                self.get_logger().info(f"ran {self.episode} episodes: exiting")
                raise SystemExit(0)
            # step_locked: the graph is still working on the final state (tactile, vision, the policy's last
            # transition, the recorder): exit once the policy has answered it (on_command), or after a while
            self.closing_since = time.monotonic()
            return
        self.start_episode(self.p["seed"] + self.episode)

    def exit_when_answered(self, answered: bool) -> None:
        """After the last episode (step_locked): exit once its final state is answered, or FINAL_ANSWER_WAIT
        s without an answer (a policy that does not answer final states; the graph stopped meanwhile)."""
        if answered:
            self.get_logger().info(f"ran {self.episode} episodes: exiting")
            raise SystemExit(0)
        if time.monotonic() - self.closing_since > FINAL_ANSWER_WAIT:
            self.get_logger().info(
                f"ran {self.episode} episodes: exiting (no answer to the final state in {FINAL_ANSWER_WAIT:g} s)"
            )
            raise SystemExit(0)

    # ------------------------------------------------------------------ inputs
    def reject(self, cause: str, text: str):
        """Log a rejected command: at most one line a second per cause, with a count."""
        line = self.rejections.note(cause, text, time.monotonic())
        if line is not None:
            self.get_logger().warning(line)

    def on_command(self, msg: GripperCommand):
        if not self.started:
            self.get_logger().debug(f"ignoring command for episode {msg.episode} step {msg.step}: not started")
            return
        if self.closing_since is not None:
            self.exit_when_answered((int(msg.episode), int(msg.step)) == tuple(self.previous_final))
            return
        self.last_command_wall = time.monotonic()
        mismatch = command_mismatch(
            self.p["mode"],
            self.episode,
            self.step_index,
            int(msg.episode),
            int(msg.step),
            period=self.period_wall,
            command_timeout=self.p["command_timeout"],
            previous_final=self.previous_final,
        )
        if mismatch is not None:
            cause, text = mismatch
            if cause == "previous episode":  # the policy answered the final state: expected
                self.get_logger().debug(f"ignoring command {text}")
            else:
                self.reject(cause, f"{text}: ignored")
            return
        try:
            action = command_to_action(msg.vx, msg.vy, msg.closure)
        except CommandError as error:
            self.reject(error.cause, f"{error}; the gripper holds")
            action = hold_action(self.task.state.gripper[0, 3])
        if self.p["mode"] == "real_time":
            self.command = (action, time.monotonic())
            return
        self.advance(action)

    def on_real_time_tick(self):
        if not self.started:
            return
        closure = self.task.state.gripper[0, 3]
        now = time.monotonic()
        self.last_command_wall = self.last_command_wall or now
        if self.command is None or now - self.command[1] > self.p["command_timeout"]:
            if now - self.last_command_wall >= NO_COMMAND_WARNING:
                self.get_logger().warning(
                    f"no command for {now - self.last_command_wall:.0f} s: is a policy running? (the gripper stands still)",
                    throttle_duration_sec=NO_COMMAND_WARNING,
                )
            elif self.command is not None:
                self.get_logger().warning("command timed out: the gripper stops and holds", throttle_duration_sec=2.0)
            action = hold_action(closure)
        else:
            action = self.command[0]
        self.advance(action)

    def on_watchdog(self):
        """Start once enough subscribers are up; in step_locked mode republish a state nobody answered."""
        now = time.monotonic()
        for line in self.rejections.due(now):
            self.get_logger().warning(line)
        if self.count_publishers(self.pub_gripper.topic_name) > 1:  # a driver, or a simulator about to leave
            self.get_logger().error(
                f"another node publishes {self.pub_gripper.topic_name} too "
                f"({', '.join(self.other_publishers(self.pub_gripper.topic_name))}): "
                "two graphs share this DDS domain and their messages mix",
                throttle_duration_sec=WAIT_REPORT_PERIOD,
            )
        if not self.started:
            if not self.info_published:  # after the look for another simulator (__init__)
                self.pub_info.publish(camera_info(self.camera))
                self.info_published = True
                return
            subscribers = self.count_subscribers(self.pub_gripper.topic_name)
            if subscribers < self.p["min_subscribers"]:
                self.get_logger().info(
                    f"waiting for {self.p['min_subscribers']} subscribers of {self.pub_gripper.topic_name} (have {subscribers})",
                    throttle_duration_sec=WAIT_REPORT_PERIOD,
                )
            elif self.recorder_ready() and self.command_source_ready():
                self.started = True
                self.start_episode(self.p["seed"])
            return
        if self.p["mode"] != "step_locked":
            return
        if self.closing_since is not None:
            self.exit_when_answered(False)
            return
        waited = time.monotonic() - self.last_publish_wall
        if self.step_index == 0 and self.episode == 0 and waited > 0.25:  # start-up: nodes still joining
            self.publish_state(new_stamp=False)
        elif waited > self.p["step_timeout"]:
            self.get_logger().warning(
                f"no command for episode {self.episode} step {self.step_index} in "
                f"{self.p['step_timeout']} s: republishing the state",
                throttle_duration_sec=5.0,
            )
            self.publish_state(new_stamp=False)

    def own_publishers(self):
        return list(self.pubs.values())

    def other_publishers(self, topic: str, wait_for_names: float = 2.0) -> list:
        """Names of the nodes publishing ``topic`` besides this one. Discovery can show a publisher before its
        node's name (rmw reports it as _NODE_NAME_UNKNOWN_): wait up to ``wait_for_names`` s for the names."""
        mine = f"{self.get_namespace().rstrip('/')}/{self.get_name()}"
        deadline = time.monotonic() + wait_for_names
        while True:
            infos = self.get_publishers_info_by_topic(topic)
            unnamed = [i for i in infos if "_UNKNOWN_" in i.node_name or "_UNKNOWN_" in i.node_namespace]
            if not unnamed or time.monotonic() >= deadline:
                break
            time.sleep(0.05)
        names = [f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in infos if i not in unnamed]
        if mine in names:
            names.remove(mine)
        return names + ["a node discovery has not named yet"] * bool(unnamed) or ["unknown"]

    def on_instance(self, msg: String):
        """Another simulator announced itself (discovery can take seconds): the later one of the two leaves."""
        try:
            other = json.loads(msg.data)
            key = (int(other["started_ns"]), str(other["host"]), int(other["pid"]))
        except (ValueError, KeyError, TypeError):
            return
        mine = (self.instance["started_ns"], self.instance["host"], self.instance["pid"])
        if key == mine:
            return
        domain = os.environ.get("ROS_DOMAIN_ID") or "0"
        who = f"pid {key[2]} on {key[1]}, started {time.strftime('%H:%M:%S', time.localtime(key[0] / 1e9))}"
        if key < mine:
            raise NodeStartError(
                f"another simulator already runs on ROS_DOMAIN_ID={domain} ({who}): two graphs would "
                "mix; stop it, or use another ROS_DOMAIN_ID (scripts/launch_graph.sh picks a free one) "
                "or --namespace"
            )
        self.get_logger().error(
            f"a second simulator appeared on ROS_DOMAIN_ID={domain} ({who}); it leaves, but "
            "messages of the two graphs may have mixed meanwhile"
        )

    def check_alone(self):
        """Refuse to start when another node already publishes one of this simulator's topics."""
        for pub in self.own_publishers():
            if self.count_publishers(pub.topic_name) > 1:
                domain = os.environ.get("ROS_DOMAIN_ID") or "0"
                raise NodeStartError(
                    f"another node already publishes {pub.topic_name} ({', '.join(self.other_publishers(pub.topic_name))}) "
                    f"on ROS_DOMAIN_ID={domain}: a second simulator or driver would mix two graphs; stop it, or use "
                    "another ROS_DOMAIN_ID (scripts/launch_graph.sh picks a free one) or --namespace"
                )

    def recorder_ready(self) -> bool:
        """True when ``wait_for_recorder`` is unset or that node subscribes to every /dlo topic with a publisher,
        so the recording misses nothing of the first episode (the graph's other publishers are up by then:
        they create their publishers before their /dlo/gripper/state subscriptions). While it waits, the topics
        the recorder still lacks are named every few seconds."""
        recorder = self.p["wait_for_recorder"]
        if not recorder:
            return True
        prefix = self.pub_gripper.topic_name[: -len("gripper/state")]  # /dlo/, or /<namespace>/dlo/
        topics = sorted(t for t, _ in self.get_topic_names_and_types() if t.startswith(prefix) and self.count_publishers(t) > 0)
        missing = [t for t in topics if not any(info.node_name == recorder for info in self.get_subscriptions_info_by_topic(t))]
        if missing and time.monotonic() - self.created_wall > DISCOVERY_GRACE + 1.0:
            known = recorder in self.get_node_names()
            self.get_logger().warning(
                f"waiting for the recorder '{recorder}' to subscribe to {', '.join(missing)}"
                + ("" if known else f" (no node '{recorder}' in the graph: is it running?)"),
                throttle_duration_sec=WAIT_REPORT_PERIOD,
            )
        return not missing

    def command_source_ready(self) -> bool:
        """real_time: True once a node publishes commands, so that the episode clock does not run before a
        policy or driver is there (a warning once a second meanwhile); step_locked waits for commands anyway."""
        topic = self.sub_command.topic_name
        if self.p["mode"] != "real_time" or self.count_publishers(topic) > 0:
            return True
        self.get_logger().warning(
            f"no publisher of {topic} for {time.monotonic() - self.created_wall:.0f} s: is a "
            "policy running? (the real-time episode starts when one appears)",
            throttle_duration_sec=NO_COMMAND_WARNING,
        )
        return False

    def on_reset_service(self, request, response):
        seed = int(request.seed) if request.seed >= 0 else self.p["seed"] + self.episode + 1
        self.previous_final = (self.episode, self.step_index)
        self.episode += 1
        self.started = True
        self.closing_since = None
        if not self.info_published:
            self.pub_info.publish(camera_info(self.camera))
            self.info_published = True
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

        cloud = particle_cloud(positions, self.task.held_task[0, :n_c])  # the touch the tactile node fits to
        state = GripperState(
            x=float(gripper[0]),
            y=float(gripper[1]),
            z=float(gripper[2]),
            closure=float(gripper[3]),
            episode=self.episode,
            step=self.step_index,
        )
        pixels = snapshot.image[0]
        image = Image(
            height=pixels.shape[0],
            width=pixels.shape[1],
            encoding="mono8",
            is_bigendian=0,
            step=pixels.shape[1],
            data=pixels.tobytes(),
        )
        # a volatile topic none listens to (the task state without a recorder, the markers without a viewer) is
        # neither built nor published: 0.3 ms a step, nothing anyone could receive
        task = self.task_state(held, n_c) if self.pub_task.get_subscription_count() else None
        for msg in (cloud, state, image, task):
            if msg is not None:
                msg.header.stamp = stamp
                msg.header.frame_id = "world"
        image.header.frame_id = CAMERA_FRAME  # the image and its camera_info share the camera's frame
        self.pub_particles.publish(cloud)
        self.pub_image.publish(image)
        if task is not None:
            self.pub_task.publish(task)
        if self.pub_markers is not None and self.pub_markers.get_subscription_count():
            self.pub_markers.publish(self.markers(positions, gripper, stamp))
        self.pub_gripper.publish(state)  # last: perception/policy react to the complete set

    def task_state(self, held, n_c: int) -> TaskState:
        """The task's state of the current step (its header set by the caller)."""
        sim = self.task.sim
        tracker = self.task.tracker
        held_indices = np.flatnonzero(held).astype(np.int32)
        return TaskState(
            episode=self.episode,
            seed=self.episode_seed,
            step=self.step_index,
            held_indices=held_indices.tolist(),
            n_held=len(held_indices),
            mean_held_index=float(self.task.mean_held_index[0]),
            num_particles=n_c,
            cable_length=float(sim.cable_length[0]),
            reward=self.last_reward,
            episode_return=float(tracker.episode_return[0]),
            done=self.done,
            outcome=int(tracker.outcome[0]) if self.done else 0,
            held_indices_authors=np.flatnonzero(self.task.held_authors[0, :n_c]).astype(np.int32).tolist(),
            mean_held_index_authors=float(self.task.mean_held_index_authors[0]),
            outcome_authors=int(tracker.outcome_authors[0]) if self.done else 0,
            task_rules=self.task.task_rules,
            move_spacing=tracker.move_spacing,
        )

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
    from dlo_common.node_main import run_node

    return run_node(SimNode, args, interrupted_rc=130, parameters=PARAMETERS, summary=__doc__)


if __name__ == "__main__":
    raise SystemExit(main())
