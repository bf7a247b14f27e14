"""dlo-experiments: the paper's grid, local parallel runs, skipping finished runs, Ray without Ray."""
import importlib.util
import json
import sys
from pathlib import Path

import pytest

from dlo_policy import experiments
from dlo_policy.train import CHECKPOINT_FILE, DONE_FILE, EVAL_FILE

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib: helper modules (spawned runs too)

TINY = ["env_module=sac_reach_env", "sac.hidden_sizes=[16,16]", "sac.batch_size=16", "sac.learning_starts=20",
        "sac.buffer_size=500", "train.eval_every=50", "train.checkpoint_every=50", "train.eval_episodes=4"]


def test_grid_covers_the_papers_experiments_once_per_seed():
    specs = experiments.experiment_grid(experiments.GROUPS, seeds=[0, 1])
    labels = sorted({s.label for s in specs})
    assert labels == sorted(["T", "K", "V", "All", "T+K", "V+K", "T+V", "All tactile-partial", "All tactile-full",
                             "T+V tactile-partial", "T+V tactile-full"])
    assert len(specs) == 2 * len(labels)
    by_label = {s.label: s for s in specs if s.seed == 0}
    assert by_label["All"].eval_without == ("T", "V")
    assert set(by_label["All"].groups) == {"single", "ablation", "sensitivity"}
    assert by_label["T+V tactile-full"].modalities == "T+V"
    assert dict(by_label["T+V tactile-full"].env_options) == {"tactile_noise": "full"}
    assert by_label["V"].eval_without == () and by_label["V"].env_options == ()
    assert experiments.experiment_grid(["single"], seeds=[3])[0].seed == 3
    order = [(s.seed, s.label) for s in experiments.experiment_grid(["single"], seeds=[1, 2])]
    assert order == [(1, "T"), (1, "K"), (1, "V"), (1, "All"), (2, "T"), (2, "K"), (2, "V"), (2, "All")]
    with pytest.raises(ValueError, match="unknown group"):
        experiments.experiment_grid(["singles"], seeds=[0])


def test_runner_skips_finished_runs_and_runs_the_rest_in_processes(tmp_path, capsys):
    out = tmp_path / "grid"
    finished = out / "K" / "seed0"
    finished.mkdir(parents=True)
    (finished / DONE_FILE).write_text("{}")
    argv = ["--out", str(out), "--groups", "single", "--seeds", "1", "--steps", "60", "--jobs", "2",
            "--threads", "1", *TINY]
    assert experiments.main(argv) == 0
    assert "4 runs, 1 done, 3 to run" in capsys.readouterr().out
    assert not (finished / EVAL_FILE).exists()
    for label in ("T", "V", "All"):
        run = out / label / "seed0"
        assert json.loads((run / DONE_FILE).read_text())["env_steps"] == 60
        assert (run / "train.log").exists() and (run / CHECKPOINT_FILE).exists()
    assert experiments.main(argv) == 0
    assert "4 runs, 4 done, 0 to run" in capsys.readouterr().out


def test_run_status_and_directories(tmp_path):
    spec = experiments.RunSpec("T+V tactile-full", "T+V", 2)
    run = spec.directory(tmp_path)
    assert run == tmp_path / "T+V_tactile-full" / "seed2"
    assert experiments.run_status(run) == "todo"
    run.mkdir(parents=True)
    (run / CHECKPOINT_FILE).write_bytes(b"")
    assert experiments.run_status(run) == "partial"
    (run / DONE_FILE).write_text("{}")
    assert experiments.run_status(run) == "done"


def test_run_config_carries_the_spec_and_overrides(tmp_path):
    spec = experiments.RunSpec("All tactile-partial", "All", 4, (("tactile_noise", "partial"),), ("T", "V"))
    config = experiments.run_config(spec, None, ["sac.batch_size=64"], steps=1000, threads=1)
    assert (config.modalities, config.seed, config.label) == ("All", 4, "All tactile-partial")
    assert config.env_options == {"tactile_noise": "partial"} and config.train.eval_without == ("T", "V")
    assert (config.train.total_steps, config.train.num_threads, config.sac.batch_size) == (1000, 1, 64)
    assert config.train.progress is False


@pytest.mark.skipif(importlib.util.find_spec("ray") is not None, reason="Ray is installed here")
def test_ray_address_without_ray_is_a_clear_error(tmp_path):
    with pytest.raises(SystemExit, match="pip install ray"):
        experiments.main(["--out", str(tmp_path), "--ray-address", "auto"])


def test_makespan_packs_longest_first_and_run_time_counts_evaluations():
    assert experiments.makespan([3, 3, 2, 2, 2], jobs=2) == 7
    assert experiments.makespan([5, 1], jobs=4) == 5
    cal = experiments.Calibration(step_s=0.1, eval_s=2.0)
    config = experiments.load_config(None, ["train.total_steps=1000", "train.eval_every=200",
                                            "train.eval_without=[T]", "train.test_episodes=100"])
    # 1000 steps + (5 evaluations + the one at step 0 + 10 test batches of 10) x 2 tested input sets
    assert cal.run_seconds(config) == pytest.approx(100 + (6 + 10) * 2 * 2.0)
    assert cal.run_seconds(config, done_steps=600) == pytest.approx(40 + (2 + 10) * 2 * 2.0)


def test_dry_run_estimates_from_a_measured_calibration(tmp_path, capsys):
    argv = ["--out", str(tmp_path / "grid"), "--groups", "single", "--seeds", "2", "--steps", "400",
            "--jobs", "2", "--dry-run", *TINY]
    assert experiments.main(argv) == 0
    out = capsys.readouterr().out
    assert "8 runs, 0 done, 8 to run" in out and "estimate: 8 runs" in out and "ms per step" in out
    assert not (tmp_path / "grid").exists()


def test_bad_env_option_stops_the_grid_before_any_run(tmp_path, capsys):
    argv = ["--out", str(tmp_path / "grid"), "--groups", "single", "--seeds", "1",
            "env_options.tactile_noise=loud"]
    assert experiments.main(argv) == 2
    assert "env_options: tactile_noise" in capsys.readouterr().err
    assert not (tmp_path / "grid").exists()
