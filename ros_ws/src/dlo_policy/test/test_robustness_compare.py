"""dlo-robustness compare: two envelopes (robustness.json made by dlo_policy.robustness.summarise from synthetic
points) side by side -- each side's tolerance as a distance from the nominal, the ratio to the reference's (bounds
where a policy tolerates its whole grid), the families and sides the issue's test counts, its summary line, the
files, and user errors in one line with exit 2."""

import json
import subprocess
import sys

import pytest
from dlo_policy import robustness_compare as C
from dlo_policy.robustness import SUMMARY_FILE, summarise

SETTINGS = {"episodes": 100, "seed": 7000, "num_envs": 10}
RANDOMISE = {"observation_delay": [0, 2], "camera_yaw": [0, 4], "friction": [0.02, 0.9], "velocity_gain": [0.5, 2.0]}


def point(authors, paper=None):
    """A point as dlo-evaluate --json writes it, with hold the end ``paper`` / ``authors``."""
    paper = authors if paper is None else paper
    rest = {"stop_before": 1.0 - paper, "reach_end_but_drop": 0.0, "drop_before": 0.0}
    rest_authors = {"stop_before": 1.0 - authors, "reach_end_but_drop": 0.0, "drop_before": 0.0}
    return {
        "episodes": SETTINGS["episodes"],
        "hold_the_end": paper,
        **rest,
        "authors_code": {"hold_the_end": authors, **rest_authors},
        "episode_reward": 0.0,
        "time_at_end": 0.0,
        "how_far": 0.0,
    }


def envelope(policy, baseline, curves, randomise=None, **settings):
    """robustness.json of ``curves`` ({family: {magnitude: hold the end, both rules}})."""
    header = {"policy": policy, "checkpoint": policy, **SETTINGS, **settings, "env_options": {}}
    if randomise:
        header["env_options"]["randomise"] = randomise
    points = {(name, m): point(v) for name, curve in curves.items() for m, v in curve.items()}
    families = {name: tuple(sorted(curve)) for name, curve in curves.items()}
    return summarise(points, point(baseline), families, header, 0.8)


SHIPPED = {
    "observation_delay": {1: 0.3, 2: 0.1, 3: 0.0, 4: 0.0, 6: 0.0},  # below from 1
    "camera_yaw": {1: 0.85, 2: 0.6, 3: 0.4, 4: 0.2},  # from 2
    "friction": {0.0: 0.7, 0.02: 0.85, 0.45: 0.9, 0.6: 0.7, 0.9: 0.6, 1.2: 0.5},  # below from 0 (0.04), above 0.6 (0.3)
    "velocity_gain": {0.25: 0.85, 0.5: 0.9, 1.5: 0.7, 2.0: 0.3},  # below: never; above from 1.5 (0.5)
    "tactile_angle_noise": {20: 0.9, 40: 0.7},  # not randomised: not counted
}
ROBUST = {
    "observation_delay": {1: 0.85, 2: 0.82, 3: 0.5, 4: 0.1, 6: 0.0},  # from 3: 3x
    "camera_yaw": {1: 0.9, 2: 0.85, 3: 0.7, 4: 0.5},  # from 3: 1.5x
    "friction": {0.0: 0.7, 0.02: 0.85, 0.45: 0.9, 0.6: 0.9, 0.9: 0.7, 1.2: 0.5},  # above from 0.9: 0.6 / 0.3 = 2x
    "velocity_gain": {0.25: 0.6, 0.5: 0.9, 1.5: 0.85, 2.0: 0.82},  # above: never up to 2 (>= 1.0 / 0.5)
    "tactile_angle_noise": {20: 0.9, 40: 0.9},
}


@pytest.fixture
def result():
    envelopes = {"shipped": envelope("shipped", 0.9, SHIPPED), "robust": envelope("robust", 0.89, ROBUST, RANDOMISE)}
    return C.compare(envelopes)


def authors(result, family, side, policy="robust"):
    return result["families"][family]["sides"][side]["authors"][policy]


def test_tolerances_are_distances_from_the_nominal_and_ratios_of_them(result):
    assert authors(result, "observation_delay", "above", "shipped") == {"magnitude": 1, "distance": 1.0, "whole_grid": False}
    assert authors(result, "observation_delay", "above")["ratio"] == {"value": 3.0, "bound": "=", "twice": True}
    assert authors(result, "camera_yaw", "above")["ratio"] == {"value": 1.5, "bound": "=", "twice": False}
    # a physics family from the end of its training range (0.04-0.3): 0.9 is 0.6 above, 0.6 is 0.3 above: 2x (the
    # magnitudes' ratio, 1.5, would not be)
    friction = authors(result, "friction", "above")
    assert friction["distance"] == pytest.approx(0.6) and friction["ratio"]["value"] == pytest.approx(2.0)
    assert friction["ratio"]["twice"] is True
    assert authors(result, "friction", "below", "shipped")["distance"] == pytest.approx(0.04)  # 0 is 0.04 below
    # the whole grid: at least the farthest magnitude tried, a bound
    gain = authors(result, "velocity_gain", "above")
    assert gain["whole_grid"] and gain["magnitude"] == 2.0 and gain["distance"] == pytest.approx(1.0)
    assert gain["ratio"]["bound"] == ">=" and gain["ratio"]["value"] == pytest.approx(2.0) and gain["ratio"]["twice"]
    below = authors(result, "velocity_gain", "below")  # shipped never drops below 1, robust at 0.25: at most 1x
    assert below["ratio"]["bound"] == "<=" and below["ratio"]["value"] == pytest.approx(1.0) and below["ratio"]["twice"] is False


def test_ratio_bounds_and_the_nominal():
    measured = {"distance": 2.0, "whole_grid": False}
    whole = {"distance": 3.0, "whole_grid": True}
    assert C.ratio(measured, whole) == {"value": 1.5, "bound": ">=", "twice": None}  # the grid is too short to tell
    assert C.ratio(whole, measured)["twice"] is False
    assert C.ratio(whole, whole) == {"value": None, "bound": None, "twice": None}
    at_nominal = {"distance": 0.0, "whole_grid": False}
    assert C.ratio(at_nominal, measured) == {"value": None, "bound": "inf", "twice": True}
    assert C.ratio(at_nominal, at_nominal)["twice"] is None


def test_the_issues_test_counts_the_randomised_families_on_the_sides_their_ranges_reach(result):
    test = result["tests"]["robust"]
    verdicts = test["per_family"]
    assert set(verdicts) == set(RANDOMISE) and "tactile_angle_noise" not in verdicts
    # friction 0.02-0.9 reaches the shipped policy's 0.6 above, not its 0 below; the gain 0.5-2 its 1.5 only
    assert verdicts["friction"]["sides"] == ["above"] and verdicts["velocity_gain"]["sides"] == ["above"]
    assert {name: v["twice"] for name, v in verdicts.items()} == {
        "observation_delay": True,
        "camera_yaw": False,
        "friction": True,
        "velocity_gain": True,
    }
    assert (test["twice"], test["families"], test["unperturbed_difference_points"], test["within"]) == (3, 4, -1.0, True)
    assert test["line"] == "robust vs shipped: unperturbed authors' rule -1 point (within 3); tolerance >= 2x on 3 of 4 families"


def test_more_than_3_points_below_unperturbed_and_families_named_by_hand():
    envelopes = {"shipped": envelope("shipped", 0.9, SHIPPED), "other": envelope("other", 0.86, ROBUST)}
    test = C.compare(envelopes, ["camera_yaw", "tactile_angle_noise"])["tests"]["other"]
    assert test["line"] == (
        "other vs shipped: unperturbed authors' rule -4 points (more than 3); tolerance >= 2x on 0 of 2 families "
        "(1 undetermined: the grid too short)"  # tactile_angle_noise: 40 against never up to 40, >= 1x
    )
    # no randomisation, no family named: every family both evaluated, every side (friction's below: 1x, the gain's
    # below: at most 1x), so only the delay passes
    test = C.compare(envelopes)["tests"]["other"]
    assert test["per_family"]["friction"]["sides"] == ["below", "above"]
    assert {name: v["twice"] for name, v in test["per_family"].items()} == {
        "observation_delay": True,
        "tactile_angle_noise": None,
        "velocity_gain": False,
        "friction": False,
        "camera_yaw": False,
    }
    assert (test["families"], test["twice"], test["undetermined"]) == (5, 1, 1)


def test_envelopes_of_other_episodes_are_refused():
    envelopes = {"shipped": envelope("shipped", 0.9, SHIPPED), "robust": envelope("robust", 0.9, ROBUST, seed=5000)}
    with pytest.raises(ValueError, match="not the same episodes: robust has seed 5000, shipped 7000"):
        C.compare(envelopes)


def write(directory, summary):
    directory.mkdir(parents=True)
    (directory / SUMMARY_FILE).write_text(json.dumps(summary))
    return directory


def compare_command(*args, timeout=120):
    return subprocess.run(
        [sys.executable, "-m", "dlo_policy.robustness", "compare", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def test_the_command_writes_the_figure_the_table_and_the_json(tmp_path):
    shipped = write(tmp_path / "shipped", envelope("shipped", 0.9, SHIPPED))
    robust = write(tmp_path / "robust_seed1", envelope("robust_seed1", 0.89, ROBUST, RANDOMISE))
    out = tmp_path / "compare"
    result = compare_command(shipped, robust, "--out", out)
    assert result.returncode == 0, result.stderr[-3000:]
    lines = result.stdout.splitlines()
    line = "robust_seed1 vs shipped: unperturbed authors' rule -1 point (within 3); tolerance >= 2x on 3 of 4 families"
    assert lines[0] == line
    last = json.loads(lines[-1])
    assert last["reference"] == "shipped" and last["tests"]["robust_seed1"]["twice"] == 3
    assert (out / "compare.png").stat().st_size > 10000
    table = (out / "compare.md").read_text()
    assert line in table and "| `friction` (Coulomb coefficient) | above | authors | 0.6 (0.3) | 0.9 (0.6) | 2 |" in table
    assert "none to 2 (>= 1)" in table  # the gain's whole grid, said so
    assert json.loads((out / "compare.json").read_text())["tests"]["robust_seed1"]["line"] == line


@pytest.mark.parametrize(
    "case, message",
    [
        ("missing", "no such directory"),
        ("empty", "no robustness.json"),
        ("broken", "cannot be read"),
        ("not_a_summary", "not a dlo-robustness summary (no episodes, seed, num_envs, threshold, baseline, families)"),
        ("other_seed", "not the same episodes: other_seed has seed 5000, shipped 7000"),
        ("one", "give two or more envelope directories"),
        ("family", "unknown perturbation 'obs_delay'"),
        ("no_out", "the following arguments are required: --out"),
    ],
)
def test_user_errors_are_one_line_and_exit_2(tmp_path, case, message):
    shipped = write(tmp_path / "shipped", envelope("shipped", 0.9, SHIPPED))
    other = tmp_path / case
    extra = ["--out", tmp_path / "out"]
    if case == "empty":
        other.mkdir()
    elif case == "broken":
        other.mkdir()
        (other / SUMMARY_FILE).write_text("{not json")
    elif case == "not_a_summary":
        write(other, {"policy": "x"})
    elif case == "other_seed":
        write(other, envelope("other_seed", 0.9, ROBUST, seed=5000))
    elif case == "family":
        other = write(other, envelope("family", 0.9, ROBUST))
        extra += ["--family", "obs_delay"]
    elif case == "no_out":
        other, extra = write(other, envelope("no_out", 0.9, ROBUST)), []
    args = [shipped] if case == "one" else [shipped, other]
    result = compare_command(*args, *extra)
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr.count("\n") == 1 and message in result.stderr and "Traceback" not in result.stderr


def test_help():
    result = compare_command("--help")
    assert result.returncode == 0 and "--out" in result.stdout and "ratio" in result.stdout
    result = subprocess.run(
        [sys.executable, "-m", "dlo_policy.robustness", "--help"], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0 and "dlo-robustness compare" in result.stdout
