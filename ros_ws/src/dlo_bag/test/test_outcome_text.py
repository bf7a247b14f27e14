"""The launcher's texts without a graph (issue 12 item 5): the streamed episode line, the run header,
health notes read from node logs and the status line (dlo_bag.outcome_table; the launcher prints them:
dlo_bringup test_graph_monitor.py and tests/test_launch_graph_exit_codes.py)."""

from dlo_bag.outcome_table import episode_line, episode_row, health_notes, outcome_table, run_header, seed_ranges, status_line

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


def test_episode_line_names_seed_both_outcomes_return_and_steps():
    line = episode_line(EPISODE, done=4, total=10)
    assert line == (
        "episode 3 (seed 13; 4/10 done): hold_the_end, authors' rule stop_before; return 4.250, "
        "97 steps, 1 particles from the end"
    )
    assert "4/unlimited done" in episode_line(EPISODE, done=4)
    assert episode_row(EPISODE) in outcome_table([EPISODE]).splitlines()  # the table's row: same function
    assert outcome_table([EPISODE]).splitlines()[0].endswith(" return time at end [steps] from end")  # its unit


def test_run_header_names_policy_checkpoint_ablation_noise_mode_and_seeds():
    episodes = [dict(EPISODE, seed=s) for s in (5, 6, 7, 9)]
    header = run_header(
        episodes, "sac", "runs/x/policy.pt", "T", "partial", "real_time", policy_line="policy sac on T+K+V without T"
    )
    assert header.startswith("run: policy sac observing T+K+V (checkpoint runs/x/policy.pt)")
    for part in (
        "ablation: without T",
        "tactile noise: partial (sigma_theta 0.25 rad, sigma_y 0.001 m)",
        "mode real_time",
        "; grip finite; seeds 5..7, 9 (4 episodes)",
    ):
        assert part in header, (part, header)
    for noise, said in [
        ("", "none"),
        ("none", "none"),
        ("[0.1,0.001]", "sigma_theta 0.1 rad, sigma_y 0.001 m"),
        ((0.1, 0.001), "sigma_theta 0.1 rad, sigma_y 0.001 m"),
    ]:  # a custom pair: its numbers
        assert f"; tactile noise: {said}; " in run_header(episodes, "sac", tactile_noise=noise), noise
    shipped = run_header(episodes[:1], "sac")
    assert "the shipped All policy" in shipped and "ablation: none" in shipped and "(1 episode)" in shipped
    assert "no checkpoint" in run_header(episodes, "tactile_reactive")
    assert "learning online into runs/o" in run_header(episodes, "sac", train_out="runs/o")
    single = [dict(EPISODE, single_particle_grip=True)]  # the sim node notes its grip in every episode
    assert "; grip single-particle; " in run_header(single, "sac")
    assert "; grip finite, single-particle; " in run_header(episodes[:1] + single, "sac")  # a mixed file: both
    perturbed = run_header(episodes, "sac", perturbations="friction=0.6,observation_delay=1")
    assert "; grip finite; perturbations friction=0.6,observation_delay=1; seeds " in perturbed
    assert "perturbations" not in shipped  # none on: not named
    assert seed_ranges([]) == "none" and seed_ranges([2, 1, 3, 3]) == "1..3"


def test_health_notes_name_missing_inputs_waits_and_warnings():
    lines = [
        "[INFO] [1.0] [policy_node]: policy sac on T+K+V; inputs ['gripper', 'tactile']",
        "[ERROR] [2.0] [policy_node]: step at t=0.08 s: no tactile input after 1.0 s (is that node running?)",
        "[ERROR] [3.0] [policy_node]: step at t=0.16 s: no tactile, vision input after 1.0 s (is ...)",
        "[INFO] [4.0] [sim_node]: waiting for 3 subscribers of /dlo/gripper/state (have 1)",
        "[WARN] [5.0] [sim_node]: no command for 3 s: is a policy running? (the gripper stands still)",
    ]
    assert health_notes("policy", lines) == [
        "policy: waiting for 3 subscribers of /dlo/gripper/state (have 1)",
        "policy: no tactile or vision input",
        "policy: 1 warning (last: no command for 3 s: is a policy running? (the gripper stands still))",
    ]
    assert health_notes("vision", ["[INFO] [1.0] [vision_node]: fine"]) == []


def test_status_line_rate_episodes_nodes_and_notes():
    line = status_line(12.46, 0.99, 2, 5, {"sim": True, "policy": False}, ["policy: no gripper input"])
    assert line == ("12.5 steps/s (sim time x0.99), 2/5 episodes done, nodes alive 1/2 (dead: policy); policy: no gripper input")
    assert status_line(None, None, 0, 0, {"sim": True}, []) == "steps/s ?, 0 episodes done, nodes alive 1/1; no warnings"
