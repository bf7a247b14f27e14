"""dlo-driver-check: does the driver running on this ROS domain fit the graph's topic contract?

    dlo-driver-check [--namespace NS] [--timeout S] [--duration S] [--rate HZ] [--command-timeout S]
                     [--speed M/S] [--workspace M] [--skip RULE ...]

It acts as the policy would: it answers every ``/dlo/gripper/state`` with a ``/dlo/gripper/cmd``
stamped with that state's episode and step, following a fixed schedule of phases (hold still,
close, open, move +x / +y / -y, go silent, drive to the workspace corner, send invalid commands,
start a new episode through ``/dlo/sim/reset`` when the driver serves it),
records what the driver publishes and judges it rule by rule (docs/ARCHITECTURE.md#topics; the driver
guide docs/WRITE_YOUR_DRIVER.md). The rules are what the unchanged graph needs to run a step:
tactile_node, vision_node and policy_node match a step's inputs by their exact header stamp
(``dlo_perception.sync.StampSync``), vision_node reads mono8 segmentation images only and
needs camera_info first, tactile_node reads the particle cloud layout of ``dlo_interface.cloud``,
and the policy answers a stamp it has seen before as a republished step. A driver that passes
them all runs the graph; a failed rule names the property and the numbers. Every rule prints one
line ``PASS``/``FAIL``/``SKIP``, its name and the measured numbers; each rule judges one property,
so one defect fails one rule:

- ``rate``: the state arrives at the control rate (``--rate``, 12.5 Hz = one per 0.08 s, within
  20 %) while the driver is commanded to hold still (by arrival time; the stamps are judged by
  ``stamps``);
- ``stamps``: header stamps strictly increase, also across an episode start (the policy answers a
  stamp it has seen again as a republished step: a driver whose stamps restart with each episode
  stalls the graph at its second episode); the step counter goes +1 per state within an episode,
  and a new episode starts at step 0. The check starts one episode through ``/dlo/sim/reset``
  (optional for a driver: without it, an episode start is judged only if the driver starts one);
- ``sync``: every state's exact stamp (to the nanosecond) is carried by the step's other inputs:
  an image and the tactile source (particle cloud or tactile pose), as the perception and policy
  nodes match them, and any other topic with a driver's part in ``dlo_common.topics`` the driver
  publishes (e.g. a modality added there); a clock read separately for each message fails it. The message carrying a
  state's stamp must also be that step's: it arrives with the state (within half a control period;
  a cloud stamped with the previous step's stamp arrives a period after the state it matches, and
  the nodes would then pair a state with the next step's touch). An input the driver does not
  publish at all is left to ``camera`` / ``touch``;
- ``camera``: ``camera_info`` (latched) exists with a valid pinhole K; the images are what
  vision_node reads: ``mono8``, segmented (pixel values 0, 128 gripper, 255 cable, and the cable
  in view), the camera_info's size and frame_id, data of height x step bytes;
- ``obey``: valid commands are executed: velocity direction within 15 deg and speed within 20 %
  (measured from consecutive states of one episode: displacement / stamp difference, or arrival-time
  difference when the stamps are unusable), closure within 0.05. A driver may end episodes by itself
  (the sim does when the cable is dropped: under the authors' task rules the sideways moves end one
  every step or two): each phase is judged on its steps in every episode, a new episode's first step
  included (a driver acts only on commands of its current episode, so that step runs under the
  command answering state 0), pooled across the episodes;
- ``invalid``: non-finite (NaN) and out-of-range (speed > 0.25 m/s, closure > 1) commands are
  rejected: the gripper, moving under a valid command just before, stops (< 0.5 mm per step) within
  two control periods of the first invalid command (the pipeline, as for ``stale``) and keeps the
  closure it had (within 0.02, also not clamped to 1); no state reported after an invalid command
  (within those two periods of the phase's end too) is non-finite;
- ``stale``: when commands stop, the gripper stops within ``--command-timeout`` (+ two control
  periods for the pipeline) and the driver keeps publishing its state (real-time timing);
- ``workspace``: every reported gripper position lies in ``|x|, |y| <= --workspace`` (+ 1 mm),
  also while commanded at full speed towards the corner (+x, +y);
- ``touch``: a tactile source exists: ``/dlo/rope/particles`` in the layout tactile_node reads
  (``dlo_interface.cloud``: fields x, y, z, held, FLOAT32, little endian, 16 bytes a point), or
  ``/dlo/tactile/pose``.

After the rules, against the shipped policy's robustness envelope (:mod:`dlo_driver_kit.envelope`, packaged with
this module; :func:`envelope_lines`), one line each, "within" or "beyond the shipped policy's 80% tolerance of" the
perturbation family it amounts to (or "not compared" and why, without the envelope); they change no exit status:

- latency: control steps the measured velocity lags each change of the commanded velocity (the move and lead-in
  phases; :func:`response_delay`: the part of the change not yet made, summed over the steps after it; 0 when the
  step after the state a command answers runs at it), the median, against ``action_delay``;
- rate jitter: std and 95th percentile of the deviation of the period between states (by arrival); the latency
  plus that percentile in steps against ``action_delay`` again;
- speed: the moves' measured speed over the commanded (as 'obey' measures it) against ``velocity_gain``;
- closure lag: the first-order time constant with which the closure follows the close/open commands, on top of the
  latency, against ``closure_lag``;
- image noise: ``dlo_perception.vision`` on the images of the hold-still phase (the camera at vision_node's default
  position): the std of y_V and theta_V and the share of images losing (or finding) the cable, against
  ``vision_offset_noise``, ``vision_angle_noise``, ``vision_dropout`` (``vision_false_visible``). It needs no
  ground truth: nothing moves, so any spread is the camera's and the segmentation's.

The rules are plain functions of a :class:`Recording` (no rclpy: testable without ROS); the node
that makes the recording is :func:`record`. Exit status: 0 every rule passed (or was skipped),
1 a rule failed, no driver answered within ``--timeout`` or another node commands the driver,
2 bad usage, 130 interrupted. The whole check takes
about ``--duration`` + 12 s.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np
from dlo_common import taichi_runtime  # noqa: F401 (before the image noise imports Taichi: its banner stays off stdout)
from dlo_common.console import console_main
from dlo_common.topics import SERVICES, message_class, select
from dlo_common.topics import topic as topic_record
from dlo_interface.camera import IMAGE_BACKGROUND, IMAGE_CABLE, IMAGE_GRIPPER
from dlo_interface.cloud import FIELD_NAMES, FLOAT32, POINT_STEP, unpack_particles
from dlo_interface.command import MAX_SPEED
from dlo_interface.world import CONTROL_PERIOD, GRIPPER_HEIGHT, WORKSPACE_HALF_WIDTH
from dlo_perception.sync import format_stamp

from dlo_driver_kit import envelope as shipped

RULES = ("rate", "stamps", "sync", "camera", "obey", "invalid", "stale", "workspace", "touch")
CONTROL_RATE = 1.0 / CONTROL_PERIOD  # Hz, one command per 0.08 s
RATE_TOLERANCE = 0.2  # relative
SPEED_TOLERANCE = 0.2  # relative
ANGLE_TOLERANCE = 15.0  # deg
CLOSURE_TOLERANCE = 0.05
STEP_AWAY = 0.5  # control periods: an input carrying a state's stamp arriving this far from the state belongs to
# another step (a driver publishes a step's messages together, the state last)
STEP_AWAY_SHARE = 0.25  # of the matched states: more than this many such arrivals fail 'sync' (not one hiccup)
SERVICE_RESET = next(sv for sv in SERVICES if sv.name == "/dlo/sim/reset")
STILL = 0.0005  # m per step: the gripper counts as not moving below this
WORKSPACE_SLACK = 0.001  # m
PIPELINE_SLACK = 0.1  # s of delivery on top of two control periods for the stale stop
REACT_PERIODS = 2  # control periods an invalid command may take to stop the gripper (the pipeline, as for 'stale')
ENCODING_BYTES = {
    "mono8": 1,
    "8UC1": 1,
    "mono16": 2,
    "16UC1": 2,
    "rgb8": 3,
    "bgr8": 3,
    "8UC3": 3,
    "rgba8": 4,
    "bgra8": 4,
    "32FC1": 4,
}
SEGMENTATION = (IMAGE_BACKGROUND, IMAGE_GRIPPER, IMAGE_CABLE)  # the pixel values vision_node reads
QUEUE_DEPTH = 100  # the checker's subscriptions: no message lost while it is busy (sync needs every one)
# The topics a robot driver publishes (those with a driver's part in dlo_common.topics, the command aside): the
# checker records each of them
DRIVER_TOPICS = tuple(t for t in select(exclude=("command",)) if t.driver)


@dataclass(frozen=True)
class Settings:
    """What the driver is expected to do (the defaults are the sim's numbers)."""

    rate: float = CONTROL_RATE  # Hz
    command_timeout: float = 0.5  # s
    workspace: float = WORKSPACE_HALF_WIDTH  # m, half width of the square workspace
    duration: float = 2.0  # s of holding still (rate, stamps, camera, touch)
    speed: float = 0.1  # m/s of the valid motion commands
    skip: tuple = ()


@dataclass(frozen=True)
class Phase:
    """``duration`` s of one command (vx, vy, closure), or of silence (``command`` None).

    ``kind``: 'idle', 'closure', 'move', 'silent' (stale check), 'workspace', 'invalid', 'lead'
    (a valid moving command just before an invalid one or the silence).
    """

    name: str
    kind: str
    duration: float
    command: tuple | None


def schedule(s: Settings) -> list[Phase]:
    """The phases of one check, in order."""
    v, fast = s.speed, MAX_SPEED
    corner_time = 2.0 * s.workspace / fast + 0.3  # from anywhere in the workspace to the corner
    invalid = max(0.6, (REACT_PERIODS + 4) / s.rate)  # s: steps for 'invalid' to judge after the allowance, at any --rate
    return [
        Phase("idle", "idle", s.duration, (0.0, 0.0, 0.0)),
        Phase("close", "closure", 0.6, (0.0, 0.0, 1.0)),
        Phase("open", "closure", 0.6, (0.0, 0.0, 0.0)),
        Phase("+x", "move", 0.8, (v, 0.0, 0.0)),
        Phase("+y", "move", 0.8, (0.0, v, 0.0)),
        Phase("-y", "move", 0.8, (0.0, -v, 0.0)),
        Phase("lead-stale", "lead", 0.4, (v, 0.0, 0.0)),
        Phase("silent", "silent", s.command_timeout + 1.0, None),
        Phase("corner", "workspace", corner_time, (fast, fast, 0.0)),
        Phase("lead-nan", "lead", 0.4, (-v, -v, 0.0)),
        Phase("nan", "invalid", invalid, (math.nan, 0.0, 0.0)),
        Phase("lead-speed", "lead", 0.4, (-v, -v, 0.0)),
        Phase("speed", "invalid", invalid, (-3.0 * fast, 0.0, 0.0)),
        Phase("lead-closure", "lead", 0.4, (-v, -v, 0.0)),
        Phase("closure", "invalid", invalid, (0.0, 0.0, 1.5)),
        Phase("reset", "reset", 0.8, (0.0, 0.0, 0.0)),  # /dlo/sim/reset at its start, then hold still
    ]


@dataclass
class StateSample:
    """One received gripper state: wall arrival time [s], header stamp [s], counters, pose [m];
    ``stamp_ns``: the exact stamp [ns] (default: ``stamp`` rounded)."""

    wall: float
    stamp: float
    episode: int
    step: int
    x: float
    y: float
    closure: float
    stamp_ns: int | None = None
    z: float = GRIPPER_HEIGHT  # m

    def __post_init__(self):
        if self.stamp_ns is None:
            self.stamp_ns = int(round(self.stamp * 1e9))


@dataclass
class ImageSample:
    width: int
    height: int
    encoding: str
    step: int
    size: int
    frame_id: str
    stamp_ns: int = 0
    values: tuple = ()  # the distinct pixel values of a mono8 image (empty for other encodings)
    wall: float | None = None  # arrival time [s] (None: unknown)
    pixels: np.ndarray | None = None  # (height, width) uint8 of a mono8 image (None: not kept), for the image noise


@dataclass
class CloudSample:
    """One particle cloud: its stamp [ns], field names and what keeps tactile_node from reading it (None: nothing)."""

    stamp_ns: int
    fields: list
    problem: str | None = None
    wall: float | None = None  # arrival time [s] (None: unknown)


@dataclass
class InfoSample:
    width: int
    height: int
    k: tuple
    frame_id: str


@dataclass
class Recording:
    """What the checker saw. ``answered``: (episode, step) -> name of the phase whose command
    answered that state; ``phases``: (name, wall start, wall end); ``last_command_wall``: wall
    time of the last command sent before the silence."""

    states: list = field(default_factory=list)
    images: list = field(default_factory=list)
    infos: list = field(default_factory=list)
    answered: dict = field(default_factory=dict)
    phases: list = field(default_factory=list)
    clouds: list = field(default_factory=list)  # CloudSample of each particle cloud received
    tactile_stamps: list = field(default_factory=list)  # stamp [ns] of each tactile pose received
    tactile_walls: list = field(default_factory=list)  # its arrival time [s] (empty: unknown)
    last_command_wall: float | None = None
    # a driver topic of the registry without a recorder here (a modality added later): {topic: ([stamp ns], [arrival
    # s])}, judged by 'sync' as the image is (a rule of its own for it: add a recorder and a check)
    others: dict = field(default_factory=dict)
    reset: str | None = None  # the episode start the checker asked for: None not asked (no /dlo/sim/reset),
    # "started" (the service said so), else what went wrong


@dataclass(frozen=True)
class Result:
    rule: str
    status: str  # PASS, FAIL, SKIP
    reason: str

    @property
    def passed(self) -> bool:
        return self.status != "FAIL"


# ---------------------------------------------------------------------------------------- helpers
def phase_window(rec: Recording, name: str) -> tuple[float, float] | None:
    for n, start, end in rec.phases:
        if n == name:
            return start, end
    return None


def steps_in(rec: Recording, names, react: int = 1) -> list[tuple[StateSample, StateSample]]:
    """Consecutive state pairs (k, k+1) of one episode that certainly ran under a command of one
    of the phases ``names``: the commands answering k, k-1, ..., k-``react`` all came from that phase
    (the driver acts on the latest command it has: the one answering k, or an older one when
    commands reach it up to ``react`` control periods late)."""
    names = {names} if isinstance(names, str) else set(names)
    pairs = []
    for a, b in zip(rec.states, rec.states[1:]):
        if b.episode != a.episode or b.step != a.step + 1:
            continue
        answers = acting(rec, a.episode, a.step, react)
        if len(answers) == 1 and answers <= names:
            pairs.append((a, b))
    return pairs


def acting(rec: Recording, episode: int, step: int, react: int) -> set:
    """The phases whose commands may move the gripper from state ``step`` of ``episode`` to the next one: those
    answering that state and the ``react`` states before it in the same episode (None for a state no command
    answered). A new episode starts without a command: a driver acts only on commands answering its current
    episode (``dlo_interface.command.command_mismatch``), so the step from a new episode's state 0 runs under the command
    answering state 0 (or none, holding), whatever answered the previous episode's last states. A driver whose
    episodes end every few steps (the sim under the authors' task rules, moved sideways) is judged on these steps."""
    return {rec.answered.get((episode, step - back)) for back in range(min(react, step) + 1)}


def first_answered(rec: Recording, name: str, episode: int) -> StateSample:
    """The first state of ``episode`` that a command of phase ``name`` answered (measured before it was sent)."""
    return next(x for x in rec.states if x.episode == episode and rec.answered.get((x.episode, x.step)) == name)


def typical_period(rec: Recording, clock: str = "stamp") -> float:
    """Median difference of consecutive states' ``clock`` ('stamp' or 'wall') [s] (the driver's own period):
    between consecutive steps of one episode (an episode's last state and the next one's state 0 may come
    together, as from the sim: a driver whose episodes end every step or two would otherwise show half its
    period), or of any consecutive states when fewer than 3 such steps exist (a broken step counter)."""
    pairs = list(zip(rec.states, rec.states[1:]))
    steps = [(a, b) for a, b in pairs if b.episode == a.episode and b.step == a.step + 1]
    dt = [
        getattr(b, clock) - getattr(a, clock)
        for a, b in (steps if len(steps) >= 3 else pairs)
        if getattr(b, clock) > getattr(a, clock)
    ]
    return float(np.median(dt)) if dt else 1.0 / CONTROL_RATE


def motion_clock(rec: Recording) -> str:
    """Which time measures the driver's motion: 'stamp' (the state's stamp, exact) when at least half of the
    consecutive steps have a stamp difference of 0.5 to 2 arrival periods, else 'wall' (arrival time), so
    that broken stamps fail 'stamps' only, not also 'obey'."""
    pairs = [(a, b) for a, b in zip(rec.states, rec.states[1:]) if b.episode == a.episode and b.step == a.step + 1]
    if not pairs:
        return "stamp"
    period = typical_period(rec, "wall")
    usable = sum(1 for a, b in pairs if 0.5 * period <= b.stamp - a.stamp <= 2 * period)
    return "stamp" if usable >= 0.5 * len(pairs) else "wall"


def judged_states(rec: Recording) -> list:
    """The states received before the schedule ended: the checker kept listening after them, so the
    step's other messages had time to arrive."""
    end = rec.phases[-1][2] if rec.phases else math.inf
    return [x for x in rec.states if x.wall <= end]


def cloud_layout_problem(msg) -> str | None:
    """What keeps tactile_node from reading this PointCloud2 (``dlo_interface.cloud``), or None."""
    fields = [(f.name, int(f.offset), int(f.datatype), int(f.count)) for f in msg.fields]
    want = [(name, 4 * i, FLOAT32, 1) for i, name in enumerate(FIELD_NAMES)]
    if fields != want or msg.is_bigendian:
        return (
            f"fields {[f[0] for f in fields]} (offset, datatype, count {[f[1:] for f in fields]})"
            f"{', big endian' if msg.is_bigendian else ''}; tactile_node reads {list(FIELD_NAMES)} as "
            f"little-endian FLOAT32 at offsets 0, 4, 8, 12, point_step {POINT_STEP}"
        )
    if len(msg.data) < int(msg.width) * int(msg.height) * POINT_STEP:
        return f"{len(msg.data)} bytes for {int(msg.width) * int(msg.height)} points of {POINT_STEP} bytes"
    try:
        unpack_particles(msg)  # what tactile_node does with it
    except ValueError as error:
        return str(error)
    return None


def moved(a: StateSample, b: StateSample) -> float:
    return math.hypot(b.x - a.x, b.y - a.y)


def finite(s: StateSample) -> bool:
    return all(math.isfinite(v) for v in (s.x, s.y, s.closure))


# ---------------------------------------------------------------------------------------- rules
def check_rate(rec: Recording, s: Settings) -> Result:
    window = phase_window(rec, "idle")
    idle = [x for x in rec.states if window and window[0] <= x.wall <= window[1]]
    if len(idle) < 3:
        return Result(
            "rate",
            "FAIL",
            f"{len(idle)} states in {s.duration:g} s of holding still "
            f"(expected about {s.rate * s.duration:.0f}): is the driver real-time?",
        )
    # the period between consecutive steps of one episode, over the whole check (robust to a burst of
    # queued states at the start and to the extra state an episode reset adds); a new episode's state 0 comes
    # when the previous episode ended (the sim publishes it right after the final state), off the driver's tick:
    # the steps from it are left out when enough others remain (episodes that end every step or two)
    steps = [(a, b) for a, b in zip(rec.states, rec.states[1:]) if b.episode == a.episode and b.step == a.step + 1]
    ticked = [(a, b) for a, b in steps if a.step > 0]
    gaps = [b.wall - a.wall for a, b in (ticked if len(ticked) >= 3 else steps)]
    stamp_gaps = [
        b.stamp - a.stamp for a, b in zip(rec.states, rec.states[1:]) if b.episode == a.episode and b.step == a.step + 1
    ]
    if len(gaps) < 3:
        return Result("rate", "FAIL", f"{len(gaps)} consecutive steps in {len(rec.states)} states")
    rate = 1.0 / max(float(np.median(gaps)), 1e-9)
    if all(g > 0 for g in stamp_gaps):
        by_stamps = f"{1.0 / float(np.median(stamp_gaps)):.2f} Hz by stamps"
    else:  # the stamps are judged by 'stamps', not here
        by_stamps = "no rate by stamps: they do not strictly increase, see 'stamps'"
    ok = abs(rate - s.rate) <= RATE_TOLERANCE * s.rate
    return Result(
        "rate",
        "PASS" if ok else "FAIL",
        f"{rate:.2f} Hz ({by_stamps}; median of {len(gaps)} steps), expected {s.rate:g} Hz +-{RATE_TOLERANCE:.0%}",
    )


def check_stamps(rec: Recording, s: Settings) -> Result:
    if len(rec.states) < 2:
        return Result("stamps", "FAIL", f"only {len(rec.states)} state(s) received")
    back = jumps = bad_episode = episodes = 0
    first_bad = ""
    for a, b in zip(rec.states, rec.states[1:]):
        if not b.stamp_ns > a.stamp_ns:
            back += 1
            first_bad = first_bad or f"stamp {format_stamp(b.stamp_ns)} s after {format_stamp(a.stamp_ns)} s"
        if b.episode == a.episode:
            if b.step != a.step + 1:
                jumps += 1
                first_bad = first_bad or f"step {a.step} -> {b.step} in episode {a.episode}"
        elif b.episode > a.episode and b.step == 0:
            episodes += 1
        else:
            bad_episode += 1
            first_bad = first_bad or f"episode {a.episode} step {a.step} -> episode {b.episode} step {b.step}"
    n = len(rec.states)
    if back or jumps or bad_episode:
        return Result(
            "stamps",
            "FAIL",
            f"{back} non-increasing stamp(s), {jumps} step jump(s), {bad_episode} bad "
            f"episode change(s) in {n} states; first: {first_bad}",
        )
    if rec.reset == "started" and not episodes:
        return Result(
            "stamps",
            "FAIL",
            f"{n} states, none of a new episode after /dlo/sim/reset said it started one "
            "(publish the new episode's step 0 state)",
        )
    if rec.reset not in (None, "started"):
        return Result("stamps", "FAIL", f"/dlo/sim/reset: {rec.reset}")
    note = (
        ""
        if episodes
        else " (no new episode seen: the driver serves no /dlo/sim/reset, so stamps across an episode start were not judged)"
    )
    return Result(
        "stamps", "PASS", f"{n} states: stamps strictly increasing, step +1 each ({episodes} new episode(s) from step 0){note}"
    )


def check_camera(rec: Recording, s: Settings) -> Result:
    if not rec.infos:
        return Result(
            "camera",
            "FAIL",
            f"no camera_info ({len(rec.images)} images): publish it latched (transient local) in the image's frame",
        )
    info = rec.infos[-1]
    k = np.asarray(info.k, dtype=float).reshape(-1)
    problems = []
    if info.width <= 0 or info.height <= 0:
        problems.append(f"camera_info size {info.width}x{info.height}")
    if (
        k.size != 9
        or not np.all(np.isfinite(k))
        or k[0] <= 0
        or k[4] <= 0
        or not 0 < k[2] < info.width
        or not 0 < k[5] < info.height
        or abs(k[8] - 1.0) > 1e-9
    ):
        problems.append(f"K {k.round(2).tolist()} is not a pinhole matrix with fx, fy > 0 and the centre in the image")
    if not info.frame_id:
        problems.append("camera_info has no frame_id")
    if not rec.images:
        problems.append("no image on /dlo/camera/image")
    encodings = sorted({im.encoding for im in rec.images} - {"mono8"})
    if encodings:
        problems.append(f"encoding {', '.join(encodings)}: vision_node reads mono8 segmentation images only")
    values = sorted({int(v) for im in rec.images for v in im.values})
    odd = [v for v in values if v not in SEGMENTATION]
    if odd:
        problems.append(
            f"pixel values {odd[:5]}{' ...' if len(odd) > 5 else ''}: a segmented image has only "
            f"{IMAGE_BACKGROUND} (background), {IMAGE_GRIPPER} (gripper), {IMAGE_CABLE} (cable)"
        )
    elif rec.images and not encodings and IMAGE_CABLE not in values:
        problems.append(f"no cable ({IMAGE_CABLE}) in any of {len(rec.images)} images: vision_node never sees it")
    for im in rec.images:
        if (im.width, im.height) != (info.width, info.height):
            problems.append(f"image {im.width}x{im.height} but camera_info {info.width}x{info.height}")
            break
        if im.frame_id != info.frame_id:
            problems.append(f"image frame '{im.frame_id}' but camera_info frame '{info.frame_id}'")
            break
        bpp = ENCODING_BYTES.get(im.encoding, 1)
        if im.step < im.width * bpp or im.size != im.step * im.height:
            problems.append(
                f"image data {im.size} bytes for {im.height} rows of step {im.step} ({im.encoding}, width {im.width})"
            )
            break
    if problems:
        return Result("camera", "FAIL", "; ".join(problems))
    return Result(
        "camera",
        "PASS",
        f"{len(rec.images)} mono8 segmented images for {len(rec.states)} states, "
        f"{info.width}x{info.height} "
        f"in '{info.frame_id}', fx {k[0]:.1f} fy {k[4]:.1f} px",
    )


def check_obey(rec: Recording, s: Settings) -> Result:
    clock = motion_clock(rec)  # the stamps, unless they are broken (that is 'stamps'' to judge)
    period = typical_period(rec, clock)
    parts, problems = [], []
    for phase in schedule(s):
        if phase.kind == "move":
            v, usable = phase_velocity(rec, phase, clock, period)
            if v is None:
                problems.append(f"{phase.name}: {usable} usable step(s) (states missing, or not half to twice a period apart)")
                continue
            want = np.asarray(phase.command[:2])
            speed, target = float(np.linalg.norm(v)), float(np.linalg.norm(want))
            # the angle between the unit vectors: any commanded speed > 0 is judged alike, however small
            angle = math.degrees(math.acos(np.clip((v / speed) @ (want / target), -1, 1))) if speed > 0 and target > 0 else 180.0
            text = f"{phase.name} {speed:.3f} m/s at {angle:.0f} deg"
            parts.append(text)
            if abs(speed - target) > SPEED_TOLERANCE * target or angle > ANGLE_TOLERANCE:
                problems.append(f"{text} (commanded {target:g} m/s)")
        elif phase.kind == "closure":
            pairs = steps_in(rec, phase.name)
            if not pairs:
                problems.append(f"{phase.name}: no state under the command")
                continue
            got, want = pairs[-1][1].closure, phase.command[2]
            parts.append(f"closure {got:.2f}")
            if not abs(got - want) <= CLOSURE_TOLERANCE:
                problems.append(f"closure {got:.2f} after commanding {want:g} for {phase.duration:g} s")
    timed = "" if clock == "stamp" else "; timed by arrival: the stamps are unusable"
    if problems:
        return Result("obey", "FAIL", "; ".join(problems) + timed)
    return Result("obey", "PASS", ", ".join(parts) + f" (commanded {s.speed:g} m/s; closure 1, 0{timed})")


def phase_velocity(rec: Recording, phase: Phase, clock: str, period: float) -> tuple:
    """(median velocity (vx, vy) [m/s] over the steps run under ``phase``'s command, usable steps), timed by
    ``clock`` over steps half to twice ``period`` apart; (None, usable) with fewer than 2 usable steps."""
    dt = [(a, b, getattr(b, clock) - getattr(a, clock)) for a, b in steps_in(rec, phase.name)]
    pairs = [(a, b, t) for a, b, t in dt if 0.5 * period <= t <= 2 * period]
    if len(pairs) < 2:
        return None, len(pairs)
    return np.median([[(b.x - a.x) / t, (b.y - a.y) / t] for a, b, t in pairs], axis=0), len(pairs)


def check_invalid(rec: Recording, s: Settings) -> Result:
    parts, problems = [], []
    for phase in schedule(s):
        if phase.kind != "invalid":
            continue
        pairs = steps_in(rec, phase.name, react=REACT_PERIODS)
        # any state that may show an invalid command executed (judged or not): none may be non-finite
        bad = [x for x in rec.states if not finite(x) and phase.name in acting(rec, x.episode, x.step - 1, REACT_PERIODS)]
        if bad:
            problems.append(f"{phase.name}: state became non-finite (x = {bad[0].x}, closure = {bad[0].closure})")
            continue
        if len(pairs) < 2:
            problems.append(f"{phase.name}: {len(pairs)} usable step(s)")
            continue
        step = max(moved(a, b) for a, b in pairs)
        # against the closure measured before the phase's first command of the state's episode was sent
        before = {e: first_answered(rec, phase.name, e).closure for e in {x.episode for pair in pairs for x in pair}}
        closure = max(abs(x.closure - before[x.episode]) for pair in pairs for x in pair)
        text = f"{phase.name} {step * 1000:.2f} mm/step, closure {closure:+.3f}"
        parts.append(text)
        if step > STILL or closure > 0.02:
            problems.append(f"{text}: not rejected (commanded {phase.command})")
    if problems:
        return Result("invalid", "FAIL", "; ".join(problems))
    return Result("invalid", "PASS", "gripper held (largest step, closure change): " + ", ".join(parts))


def check_stale(rec: Recording, s: Settings) -> Result:
    window = phase_window(rec, "silent")
    if window is None or rec.last_command_wall is None:
        return Result("stale", "FAIL", "the silent phase did not run")
    t0, end = rec.last_command_wall, window[1]
    period = 1.0 / s.rate
    before = [
        (a, b)
        for a, b in zip(rec.states, rec.states[1:])
        if a.episode == b.episode and b.step == a.step + 1 and window[0] - 0.4 <= b.wall <= t0 + 0.5 * period
    ]
    if not any(moved(a, b) > STILL for a, b in before):
        return Result("stale", "FAIL", "the gripper did not move under the last command before the silence (cannot see it stop)")
    after = [(a, b) for a, b in zip(rec.states, rec.states[1:]) if t0 < b.wall <= end]
    limit = s.command_timeout + 2 * max(period, typical_period(rec)) + PIPELINE_SLACK
    late = [b for a, b in after if b.wall > t0 + limit]
    if len(late) < 2:
        return Result(
            "stale",
            "FAIL",
            f"{len(late)} states between {limit:.2f} s and {end - t0:.2f} s after the last "
            "command: a real-time driver keeps publishing its state",
        )
    moving = [b.wall for a, b in after if moved(a, b) > STILL and b.episode == a.episode]  # not a reset's jump
    stop = (max(moving) - t0) if moving else 0.0
    if stop > limit:
        return Result(
            "stale",
            "FAIL",
            f"still moving {stop:.2f} s after the last command (command_timeout {s.command_timeout:g} s, allowed {limit:.2f} s)",
        )
    return Result(
        "stale",
        "PASS",
        f"stopped {stop:.2f} s after the last command (command_timeout {s.command_timeout:g} s, allowed {limit:.2f} s)",
    )


def check_workspace(rec: Recording, s: Settings) -> Result:
    states = [x for x in rec.states if finite(x)]
    if not states:
        return Result("workspace", "FAIL", "no finite gripper state")
    worst = max(states, key=lambda x: max(abs(x.x), abs(x.y)))
    reach = max(abs(worst.x), abs(worst.y))
    if reach > s.workspace + WORKSPACE_SLACK:
        return Result(
            "workspace",
            "FAIL",
            f"gripper at x = {worst.x:.3f} m, y = {worst.y:.3f} m (step {worst.step}), outside |x|, |y| <= {s.workspace:g} m",
        )
    window = phase_window(rec, "corner")
    corner = [x for x in states if window and window[0] <= x.wall <= window[1]]
    where = ""
    if corner:
        last = corner[-1]
        at = max(last.x, last.y) >= s.workspace - 0.002
        where = (
            f"; driven to the corner it stopped at the boundary (x = {last.x:.3f}, y = {last.y:.3f} m)"
            if at
            else f"; driven to the corner it ended at x = {last.x:.3f}, y = {last.y:.3f} m, short of the boundary"
        )
    return Result(
        "workspace", "PASS", f"all {len(states)} states inside |x|, |y| <= {s.workspace:g} m (largest {reach:.3f} m){where}"
    )


def check_touch(rec: Recording, s: Settings) -> Result:
    bad = [c for c in rec.clouds if c.problem]
    if bad:
        return Result(
            "touch", "FAIL", f"{len(bad)} of {len(rec.clouds)} particle clouds unreadable for tactile_node: {bad[0].problem}"
        )
    if rec.clouds:
        return Result(
            "touch",
            "PASS",
            f"{len(rec.clouds)} particle clouds in the layout tactile_node reads "
            f"({', '.join(FIELD_NAMES)}; 'held' flags the touched points)",
        )
    if rec.tactile_stamps:
        return Result("touch", "PASS", f"{len(rec.tactile_stamps)} tactile poses")
    return Result(
        "touch", "FAIL", "no tactile source: neither /dlo/rope/particles (contact points flagged 'held') nor /dlo/tactile/pose"
    )


def check_sync(rec: Recording, s: Settings) -> Result:
    """Every state's exact stamp on the step's image and tactile source (what the nodes match on)."""
    states = judged_states(rec)
    if not states:
        return Result("sync", "FAIL", "no state received before the end of the check")
    inputs = [
        ("image", [im.stamp_ns for im in rec.images]),
        ("particle cloud", [c.stamp_ns for c in rec.clouds]),
        ("tactile pose", rec.tactile_stamps),
    ]
    walls = {
        "image": [im.wall for im in rec.images],
        "particle cloud": [c.wall for c in rec.clouds],
        "tactile pose": rec.tactile_walls,
    }
    for name, (stamps, arrivals) in rec.others.items():
        inputs.append((f"{name} message", stamps))
        walls[f"{name} message"] = arrivals
    present = [(name, stamps) for name, stamps in inputs if stamps]
    absent = [("image", "camera")] if not rec.images else []  # an input never published is another rule's
    absent += [("tactile source", "touch")] if not rec.clouds and not rec.tactile_stamps else []
    note = f" (no {' and no '.join(n for n, _ in absent)} to match: see {', '.join(r for _, r in absent)})" if absent else ""
    failing = {}  # (unmatched, judged, first unmatched state, nearby stamps) -> input names: alike in one phrase
    for name, stamps in present:
        have, start = set(stamps), min(stamps)
        judged = [x for x in states if x.stamp_ns >= start]  # earlier: before the checker's subscription matched
        unmatched = [x for x in judged if x.stamp_ns not in have]
        if unmatched:
            first = unmatched[0]
            near = tuple(sorted(sorted(have, key=lambda t: (abs(t - first.stamp_ns), t))[:2]))
            failing.setdefault((len(unmatched), len(judged), first.stamp_ns, first.step, near), []).append(name)
    problems = []
    for (count, judged, first_ns, step, near), names in failing.items():
        off = min(near, key=lambda t: abs(t - first_ns)) - first_ns
        what = " and ".join(names)
        problems.append(
            f"{count} of {judged} states have no {' and no '.join(names)} with their exact stamp; "
            f"first: step {step} at {format_stamp(first_ns)} s, {what} stamps "
            f"{', '.join(format_stamp(t) for t in near)} nearby (the nearest {abs(off) / 1e3:g} us "
            f"{'later' if off > 0 else 'earlier'})"
        )
    problems += [p for name, stamps in present if (p := step_away(name, stamps, walls[name], states, rec))]
    if problems:
        return Result(
            "sync",
            "FAIL",
            "; ".join(problems) + ": stamp every message of a step with its state's "
            "stamp (tactile_node, vision_node and policy_node match a step's inputs by exact "
            "stamp and never run a step without all of them)" + note,
        )
    names = " and ".join(f"a{'n' if name[0] in 'aeiou' else ''} {name}" for name, _ in present)
    if not present:
        return Result("sync", "PASS", f"{len(states)} states, nothing else to match{note}")
    return Result(
        "sync",
        "PASS",
        f"{len(states)} states, each with {names} of its exact stamp (the perception "
        f"and policy nodes match a step by stamp){note}",
    )


def step_away(name: str, stamps: list, walls: list, states: list, rec: Recording) -> str | None:
    """What is wrong when the ``name`` messages carrying the states' stamps arrive a step away from their
    states (stamped with another step's stamp: the nodes would pair a state with another step's input), or None.
    ``walls``: the arrival time of each message (None: unknown, not judged). A stamp carried by several
    states or messages is not judged here (repeated stamps are 'stamps'' to judge)."""
    once = Counter(stamps)
    arrival = {stamp: wall for stamp, wall in zip(stamps, walls) if wall is not None and once[stamp] == 1}
    states_once = Counter(x.stamp_ns for x in states)
    offsets = [arrival[x.stamp_ns] - x.wall for x in states if x.stamp_ns in arrival and states_once[x.stamp_ns] == 1]
    if not offsets:
        return None
    period = typical_period(rec, "wall")
    away = [off for off in offsets if abs(off) > STEP_AWAY * period]
    if len(away) <= STEP_AWAY_SHARE * len(offsets):
        return None
    median = float(np.median(away))
    return (
        f"{len(away)} of {len(offsets)} states get the {name} carrying their stamp a step away: it arrives "
        f"{abs(median) * 1e3:.0f} ms {'after' if median > 0 else 'before'} the state (median; the control "
        f"period is {period * 1e3:.0f} ms), so it was measured in another step"
    )


CHECKS = {
    "rate": check_rate,
    "stamps": check_stamps,
    "sync": check_sync,
    "camera": check_camera,
    "obey": check_obey,
    "invalid": check_invalid,
    "stale": check_stale,
    "workspace": check_workspace,
    "touch": check_touch,
}


def evaluate(rec: Recording, s: Settings) -> list[Result]:
    """One Result per rule, in RULES order (skipped rules as SKIP)."""
    return [Result(rule, "SKIP", "skipped (--skip)") if rule in s.skip else CHECKS[rule](rec, s) for rule in RULES]


def format_results(results: list[Result]) -> str:
    return "\n".join(f"{r.status} {r.rule:<9} {r.reason}" for r in results)


# ---------------------------------------------------------------------------------------- against the shipped policy
RESPONSE_WINDOW = 5  # steps after a change of command over which the response is followed
RESPONSE_MIN_STEPS = 3  # a change followed for fewer steps (its episode ended) is not judged
STILL_IMAGES_MIN = 5  # images of the hold-still phase needed to estimate the image noise


def valid_command(command) -> bool:
    """A command the driver must execute (finite, speed and closure in range): what the responses are timed on."""
    return (
        command is not None
        and all(math.isfinite(v) for v in command)
        and math.hypot(command[0], command[1]) <= MAX_SPEED
        and 0.0 <= command[2] <= 1.0
    )


def response_delay(levels, before, after) -> float:
    """Control steps a response lags behind its command: the sum, over the steps after the change, of the part of
    the change from ``before`` to ``after`` not yet made (``levels``: the quantity per step, a velocity or a
    closure). A response d steps late counts d; a first-order lag of rate r per step (1 - r) / r."""
    levels, before, after = (np.atleast_1d(np.asarray(v, dtype=float)) for v in (levels, before, after))
    span = after - before
    done = np.clip(((levels.reshape(len(levels), -1) - before) @ span) / float(span @ span), 0.0, 1.0)
    return float(np.sum(1.0 - done))


def _by_step(rec: Recording) -> dict:
    return {(x.episode, x.step): x for x in rec.states}


def _changes(rec: Recording, s: Settings, kinds: tuple):
    """(phase, episode, k0) for each phase of ``kinds`` with a valid command and each episode it answered: k0 the
    first state of that episode it answered (the command changed there, or the episode started with it)."""
    for phase in schedule(s):
        if phase.kind not in kinds or not valid_command(phase.command):
            continue
        firsts = {}
        for (episode, step), name in rec.answered.items():
            if name == phase.name and step < firsts.get(episode, math.inf):
                firsts[episode] = step
        for episode, k0 in sorted(firsts.items()):
            yield phase, episode, k0


def motion_latency(rec: Recording, s: Settings) -> list[float]:
    """Command-to-state latency [control steps] of each change of the commanded velocity (the move and lead-in
    phases): how many steps the gripper's measured velocity lags the command answering state k0 (0: the step
    k0 -> k0 + 1 already runs at it, as in the simulator and the gym env). The velocity before is the step into k0
    (at rest at an episode's start), the velocity after the mean of the last two steps followed."""
    states, clock = _by_step(rec), motion_clock(rec)
    period = typical_period(rec, clock)
    delays = []
    for phase, episode, k0 in _changes(rec, s, ("move", "lead")):

        def velocity(k, episode=episode):
            a, b = states.get((episode, k)), states.get((episode, k + 1))
            t = None if a is None or b is None else getattr(b, clock) - getattr(a, clock)
            return None if t is None or not 0.5 * period <= t <= 2 * period else ((b.x - a.x) / t, (b.y - a.y) / t)

        levels = []
        for k in range(k0, k0 + RESPONSE_WINDOW):
            v = velocity(k) if rec.answered.get((episode, k)) == phase.name else None
            if v is None:
                break
            levels.append(v)
        before = (0.0, 0.0) if k0 == 0 else velocity(k0 - 1)
        if len(levels) < RESPONSE_MIN_STEPS or before is None:
            continue
        after = np.mean(levels[-2:], axis=0)
        change = np.asarray(phase.command[:2]) - np.asarray(before)
        if np.linalg.norm(after - before) < 0.25 * np.linalg.norm(change):  # it did not follow: 'obey' says so
            continue
        delays.append(response_delay(levels, before, after))
    return delays


def closure_delays(rec: Recording, s: Settings) -> list[tuple[float, int]]:
    """(control steps the measured closure lags, steps followed) for each change of the commanded closure (the
    close and open phases), as motion_latency: from the closure of state k0 to the commanded one, over the states
    k0 + 1, k0 + 2, ... the phase answered."""
    states, delays = _by_step(rec), []
    for phase, episode, k0 in _changes(rec, s, ("closure",)):
        levels = []
        for k in range(k0, k0 + 2 * RESPONSE_WINDOW):
            after = states.get((episode, k + 1))
            if rec.answered.get((episode, k)) != phase.name or after is None:
                break
            levels.append(after.closure)
        start, target = states.get((episode, k0)), phase.command[2]
        if len(levels) < RESPONSE_MIN_STEPS or start is None or abs(target - start.closure) < 0.25:
            continue
        delays.append((response_delay(levels, start.closure, target), len(levels)))
    return delays


def lag_time_constant(steps: float, followed: int, period: float) -> float:
    """The first-order time constant [s] whose response, followed over ``followed`` control steps of ``period`` s,
    lags ``steps`` (the closure lag of dlo_policy.perturbations: rate r = 1 - exp(-period / tau) per step lags
    (1 - r) / r (1 - (1 - r)^followed) over them); inf when it lags at least ``followed`` (no response seen)."""
    if steps <= 0:
        return 0.0
    if steps >= followed:
        return math.inf
    low, high = 1e-12, 1.0  # the lag falls as the rate rises

    def lag(rate):
        return (1.0 - rate) / rate * (1.0 - (1.0 - rate) ** followed)

    for _ in range(100):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if lag(middle) > steps else (low, middle)
    return -period / math.log(1.0 - 0.5 * (low + high))


def rate_jitter(rec: Recording) -> tuple:
    """(std, 95th percentile of |period - median period|) of the arrival times between consecutive steps [s], over
    the whole check (the steps from a new episode's state 0 left out, as 'rate'); (None, None) with < 3 steps."""
    steps = [(a, b) for a, b in zip(rec.states, rec.states[1:]) if b.episode == a.episode and b.step == a.step + 1]
    gaps = np.array([b.wall - a.wall for a, b in steps if a.step > 0] or [b.wall - a.wall for a, b in steps])
    if len(gaps) < 3:
        return None, None
    return float(np.std(gaps)), float(np.percentile(np.abs(gaps - np.median(gaps)), 95))


def velocity_gain(rec: Recording, s: Settings) -> float | None:
    """Measured speed / commanded speed, the median over the move phases ('obey''s velocities); None if none."""
    clock = motion_clock(rec)
    period = typical_period(rec, clock)
    gains = []
    for phase in schedule(s):
        if phase.kind == "move":
            v, _ = phase_velocity(rec, phase, clock, period)
            if v is not None:
                gains.append(float(np.linalg.norm(v)) / math.hypot(*phase.command[:2]))
    return float(np.median(gains)) if gains else None


def image_noise(rec: Recording) -> dict | None:
    """What the vision computation (dlo_perception.vision, as vision_node runs it, camera at its default position)
    reads from the images of the hold-still phase, where neither gripper nor cable moves: ``images`` judged,
    ``visible`` of them, the std of y_V [m] and theta_V [rad] over the visible ones (the image noise a camera adds
    on top of the simulator's clean render). None with fewer than STILL_IMAGES_MIN still mono8 images."""
    window = phase_window(rec, "idle")
    if window is None or not rec.infos:
        return None
    states = {x.stamp_ns: x for x in rec.states if window[0] <= x.wall <= window[1]}
    info = rec.infos[-1]
    still = [
        (im, states[im.stamp_ns])
        for im in rec.images
        if im.pixels is not None and im.stamp_ns in states and im.pixels.shape == (info.height, info.width)
    ]
    if len(still) < STILL_IMAGES_MIN:
        return None
    from dlo_interface.camera import TopCamera
    from dlo_perception.vision import visual_pose

    camera = TopCamera.from_camera_info(info.width, info.height, info.k, TopCamera.position)
    by_z = {}
    for im, x in still:  # one batch per gripper height (one in practice)
        by_z.setdefault(x.z, []).append((im, x))
    visible, ys, angles = 0, [], []
    for z, group in by_z.items():
        pose = visual_pose(np.stack([im.pixels for im, _ in group]), camera, np.array([[x.x, x.y] for _, x in group]), z)
        visible += int(np.sum(pose.visible))
        ys += list(pose.y[pose.visible])
        angles += list(pose.angle[pose.visible])
    spread = len(ys) >= 2
    return {
        "images": len(still),
        "visible": visible,
        "y_std": float(np.std(ys)) if spread else None,
        "angle_std": float(np.std(angles)) if spread else None,
    }


def steps_text(value: float) -> str:
    return f"{value:.1f} step{'' if round(value, 1) == 1 else 's'}"


def envelope_lines(rec: Recording, s: Settings, envelope: dict | None, why: str = "") -> list[str]:
    """The driver's measured timing, actuation and image noise, each against the shipped policy's 80% tolerance of
    the perturbation family it amounts to (dlo_driver_kit.envelope); a line for what could not be measured."""
    lines = []
    period = 1.0 / s.rate
    delays = motion_latency(rec, s)
    latency = float(np.median(delays)) if delays else None
    if latency is None:
        lines.append("latency: not measured (no change of the commanded velocity followed for 3 steps of one episode)")
    else:
        text = (
            f"latency {steps_text(latency)} (command to state: median of {len(delays)} changes of command, "
            f"largest {max(delays):.1f})"
        )
        lines.append(shipped.compare(envelope, "action_delay", latency, text, "steps of delay", why))
    std, p95 = rate_jitter(rec)
    if std is None:
        lines.append("rate jitter: not measured (fewer than 3 consecutive steps)")
    else:
        late = (latency or 0.0) + p95 / period
        text = (
            f"rate jitter {std * 1e3:.1f} ms (std of the period between states; 95% within {p95 * 1e3:.1f} ms = "
            f"{p95 / period:.2f} steps; latency with it {late:.2f} steps)"
        )
        lines.append(shipped.compare(envelope, "action_delay", late, text, "steps of delay", why))
    gain = velocity_gain(rec, s)
    if gain is not None:
        lines.append(shipped.compare_gain(envelope, gain, f"speed {gain:.2f}x the commanded (median of the moves)", why))
    closure = closure_delays(rec, s)
    if closure:
        delay, followed = min(closure, key=lambda c: abs(c[0] - float(np.median([d for d, _ in closure]))))
        lag = max(delay - (latency or 0.0), 0.0)  # the closure's own lag, on top of the command's latency
        tau = lag_time_constant(lag, followed - round(latency or 0.0), period)
        text = f"closure lag {tau:.2f} s (first-order time constant: the closure follows {lag:.1f} steps after the motion)"
        lines.append(shipped.compare(envelope, "closure_lag", tau, text, "s", why))
    noise = image_noise(rec)
    if noise is None:
        lines.append(f"image noise: not estimated (fewer than {STILL_IMAGES_MIN} mono8 images while holding still)")
    else:
        seen = f"over {noise['images']} images holding still, the cable seen in {noise['visible']}"
        if noise["y_std"] is not None:
            text = f"image noise {noise['y_std'] * 1e3:.1f} mm on y_V (std {seen})"
            lines.append(shipped.compare(envelope, "vision_offset_noise", noise["y_std"] * 1e3, text, "mm", why))
            text = f"image noise {math.degrees(noise['angle_std']):.1f} deg on theta_V (std {seen})"
            lines.append(shipped.compare(envelope, "vision_angle_noise", math.degrees(noise["angle_std"]), text, "deg", why))
        mostly = noise["visible"] >= noise["images"] / 2
        flicker = (noise["images"] - noise["visible"] if mostly else noise["visible"]) / noise["images"]
        family = "vision_dropout" if mostly else "vision_false_visible"
        what = "lost" if mostly else "reported"
        count = round(flicker * noise["images"])
        text = f"detection flicker {flicker:.0%} (the cable {what} in {count} of {noise['images']} still images)"
        lines.append(shipped.compare(envelope, family, flicker, text, "", why))
    return lines


# ---------------------------------------------------------------------------------------- ROS part
class CheckError(RuntimeError):
    """The check cannot run (one line for the user)."""


def check_alone(node, topic: str) -> None:
    """Raise CheckError when another node publishes the command topic (a policy would mix its commands in)."""
    import rclpy

    named_by = time.monotonic() + 2.0  # endpoints are discovered before their nodes' names
    while node.count_publishers(topic) > 1:
        infos = [i for i in node.get_publishers_info_by_topic(topic) if i.node_name != node.get_name()]
        others = [f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in infos]
        if not any("_UNKNOWN_" in name for name in others) or time.monotonic() > named_by:
            raise CheckError(
                f"another node commands the driver ({', '.join(others) or 'unknown'} publishes {topic}): "
                "stop it (the policy) before the check"
            )
        rclpy.spin_once(node, timeout_sec=0.05)


def _image_sample(msg, stamp: int) -> ImageSample:
    """What the check keeps of an image (stamped ``stamp`` [ns]), received now: its layout and, for mono8, the pixel
    values vision_node will see (row padding left out) and the pixels."""
    values, pixels = (), None
    if msg.encoding == "mono8":  # the pixel values vision_node will see (row padding left out)
        data = np.frombuffer(bytes(msg.data), np.uint8)
        if msg.step >= msg.width and data.size == msg.height * msg.step:
            data = pixels = data.reshape(msg.height, msg.step)[:, : msg.width].copy()
        values = tuple(int(v) for v in np.unique(data))
    return ImageSample(
        int(msg.width),
        int(msg.height),
        msg.encoding,
        int(msg.step),
        len(msg.data),
        msg.header.frame_id,
        stamp,
        values,
        time.monotonic(),
        pixels,
    )


def record(s: Settings, namespace: str, timeout: float, log=print) -> Recording | None:
    """Run the schedule against the driver on the current ROS domain; None when no state arrives
    within ``timeout`` s."""
    import rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile

    GripperCommand = message_class(topic_record("command").type)
    prefix = "/" + namespace.strip("/") if namespace.strip("/") else ""
    rec = Recording()
    phases = schedule(s)
    current = {"index": -1}

    from rclpy.signals import SignalHandlerOptions

    rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)  # Ctrl-C: KeyboardInterrupt, one line
    node = rclpy.create_node("dlo_driver_check")
    try:
        pub = node.create_publisher(GripperCommand, prefix + topic_record("command").name, 10)

        def stamp_ns(msg) -> int:
            return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)

        def on_state(msg):
            sample = StateSample(
                time.monotonic(),
                msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec,
                int(msg.episode),
                int(msg.step),
                float(msg.x),
                float(msg.y),
                float(msg.closure),
                stamp_ns(msg),
                float(msg.z),
            )
            rec.states.append(sample)
            i = current["index"]
            if i < 0 or i >= len(phases) or phases[i].command is None:
                return
            vx, vy, closure = phases[i].command
            cmd = GripperCommand(vx=float(vx), vy=float(vy), closure=float(closure), episode=msg.episode, step=msg.step)
            cmd.header = msg.header
            pub.publish(cmd)
            rec.answered[(sample.episode, sample.step)] = phases[i].name
            rec.last_command_wall = time.monotonic()

        def on_image(msg):
            rec.images.append(_image_sample(msg, stamp_ns(msg)))

        def on_info(msg):
            rec.infos.append(InfoSample(int(msg.width), int(msg.height), tuple(msg.k), msg.header.frame_id))

        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        handlers = {
            "gripper": on_state,
            "image": on_image,
            "camera_info": on_info,
            "particles": lambda m: rec.clouds.append(
                CloudSample(stamp_ns(m), [f.name for f in m.fields], cloud_layout_problem(m), time.monotonic())
            ),
            "tactile": lambda m: (rec.tactile_stamps.append(stamp_ns(m)), rec.tactile_walls.append(time.monotonic())),
        }

        def on_other(name, msg):  # a driver topic without a recorder of its own: its stamps for 'sync'
            stamps, arrivals = rec.others.setdefault(name, ([], []))
            stamps.append(stamp_ns(msg))
            arrivals.append(time.monotonic())

        for t in DRIVER_TOPICS:  # what a driver may publish, each with its recorder (one per driver topic)
            handler = handlers.get(t.key, lambda m, name=t.name: on_other(name, m))
            node.create_subscription(
                message_class(t.type), prefix + t.name, handler, latched if t.rate == "latched" else QUEUE_DEPTH
            )

        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and (not rec.states or pub.get_subscription_count() == 0):
            rclpy.spin_once(node, timeout_sec=0.05)
        if not rec.states:
            return None
        check_alone(node, pub.topic_name)
        state_topic = prefix + topic_record("gripper").name
        log(
            f"driver found: {len(node.get_publishers_info_by_topic(state_topic))} publisher(s) of "
            f"{state_topic}; checking for about {sum(p.duration for p in phases):.0f} s"
        )
        rec.states.clear()
        silent_from = None
        ResetEpisode = message_class(SERVICE_RESET.type)
        reset_client = node.create_client(ResetEpisode, prefix + SERVICE_RESET.name)
        for i, phase in enumerate(phases):
            current["index"] = i
            start = time.monotonic()
            if phase.kind == "reset" and reset_client.service_is_ready():
                rec.reset = start_episode(node, reset_client, ResetEpisode.Request(seed=-1))
            end = start + phase.duration
            while time.monotonic() < end:
                rclpy.spin_once(node, timeout_sec=0.01)
            rec.phases.append((phase.name, start, time.monotonic()))
            check_alone(node, pub.topic_name)
            if phase.kind == "lead" and phases[i + 1].kind == "silent":
                silent_from = rec.last_command_wall
        current["index"] = len(phases)
        end = time.monotonic() + 0.2
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.01)
        rec.last_command_wall = silent_from
        return rec
    finally:
        from dlo_common.node_main import shut_down

        shut_down(node)  # a middleware teardown that hangs is cut (exit 1, stacks on stderr)


def start_episode(node, client, request, timeout: float = 5.0) -> str:
    """Ask the driver for a new episode (``/dlo/sim/reset``), spinning ``node`` meanwhile (states keep being
    answered): "started", or what went wrong."""
    import rclpy

    future = client.call_async(request)
    deadline = time.monotonic() + timeout
    while not future.done() and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.01)
    if not future.done():
        future.cancel()
        return f"no answer within {timeout:g} s"
    response = future.result()
    if response is None or not response.success:
        return f"refused ({getattr(response, 'message', '') or 'no reason given'})"
    return "started"


@console_main("dlo-driver-check")
def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="dlo-driver-check",
        description="Check the driver (or sim node in real_time mode) running on this ROS domain against the "
        "topic contract, rule by rule: " + ", ".join(RULES) + ". It sends commands to "
        "/dlo/gripper/cmd (the gripper moves about 0.6 m): nothing else may command the driver meanwhile.",
        epilog="Try it on the simulator first: 'ros2run dlo_sim sim_node --ros-args -p mode:=real_time &' then "
        "'dlo-driver-check' (9/9; docs/WRITE_YOUR_DRIVER.md). After the rules it compares the driver's latency, rate "
        "jitter, speed, closure lag and image noise with the shipped policy's robustness envelope (lines only). Exit "
        "status: 0 every rule passed, 1 a rule failed, no driver answered or another node commands the driver, 2 bad "
        "usage, 130 interrupted.",
    )
    parser.add_argument("--namespace", default="", help="topics under /NS/dlo/... (as launch_graph.sh --namespace)")
    parser.add_argument("--timeout", type=float, default=10.0, help="s to wait for the driver's first state (10)")
    parser.add_argument("--duration", type=float, default=2.0, help="s of holding still for rate/camera/touch (2)")
    parser.add_argument("--rate", type=float, default=CONTROL_RATE, help=f"expected control rate [Hz] ({CONTROL_RATE:g})")
    parser.add_argument(
        "--command-timeout",
        type=float,
        default=0.5,
        help="the driver's command_timeout [s]: a stale command must stop the gripper (0.5)",
    )
    parser.add_argument("--speed", type=float, default=0.1, help="speed of the test motions [m/s] (0.1)")
    parser.add_argument(
        "--workspace",
        type=float,
        default=WORKSPACE_HALF_WIDTH,
        help=f"half width of the square workspace [m] ({WORKSPACE_HALF_WIDTH:g})",
    )
    parser.add_argument(
        "--skip",
        action="append",
        default=[],
        choices=RULES,
        metavar="RULE",
        help=f"do not judge this rule (repeatable): one of {', '.join(RULES)}",
    )
    args = parser.parse_args(argv)
    for name in ("timeout", "duration", "rate", "command_timeout", "speed", "workspace"):
        if not getattr(args, name) > 0:
            parser.error(f"--{name.replace('_', '-')} must be > 0, got {getattr(args, name)}")
    if args.speed > MAX_SPEED:
        parser.error(f"--speed must be <= {MAX_SPEED:g} m/s (the command limit)")
    settings = Settings(
        rate=args.rate,
        command_timeout=args.command_timeout,
        workspace=args.workspace,
        duration=args.duration,
        speed=args.speed,
        skip=tuple(args.skip),
    )
    try:
        rec = record(settings, args.namespace, args.timeout)
    except CheckError as error:
        print(f"dlo-driver-check: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("dlo-driver-check: interrupted", file=sys.stderr)
        return 130
    if rec is None:
        topic = ("/" + args.namespace.strip("/") if args.namespace.strip("/") else "") + topic_record("gripper").name
        print(
            f"dlo-driver-check: no driver: nothing published {topic} within {args.timeout:g} s on "
            f"ROS_DOMAIN_ID={os.environ.get('ROS_DOMAIN_ID') or '0'} (is the driver running, on this domain "
            "and namespace, in real_time mode?)",
            file=sys.stderr,
        )
        return 1
    results = evaluate(rec, settings)
    print(format_results(results))
    failed = [r.rule for r in results if not r.passed]
    print(f"{len(results) - len(failed)}/{len(results)} rules passed" + (f"; failed: {', '.join(failed)}" if failed else ""))
    envelope, why = shipped.load()
    print(
        "Against the shipped policy's robustness envelope (what it tolerates before it holds the end in fewer than 80% "
        "of the episodes; docs/RESULTS.md#robustness-envelope):"
    )
    for line in envelope_lines(rec, settings, envelope, why):
        print(f"  {line}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
