"""The launcher's episode and status lines without a graph (issue 12 item 5): the monitor follows a growing
outcomes file (episodes printed as they are appended, a line still being written when it is complete) and the
nodes' logs (issue 20: what a node waits for is on the status line while it waits, and only then), on a clock of
the test's own; the step rate comes from the /clock counter's lines. Their texts: dlo_bag test_outcome_text.py."""

import io
import json

from dlo_bringup.graph_monitor import ClockReader, Monitor

EPISODE = {
    "episode": 3,
    "seed": 13,
    "outcome": "hold_the_end",
    "outcome_authors": "stop_before",
    "episode_return": 4.25,
    "episode_length": 97,
    "time_at_end": 12,
    "how_far": 1,
}
SIM_WAITS = (
    "[INFO] [100.0] [sim_node]: waiting for 4 subscribers of /dlo/gripper/state (have 0)\n"
    "[WARN] [104.2] [sim_node]: waiting for the recorder 'recorder' to subscribe to /dlo/gripper/cmd\n"
)
SIM_EPISODE = (
    "[INFO] [106.1] [sim_node]: episode 0 (seed 13): hold_the_end (authors' rule: stop_before), return 4.250, "
    "time at end 12, 1 particles from the end\n"
)
RECORDER_WAIT = "sim: waiting for the recorder 'recorder' to subscribe to /dlo/gripper/cmd"


class Run:
    """A monitor of 3 episodes with status lines every 0.25 s of the test's clock, its lines in ``said``."""

    def __init__(self, tmp_path, alive, clock=None):
        self.outcomes, self.logs = tmp_path / "outcomes.jsonl", tmp_path / "logs"
        self.logs.mkdir()
        for name in alive:
            (self.logs / f"{name}.log").touch()
        self.alive, self.time, self.said = alive, 0.0, []
        self.clock = clock

    def start(self):
        self.monitor = Monitor(
            self.outcomes,
            self.logs,
            3,
            0.25,
            alive=lambda: dict(self.alive),
            clock=self.clock,
            say=self.said.append,
            now=lambda: self.time,
        )
        return self

    def append(self, path, text):
        with open(path, "a") as f:
            f.write(text)

    def tick(self, seconds=0.25):
        """The lines the monitor says when ``seconds`` have passed."""
        self.time += seconds
        before = len(self.said)
        self.monitor.tick()
        return self.said[before:]


def test_episodes_are_streamed_as_appended_and_status_lines_name_health(tmp_path):
    run = Run(tmp_path, {"policy": True}).start()
    assert run.tick(0.125) == []  # no status line before its period
    assert run.tick(0.125) == ["[launch] status: steps/s ?, 0/3 episodes done, nodes alive 1/1; no warnings"]
    run.append(run.logs / "policy.log", "[ERROR] [2.0] [policy_node]: step at t=0.08 s: no gripper input after 1.0 s\n")
    assert "policy: no gripper input" in run.tick()[0]
    run.append(run.outcomes, json.dumps(dict(EPISODE, episode=0)) + "\n")
    assert run.tick(0.1) == [
        "[launch] episode 0 (seed 13; 1/3 done): hold_the_end, authors' rule stop_before; "
        "return 4.250, 97 steps, 1 particles from the end"
    ]
    run.alive["policy"] = False
    assert run.tick()[-1] == "[launch] status: steps/s ?, 1/3 episodes done, nodes alive 0/1 (dead: policy); no warnings"
    run.append(run.outcomes, json.dumps(dict(EPISODE, episode=1)) + "\n" + json.dumps(dict(EPISODE, episode=2))[:20])
    assert [line[:33] for line in run.tick(0.1)] == ["[launch] episode 1 (seed 13; 2/3 "]  # the rest: being written
    run.append(run.outcomes, json.dumps(dict(EPISODE, episode=2))[20:] + "\n")
    said = run.tick()
    assert said[0].startswith("[launch] episode 2 (seed 13; 3/3 done)") and len(said) == 1  # done: no status line
    assert not any("unreadable" in line for line in run.said)


def test_status_lines_say_what_a_node_waits_for_until_it_no_longer_does(tmp_path):
    """Issue 20: `launch_graph.sh --record DIR --status-period 2` said "sim: waiting for the recorder ..." on the
    status line after episode 0 had finished (the sim had logged that line, started and finished an episode
    within one status period). A "waiting for" line is a state: it holds on every status line (the sim repeats
    it only every 5 s; one logged before the monitor started too) until the node logs anything after it."""
    run = Run(tmp_path, {"sim": True})
    first, second = SIM_WAITS.splitlines(keepends=True)
    run.append(run.logs / "sim.log", "[WARN] [99.0] [sim_node]: before the monitor\n" + first)
    run.start()
    assert run.tick()[0].endswith(  # the wait holds, the warning before the monitor is past
        "0/3 episodes done, nodes alive 1/1; sim: waiting for 4 subscribers of /dlo/gripper/state (have 0)"
    )
    run.append(run.logs / "sim.log", second)
    waiting = run.tick()[0]
    assert waiting.endswith(f"0/3 episodes done, nodes alive 1/1; {RECORDER_WAIT}"), waiting  # the later wait
    assert run.tick() == [waiting]  # nothing new logged: the sim still waits
    # the sim logs its wait once more, then starts and finishes episode 0, all within one status period
    run.append(run.logs / "sim.log", second + SIM_EPISODE)
    run.append(run.outcomes, json.dumps(dict(EPISODE, episode=0)) + "\n")
    episode, status = run.tick()
    assert episode.startswith("[launch] episode 0 (seed 13; 1/3 done)")
    assert status.endswith("1/3 episodes done, nodes alive 1/1; no warnings"), status


def test_the_step_rate_comes_from_the_clock_counters_lines(tmp_path):
    """The /clock counter prints STEPS LAST_NS LAST_STEP_WALL as they change: the status line's rate is the steps
    counted in its period per second, the sim time factor the sim time that passed per second; a counter that
    could not start says why once, and the status lines go on without a rate."""
    clock = ClockReader(io.StringIO("0 -1 -1\n12 960000000 1000.0\n"))
    clock._thread.join()
    assert (clock.steps, clock.last_ns, clock.last_step_wall, clock.error) == (12, 960_000_000, 1000.0, None)
    run = Run(tmp_path, {"sim": True}, clock).start()
    assert run.tick(0.5)[0].startswith("[launch] status: 24.0 steps/s, 0/3")  # 12 steps in 0.5 s; no sim time yet
    clock.steps, clock.last_ns = 17, 1_360_000_000
    assert run.tick(0.5)[0].startswith("[launch] status: 10.0 steps/s (sim time x0.80), 0/3")
    broken = ClockReader(io.StringIO("error ModuleNotFoundError: No module named 'rclpy'\n"))
    broken._thread.join()
    (tmp_path / "broken").mkdir()
    run = Run(tmp_path / "broken", {"sim": True}, broken).start()
    assert run.tick() == [
        "[launch] status: no step rate (ModuleNotFoundError: No module named 'rclpy')",
        "[launch] status: steps/s ?, 0/3 episodes done, nodes alive 1/1; no warnings",
    ]
    assert run.tick() == ["[launch] status: steps/s ?, 0/3 episodes done, nodes alive 1/1; no warnings"]
