"""dlo-report's figures (matplotlib, Agg: files only) from the curves of `dlo_policy.report_data`."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Optional, Sequence

import matplotlib
import numpy as np

matplotlib.use("Agg")  # files only, no display
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
from matplotlib.ticker import FuncFormatter  # noqa: E402

from .grid import SENSITIVITY_PAIRS, TACTILE_NOISE_LEVELS, sensitivity_label  # noqa: E402
from .report_data import (  # noqa: E402
    FINAL_EVALUATIONS,
    HOLD,
    HOLD_AUTHORS,
    PAIRS,
    SINGLE,
    SMOOTHING_TEXT,
    Curves,
    Runs,
    final_values,
    mean_and_ci,
    ordered,
    smooth,
)
from .rundir import AUTHORS_SUFFIX, OUTCOMES  # noqa: E402

# metric column -> (axis title, y limits or None)
METRICS = {
    "episode_reward": ("episode reward", None),
    HOLD: ("hold the end, paper-text rule", (-0.02, 1.02)),
    HOLD_AUTHORS: ("hold the end, authors' rule", (-0.02, 1.02)),
    "time_at_end": ("time at end [control steps]", None),
    "how_far": ("how far: particles from the end (0 = last)", None),
}
MIN_SEEDS_FOR_BAND = 3  # a 95% CI band over fewer seeds is too wide to draw (t = 12.7 for 2)
OUTCOME_COLORS = {
    "hold_the_end": "tab:green",
    "stop_before": "tab:orange",
    "reach_end_but_drop": "tab:blue",
    "drop_before": "tab:red",
}
CONFIG_COLORS = {
    "T": "tab:blue",
    "K": "tab:orange",
    "V": "tab:green",
    "All": "black",
    "T+K": "tab:purple",
    "V+K": "tab:brown",
    "T+V": "tab:pink",
}
COMPARE_COLORS = (
    "tab:blue",
    "tab:orange",
    "tab:green",
    "tab:red",
    "tab:purple",
    "tab:brown",
    "tab:pink",
    "tab:gray",
    "tab:olive",
    "tab:cyan",
)
OTHER_COLORS = ("tab:cyan", "tab:olive", "tab:gray", "tab:red", "tab:blue", "tab:orange", "tab:green")
SEED_LINE = {"linewidth": 0.7, "alpha": 0.35}
MEAN_LINEWIDTH = 2.2
BAND_ALPHA = 0.18


def band_allowed(seeds: int) -> bool:
    """Whether a figure draws the 95% CI band of a mean over `seeds` seeds."""
    return seeds >= MIN_SEEDS_FOR_BAND


def config_color(label: str, index: int = 0) -> str:
    return CONFIG_COLORS.get(label, OTHER_COLORS[index % len(OTHER_COLORS)])


def draw_curve(
    ax,
    steps: np.ndarray,
    samples: np.ndarray,
    color: str,
    label: Optional[str] = None,
    seed_lines: bool = True,
    linestyle: str = "-",
    linewidth: float = MEAN_LINEWIDTH,
    band: bool = True,
) -> bool:
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
    fig, axes = plt.subplots(
        rows, columns, figsize=(max(3.9 * columns, 7.5), 3.3 * rows + 1.2), sharey=True, squeeze=False, layout="constrained"
    )
    band_drawn, authors_drawn = False, False
    for ax, label in zip(axes.flat, present):
        curves = runs[label][""]
        for outcome in OUTCOMES:
            hold = outcome == HOLD
            width = MEAN_LINEWIDTH if hold else 1.4
            band_drawn |= draw_curve(
                ax, curves.steps, curves.values[outcome], OUTCOME_COLORS[outcome], seed_lines=hold, band=hold, linewidth=width
            )
            authors = curves.values[outcome + AUTHORS_SUFFIX]
            if not np.isnan(authors).any():
                authors_drawn = True
                draw_curve(
                    ax,
                    curves.steps,
                    authors,
                    OUTCOME_COLORS[outcome],
                    seed_lines=False,
                    band=False,
                    linestyle="--",
                    linewidth=width,
                )
        ax.set_title(f"{label} ({seeds_text(curves)})")
        ax.set_ylim(-0.02, 1.02)
        _step_axis(ax)
    for ax in axes.flat[len(present) :]:
        ax.axis("off")
    for ax in axes[:, 0]:
        ax.set_ylabel("fraction of evaluation episodes")
    handles = [Line2D([], [], color=OUTCOME_COLORS[o], linewidth=MEAN_LINEWIDTH, label=o.replace("_", " ")) for o in OUTCOMES]
    handles += [Line2D([], [], color="black", linewidth=1.4, label="paper-text rule (solid)")]
    handles += [
        Line2D(
            [],
            [],
            color="black",
            linewidth=1.4,
            linestyle="--",
            label="authors' rule (dashed)" if authors_drawn else "authors' rule: n/a in these eval.csv",
        )
    ]
    if any(runs[label][""].seeds > 1 for label in present):
        handles.append(Line2D([], [], color=OUTCOME_COLORS[HOLD], **SEED_LINE, label="one seed, hold the end (paper rule)"))
    if band_drawn:
        handles.append(
            Patch(color=OUTCOME_COLORS[HOLD], alpha=BAND_ALPHA * 2, label=f"95% CI of the mean (>= {MIN_SEEDS_FOR_BAND} seeds)")
        )
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
            ax.text(
                0.5, 0.5, "n/a: no such column in these eval.csv", ha="center", va="center", transform=ax.transAxes, fontsize=9
            )
        counts = {runs[label][""].seeds for label in present}
        ax.set_title(f"{title}\n({_seed_counts(counts)})", fontsize=10)
        if limits:
            ax.set_ylim(*limits)
        _step_axis(ax)
    legend_ax = axes.flat[-1]
    legend_ax.axis("off")
    handles = [
        Line2D([], [], color=config_color(label, i), linewidth=MEAN_LINEWIDTH, label=f"{label} ({seeds_text(runs[label][''])})")
        for i, label in enumerate(present)
    ]
    seed_lines = any(runs[label][""].seeds > 1 for label in present)
    legend_ax.legend(
        handles=handles + style_handles(band_drawn, seed_lines),
        loc="center",
        fontsize=9,
        frameon=False,
        title=f"{SMOOTHING_TEXT.capitalize()}",
        title_fontsize=9,
    )
    fig.suptitle(f"Evaluation metrics over training ({SMOOTHING_TEXT})", fontsize=11)
    return fig


def _seed_counts(counts: set[int]) -> str:
    if len(counts) == 1:
        n = counts.pop()
        return f"{n} seed{'s' if n != 1 else ''} per configuration"
    return f"{min(counts)}-{max(counts)} seeds per configuration, see legend"


def draw_bars(ax, names: Sequence[str], samples: Sequence[np.ndarray], colors: Sequence[str], ylabel: str) -> None:
    """Bar = mean over seeds, dots = the seeds, error bar = 95% CI for >= 3 seeds only."""
    for i, (values, color) in enumerate(zip(samples, colors)):
        mean, ci = mean_and_ci(values)
        ax.bar(i, mean, color=color, alpha=0.45, width=0.65, yerr=ci if band_allowed(len(values)) else None, capsize=4)
        jitter = np.linspace(-0.15, 0.15, len(values)) if len(values) > 1 else np.zeros(1)
        ax.plot(i + jitter, values, "o", color=color, markersize=3.5, markeredgecolor="black", markeredgewidth=0.4)
    ax.set_xticks(
        range(len(names)), [f"{n}\n({len(s)} seed{'s' if len(s) != 1 else ''})" for n, s in zip(names, samples)], fontsize=8
    )
    ax.set_ylabel(ylabel)
    ax.grid(axis="y", alpha=0.3, linewidth=0.5)


BAR_NOTE = (
    f"dots: each seed's mean of its last {FINAL_EVALUATIONS} evaluations; bar: their mean;\n"
    f"error bar: 95% CI of the mean (>= {MIN_SEEDS_FOR_BAND} seeds only)"
)


def ablation_figure(runs: Runs) -> Optional[Figure]:
    """All tested with all inputs / without T / without V (bars), and reward over training of All,
    All tested without X and the agents trained without X. None without ablation evaluations."""
    all_runs = runs.get("All", {})
    tested = [w for w in ("", "T", "V") if w in all_runs]
    if "" not in all_runs or len(tested) < 2:
        return None
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2), layout="constrained")
    names = ["All" if w == "" else f"All, tested\nwithout {w}" for w in tested]
    draw_bars(
        axes[0],
        names,
        [final_values(all_runs[w], "episode_reward") for w in tested],
        ["black", "tab:blue", "tab:red"][: len(tested)],
        "final episode reward",
    )
    axes[0].set_title(BAR_NOTE, fontsize=8)
    band_drawn = False
    for ax, removed, trained_without in ((axes[1], "T", "V+K"), (axes[2], "V", "T+K")):
        entries = [("All", all_runs[""], "black")]
        if removed in all_runs:
            entries.append((f"All, tested without {removed}", all_runs[removed], "tab:blue"))
        if "" in runs.get(trained_without, {}):
            entries.append((f"trained without {removed} ({trained_without})", runs[trained_without][""], "tab:red"))
        for name, curves, color in entries:
            band_drawn |= draw_curve(
                ax, curves.steps, curves.values["episode_reward"], color, label=f"{name} ({seeds_text(curves)})"
            )
        ax.set_title(f"without {removed}", fontsize=10)
        ax.set_ylabel("episode reward")
        _step_axis(ax)
        ax.legend(
            handles=ax.get_legend_handles_labels()[0] + style_handles(band_drawn, any(c.seeds > 1 for _, c, _ in entries)),
            fontsize=7,
        )
    fig.suptitle(f"Ablation: episode reward (curves: {SMOOTHING_TEXT})", fontsize=11)
    return fig


def sensitivity_figure(runs: Runs) -> Optional[Figure]:
    """Final episode reward per tactile-noise level, with K and without K. None without noise runs."""
    if not any(sensitivity_label(m, n) in runs for m, _ in SENSITIVITY_PAIRS for n in TACTILE_NOISE_LEVELS):
        return None
    fig, axes = plt.subplots(1, len(SENSITIVITY_PAIRS), figsize=(12, 4.2), sharey=True, layout="constrained")
    for ax, (modalities, no_tactile) in zip(axes, SENSITIVITY_PAIRS):
        entries = [("noise: none", modalities)] + [
            (f"noise: {n}", sensitivity_label(modalities, n)) for n in TACTILE_NOISE_LEVELS
        ]
        entries.append(("no tactile", no_tactile))
        entries = [(name, label) for name, label in entries if "" in runs.get(label, {})]
        draw_bars(
            ax,
            [f"{name}\n{label}" for name, label in entries],
            [final_values(runs[label][""], "episode_reward") for _, label in entries],
            [f"C{i}" for i in range(len(entries))],
            "final episode reward",
        )
        ax.set_title(f"{modalities} ({'with K' if 'K' in modalities or modalities == 'All' else 'without K'})", fontsize=10)
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
    fig, axes = plt.subplots(
        rows, columns, figsize=(max(4.2 * columns, 7.5), 3.4 * rows + 1.0), sharey=True, squeeze=False, layout="constrained"
    )
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
    for ax in axes.flat[len(labels) :]:
        ax.axis("off")
    for ax in axes[:, 0]:
        ax.set_ylabel("hold the end (paper rule)")
    handles = [Line2D([], [], color=colors[name], linewidth=MEAN_LINEWIDTH, label=name) for name, _ in named]
    seed_lines = any(by_without[""].seeds > 1 for _, runs in named for by_without in runs.values() if "" in by_without)
    fig.legend(
        handles=handles + style_handles(band_drawn, seed_lines),
        loc="outside lower center",
        ncol=min(len(handles) + 3, 5),
        fontsize=8,
        frameon=False,
    )
    fig.suptitle(f"Hold the end per setting: mean over seeds\n({SMOOTHING_TEXT})", fontsize=10)
    return fig


def save_figure(fig: Figure, path: Path) -> Path:
    fig.savefig(path, dpi=130, bbox_inches="tight")  # "tight": nothing outside the axes is cut off
    plt.close(fig)
    return path


def planned_figures(runs: Runs) -> list[tuple[str, Any, str]]:
    """(file name, drawing function, reason when it draws nothing) of dlo-report RESULTS."""
    has_pairs = bool(figure_labels(runs, PAIRS))
    pairs = (*PAIRS, "All") if has_pairs else ()  # All is the pairs' reference only when pairs exist
    no_single, no_pairs = "no runs of T, K, V or All", "no runs of T+K, V+K or T+V"
    return [
        ("outcomes_single.png", lambda: outcome_figure(runs, SINGLE), no_single),
        ("outcomes_pairs.png", lambda: outcome_figure(runs, pairs), no_pairs),
        ("metrics_single.png", lambda: metrics_figure(runs, SINGLE), no_single),
        ("metrics_pairs.png", lambda: metrics_figure(runs, pairs), no_pairs),
        (
            "ablation.png",
            lambda: ablation_figure(runs),
            "no All runs evaluated without T or V (dlo-experiments --groups ablation)",
        ),
        ("sensitivity.png", lambda: sensitivity_figure(runs), "no tactile-noise runs (dlo-experiments --groups sensitivity)"),
    ]
