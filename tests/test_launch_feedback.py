"""A running graph tells you what it does (issue 12 item 5): launch_graph.sh streams one line per
finished episode and a status line while the graph runs (issue 20: recording, so the sim first waits for the
recorder; the status line says so only while it waits), and heads its outcome table with the policy,
ablation, noise and seeds of the run (one launch, read incrementally, for all of these; its tactile noise
is a custom pair, given as on the command line, which the tactile node and the header name); the real-time
sim started alone waits for a command publisher (warning once a second) instead of running its
episodes, starts when one appears, and warns while no command arrives."""

import json
import os
import pathlib
import queue
import re
import signal
import subprocess
import threading
import time

import pytest
from harness import stop_or_explain

ROOT = pathlib.Path(__file__).resolve().parents[1]
ROS2RUN = str(ROOT / "scripts" / "ros2run")
SEED, EPISODES = 5, 3
NOISE, NOISE_SAID = "0.1,0.001", "sigma_theta 0.1 rad, sigma_y 0.001 m"  # --tactile-noise, how the run names it


@pytest.fixture(scope="module")
def streamed_run(tmp_path_factory):
    """One launch; each stdout line is recorded with how many episodes the sim had written to
    outcomes.jsonl when the line was read and whether the launcher was still running."""
    logs = tmp_path_factory.mktemp("feedback") / "logs"
    launch = subprocess.Popen(
        [
            "bash",
            str(ROOT / "scripts" / "launch_graph.sh"),
            "--policy",
            "tactile_reactive",
            "--episodes",
            str(EPISODES),
            "--seed",
            str(SEED),
            "--without",
            "V",
            "--tactile-noise",
            NOISE,
            "--status-period",
            "0.5",
            "--logs",
            str(logs),
            "--record",
            str(logs.parent / "bag"),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
        env={**os.environ, "DLO_USE_ROS2RUN": "1"},
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    lines = queue.Queue()
    reader = threading.Thread(target=lambda: [lines.put(line) for line in launch.stdout], daemon=True)
    reader.start()
    seen = []  # (line, episodes in outcomes.jsonl when it was read, launcher running)
    outcomes = logs / "outcomes.jsonl"
    deadline = time.monotonic() + 600
    try:
        while reader.is_alive() or not lines.empty():
            assert time.monotonic() < deadline, "".join(s[0] for s in seen)
            try:
                line = lines.get(timeout=0.5)
            except queue.Empty:
                continue
            written = len(outcomes.read_text().splitlines()) if outcomes.exists() else 0
            seen.append((line.rstrip("\n"), written, launch.poll() is None))
        rc = launch.wait(timeout=60)
    finally:
        try:
            os.killpg(launch.pid, signal.SIGKILL)  # whatever is left of the graph
        except ProcessLookupError:
            pass
        launch.wait()
    return {
        "rc": rc,
        "seen": seen,
        "out": "\n".join(s[0] for s in seen),
        "live": [json.loads(line) for line in outcomes.read_text().splitlines()],
        "tactile_log": (logs / "tactile.log").read_text(),
    }


def test_the_launch_succeeds(streamed_run):
    assert streamed_run["rc"] == 0, streamed_run["out"]
    assert len(streamed_run["live"]) == EPISODES


def test_episode_lines_stream_while_the_graph_runs(streamed_run):
    """Each finished episode's line (seed, both outcomes, return, steps) is printed once; the first one
    before the sim wrote its last episode, i.e. while the graph still ran, not at the end."""
    seen, live = streamed_run["seen"], streamed_run["live"]
    for k, e in enumerate(live):
        expected = (
            f"[launch] episode {k} (seed {SEED + k}; {k + 1}/{EPISODES} done): {e['outcome']}, authors' rule "
            f"{e['outcome_authors']}; return {e['episode_return']:.3f}, {e['episode_length']} steps"
        )
        matches = [s for s in seen if s[0].startswith(expected)]
        assert len(matches) == 1, (expected, streamed_run["out"])
    first = next(s for s in seen if s[0].startswith("[launch] episode 0 "))
    assert first[1] < EPISODES and first[2], first  # read before the last episode ended, launcher running
    table = next(i for i, s in enumerate(seen) if s[0].startswith("run: "))
    assert all(i < table for i, s in enumerate(seen) if s[0].startswith("[launch] episode "))


def test_status_lines_report_rate_episodes_and_nodes(streamed_run):
    status = [s[0] for s in streamed_run["seen"] if s[0].startswith("[launch] status: ")]
    assert status, streamed_run["out"]
    for line in status:
        # once the last episode is done the sim exits, and a status line printed meanwhile may count it gone
        alive = "[45]/5" if "3/3 episodes done" in line else "5/5"
        assert re.search(rf"status: (\d+\.\d steps/s|steps/s \?).*, \d/3 episodes done, nodes alive {alive}", line), line
    assert any(re.search(r"[1-9]\d*\.\d steps/s", line) for line in status), status  # steps counted on /clock


def test_status_lines_drop_the_wait_once_the_graph_runs(streamed_run):
    """Issue 20: with --record the sim first waits for the recorder ("sim: waiting for the recorder ..." on the
    status line while it does); once steps are counted or an episode has finished, no status line says so."""
    status = [s[0] for s in streamed_run["seen"] if s[0].startswith("[launch] status: ")]
    running = [line for line in status if re.search(r"[1-9]\d*\.\d steps/s|status: .*[1-9]/3 episodes done", line)]
    assert running, status
    assert not [line for line in running if "waiting for" in line], status


def test_the_outcome_table_is_headed_by_what_produced_it(streamed_run):
    out = streamed_run["out"]
    header = next(line for line in out.splitlines() if line.startswith("run: "))
    for part in (
        "policy tactile_reactive observing K+T+V",
        "no checkpoint",
        "ablation: without V",
        f"tactile noise: {NOISE_SAID}",
        "mode step_locked",
        f"seeds {SEED}..{SEED + EPISODES - 1} (3 episodes)",
    ):
        assert part in header, (part, header)
    assert out.splitlines()[out.splitlines().index(header) + 1].split()[:2] == ["episode", "seed"]


def test_the_custom_noise_pair_reaches_the_tactile_node(streamed_run):
    """--tactile-noise 0.1,0.001 is passed on as -p tactile_noise:=[0.1,0.001]: the node says it uses that pair."""
    log = streamed_run["tactile_log"]
    assert f"[tactile_node]: tactile noise: {NOISE_SAID}; seed {SEED}" in log, log


def test_real_time_sim_waits_for_a_command_publisher_then_warns_without_commands(tmp_path):
    import rclpy
    from dlo_msgs.msg import GripperCommand, TaskState

    log = tmp_path / "sim.log"
    sim = subprocess.Popen(
        [
            ROS2RUN,
            "dlo_sim",
            "sim_node",
            "--ros-args",
            "-p",
            "mode:=real_time",
            "-p",
            "publish_markers:=false",
            "-p",
            "camera_resolution:=32",
        ],
        stdout=open(log, "w"),
        stderr=subprocess.STDOUT,
        env=dict(os.environ, PYTHONFAULTHANDLER="1"),
    )  # (its Python stacks, should it hang)
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("feedback_probe", context=context)
    tasks = []
    node.create_subscription(TaskState, "/dlo/task/state", tasks.append, 100)
    executor = rclpy.executors.SingleThreadedExecutor(context=context)
    executor.add_node(node)

    def spin_until(condition, timeout):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not condition():
            executor.spin_once(timeout_sec=0.05)
        return condition()

    def count(text):
        return log.read_text().count(text)

    try:
        waiting = "no publisher of /dlo/gripper/cmd for"
        assert spin_until(lambda: count(waiting) >= 3, 240), log.read_text()  # once a second, repeatedly
        assert "is a policy running?" in log.read_text()
        spin_until(lambda: False, 1.0)
        assert tasks == [] and sim.poll() is None  # no episode runs without a command publisher
        node.create_publisher(GripperCommand, "/dlo/gripper/cmd", 10)
        assert spin_until(lambda: len(tasks) >= 3, 120), log.read_text()  # the episode starts
        assert tasks[0].episode == 0 and tasks[0].step == 0
        assert spin_until(lambda: count("no command for") >= 2, 60), log.read_text()  # still no command sent
        assert tasks[-1].step > tasks[0].step  # real time runs on, the gripper holding
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)
        stop_or_explain(sim, "the sim node", 30, log)
    assert "Traceback" not in log.read_text()


@pytest.mark.parametrize(
    "args, message",
    [
        (["--policy", "nosuch"], "launch_graph: --policy must be one of sac, tactile_reactive, oracle, random, got 'nosuch'"),
        (
            ["--without", "X"],
            "launch_graph: --without must be empty or modalities joined by '+' (K, T, V), e.g. T or T+V, got 'X'",
        ),
        (["--checkpoint", "/nonexistent/policy.pt"], "launch_graph: --checkpoint /nonexistent/policy.pt: no such file"),
        (["--task-rules", "authors"], "launch_graph: --task-rules must be paper_text or authors_code, got 'authors'"),
    ],
)
def test_the_launcher_refuses_its_own_bad_choices_before_any_node_starts(args, message, tmp_path):
    logs = tmp_path / "logs"
    result = subprocess.run(
        ["bash", str(ROOT / "scripts" / "launch_graph.sh"), *args, "--logs", str(logs), "--episodes", "1"],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "DLO_USE_ROS2RUN": "1"},
    )
    assert result.returncode == 2, result.stdout + result.stderr
    assert result.stderr.splitlines() == [message]
    assert result.stdout == "" and not logs.exists()  # no domain chosen, no node started
