"""dlo-report: statistics, and figures + table built from real (tiny) training runs."""
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from dlo_policy import report
from dlo_policy.config import load_config
from dlo_policy.experiments import RunSpec, run_config
from dlo_policy.train import train

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib: helper modules

TINY = ["env_module=sac_reach_env", "sac.hidden_sizes=[16,16]", "sac.batch_size=16", "sac.learning_starts=20",
        "sac.buffer_size=500", "train.eval_every=20", "train.checkpoint_every=1000", "train.eval_episodes=4"]
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    """Two seeds each of All (also tested without T and V), V+K, T+K, and a tactile-noise label."""
    previous = torch.get_num_threads()
    out = tmp_path_factory.mktemp("results")
    specs = [RunSpec(label, modalities, seed, eval_without=without)
             for label, modalities, without in (("All", "All", ("T", "V")), ("V+K", "V+K", ()), ("T+K", "T+K", ()),
                                                ("All tactile-partial", "All", ()))
             for seed in (0, 1)]
    for spec in specs:
        train(run_config(spec, None, TINY, steps=120, threads=1), spec.directory(out))
    torch.set_num_threads(previous)
    return out


def test_report_builds_figures_and_table_from_run_directories(results, capsys):
    out = results / "report"
    assert report.main([str(results), "--out", str(out)]) == 0
    for name in ("outcomes_single.png", "outcomes_pairs.png", "metrics_single.png", "metrics_pairs.png",
                 "ablation.png", "sensitivity.png"):
        data = (out / name).read_bytes()
        assert data.startswith(PNG_MAGIC) and len(data) > 10_000, name
    table = (out / "results.md").read_text()
    assert table in capsys.readouterr().out
    lines = {line.split(" | ")[0].lstrip("| "): line for line in table.splitlines() if line.startswith("| ")}
    assert lines["All"].endswith("| 92% |") and lines["V+K"].endswith("| 89% |") and lines["T+K"].endswith("| 16% |")
    assert "| 2 |" in lines["All, tested without T"] and lines["All, tested without T"].endswith("|  |")
    assert "All tactile-partial" in lines and "| 120 |" in lines["All"]


def test_load_runs_groups_seeds_by_label_and_tested_inputs(results):
    runs = report.load_runs(results)
    assert set(runs) == {"All", "V+K", "T+K", "All tactile-partial"}
    assert set(runs["All"]) == {"", "T", "V"} and set(runs["V+K"]) == {""}
    curves = runs["All"]["T"]
    assert curves.seeds == 2 and list(curves.steps) == list(range(0, 121, 20))
    outcome_sum = sum(curves.values[o] for o in report.OUTCOMES)
    np.testing.assert_allclose(outcome_sum, 1.0)
    assert load_config(results / "All" / "seed0" / "config.yaml").train.eval_without == ("T", "V")


def test_smoothing_and_confidence_interval():
    np.testing.assert_allclose(report.smooth(np.array([[0.0, 2, 4, 6, 8, 10, 12]]), window=5),
                               [[0, 1, 2, 3, 4, 6, 8]])
    mean, ci = report.mean_and_ci(np.array([[1.0], [2.0], [3.0]]))
    assert mean[0] == pytest.approx(2.0) and ci[0] == pytest.approx(4.303 / np.sqrt(3))
    assert report.mean_and_ci(np.array([[5.0]]))[1][0] == 0.0


def test_report_without_runs_is_an_error(tmp_path):
    assert report.main([str(tmp_path)]) == 2
