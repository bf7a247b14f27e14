"""scripts/launch_graph.sh's exit status in every combination of failures its --help and the README
name (0 every episode ran and the bag is complete; 2 a bad option or a node rejecting its parameters;
3 a node died or exited early, the sim interrupted on its own or refusing to start; 4 the recording
failed: a write error, the recorder died or dropped messages, a bag left unclosed; 130 interrupted),
and the one line that names the cause.

The graph's nodes are stand-ins here (a fake ``ros2`` on PATH, which the launcher uses like a real ROS 2
install's): each behaves as a real node does in that failure (exit status, the log line the launcher
reads, the bag files it leaves), so each case runs in seconds. The real faults behind them are in
tests/test_graph_isolation.py (a recorder killed with SIGKILL, a full disk, the sim interrupted, a
second simulator) and tests/test_graph.py (Ctrl-C mid-run)."""

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from dlo_bringup.graph import STOP_LIMIT
from dlo_bringup.launcher import watch_hint
from dlo_common.node_main import TEARDOWN_LIMIT
from std_msgs.msg import String

ROOT = Path(__file__).resolve().parents[1]
LAUNCH = ROOT / "scripts" / "launch_graph.sh"
NODES = {
    "sim_node": "sim",
    "recorder_node": "recorder",
    "tactile_node": "tactile",
    "vision_node": "vision",
    "policy_node": "policy",
}  # what the launcher starts without --foxglove (the bridge is not faked here)

# What a node does, from FAKE_GRAPH (JSON, by launcher name): "exit" its status (default 0; "SIGKILL": killed),
# "when" "start" (the sim: at once, before it says it is alone on the domain, as a sim rejecting its parameters or
# refusing to start next to another simulator does, so the launcher starts no other node; any other node: once the
# others handle signals), "signal" (on SIGINT/SIGTERM, the default) or, for the sim, "episodes" (after writing
# "episodes" outcome lines, once the whole graph has started); "say" lines to print first; the recorder creates its
# bag directory with a .mcap and writes metadata.yaml when it closes ("closes": true), and "summary" (JSON) to its
# summary_file; "stop_delay" s it then takes before it exits (a slow teardown); "slow_start": true, a node still
# starting (importing) when the launcher is interrupted: it sets no signal handler for 10 minutes.
FAKE_ROS2 = r'''#!{python}
import json, os, signal, sys, time
from pathlib import Path

_, pkg, exe, *rest = sys.argv[1:]
name = {nodes}[exe]
plan = json.loads(os.environ["FAKE_GRAPH"]).get(name, {{}})
params = dict(rest[i + 1].split(":=", 1) for i, arg in enumerate(rest) if arg == "-p")
bag = Path(params["output"]) if name == "recorder" else None


def finish(*_):
    for line in plan.get("say", []):
        print(line, flush=True)
    if bag is not None and plan.get("closes", True):
        (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: {{}}\n")
    if "summary" in plan:
        Path(params["summary_file"]).write_text(json.dumps(plan["summary"]) + "\n")
    time.sleep(plan.get("stop_delay", 0))
    if plan.get("exit") == "SIGKILL":
        os.kill(os.getpid(), signal.SIGKILL)
    os._exit(plan.get("exit", 130 if name == "sim" else 0))


if plan.get("slow_start"):  # still importing, as a real node before rclpy.init: SIGINT at whatever it started with
    Path(os.environ["FAKE_READY"]).with_name(f"starting_{{name}}").touch()
    time.sleep(600)
for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):  # a background job of bash starts with SIGINT ignored
    signal.signal(sig, finish)
Path(os.environ["FAKE_READY"]).with_name(f"args_{{name}}.json").write_text(json.dumps(rest))  # what the launcher passed
(Path(os.environ["FAKE_READY"]) / name).touch()  # from here on a signal is handled, not ignored
if bag is not None:
    bag.mkdir(parents=True)
    (bag / (bag.name + "_0.mcap")).write_bytes(b"\x89MCAP0\r\n")
when = plan.get("when", "signal")
if name == "sim" and when == "start":
    finish()
if name == "sim":
    print(f"[INFO] [sim_node]: alone on ROS_DOMAIN_ID={{os.environ['ROS_DOMAIN_ID']}}", flush=True)


def wait_for_the_graph():
    """Until every other node of the graph handles signals: a loaded machine starts Python slowly, and a node
    the launcher stops before it has set its handler ends by KeyboardInterrupt, not as the case plans."""
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not all(
            (Path(os.environ["FAKE_READY"]) / n).exists() for n in json.loads(os.environ["FAKE_NODES"]) if n != name):
        time.sleep(0.05)


if when == "start":  # a node other than the sim fails once the graph is up, as a node failing in a running graph
    wait_for_the_graph()
    finish()
if when == "episodes":  # the sim: once every node of the graph runs and handles signals, its episodes, then it ends
    outcomes = Path(params["summary_file"])
    wait_for_the_graph()
    seed = int(params["seed"])
    with outcomes.open("a") as f:
        for k in range(plan["episodes"]):
            f.write(json.dumps({{"episode": k, "seed": seed + k, "outcome": "hold_the_end", "outcome_code": 1,
                                "outcome_authors": "stop_before", "time_at_end": 140, "how_far": 0,
                                "episode_return": 100.5, "episode_length": 150, "task_rules": "authors_code"}}) + "\n")
    finish()
while True:
    time.sleep(1)
'''


def test_the_fake_graph_is_the_launchers_graph(tmp_path):
    """The stand-ins are every node the launcher starts (the graph's description, dlo_bringup.graph), but the
    Foxglove bridge, which only --foxglove starts: a node added to the graph is added here too."""
    from dlo_bringup.graph import graph_nodes
    from dlo_bringup.options import parse_args, resolve

    options = resolve(parse_args(["--record", str(tmp_path / "bag"), "--foxglove", "--policy", "random"]))
    started = [(spec.name, spec.package, spec.executable) for spec in graph_nodes(options, tmp_path)]
    assert {exe: name for name, _, exe in started if name != "foxglove"} == NODES
    assert ("foxglove", "dlo_viz", "foxglove_bridge") in started


def ran(plan, *args):
    return plan, args


def episodes(n, status=0):
    return {"when": "episodes", "episodes": n, "exit": status}


FAILED = "recording failed: no space left on device (write to run_0.mcap: [Errno 28] No space left on device)"
CASES = {
    # every episode ran
    "complete": (
        ran({"sim": episodes(2)}, "--episodes", 2, "--record", "BAG"),
        0,
        ["[launch] bag: BAG (inspect: dlo-bag-info BAG)"],
    ),
    "complete_without_a_bag": (ran({"sim": episodes(2)}, "--episodes", 2), 0, []),
    "recorder_dropped_messages": (
        ran({"sim": episodes(2), "recorder": {"exit": 1}}, "--episodes", 2, "--record", "BAG"),
        4,
        ["[launch] recording incomplete: the recorder dropped messages (see LOGS/recorder.log)"],
    ),
    "recording_failed_at_the_end": (
        ran({"sim": episodes(2), "recorder": {"exit": 3, "say": [FAILED]}}, "--episodes", 2, "--record", "BAG"),
        4,
        ["[launch] recording failed: no space left on device (see LOGS/recorder.log)"],
    ),
    "bag_left_unclosed": (
        ran({"sim": episodes(2), "recorder": {"closes": False}}, "--episodes", 2, "--record", "BAG"),
        4,
        ["[launch] the bag BAG is incomplete: recover it with: dlo-bag-recover BAG"],
    ),
    "recorder_ended_oddly": (
        ran({"sim": episodes(2), "recorder": {"exit": 5}}, "--episodes", 2, "--record", "BAG"),
        4,
        ["[launch] the recorder ended with status 5; the end of its log:"],
    ),
    # a node of the graph fails while it runs
    "recorder_died": (
        ran({"recorder": {"when": "start", "exit": 1, "closes": False}}, "--episodes", 2, "--record", "BAG"),
        4,
        [
            "[launch] recorder exited early (status 1); the end of its log:",
            "[launch] the bag BAG is incomplete: recover it with: dlo-bag-recover BAG",
        ],
    ),
    "recorder_killed": (
        ran({"recorder": {"when": "start", "exit": "SIGKILL", "closes": False}}, "--episodes", 2, "--record", "BAG"),
        4,
        ["[launch] recorder exited early (status 137: killed by SIGKILL); the end of its log:"],
    ),
    "recorder_stopped_early": (
        ran({"recorder": {"when": "start"}}, "--episodes", 2, "--record", "BAG"),
        4,
        ["[launch] recorder exited early (status 0); the end of its log:", "[launch] bag: BAG (inspect: dlo-bag-info BAG)"],
    ),  # closed, but not every episode
    "recording_failed_mid_run": (
        ran({"recorder": {"when": "start", "exit": 3, "say": [FAILED]}}, "--episodes", 2, "--record", "BAG"),
        4,
        [
            "[launch] recording failed: no space left on device: the recorder stopped (status 3); graph stopped",
            "[launch] bag: BAG (inspect: dlo-bag-info BAG)",
        ],
    ),
    "policy_died": (
        ran({"policy": {"when": "start", "exit": 1}}, "--episodes", 2),
        3,
        ["[launch] policy exited early (status 1); the end of its log:"],
    ),
    "vision_killed": (
        ran({"vision": {"when": "start", "exit": "SIGKILL"}}, "--episodes", 2),
        3,
        ["[launch] vision exited early (status 137: killed by SIGKILL); the end of its log:"],
    ),
    "tactile_rejected_its_parameters": (
        ran({"tactile": {"when": "start", "exit": 2}}, "--episodes", 2),
        2,
        ["[launch] tactile exited early (status 2); the end of its log:"],
    ),
    "policy_died_and_recorder_dropped": (
        ran({"policy": {"when": "start", "exit": 1}, "recorder": {"exit": 1}}, "--episodes", 2, "--record", "BAG"),
        4,
        [
            "[launch] policy exited early (status 1); the end of its log:",
            "[launch] recording incomplete: the recorder dropped messages (see LOGS/recorder.log)",
        ],
    ),
    # the sim ends early
    "sim_ended_short": (
        ran({"sim": episodes(1)}, "--episodes", 2),
        3,
        ["[launch] sim exited early (status 0, 1 of 2 episodes done); the end of its log:"],
    ),
    "sim_interrupted_alone": (
        ran({"sim": episodes(1, 130)}, "--episodes", 3),
        3,
        ["[launch] sim exited early (status 130: interrupted by SIGINT, 1 of 3 episodes done); the end of its log:"],
    ),
    "unlimited_sim_ended": (
        ran({"sim": episodes(1)}, "--episodes", 0),
        3,
        ["[launch] sim exited early (status 0, 1 of unlimited episodes done); the end of its log:"],
    ),
    "sim_rejected_its_parameters": (
        ran({"sim": {"when": "start", "exit": 2}}, "--episodes", 2),
        2,
        ["[launch] sim exited early (status 2, 0 of 2 episodes done); the end of its log:"],
    ),
    "sim_refused_to_start": (
        ran({"sim": {"when": "start", "exit": 3}}, "--episodes", 2, "--record", "BAG"),
        3,
        ["[launch] sim exited early (status 3, 0 of 2 episodes done); the end of its log:"],
    ),
}
INTERRUPTS = {  # the launcher gets the signal while the graph runs (unlimited episodes)
    "interrupted": (
        signal.SIGINT,
        {},
        130,
        ["[launch] interrupted: stopping the graph", "[launch] bag: BAG (inspect: dlo-bag-info BAG)"],
    ),
    "terminated": (signal.SIGTERM, {}, 130, ["[launch] interrupted: stopping the graph"]),
    "interrupted_and_the_recording_failed": (
        signal.SIGINT,
        {"recorder": {"exit": 3, "say": [FAILED]}},
        130,
        [
            "[launch] interrupted: stopping the graph",
            "[launch] recording failed: no space left on device (see LOGS/recorder.log)",
        ],
    ),
    "interrupted_and_the_recorder_dropped": (
        signal.SIGINT,
        {"recorder": {"exit": 1}},
        130,
        ["[launch] recording incomplete: the recorder dropped messages (see LOGS/recorder.log)"],
    ),
}


def fake_graph_env(tmp_path, plan, args, ros2=True):
    """The environment in which the launcher's nodes are the stand-ins of ``plan``: on a ROS 2 install (a fake
    ``ros2`` on PATH: `ros2 run`), or with ``ros2=False`` on the wheels (no ros2: scripts/ros2run finds them in
    a package prefix of their own)."""
    fake = tmp_path / "bin" / "ros2"
    fake.parent.mkdir()
    fake.write_text(FAKE_ROS2.format(python=sys.executable, nodes=NODES))
    fake.chmod(0o755)
    env = {k: v for k, v in os.environ.items() if k != "DLO_USE_ROS2RUN"}
    if ros2:
        env["PATH"] = f"{fake.parent}{os.pathsep}{env['PATH']}"
    else:
        prefix = tmp_path / "prefix"
        for exe in [*NODES, "foxglove_bridge"]:
            package = {
                "sim_node": "dlo_sim",
                "recorder_node": "dlo_bag",
                "tactile_node": "dlo_perception",
                "vision_node": "dlo_perception",
                "policy_node": "dlo_policy",
                "foxglove_bridge": "dlo_viz",
            }[exe]
            index = prefix / "share" / "ament_index" / "resource_index" / "packages" / package
            index.parent.mkdir(parents=True, exist_ok=True)
            index.touch()
            script = prefix / "lib" / package / exe
            script.parent.mkdir(parents=True, exist_ok=True)
            script.write_text(f'#!/bin/sh\nexec "{fake}" run {package} {exe} "$@"\n')
            script.chmod(0o755)
        assert shutil.which("ros2", path=env["PATH"]) is None
        env.update(DLO_USE_ROS2RUN="1", AMENT_PREFIX_PATH=str(prefix))
    (tmp_path / "ready").mkdir()
    nodes = [n for n in NODES.values() if n != "recorder" or "--record" in args]  # what the launcher starts
    env.update(FAKE_GRAPH=json.dumps(plan), FAKE_READY=str(tmp_path / "ready"), FAKE_NODES=json.dumps(nodes))
    return env


def start(tmp_path, plan, args, own_groups, ros2=True, logs=True, env=None):
    """launch_graph.sh with the fake nodes of ``plan``, in its own session; (process, out file, logs, bag).
    ``logs``: with --logs (else the launcher makes a temp dir)."""
    logs_dir, bag = tmp_path / "logs", tmp_path / "bag"
    env = {**fake_graph_env(tmp_path, plan, args, ros2), **(env or {})}
    argv = [str(bag) if a == "BAG" else str(a) for a in args] + (["--logs", str(logs_dir)] if logs else [])
    out = tmp_path / "launch.out"
    with out.open("w") as f:
        proc = subprocess.Popen(
            ["bash", str(LAUNCH), *argv, "--status-period", "0"],
            stdout=f,
            stderr=subprocess.STDOUT,
            env=env,
            start_new_session=True,
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
        )
    own_groups(proc.pid)
    return proc, out, logs_dir, bag


def check(proc, out, logs, bag, rc, lines):
    try:
        status = proc.wait(timeout=300)
    except subprocess.TimeoutExpired:
        raise AssertionError(f"the launcher did not end:\n{out.read_text()}") from None
    text = out.read_text()
    assert status == rc, text
    printed = text.splitlines()
    for line in lines:
        line = line.replace("LOGS", str(logs)).replace("BAG", str(bag))
        assert line in printed, f"no line {line!r} in:\n{text}"
    assert "Traceback" not in text
    return text


@pytest.mark.parametrize("case", sorted(CASES))
def test_the_exit_status_and_its_cause(case, tmp_path, own_groups):
    (plan, args), rc, lines = CASES[case]
    proc, out, logs, bag = start(tmp_path, plan, args, own_groups)
    text = check(proc, out, logs, bag, rc, lines)
    if case in ("sim_rejected_its_parameters", "sim_refused_to_start"):  # the graph stopped at the sim: nothing else
        # was started (the sim never said it was alone on the domain)
        assert not any((logs / f"{node}.log").exists() for node in ("recorder", "tactile", "vision", "policy")), text
    if rc == 0:  # the run's outcome table follows (both rules), and no node was reported
        assert "hold_the_end            2/2    100.0%    0/2      0.0%" in text and "exited early" not in text


@pytest.mark.parametrize("case", sorted(INTERRUPTS))
def test_an_interrupted_run_is_130_whatever_else_failed(case, tmp_path, own_groups):
    sig, plan, rc, lines = INTERRUPTS[case]
    proc, out, logs, bag = start(tmp_path, plan, ("--episodes", 0, "--record", "BAG"), own_groups)
    deadline = time.monotonic() + 120
    while {p.name for p in (tmp_path / "ready").iterdir()} != set(NODES.values()):  # every node handles signals
        assert proc.poll() is None and time.monotonic() < deadline, out.read_text()
        time.sleep(0.1)
    proc.send_signal(sig)
    check(proc, out, logs, bag, rc, lines)


@pytest.mark.parametrize("name", ["policy", "recorder"])
def test_an_interrupt_while_a_node_still_starts_stops_it_with_that_sigint(name, tmp_path, own_groups):
    """Ctrl-C while a node is still starting (importing torch, before rclpy.init sets its signal handlers)
    stops it then: a bash background job starts with SIGINT ignored, and such a node used to be killed with
    SIGKILL 10 s later ("did not stop within 10 s of SIGINT"), a recorder perhaps mid-way through opening its bag.
    The recorder's own status then is the interrupt's, not a failure to report with its log."""
    proc, out, logs, bag = start(tmp_path, {name: {"slow_start": True}}, ("--episodes", 0, "--record", "BAG"), own_groups)
    deadline = time.monotonic() + 120
    while not (tmp_path / f"starting_{name}").exists():
        assert proc.poll() is None and time.monotonic() < deadline, out.read_text()
        time.sleep(0.1)
    proc.send_signal(signal.SIGINT)
    text = check(proc, out, logs, bag, 130, ["[launch] interrupted: stopping the graph"])
    assert "did not stop within" not in text and "the recorder ended" not in text, text
    assert "KeyboardInterrupt" in (logs / f"{name}.log").read_text()  # it ended by that SIGINT, in its import


BAD_OPTIONS = {
    "episodes": (["--episodes", "-1"], "launch_graph: --episodes must be a number >= 0, got '-1'"),
    "seed": (["--seed", "x"], "launch_graph: --seed must be a number >= 0, got 'x'"),
    "mode": (["--mode", "fast"], "launch_graph: --mode must be step_locked or real_time"),
    "status_period": (["--status-period", "soon"], "launch_graph: --status-period must be a number of seconds >= 0, got 'soon'"),
    "domain_id": (["--domain-id", "300"], "launch_graph: --domain-id must be a number in 0..232, got '300'"),
    "namespace": (
        ["--namespace", "9lives"],
        "launch_graph: --namespace must be a ROS name like 'robot1' or 'lab/robot1', got '9lives'",
    ),
    "foxglove_port": (["--foxglove", "70000"], "launch_graph: --foxglove PORT must be in 0..65535, got '70000'"),
    "record_exists": (["--record", "EXISTING"], "launch_graph: --record EXISTING already exists; choose a new directory"),
    "unknown": (["--bogus"], "launch_graph: unknown option '--bogus' (options: scripts/launch_graph.sh --help)"),
    "no_value": (["--seed"], "launch_graph: --seed needs a value (options: scripts/launch_graph.sh --help)"),
    "carry_law": (["--carry-law", "flex"], "launch_graph: --carry-law must be paper or authors, got 'flex'"),
    "vision_source": (["--vision-source", "camera"], "launch_graph: --vision-source must be image or particles, got 'camera'"),
    "contact_radius": (
        ["--contact-radius", "0.007"],
        "launch_graph: --contact-radius must be a number in (0, 0.006] m, got '0.007'",
    ),
    "contact_radius_text": (
        ["--contact-radius", "5e-3"],
        "launch_graph: --contact-radius must be a number in (0, 0.006] m, got '5e-3'",
    ),
    "move_spacing": (
        ["--move-spacing", "0.02"],
        "launch_graph: --move-spacing must be a number in [0, 0.01] m (0: the cable's own spacing), got '0.02'",
    ),
    "move_spacing_negative": (
        ["--move-spacing", "-0.004"],
        "launch_graph: --move-spacing must be a number in [0, 0.01] m (0: the cable's own spacing), got '-0.004'",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_OPTIONS))
def test_a_bad_option_is_exit_2_in_one_line_before_anything_starts(case, tmp_path):
    """launch_graph.sh --help (exit status 2: bad option): one line naming the option, nothing started.
    (--policy, --without, --checkpoint, --task-rules: tests/test_launch_feedback.py; --tactile-noise:
    tests/test_tactile_noise_setting.py.)"""
    args, message = BAD_OPTIONS[case]
    existing = tmp_path / "existing_bag"
    existing.mkdir()
    args = [str(existing) if a == "EXISTING" else a for a in args]
    logs = tmp_path / "logs"
    result = subprocess.run(["bash", str(LAUNCH), "--logs", str(logs), *args], capture_output=True, text=True, timeout=120)
    assert result.returncode == 2, result.stdout + result.stderr
    assert result.stderr.splitlines() == [message.replace("EXISTING", str(existing))], result.stderr  # no usage dump
    assert result.stdout == "" and not logs.exists()  # no domain chosen, no node started


NOTE = (
    "[launch] note: the policy was trained with task_rules={}, single_particle_grip={}; this graph runs "
    "task_rules={}, single_particle_grip={} (as asked)"
)
SIM_SETTINGS = {  # launcher options (OURS: a copy of the shipped policy's run as if trained with our finite grip)
    # -> the sim's task_rules and single_particle_grip, and the note on settings that differ from the training
    "shipped": ([], "authors_code", "true", None),
    "shipped_asked_for_our_grip": (
        ["--single-particle-grip", "false"],
        "authors_code",
        "false",
        NOTE.format("authors_code", "true", "authors_code", "false"),
    ),
    "trained_with_our_grip": (["--checkpoint", "OURS"], "authors_code", "false", None),
    "trained_with_our_grip_asked_for_the_authors_grip": (
        ["--checkpoint", "OURS", "--single-particle-grip"],
        "authors_code",
        "true",
        NOTE.format("authors_code", "false", "authors_code", "true"),
    ),
    "trained_with_it_asked_otherwise": (
        ["--checkpoint", "OURS", "--single-particle-grip", "true", "--task-rules", "paper_text"],
        "paper_text",
        "true",
        NOTE.format("authors_code", "false", "paper_text", "true"),
    ),
    "scripted_policy": (["--policy", "tactile_reactive"], "authors_code", "false", None),
    "scripted_policy_asked": (["--policy", "tactile_reactive", "--single-particle-grip", "true"], "authors_code", "true", None),
    "learning_online": (["--train-out", "OUT"], "authors_code", "false", None),  # from scratch: no trained task
}


@pytest.mark.parametrize("case", sorted(SIM_SETTINGS))
def test_the_sim_runs_the_task_the_policy_was_trained_on_unless_asked(case, tmp_path, own_groups):
    """launch_graph.sh --help (--task-rules, --single-particle-grip): with --policy sac the sim gets the task
    rules and the grip of the checkpoint's run (its config.yaml: the shipped policy, trained with the authors'
    one-particle grip, meets that grip without a flag, one trained with ours meets ours); a setting asked for
    that differs is run, with a note."""
    args, rules, grip, note = SIM_SETTINGS[case]
    shipped = ROOT / "ros_ws" / "src" / "dlo_policy" / "policies" / "all"
    ours = tmp_path / "finite_grip_run"
    ours.mkdir()
    (ours / "policy.pt").write_bytes((shipped / "policy.pt").read_bytes())
    config = (shipped / "config.yaml").read_text()
    assert "  task_rules: authors_code\n  single_particle_grip: true\n" in config
    (ours / "config.yaml").write_text(config.replace("  single_particle_grip: true\n", "  single_particle_grip: false\n"))
    args = [str(ours / "policy.pt") if a == "OURS" else str(tmp_path / "online") if a == "OUT" else a for a in args]
    proc, out, logs, bag = start(tmp_path, {"sim": episodes(1)}, ["--episodes", "1", *args], own_groups)
    text = check(proc, out, logs, bag, 0, [note] if note else [])
    assert ("[launch] note:" in text) == (note is not None), text
    sim = json.loads((tmp_path / "args_sim.json").read_text())
    given = {sim[i + 1].split(":=")[0]: sim[i + 1].split(":=")[1] for i, a in enumerate(sim) if a == "-p"}
    assert (given["task_rules"], given["single_particle_grip"]) == (rules, grip), given


@pytest.mark.parametrize("config", ["broken", "missing_file"])
def test_a_checkpoint_whose_run_cannot_be_read_is_exit_2_in_one_line(config, tmp_path):
    """--policy sac: the checkpoint's run config.yaml is read before anything starts; unreadable: exit 2."""
    checkpoint = tmp_path / "run" / "policy.pt"
    checkpoint.parent.mkdir()
    checkpoint.write_bytes(b"")
    (checkpoint.parent / "config.yaml").write_text("env_options: {task_rules: authors_code\n")
    if config == "missing_file":
        checkpoint.unlink()
    logs = tmp_path / "logs"
    result = subprocess.run(
        ["bash", str(LAUNCH), "--logs", str(logs), "--checkpoint", str(checkpoint)], capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 2, result.stdout + result.stderr
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
    assert lines[0] == (
        f"launch_graph: --checkpoint {checkpoint}: no such file"
        if config == "missing_file"
        else f"launch_graph: --checkpoint: checkpoint {checkpoint}: its run's config.yaml cannot be read: "
        f"{checkpoint.parent / 'config.yaml'}: not valid YAML (line 2, column 1): "
        "expected ',' or '}', but got '<stream end>'"
    )
    assert result.stdout == "" and not logs.exists()


COMPLETE = {"written": 120, "dropped": 0, "complete": True, "failure": ""}  # the recorder's summary_file
RECORDER_STOPS = {  # (issue 38 item 9) how the recorder stops once the sim has run its episodes
    # its closing work and a middleware teardown up to dlo_common.node_main's limit: longer than the launcher
    # used to wait before its SIGKILL (as long as that limit), which made a complete bag a failed recording
    "slow_to_stop": (
        {"stop_delay": TEARDOWN_LIMIT + 1, "summary": COMPLETE},
        0,
        ["[launch] bag: BAG (inspect: dlo-bag-info BAG)"],
    ),
    # the bag closed and complete, then the teardown cut at that limit (exit 1, its stacks in its log)
    "teardown_cut": (
        {"stop_delay": TEARDOWN_LIMIT + 1, "exit": 1, "summary": COMPLETE},
        0,
        [
            "[launch] the recorder's middleware teardown was cut short after it had closed the bag (status 1;"
            " its stacks: LOGS/recorder.log); the recording is complete: 120 messages written, none dropped",
            "[launch] bag: BAG (inspect: dlo-bag-info BAG)",
        ],
    ),
    # exit 1 with messages dropped, as its summary counts them: a failed recording
    "dropped_by_its_count": (
        {"exit": 1, "summary": dict(COMPLETE, dropped=3)},
        4,
        ["[launch] recording incomplete: the recorder dropped messages (see LOGS/recorder.log)"],
    ),
}


@pytest.fixture(scope="module")
def recorder_stops(request, tmp_path_factory):
    """The launches of the RECORDER_STOPS cases the session runs, all started at once: each recorder takes its
    stop_delay (TEARDOWN_LIMIT + 1 s) to stop, which one launch after the other cost that long each. case ->
    (process, out file, logs, bag); a test registers its launch with its own ``own_groups`` (stopped at its
    teardown as if it had started it), and whatever is left of a launch no test waited for is killed here."""
    cases = sorted(
        {
            item.callspec.params["case"]
            for item in request.session.items
            if "recorder_stops" in getattr(item, "fixturenames", ()) and hasattr(item, "callspec")
        }
    )
    runs = {}
    for case in cases:
        recorder = RECORDER_STOPS[case][0]
        plan, args = {"sim": episodes(2), "recorder": recorder}, ("--episodes", 2, "--record", "BAG")
        runs[case] = start(tmp_path_factory.mktemp(case), plan, args, lambda pid: None)
    yield runs
    for proc, *_ in runs.values():
        if proc.poll() is None:  # (fake nodes: nothing to close)
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


@pytest.mark.parametrize("case", sorted(RECORDER_STOPS))
def test_a_recorder_is_given_its_teardown_and_a_cut_one_with_a_complete_bag_is_no_failure(case, recorder_stops, own_groups):
    """The launcher waits out a recorder's closing work and teardown (longer than TEARDOWN_LIMIT), takes a teardown
    cut after a complete bag for no failure, and fails a recording whose summary counts dropped messages."""
    _, rc, lines = RECORDER_STOPS[case]
    proc, out, logs, bag = recorder_stops[case]
    own_groups(proc.pid)
    text = check(proc, out, logs, bag, rc, lines)
    assert "did not stop within" not in text and STOP_LIMIT > TEARDOWN_LIMIT + 5


BYSTANDER = r"""
import signal, sys, time
from pathlib import Path
for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
    signal.signal(sig, lambda signum, frame: Path(sys.argv[1]).open("a").write(f"{signum}\n"))
while True:
    time.sleep(1)
"""
# In a PID namespace of its own (so that the pids are the test's alone): the launcher with --episodes 0, SIGINT to
# it; the sim takes a few seconds to stop; the tactile node stops at once; once the launcher has reaped it, a
# bystander process is started with the tactile node's pid (ns_last_pid). It must get no signal from the launcher.
PID_REUSE = r"""
import json, os, re, signal, subprocess, sys, time
from pathlib import Path

launch, logs, ready, record, nodes = sys.argv[1:6]
out = open(Path(logs).parent / "launch.out", "w")
proc = subprocess.Popen(["bash", launch, "--episodes", "0", "--logs", logs, "--status-period", "0"], stdout=out,
                        stderr=subprocess.STDOUT)
deadline = time.monotonic() + 120
while {p.name for p in Path(ready).iterdir()} != set(json.loads(nodes)):
    assert proc.poll() is None and time.monotonic() < deadline, "the graph did not start"
    time.sleep(0.05)
text = (Path(logs).parent / "launch.out").read_text()
tactile = int(re.search(r"\[launch\] tactile \(pid (\d+)\)", text).group(1))
proc.send_signal(signal.SIGINT)
bystander = None
while proc.poll() is None and bystander is None and time.monotonic() < deadline:
    if not os.path.exists(f"/proc/{tactile}"):  # reaped: its pid is free
        with open("/proc/sys/kernel/ns_last_pid", "w") as f:
            f.write(str(tactile - 1))
        candidate = subprocess.Popen([sys.executable, "-c", sys.argv[6], record])
        if candidate.pid == tactile:
            bystander = candidate
        else:  # another process took the pid first: try again
            candidate.kill()
            candidate.wait()
    time.sleep(0.01)
rc = proc.wait(timeout=300)
print(json.dumps({"rc": rc, "planted": bystander is not None,
                  "alive": bystander is not None and bystander.poll() is None}))
"""


def test_a_reused_pid_of_a_node_that_ended_gets_no_signal(tmp_path, own_groups):
    """Issue 38 item 9: the launcher signalled the pids it stored, also of nodes that had ended: a pid the kernel
    had given to another process meanwhile got SIGINT, and 10 s later SIGKILL. It signals only its children that
    still run."""
    if (
        os.geteuid() != 0
        or subprocess.run(["unshare", "--pid", "--fork", "--mount-proc", "true"], capture_output=True).returncode != 0
    ):
        pytest.skip("needs a PID namespace of the test's own (root, unshare) to give a pid to a process of its choice")
    plan = {"sim": {"stop_delay": 4}}
    env = fake_graph_env(tmp_path, plan, ())
    logs = tmp_path / "logs"
    harness = subprocess.Popen(
        [
            "unshare",
            "--pid",
            "--fork",
            "--mount-proc",
            sys.executable,
            "-c",
            PID_REUSE,
            str(LAUNCH),
            str(logs),
            str(tmp_path / "ready"),
            str(tmp_path / "signals"),
            env["FAKE_NODES"],
            BYSTANDER,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        start_new_session=True,
    )
    own_groups(harness.pid)
    result, err = harness.communicate(timeout=600)
    launch_out = (tmp_path / "launch.out").read_text() if (tmp_path / "launch.out").exists() else ""
    assert harness.returncode == 0, err + launch_out
    result = json.loads(result)
    assert result["rc"] == 130, launch_out
    assert result["planted"], launch_out  # the tactile node's pid was given to the bystander while the sim stopped
    signals = (tmp_path / "signals").read_text().split() if (tmp_path / "signals").exists() else []
    assert result["alive"] and signals == [], (signals, launch_out)
    assert "did not stop within" not in launch_out


def test_the_temp_logs_go_when_the_run_went_well_and_are_named_when_kept(tmp_path, own_groups):
    """Issue 38 item 8: each launch left a dlo-graph-* folder in the temp directory. Without --logs it goes at the
    end of a run that went well; a failed run keeps it and says where."""
    temp = tmp_path / "temp"
    temp.mkdir()
    good = tmp_path / "good"
    good.mkdir()
    proc, out, logs, bag = start(good, {"sim": episodes(1)}, ("--episodes", 1), own_groups, logs=False, env={"TMPDIR": str(temp)})
    text = check(proc, out, logs, bag, 0, [])
    assert list(temp.iterdir()) == [] and "logs kept" not in text, text
    failed = tmp_path / "failed"
    failed.mkdir()
    proc, out, logs, bag = start(
        failed, {"policy": {"when": "start", "exit": 1}}, ("--episodes", 2), own_groups, logs=False, env={"TMPDIR": str(temp)}
    )
    text = check(proc, out, logs, bag, 3, [])
    (kept,) = temp.iterdir()
    assert kept.name.startswith("dlo-graph-") and (kept / "policy.log").is_file()
    assert f"[launch] logs kept (the run failed): {kept}" in text.splitlines(), text


@pytest.mark.parametrize("ros2", [True, False], ids=["ros2_on_path", "wheels"])
def test_the_domain_line_says_how_to_watch_with_what_is_here(ros2, tmp_path, own_groups):
    """Issue 38 item 7: the launcher suggested `ros2 topic list`, which the wheels do not have: there it suggests
    dlo_bringup's topic_list through scripts/ros2run (test_the_suggested_topic_list_lists_the_domains_topics runs
    it), on a ROS 2 install `ros2 topic list`. The nodes start with `ros2 run` or scripts/ros2run accordingly."""
    proc, out, logs, bag = start(tmp_path, {"sim": episodes(1)}, ("--episodes", 1), own_groups, ros2=ros2)
    text = check(proc, out, logs, bag, 0, [])
    (line,) = [line for line in text.splitlines() if line.startswith("[launch] ROS_DOMAIN_ID=")]
    domain = re.match(r"\[launch\] ROS_DOMAIN_ID=(\d+) ", line).group(1)
    if ros2:
        assert line.endswith(f"(to watch: ROS_DOMAIN_ID={domain} ros2 topic list)"), line
    else:
        suggested = re.search(rf"\(to watch: ROS_DOMAIN_ID={domain} (\S+) dlo_bringup topic_list\)$", line)
        assert suggested and (ROOT / suggested.group(1)).resolve() == ROOT / "scripts" / "ros2run", line
        assert "ros2 topic list" not in line


def test_help_shows_the_lines_as_the_graph_prints_them():
    """Issue 38 item 8: --help showed an old episode-line format; its examples are what the launcher prints, and
    the outcome table names the unit of 'time at end' (steps; the complete case's table above shows it)."""
    from dlo_bag.outcome_table import episode_line, outcome_table, status_line

    result = subprocess.run(["bash", str(LAUNCH), "--help"], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and result.stderr == ""
    example = {
        "episode": 0,
        "seed": 0,
        "outcome": "hold_the_end",
        "outcome_authors": "hold_the_end",
        "episode_return": 4.321,
        "episode_length": 97,
        "time_at_end": 90,
        "how_far": 0,
    }
    lines = result.stdout.splitlines()
    assert "[launch] " + episode_line(example, 1, 5) in lines
    assert (
        "[launch] status: "
        + status_line(11.8, 0.94, 1, 5, dict.fromkeys(("sim", "tactile", "vision", "policy"), True), ["policy: no tactile input"])
        in lines
    )
    assert "time at end [steps]" in outcome_table([example]).splitlines()[0]


def test_the_launch_file_starts_what_the_launcher_started(tmp_path, own_groups, monkeypatch):
    """The ROS 2 launch file (launch/graph.launch.py, read with stand-ins for launch and launch_ros) starts, for the
    same options, the nodes the launcher started here, with the arguments its stand-ins were given."""
    sys.path.insert(0, str(ROOT / "ros_ws" / "src" / "dlo_bringup" / "test"))
    from launch_file_stubs import launched_nodes, node_command

    args = (
        "--episodes",
        1,
        "--seed",
        7,
        "--policy",
        "random",
        "--without",
        "V",
        "--tactile-noise",
        "0.1,0.001",
        "--task-rules",
        "paper_text",
        "--single-particle-grip",
        "--contact-radius",
        "0.005",
        "--record",
        "BAG",
        "--namespace",
        "robot1",
    )
    logs, bag = tmp_path / "logs", tmp_path / "bag"  # (as start() gives them; the bag must not exist yet)
    nodes, _ = launched_nodes(
        monkeypatch,
        {
            "episodes": "1",
            "seed": "7",
            "policy": "random",
            "without": "V",
            "tactile_noise": "0.1,0.001",
            "task_rules": "paper_text",
            "single_particle_grip": "true",
            "contact_radius": "0.005",
            "record": str(bag),
            "namespace": "robot1",
            "logs": str(logs),
        },
    )
    shutil.rmtree(logs)  # (the launch file made it)
    proc, out, logs, bag = start(tmp_path, {"sim": episodes(1)}, args, own_groups)
    check(proc, out, logs, bag, 0, [])
    for node in nodes:
        package, executable, parameters, remappings = node_command(node)
        given = json.loads((tmp_path / f"args_{NODES[executable]}.json").read_text())
        assert given[0] == "--ros-args"
        assert [
            (a.split(":=")[0], yaml.safe_load(a.split(":=")[1])) for f, a in zip(given[1::2], given[2::2]) if f == "-p"
        ] == parameters, executable
        assert [tuple(a.split(":=")) for f, a in zip(given[1::2], given[2::2]) if f == "-r"] == remappings
    assert sorted(NODES[node_command(node)[1]] for node in nodes) == sorted(NODES.values())


def test_the_suggested_topic_list_lists_the_domains_topics(own_groups):
    """What the wheels' launcher suggests for watching its domain (no `ros2 topic list` there) works: run on a
    domain where a node publishes, it lists that topic (discovery may take seconds: it waits for the list to
    settle)."""
    import rclpy

    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        node = rclpy.create_node("watched", context=context)
        node.create_publisher(String, "/dlo/watch_me", 1)
        hint = watch_hint(int(os.environ["ROS_DOMAIN_ID"]))
        assert shutil.which("ros2") is None and "topic_list" in hint  # (the wheels)
        watch = subprocess.Popen(
            ["bash", "-c", hint], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True, cwd=ROOT
        )
        own_groups(watch.pid)
        out, err = watch.communicate(timeout=120)
    finally:
        rclpy.shutdown(context=context)
    assert watch.returncode == 0 and "/dlo/watch_me" in out.splitlines(), out + err
