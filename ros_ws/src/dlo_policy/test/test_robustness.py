"""dlo-robustness: 95% Wilson intervals, each family's tolerance on each side of its nominal, and the command: a grid
evaluated through dlo-evaluate's protocol with the family as the env's perturbation, points written one by one and
read back on a rerun (resumable), the summary JSON and the figure, the table and a JSON line on stdout, progress lines
on stderr off a terminal, user errors in one line with exit 2."""

import json
import shutil
import subprocess
import sys

import pytest
import yaml
from dlo_policy import perturbations as P
from dlo_policy.robustness import sides, tolerance, wilson


def test_wilson_interval():
    assert wilson(90, 100) == pytest.approx((0.82563, 0.94477), abs=1e-5)
    low, high = wilson(0, 100)
    assert low == pytest.approx(0.0, abs=1e-12) and high == pytest.approx(0.03699, abs=1e-5)
    assert wilson(100, 100)[1] == 1.0


def test_tolerance_is_the_first_magnitude_below_the_threshold_going_away_from_the_nominal():
    delay = P.family("observation_delay")
    assert tolerance(delay, 0.9, {1: 0.85, 2: 0.7, 3: 0.9, 4: 0.1}) == {"above": 2}
    assert tolerance(delay, 0.9, {1: 0.85, 2: 0.81}) == {"above": None}  # tolerates the whole grid
    assert tolerance(delay, 0.7, {1: 0.85}) == {"above": 0}  # already below unperturbed
    gain = P.family("velocity_gain")  # nominal 1: two sides, nearest first
    assert sides(gain, [0.25, 0.5, 0.75, 1.5, 3.0]) == {"below": [0.75, 0.5, 0.25], "above": [1.5, 3.0]}
    assert tolerance(gain, 0.9, {0.25: 0.1, 0.5: 0.5, 0.75: 0.85, 1.5: 0.79, 3.0: 0.2}) == {"below": 0.5, "above": 1.5}
    friction = P.family("friction")  # the nominal is the training range 0.04-0.3: a value inside is on neither side
    assert sides(friction, [0.0, 0.02, 0.1, 0.45, 0.9]) == {"below": [0.02, 0.0], "above": [0.45, 0.9]}
    assert tolerance(friction, 0.9, {0.0: 0.5, 0.02: 0.9, 0.1: 0.1, 0.45: 0.95, 0.9: 0.6}) == {"below": 0.0, "above": 0.9}
    assert tolerance(P.family("cable_length"), 0.9, {10: 0.5, 20: 0.9}) == {"below": 10}  # one side only


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """The shipped policy in a run directory of its own whose episodes last 4 control steps."""
    from dlo_policy.rundir import shipped_policy_path

    shipped = shipped_policy_path()
    run = tmp_path_factory.mktemp("runs") / "tiny"
    run.mkdir()
    shutil.copy(shipped, run / "policy.pt")
    config = yaml.safe_load((shipped.parent / "config.yaml").read_text())
    config["env_options"]["horizon"] = 4
    (run / "config.yaml").write_text(yaml.safe_dump(config))
    return run / "policy.pt"


def robustness(*args, timeout=600):
    return subprocess.run(
        [sys.executable, "-m", "dlo_policy.robustness", *map(str, args)], capture_output=True, text=True, timeout=timeout
    )


GRID = (
    "--episodes",
    2,
    "--num-envs",
    2,
    "--seed",
    40,
    "--family",
    "observation_delay",
    "--grid",
    "observation_delay=1,3",
    "--grid",
    "friction=0.9",
)


def test_a_grid_is_evaluated_written_and_resumed(tiny_run, tmp_path):
    out = tmp_path / "robustness"
    result = robustness("--checkpoint", tiny_run, "--out", out, *GRID)
    assert result.returncode == 0, result.stderr[-3000:]
    lines = result.stdout.splitlines()
    assert lines[0].startswith("family") and lines[1].startswith("observation_delay") and lines[2].startswith("friction")
    summary_line = json.loads(lines[-1])  # the JSON line last
    assert summary_line["points"] == 4 and summary_line["run"] == 4 and summary_line["read"] == 0
    assert set(summary_line["tolerance"]) == {"observation_delay", "friction"}
    assert all(line.startswith("dlo-robustness: ") for line in result.stderr.splitlines() if line.strip()), (
        result.stderr
    )  # off a terminal: plain progress lines, nothing else
    assert "/8 episodes" in result.stderr  # 4 points x 2 episodes

    policy_dir = out / "tiny"  # the run directory's name
    points = sorted(p.relative_to(policy_dir / "points").as_posix() for p in (policy_dir / "points").rglob("*.json"))
    assert points == ["baseline.json", "friction/0.9.json", "observation_delay/1.json", "observation_delay/3.json"]
    point = json.loads((policy_dir / "points" / "friction" / "0.9.json").read_text())
    assert point["env_options"]["perturbations"] == {"friction": 0.9} and point["env_options"]["horizon"] == 4
    assert point["episodes"] == 2 and "authors_code" in point and point["seed"] == 40
    summary = json.loads((policy_dir / "robustness.json").read_text())
    assert summary["policy"] == "tiny" and summary["episodes"] == 2 and summary["threshold"] == 0.8
    delay = summary["families"]["observation_delay"]
    assert [p["magnitude"] for p in delay["points"]] == [1, 3] and delay["unit"] == "control steps"
    for p in delay["points"] + [summary["baseline"]]:
        for key in ("hold_the_end", "hold_the_end_authors"):
            low, high = p[key + "_ci95"]
            assert low <= p[key] <= high
    assert set(delay["tolerance"]) == {"paper", "authors"} and set(delay["tolerance"]["paper"]) == {"above"}
    assert (policy_dir / "robustness.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    again = robustness("--checkpoint", tiny_run, "--out", out, *GRID)  # everything read back, nothing run
    assert again.returncode == 0, again.stderr[-3000:]
    assert json.loads(again.stdout.splitlines()[-1])["run"] == 0
    assert json.loads((policy_dir / "robustness.json").read_text())["families"] == summary["families"]

    (policy_dir / "points" / "observation_delay" / "3.json").unlink()  # an interrupted run: only the rest runs
    resumed = robustness("--checkpoint", tiny_run, "--out", out, *GRID)
    assert json.loads(resumed.stdout.splitlines()[-1])["run"] == 1

    other = robustness("--checkpoint", tiny_run, "--out", out, *GRID[2:], "--episodes", 3)
    assert other.returncode == 2 and other.stderr.count("\n") == 1
    assert "made with other settings (episodes 2)" in other.stderr and "Traceback" not in other.stderr


@pytest.mark.parametrize(
    "args, message",
    [
        (("--family", "obs_delay"), "unknown perturbation 'obs_delay'; did you mean 'observation_delay'?"),
        (("--grid", "observation_delay=1.5"), "observation_delay: expected an integer"),
        (("--grid", "friction"), "--grid: expected NAME=M1,M2,..."),
        (("--episodes", "0"), "--episodes, --num-envs and --threads must be >= 1"),
        (("--checkpoint", "/nonexistent/policy.pt"), "checkpoint /nonexistent/policy.pt does not exist"),
        (("--threshold", "2"), "--threshold in (0, 1]"),
        (("--nosuch",), "unrecognized arguments: --nosuch"),
    ],
)
def test_user_errors_are_one_line_and_exit_2(args, message):
    result = robustness(*args, timeout=120)
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr.count("\n") == 1 and message in result.stderr and "Traceback" not in result.stderr


def test_help():
    result = robustness("--help", timeout=120)
    assert result.returncode == 0 and "--family" in result.stdout and "tolerance" in result.stdout.lower()
