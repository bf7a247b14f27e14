"""docs/INTERFACES.md is generated (tools/gen_interfaces.py) and must be current.

The first test starts the graph (scripts/launch_graph.sh, real_time, one episode, on a free domain of
its own), regenerates the doc and compares it with the committed file: topics, types, publishers,
subscribers, QoS, frames, stamps, services, timers, messages and parameter tables. The others test
the generator's parts without a graph: the hook that records what nodes declare, the stale check
and its diff, the rate check. No assertion on wall time.
"""

import copy
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
GEN = ROOT / "tools" / "gen_interfaces.py"
sys.path.insert(0, str(ROOT / "tools"))

import gen_interfaces  # noqa: E402

STEP = 80_000_000  # ns per control step


def endpoint(kind, node, topic, type_, depth=10, durability="volatile", **extra):
    return {
        "kind": kind,
        "node": node,
        "exe": node,
        "pid": 1,
        "topic": topic,
        "type": type_,
        "history": "keep_last",
        "depth": depth,
        "reliability": "reliable",
        "durability": durability,
        **extra,
    }


def synthetic_snapshot(states=20):
    """A small graph: the sim publishes state + info, tactile answers every state, the policy commands."""
    stamps = [STEP * (i + 1) for i in range(states)]
    records = [
        {"kind": "node", "node": "sim_node", "exe": "sim_node", "pid": 1},
        endpoint("publisher", "sim_node", "/dlo/gripper/state", "dlo_msgs/msg/GripperState"),
        endpoint(
            "publisher",
            "sim_node",
            "/dlo/camera/camera_info",
            "sensor_msgs/msg/CameraInfo",
            depth=1,
            durability="transient_local",
        ),
        endpoint("subscription", "sim_node", "/dlo/gripper/cmd", "dlo_msgs/msg/GripperCommand"),
        endpoint("publisher", "sim_node", "/parameter_events", "rcl_interfaces/msg/ParameterEvent", depth=1000),
        {
            "kind": "service",
            "node": "sim_node",
            "exe": "sim_node",
            "pid": 1,
            "name": "/dlo/sim/reset",
            "type": "dlo_msgs/srv/ResetEpisode",
        },
        {
            "kind": "service",
            "node": "sim_node",
            "exe": "sim_node",
            "pid": 1,
            "name": "/sim_node/get_parameters",
            "type": "rcl_interfaces/srv/GetParameters",
        },
        {"kind": "timer", "node": "sim_node", "exe": "sim_node", "pid": 1, "period_s": 0.08, "callback": "on_real_time_tick"},
        {
            "kind": "parameter",
            "node": "sim_node",
            "exe": "sim_node",
            "pid": 1,
            "name": "use_sim_time",
            "default": False,
            "value": False,
            "description": "",
        },
        endpoint("subscription", "tactile_node", "/dlo/gripper/state", "dlo_msgs/msg/GripperState"),
        endpoint("publisher", "tactile_node", "/dlo/tactile/pose", "dlo_msgs/msg/TactilePose"),
        endpoint("subscription", "policy_node", "/dlo/tactile/pose", "dlo_msgs/msg/TactilePose"),
        endpoint("publisher", "policy_node", "/dlo/gripper/cmd", "dlo_msgs/msg/GripperCommand"),
    ]
    for step in range(3):  # the sim's publish calls: clock, camera_info once, then the state last
        for topic in ["/clock"] + ["/dlo/camera/camera_info"] * (step == 0) + ["/dlo/gripper/state"]:
            records.append({"kind": "publish", "pid": 1, "seq": len(records), "topic": topic})
    samples = {
        "/dlo/gripper/state": {"count": states, "stamps": stamps, "frame_id": "world"},
        "/dlo/camera/camera_info": {
            "count": 1,
            "stamps": [0],
            "frame_id": "top_camera_optical",
            "camera_info": {"width": 128, "height": 128, "k": [1.0] * 9, "distortion_model": "plumb_bob"},
        },
        "/dlo/tactile/pose": {"count": states, "stamps": stamps, "frame_id": "gripper"},
        "/dlo/gripper/cmd": {"count": states, "stamps": stamps, "frame_id": "world"},
    }
    return {"records": records, "samples": samples, "wire": {}}


def run_gen(*args, timeout=600):
    return subprocess.run([sys.executable, str(GEN), *args], capture_output=True, text=True, timeout=timeout)


def test_committed_doc_is_current_with_the_live_graph():
    """Regenerate from a running graph: any change of topics, types, endpoints, QoS, frames, stamps,
    services, timers, message or parameter declarations without regenerating the doc fails here."""
    result = run_gen("--check", timeout=900)
    assert result.returncode == 0, (
        "docs/INTERFACES.md is stale or could not be regenerated; run: python tools/gen_interfaces.py\n"
        + result.stdout
        + result.stderr[-6000:]
    )
    text = (ROOT / "docs" / "INTERFACES.md").read_text()
    for needle in (
        "`/dlo/gripper/state` | `dlo_msgs/msg/GripperState` | `sim_node`",
        "`/dlo/gripper/cmd` | `dlo_msgs/msg/GripperCommand` | `policy_node`",
        "`/dlo/sim/reset` | `dlo_msgs/srv/ResetEpisode` | `sim_node`",
        "| `/dlo/camera/camera_info` | `sensor_msgs/msg/CameraInfo` | `sim_node` |",
    ):
        assert needle in text
    assert "| `rate_factor` | double |" in text  # a parameter table row (dlo_common.params.markdown_table)
    assert "  sim_node --> t" in text and "--> policy_node" in text  # the Mermaid data flow


def test_check_passes_on_the_same_snapshot_and_fails_with_a_diff_when_the_graph_changes(tmp_path):
    snapshot = tmp_path / "snapshot.json"
    snapshot.write_text(json.dumps(synthetic_snapshot()))
    doc = tmp_path / "INTERFACES.md"
    assert run_gen("--snapshot", str(snapshot), "--output", str(doc)).returncode == 0
    text = doc.read_text()
    assert (
        "| `/dlo/gripper/state` | `dlo_msgs/msg/GripperState` | `sim_node` | `tactile_node` | step | "
        "reliable, volatile, keep last 10 | `world` |" in text
    )
    assert (
        "| `/dlo/camera/camera_info` | `sensor_msgs/msg/CameraInfo` | `sim_node` | — | latched | "
        "reliable, transient local, keep last 1 | `top_camera_optical` |" in text
    )
    assert "/parameter_events" not in text and "/sim_node/get_parameters" not in text  # infrastructure left out
    assert "| `/dlo/sim/reset` | `dlo_msgs/srv/ResetEpisode` | `sim_node` |" in text
    assert "| `sim_node` | 0.08 | `on_real_time_tick` |" in text
    assert "advances by 0.08 s per step (observed)" in text
    assert "in this order (observed): `/clock` → `/dlo/gripper/state`: the gripper state **last**" in text
    assert "**stamp**: = the step's state stamp" in text and "**stamp**: 0 (unset)" in text
    assert "`use_sim_time` is false for every node" in text
    assert "### `dlo_msgs/msg/GripperCommand`" in text and "float64 vx" in text  # message definitions
    assert "### `dlo_sim sim_node`" in text  # a parameter table for every *_node entry point
    assert run_gen("--snapshot", str(snapshot), "--output", str(doc), "--check").returncode == 0

    changed = synthetic_snapshot()
    changed["records"][1]["depth"] = 5  # the sim's state publisher asks for depth 5 now
    snapshot.write_text(json.dumps(changed))
    result = run_gen("--snapshot", str(snapshot), "--output", str(doc), "--check")
    assert result.returncode == 1
    assert "stale" in result.stderr and "keep last 5" in result.stderr and "keep last 10" in result.stderr
    assert doc.read_text() == text  # --check writes nothing


def test_a_new_subscriber_or_frame_makes_the_doc_stale():
    base = synthetic_snapshot()
    render = lambda snap: gen_interfaces.generate(snap, log=lambda line: None)  # noqa: E731
    text = render(base)
    more = copy.deepcopy(base)
    more["records"].append(endpoint("subscription", "vision_node", "/dlo/gripper/state", "dlo_msgs/msg/GripperState"))
    assert render(more) != text and "`tactile_node`, `vision_node`" in render(more)
    frame = copy.deepcopy(base)
    frame["samples"]["/dlo/tactile/pose"]["frame_id"] = "world"
    assert render(frame) != text
    stamp = copy.deepcopy(base)
    stamp["samples"]["/dlo/tactile/pose"]["stamps"] = [s + 1 for s in stamp["samples"]["/dlo/tactile/pose"]["stamps"]]
    assert "**stamp**: own" in render(stamp)
    assert "carry stamps that are not a state's: `/dlo/tactile/pose`" in render(stamp)  # a known deviation
    unframed = copy.deepcopy(base)
    unframed["samples"]["/dlo/gripper/cmd"]["frame_id"] = ""
    assert "empty in: `/dlo/gripper/cmd`" in render(unframed)


def test_rates_are_checked_against_the_declared_class_not_written():
    snap = synthetic_snapshot()
    declared = gen_interfaces.semantics()
    assert gen_interfaces.check_rates(snap, declared) == []
    snap["samples"]["/dlo/tactile/pose"]["count"] = 40  # two per state: a duplicate publisher
    snap["samples"]["/dlo/camera/camera_info"]["count"] = 20  # republished every step
    problems = gen_interfaces.check_rates(snap, declared)
    assert any(p.startswith("/dlo/tactile/pose: declared 'step', measured '2.00/state'") for p in problems)
    assert any(p.startswith("/dlo/camera/camera_info: declared 'latched'") for p in problems)
    # the doc does not change with the measured counts
    assert gen_interfaces.generate(snap, log=lambda line: None) == gen_interfaces.generate(
        synthetic_snapshot(), log=lambda line: None
    )


def test_hook_records_what_a_node_declares(tmp_path):
    """The sitecustomize hook records QoS depth (which DDS discovery does not report), timers and parameters."""
    code = (
        "import rclpy\n"
        "from rclpy.qos import QoSProfile, DurabilityPolicy\n"
        "from std_msgs.msg import String\n"
        "rclpy.init()\n"
        "n = rclpy.create_node('hooked')\n"
        "n.create_publisher(String, 'chatter', QoSProfile(depth=7, durability=DurabilityPolicy.TRANSIENT_LOCAL))\n"
        "n.create_subscription(String, '/heard', lambda m: None, 3)\n"
        "n.create_timer(0.125, lambda: None)\n"
        "p = n.create_publisher(String, 'said', 1)\n"
        "p.publish(String(data='a')); p.publish(String(data='b'))\n"
        "n.declare_parameter('speed', 0.5)\n"
        "n.destroy_node(); rclpy.shutdown()\n"
    )
    env = dict(
        os.environ,
        PYTHONPATH=f"{gen_interfaces.HOOK_DIR}{os.pathsep}{os.environ.get('PYTHONPATH', '')}",
        DLO_INTERFACES_DUMP=str(tmp_path),
    )
    result = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    records = [json.loads(line) for f in tmp_path.glob("*.jsonl") for line in f.read_text().splitlines()]
    by_kind = {}
    for r in records:
        assert r.get("node", "hooked") == "hooked"
        by_kind.setdefault(r["kind"], []).append(r)
    pub = [r for r in by_kind["publisher"] if r["topic"] == "/chatter"]
    assert pub == [
        {
            **pub[0],
            "type": "std_msgs/msg/String",
            "history": "keep_last",
            "depth": 7,
            "durability": "transient_local",
            "reliability": "reliable",
        }
    ]
    assert [(r["topic"], r["depth"]) for r in by_kind["subscription"]] == [("/heard", 3)]
    assert [r["period_s"] for r in by_kind["timer"]] == [0.125]
    said = [r["seq"] for r in by_kind["publish"] if r["topic"] == "/said"]
    assert len(said) == 2 and said[0] < said[1]  # in order (the declared parameter's event came first)
    assert {"name": "speed", "default": 0.5, "value": 0.5}.items() <= [r for r in by_kind["parameter"] if r["name"] == "speed"][
        0
    ].items()


def test_help_and_bad_options():
    result = run_gen("--help")
    assert result.returncode == 0 and "--check" in result.stdout and "docs/INTERFACES.md" in result.stdout
    bad = run_gen("--domain-id", "999")
    assert bad.returncode == 2 and "--domain-id must be in 0..232" in bad.stderr
    missing = run_gen("--snapshot", "/nonexistent/snapshot.json")
    assert missing.returncode == 2 and "cannot read snapshot" in missing.stderr


@pytest.mark.parametrize("topic", gen_interfaces.CONTRACT_TOPICS)
def test_every_contract_topic_has_units_and_a_driver_rule(topic):
    """Every topic of the contract (the registry's but the internal and provenance ones) has its values and what a
    real robot does: hand-written, or from its record (a topic added to dlo_common.topics needs no line here)."""
    entry = gen_interfaces.semantics()[topic]
    assert entry["rate"] in ("step", "latched") and entry["units"] and entry["driver"]


def test_a_topic_without_a_hand_written_line_is_documented_from_its_record(monkeypatch):
    from dlo_common import topics

    wrist = topics.Topic(
        "/dlo/test/force",
        "made_up_msgs/msg/WrenchStamped",
        "sim_node",
        "observation",
        "the force the cable pulls the gripper with",
        key="wrist",
        driver="publishes (a wrist force sensor)",
        plot=(topics.Series("wrench.force.x", "F_x", "N"), topics.Series("wrench.force.y", "F_y", "N")),
    )
    monkeypatch.setattr(topics, "TOPICS", topics.TOPICS + (wrist,))
    entry = gen_interfaces.semantics()[wrist.name]
    assert entry == {
        "rate": "step",
        "units": "the force the cable pulls the gripper with: `wrench.force.x` F_x [N], `wrench.force.y` F_y [N]",
        "driver": "publishes (a wrist force sensor)",
        "role": "publishes (a wrist force sensor)",
    }
    assert gen_interfaces.standard_messages().startswith("`rosgraph_msgs/Clock`, `sensor_msgs/PointCloud2`, `Image`")
    assert gen_interfaces.standard_messages().endswith(" and `made_up_msgs/WrenchStamped`")  # a package of its own
