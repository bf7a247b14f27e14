"""dlo-report: statistics, tables and figures from hand-made run directories, and one real tiny run."""

import csv
import json
import math
import sys
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pytest
import torch
from dlo_policy import report, report_data, report_plots, report_tables
from dlo_policy.config import load_config, save_config
from dlo_policy.grid import RunSpec, run_config
from dlo_policy.rundir import EVAL_COLUMNS, OUTCOMES_AUTHORS
from dlo_policy.train import train
from matplotlib.collections import PolyCollection

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib: helper modules

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
OLD_COLUMNS = tuple(c for c in EVAL_COLUMNS if c not in OUTCOMES_AUTHORS and c != "eval_seed")
EVERY = 100


def write_run(
    root: Path,
    label: str,
    seed: int,
    hold,
    *,
    authors=None,
    modalities=None,
    done=True,
    test=None,
    without=None,
    old_csv=False,
    total_steps=None,
    config_overrides=(),
):
    """A run directory as dlo-train leaves it: config.yaml, eval.csv (hold the end per evaluation,
    every EVERY steps; authors' rule = `authors` or hold - 0.1), done.json and test.json if given.
    without: {modality: hold curve} extra ablation rows; test: (paper, authors) or
    {tested_without: (paper, authors)}; old_csv: no *_authors / eval_seed columns."""
    directory = root / label.replace(" ", "_") / f"seed{seed}"
    directory.mkdir(parents=True)
    without = without or {}
    config = load_config(
        None,
        config_overrides,
        {
            "modalities": modalities or label,
            "seed": seed,
            "label": label,
            "train.eval_every": EVERY,
            "train.total_steps": total_steps or (len(hold) - 1) * EVERY,
            "train.eval_without": sorted(without),
        },
    )
    save_config(config, directory / "config.yaml")
    curves = {"": (hold, authors if authors is not None else [max(h - 0.1, 0.0) for h in hold])}
    curves.update({w: (c, [max(h - 0.1, 0.0) for h in c]) for w, c in without.items()})
    rows = []
    for k in range(len(hold)):
        for tested, (paper, authors_curve) in curves.items():
            h, a = paper[k], authors_curve[k]
            rows.append(
                {
                    "step": k * EVERY,
                    "tested_without": tested,
                    "episodes": 10,
                    "eval_seed": 1_000_000 + 100_000 * seed + 10 * k,
                    "hold_the_end": h,
                    "stop_before": 1 - h,
                    "reach_end_but_drop": 0.0,
                    "drop_before": 0.0,
                    "hold_the_end_authors": a,
                    "stop_before_authors": 1 - a,
                    "reach_end_but_drop_authors": 0.0,
                    "drop_before_authors": 0.0,
                    "episode_reward": 3 * h,
                    "time_at_end": 20 * h,
                    "how_far": 30 * (1 - h),
                    "train_episodes": k,
                    "wall_time_s": k,
                }
            )
    columns = OLD_COLUMNS if old_csv else EVAL_COLUMNS
    with (directory / "eval.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    if done:
        (directory / "done.json").write_text("{}\n")
    tests = test if isinstance(test, dict) else ({"": test} if test is not None else {})
    for tested, (paper, authors_value) in tests.items():
        name = f"test_without_{tested}.json" if tested else "test.json"
        payload = {"episodes": 100, "hold_the_end": paper, "stop_before": 1 - paper}
        if authors_value is not None:
            payload["authors_code"] = {"hold_the_end": authors_value}
        (directory / name).write_text(json.dumps(payload))
    return directory


def table_rows(text: str) -> dict[str, list[str]]:
    """Markdown table -> first cell -> all cells (first table of the text)."""
    rows = {}
    for line in text.splitlines():
        if line.startswith("| ") and not line.startswith("| configuration"):
            cells = [c.strip() for c in line.strip().strip("|").split(" | ")]
            rows.setdefault(cells[0], cells)
    return rows


FLAT = [0.5] * 12


# ------------------------------------------------------------------------------------------ statistics


def test_smoothing_and_confidence_interval():
    np.testing.assert_allclose(report_data.smooth(np.array([[0.0, 2, 4, 6, 8, 10, 12]]), window=5), [[0, 1, 2, 3, 4, 6, 8]])
    mean, ci = report_data.mean_and_ci(np.array([[1.0], [2.0], [3.0]]))
    assert mean[0] == pytest.approx(2.0) and ci[0] == pytest.approx(4.303 / np.sqrt(3))
    assert report_data.mean_and_ci(np.array([[5.0]]))[1][0] == 0.0
    single = report_data.stat_of([0.4])
    assert single.mean == pytest.approx(0.4) and single.n == 1 and math.isnan(single.ci)


@pytest.mark.parametrize("n, quantile", [(2, 12.706), (3, 4.303), (30, 2.045), (31, 2.042), (32, 1.96), (100, 1.96)])
def test_the_confidence_half_width_uses_t_with_n_minus_1_degrees_of_freedom_up_to_30_then_the_normal(n, quantile):
    """report_data.T_975 holds df = 1..30: n = 31 samples (df 30) still take the table's last entry."""
    samples = np.array([0.0, 1.0] * (n // 2) + [0.5] * (n % 2))
    stat = report_data.stat_of(samples)
    assert stat.n == n
    assert stat.ci == pytest.approx(quantile * samples.std(ddof=1) / math.sqrt(n))


def test_last5_over_best_ratio_on_a_hand_made_curve():
    """Rises to 1.0 for 5 evaluations, sags to 0.5: best smoothed 1.0 at the 10th, last-5 0.5, ratio 0.5."""
    sag = [0, 0, 0, 0, 0, 1, 1, 1, 1, 1, 0.5, 0.5, 0.5, 0.5, 0.5]
    curves = report_data.Curves(np.arange(len(sag)) * EVERY, {"hold_the_end": np.array([sag, sag])})
    best, step = report_data.best_smoothed(curves)
    assert best.mean == pytest.approx(1.0) and step == 9 * EVERY and best.ci == pytest.approx(0.0)
    last = report_data.last_mean(curves)
    assert last.mean == pytest.approx(0.5)
    assert report_data.level_ratio(last, best) == pytest.approx(0.5)
    assert report_tables.format_ratio(0.5) == "0.50 (sags)"
    # the threshold: 0.9 holds; 0.8999 sags and is not printed as "0.90"
    assert report_tables.format_ratio(0.45 / 0.5) == "0.90 (holds)" and report_tables.format_ratio(0.8999) == "0.89 (sags)"
    # two seeds, different levels: the ratio is of the seed means
    other = [x * 0.5 for x in sag[:10]] + [0.5] * 5  # best smoothed 0.5, last-5 0.5
    curves = report_data.Curves(curves.steps, {"hold_the_end": np.array([sag, other])})
    best, step = report_data.best_smoothed(curves)
    assert best.mean == pytest.approx(0.75) and step == 9 * EVERY
    assert report_data.level_ratio(report_data.last_mean(curves), best) == pytest.approx(0.5 / 0.75)


def test_ratio_in_the_table_of_a_hand_made_run(tmp_path):
    write_run(tmp_path, "V", 0, [0, 0.2, 0.4, 0.6, 0.8, 1, 1, 1, 1, 1, 0.7, 0.7, 0.7, 0.7, 0.7])
    row = table_rows(report_tables.results_table(report_data.load_runs(tmp_path)))["V"]
    assert row[2] == f"100% (1 seed) at {9 * EVERY:,}" and row[4] == "70% (1 seed)" and row[6] == "0.70 (sags)"
    # the authors' rule (hold - 0.1 here): best smoothed 90%, last-5 60%, its own ratio 0.6 / 0.9
    assert row[3] == f"90% (1 seed) at {9 * EVERY:,}" and row[5] == "60% (1 seed)" and row[7] == "0.66 (sags)"


def test_the_unsmoothed_best_is_the_highest_evaluation_of_the_seed_averaged_curve(tmp_path):
    """results.md's second table: the best of the seed mean WITHOUT smoothing (the paper's listed statistic), under
    both rules, at its step, beside the paper's number; the main table keeps the smoothed best."""
    write_run(tmp_path, "V", 1, [0, 0, 1, 0, 0, 0.5, 0.5], authors=[0, 0, 0.8, 0, 0, 0, 0])
    write_run(tmp_path, "V", 2, [0, 0, 0.6, 0, 0, 0.5, 0.7], authors=[0, 0, 0.4, 0, 0, 0, 0.2])
    text = report_tables.results_table(report_data.load_runs(tmp_path))
    main, unsmoothed = text.split("| configuration | seeds (finished/total) × steps | best unsmoothed")
    # smoothed (trailing 5): seeds 0.40 and 0.36 at the last step, the highest of the seed mean (0.38)
    assert table_rows(main)["V"][2] == f"38% ± 25% at {6 * EVERY:,}"
    row = table_rows("| configuration" + unsmoothed)["V"]
    # unsmoothed: the seed mean peaks at step 2 (1.0 and 0.6; authors' rule 0.8 and 0.4), t(1) = 12.706
    assert row[1:4] == ["2/2 × 600", f"80% ± 254% at {2 * EVERY:,}", f"60% ± 254% at {2 * EVERY:,}"]
    assert row[4] == "77%"
    assert "*Best unsmoothed mean*" in unsmoothed and "10 seeds" in unsmoothed


def test_band_only_from_three_seeds():
    assert not report_plots.band_allowed(1) and not report_plots.band_allowed(2)
    assert report_plots.band_allowed(3) and report_plots.band_allowed(10)
    rng = np.random.default_rng(0)
    for seeds, bands in ((2, 0), (3, 1)):
        fig, ax = plt.subplots()
        drawn = report_plots.draw_curve(ax, np.arange(8), rng.random((seeds, 8)), "C0")
        polys = [c for c in ax.collections if isinstance(c, PolyCollection)]
        assert drawn == bool(bands) and len(polys) == bands
        assert len(ax.lines) == seeds + 1  # a thin line per seed and the mean
        plt.close(fig)


# -------------------------------------------------------------------------------------- report files


def test_no_pairs_figure_without_pair_runs(tmp_path, capsys):
    results, out = tmp_path / "results", tmp_path / "out"
    for label, seeds in (("T", 1), ("V", 2), ("All", 3)):
        for seed in range(seeds):
            write_run(results, label, seed, FLAT, test=(0.5, 0.4))
    assert report.main([str(results), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    for name in ("outcomes_single.png", "metrics_single.png"):
        data = (out / name).read_bytes()
        assert data.startswith(PNG_MAGIC) and len(data) > 10_000, name
    for name in ("outcomes_pairs.png", "metrics_pairs.png", "ablation.png", "sensitivity.png"):
        assert not (out / name).exists() and f"skipped {name}: " in printed
    assert "skipped outcomes_pairs.png: no runs of T+K, V+K or T+V" in printed
    assert (out / "results.md").read_text() in printed


def test_pairs_figures_hold_all_as_reference_when_pairs_exist(tmp_path):
    for label in ("V+K", "All"):
        write_run(tmp_path, label, 0, FLAT)
    runs = report_data.load_runs(tmp_path)
    figures = {name: draw for name, draw, _ in report_plots.planned_figures(runs)}
    fig = figures["outcomes_pairs.png"]()
    titles = [ax.get_title() for ax in fig.axes if ax.get_title()]
    assert titles == ["V+K (1 seed)", "All (1 seed)"]
    plt.close(fig)
    assert figures["outcomes_single.png"]() is not None  # All
    write_run(tmp_path / "only_all", "All", 0, FLAT)
    runs = report_data.load_runs(tmp_path / "only_all")
    assert {n: d() for n, d, _ in report_plots.planned_figures(runs)}["outcomes_pairs.png"] is None


def test_figures_state_seeds_and_smoothing(tmp_path):
    for seed in range(3):
        write_run(tmp_path, "V", seed, FLAT, done=seed < 2)
    write_run(tmp_path, "T", 0, FLAT)
    runs = report_data.load_runs(tmp_path)
    fig = report_plots.outcome_figure(runs, report_data.SINGLE)
    assert [ax.get_title() for ax in fig.axes[:2]] == ["T (1 seed)", "V (3 seeds, 2 finished)"]
    assert "trailing mean of 5 evaluations" in fig.get_suptitle()
    bands = [len([c for c in ax.collections if isinstance(c, PolyCollection)]) for ax in fig.axes[:2]]
    assert bands == [0, 1]  # the hold-the-end band: V only
    plt.close(fig)
    fig = report_plots.metrics_figure(runs, report_data.SINGLE)
    assert "trailing mean of 5 evaluations" in fig.get_suptitle()
    assert all("seeds per configuration" in ax.get_title() for ax in fig.axes[:5])
    legend = [t.get_text() for t in fig.axes[5].get_legend().get_texts()]
    assert "T (1 seed)" in legend and "V (3 seeds, 2 finished)" in legend
    plt.close(fig)


def test_single_seed_rows_show_no_plus_minus(tmp_path):
    write_run(tmp_path, "T", 0, [0.1, 0.2, 0.3, 0.2, 0.2, 0.2], test=(0.25, 0.2))
    for seed in range(2):
        write_run(tmp_path, "V", seed, [0.5, 0.6, 0.7, 0.8, 0.8, 0.8 + 0.1 * seed], test=(0.8, 0.7))
    rows = table_rows(report_tables.results_table(report_data.load_runs(tmp_path)))
    assert not any("±" in cell for cell in rows["T"])
    assert rows["T"][1] == "1/1 × 500" and rows["T"][8:10] == ["25% (1 seed)", "20% (1 seed)"]
    assert "(1 seed)" in rows["T"][2] and rows["T"][-1] == "12%"
    assert "±" in rows["V"][2] and "±" in rows["V"][8] and "(1 seed)" not in " ".join(rows["V"])


def test_held_out_test_means_come_from_test_json_of_finished_seeds(tmp_path):
    for seed, paper, authors in ((0, 0.9, 0.6), (1, 0.8, 0.5), (2, 0.7, 0.4)):
        write_run(
            tmp_path,
            "All",
            seed,
            FLAT,
            test={"": (paper, authors), "T": (paper - 0.5, authors - 0.3)},
            without={"T": [0.2] * len(FLAT)},
        )
    # a seed still training: a stray test.json of it does not count, its curve does
    write_run(tmp_path, "All", 3, FLAT[:8], done=False, test=(0.0, 0.0), without={"T": [0.2] * 8}, total_steps=1100)
    runs = report_data.load_runs(tmp_path)
    curves = runs["All"][""]
    assert curves.seeds == 4 and curves.finished_seeds == 3 and list(curves.steps) == [k * EVERY for k in range(8)]
    paper, authors = report_data.held_out_test(curves), report_data.held_out_test(curves, authors=True)
    half_width = 4.303 * 0.1 / math.sqrt(3)
    assert (paper.mean, paper.ci, paper.n) == pytest.approx((0.8, half_width, 3))
    assert (authors.mean, authors.ci) == pytest.approx((0.5, half_width))
    rows = table_rows(report_tables.results_table(runs))
    assert rows["All"][1] == "3/4 × 700 (of 1,100)"
    assert rows["All"][8:10] == [f"80% ± {half_width:.0%}", f"50% ± {half_width:.0%}"]
    assert rows["All, tested without T"][8:10] == [f"30% ± {half_width:.0%}", f"20% ± {half_width:.0%}"]
    assert rows["All"][-1] == "92%" and rows["All, tested without T"][-1] == "—"


def test_held_out_test_without_authors_rule_is_na(tmp_path):
    for seed in range(2):
        write_run(tmp_path, "K", seed, FLAT, test=(0.3, None))
    write_run(tmp_path, "V", 0, FLAT, test=(0.3, 0.2))
    (tmp_path / "V" / "seed0" / "test.json").unlink()
    rows = table_rows(report_tables.results_table(report_data.load_runs(tmp_path)))
    assert rows["K"][8].startswith("30% ± ") and rows["K"][9] == "n/a"
    assert rows["V"][8:10] == ["n/a", "n/a"]


def test_old_eval_csv_without_authors_columns_gives_na(tmp_path, capsys):
    for seed in range(3):
        write_run(tmp_path, "V", seed, FLAT, old_csv=True, test=(0.5, None))
    out = tmp_path / "out"
    assert report.main([str(tmp_path), "--out", str(out)]) == 0
    captured = capsys.readouterr()
    row = table_rows((out / "results.md").read_text())["V"]
    assert row[2].startswith("50% ± 0% at") and row[3] == "n/a" and row[7] == "n/a"
    assert (out / "outcomes_single.png").read_bytes().startswith(PNG_MAGIC)
    assert (out / "metrics_single.png").read_bytes().startswith(PNG_MAGIC)
    assert "repeat the same episodes" in captured.err and "repeat the same episodes" in (out / "results.md").read_text()


def test_compare_writes_both_settings_with_their_numbers(tmp_path, capsys):
    rising = [0.0, 0.25, 0.5, 0.75, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0]  # quarters: exact sums
    sagging = rising[:5] + [0.5] * 6
    for seed in range(3):
        write_run(tmp_path / "a", "All", seed, rising, test=(0.9, 0.8))
        write_run(tmp_path / "b", "All", seed, sagging, test=(0.6 + 0.1 * seed, 0.5))
    out = tmp_path / "cmp"
    assert report.main(["--compare", f"frozen={tmp_path / 'a'}", f"running={tmp_path / 'b'}", "--out", str(out)]) == 0
    text = (out / "compare.md").read_text()
    assert text in capsys.readouterr().out
    rows = {
        tuple(cells[:2]): cells
        for cells in ([c.strip() for c in line.strip().strip("|").split(" | ")] for line in text.splitlines())
        if cells[0] == "All"
    }
    assert set(rows) == {("All", "frozen"), ("All", "running")}
    frozen, running = rows[("All", "frozen")], rows[("All", "running")]
    # frozen: smoothed 1.0 first at evaluation 8 (evaluations 4..8 are 1.0); last-5 1.0
    assert frozen[2] == "3/3 × 1,000" and frozen[3] == f"100% ± 0% at {8 * EVERY:,}"
    assert frozen[5:11] == ["100% ± 0%", "90% ± 0%", "1.00 (holds)", "1.00 (holds)", "90% ± 0%", "80% ± 0%"]
    # running: smoothed best (0.5 + 0.75 + 1 + 0.5 + 0.5) / 5 = 0.65 first at evaluation 6; last-5 0.5
    assert running[3] == f"65% ± 0% at {6 * EVERY:,}" and running[5] == "50% ± 0%"
    assert running[7] == "0.76 (sags)"  # 0.5 / 0.65 = 0.769, rounded down
    assert running[9:11] == [f"70% ± {4.303 * 0.1 / math.sqrt(3):.0%}", "50% ± 0%"]
    assert (out / "compare.png").read_bytes().startswith(PNG_MAGIC)
    assert not (out / "results.md").exists()


def test_seeds_of_different_lengths_count_up_to_the_longest_configured_run(tmp_path):
    """Curves.total_steps is the configured run length over all seeds (the table's "of N"), not the first seed's."""
    write_run(tmp_path, "V", 0, [0.2] * 5, total_steps=4 * EVERY)  # finished at 400
    write_run(tmp_path, "V", 1, [0.2] * 5, total_steps=8 * EVERY)  # configured for 800 (train.total_steps: no warning)
    curves = report_data.load_runs(tmp_path)["V"][""]
    assert curves.seed_ids == (0, 1) and curves.total_steps == 8 * EVERY
    row = next(
        line for line in report_tables.results_table(report_data.load_runs(tmp_path)).splitlines() if line.startswith("| V |")
    )
    assert "2/2 × 400 (of 800)" in row


def test_a_setting_without_a_configuration_gets_a_full_row_in_compare_md(tmp_path):
    """compare.md: the row of a setting that lacks a configuration has as many cells as the header."""
    write_run(tmp_path / "a", "V", 0, [0.2] * 6, total_steps=5 * EVERY)
    write_run(tmp_path / "a", "K", 0, [0.1] * 6, total_steps=5 * EVERY)
    write_run(tmp_path / "b", "V", 0, [0.4] * 6, total_steps=5 * EVERY)
    text = report_tables.compare_table(
        [("a", report_data.load_runs(tmp_path / "a")), ("b", report_data.load_runs(tmp_path / "b"))]
    )
    lines = [line for line in text.splitlines() if line.startswith("|")]
    header = lines[0].count("|")
    assert all(line.count("|") == header for line in lines), text
    missing = [line for line in lines if line.startswith("| K | b |")]
    assert len(missing) == 1 and "no runs" in missing[0]


# --------------------------------------------------------------------------------------- command line


@pytest.mark.parametrize(
    "case", ["missing", "empty", "malformed", "duplicate", "no_out", "both", "neither", "same_name", "unknown_flag"]
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, case):
    results = tmp_path / "results"
    write_run(results, "V", 0, FLAT)
    (tmp_path / "empty").mkdir()
    argv = {
        "missing": [str(tmp_path / "nope")],
        "empty": [str(tmp_path / "empty")],
        "malformed": ["--compare", str(results), "--out", str(tmp_path / "o")],
        "no_out": ["--compare", f"a={results}"],
        "both": [str(results), "--compare", f"a={results}", "--out", str(tmp_path / "o")],
        "neither": [],
        "same_name": ["--compare", f"a={results}", f"a={results}", "--out", str(tmp_path / "o")],
        "unknown_flag": [str(results), "--bogus"],
    }
    if case == "duplicate":  # the same label and seed twice: two settings mixed
        write_run(tmp_path / "results" / "other", "V", 0, FLAT)
        argv["duplicate"] = [str(results)]
    assert report.main(argv[case]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("dlo-report: error: ") and "Traceback" not in err


def test_help_describes_both_modes_and_the_statistics(capsys):
    assert report.main(["--help"]) == 0
    text = capsys.readouterr().out
    for phrase in (
        "--compare NAME=DIR",
        "compare.md",
        "results.md",
        "outcomes_pairs.png",
        "held-out test",
        "trailing mean",
        ">= 3 seeds",
        "(1 seed)",
        "authors' rule",
        "last-5 mean",
        "exit status 2",
    ):
        assert phrase.lower() in text.lower(), phrase


def test_differing_configs_of_one_label_are_a_warning(tmp_path, capsys):
    write_run(tmp_path, "V", 0, FLAT)
    write_run(tmp_path, "V", 1, FLAT, config_overrides=["sac.observation_scaling=none"])
    assert report.main([str(tmp_path), "--out", str(tmp_path / "out")]) == 0
    assert "differ in sac.observation_scaling" in capsys.readouterr().err
    assert "differ in sac.observation_scaling" in (tmp_path / "out" / "results.md").read_text()


# ------------------------------------------------------------------------------------------ real run


def test_report_reads_what_dlo_train_writes(tmp_path, capsys):
    """One tiny real training run (All, also evaluated without T): eval.csv, done.json, test.json and
    test_without_T.json as dlo-train writes them give a full table row and the ablation figure."""
    previous = torch.get_num_threads()
    tiny = [
        "env_module=sac_reach_env",
        "sac.hidden_sizes=[16,16]",
        "sac.batch_size=16",
        "sac.learning_starts=20",
        "sac.buffer_size=500",
        "train.eval_every=20",
        "train.checkpoint_every=1000",
        "train.eval_episodes=4",
        "train.test_episodes=6",
    ]
    spec = RunSpec("All", "All", 0, eval_without=("T",))
    try:
        train(run_config(spec, None, tiny, steps=100, threads=1), spec.directory(tmp_path))
    finally:
        torch.set_num_threads(previous)
    out = tmp_path / "report"
    assert report.main([str(tmp_path), "--out", str(out)]) == 0
    rows = table_rows((out / "results.md").read_text())
    test = json.loads((spec.directory(tmp_path) / "test.json").read_text())
    assert rows["All"][1] == "1/1 × 100"
    assert rows["All"][8] == f"{test['hold_the_end']:.0%} (1 seed)"
    assert rows["All"][9] == f"{test['authors_code']['hold_the_end']:.0%} (1 seed)"
    assert "All, tested without T" in rows and rows["All, tested without T"][6] != "n/a"
    assert (out / "ablation.png").read_bytes().startswith(PNG_MAGIC)
    assert "warning" not in capsys.readouterr().err


def test_reading_runs_loads_no_learner():
    """docs/ARCHITECTURE.md#dependencies: the modules that read runs (rundir, grid, config) import
    neither torch nor Ray, and dlo-report imports only them, numpy and matplotlib (a results directory
    can be reported on a machine without the learner)."""
    import subprocess

    code = (
        "import sys\n"
        "import dlo_policy.rundir, dlo_policy.grid, dlo_policy.config\n"
        "light = {'torch', 'ray'} & set(sys.modules)\n"
        "import dlo_policy.report\n"
        "print(sorted(light), sorted({'torch', 'ray', 'taichi', 'gymnasium'} & set(sys.modules)))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split("\n")[0] == "[] []", result.stdout


def test_runs_behind_symbolic_links_are_read(tmp_path):
    """A results directory may link another's seed directories (results/fidelity/screen_baseline_15k)."""
    for seed in range(2):
        write_run(tmp_path / "study", "V", seed, FLAT, test=(0.5, 0.4))
    (tmp_path / "linked" / "V").mkdir(parents=True)
    for seed in range(2):
        (tmp_path / "linked" / "V" / f"seed{seed}").symlink_to(tmp_path / "study" / "V" / f"seed{seed}")
    runs = report_data.load_runs(tmp_path / "linked")
    assert runs["V"][""].seeds == 2
