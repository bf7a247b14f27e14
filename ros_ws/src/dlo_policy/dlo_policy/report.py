"""Figures and tables of the paper's results from dlo-train run directories: `dlo-report`.

    dlo-report RESULTS [--out DIR]                                  # the study (default DIR: RESULTS/report)
    dlo-report --compare NAME=DIR [NAME=DIR ...] --out DIR          # one study under several settings

Input. Every directory below RESULTS holding config.yaml + eval.csv is one run (dlo-train); runs
are grouped by their label (config `label`, else the modalities) and each eval.csv's rows by
`tested_without` ('' = all inputs; T / V = the ablation's evaluations with that input blanked).
A run is finished when it holds done.json; finished runs also hold test.json (held-out test of the
best evaluation's policy: dlo-evaluate JSON, top level = paper-text rule, "authors_code" = the
authors' rule) and test_without_X.json for the ablation. eval.csv files without the *_authors
columns (older runs) give "n/a" for the authors' rule. Runs still in progress count up to the
last evaluation step every seed of the configuration has reached (their common step prefix).
Two runs with the same label and seed under one RESULTS are an error (two settings mixed: use
--compare). Seeds whose configs differ in anything but the seed and thread/progress/step/ablation
settings are reported as a warning (stderr and results.md).

Statistics, per configuration, for n seeds s with x_s(k) = the seed's value at evaluation k
(k = 0 .. K, K = the last evaluation of the common step prefix):
    smoothed         y_s(k) = mean of x_s(j) for j = max(0, k - 4) .. k   (trailing mean of
                     SMOOTHING_WINDOW = 5 evaluations, fewer at the start)
    mean curve       m(k) = (1/n) sum_s y_s(k)
    95% CI           m(k) +- t(0.975, n - 1) sd_s(y_s(k)) / sqrt(n)   (Student t, sample sd)
                     drawn as a band only for n >= 3 seeds (band_allowed); written as "+- x%" in
                     the tables for n >= 2; a single seed is written "(1 seed)", never "+- 0%"
    best             B = max_k m(k) of hold the end, and the step k* where it is reached (paper
                     rule and authors' rule separately: the paper's "best mean" number)
    last-5 mean      L = (1/n) sum_s (1/5) sum_{k=K-4..K} x_s(k)   (raw evaluations, paper rule)
    holds its level  L / B >= 0.9
    held-out test    (1/m) sum over the m finished seeds of test.json's hold_the_end (paper rule)
                     and authors_code.hold_the_end (authors' rule), +- 95% CI for m >= 2
    last-5 / best    printed with two decimals rounded down, so "0.89 (sags)" never reads "0.90"
Each evaluation runs the deterministic policy on fresh episodes (seeds never reused, see
dlo-train; an eval.csv without distinct eval_seed values gives a warning: its best mean is selected
on repeated episodes); the held-out test runs once after training on episodes whose seeds no
evaluation used.

Output of `dlo-report RESULTS` (PNG via matplotlib Agg; a figure is written only when its group
has runs, else it is skipped with the reason printed):
    outcomes_single.png   per configuration T, K, V, All: the four outcome fractions over
                          training, mean over seeds, solid = paper-text rule, dashed = authors'
                          rule; thin lines = each seed's hold the end (paper rule), band = its
                          95% CI for >= 3 seeds
    outcomes_pairs.png    the same for T+K, V+K, T+V, with All as the reference (only when one of
                          T+K, V+K, T+V has runs)
    metrics_single.png    episode reward, hold the end (paper rule), hold the end (authors' rule),
    metrics_pairs.png     time at end, how far: thin line per seed, bold mean, band for >= 3 seeds
                          (same groups as the outcome figures)
    ablation.png          final episode reward of All tested with all inputs / without T / without V
                          (last-5 mean per seed as dots, bar = mean) and reward over training
                          against the agents trained without that input (V+K, T+K)
    sensitivity.png       final episode reward per tactile-noise level, with K (All) and without
                          (T+V), against no tactile input (V+K, V)
    results.md            one row per configuration (and per tested input set of the ablation):
                          seeds (finished/total) x steps, best smoothed mean hold the end under
                          both rules, last-5 mean and last-5/best, held-out test under both rules,
                          the paper's number; the definitions are written under the table
Output of `--compare` (each DIR a results directory of the same configurations trained under
another setting, NAME its name in the outputs):
    compare.md            per configuration and NAME: seeds x steps, best smoothed mean, last-5
                          mean, last-5/best, held-out test under both rules
    compare.png           hold the end (paper rule) per configuration: bold mean line per NAME,
                          thin line per seed, band for >= 3 seeds
Exit status 2 with one line on stderr for bad input (missing directory, no runs, malformed
NAME=DIR, the same label and seed twice).
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple, Optional, Sequence

import matplotlib
import numpy as np

matplotlib.use("Agg")  # files only, no display
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
from matplotlib.ticker import FuncFormatter  # noqa: E402

from .config import ConfigError, RunConfig, load_config
from .evaluate import AUTHORS_SUFFIX, OUTCOMES, OUTCOMES_AUTHORS
from .experiments import SENSITIVITY_PAIRS, TACTILE_NOISE_LEVELS, sensitivity_label
from .train import CONFIG_FILE, DONE_FILE, EVAL_FILE, test_file

PAPER_HOLD_THE_END = {"T": 0.12, "K": 0.11, "V": 0.77, "All": 0.92, "T+K": 0.16, "V+K": 0.89, "T+V": 0.77}
SINGLE, PAIRS = ("T", "K", "V", "All"), ("T+K", "V+K", "T+V")  # figure groups; All is the pairs' reference
TABLE_ORDER = (*SINGLE, *PAIRS)
HOLD, HOLD_AUTHORS = "hold_the_end", "hold_the_end" + AUTHORS_SUFFIX
# metric column -> (axis title, y limits or None)
METRICS = {"episode_reward": ("episode reward", None),
           HOLD: ("hold the end, paper-text rule", (-0.02, 1.02)),
           HOLD_AUTHORS: ("hold the end, authors' rule", (-0.02, 1.02)),
           "time_at_end": ("time at end [control steps]", None),
           "how_far": ("how far: particles from the end (0 = last)", None)}
CURVE_COLUMNS = (*OUTCOMES, *OUTCOMES_AUTHORS, "episode_reward", "time_at_end", "how_far", "episodes", "eval_seed")
SMOOTHING_WINDOW = 5  # evaluations in the trailing mean of each seed's curve
FINAL_EVALUATIONS = 5  # evaluations in the last-5 mean
MIN_SEEDS_FOR_BAND = 3  # a 95% CI band over fewer seeds is too wide to draw (t = 12.7 for 2)
HOLDS_LEVEL_RATIO = 0.9  # last-5 mean / best smoothed mean at or above this: "holds its level"
SMOOTHING_TEXT = f"each seed smoothed by a trailing mean of {SMOOTHING_WINDOW} evaluations"
# seed-independent config keys: seeds of one configuration may differ in these without a warning
IGNORED_CONFIG_KEYS = ("seed", "train.num_threads", "train.progress", "train.total_steps", "train.eval_without")
# two-sided 95% Student t quantiles t(0.975, df) for df = 1..30; the normal 1.96 beyond
T_975 = (12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145,
         2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048,
         2.045, 2.042)
OUTCOME_COLORS = {"hold_the_end": "tab:green", "stop_before": "tab:orange", "reach_end_but_drop": "tab:blue",
                  "drop_before": "tab:red"}
CONFIG_COLORS = {"T": "tab:blue", "K": "tab:orange", "V": "tab:green", "All": "black", "T+K": "tab:purple",
                 "V+K": "tab:brown", "T+V": "tab:pink"}
COMPARE_COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink",
                  "tab:gray", "tab:olive", "tab:cyan")
OTHER_COLORS = ("tab:cyan", "tab:olive", "tab:gray", "tab:red", "tab:blue", "tab:orange", "tab:green")
SEED_LINE = {"linewidth": 0.7, "alpha": 0.35}
MEAN_LINEWIDTH = 2.2
BAND_ALPHA = 0.18


class ReportError(ValueError):
    """Bad input: reported as one line on stderr, exit status 2."""


# ---------------------------------------------------------------------------------------------- data


@dataclass
class Curves:
    """One configuration's evaluations for one tested input set, over its seeds.

    steps: (K+1,) evaluation steps of the common step prefix; values: column -> (seeds, K+1) array
    (NaN where a run's eval.csv lacks the column); per seed: its id, whether it finished, its
    held-out test JSON (None when unfinished or missing); total_steps: the configured run length."""

    steps: np.ndarray
    values: dict[str, np.ndarray]
    seed_ids: tuple[int, ...] = ()
    finished: tuple[bool, ...] = ()
    tests: tuple[Optional[dict[str, Any]], ...] = ()
    total_steps: int = 0

    @property
    def seeds(self) -> int:
        return next(iter(self.values.values())).shape[0]

    @property
    def finished_seeds(self) -> int:
        return sum(self.finished)


Runs = dict[str, dict[str, Curves]]  # label -> tested_without ('' = all inputs) -> Curves


@dataclass
class RunDir:
    """One run directory as read from disk."""

    path: Path
    config: RunConfig
    finished: bool
    rows: dict[str, list[dict[str, float]]]  # tested_without -> numeric eval.csv rows
    tests: dict[str, Optional[dict[str, Any]]] = field(default_factory=dict)  # tested_without -> test JSON


def _number(text: Optional[str]) -> float:
    """A CSV cell as float; NaN for a missing column, an empty cell or text."""
    try:
        return float(text) if text not in (None, "") else math.nan
    except ValueError:
        return math.nan


def read_eval_csv(path: Path) -> dict[str, list[dict[str, float]]]:
    """eval.csv -> tested_without -> rows of floats (step and CURVE_COLUMNS; missing columns NaN)."""
    groups: dict[str, list[dict[str, float]]] = {}
    with path.open(newline="") as f:
        for row in csv.DictReader(f):
            step = _number(row.get("step"))
            if math.isnan(step):
                continue
            values = {"step": step, **{column: _number(row.get(column)) for column in CURVE_COLUMNS}}
            groups.setdefault(row.get("tested_without") or "", []).append(values)
    return groups


def read_test_json(path: Path, warnings: list[str]) -> Optional[dict[str, Any]]:
    """A held-out test JSON, or None when absent or unreadable (a warning then)."""
    if not path.exists():
        return None
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as error:
        warnings.append(f"{path}: unreadable ({error}); its held-out test is left out")
        return None
    return data if isinstance(data, dict) else None


def read_run(config_path: Path, warnings: list[str]) -> Optional[RunDir]:
    """The run in config_path's directory, or None (with a warning) when it cannot be read."""
    directory = config_path.parent
    if not (directory / EVAL_FILE).exists():
        return None
    try:
        config = load_config(config_path)
        rows = read_eval_csv(directory / EVAL_FILE)
    except (ConfigError, OSError, ValueError, TypeError) as error:
        warnings.append(f"{directory}: skipped, cannot be read ({str(error).splitlines()[0]})")
        return None
    finished = (directory / DONE_FILE).exists()
    tests = {without: read_test_json(directory / test_file(without), warnings) if finished else None
             for without in rows}
    return RunDir(directory, config, finished, rows, tests)


def read_runs(results: Path, warnings: Optional[list[str]] = None) -> list[RunDir]:
    """Every readable run directory below `results` (sorted by path)."""
    warnings = [] if warnings is None else warnings
    runs = [read_run(path, warnings) for path in sorted(results.rglob(CONFIG_FILE))]
    return [run for run in runs if run is not None and any(run.rows.values())]


def _flat(data: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    flat = {}
    for key, value in data.items():
        if isinstance(value, dict) and value:
            flat.update(_flat(value, f"{prefix}{key}."))
        else:
            flat[prefix + key] = value
    return flat


def check_seeds(label: str, runs: Sequence[RunDir], warnings: list[str]) -> None:
    """ReportError when two runs of `label` share a seed; a warning when their configs differ."""
    by_seed: dict[int, list[Path]] = {}
    for run in runs:
        by_seed.setdefault(run.config.seed, []).append(run.path)
    for seed, paths in by_seed.items():
        if len(paths) > 1:
            raise ReportError(f"label {label!r} seed {seed} is in {len(paths)} run directories "
                              f"({', '.join(map(str, paths))}): two settings mixed? compare them with --compare NAME=DIR")
    flats = [_flat(run.config.to_dict()) for run in runs]
    differing = sorted(key for key in set().union(*flats) if key not in IGNORED_CONFIG_KEYS
                       and len({repr(f.get(key)) for f in flats}) > 1)
    if differing:
        warnings.append(f"the seeds of {label!r} differ in {', '.join(differing)}")


def common_prefix(step_lists: Sequence[Sequence[float]]) -> int:
    """Length of the longest evaluation-step prefix that every seed has, with equal steps."""
    length = 0
    for column in zip(*step_lists):
        if len(set(column)) != 1:
            break
        length += 1
    return length


def group_curves(runs: Sequence[RunDir], without: str) -> Optional[Curves]:
    """The seeds of one configuration's `without` rows as Curves (None without a common evaluation)."""
    runs = sorted((run for run in runs if run.rows.get(without)), key=lambda run: run.config.seed)
    if not runs:
        return None
    length = common_prefix([[row["step"] for row in run.rows[without]] for run in runs])
    if length == 0:
        return None
    steps = np.array([int(row["step"]) for row in runs[0].rows[without][:length]])
    values = {column: np.array([[row[column] for row in run.rows[without][:length]] for run in runs])
              for column in CURVE_COLUMNS}
    return Curves(steps, values, tuple(run.config.seed for run in runs), tuple(run.finished for run in runs),
                  tuple(run.tests.get(without) for run in runs), max(run.config.train.total_steps for run in runs))


def fresh_episodes(curves: Curves) -> bool:
    """Whether every seed's evaluations drew different episodes (distinct eval_seed per evaluation)."""
    seeds = curves.values["eval_seed"]
    return not np.isnan(seeds).any() and all(len(set(row)) == len(row) for row in seeds.tolist())


def load_runs(results: Path, warnings: Optional[list[str]] = None) -> Runs:
    """label -> tested_without ('' = all inputs) -> Curves, over every run directory below `results`.
    Appends data problems to `warnings`; ReportError for a label+seed present twice."""
    warnings = [] if warnings is None else warnings
    by_label: dict[str, list[RunDir]] = {}
    for run in read_runs(results, warnings):
        by_label.setdefault(run.config.name, []).append(run)
    grouped: Runs = {}
    for label, label_runs in by_label.items():
        check_seeds(label, label_runs, warnings)
        for without in sorted({w for run in label_runs for w in run.rows}):
            curves = group_curves(label_runs, without)
            if curves is not None:
                grouped.setdefault(label, {})[without] = curves
        if "" in grouped.get(label, {}) and not fresh_episodes(grouped[label][""]):
            warnings.append(f"the evaluations of {label!r} repeat the same episodes (eval.csv without eval_seed, "
                            "from before fresh evaluation episodes): its best mean is selected on them")
    return grouped


def load_results_dir(results: Path, warnings: list[str]) -> Runs:
    """load_runs with the input checks of the command line (ReportError: missing, no runs)."""
    if not results.is_dir():
        raise ReportError(f"{results}: no such directory")
    runs = load_runs(results, warnings)
    if not runs:
        raise ReportError(f"no run directories (config.yaml + eval.csv with evaluations) under {results}")
    return runs


# ---------------------------------------------------------------------------------------- statistics


class Stat(NamedTuple):
    """Mean over n samples and its 95% CI half-width (NaN when n < 2; mean NaN when unknown)."""

    mean: float
    ci: float
    n: int


def smooth(series: np.ndarray, window: int = SMOOTHING_WINDOW) -> np.ndarray:
    """Trailing moving average along the last axis (shorter windows at the start)."""
    cumulative = np.cumsum(series, axis=-1)
    out = cumulative.copy()
    out[..., window:] = cumulative[..., window:] - cumulative[..., :-window]
    counts = np.minimum(np.arange(1, series.shape[-1] + 1), window)
    return out / counts


def t_quantile(n: int) -> float:
    """t(0.975, n - 1): the 95% two-sided Student t quantile for the mean of n >= 2 samples."""
    return T_975[n - 2] if n - 1 <= len(T_975) else 1.96


def mean_and_ci(samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean over axis 0 and the 95% confidence half-width of that mean (0 for a single sample)."""
    n = samples.shape[0]
    mean = samples.mean(axis=0)
    if n < 2:
        return mean, np.zeros_like(mean)
    return mean, t_quantile(n) * samples.std(axis=0, ddof=1) / math.sqrt(n)


def stat_of(samples: Sequence[float]) -> Stat:
    """Stat of 1-D samples (NaN mean if any sample is NaN or there are none)."""
    values = np.asarray(samples, dtype=float)
    n = values.size
    if n == 0 or np.isnan(values).any():
        return Stat(math.nan, math.nan, n)
    mean, ci = mean_and_ci(values)
    return Stat(float(mean), float(ci) if n >= 2 else math.nan, n)


def band_allowed(seeds: int) -> bool:
    """Whether a figure draws the 95% CI band of a mean over `seeds` seeds."""
    return seeds >= MIN_SEEDS_FOR_BAND


def best_smoothed(curves: Curves, column: str = HOLD) -> tuple[Stat, Optional[int]]:
    """B = max_k of the seed mean of smoothed `column`, its CI at k*, and the step k* (None if unknown)."""
    smoothed = smooth(curves.values[column])
    mean = smoothed.mean(axis=0)
    if np.isnan(mean).any():
        return Stat(math.nan, math.nan, curves.seeds), None
    best = int(np.argmax(mean))
    return stat_of(smoothed[:, best]), int(curves.steps[best])


def last_mean(curves: Curves, column: str = HOLD, evaluations: int = FINAL_EVALUATIONS) -> Stat:
    """L: per seed the mean of its last `evaluations` raw evaluations, then the Stat over seeds."""
    return stat_of(curves.values[column][:, -evaluations:].mean(axis=1))


def level_ratio(last: Stat, best: Stat) -> float:
    """L / B (NaN when either is unknown or B = 0)."""
    if math.isnan(last.mean) or math.isnan(best.mean) or best.mean <= 0:
        return math.nan
    return last.mean / best.mean


def test_value(test: dict[str, Any], authors: bool = False) -> float:
    """hold the end of a held-out test JSON under the paper-text rule (top level) or the authors' rule."""
    source = test.get("authors_code") if authors else test
    value = source.get(HOLD) if isinstance(source, dict) else None
    return float(value) if isinstance(value, (int, float)) else math.nan


def held_out_test(curves: Curves, authors: bool = False) -> Stat:
    """Mean over the finished seeds with a held-out test JSON (NaN if any of them lacks the rule)."""
    return stat_of([test_value(test, authors) for test in curves.tests if test is not None])


def test_episodes(curves: Curves) -> set[int]:
    """Episode counts of the configuration's held-out tests."""
    return {int(t["episodes"]) for t in curves.tests if t is not None and isinstance(t.get("episodes"), int)}


@dataclass
class Summary:
    """The table numbers of one configuration and tested input set."""

    name: str
    seeds: int
    finished: int
    last_step: int
    total_steps: int
    best: Stat
    best_step: Optional[int]
    best_authors: Stat
    best_authors_step: Optional[int]
    last: Stat
    ratio: float
    test: Stat
    test_authors: Stat


def summarize(name: str, curves: Curves) -> Summary:
    best, best_step = best_smoothed(curves, HOLD)
    best_authors, best_authors_step = best_smoothed(curves, HOLD_AUTHORS)
    last = last_mean(curves, HOLD)
    return Summary(name, curves.seeds, curves.finished_seeds, int(curves.steps[-1]), curves.total_steps,
                   best, best_step, best_authors, best_authors_step, last, level_ratio(last, best),
                   held_out_test(curves), held_out_test(curves, authors=True))


# ------------------------------------------------------------------------------------------- tables


def format_stat(stat: Stat) -> str:
    """'45% ± 12%' (n >= 2), '45% (1 seed)', or 'n/a'."""
    if math.isnan(stat.mean):
        return "n/a"
    if stat.n < 2:
        return f"{stat.mean:.0%} (1 seed)"
    return f"{stat.mean:.0%} ± {stat.ci:.0%}"


def format_best(stat: Stat, step: Optional[int]) -> str:
    return "n/a" if step is None or math.isnan(stat.mean) else f"{format_stat(stat)} at {step:,}"


def holds_level(ratio: float) -> bool:
    """Whether last-5 mean / best smoothed mean reaches HOLDS_LEVEL_RATIO (1e-9: float rounding)."""
    return ratio >= HOLDS_LEVEL_RATIO - 1e-9


def format_ratio(ratio: float) -> str:
    """'0.93 (holds)' / '0.89 (sags)': two decimals rounded down, so the text agrees with the verdict."""
    if math.isnan(ratio):
        return "n/a"
    return f"{math.floor((ratio + 1e-9) * 100) / 100:.2f} ({'holds' if holds_level(ratio) else 'sags'})"


def format_test(stat: Stat, finished: int) -> str:
    text = format_stat(stat)
    if stat.n and stat.n < finished:
        text += f" ({stat.n} of {finished} finished seeds)"
    return text


def format_seeds(summary: Summary) -> str:
    text = f"{summary.finished}/{summary.seeds} × {summary.last_step:,}"
    return text + (f" (of {summary.total_steps:,})" if summary.last_step < summary.total_steps else "")


def row_name(label: str, without: str) -> str:
    return label + (f", tested without {without}" if without else "")


def ordered(runs: Runs) -> list[tuple[str, str, Curves]]:
    """(label, tested_without, Curves) in table order: singles, pairs, then the others by name."""
    labels = [label for label in TABLE_ORDER if label in runs] + sorted(set(runs) - set(TABLE_ORDER))
    return [(label, without, curves) for label in labels for without, curves in sorted(runs[label].items())]


SUMMARY_HEADER = ("seeds (finished/total) × steps", "best smoothed mean hold the end, paper rule (at step)",
                  "same, authors' rule", "last-5 mean, paper rule", "last-5 / best",
                  "held-out test, paper rule", "held-out test, authors' rule")


def summary_cells(summary: Summary) -> list[str]:
    return [format_seeds(summary), format_best(summary.best, summary.best_step),
            format_best(summary.best_authors, summary.best_authors_step), format_stat(summary.last),
            format_ratio(summary.ratio), format_test(summary.test, summary.finished),
            format_test(summary.test_authors, summary.finished)]


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)] + ["| " + " | ".join(row) + " |"
                                                                            for row in rows]


def definitions(runs_list: Sequence[Runs]) -> str:
    """The note under a table: exact definitions, with the episode counts found in the data."""
    curves = [c for runs in runs_list for by_without in runs.values() for c in by_without.values()]
    tests = sorted(set().union(*(test_episodes(c) for c in curves))) if curves else []
    episodes = sorted({int(e) for c in curves for e in c.values["episodes"].ravel() if not math.isnan(e)})
    episodes_text = "/".join(map(str, episodes)) if episodes else "`train.eval_episodes`"
    tests_text = "/".join(map(str, tests)) if tests else "`train.test_episodes`"
    return "\n".join([
        "Definitions. Every `train.eval_every` steps each seed's deterministic policy is evaluated on "
        f"{episodes_text} fresh episodes (seeds never reused within or across runs; see the warnings otherwise). "
        f"*Best smoothed mean*: {SMOOTHING_TEXT} (fewer at the start), averaged over seeds, maximised over the "
        "evaluation steps (the step is shown): the paper's \"best mean\". "
        "*± x%*: 95% confidence half-width of the mean over seeds (Student t, n - 1 degrees of freedom), "
        "written for >= 2 seeds only; \"(1 seed)\" marks a single seed's value. "
        f"*Last-5 mean*: per seed the mean of its last {FINAL_EVALUATIONS} (unsmoothed) evaluations, averaged over "
        f"seeds; *last-5 / best* (printed rounded down) >= {HOLDS_LEVEL_RATIO}: training holds its level, else it sags. "
        "*Seeds*: finished (done.json) / all seeds; unfinished seeds count up to the last step every seed has "
        "reached (steps column; \"of N\": the configured length). "
        f"*Held-out test*: each finished seed's best evaluation policy (highest hold the end, then reward) tested "
        f"once on {tests_text} episodes whose seeds no evaluation used (test.json; test_without_X.json for the "
        "tested-without rows), averaged over finished seeds.",
        "",
        "- *Paper-text rule*: the episode reaches the horizon holding any of the last 10 particles.",
        "- *Authors' rule* (their code): on the last step their narrower held set is non-empty and its mean "
        "particle index is within 5 of the last particle.",
        "- *n/a*: not in the data (eval.csv written before the authors' rule existed, no finished seed with a "
        "held-out test, or a best of 0)."])


def results_table(runs: Runs, warnings: Sequence[str] = ()) -> str:
    """results.md: one row per configuration and tested input set, the definitions, any warnings."""
    rows = []
    for label, without, curves in ordered(runs):
        paper = PAPER_HOLD_THE_END.get(label) if not without else None
        rows.append([row_name(label, without), *summary_cells(summarize(row_name(label, without), curves)),
                     "—" if paper is None else f"{paper:.0%}"])
    lines = markdown_table(["configuration", *SUMMARY_HEADER, "paper (best mean)"], rows)
    text = "\n".join(lines) + "\n\n" + definitions([runs]) + "\n- *paper*: best mean hold the end in the paper.\n"
    if warnings:
        text += "\nWarnings:\n" + "".join(f"- {w}\n" for w in warnings)
    return text


def compare_table(named: Sequence[tuple[str, Runs]], warnings: Sequence[str] = ()) -> str:
    """compare.md: one row per configuration (and tested input set) and setting NAME."""
    keys: list[tuple[str, str]] = []
    for _, runs in named:
        keys += [(label, without) for label, without, _ in ordered(runs) if (label, without) not in keys]
    order = {label: i for i, label in enumerate(TABLE_ORDER)}
    keys.sort(key=lambda key: (order.get(key[0], len(order)), key[0], key[1]))
    rows = []
    for label, without in keys:
        for name, runs in named:
            curves = runs.get(label, {}).get(without)
            cells = summary_cells(summarize(name, curves)) if curves is not None else ["no runs"] + [""] * 6
            rows.append([row_name(label, without), name, *cells])
    text = "\n".join(markdown_table(["configuration", "setting", *SUMMARY_HEADER], rows))
    text += ("\n\n" + definitions([runs for _, runs in named])
             + "\n- *setting*: the NAME of a results directory given as --compare NAME=DIR.\n")
    if warnings:
        text += "\nWarnings:\n" + "".join(f"- {w}\n" for w in warnings)
    return text


# ------------------------------------------------------------------------------------------ figures


def config_color(label: str, index: int = 0) -> str:
    return CONFIG_COLORS.get(label, OTHER_COLORS[index % len(OTHER_COLORS)])


def draw_curve(ax, steps: np.ndarray, samples: np.ndarray, color: str, label: Optional[str] = None,
               seed_lines: bool = True, linestyle: str = "-", linewidth: float = MEAN_LINEWIDTH,
               band: bool = True) -> bool:
    """Each seed smoothed (thin lines if seed_lines), their mean (bold), the 95% CI band if `band`
    and band_allowed(seeds). Returns whether a band was drawn; draws nothing for NaN data."""
    smoothed = smooth(samples)
    if np.isnan(smoothed).any():
        return False
    if seed_lines and samples.shape[0] > 1:  # one seed: its line is the mean
        for seed_curve in smoothed:
            ax.plot(steps, seed_curve, color=color, linestyle=linestyle, **SEED_LINE)
    mean, ci = mean_and_ci(smoothed)
    ax.plot(steps, mean, color=color, linestyle=linestyle, linewidth=linewidth, label=label)
    if band and band_allowed(samples.shape[0]):
        ax.fill_between(steps, mean - ci, mean + ci, color=color, alpha=BAND_ALPHA, linewidth=0)
        return True
    return False


def seeds_text(curves: Curves) -> str:
    """'5 seeds' / '1 seed', with the finished count when not all are finished."""
    text = f"{curves.seeds} seed{'s' if curves.seeds != 1 else ''}"
    return text if curves.finished_seeds == curves.seeds else f"{text}, {curves.finished_seeds} finished"


def _step_axis(ax) -> None:
    ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{x / 1000:g}k"))
    ax.set_xlabel("training step")
    ax.grid(alpha=0.3, linewidth=0.5)


def style_handles(band_drawn: bool, seed_lines: bool = True) -> list:
    """Legend entries of the line styles: one seed (if drawn), the mean, the band (if drawn)."""
    handles = [Line2D([], [], color="gray", **SEED_LINE, label="one seed")] if seed_lines else []
    handles.append(Line2D([], [], color="gray", linewidth=MEAN_LINEWIDTH, label="mean over seeds"))
    if band_drawn:
        handles.append(Patch(color="gray", alpha=BAND_ALPHA * 2, label=f"95% CI of the mean (>= {MIN_SEEDS_FOR_BAND} seeds)"))
    return handles


def figure_labels(runs: Runs, labels: Sequence[str]) -> list[str]:
    return [label for label in labels if "" in runs.get(label, {})]


def outcome_figure(runs: Runs, labels: Sequence[str]) -> Optional[Figure]:
    """One panel per configuration in `labels` with all-input runs: the four outcome fractions
    (mean over seeds; solid paper-text rule, dashed authors' rule), each seed's hold the end (paper
    rule) as a thin line and its CI band for >= 3 seeds. None when no label has runs."""
    present = figure_labels(runs, labels)
    if not present:
        return None
    columns = min(len(present), 4)
    rows = math.ceil(len(present) / columns)
    fig, axes = plt.subplots(rows, columns, figsize=(max(3.9 * columns, 7.5), 3.3 * rows + 1.2), sharey=True,
                             squeeze=False, layout="constrained")
    band_drawn, authors_drawn = False, False
    for ax, label in zip(axes.flat, present):
        curves = runs[label][""]
        for outcome in OUTCOMES:
            hold = outcome == HOLD
            width = MEAN_LINEWIDTH if hold else 1.4
            band_drawn |= draw_curve(ax, curves.steps, curves.values[outcome], OUTCOME_COLORS[outcome],
                                     seed_lines=hold, band=hold, linewidth=width)
            authors = curves.values[outcome + AUTHORS_SUFFIX]
            if not np.isnan(authors).any():
                authors_drawn = True
                draw_curve(ax, curves.steps, authors, OUTCOME_COLORS[outcome], seed_lines=False, band=False,
                           linestyle="--", linewidth=width)
        ax.set_title(f"{label} ({seeds_text(curves)})")
        ax.set_ylim(-0.02, 1.02)
        _step_axis(ax)
    for ax in axes.flat[len(present):]:
        ax.axis("off")
    for ax in axes[:, 0]:
        ax.set_ylabel("fraction of evaluation episodes")
    handles = [Line2D([], [], color=OUTCOME_COLORS[o], linewidth=MEAN_LINEWIDTH, label=o.replace("_", " "))
               for o in OUTCOMES]
    handles += [Line2D([], [], color="black", linewidth=1.4, label="paper-text rule (solid)")]
    handles += [Line2D([], [], color="black", linewidth=1.4, linestyle="--",
                       label="authors' rule (dashed)" if authors_drawn else "authors' rule: n/a in these eval.csv")]
    if any(runs[label][""].seeds > 1 for label in present):
        handles.append(Line2D([], [], color=OUTCOME_COLORS[HOLD], **SEED_LINE,
                              label="one seed, hold the end (paper rule)"))
    if band_drawn:
        handles.append(Patch(color=OUTCOME_COLORS[HOLD], alpha=BAND_ALPHA * 2,
                             label=f"95% CI of the mean (>= {MIN_SEEDS_FOR_BAND} seeds)"))
    fig.legend(handles=handles, loc="outside lower center", ncol=4, fontsize=8, frameon=False)
    fig.suptitle(f"Outcomes over training: mean over seeds\n({SMOOTHING_TEXT})", fontsize=10)
    return fig


def metrics_figure(runs: Runs, labels: Sequence[str]) -> Optional[Figure]:
    """Panels per metric (METRICS); per configuration in `labels`: a thin line per seed, the bold
    mean, the CI band for >= 3 seeds. None when no label has runs."""
    present = figure_labels(runs, labels)
    if not present:
        return None
    fig, axes = plt.subplots(2, 3, figsize=(13, 7), layout="constrained")
    band_drawn = False
    for ax, (metric, (title, limits)) in zip(axes.flat, METRICS.items()):
        drawn = 0
        for i, label in enumerate(present):
            curves = runs[label][""]
            if np.isnan(curves.values[metric]).any():
                continue
            band_drawn |= draw_curve(ax, curves.steps, curves.values[metric], config_color(label, i))
            drawn += 1
        if drawn == 0:
            ax.text(0.5, 0.5, "n/a: no such column in these eval.csv", ha="center", va="center",
                    transform=ax.transAxes, fontsize=9)
        counts = {runs[label][""].seeds for label in present}
        ax.set_title(f"{title}\n({_seed_counts(counts)})", fontsize=10)
        if limits:
            ax.set_ylim(*limits)
        _step_axis(ax)
    legend_ax = axes.flat[-1]
    legend_ax.axis("off")
    handles = [Line2D([], [], color=config_color(label, i), linewidth=MEAN_LINEWIDTH,
                      label=f"{label} ({seeds_text(runs[label][''])})") for i, label in enumerate(present)]
    seed_lines = any(runs[label][""].seeds > 1 for label in present)
    legend_ax.legend(handles=handles + style_handles(band_drawn, seed_lines), loc="center", fontsize=9, frameon=False,
                     title=f"{SMOOTHING_TEXT.capitalize()}", title_fontsize=9)
    fig.suptitle(f"Evaluation metrics over training ({SMOOTHING_TEXT})", fontsize=11)
    return fig


def _seed_counts(counts: set[int]) -> str:
    if len(counts) == 1:
        n = counts.pop()
        return f"{n} seed{'s' if n != 1 else ''} per configuration"
    return f"{min(counts)}-{max(counts)} seeds per configuration, see legend"


def final_values(curves: Curves, metric: str) -> np.ndarray:
    """Per seed: the mean of the last FINAL_EVALUATIONS evaluations."""
    return curves.values[metric][:, -FINAL_EVALUATIONS:].mean(axis=1)


def draw_bars(ax, names: Sequence[str], samples: Sequence[np.ndarray], colors: Sequence[str], ylabel: str) -> None:
    """Bar = mean over seeds, dots = the seeds, error bar = 95% CI for >= 3 seeds only."""
    for i, (values, color) in enumerate(zip(samples, colors)):
        mean, ci = mean_and_ci(values)
        ax.bar(i, mean, color=color, alpha=0.45, width=0.65,
               yerr=ci if band_allowed(len(values)) else None, capsize=4)
        jitter = np.linspace(-0.15, 0.15, len(values)) if len(values) > 1 else np.zeros(1)
        ax.plot(i + jitter, values, "o", color=color, markersize=3.5, markeredgecolor="black", markeredgewidth=0.4)
    ax.set_xticks(range(len(names)), [f"{n}\n({len(s)} seed{'s' if len(s) != 1 else ''})"
                                      for n, s in zip(names, samples)], fontsize=8)
    ax.set_ylabel(ylabel)
    ax.grid(axis="y", alpha=0.3, linewidth=0.5)


BAR_NOTE = (f"dots: each seed's mean of its last {FINAL_EVALUATIONS} evaluations; bar: their mean;\n"
            f"error bar: 95% CI of the mean (>= {MIN_SEEDS_FOR_BAND} seeds only)")


def ablation_figure(runs: Runs) -> Optional[Figure]:
    """All tested with all inputs / without T / without V (bars), and reward over training of All,
    All tested without X and the agents trained without X. None without ablation evaluations."""
    all_runs = runs.get("All", {})
    tested = [w for w in ("", "T", "V") if w in all_runs]
    if "" not in all_runs or len(tested) < 2:
        return None
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2), layout="constrained")
    names = ["All" if w == "" else f"All, tested\nwithout {w}" for w in tested]
    draw_bars(axes[0], names, [final_values(all_runs[w], "episode_reward") for w in tested],
              ["black", "tab:blue", "tab:red"][:len(tested)], "final episode reward")
    axes[0].set_title(BAR_NOTE, fontsize=8)
    band_drawn = False
    for ax, removed, trained_without in ((axes[1], "T", "V+K"), (axes[2], "V", "T+K")):
        entries = [("All", all_runs[""], "black")]
        if removed in all_runs:
            entries.append((f"All, tested without {removed}", all_runs[removed], "tab:blue"))
        if "" in runs.get(trained_without, {}):
            entries.append((f"trained without {removed} ({trained_without})", runs[trained_without][""], "tab:red"))
        for name, curves, color in entries:
            band_drawn |= draw_curve(ax, curves.steps, curves.values["episode_reward"], color,
                                     label=f"{name} ({seeds_text(curves)})")
        ax.set_title(f"without {removed}", fontsize=10)
        ax.set_ylabel("episode reward")
        _step_axis(ax)
        ax.legend(handles=ax.get_legend_handles_labels()[0]
                  + style_handles(band_drawn, any(c.seeds > 1 for _, c, _ in entries)), fontsize=7)
    fig.suptitle(f"Ablation: episode reward (curves: {SMOOTHING_TEXT})", fontsize=11)
    return fig


def sensitivity_figure(runs: Runs) -> Optional[Figure]:
    """Final episode reward per tactile-noise level, with K and without K. None without noise runs."""
    if not any(sensitivity_label(m, n) in runs for m, _ in SENSITIVITY_PAIRS for n in TACTILE_NOISE_LEVELS):
        return None
    fig, axes = plt.subplots(1, len(SENSITIVITY_PAIRS), figsize=(12, 4.2), sharey=True, layout="constrained")
    for ax, (modalities, no_tactile) in zip(axes, SENSITIVITY_PAIRS):
        entries = [("noise: none", modalities)] + [(f"noise: {n}", sensitivity_label(modalities, n))
                                                   for n in TACTILE_NOISE_LEVELS]
        entries.append(("no tactile", no_tactile))
        entries = [(name, label) for name, label in entries if "" in runs.get(label, {})]
        draw_bars(ax, [f"{name}\n{label}" for name, label in entries],
                  [final_values(runs[label][""], "episode_reward") for _, label in entries],
                  [f"C{i}" for i in range(len(entries))], "final episode reward")
        ax.set_title(f"{modalities} ({'with K' if 'K' in modalities or modalities == 'All' else 'without K'})",
                     fontsize=10)
    fig.suptitle(f"Tactile sensitivity: final episode reward\n{BAR_NOTE}", fontsize=10)
    return fig


def compare_figure(named: Sequence[tuple[str, Runs]]) -> Optional[Figure]:
    """Hold the end (paper rule) per configuration: one bold mean line per setting NAME, a thin
    line per seed, the CI band for >= 3 seeds."""
    labels: list[str] = []
    for _, runs in named:
        labels += [label for label, without, _ in ordered(runs) if without == "" and label not in labels]
    if not labels:
        return None
    columns = min(len(labels), 4)
    rows = math.ceil(len(labels) / columns)
    fig, axes = plt.subplots(rows, columns, figsize=(max(4.2 * columns, 7.5), 3.4 * rows + 1.0), sharey=True,
                             squeeze=False, layout="constrained")
    colors = {name: COMPARE_COLORS[i % len(COMPARE_COLORS)] for i, (name, _) in enumerate(named)}
    band_drawn = False
    for ax, label in zip(axes.flat, labels):
        counts = []
        for name, runs in named:
            curves = runs.get(label, {}).get("")
            if curves is None:
                counts.append(f"{name} 0")
                continue
            band_drawn |= draw_curve(ax, curves.steps, curves.values[HOLD], colors[name])
            counts.append(f"{name} {curves.seeds}")
        ax.set_title(f"{label}\nseeds: {', '.join(counts)}", fontsize=9)
        ax.set_ylim(-0.02, 1.02)
        _step_axis(ax)
    for ax in axes.flat[len(labels):]:
        ax.axis("off")
    for ax in axes[:, 0]:
        ax.set_ylabel("hold the end (paper rule)")
    handles = [Line2D([], [], color=colors[name], linewidth=MEAN_LINEWIDTH, label=name) for name, _ in named]
    seed_lines = any(by_without[""].seeds > 1 for _, runs in named for by_without in runs.values() if "" in by_without)
    fig.legend(handles=handles + style_handles(band_drawn, seed_lines), loc="outside lower center",
               ncol=min(len(handles) + 3, 5), fontsize=8, frameon=False)
    fig.suptitle(f"Hold the end per setting: mean over seeds\n({SMOOTHING_TEXT})", fontsize=10)
    return fig


def save_figure(fig: Figure, path: Path) -> Path:
    fig.savefig(path, dpi=130, bbox_inches="tight")  # "tight": nothing outside the axes is cut off
    plt.close(fig)
    return path


# ------------------------------------------------------------------------------------------- report


def planned_figures(runs: Runs) -> list[tuple[str, Any, str]]:
    """(file name, drawing function, reason when it draws nothing) of dlo-report RESULTS."""
    has_pairs = bool(figure_labels(runs, PAIRS))
    pairs = (*PAIRS, "All") if has_pairs else ()  # All is the pairs' reference only when pairs exist
    no_single, no_pairs = "no runs of T, K, V or All", "no runs of T+K, V+K or T+V"
    return [("outcomes_single.png", lambda: outcome_figure(runs, SINGLE), no_single),
            ("outcomes_pairs.png", lambda: outcome_figure(runs, pairs), no_pairs),
            ("metrics_single.png", lambda: metrics_figure(runs, SINGLE), no_single),
            ("metrics_pairs.png", lambda: metrics_figure(runs, pairs), no_pairs),
            ("ablation.png", lambda: ablation_figure(runs),
             "no All runs evaluated without T or V (dlo-experiments --groups ablation)"),
            ("sensitivity.png", lambda: sensitivity_figure(runs),
             "no tactile-noise runs (dlo-experiments --groups sensitivity)")]


@dataclass
class Written:
    """What a report command wrote and skipped."""

    paths: list[Path] = field(default_factory=list)
    skipped: list[tuple[str, str]] = field(default_factory=list)  # (file name, why)
    warnings: list[str] = field(default_factory=list)
    table: str = ""


def build_report(results: Path, out_dir: Path) -> Written:
    """Write the figures the data allows and results.md into out_dir (ReportError on bad input)."""
    written = Written()
    runs = load_results_dir(results, written.warnings)
    out_dir.mkdir(parents=True, exist_ok=True)
    for name, draw, reason in planned_figures(runs):
        fig = draw()
        if fig is None:
            stale = " (the older file there is left as it is)" if (out_dir / name).exists() else ""
            written.skipped.append((name, reason + stale))
        else:
            written.paths.append(save_figure(fig, out_dir / name))
    written.table = results_table(runs, written.warnings)
    (out_dir / "results.md").write_text(written.table)
    written.paths.append(out_dir / "results.md")
    return written


def parse_named_dir(text: str) -> tuple[str, Path]:
    """'NAME=DIR' -> (NAME, DIR); ReportError when malformed."""
    name, sep, directory = text.partition("=")
    if not sep or not name.strip() or not directory.strip():
        raise ReportError(f"--compare {text!r}: expected NAME=DIR, e.g. running=runs/sag/running")
    return name.strip(), Path(directory.strip())


def build_comparison(specs: Sequence[str], out_dir: Path) -> Written:
    """compare.md and compare.png of results directories given as NAME=DIR (ReportError on bad input)."""
    written = Written()
    pairs = [parse_named_dir(spec) for spec in specs]
    names = [name for name, _ in pairs]
    if len(set(names)) != len(names):
        raise ReportError(f"--compare: each NAME once (got {', '.join(names)})")
    named = []
    for name, directory in pairs:
        warnings: list[str] = []
        named.append((name, load_results_dir(directory, warnings)))
        written.warnings += [f"{name}: {w}" for w in warnings]
    out_dir.mkdir(parents=True, exist_ok=True)
    fig = compare_figure(named)
    if fig is None:
        written.skipped.append(("compare.png", "no all-inputs evaluations"))
    else:
        written.paths.append(save_figure(fig, out_dir / "compare.png"))
    written.table = compare_table(named, written.warnings)
    (out_dir / "compare.md").write_text(written.table)
    written.paths.append(out_dir / "compare.md")
    return written


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, no usage block
        print(f"{self.prog}: error: {message} (see {self.prog} --help)", file=sys.stderr)
        raise SystemExit(2)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="dlo-report", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("results", type=Path, nargs="?", metavar="RESULTS",
                        help="directory holding dlo-train run directories (anywhere below it)")
    parser.add_argument("--out", type=Path, metavar="DIR",
                        help="where to write (default RESULTS/report; required with --compare)")
    parser.add_argument("--compare", nargs="+", metavar="NAME=DIR",
                        help="compare results directories of the same configurations trained under different "
                             "settings: writes compare.md and compare.png instead of the study's report")
    return parser


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exit_:  # --help (0) or a usage error (2), already printed
        return int(exit_.code or 0)
    try:
        if args.compare:
            if args.results is not None:
                raise ReportError("give either RESULTS or --compare NAME=DIR ..., not both")
            if args.out is None:
                raise ReportError("--compare needs --out DIR")
            written = build_comparison(args.compare, args.out)
        elif args.results is None:
            raise ReportError("give RESULTS (a results directory) or --compare NAME=DIR ...")
        else:
            written = build_report(args.results, args.out or args.results / "report")
    except ReportError as error:
        print(f"dlo-report: error: {error}", file=sys.stderr)
        return 2
    for warning in written.warnings:
        print(f"dlo-report: warning: {warning}", file=sys.stderr)
    print(written.table)
    for name, reason in written.skipped:
        print(f"skipped {name}: {reason}")
    print("\n".join(f"wrote {path}" for path in written.paths))
    return 0


if __name__ == "__main__":
    sys.exit(main())
