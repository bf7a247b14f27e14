#!/usr/bin/env python3
"""Generate docs/INTERFACES.md, the interface reference of the dlo-vitac graph, from the code.

What is generated and from where:
- topics, types, publishers, subscribers and QoS (history/depth as the code requests them,
  reliability/durability as DDS discovery reports them), services, timers [s] and the frame_id,
  stamp and layout of every message: from a live graph. The script starts
  ``scripts/launch_graph.sh`` (real_time, the shipped SAC policy, recorder on, its own DDS domain)
  with ``tools/gen_interfaces_hook`` on PYTHONPATH (a ``sitecustomize`` that records each node's
  ``create_publisher``/``create_subscription``/``create_service``/``create_timer``/
  ``declare_parameter`` calls) and subscribes to every topic for a few seconds;
- rates: each topic's rate class (once per control step, or latched once) is declared below and
  checked against the measured message counts (the doc states the configured rate, 1 / (DT *
  SUBSTEPS_PER_ACTION) = 12.5 Hz, never a noisy measurement);
- message and service definitions: ros_ws/src/dlo_msgs/{msg,srv};
- parameter tables: each node module's PARAMETERS declarations (dlo_common.params.markdown_table),
  for every ``*_node`` entry point in the packages' setup.py;
- units and ranges: the hand-written lines of ``semantics`` below, with numbers taken from dlo_interface.world /
  dlo_interface.command / dlo_interface.task constants; a topic without one: its registry record's description and
  ``plot`` series (field, name, unit), so a topic added to dlo_common.topics is documented with no line here.

``--check`` regenerates into memory and compares with the committed file: exit 1 and a diff
summary when it is stale. Exit 2 on a usage error or when the graph could not be started.
"""

from __future__ import annotations

import argparse
import contextlib
import difflib
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from dlo_common.topics import select

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "INTERFACES.md"
HOOK_DIR = ROOT / "tools" / "gen_interfaces_hook"
MSG_DIR = ROOT / "ros_ws" / "src" / "dlo_msgs"
PROBE_NODE = "interfaces_probe"
EXIT_STALE, EXIT_ERROR = 1, 2

# Topics docs/ARCHITECTURE.md#topics lists (the contract): the registry's (dlo_common.topics) but the simulator's
# internal ones and the run's provenance (no data of a step); the live graph is compared with it.
CONTRACT_TOPICS = tuple(t.name for t in select(exclude=("internal", "provenance")))
INFRASTRUCTURE_TOPICS = ("/parameter_events", "/rosout")
PARAMETER_SERVICES = (
    "describe_parameters",
    "get_parameters",
    "get_parameter_types",
    "list_parameters",
    "set_parameters",
    "set_parameters_atomically",
    "get_type_description",
)


def semantics() -> dict:
    """Per topic of the registry (dlo_common.topics): its rate class, the driver's part (``role``) and
    ``sim_only`` from its record, and the hand-written units/ranges and what a real robot does.

    ``rate``: "step" = one message per control step (the state of step k and everything computed
    from it), "latched" = published once, transient-local. ``driver``: what a real robot driver
    must do about the topic. Numbers come from the code's constants. A topic without a hand-written
    entry shows its record's description and plot series as its units (:func:`record_units`) and its record's
    driver's part (or its publisher) as what a real robot does.
    """
    from dlo_interface.camera import IMAGE_BACKGROUND, IMAGE_CABLE, IMAGE_GRIPPER, TopCamera
    from dlo_interface.command import MAX_SPEED
    from dlo_interface.task import END_PARTICLES, HORIZON
    from dlo_interface.world import FIXED_END, GRIPPER_HEIGHT, WORKSPACE_HALF_WIDTH
    from dlo_perception.tactile import Y_LIMIT

    w = WORKSPACE_HALF_WIDTH
    cam = TopCamera.covering_workspace()
    prose = {
        "/clock": dict(
            units="simulation time of the state just published (0.08 s per control step)",
            driver="not needed: no node runs with use_sim_time; a driver stamps with its own clock",
        ),
        "/dlo/gripper/state": dict(
            units=f"x, y [m] in the workspace [{-w}, {w}]; z [m] gripper height (sim: {GRIPPER_HEIGHT}, constant; "
            "vision_node converts pixels to metres at this height); closure c_G [-] in [0, 1]; "
            f"episode (0-based); step 0..{HORIZON} within the episode",
            driver="**must publish**, once per control step, after the step's image (perception and policy react "
            "to the state); `step` +1 per control step (per executed command in step_locked, per tick in "
            "real_time), `episode` +1 per reset",
        ),
        "/dlo/gripper/cmd": dict(
            units=f"vx, vy [m/s] with |vx|, |vy| <= {MAX_SPEED:g} (= {MAX_SPEED * 0.01:g} m per 0.01 s); closure "
            "[-] in [0, 1]; episode, step = those of the state it answers; header = that state's header",
            driver="**must obey**: apply it from the next control step on until the next command; reject (warn, "
            "hold) non-finite or out-of-range values and commands for another episode or a stale step; stop "
            "and hold the closure when the last command is older than command_timeout",
        ),
        "/dlo/camera/image": dict(
            units=f"mono8 segmentation, {cam.width} x {cam.height} px: {IMAGE_CABLE} cable, {IMAGE_GRIPPER} gripper, "
            f"{IMAGE_BACKGROUND} background; top view (column u ~ world +x, row v ~ world -y)",
            driver="**must publish** (a segmented top-camera frame with the state's stamp), or publish "
            "/dlo/vision/pose itself and not run vision_node",
        ),
        "/dlo/camera/camera_info": dict(
            units=f"K [px] of the top camera; sim: {cam.width} x {cam.height}, fx = fy = {cam.fx:g}, "
            f"cx = cy = {cam.cx:g}, camera at {cam.position} m looking down -z (the position is vision_node's "
            "camera_position parameter, CameraInfo has no pose)",
            driver="**must publish**, transient-local (latched), frame_id = the image's",
        ),
        "/dlo/rope/particles": dict(
            units=f"points in index order (0 = fixed end at {FIXED_END} m): x, y, z [m] world; held 1.0 = between "
            "the fingers, else 0.0",
            driver="ground truth in the sim; a driver may publish the tactile sensor's contact points here "
            "(held = 1 for points in contact) for tactile_node, or publish /dlo/tactile/pose itself",
        ),
        "/dlo/tactile/pose": dict(
            units=f"angle theta_T [rad] in (-pi/2, pi/2]; y y_T [m], |y_T| <= {Y_LIMIT}; contact (>= 2 points "
            "between the fingers; false: angle = y = 0); contact_count",
            driver="from tactile_node (particles), or from a tactile sensor driver directly (same stamp as the state)",
        ),
        "/dlo/vision/pose": dict(
            units="visible v_V; confidence q_V in [0, 1]; angle theta_V [rad]; y y_V [m] (0 when not visible)",
            driver="from vision_node (image + camera_info + state)",
        ),
        "/dlo/task/state": dict(
            units=f"episode, seed, step; held particle indices, n_h, p_i (mean held index, -1 = none); n_c, L_c [m]; "
            f"reward and return; done and outcome (paper rule: any of the last {END_PARTICLES} held) and the "
            "authors' rule's held set, mean index and outcome",
            driver="simulation only (needs the cable's ground truth): a driver publishes none; the policy needs it "
            "only for online training (train:=true); dlo-analyze of a driver bag has no outcomes",
        ),
        "/dlo/markers": dict(
            units="cable line strip (width 0.008 m) and the two finger cylinders, world frame",
            driver="optional (visualisation only)",
        ),
        "/dlo/sim/instance": dict(
            units="JSON {host, pid, started_ns}: the simulator on this domain",
            driver="simulator-internal (two simulators on one domain: the later one leaves)",
        ),
        "/dlo/policy/info": dict(
            units="JSON {policy, checkpoint, sha256, shipped, modalities, without, task_rules, single_particle_grip, "
            "env_options, ...}: the policy node's policy and what it was trained under, published once",
            driver="nothing (the policy node publishes it; the recorder keeps it in the bag for dlo-analyze)",
        ),
    }
    entries = {}
    for t in select():
        entry = {
            "rate": t.rate,
            "units": record_units(t),
            "driver": t.driver or ("simulation only: a driver publishes none" if t.sim_only else f"from `{t.publisher}`"),
            **({"role": t.driver} if t.driver else {}),
            **({"sim_only": True} if t.sim_only else {}),
        }
        entries[t.name] = {**entry, **prose.get(t.name, {})}
    return entries


def record_units(t) -> str:
    """A topic's values from its registry record alone: its description and its plot series, e.g. "the wrist's force:
    `wrench.force.x` F_x [N], `wrench.force.y` F_y [N]"."""
    series = ", ".join(f"`{s.field}` {s.name} [{s.unit}]" for s in t.plot)
    return f"{t.description}: {series}" if series else t.description


def standard_messages() -> str:
    """The message types of the registry's topics that are not dlo_msgs, each package named once, in registry
    order: "`rosgraph_msgs/Clock`, `sensor_msgs/PointCloud2`, `Image`, ... and `std_msgs/String`"."""
    by_package: dict[str, list[str]] = {}
    for t in select():
        package, _, name = t.type.split("/")
        if package != "dlo_msgs" and name not in by_package.setdefault(package, []):
            by_package[package].append(name)
    names = [
        f"`{package}/{name}`" if i == 0 else f"`{name}`" for package, found in by_package.items() for i, name in enumerate(found)
    ]
    return ", ".join(names[:-1]) + " and " + names[-1] if len(names) > 1 else "".join(names)


# ----------------------------------------------------------------------------------- live capture
class CaptureError(RuntimeError):
    """The graph could not be started or observed (the message says why)."""


def domain_busy(domain: int) -> bool:
    """True when a process on this machine has bound one of the domain's RTPS UDP ports (7400 + 250 d + 0..249)."""
    lo, hi = 7400 + 250 * domain, 7400 + 250 * domain + 249
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        with contextlib.suppress(OSError):
            for line in Path(table).read_text().splitlines()[1:]:
                port = int(line.split()[1].rsplit(":", 1)[1], 16)
                if lo <= port <= hi:
                    return True
    return False


def free_domain() -> int:
    """A free ROS domain in 201..232 (launch_graph.sh picks 10..99 and test sessions 100..200)."""
    candidates = list(range(201, 233))
    random.Random(os.getpid() ^ time.time_ns()).shuffle(candidates)
    for domain in candidates:
        if not domain_busy(domain):
            return domain
    raise CaptureError("no free ROS_DOMAIN_ID in 201..232 on this machine; give --domain-id N")


def stop_group(proc: subprocess.Popen, grace: float = 30.0) -> None:
    """SIGINT the launcher's process group (it stops its graph), SIGKILL what is left after ``grace`` s. Returns
    as soon as no process of the group is left (the launcher, our child, reaped: a zombie leader still counts as
    a member of its group, and waiting for it took the whole grace)."""
    for sig, wait in ((signal.SIGINT, grace), (signal.SIGKILL, 5.0)):
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, sig)
        deadline = time.monotonic() + wait
        while time.monotonic() < deadline:
            proc.poll()  # reaps the launcher once it has ended
            try:
                os.killpg(proc.pid, 0)
            except ProcessLookupError:
                proc.wait()
                return
            time.sleep(0.2)
    with contextlib.suppress(subprocess.TimeoutExpired):
        proc.wait(timeout=5)


def capture(domain: int, window: float, timeout: float, workdir: Path, log=print, look_first: bool = True) -> dict:
    """Start the graph on ``domain``, observe it for ``window`` s of messages, stop it: -> snapshot dict.
    ``look_first``: first make sure (by discovery, 1.5 s) that no other node runs on the domain; not needed for a
    domain :func:`free_domain` picked with localhost discovery (no process on this machine had bound its ports and
    no other machine can join it)."""
    dump = workdir / "dump"
    dump.mkdir()
    env = dict(os.environ)
    env["PYTHONPATH"] = f"{HOOK_DIR}{os.pathsep}{env.get('PYTHONPATH', '')}"
    env["DLO_INTERFACES_DUMP"] = str(dump)
    env["ROS_DOMAIN_ID"] = str(domain)
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    cmd = [
        str(ROOT / "scripts" / "launch_graph.sh"),
        "--episodes",
        "1",
        "--mode",
        "real_time",
        "--domain-id",
        str(domain),
        "--logs",
        str(workdir / "logs"),
        "--record",
        str(workdir / "bag"),
    ]
    import rclpy
    from dlo_common.node_main import shut_down
    from rclpy.signals import SignalHandlerOptions

    os.environ["ROS_DOMAIN_ID"] = str(domain)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)  # Ctrl-C: KeyboardInterrupt, the graph is stopped
    node = rclpy.create_node(PROBE_NODE)
    try:
        if look_first:
            time.sleep(1.5)  # discovery: another graph on this domain would mix into the doc
        others = sorted({n for n in node.get_node_names() if n != PROBE_NODE})
        if others:
            raise CaptureError(
                f"ROS_DOMAIN_ID={domain} already has nodes ({', '.join(others)}): stop them or give another --domain-id"
            )
        log(f"[gen_interfaces] starting the graph on ROS_DOMAIN_ID={domain}: {' '.join(cmd[1:])}")
        with open(workdir / "launch.log", "w") as out:
            proc = subprocess.Popen(
                cmd,
                env=env,
                stdout=out,
                stderr=subprocess.STDOUT,
                start_new_session=True,
                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
            )
        try:
            samples, wire = observe(node, proc, window, timeout)
        finally:
            stop_group(proc)
    finally:
        shut_down(node)
    records = []
    for path in sorted(dump.glob("*.jsonl")):
        records += [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    if not records:
        raise CaptureError("the hook recorded nothing: were the nodes started with tools/gen_interfaces_hook on PYTHONPATH?")
    return {"records": records, "samples": samples, "wire": wire}


def _wait_for_policy(node, proc: subprocess.Popen, deadline: float, timeout: float) -> None:
    """Until the policy answers the sim (both gripper topics have a publisher)."""
    import rclpy

    while not (node.count_publishers("/dlo/gripper/cmd") and node.count_publishers("/dlo/gripper/state")):
        if proc.poll() is not None:
            raise CaptureError(f"the graph ended before it ran (launch_graph.sh exit {proc.returncode})")
        if time.monotonic() > deadline:
            raise CaptureError(f"no policy answering the sim within {timeout:.0f} s")
        rclpy.spin_once(node, timeout_sec=0.2)


def _wait_for_discovery(node, deadline: float) -> None:
    """The remaining endpoints: until the graph's topics have stopped appearing for 2 s (a loaded machine
    discovers them later than an idle one)."""
    import rclpy

    known, stable_since = set(), time.monotonic()
    while time.monotonic() - stable_since < 2.0 and time.monotonic() < deadline:
        topics = {t for t, _ in node.get_topic_names_and_types() if node.count_publishers(t)}
        if topics != known:
            known, stable_since = topics, time.monotonic()
        rclpy.spin_once(node, timeout_sec=0.1)


def _subscribe_everything(node, samples: dict[str, dict]) -> list:
    """A subscription to every /dlo topic and /clock (transient-local where a publisher latches) that counts
    its messages, keeps the first and the stamps in ``samples[topic]``."""
    from dlo_bag.playback import import_message_class
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    def on_message(topic, msg):
        entry = samples[topic]
        entry["count"] += 1
        if entry["first"] is None:
            entry["first"] = msg
        stamp = stamp_of(msg)
        if stamp is not None:
            entry["stamps"].append(stamp)

    subscriptions = []
    for topic, types in node.get_topic_names_and_types():
        if not (topic.startswith("/dlo/") or topic == "/clock"):
            continue
        infos = node.get_publishers_info_by_topic(topic)
        latched = any(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in infos)
        qos = QoSProfile(
            depth=100,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
        )
        samples[topic] = {"count": 0, "first": None, "stamps": []}
        subscriptions.append(
            node.create_subscription(import_message_class(types[0]), topic, lambda m, t=topic: on_message(t, m), qos)
        )
    return subscriptions


def _spin_window(node, proc: subprocess.Popen, samples: dict, window: float, deadline: float, timeout: float) -> float | None:
    """Spin for ``window`` s from the first gripper state (or until the graph ends): when that state came."""
    import rclpy

    started = None
    while True:
        rclpy.spin_once(node, timeout_sec=0.1)
        if started is None and samples.get("/dlo/gripper/state", {}).get("count"):
            started = time.monotonic()
        if started is not None and time.monotonic() - started > window:
            break
        if proc.poll() is not None:
            break
        if started is None and time.monotonic() > deadline:
            raise CaptureError(f"no /dlo/gripper/state within {timeout:.0f} s")
    return started


def observe(node, proc: subprocess.Popen, window: float, timeout: float) -> tuple[dict, dict]:
    """Subscribe to every /dlo topic and /clock once the policy answers; count and inspect messages."""
    deadline = time.monotonic() + timeout
    _wait_for_policy(node, proc, deadline, timeout)
    _wait_for_discovery(node, deadline)
    samples: dict[str, dict] = {}
    subscriptions = _subscribe_everything(node, samples)  # noqa: F841 - kept alive while spinning
    started = _spin_window(node, proc, samples, window, deadline, timeout)
    wire = {}
    for topic in samples:
        wire[topic] = {
            "publishers": [endpoint_info(i) for i in node.get_publishers_info_by_topic(topic)],
            "subscribers": [endpoint_info(i) for i in node.get_subscriptions_info_by_topic(topic) if i.node_name != PROBE_NODE],
        }
    observed = time.monotonic() - started if started is not None else 0.0
    summary = {topic: summarise(topic, entry) for topic, entry in samples.items()}
    for entry in summary.values():
        entry["observed_s"] = observed
    return summary, wire


def endpoint_info(info) -> dict:
    return {
        "node": info.node_name,
        "type": info.topic_type,
        "reliability": info.qos_profile.reliability.name.lower(),
        "durability": info.qos_profile.durability.name.lower(),
    }


def stamp_of(msg):
    """Nanoseconds of a message's header stamp (or Clock's clock); None without one."""
    stamp = getattr(getattr(msg, "header", None), "stamp", None) or getattr(msg, "clock", None)
    if stamp is None and getattr(msg, "markers", None):
        stamp = msg.markers[0].header.stamp
    return None if stamp is None else stamp.sec * 1_000_000_000 + stamp.nanosec


def summarise(topic: str, entry: dict) -> dict:
    """What the doc needs of one topic's messages (JSON-able)."""
    msg = entry["first"]
    out = {"count": entry["count"], "stamps": entry["stamps"]}
    if msg is None:
        return out
    header = getattr(msg, "header", None)
    if header is not None:
        out["frame_id"] = header.frame_id
    if getattr(msg, "markers", None) is not None:
        out["frame_id"] = sorted({m.header.frame_id for m in msg.markers})
        out["markers"] = sorted({f"{m.ns}: {marker_type(m.type)}" for m in msg.markers})
    if hasattr(msg, "fields") and hasattr(msg, "point_step"):
        out["fields"] = [(f.name, point_type(f.datatype), int(f.offset)) for f in msg.fields]
        out["point_step"] = int(msg.point_step)
        out["is_bigendian"] = bool(msg.is_bigendian)
    if hasattr(msg, "encoding"):
        out["image"] = {"encoding": msg.encoding, "width": msg.width, "height": msg.height, "step": msg.step}
    if hasattr(msg, "k") and hasattr(msg, "distortion_model"):
        out["camera_info"] = {
            "width": msg.width,
            "height": msg.height,
            "k": [float(v) for v in msg.k],
            "distortion_model": msg.distortion_model,
        }
    return out


def marker_type(code: int) -> str:
    from visualization_msgs.msg import Marker

    names = {
        getattr(Marker, n): n
        for n in dir(Marker)
        if n.isupper() and isinstance(getattr(Marker, n), int) and n not in ("ADD", "MODIFY", "DELETE", "DELETEALL")
    }
    return names.get(code, str(code))


def point_type(code: int) -> str:
    from sensor_msgs.msg import PointField

    names = {getattr(PointField, n): n for n in ("INT8", "UINT8", "INT16", "UINT16", "INT32", "UINT32", "FLOAT32", "FLOAT64")}
    return names.get(code, str(code))


# ----------------------------------------------------------------------------------- the model
def build_model(snapshot: dict) -> dict:
    """Snapshot -> the deterministic facts the doc shows (no counts, no wall time, no pids)."""
    records = snapshot["records"]
    nodes = {}
    for r in records:
        if r["kind"] == "node":
            nodes.setdefault(r["node"], r["exe"])
    topics: dict[str, dict] = {}
    for r in records:
        if r["kind"] not in ("publisher", "subscription") or r["topic"] in INFRASTRUCTURE_TOPICS:
            continue
        t = topics.setdefault(r["topic"], {"type": r["type"], "publishers": [], "subscribers": []})
        endpoint = {k: r[k] for k in ("node", "history", "depth", "reliability", "durability")}
        key = "publishers" if r["kind"] == "publisher" else "subscribers"
        if endpoint not in t[key]:
            t[key].append(endpoint)
    for topic, wire in snapshot.get("wire", {}).items():  # endpoints the hook could not see (non-Python nodes)
        t = topics.setdefault(
            topic, {"type": wire["publishers"][0]["type"] if wire["publishers"] else "?", "publishers": [], "subscribers": []}
        )
        for key in ("publishers", "subscribers"):
            known = {e["node"] for e in t[key]}
            for e in wire[key]:
                if e["node"] not in known and e["node"] != PROBE_NODE:
                    t[key].append(
                        {
                            "node": e["node"],
                            "history": "unknown",
                            "depth": "?",
                            "reliability": e["reliability"],
                            "durability": e["durability"],
                        }
                    )
    for t in topics.values():
        t["publishers"].sort(key=lambda e: e["node"])
        t["subscribers"].sort(key=lambda e: e["node"])
    services = sorted(
        {
            (r["name"], r["type"], r["node"])
            for r in records
            if r["kind"] == "service" and r["name"].rsplit("/", 1)[-1] not in PARAMETER_SERVICES
        }
    )
    clients = sorted(
        {
            (r["name"], r["type"], r["node"])
            for r in records
            if r["kind"] == "client" and r["name"].rsplit("/", 1)[-1] not in PARAMETER_SERVICES
        }
    )
    timers = sorted({(r["node"], round(r["period_s"], 6), r["callback"]) for r in records if r["kind"] == "timer"})
    use_sim_time = {r["node"]: r["value"] for r in records if r["kind"] == "parameter" and r["name"] == "use_sim_time"}
    sim_pids = {r["pid"] for r in records if r["kind"] == "node" and r["node"] == "sim_node"}
    sequence = [
        r["topic"]
        for r in sorted((r for r in records if r["kind"] == "publish" and r["pid"] in sim_pids), key=lambda r: r["seq"])
    ]
    clocks = [i for i, topic in enumerate(sequence) if topic == "/clock"]
    step_order = sequence[clocks[1] : clocks[2]] if len(clocks) >= 3 else []
    samples = snapshot.get("samples", {})
    state_stamps = samples.get("/dlo/gripper/state", {}).get("stamps", [])
    step_ns = None
    if len(state_stamps) > 2:
        diffs = [b - a for a, b in zip(state_stamps, state_stamps[1:]) if b > a]
        step_ns = max(set(diffs), key=diffs.count) if diffs else None
    for topic, t in topics.items():
        s = samples.get(topic, {})
        t["frame_id"] = s.get("frame_id")
        for key in ("fields", "point_step", "is_bigendian", "image", "camera_info", "markers"):
            if key in s:
                t[key] = s[key]
        t["stamp"] = stamp_rule(topic, s.get("stamps", []), state_stamps)
    return {
        "nodes": nodes,
        "topics": topics,
        "services": services,
        "clients": clients,
        "timers": timers,
        "step_order": step_order,
        "use_sim_time": use_sim_time,
        "step_ns": step_ns,
    }


def stamp_rule(topic: str, stamps: list, state_stamps: list) -> str:
    """How a topic's stamps relate to the state's: checked on the live messages."""
    if not stamps:
        return "none (no header)"
    if not state_stamps:
        return "?"
    if topic == "/dlo/gripper/state":
        return "simulation time of the state"
    lo, hi = min(state_stamps), max(state_stamps)
    inside = [s for s in stamps if lo <= s <= hi]
    if not inside and all(s == 0 for s in stamps):
        return "0 (unset)"
    known = set(state_stamps)
    if inside and all(s in known for s in inside):
        return "= the step's state stamp"
    return "own"


def rate_classes(snapshot: dict) -> dict:
    """Measured rate class per topic: 'step' (about one per state), 'latched' (once), or 'n/state'."""
    samples = snapshot.get("samples", {})
    states = samples.get("/dlo/gripper/state", {}).get("count", 0)
    out = {}
    for topic, s in samples.items():
        count = s.get("count", 0)
        if states < 5:
            out[topic] = "unmeasured"
        elif count <= 2:
            out[topic] = "latched"
        elif 0.6 <= count / states <= 1.4:
            out[topic] = "step"
        else:
            out[topic] = f"{count / states:.2f}/state"
    return out


def check_rates(snapshot: dict, declared: dict) -> list[str]:
    """Lines naming each topic whose measured rate class differs from the declared one."""
    measured = rate_classes(snapshot)
    return [
        f"{topic}: declared '{declared[topic]['rate']}', measured '{cls}'"
        for topic, cls in sorted(measured.items())
        if topic in declared and cls not in (declared[topic]["rate"], "unmeasured")
    ]


# ----------------------------------------------------------------------------------- static parts
def message_definitions() -> list[tuple[str, str]]:
    """(name, text) of every dlo_msgs message and service definition."""
    out = []
    for sub in ("msg", "srv"):
        for path in sorted((MSG_DIR / sub).glob(f"*.{sub}")):
            out.append((f"dlo_msgs/{sub}/{path.stem}", path.read_text().rstrip()))
    return out


def node_executables() -> list[tuple[str, str, str]]:
    """(package, executable, module) of every node executable: the setup.py entry points of a *_node module."""
    import re

    out = []
    for setup in sorted((ROOT / "ros_ws" / "src").glob("*/setup.py")):
        for exe, module in re.findall(r"[\"'](\w+)\s*=\s*([\w.]+_node):main[\"']", setup.read_text()):
            out.append((setup.parent.name, exe, module))
    return out


def parameter_tables() -> list[tuple[str, str, str]]:
    """[(package, executable, Markdown table)] from each node module's PARAMETERS (dlo_common.params.markdown_table)."""
    import importlib

    from dlo_common.params import markdown_table

    tables = []
    for package, exe, module_name in node_executables():
        params = getattr(importlib.import_module(module_name), "PARAMETERS", None)
        tables.append(
            (
                package,
                exe,
                markdown_table(params) if params is not None else "(no module-level PARAMETERS: see the node's source)",
            )
        )
    return tables


# ----------------------------------------------------------------------------------- rendering
def qos_text(e: dict) -> str:
    depth = f"{e['history'].replace('_', ' ')} {e['depth']}" if e["history"] != "unknown" else "depth ?"
    return f"{e['reliability']}, {e['durability'].replace('_', ' ')}, {depth}"


def _head_lines() -> list[str]:
    """The title, what the doc is, its conventions and its contents."""
    out: list[str] = []
    add = out.append
    add("# Interfaces of the dlo-vitac graph\n")
    add(
        "<!-- Generated by tools/gen_interfaces.py from a live graph and the code: do not edit by hand. "
        "Regenerate: python tools/gen_interfaces.py; check: python tools/gen_interfaces.py --check -->\n"
    )
    add(
        "The reference a robotics user writes a driver from. Everything below except the units/ranges column "
        "and the prose is generated from the code or observed on a running graph (`scripts/launch_graph.sh "
        "--mode real_time --record`, the shipped SAC policy), so it cannot drift: "
        "`tests/test_interfaces_doc.py` regenerates it and fails when it is stale. How to write a driver: "
        "[WRITE_YOUR_DRIVER.md](WRITE_YOUR_DRIVER.md); whether yours fits, rule by rule: `dlo-driver-check`. "
        "The topic contract: [ARCHITECTURE.md#topics](ARCHITECTURE.md#topics); "
        "the library API: [LIBRARY_API.md](LIBRARY_API.md).\n"
    )
    add(
        "Conventions: SI units, REP-103 (right-handed, z up). Every topic is under `/dlo` (plus `/clock`); "
        "`launch_graph.sh --namespace NS` prefixes them all with `/NS`. Every message's `header.frame_id` "
        "names the frame of its values; its `header.stamp` is the simulation (or driver) time of the control "
        "step it belongs to, so nodes match one step's messages exactly by stamp.\n"
    )

    add("## Contents\n")
    for title in (
        "A driver's interface",
        "Topics",
        "Topic details: units, ranges, QoS of every endpoint",
        "Services",
        "Frames",
        "Timing",
        "What the simulator publishes that a robot cannot",
        "Message definitions",
        "Node parameters",
        "Known deviations from the topic contract",
    ):
        add(f"- [{title}](#{anchor(title)})")
    add("")
    return out


def _driver_lines(topics: dict, order: list, sem: dict) -> list[str]:
    """A driver's interface: the topics a driver publishes or subscribes, with the graph's QoS."""
    out: list[str] = []
    add = out.append
    add("## A driver's interface\n")
    add(
        "What a real robot driver that replaces `sim_node` publishes and subscribes, with the QoS the graph uses "
        "on that topic (a driver should offer the same: reliable and volatile match every subscriber here; "
        "camera_info must be transient-local so a late vision node gets it). Details and units below.\n"
    )
    add("| topic | the driver | type | rate | QoS | frame_id |")
    add("|---|---|---|---|---|---|")
    for topic in order:
        role = sem.get(topic, {}).get("role")
        if role:
            t = topics[topic]
            ends = t["subscribers"] if role.startswith("subscribes") else t["publishers"]
            mine = [e for e in ends if e["node"] in ("sim_node", "tactile_node")] or ends
            qos = "; ".join(sorted({qos_text(e) for e in mine})) or "—"
            add(f"| `{topic}` | {role} | `{t['type']}` | {sem[topic]['rate']} | {qos} | {frame_text(t)} |")
    add("")
    add(
        "Service (optional): `/dlo/sim/reset` (`dlo_msgs/srv/ResetEpisode`) to start an episode on request. "
        "Step-by-step guide and a template: [WRITE_YOUR_DRIVER.md](WRITE_YOUR_DRIVER.md); conformance: "
        "`dlo-driver-check`.\n"
    )
    return out


def _topics_lines(model: dict, order: list, sem: dict, period: float) -> list[str]:
    """Topics: one row per topic, the data flow, the nodes."""
    out: list[str] = []
    add = out.append
    rate = 1.0 / period
    topics = model["topics"]
    add("## Topics\n")
    add(
        f"Rates: **step** = one message per control step: {rate:g} Hz (one step = {period:g} s of simulation) "
        "times `rate_factor` in real_time; in step_locked as fast as the graph answers. **latched** = published "
        "once, transient-local (late joiners get it). QoS is the publisher's (history depth as the code "
        "requests it); subscribers' QoS are in the details.\n"
    )
    add("| topic | type | publisher | subscribers | rate | QoS | frame_id |")
    add("|---|---|---|---|---|---|---|")
    for topic in order:
        t = topics[topic]
        s = sem.get(topic, {})
        pubs = ", ".join(f"`{e['node']}`" for e in t["publishers"]) or "—"
        subs = ", ".join(f"`{e['node']}`" for e in t["subscribers"]) or "—"
        qos = "; ".join(sorted({qos_text(e) for e in t["publishers"]})) or "—"
        add(f"| `{topic}` | `{t['type']}` | {pubs} | {subs} | {s.get('rate', '?')} | {qos} | {frame_text(t)} |")
    add("")
    add("The data flow (without `recorder`, which subscribes to every topic, and the launcher's monitor):\n")
    add("```mermaid")
    add(mermaid_graph(topics, order))
    add("```\n")
    add(
        "Nodes (executable → node name): "
        + ", ".join(f"`{exe}` → `{name}`" for name, exe in sorted(model["nodes"].items()))
        + ". `recorder` runs only with "
        "`--record`; the Foxglove bridge (`--foxglove`) subscribes to a topic only while a client watches it and "
        "is not shown. `policy_node` subscribes to what its policy needs: with `policy:=oracle` also "
        "`/dlo/rope/particles`, with `train:=true` also `/dlo/task/state`; not to the topic of a modality it "
        "does not observe (not in its modalities, or in `without:=`).\n"
    )
    return out


def _topic_detail_lines(topic: str, t: dict, s: dict) -> list[str]:
    """One topic's details: values, frame and stamp, layout, markers, a real robot's part, QoS of every endpoint."""
    out: list[str] = []
    add = out.append
    add(f"### `{topic}` (`{t['type']}`)\n")
    if s.get("units"):
        add(f"- **Values**: {s['units']}.")
    add(f"- **frame_id**: {frame_text(t)}; **stamp**: {t['stamp']}.")
    if "fields" in t:
        fields = ", ".join(f"`{n}` {typ} @{off}" for n, typ, off in t["fields"])
        add(
            f"- **Layout**: fields {fields}; point_step {t['point_step']}, "
            f"{'big' if t['is_bigendian'] else 'little'} endian; one point per particle."
        )
    if "image" in t:
        i = t["image"]
        add(f"- **Layout**: encoding `{i['encoding']}`, {i['width']} x {i['height']} px, step {i['step']} bytes.")
    if "camera_info" in t:
        c = t["camera_info"]
        add(
            f"- **Layout**: {c['width']} x {c['height']} px, distortion_model `{c['distortion_model'] or '(empty)'}`"
            f", K = {[round(v, 6) for v in c['k']]}."
        )
    if "markers" in t:
        add(f"- **Markers**: {', '.join(t['markers'])}.")
    if s.get("driver"):
        add(f"- **Real robot**: {s['driver']}.")
    for key, label in (("publishers", "Publisher"), ("subscribers", "Subscriber")):
        for e in t[key]:
            add(f"- {label} `{e['node']}`: {qos_text(e)}.")
    add("")
    return out


def _details_lines(topics: dict, order: list, sem: dict) -> list[str]:
    """Topic details: units, ranges, QoS of every endpoint."""
    out: list[str] = []
    add = out.append
    add("## Topic details: units, ranges, QoS of every endpoint\n")
    for topic in order:
        out += _topic_detail_lines(topic, topics[topic], sem.get(topic, {}))
    return out


def _services_lines(model: dict) -> list[str]:
    """Services: server and clients of each."""
    out: list[str] = []
    add = out.append
    add("## Services\n")
    add("| service | type | server | clients in the graph |")
    add("|---|---|---|---|")
    for name, typ, node in model["services"]:
        clients = ", ".join(f"`{c[2]}`" for c in model["clients"] if c[0] == name) or "none (call it yourself)"
        add(f"| `{name}` | `{typ}` | `{node}` | {clients} |")
    add("")
    add(
        "`/dlo/sim/reset` starts a new episode at once (`seed < 0`: the node's own sequence `seed + episode`); "
        "the response names the new episode counter and seed. A driver may offer the same service (e.g. to "
        "move the robot home). Every node also serves the standard ROS 2 parameter services "
        "(`/<node>/get_parameters`, `/<node>/set_parameters`, ...).\n"
    )
    return out


def _frames_lines(topics: dict, cam, fixed_end, half_width: float, gripper_height: float) -> list[str]:
    """Frames: world, gripper, the camera's; the static transforms and the diagram."""
    out: list[str] = []
    add = out.append
    add("## Frames\n")
    if not {"/tf", "/tf_static"} & set(topics):
        add("No node publishes `/tf`: the frames are fixed by convention, and each message names its frame.\n")
    add("| frame | origin | axes | used by |")
    add("|---|---|---|---|")
    users = {}
    for topic, t in topics.items():
        for f in t.get("frame_id") if isinstance(t.get("frame_id"), list) else [t.get("frame_id")]:
            if f:
                users.setdefault(f, []).append(f"`{topic}`")
    add(
        f"| `world` | table centre, table plane z = 0 | x along the cable (fixed end at x = {fixed_end[0]}), "
        f"z up | {', '.join(sorted(users.get('world', [])))} |"
    )
    add(
        f"| `gripper` | gripper centre (x_G, y_G, z_G = {gripper_height} m), midway between the finger axes | "
        "parallel to `world` (the gripper does not rotate): x = direction of travel, y = along the fingers | "
        f"{', '.join(sorted(users.get('gripper', [])))} |"
    )
    optical = [f for f in users if f not in ("world", "gripper")]
    for f in sorted(optical):
        add(
            f"| `{f}` | camera centre {cam.position} m in `world` | REP-103 optical: x = world x, "
            f"y = world -y, z = world -z (looks down) | {', '.join(sorted(users[f]))} |"
        )
    add("")
    add(
        "Static transforms for RViz/Foxglove (not published by the graph): "
        f"`ros2 run tf2_ros static_transform_publisher --z {cam.position[2]} --roll 3.141592653589793 "
        "--frame-id world --child-frame-id top_camera_optical`; the `gripper` frame moves with "
        "`/dlo/gripper/state` (translation only).\n"
    )
    add("```")
    add(frames_diagram(fixed_end, half_width, cam.position[2], gripper_height))
    add("```\n")
    return out


def _timing_lines(model: dict, period: float, substeps: int, dt: float, horizon: int) -> list[str]:
    """Timing: a control step, the publishing order within it, the two modes, the timers."""
    out: list[str] = []
    add = out.append
    add("## Timing\n")
    step_ns = model["step_ns"]
    step_text = f"{step_ns / 1e9:g} s" if step_ns else "?"
    add(
        f"One control step = {substeps} simulation steps of {dt} s = {period:g} s; the state's stamp "
        f"advances by {step_text} per step (observed), continuing across episodes; an episode has {horizon} steps. "
        "Within a step the simulator publishes, in this order (observed): "
        + (" → ".join(f"`{t}`" for t in model["step_order"]) or "?")
        + (
            ": the gripper state **last**, so perception and the policy react to a complete step. "
            if model["step_order"][-1:] == ["/dlo/gripper/state"]
            else ". "
        )
        + "Perception outputs and the command carry the state's stamp; the command also echoes its episode and "
        "step.\n"
    )
    sim = sim_defaults()
    add(
        "- **step_locked** (`mode:=step_locked`, default): the simulator advances one step when the command "
        "answering the current step (same episode and step) arrives; deterministic, as fast as the graph answers. "
        f"A step nobody answers within `step_timeout` (default {sim.get('step_timeout')} s) is republished with the "
        "same stamp (perception and policy answer it again, unchanged); at start-up the first state is republished "
        "every 0.25 s until answered."
    )
    add(
        f"- **real_time** (`mode:=real_time`): a timer advances one step every {period:g} s / `rate_factor` "
        f"(default {sim.get('rate_factor')}) of wall time with the last accepted command; a command for another "
        "episode, or for a step older than `command_timeout` (default "
        f"{sim.get('command_timeout')} s), is rejected; when the last command is older than `command_timeout` the "
        "gripper stops and holds its closure. This is how a real robot driver runs."
    )
    add(
        "- In both modes a non-finite or out-of-range command is rejected with a warning (at most one line a "
        "second per cause) and the gripper holds.\n"
    )
    add("Timers of the running graph (period [s], callback):\n")
    add("| node | period [s] | callback |")
    add("|---|---|---|")
    for node, period_s, callback in model["timers"]:
        add(f"| `{node}` | {period_s:g} | `{callback}` |")
    add("")
    add(f"(Observed with `mode:=real_time`, `rate_factor:=1`: the sim's tick timer is {period:g} s / rate_factor.)\n")
    return out


def _sim_only_lines(topics: dict, order: list, sem: dict) -> list[str]:
    """What the simulator publishes that a robot cannot."""
    out: list[str] = []
    add = out.append
    add("## What the simulator publishes that a robot cannot\n")
    add("| topic | in the simulation | with a real robot driver |")
    add("|---|---|---|")
    for topic in order:
        s = sem.get(topic, {})
        if s.get("sim_only"):
            add(f"| `{topic}` | {', '.join('`' + e['node'] + '`' for e in topics[topic]['publishers'])} | {s['driver']} |")
    add("")
    add(
        "A driver does with each topic what [A driver's interface](#a-drivers-interface) says (the **Real robot** "
        "lines above); the perception and policy nodes then run unchanged. Without `/dlo/task/state` there is no "
        "reward or outcome: run a trained policy, judge episodes yourself (or from the camera).\n"
    )
    return out


def _definitions_lines(definitions: list) -> list[str]:
    """The dlo_msgs message and service definitions."""
    out: list[str] = []
    add = out.append
    add("## Message definitions\n")
    add(
        "The project's own interfaces (`ros_ws/src/dlo_msgs`), with their comments (units in brackets). The "
        f"standard messages used are {standard_messages()} (layouts in the topic details).\n"
    )
    for name, text in definitions:
        add(f"### `{name}`\n")
        add("```")
        add(text)
        add("```\n")
    return out


def _parameter_lines(params: list) -> list[str]:
    """Every node's parameter table."""
    out: list[str] = []
    add = out.append
    add("## Node parameters\n")
    add(
        "Rendered from each node module's `PARAMETERS` declarations by `dlo_common.params.markdown_table`, the "
        "same declarations the node checks at start and prints with `--help` (`ros2 run <package> <executable> "
        "--help`); set them with `--ros-args -p name:=value` or `--params-file` (each package's "
        "`config/<executable>.yaml`).\n"
    )
    for package, exe, table in params:
        add(f"### `{package} {exe}`\n")
        add(table.rstrip())
        add("")
    return out


def _deviation_lines(model: dict) -> list[str]:
    """Known deviations from the topic contract."""
    out: list[str] = []
    add = out.append
    add("## Known deviations from the topic contract\n")
    for line in deviations(model):
        add(f"- {line}")
    add("")
    return out


def render(model: dict, sem: dict, params: list, definitions: list) -> str:
    from dlo_interface.camera import TopCamera
    from dlo_interface.task import HORIZON
    from dlo_interface.world import DT, FIXED_END, GRIPPER_HEIGHT, SUBSTEPS_PER_ACTION, WORKSPACE_HALF_WIDTH

    period = DT * SUBSTEPS_PER_ACTION
    topics = model["topics"]
    order = sorted(topics, key=lambda t: (t == "/clock", not t.startswith("/dlo/gripper"), t))
    out = _head_lines()
    out += _driver_lines(topics, order, sem)
    out += _topics_lines(model, order, sem, period)
    out += _details_lines(topics, order, sem)
    out += _services_lines(model)
    cam = TopCamera.covering_workspace()
    out += _frames_lines(topics, cam, FIXED_END, WORKSPACE_HALF_WIDTH, GRIPPER_HEIGHT)
    out += _timing_lines(model, period, SUBSTEPS_PER_ACTION, DT, HORIZON)
    out += _sim_only_lines(topics, order, sem)
    out += _definitions_lines(definitions)
    out += _parameter_lines(params)
    out += _deviation_lines(model)
    return "\n".join(out)


def mermaid_graph(topics: dict, order: list) -> str:
    """A Mermaid flowchart: nodes (rounded) -> topics (boxes) -> nodes, from the live endpoints."""
    hidden = {"recorder", "launch_monitor", PROBE_NODE}
    lines = ["flowchart LR"]
    names = sorted({e["node"] for t in topics.values() for k in ("publishers", "subscribers") for e in t[k]} - hidden)
    for name in names:
        lines.append(f"  {name}([{name}])")
    for i, topic in enumerate(order):
        t = topics[topic]
        pubs = [e["node"] for e in t["publishers"] if e["node"] not in hidden]
        subs = [e["node"] for e in t["subscribers"] if e["node"] not in hidden and e["node"] not in pubs]
        if not pubs or not subs:
            continue
        lines.append(f'  t{i}["{topic}"]')
        lines += [f"  {p} --> t{i}" for p in pubs] + [f"  t{i} --> {n}" for n in subs]
    return "\n".join(lines)


def sim_defaults() -> dict:
    """name -> default of the sim node's declared parameters (its module found as every node's is, by entry point)."""
    import importlib

    from dlo_common.params import as_params

    module = next(module for _, exe, module in node_executables() if exe == "sim_node")
    return {p.name: p.default for p in as_params(importlib.import_module(module).PARAMETERS)}


def anchor(title: str) -> str:
    keep = "".join(c for c in title.lower() if c.isalnum() or c in " -")
    return keep.replace(" ", "-")


def frame_text(t: dict) -> str:
    f = t.get("frame_id")
    if f is None:
        return "— (no header)"
    if isinstance(f, list):
        return ", ".join(f"`{x}`" for x in f)
    return f"`{f}`" if f else "(empty)"


def frames_diagram(fixed_end, half_width: float, camera_z: float, gripper_z: float) -> str:
    """ASCII side and top views of the frames; numbers only at line ends so the columns stay aligned."""
    w = f"{half_width:g}"
    return f"""\
side view (world x-z)
                       camera: frame top_camera_optical at (0, 0, {camera_z:g}) m
        z ^                  z_opt points down (-z), x_opt = +x, y_opt = -y
          |                    |
          |                    v
          |      *~~~~~~~~(G)~~~~~~~~~~~~~~~~~   * fixed end {tuple(fixed_end)} m
          |                                      G gripper centre, z_G = {gripper_z:g} m
  table   +========================================> x
  z = 0        -{w}            0            +{w}

top view (world x-y): what the camera image shows (column u ~ +x, row v ~ -y)
        y ^
          |    +------------------------------+  y = +{w}
          |    |      workspace               |
          |    |   *~~~~(G)~~~~~~~~~~~~~~~~   |  y = 0      gripper frame at G:
          |    |          --> x_gripper       |               x = direction of travel (+x)
          |    |                              |               y = along the fingers (+y)
          |    +------------------------------+  y = -{w}
          +-----------------------------------------> x
              x = -{w}                     x = +{w}"""


def deviations(model: dict) -> list[str]:
    lines = []
    topics = model["topics"]
    extra = sorted(set(topics) - set(CONTRACT_TOPICS))
    if extra:
        lines.append(
            "Topics the graph has that docs/ARCHITECTURE.md#topics does not list: " + ", ".join(f"`{t}`" for t in extra) + "."
        )
    missing = sorted(set(CONTRACT_TOPICS) - set(topics))
    if missing:
        lines.append(
            "Topics docs/ARCHITECTURE.md#topics lists that the running graph lacks: " + ", ".join(f"`{t}`" for t in missing) + "."
        )
    headerless = sorted(t for t, v in topics.items() if t.startswith("/dlo/") and v.get("frame_id") is None)
    if headerless:
        lines.append(
            'docs/ARCHITECTURE.md#topics: "every message has a `std_msgs/Header`"; these have none: '
            + ", ".join(f"`{t}` (`{topics[t]['type']}`)" for t in headerless)
            + "."
        )
    own = sorted(t for t, v in topics.items() if v.get("stamp") == "own")
    if own:
        lines.append(
            'docs/ARCHITECTURE.md#topics: outputs "carry the stamp of the input they were computed from"; these '
            "carry stamps that are not a state's: " + ", ".join(f"`{t}`" for t in own) + "."
        )
    unframed = sorted(t for t, v in topics.items() if v.get("frame_id") == "")
    if unframed:
        lines.append(
            'docs/ARCHITECTURE.md#topics: "every message\'s `frame_id` names the frame its values are in"; empty '
            "in: " + ", ".join(f"`{t}`" for t in unframed) + "."
        )
    if model["services"]:
        lines.append(
            "docs/ARCHITECTURE.md#topics names no services; the graph serves "
            + ", ".join(f"`{name}`" for name, _, _ in model["services"])
            + "."
        )
    sim_time = sorted(n for n, v in model["use_sim_time"].items() if v)
    if len(sim_time) < len(model["use_sim_time"]):
        lines.append(
            'The topic contract: "nodes run with `use_sim_time`". In the launched graph `use_sim_time` is '
            f"{'true only for ' + ', '.join(sim_time) if sim_time else 'false for every node'}: nodes "
            "stamp their outputs with the stamp of their inputs (so the matching by stamp holds), and their "
            "timers and logs run on wall time (the real_time tick must: it drives `/clock`)."
        )
    if not {"/tf", "/tf_static"} & set(topics):
        lines.append(
            "docs/ARCHITECTURE.md#world names the frames but no node publishes `/tf` or `/tf_static` "
            "(see Frames for the "
            "static transform to publish yourself)."
        )
    info = topics.get("/dlo/camera/camera_info", {})
    if info.get("stamp", "").startswith("0"):
        lines.append(
            "`/dlo/camera/camera_info` is published once with stamp 0 (latched), not with each image: "
            "a consumer pairs them by frame_id, not by stamp (image_transport's CameraSubscriber would not)."
        )
    lines.append(
        'docs/ARCHITECTURE.md#topics: "a driver that publishes `gripper/state` and `camera/image` and obeys '
        '`gripper/cmd` replaces the sim node with no change elsewhere". It must also provide a tactile '
        "source (`/dlo/rope/particles` contact points or `/dlo/tactile/pose`): tactile_node needs particles."
    )
    return lines


# ----------------------------------------------------------------------------------- main
def diff_summary(old: str, new: str, limit: int = 40) -> str:
    diff = list(difflib.unified_diff(old.splitlines(), new.splitlines(), "committed", "regenerated", lineterm="", n=0))
    changed = sum(1 for line in diff if line[:1] in "+-" and not line.startswith(("+++", "---")))
    shown = diff[:limit]
    more = f"\n... ({len(diff) - limit} more diff lines)" if len(diff) > limit else ""
    return f"{changed} lines differ:\n" + "\n".join(shown) + more


def generate(snapshot: dict, log=print) -> str:
    sem = semantics()
    measured = rate_classes(snapshot)
    states = snapshot.get("samples", {}).get("/dlo/gripper/state", {}).get("count", 0)
    for topic, s in sorted(snapshot.get("samples", {}).items()):
        log(f"[gen_interfaces] {topic}: {s.get('count', 0)} messages for {states} states ({measured.get(topic)})")
    for line in check_rates(snapshot, sem):
        log(f"[gen_interfaces] warning: rate {line}")
    state = snapshot.get("samples", {}).get("/dlo/gripper/state", {})
    if state.get("observed_s"):
        from dlo_interface.world import DT, SUBSTEPS_PER_ACTION

        hz, configured = state["count"] / state["observed_s"], 1.0 / (DT * SUBSTEPS_PER_ACTION)
        log(
            f"[gen_interfaces] /dlo/gripper/state: {hz:.1f} Hz measured in real_time, {configured:g} Hz configured"
            + ("" if abs(hz - configured) <= 0.2 * configured else " (warning: more than 20% off; a loaded machine?)")
        )
    for topic in sorted(set(snapshot.get("samples", {})) - set(sem)):
        log(f"[gen_interfaces] warning: {topic} has no entry in the semantics table (units, rate, driver)")
    return render(build_model(snapshot), sem, parameter_tables(), message_definitions())


def parse_args(argv=None):
    parser = argparse.ArgumentParser(
        prog="gen_interfaces.py",
        description=__doc__.split("\n\n")[0],
        epilog="Exit status: 0 written (or current with --check), 1 stale (--check), 2 error, 130 interrupted.",
    )
    parser.add_argument(
        "--check",
        action="store_true",
        help="regenerate in memory and compare with the committed file; exit 1 with a diff if stale",
    )
    parser.add_argument("--output", type=Path, default=DOC, help=f"file to write or check (default {DOC.relative_to(ROOT)})")
    parser.add_argument(
        "--domain-id", type=int, default=None, help="ROS_DOMAIN_ID of the graph it starts (default: a free one in 201..232)"
    )
    parser.add_argument("--window", type=float, default=4.0, help="seconds of messages to observe (default 4)")
    parser.add_argument("--timeout", type=float, default=240.0, help="seconds to wait for the graph to come up (default 240)")
    parser.add_argument(
        "--snapshot",
        type=Path,
        default=None,
        help="render from this snapshot JSON (written by --save-snapshot) instead of starting a graph",
    )
    parser.add_argument("--save-snapshot", type=Path, default=None, help="also write the observed snapshot as JSON")
    parser.add_argument("--keep", action="store_true", help="keep the graph's logs and bag (the path is printed)")
    args = parser.parse_args(argv)
    if args.domain_id is not None and not 0 <= args.domain_id <= 232:
        parser.error(f"--domain-id must be in 0..232, got {args.domain_id}")
    if args.window <= 0 or args.timeout <= 0:
        parser.error("--window and --timeout must be > 0")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    log = lambda line: print(line, file=sys.stderr)  # noqa: E731
    if args.snapshot is not None:
        try:
            snapshot = json.loads(args.snapshot.read_text())
        except (OSError, ValueError) as error:
            print(f"gen_interfaces: cannot read snapshot {args.snapshot}: {error}", file=sys.stderr)
            return EXIT_ERROR
    else:
        workdir = Path(tempfile.mkdtemp(prefix="dlo-interfaces-"))
        try:
            domain = args.domain_id if args.domain_id is not None else free_domain()
            local = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST") == "LOCALHOST" and not os.environ.get(
                "ROS_STATIC_PEERS"
            )
            look_first = args.domain_id is not None or not local
            snapshot = capture(domain, args.window, args.timeout, workdir, log, look_first=look_first)
        except CaptureError as error:
            tail = (workdir / "launch.log").read_text()[-2000:] if (workdir / "launch.log").exists() else ""
            print(f"gen_interfaces: {error} (logs: {workdir})\n{tail}", file=sys.stderr)
            return EXIT_ERROR
        except KeyboardInterrupt:
            print("gen_interfaces: interrupted; the graph was stopped, nothing written", file=sys.stderr)
            if not args.keep:
                import shutil

                shutil.rmtree(workdir, ignore_errors=True)
            return 130
        finally:
            if args.keep:
                log(f"[gen_interfaces] logs and bag kept in {workdir}")
        if not args.keep:
            import shutil

            shutil.rmtree(workdir, ignore_errors=True)
        if args.save_snapshot:
            args.save_snapshot.write_text(json.dumps(snapshot, indent=1, default=str))
    text = generate(snapshot, log)
    if args.check:
        old = args.output.read_text() if args.output.exists() else ""
        if old == text:
            log(f"[gen_interfaces] {args.output} is current")
            return 0
        print(
            f"gen_interfaces: {args.output} is stale; regenerate with: python tools/gen_interfaces.py\n"
            + diff_summary(old, text),
            file=sys.stderr,
        )
        return EXIT_STALE
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(text)
    log(f"[gen_interfaces] wrote {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
