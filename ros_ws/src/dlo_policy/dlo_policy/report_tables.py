"""dlo-report's tables: results.md and compare.md (Markdown) from the statistics of `dlo_policy.report_data`."""

from __future__ import annotations

import math
from typing import Optional, Sequence

from .report_data import (
    FINAL_EVALUATIONS,
    HOLD,
    HOLD_AUTHORS,
    HOLDS_LEVEL_RATIO,
    SMOOTHING_TEXT,
    TABLE_ORDER,
    Runs,
    Stat,
    Summary,
    best_smoothed,
    holds_level,
    ordered,
    summarize,
    test_episodes,
)

PAPER_HOLD_THE_END = {"T": 0.12, "K": 0.11, "V": 0.77, "All": 0.92, "T+K": 0.16, "V+K": 0.89, "T+V": 0.77}


def format_stat(stat: Stat) -> str:
    """'45% ± 12%' (n >= 2), '45% (1 seed)', or 'n/a'."""
    if math.isnan(stat.mean):
        return "n/a"
    if stat.n < 2:
        return f"{stat.mean:.0%} (1 seed)"
    return f"{stat.mean:.0%} ± {stat.ci:.0%}"


def format_best(stat: Stat, step: Optional[int]) -> str:
    return "n/a" if step is None or math.isnan(stat.mean) else f"{format_stat(stat)} at {step:,}"


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


SUMMARY_HEADER = (
    "seeds (finished/total) × steps",
    "best smoothed mean hold the end, paper rule (at step)",
    "same, authors' rule",
    "last-5 mean, paper rule",
    "same, authors' rule",
    "last-5 / best, paper rule",
    "same, authors' rule",
    "held-out test, paper rule",
    "held-out test, authors' rule",
)


def summary_cells(summary: Summary) -> list[str]:
    return [
        format_seeds(summary),
        format_best(summary.best, summary.best_step),
        format_best(summary.best_authors, summary.best_authors_step),
        format_stat(summary.last),
        format_stat(summary.last_authors),
        format_ratio(summary.ratio),
        format_ratio(summary.ratio_authors),
        format_test(summary.test, summary.finished),
        format_test(summary.test_authors, summary.finished),
    ]


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)] + ["| " + " | ".join(row) + " |" for row in rows]


def definitions(runs_list: Sequence[Runs]) -> str:
    """The note under a table: exact definitions, with the episode counts found in the data."""
    curves = [c for runs in runs_list for by_without in runs.values() for c in by_without.values()]
    tests = sorted(set().union(*(test_episodes(c) for c in curves))) if curves else []
    episodes = sorted({int(e) for c in curves for e in c.values["episodes"].ravel() if not math.isnan(e)})
    episodes_text = "/".join(map(str, episodes)) if episodes else "`train.eval_episodes`"
    tests_text = "/".join(map(str, tests)) if tests else "`train.test_episodes`"
    return "\n".join(
        [
            "Definitions. Every `train.eval_every` steps each seed's deterministic policy is evaluated on "
            f"{episodes_text} fresh episodes (seeds never reused within or across runs; see the warnings otherwise). "
            f"*Best smoothed mean*: {SMOOTHING_TEXT} (fewer at the start), averaged over seeds, maximised over the "
            'evaluation steps (the step is shown): the paper\'s "best mean". '
            "*± x%*: 95% confidence half-width of the mean over seeds (Student t, n - 1 degrees of freedom), "
            'written for >= 2 seeds only; "(1 seed)" marks a single seed\'s value. '
            "The best is a maximum over the evaluation steps of a noisy curve: it and its interval are biased upwards "
            "(the more evaluations and the fewer seeds, the more); the last-5 mean is taken at a fixed step, unbiased. "
            f"*Last-5 mean*: per seed the mean of its last {FINAL_EVALUATIONS} (unsmoothed) evaluations, averaged over "
            f"seeds; *last-5 / best* (printed rounded down, under each rule against that rule's best) >= "
            f"{HOLDS_LEVEL_RATIO}: training holds its level, else it sags. "
            "*Seeds*: finished (done.json) / all seeds; unfinished seeds count up to the last step every seed has "
            'reached (steps column; "of N": the configured length). '
            f"*Held-out test*: each finished seed's best evaluation policy (highest hold the end, then reward) tested "
            f"once on {tests_text} episodes whose seeds no evaluation used (test.json; test_without_X.json for the "
            "tested-without rows), averaged over finished seeds.",
            "",
            "- *Paper-text rule*: the episode reaches the horizon holding any of the last 10 particles.",
            "- *Authors' rule* (their code): on the last step their narrower held set is non-empty and its mean "
            "particle index is within 5 of the last particle.",
            "- *n/a*: not in the data (eval.csv written before the authors' rule existed, no finished seed with a "
            "held-out test, or a best of 0).",
        ]
    )


UNSMOOTHED_NOTE = (
    "*Best unsmoothed mean*: the highest evaluation of the seed-averaged curve without smoothing. The paper's "
    'footnote to its listed numbers ("the results in figures are smoothed for better readability so listed '
    'results might not be directly visible") suggests they are this statistic, over its 10 seeds. A maximum '
    "over many noisy evaluations: it lies above the smoothed best, the more so the fewer the seeds."
)


UNSMOOTHED_HEADER = (
    "configuration",
    "seeds (finished/total) × steps",
    "best unsmoothed mean hold the end, paper rule (at step)",
    "same, authors' rule",
    "paper (listed)",
)


def results_table(runs: Runs, warnings: Sequence[str] = ()) -> str:
    """results.md: one row per configuration and tested input set, the definitions, then the unsmoothed bests (the
    paper's listed statistic: best_smoothed with window 1, under both rules), any warnings."""
    rows, unsmoothed_rows = [], []
    for label, without, curves in ordered(runs):
        name = row_name(label, without)
        summary = summarize(name, curves)
        paper = PAPER_HOLD_THE_END.get(label) if not without else None
        paper_cell = "—" if paper is None else f"{paper:.0%}"
        rows.append([name, *summary_cells(summary), paper_cell])
        unsmoothed_rows.append(
            [
                name,
                format_seeds(summary),
                format_best(*best_smoothed(curves, HOLD, window=1)),
                format_best(*best_smoothed(curves, HOLD_AUTHORS, window=1)),
                paper_cell,
            ]
        )
    lines = markdown_table(["configuration", *SUMMARY_HEADER, "paper (best mean)"], rows)
    text = "\n".join(lines) + "\n\n" + definitions([runs]) + "\n- *paper*: best mean hold the end in the paper.\n"
    text += "\n" + "\n".join(markdown_table(UNSMOOTHED_HEADER, unsmoothed_rows)) + "\n\n" + UNSMOOTHED_NOTE + "\n"
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
            cells = (
                summary_cells(summarize(name, curves)) if curves is not None else ["no runs"] + [""] * (len(SUMMARY_HEADER) - 1)
            )
            rows.append([row_name(label, without), name, *cells])
    text = "\n".join(markdown_table(["configuration", "setting", *SUMMARY_HEADER], rows))
    text += (
        "\n\n"
        + definitions([runs for _, runs in named])
        + "\n- *setting*: the NAME of a results directory given as --compare NAME=DIR.\n"
    )
    if warnings:
        text += "\nWarnings:\n" + "".join(f"- {w}\n" for w in warnings)
    return text
