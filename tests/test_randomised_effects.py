"""tools/randomised_effects.py: the fitted change in episode length is the one planted in a synthetic run."""

import csv
import importlib.util
import pathlib

import numpy as np
import yaml

ROOT = pathlib.Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("randomised_effects", ROOT / "tools" / "randomised_effects.py")
tool = importlib.util.module_from_spec(spec)
spec.loader.exec_module(tool)


def synthetic_run(path, episodes=400, seed=0, ranges=None):
    """Episode length 140 - 90 * (velocity_gain scaled to its range), friction without effect."""
    rng = np.random.default_rng(seed)
    ranges = ranges or {"velocity_gain": [0.5, 2.0], "friction": [0.02, 0.9]}
    (path / "config.yaml").write_text(yaml.safe_dump({"env_options": {"randomise": ranges}}))
    step = 0
    with (path / "randomised.csv").open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["step", "episode", "episode_seed", "velocity_gain", "friction"])
        for k in range(episodes):
            gain, friction = rng.uniform(0.5, 2.0), rng.uniform(0.02, 0.9)
            step += int(round(140 - 90 * (gain - 0.5) / 1.5))
            writer.writerow([step, k, k, gain, friction])
    return path


def test_the_planted_effect_is_found_and_the_other_family_has_none(tmp_path):
    result = tool.effects(synthetic_run(tmp_path))
    fit = result["fits"]["length"]
    assert abs(fit["velocity_gain"] + 90) < 2 and abs(fit["friction"]) < 2
    assert result["families"] == ["velocity_gain", "friction"] and result["episodes"] < 400


def test_ranges_given_as_text_on_the_command_line_are_read_as_the_run_read_them(tmp_path):
    """dlo-train ... env_options.randomise=velocity_gain=0.5:2,friction=0.02:0.9 keeps the text in config.yaml."""
    result = tool.effects(synthetic_run(tmp_path, ranges="velocity_gain=0.5:2,friction=0.02:0.9"))
    assert abs(result["fits"]["length"]["velocity_gain"] + 90) < 2


def test_a_directory_without_randomised_csv_is_one_line_and_exit_2(tmp_path, capsys):
    assert tool.main([str(tmp_path)]) == 2
    assert capsys.readouterr().err.count("\n") == 1
