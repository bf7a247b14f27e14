"""The launcher's graph_monitor without a graph (issue 12 item 5): it follows a growing outcomes file
(episodes printed as they are appended, the rest on SIGTERM) and the nodes' logs (issue 20: what a node
waits for is on the status line while it waits, and only then). Its texts: dlo_bag test_outcome_text.py."""

import json
import os
import signal
import subprocess
import sys
import time

EPISODE = {"episode": 3, "seed": 13, "outcome": "hold_the_end", "outcome_authors": "stop_before",
           "episode_return": 4.25, "episode_length": 97, "time_at_end": 12, "how_far": 1}


def test_graph_monitor_streams_appended_episodes_and_status(tmp_path):
    outcomes, logs = tmp_path / "outcomes.jsonl", tmp_path / "logs"
    logs.mkdir()
    (logs / "policy.log").write_text("")
    monitor = subprocess.Popen(
        [sys.executable, "-m", "dlo_viz.graph_monitor", str(outcomes), "--logs", str(logs), "--no-ros",
         "--episodes", "3", "--status-period", "0.3", "--node", f"policy={os.getpid()}"],
        stdout=subprocess.PIPE, text=True)
    try:
        def next_line_with(text):
            while True:
                line = monitor.stdout.readline()
                assert line, "the monitor ended early"
                if text in line:
                    return line
        status = next_line_with("status:")
        assert "0/3 episodes done, nodes alive 1/1; no warnings" in status
        with open(logs / "policy.log", "a") as log:
            log.write("[ERROR] [2.0] [policy_node]: step at t=0.08 s: no gripper input after 1.0 s (x)\n")
        assert "policy: no gripper input" in next_line_with("policy:")
        with open(outcomes, "a") as f:
            f.write(json.dumps(dict(EPISODE, episode=0)) + "\n")
        first = next_line_with("episode 0")  # printed while the monitor still runs
        assert first.startswith("[launch] episode 0 (seed 13; 1/3 done)") and monitor.poll() is None
        with open(outcomes, "a") as f:
            f.write(json.dumps(dict(EPISODE, episode=1)) + "\n")
            f.write(json.dumps(dict(EPISODE, episode=2))[:20])  # a line still being written
        time.sleep(0.5)
        with open(outcomes, "a") as f:
            f.write(json.dumps(dict(EPISODE, episode=2))[20:] + "\n")
        monitor.send_signal(signal.SIGTERM)
        rest, _ = monitor.communicate(timeout=30)
    finally:
        if monitor.poll() is None:
            monitor.kill()
            monitor.wait()
    assert monitor.returncode == 0
    lines = [line for line in rest.splitlines() if "] episode" in line]
    assert any("episode 2 (seed 13; 3/3 done)" in line for line in lines), rest
    assert "unreadable" not in rest


SIM_WAITS = ("[INFO] [100.0] [sim_node]: waiting for 4 subscribers of /dlo/gripper/state (have 0)\n"
             "[WARN] [104.2] [sim_node]: waiting for the recorder 'recorder' to subscribe to /dlo/gripper/cmd\n")
SIM_EPISODE = ("[INFO] [106.1] [sim_node]: episode 0 (seed 13): hold_the_end (authors' rule: stop_before), return 4.250, "
               "time at end 12, 1 particles from the end\n")
RECORDER_WAIT = "sim: waiting for the recorder 'recorder' to subscribe to /dlo/gripper/cmd"


def test_status_lines_say_what_a_node_waits_for_until_it_no_longer_does(tmp_path):
    """Issue 20: `launch_graph.sh --record DIR --status-period 2` said "sim: waiting for the recorder ..." on the
    status line after episode 0 had finished (the sim had logged that line, started and finished an episode
    within one status period). A "waiting for" line is a state: it holds on every status line (the sim repeats
    it only every 5 s; one logged before the monitor started too) until the node logs anything after it."""
    outcomes, logs = tmp_path / "outcomes.jsonl", tmp_path / "logs"
    logs.mkdir()
    first, second = SIM_WAITS.splitlines(keepends=True)
    (logs / "sim.log").write_text("[WARN] [99.0] [sim_node]: before the monitor\n" + first)
    monitor = subprocess.Popen(
        [sys.executable, "-m", "dlo_viz.graph_monitor", str(outcomes), "--logs", str(logs), "--no-ros",
         "--episodes", "3", "--status-period", "0.3", "--node", f"sim={os.getpid()}"],
        stdout=subprocess.PIPE, text=True)

    def next_line_with(text):
        while True:
            line = monitor.stdout.readline()
            assert line, "the monitor ended early"
            if text in line:
                return line.rstrip("\n")

    def append(path, text):
        with open(path, "a") as f:
            f.write(text)
    try:
        assert next_line_with("status:").endswith(  # the wait holds, the warning before the monitor is past
            "0/3 episodes done, nodes alive 1/1; sim: waiting for 4 subscribers of /dlo/gripper/state (have 0)")
        append(logs / "sim.log", second)
        waiting = next_line_with("recorder")
        assert waiting.endswith(f"0/3 episodes done, nodes alive 1/1; {RECORDER_WAIT}"), waiting  # the later wait
        assert next_line_with("status:") == waiting  # nothing new logged: the sim still waits
        # the sim logs its wait once more, then starts and finishes episode 0, all within one status period
        append(logs / "sim.log", second + SIM_EPISODE)
        append(outcomes, json.dumps(dict(EPISODE, episode=0)) + "\n")
        assert next_line_with("] episode 0").startswith("[launch] episode 0 (seed 13; 1/3 done)")
        after = next_line_with("status:")
        assert after.endswith("1/3 episodes done, nodes alive 1/1; no warnings"), after
        monitor.send_signal(signal.SIGTERM)
        monitor.communicate(timeout=30)
    finally:
        if monitor.poll() is None:
            monitor.kill()
            monitor.wait()


def test_a_wait_is_over_once_the_graph_steps_after_it(tmp_path):
    """The other end of a wait: a control step counted on /clock after the line was logged (its rclpy time
    stamp, or when it was read for a line without one); later warnings are still counted."""
    from dlo_viz.graph_monitor import LogTail, NodeHealth

    log = tmp_path / "sim.log"
    log.write_text(SIM_WAITS)
    sim = NodeHealth("sim", LogTail(str(log)))
    assert sim.notes(last_step_wall=None) == [RECORDER_WAIT]  # no step rate known
    assert sim.notes(last_step_wall=104.0) == [RECORDER_WAIT]  # the last step came before the wait
    assert sim.notes(last_step_wall=104.3) == []  # a step after it: the sim runs
    with open(log, "a") as f:
        f.write("[WARN] [sim_node]: waiting for something, logged without a time\n")
    before = time.time()
    assert sim.notes(last_step_wall=before - 1.0) == ["sim: waiting for something, logged without a time"]
    assert sim.notes(last_step_wall=time.time() + 1.0) == []
    with open(log, "a") as f:
        f.write(SIM_WAITS.splitlines(keepends=True)[1] + "[WARN] [105.0] [sim_node]: no command for 3 s\n")
    assert sim.notes() == ["sim: 1 warning (last: no command for 3 s)"]  # a line after the wait ends it
