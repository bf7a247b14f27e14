"""launch_graph.sh --composed (every node in one process, dlo_bringup.composed) runs the graph of processes' episodes:
the same outcomes, step counts and returns, the same recorded commands step by step, the same lines; one SIGINT
stops it with a closed, complete bag; a node that refuses to start ends it with the exit status and line of the
graph of processes."""

from __future__ import annotations

import json
import os
import pathlib
import signal
import subprocess
import time

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
LAUNCH = ROOT / "scripts" / "launch_graph.sh"
SEED = 7005  # the shipped policy holds the end in both episodes: 150 steps each (tests/test_graph_equals_env.py)
ENV = {**os.environ, "DLO_USE_ROS2RUN": "1"}


def commands(bag: pathlib.Path) -> dict:
    """{(episode, step): (vx, vy, closure)} of the recorded /dlo/gripper/cmd (a republished step answered alike)."""
    from dlo_bag.reader import read_messages

    answered = {}
    for item in read_messages(bag, topics=["/dlo/gripper/cmd"]):
        m = item.msg
        answered.setdefault((int(m.episode), int(m.step)), (m.vx, m.vy, m.closure))
    return answered


@pytest.fixture(scope="module")
def both_modes(tmp_path_factory, launch_in_own_group):
    """The same two step-locked episodes of the shipped policy, recorded, with a process per node and composed."""
    runs = {}
    for mode in ("processes", "composed"):
        work = tmp_path_factory.mktemp(mode)
        args = ["--episodes", "2", "--seed", str(SEED), "--logs", str(work / "logs"), "--record", str(work / "bag")]
        args += ["--status-period", "0"] + (["--composed"] if mode == "composed" else [])
        result = launch_in_own_group(["bash", str(LAUNCH), *args], timeout=600, env=ENV)
        runs[mode] = (result, work)
    return runs


def test_composed_episodes_equal_those_of_the_graph_of_processes(both_modes):
    outcomes, lines = {}, {}
    for mode, (result, work) in both_modes.items():
        assert result.returncode == 0, f"{mode}:\n{result.stdout[-3000:]}{result.stderr[-3000:]}"
        outcomes[mode] = [json.loads(line) for line in (work / "logs" / "outcomes.jsonl").read_text().splitlines()]
        lines[mode] = [line for line in result.stdout.splitlines() if line.startswith("[launch] episode ")]
    assert [(e["seed"], e["episode_length"]) for e in outcomes["composed"]] == [(SEED, 150), (SEED + 1, 150)]
    assert outcomes["composed"] == outcomes["processes"]  # outcome, both rules, return, time at end, how far, ...
    assert lines["composed"] == lines["processes"] and len(lines["composed"]) == 2
    table = {mode: result.stdout[result.stdout.index("run: policy") :] for mode, (result, _) in both_modes.items()}
    assert table["composed"].replace(str(both_modes["composed"][1]), "W") == table["processes"].replace(
        str(both_modes["processes"][1]), "W"
    )


def test_composed_records_the_same_commands_in_a_complete_bag(both_modes):
    answered = {}
    for mode, (result, work) in both_modes.items():
        assert result.returncode == 0, result.stderr[-3000:]
        summary = json.loads((work / "logs" / "recorder_summary.json").read_text())
        assert summary["complete"] and summary["dropped"] == 0 and not summary["failure"], summary
        assert (work / "bag" / "metadata.yaml").is_file()
        answered[mode] = commands(work / "bag")
    assert len(answered["composed"]) == 2 * 151  # every state of both episodes answered, the final ones too
    assert answered["composed"] == answered["processes"]  # bit for bit


def test_each_node_of_the_composed_graph_has_its_own_log(both_modes):
    result, work = both_modes["composed"]
    logs = work / "logs"
    assert "[launch] sim, recorder, tactile, vision, policy: one process (pid" in result.stdout
    expected = {
        "sim": "alone on ROS_DOMAIN_ID",
        "recorder": "recording '/dlo'",
        "tactile": "tactile noise: none",
        "vision": "",
        "policy": "policy sac on K+T+V",
    }
    for name, line in expected.items():
        text = (logs / f"{name}.log").read_text()
        assert line in text, f"{name}.log:\n{text}"
        others = {"sim": "[sim_node]", "tactile": "[tactile_node]", "policy": "[policy_node]", "recorder": "[recorder]"}
        assert not any(tag in text for other, tag in others.items() if other != name), f"{name}.log:\n{text}"
    assert "ran 2 episodes: exiting" in (logs / "sim.log").read_text()
    assert "dropped 0" in (logs / "recorder.log").read_text()  # its summary at the end
    status = json.loads((logs / "composed_status.json").read_text())
    assert status == {"ended_by": "sim", "status": dict.fromkeys(expected, 0), "rc": 0}


def wait_for(path: pathlib.Path, text: str, limit: float) -> None:
    deadline = time.monotonic() + limit
    while time.monotonic() < deadline:
        if path.exists() and text in path.read_text():
            return
        time.sleep(0.2)
    raise AssertionError(f"no {text!r} in {path} within {limit} s:\n{path.read_text() if path.exists() else ''}")


@pytest.mark.parametrize("whom", ["launcher", "terminal"])
def test_one_sigint_stops_the_composed_graph_with_a_closed_complete_bag(whom, tmp_path, own_groups):
    """SIGINT to the launcher, or a terminal's Ctrl-C (to the launcher and the composed process together): exit 130,
    the outcome table, the bag closed with every message it received written."""
    out, logs, bag = tmp_path / "launch.out", tmp_path / "logs", tmp_path / "bag"
    args = ["--composed", "--episodes", "0", "--seed", str(SEED), "--logs", str(logs), "--record", str(bag)]
    with out.open("w") as f:
        proc = subprocess.Popen(
            ["bash", str(LAUNCH), *args, "--status-period", "0"],
            stdout=f,
            stderr=subprocess.STDOUT,
            env=ENV,
            start_new_session=True,
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
        )
    own_groups(proc.pid)
    wait_for(out, "[launch] episode 0 ", 300)
    if whom == "launcher":
        proc.send_signal(signal.SIGINT)
    else:
        os.killpg(proc.pid, signal.SIGINT)
    assert proc.wait(timeout=120) == 130, out.read_text()
    text = out.read_text()
    assert "[launch] interrupted: stopping the graph" in text and "outcome                    paper rule" in text
    assert f"[launch] bag: {bag} (inspect: dlo-bag-info {bag})" in text
    assert "Traceback" not in text and "could not finish" not in text
    summary = json.loads((logs / "recorder_summary.json").read_text())
    assert summary["complete"] and summary["dropped"] == 0 and summary["written"] == summary["received"] > 0
    assert json.loads((logs / "composed_status.json").read_text())["ended_by"] == "signal"
    assert (bag / "metadata.yaml").is_file()


def not_a_policy(tmp_path):
    path = tmp_path / "not_a_policy.pt"
    path.write_text("not a checkpoint\n")
    return path


# a node that refuses its parameters: the sim (first, alone) and the policy (built last, after the sim is up)
REFUSALS = {
    "sim": (["--rate-factor", "fast"], "[launch] sim exited early (status 2,", "rate_factor"),
    "policy": (["--checkpoint", not_a_policy], "[launch] policy exited early (status 2)", "not a dlo-vitac policy file"),
}


@pytest.mark.parametrize("node", sorted(REFUSALS))
def test_a_node_that_refuses_its_parameters_ends_the_composed_graph_as_it_ends_the_graph_of_processes(
    node, tmp_path, launch_in_own_group
):
    extra, line, why = REFUSALS[node]
    extra = [str(a(tmp_path)) if callable(a) else a for a in extra]
    printed = {}
    for mode in ("processes", "composed"):
        args = ["--episodes", "1", "--logs", str(tmp_path / mode), "--status-period", "0", *extra]
        result = launch_in_own_group(
            ["bash", str(LAUNCH), *args, *(["--composed"] if mode == "composed" else [])], timeout=300, env=ENV
        )
        assert result.returncode == 2, f"{mode}:\n{result.stdout[-2000:]}{result.stderr[-2000:]}"
        assert line in result.stderr, f"{mode}:\n{result.stderr}"
        assert why in result.stderr, f"{mode}: the end of the node's log names the cause:\n{result.stderr}"
        assert "Traceback" not in result.stderr
        printed[mode] = [line for line in result.stderr.splitlines() if line.startswith("[launch]")]
    assert printed["composed"] == printed["processes"]
