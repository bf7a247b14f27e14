"""dlo-report's data: every run directory below a results directory read into curves per configuration
and tested input set, and the statistics of the tables and figures (their definitions: the dlo-report
help, `dlo_policy.report`). Reads runs through `dlo_policy.rundir`; no torch, no matplotlib.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple, Optional, Sequence

import numpy as np

from . import rundir
from .config import ConfigError, RunConfig
from .rundir import AUTHORS_SUFFIX, CONFIG_FILE, EVAL_FILE, OUTCOMES, OUTCOMES_AUTHORS


class ReportError(ValueError):
    """Bad input: reported as one line on stderr, exit status 2."""


SINGLE, PAIRS = ("T", "K", "V", "All"), ("T+K", "V+K", "T+V")  # figure groups; All is the pairs' reference
TABLE_ORDER = (*SINGLE, *PAIRS)
HOLD, HOLD_AUTHORS = "hold_the_end", "hold_the_end" + AUTHORS_SUFFIX
CURVE_COLUMNS = (*OUTCOMES, *OUTCOMES_AUTHORS, "episode_reward", "time_at_end", "how_far", "episodes", "eval_seed")
SMOOTHING_WINDOW = 5  # evaluations in the trailing mean of each seed's curve
FINAL_EVALUATIONS = 5  # evaluations in the last-5 mean
HOLDS_LEVEL_RATIO = 0.9  # last-5 mean / best smoothed mean at or above this: "holds its level"
SMOOTHING_TEXT = f"each seed smoothed by a trailing mean of {SMOOTHING_WINDOW} evaluations"
# seed-independent config keys: seeds of one configuration may differ in these without a warning
IGNORED_CONFIG_KEYS = ("seed", "train.num_threads", "train.progress", "train.total_steps", "train.eval_without")
# two-sided 95% Student t quantiles t(0.975, df) for df = 1..30; the normal 1.96 beyond
T_975 = (
    12.706,
    4.303,
    3.182,
    2.776,
    2.571,
    2.447,
    2.365,
    2.306,
    2.262,
    2.228,
    2.201,
    2.179,
    2.160,
    2.145,
    2.131,
    2.120,
    2.110,
    2.101,
    2.093,
    2.086,
    2.080,
    2.074,
    2.069,
    2.064,
    2.060,
    2.056,
    2.052,
    2.048,
    2.045,
    2.042,
)


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


def read_evaluations(run_dir: Path) -> dict[str, list[dict[str, float]]]:
    """The run's eval.csv -> tested_without -> rows of floats (step and CURVE_COLUMNS; missing columns NaN)."""
    groups: dict[str, list[dict[str, float]]] = {}
    for row in rundir.read_eval_rows(run_dir):
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
        config = rundir.read_config(directory)
        rows = read_evaluations(directory)
    except (ConfigError, OSError, ValueError, TypeError) as error:
        warnings.append(f"{directory}: skipped, cannot be read ({str(error).splitlines()[0]})")
        return None
    finished = rundir.is_done(directory)
    tests = {without: read_test_json(directory / rundir.test_file(without), warnings) if finished else None for without in rows}
    return RunDir(directory, config, finished, rows, tests)


def read_runs(results: Path, warnings: Optional[list[str]] = None) -> list[RunDir]:
    """Every readable run directory below `results` (sorted by path), also behind symbolic links (a results
    directory may link another's seeds, as results/fidelity/screen_baseline_15k does)."""
    warnings = [] if warnings is None else warnings
    found = [Path(folder) / CONFIG_FILE for folder, _, files in os.walk(results, followlinks=True) if CONFIG_FILE in files]
    runs = [read_run(path, warnings) for path in sorted(found)]
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
            raise ReportError(
                f"label {label!r} seed {seed} is in {len(paths)} run directories "
                f"({', '.join(map(str, paths))}): two settings mixed? compare them with --compare NAME=DIR"
            )
    flats = [_flat(run.config.to_dict()) for run in runs]
    differing = sorted(
        key for key in set().union(*flats) if key not in IGNORED_CONFIG_KEYS and len({repr(f.get(key)) for f in flats}) > 1
    )
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
    values = {column: np.array([[row[column] for row in run.rows[without][:length]] for run in runs]) for column in CURVE_COLUMNS}
    return Curves(
        steps,
        values,
        tuple(run.config.seed for run in runs),
        tuple(run.finished for run in runs),
        tuple(run.tests.get(without) for run in runs),
        max(run.config.train.total_steps for run in runs),
    )


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
            warnings.append(
                f"the evaluations of {label!r} repeat the same episodes (eval.csv without eval_seed, "
                "from before fresh evaluation episodes): its best mean is selected on them"
            )
    return grouped


def load_results_dir(results: Path, warnings: list[str]) -> Runs:
    """load_runs with the input checks of the command line (ReportError: missing, no runs)."""
    if not results.is_dir():
        raise ReportError(f"{results}: no such directory")
    runs = load_runs(results, warnings)
    if not runs:
        raise ReportError(f"no run directories (config.yaml + eval.csv with evaluations) under {results}")
    return runs


def ordered(runs: Runs) -> list[tuple[str, str, Curves]]:
    """(label, tested_without, Curves) in table order: singles, pairs, then the others by name."""
    labels = [label for label in TABLE_ORDER if label in runs] + sorted(set(runs) - set(TABLE_ORDER))
    return [(label, without, curves) for label in labels for without, curves in sorted(runs[label].items())]


# --------------------------------------------------------------------------------------- statistics


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


def best_smoothed(curves: Curves, column: str = HOLD, window: int = SMOOTHING_WINDOW) -> tuple[Stat, Optional[int]]:
    """B = max_k of the seed mean of smoothed `column`, its CI at k*, and the step k* (None if unknown).
    window=1: the best of the unsmoothed seed-averaged curve."""
    smoothed = smooth(curves.values[column], window)
    mean = smoothed.mean(axis=0)
    if np.isnan(mean).any():
        return Stat(math.nan, math.nan, curves.seeds), None
    best = int(np.argmax(mean))
    return stat_of(smoothed[:, best]), int(curves.steps[best])


def last_mean(curves: Curves, column: str = HOLD, evaluations: int = FINAL_EVALUATIONS) -> Stat:
    """L: per seed the mean of its last `evaluations` raw evaluations, then the Stat over seeds."""
    return stat_of(curves.values[column][:, -evaluations:].mean(axis=1))


def final_values(curves: Curves, metric: str) -> np.ndarray:
    """Per seed: the mean of the last FINAL_EVALUATIONS evaluations."""
    return curves.values[metric][:, -FINAL_EVALUATIONS:].mean(axis=1)


def level_ratio(last: Stat, best: Stat) -> float:
    """L / B (NaN when either is unknown or B = 0)."""
    if math.isnan(last.mean) or math.isnan(best.mean) or best.mean <= 0:
        return math.nan
    return last.mean / best.mean


def holds_level(ratio: float) -> bool:
    """Whether last-5 mean / best smoothed mean reaches HOLDS_LEVEL_RATIO (1e-9: float rounding)."""
    return ratio >= HOLDS_LEVEL_RATIO - 1e-9


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
    last_authors: Stat = Stat(math.nan, math.nan, 0)
    ratio_authors: float = math.nan


def summarize(name: str, curves: Curves) -> Summary:
    best, best_step = best_smoothed(curves, HOLD)
    best_authors, best_authors_step = best_smoothed(curves, HOLD_AUTHORS)
    last = last_mean(curves, HOLD)
    last_authors = last_mean(curves, HOLD_AUTHORS)
    return Summary(
        name,
        curves.seeds,
        curves.finished_seeds,
        int(curves.steps[-1]),
        curves.total_steps,
        best,
        best_step,
        best_authors,
        best_authors_step,
        last,
        level_ratio(last, best),
        held_out_test(curves),
        held_out_test(curves, authors=True),
        last_authors,
        level_ratio(last_authors, best_authors),
    )
