"""launch_graph.sh under real faults: two graphs at once, a shared domain, a recorder killed with
SIGKILL, a full disk (a real 2 MiB tmpfs), the sim interrupted alone. Each case checks the exit
code, the one-line cause and what the bag still holds. Every launcher runs in its own session and
its whole process group is killed if a test fails, so no node outlives a test."""

import functools
import json
import os
import pathlib
import re
import signal
import subprocess
import sys
import time

import pytest
from dlo_bag.analysis import read_run
from dlo_bag.info import bag_info
from dlo_bag.reader import read_messages
from dlo_bag.recorder_node import PARAMETERS as RECORDER_PARAMETERS
from dlo_common.params import as_params

ROOT = pathlib.Path(__file__).resolve().parents[1]
LAUNCH = ROOT / "scripts" / "launch_graph.sh"
ENV = {**os.environ, "DLO_USE_ROS2RUN": "1"}
EXIT_NODE_FAILED, EXIT_RECORDING_FAILED = 3, 4
# the recorder's flush_period: its default, which the launcher keeps
FLUSH_PERIOD = next(p.default for p in as_params(RECORDER_PARAMETERS) if p.name == "flush_period")


class Launch:
    """launch_graph.sh in its own session, output to a file (read while it runs)."""

    def __init__(self, tmp, name, *args):
        self.logs = tmp / f"{name}_logs"
        self.out_path = tmp / f"{name}.out"
        self.out_file = open(self.out_path, "w")
        self.p = subprocess.Popen(
            ["bash", str(LAUNCH), *map(str, args), "--logs", str(self.logs)],
            stdout=self.out_file,
            stderr=subprocess.STDOUT,
            env=ENV,
            start_new_session=True,
            # bash cannot trap a signal ignored at its start: a test run started as a
            # background job (SIGINT ignored) must not make Ctrl-C a no-op here
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
        )

    @property
    def out(self):
        return self.out_path.read_text()

    def pid_of(self, node, timeout=120):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            found = re.search(rf"\[launch\] {node} \(pid (\d+)\)", self.out)
            if found:
                return int(found.group(1))
            assert self.p.poll() is None, self.out
            time.sleep(0.2)
        raise AssertionError(f"{node} never started:\n{self.out}")

    def episodes_done(self):
        path = self.logs / "outcomes.jsonl"
        return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []

    def wait_episodes(self, n, timeout=300):
        deadline = time.monotonic() + timeout
        while len(self.episodes_done()) < n:
            assert time.monotonic() < deadline and self.p.poll() is None, self.out
            time.sleep(0.3)

    def wait(self, timeout=600):
        try:
            return self.p.wait(timeout=timeout)
        finally:
            self.kill()

    def kill(self):
        """Kill the launcher's whole process group (its nodes too) if anything is left."""
        try:
            os.killpg(self.p.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self.p.wait()
        self.out_file.close()


@pytest.fixture
def launches():
    started = []

    def start(tmp, name, *args):
        launch = Launch(tmp, name, *args)
        started.append(launch)
        return launch

    yield start
    for launch in started:
        launch.kill()


@functools.cache
def reference_outcome(seed):
    """The in-process gym environment with the same controller: what a graph alone must give (computed once a
    seed: the tests ask for it while their graphs run, and two of them for the same seed)."""
    from dlo_policy.env import make_env
    from dlo_policy.scripted import TactileReactive

    env = make_env("All", seed=seed)
    controller = TactileReactive()
    observation, _ = env.reset(seed=seed)
    controller.reset()
    while True:
        observation, _, terminated, truncated, info = env.step(controller(observation[None], env.vec)[0])
        if terminated or truncated:
            return info["outcome"], info["episode_return"]


def one_step_each(bag, seed):
    """Every step of the bag's episode 0 recorded, all of it from one simulator (seed). A step recorded more
    than once is the simulator republishing a state nobody has answered yet (at start-up every 0.25 s until
    the policy's first command arrives, later after step_timeout): byte for byte the same message."""
    read = {
        topic: (list(read_messages(bag, [topic])), list(read_messages(bag, [topic], raw=True)))
        for topic in ("/dlo/task/state", "/dlo/gripper/state")
    }
    tasks = [m.msg for m in read["/dlo/task/state"][0]]
    assert {t.seed for t in tasks} == {seed}
    steps = [t.step for t in tasks if t.episode == 0]
    assert sorted(set(steps)) == list(range(max(steps) + 1))
    for topic, (decoded, raw) in read.items():
        assert [m.timestamp for m in decoded] == [m.timestamp for m in raw]
        by_step = {}
        for m, r in zip(decoded, raw):
            by_step.setdefault((m.msg.episode, m.msg.step), set()).add(bytes(r.msg))
        assert {k: len(v) for k, v in by_step.items() if len(v) > 1} == {}, topic


def test_two_graphs_at_once_never_see_each_other(tmp_path, launches):
    """Two launchers with default options at the same time (seeds 11 and 12, so that a message of the other
    graph would show): own domains, own bags, the outcomes of each graph alone."""
    a = launches(tmp_path, "a", "--policy", "tactile_reactive", "--episodes", 1, "--seed", 11, "--record", tmp_path / "bag_a")
    b = launches(tmp_path, "b", "--policy", "tactile_reactive", "--episodes", 1, "--seed", 12, "--record", tmp_path / "bag_b")
    references = {seed: reference_outcome(seed) for seed in (11, 12)}  # meanwhile
    assert a.wait() == 0, a.out
    assert b.wait() == 0, b.out
    domains = {re.search(r"ROS_DOMAIN_ID=(\d+)", x.out).group(1) for x in (a, b)}
    assert len(domains) == 2
    for launch, bag, seed in ((a, tmp_path / "bag_a", 11), (b, tmp_path / "bag_b", 12)):
        outcome, episode_return = references[seed]
        live = launch.episodes_done()
        assert [e["outcome"] for e in live] == [outcome]
        assert live[0]["episode_return"] == pytest.approx(episode_return, abs=1e-9)
        one_step_each(bag, seed)
        assert "another" not in (launch.logs / "sim.log").read_text()


def test_a_second_simulator_on_a_shared_domain_refuses_to_start(tmp_path, launches):
    """A second graph on the domain of a running one: its sim leaves (exit 3, one line), the first graph runs on
    and finishes an episode after it (the second is started once the first's sim has said it is alone on the
    domain: the launcher starts the other nodes only then)."""
    a = launches(
        tmp_path, "a", "--policy", "tactile_reactive", "--episodes", 0, "--seed", 11, "--domain-id", os.environ["ROS_DOMAIN_ID"]
    )
    a.pid_of("tactile")
    b = launches(
        tmp_path,
        "b",
        "--policy",
        "tactile_reactive",
        "--episodes",
        1,
        "--seed",
        12,  # a long episode
        "--domain-id",
        os.environ["ROS_DOMAIN_ID"],
    )
    assert b.wait() == EXIT_NODE_FAILED, b.out
    assert "sim exited early (status 3, 0 of 1 episodes done)" in b.out
    # one line, at start-up or as soon as discovery shows the running simulator (the later one leaves)
    assert re.search(r"another (simulator already runs|node already publishes \S+ \(/sim_node\)) on ROS_DOMAIN_ID", b.out), b.out
    assert a.p.poll() is None, a.out  # the running graph goes on
    done = len(a.episodes_done())
    a.wait_episodes(done + 1)
    a.p.send_signal(signal.SIGINT)
    assert a.wait() == 130, a.out


def test_namespaces_share_a_domain_deliberately(tmp_path, launches):
    domain = os.environ["ROS_DOMAIN_ID"]
    a = launches(
        tmp_path,
        "a",
        "--policy",
        "tactile_reactive",
        "--episodes",
        1,
        "--seed",
        11,
        "--domain-id",
        domain,
        "--namespace",
        "robot1",
        "--record",
        tmp_path / "bag",
    )
    b = launches(
        tmp_path,
        "b",
        "--policy",
        "tactile_reactive",
        "--episodes",
        1,
        "--seed",
        11,
        "--domain-id",
        domain,
        "--namespace",
        "robot2",
    )
    outcome, _ = reference_outcome(11)  # meanwhile
    assert a.wait() == 0, a.out
    assert b.wait() == 0, b.out
    assert [e["outcome"] for e in a.episodes_done()] == [e["outcome"] for e in b.episodes_done()] == [outcome]
    topics = set(bag_info(tmp_path / "bag").topics)
    assert "/robot1/dlo/task/state" in topics and "/robot1/clock" in topics
    assert not any(t.startswith("/robot2") or t.startswith("/dlo") for t in topics)
    result = subprocess.run(
        [sys.executable, "-m", "dlo_bag.analysis", str(tmp_path / "bag"), "--json", str(tmp_path / "a.json")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert [s["outcome"] for s in json.loads((tmp_path / "a.json").read_text())] == [outcome]


def test_recorder_killed_mid_run_fails_the_launch_and_the_bag_is_recovered(tmp_path, launches):
    """SIGKILL to the recorder mid-run: the launch fails with exit 4 and names dlo-bag-recover, which
    rebuilds the bag. The guarantee (docs/ARCHITECTURE.md#recording): the recorder flushes at least
    every flush period, so a kill loses at most what it received in about the last one. Checked by
    what the sim had reported finished 3 flush periods before the kill: each of those episodes is
    complete in the recovered bag. Episodes that end later (also those that end after the kill, while
    the launcher notices the dead recorder, more of them on a loaded machine) may be missing."""
    bag = tmp_path / "bag"
    run = launches(tmp_path, "run", "--policy", "tactile_reactive", "--episodes", 0, "--seed", 5, "--record", bag)
    recorder = run.pid_of("recorder")
    run.wait_episodes(1)
    safe = run.episodes_done()  # finished now: at least 3 flush periods before the kill
    time.sleep(3 * FLUSH_PERIOD)
    at_kill = run.episodes_done()
    os.kill(recorder, signal.SIGKILL)
    assert run.wait() == EXIT_RECORDING_FAILED, run.out
    assert "recorder exited early (status 137: killed by SIGKILL)" in run.out
    assert f"dlo-bag-recover {bag}" in run.out
    live = run.episodes_done()  # every episode the sim finished, also after the kill
    fixed = subprocess.run(
        [str(ROOT / "scripts" / "ros2run"), "dlo_bag", "dlo-bag-recover", str(bag)], capture_output=True, text=True, timeout=120
    )
    assert fixed.returncode == 0 and "recovered" in fixed.stdout, fixed.stdout + fixed.stderr
    episodes = read_run(bag)
    finished = [e for e, streams in episodes.items() if any(m.done for m in streams["task"].values())]
    assert finished == list(range(len(finished)))
    assert len(finished) >= len(safe), (
        f"the recovered bag has {len(finished)} finished episodes; {len(safe)} had finished "
        f"{3 * FLUSH_PERIOD} s before the kill ({len(at_kill)} at the kill, {len(live)} in all)"
    )
    result = subprocess.run(
        [sys.executable, "-m", "dlo_bag.analysis", str(bag), "--json", str(tmp_path / "a.json")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    analysed = [s for s in json.loads((tmp_path / "a.json").read_text()) if s["complete"]]
    assert len(analysed) >= len(safe)
    for mine, truth in zip(analysed, live):  # what the bag holds is what the sim reported
        assert (mine["episode"], mine["outcome"]) == (truth["episode"], truth["outcome"])


def test_disk_full_stops_the_graph_and_names_the_cause(tmp_path, launches):
    if os.geteuid() != 0:
        pytest.skip("needs root to mount a tmpfs; the write-failure injection of the recorder tests covers the rest")
    disk = tmp_path / "disk"
    disk.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(disk)]).returncode != 0:
        pytest.skip("cannot mount a tmpfs here")
    try:
        bag = disk / "bag"
        run = launches(tmp_path, "run", "--policy", "tactile_reactive", "--episodes", 0, "--seed", 5, "--record", bag)
        assert run.wait() == EXIT_RECORDING_FAILED, run.out
        assert "[launch] recording failed: no space left on device" in run.out
        assert "Traceback" not in (run.logs / "recorder.log").read_text()
        summary = json.loads((run.logs / "recorder_summary.json").read_text())
        assert summary["failure"] == "no space left on device" and summary["complete"]
        assert summary["written"] == summary["received_at_failure"] == bag_info(bag).message_count
        assert read_run(bag)  # readable as it is: no recovery needed
    finally:
        subprocess.run(["umount", "-l", str(disk)])


def test_the_sim_interrupted_alone_is_a_failed_run(tmp_path, launches):
    # 1000 episodes: the SIGINT comes long before the last (with 3, a fast machine could finish them first)
    run = launches(tmp_path, "run", "--policy", "tactile_reactive", "--episodes", 1000, "--seed", 5)
    sim = run.pid_of("sim")
    run.wait_episodes(1)
    os.kill(sim, signal.SIGINT)
    assert run.wait() == EXIT_NODE_FAILED, run.out
    done = re.search(r"sim exited early \(status 130: interrupted by SIGINT, (\d+) of 1000 episodes done\)", run.out)
    assert done and 1 <= int(done.group(1)) < 1000, run.out


def process_start(pid):
    """(state, start time) of process ``pid`` from /proc, or None once it is gone (reaped). The start
    time tells the process apart from a later one that got the same pid."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()  # after "pid (comm)": comm may hold spaces
    except (FileNotFoundError, ProcessLookupError):  # reaped, also between a check and the read
        return None
    return fields[0], fields[19]


def test_a_killed_launcher_leaves_no_node_running_and_a_closed_bag(tmp_path, launches):
    """SIGKILL to launch_graph.sh itself (a test timeout, a crashed terminal): its nodes get SIGINT."""
    bag = tmp_path / "bag"
    run = launches(tmp_path, "run", "--policy", "tactile_reactive", "--episodes", 0, "--seed", 5, "--record", bag)
    nodes = {node: run.pid_of(node) for node in ("sim", "recorder", "tactile", "vision", "policy")}
    started = {node: (process_start(pid) or (None, None))[1] for node, pid in nodes.items()}
    run.wait_episodes(1)
    run.p.send_signal(signal.SIGKILL)  # the launcher only, not its process group
    run.p.wait()

    def running():  # a zombie has exited; a pid taken by a new process is not the node
        return [
            node
            for node, pid in nodes.items()
            if (state := process_start(pid)) is not None and state[0] != "Z" and state[1] == started[node]
        ]

    deadline = time.monotonic() + 60
    alive = running()
    while alive and time.monotonic() < deadline:
        time.sleep(0.5)
        alive = running()
    assert not alive, f"still running 60 s after the launcher's SIGKILL: {alive}\n" + "\n".join(
        f"--- {node}.log:\n" + (run.logs / f"{node}.log").read_text()[-1500:] for node in alive
    )
    assert (bag / "metadata.yaml").is_file(), (run.logs / "recorder.log").read_text()[-3000:]  # stopped, not killed
    assert read_run(bag)


def test_a_node_rejecting_its_parameters_stops_the_graph_with_exit_2(tmp_path, launches):
    # the launcher checks its own options first; --rate-factor goes to the sim unchecked, so the sim's
    # own parameter check is what refuses it here
    run = launches(tmp_path, "run", "--rate-factor", 0, "--episodes", 1)
    assert run.wait() == 2, run.out
    assert "sim exited early (status 2" in run.out
    assert "parameter 'rate_factor': must be > 0" in run.out  # the node's own one-line reason, shown by the launcher
    for node in ("tactile", "vision", "policy"):  # the graph stopped at the sim: nothing else was started
        assert not (run.logs / f"{node}.log").exists(), node
