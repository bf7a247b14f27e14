"""Figures and table of the paper's results from run directories: `dlo-report`.

    dlo-report results [--out results/report]

Reads every run directory under RESULTS (config.yaml + eval.csv, see dlo-train), groups seeds by
the run's label, and writes (PNG, matplotlib Agg):
    outcomes_single.png, outcomes_pairs.png   outcome fractions over training per configuration
    metrics_single.png, metrics_pairs.png     reward, hold the end, time at end, how far
    ablation.png                              All tested without T / V vs agents trained without them
    sensitivity.png                           final reward per tactile noise level, with and without K
    results.md                                best mean hold-the-end per configuration vs the paper
Curves: each seed smoothed with a trailing window of 5 evaluations, then mean over seeds with a
95% confidence band (Student t). Bars: per seed the mean of the last 5 evaluations, then the same.
"""
from __future__ import annotations

import argparse
import csv
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

import matplotlib
import numpy as np

matplotlib.use("Agg")  # files only, no display
import matplotlib.pyplot as plt  # noqa: E402

from .config import load_config
from .evaluate import OUTCOMES
from .observation import parse_modalities
from .experiments import SENSITIVITY_PAIRS, TACTILE_NOISE_LEVELS, sensitivity_label
from .train import CONFIG_FILE, EVAL_FILE

PAPER_HOLD_THE_END = {"T": 0.12, "K": 0.11, "V": 0.77, "All": 0.92, "T+K": 0.16, "V+K": 0.89, "T+V": 0.77}
SINGLE, PAIRS = ("T", "K", "V", "All"), ("T+K", "V+K", "T+V", "All")
METRICS = {"episode_reward": "episode reward", "hold_the_end": "hold the end", "time_at_end": "time at end [steps]",
           "how_far": "how far it goes"}
SMOOTHING_WINDOW = 5
FINAL_EVALUATIONS = 5
# two-sided 95% Student t quantiles t(0.975, df) for df = 1..30; the normal 1.96 beyond
T_975 = (12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145,
         2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048,
         2.045, 2.042)


@dataclass
class Curves:
    """One configuration's evaluations for one tested input set: metric -> (seeds, steps) array."""

    steps: np.ndarray
    values: dict[str, np.ndarray]

    @property
    def seeds(self) -> int:
        return next(iter(self.values.values())).shape[0]


def smooth(series: np.ndarray, window: int = SMOOTHING_WINDOW) -> np.ndarray:
    """Trailing moving average along the last axis (shorter windows at the start)."""
    cumulative = np.cumsum(series, axis=-1)
    out = cumulative.copy()
    out[..., window:] = cumulative[..., window:] - cumulative[..., :-window]
    counts = np.minimum(np.arange(1, series.shape[-1] + 1), window)
    return out / counts


def mean_and_ci(samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean over axis 0 and the 95% confidence half-width of that mean (0 for a single sample)."""
    n = samples.shape[0]
    mean = samples.mean(axis=0)
    if n < 2:
        return mean, np.zeros_like(mean)
    t = T_975[n - 2] if n - 1 <= len(T_975) else 1.96
    return mean, t * samples.std(axis=0, ddof=1) / math.sqrt(n)


def load_runs(results: Path) -> dict[str, dict[str, Curves]]:
    """label -> tested_without ('' = all inputs) -> Curves, over every run directory under `results`."""
    rows_by_group: dict[tuple[str, str], list[list[dict[str, str]]]] = {}
    for config_path in sorted(results.rglob(CONFIG_FILE)):
        eval_path = config_path.parent / EVAL_FILE
        if not eval_path.exists():
            continue
        label = load_config(config_path).name
        with eval_path.open(newline="") as f:
            rows = list(csv.DictReader(f))
        for without in sorted({row["tested_without"] for row in rows}):
            rows_by_group.setdefault((label, without), []).append(
                [row for row in rows if row["tested_without"] == without])
    runs: dict[str, dict[str, Curves]] = {}
    for (label, without), seed_rows in rows_by_group.items():
        length = min(len(rows) for rows in seed_rows)  # seeds still running: their common prefix
        if length == 0:
            continue
        steps = np.array([int(row["step"]) for row in seed_rows[0][:length]])
        values = {metric: np.array([[float(row[metric]) for row in rows[:length]] for rows in seed_rows])
                  for metric in (*OUTCOMES, *METRICS)}
        runs.setdefault(label, {})[without] = Curves(steps, values)
    return runs


def _band(ax, steps, samples, label, color=None):
    mean, ci = mean_and_ci(smooth(samples))
    line, = ax.plot(steps, mean, label=label, color=color)
    ax.fill_between(steps, mean - ci, mean + ci, alpha=0.25, color=line.get_color(), linewidth=0)


def outcome_figure(runs: dict[str, dict[str, Curves]], labels: Sequence[str], path: Path) -> bool:
    present = [label for label in labels if "" in runs.get(label, {})]
    if not present:
        return False
    fig, axes = plt.subplots(1, len(present), figsize=(4 * len(present), 3.4), sharey=True, squeeze=False)
    for ax, label in zip(axes[0], present):
        curves = runs[label][""]
        for outcome in OUTCOMES:
            _band(ax, curves.steps, curves.values[outcome], outcome.replace("_", " "))
        ax.set_title(f"{label} ({curves.seeds} seeds)")
        ax.set_xlabel("training step")
        ax.set_ylim(-0.02, 1.02)
    axes[0][0].set_ylabel("fraction of episodes")
    axes[0][-1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def metrics_figure(runs: dict[str, dict[str, Curves]], labels: Sequence[str], path: Path) -> bool:
    present = [label for label in labels if "" in runs.get(label, {})]
    if not present:
        return False
    fig, axes = plt.subplots(1, len(METRICS), figsize=(4 * len(METRICS), 3.4))
    for ax, (metric, title) in zip(axes, METRICS.items()):
        for label in present:
            curves = runs[label][""]
            _band(ax, curves.steps, curves.values[metric], label)
        ax.set_title(title)
        ax.set_xlabel("training step")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def final_values(curves: Curves, metric: str) -> np.ndarray:
    """Per seed: the mean of the last FINAL_EVALUATIONS evaluations."""
    return curves.values[metric][:, -FINAL_EVALUATIONS:].mean(axis=1)


def _bars(ax, names: list[str], samples: list[np.ndarray], ylabel: str) -> None:
    stats = [mean_and_ci(s) for s in samples]
    ax.bar(range(len(names)), [m for m, _ in stats], yerr=[c for _, c in stats], capsize=4,
           color=[f"C{i}" for i in range(len(names))])
    ax.set_xticks(range(len(names)), names, rotation=20, ha="right", fontsize=8)
    ax.set_ylabel(ylabel)


def ablation_figure(runs: dict[str, dict[str, Curves]], path: Path) -> bool:
    all_runs = runs.get("All", {})
    tested = [w for w in ("", "T", "V") if w in all_runs]
    if len(tested) < 2:
        return False
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    names = ["All" if w == "" else f"All, tested without {w}" for w in tested]
    _bars(axes[0], names, [final_values(all_runs[w], "episode_reward") for w in tested], "final episode reward")
    for ax, removed, trained_without in ((axes[1], "T", "V+K"), (axes[2], "V", "T+K")):
        if removed in all_runs:
            _band(ax, all_runs[""].steps, all_runs[""].values["episode_reward"], "All")
            _band(ax, all_runs[removed].steps, all_runs[removed].values["episode_reward"],
                  f"All, tested without {removed}")
        if "" in runs.get(trained_without, {}):
            curves = runs[trained_without][""]
            _band(ax, curves.steps, curves.values["episode_reward"], f"trained without {removed} ({trained_without})")
        ax.set_title(f"without {removed}")
        ax.set_xlabel("training step")
        ax.set_ylabel("episode reward")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def sensitivity_figure(runs: dict[str, dict[str, Curves]], path: Path) -> bool:
    if not any(sensitivity_label(m, n) in runs for m, _ in SENSITIVITY_PAIRS for n in TACTILE_NOISE_LEVELS):
        return False
    fig, axes = plt.subplots(1, len(SENSITIVITY_PAIRS), figsize=(10, 3.6), sharey=True)
    for ax, (modalities, no_tactile) in zip(axes, SENSITIVITY_PAIRS):
        entries = [("none", modalities)] + [(n, sensitivity_label(modalities, n)) for n in TACTILE_NOISE_LEVELS]
        entries.append(("no tactile", no_tactile))
        entries = [(name, label) for name, label in entries if "" in runs.get(label, {})]
        _bars(ax, [f"{name} ({label})" for name, label in entries],
              [final_values(runs[label][""], "episode_reward") for _, label in entries], "final episode reward")
        ax.set_title("with K" if "K" in parse_modalities(modalities) else "without K")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def results_table(runs: dict[str, dict[str, Curves]]) -> str:
    """Markdown: best (over evaluations) seed-mean of the smoothed hold-the-end rate per configuration."""
    order = [*SINGLE, "T+K", "V+K", "T+V"]
    rows = []
    for label in order + sorted(set(runs) - set(order)):
        for without, curves in sorted(runs.get(label, {}).items()):
            mean, ci = mean_and_ci(smooth(curves.values["hold_the_end"]))
            best = int(np.argmax(mean))
            name = label + (f", tested without {without}" if without else "")
            paper = PAPER_HOLD_THE_END.get(label) if not without else None
            rows.append(f"| {name} | {curves.seeds} | {mean[best]:.0%} ± {ci[best]:.0%} | {curves.steps[best]} | "
                        f"{curves.steps[-1]} | {'' if paper is None else f'{paper:.0%}'} |")
    header = ["| configuration | seeds | best mean hold the end (95% CI) | at step | steps run | paper (best mean) |",
              "|---|---|---|---|---|---|"]
    note = (f"Hold-the-end rate per evaluation (seeded episodes, deterministic actions), smoothed over "
            f"{SMOOTHING_WINDOW} evaluations per seed, averaged over seeds; the best evaluation step is shown "
            "with the 95% confidence half-width over seeds (Student t).")
    return "\n".join(header + rows) + "\n\n" + note + "\n"


def build_report(results: Path, out_dir: Path) -> list[Path]:
    """Write the figures and results.md that the data allows; returns the written paths."""
    runs = load_runs(results)
    if not runs:
        raise FileNotFoundError(f"no run directories (config.yaml + eval.csv) under {results}")
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    figures = {"outcomes_single.png": lambda p: outcome_figure(runs, SINGLE, p),
               "outcomes_pairs.png": lambda p: outcome_figure(runs, PAIRS, p),
               "metrics_single.png": lambda p: metrics_figure(runs, SINGLE, p),
               "metrics_pairs.png": lambda p: metrics_figure(runs, PAIRS, p),
               "ablation.png": lambda p: ablation_figure(runs, p),
               "sensitivity.png": lambda p: sensitivity_figure(runs, p)}
    for name, draw in figures.items():
        if draw(out_dir / name):
            written.append(out_dir / name)
    (out_dir / "results.md").write_text(results_table(runs))
    written.append(out_dir / "results.md")
    return written


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(
        prog="dlo-report", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("results", type=Path, help="directory holding dlo-train run directories")
    parser.add_argument("--out", type=Path, help="where to write figures and results.md (default RESULTS/report)")
    args = parser.parse_args(argv)
    try:
        written = build_report(args.results, args.out or args.results / "report")
    except FileNotFoundError as error:
        print(f"dlo-report: error: {error}", file=sys.stderr)
        return 2
    print(written[-1].read_text())
    print("\n".join(f"wrote {path}" for path in written))
    return 0


if __name__ == "__main__":
    sys.exit(main())
