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
                          the paper's number; the definitions are written under the table;
                          then a second table: the best of the UNSMOOTHED seed-averaged curve
                          under both rules (what the paper's footnote suggests its listed
                          numbers are)
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
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Sequence

from dlo_common.console import console_main

from .cli import OneLineErrorParser
from .report_data import ReportError, load_results_dir
from .report_plots import compare_figure, planned_figures, save_figure
from .report_tables import compare_table, results_table


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


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineErrorParser(prog="dlo-report", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "results", type=Path, nargs="?", metavar="RESULTS", help="directory holding dlo-train run directories (anywhere below it)"
    )
    parser.add_argument(
        "--out", type=Path, metavar="DIR", help="where to write (default RESULTS/report; required with --compare)"
    )
    parser.add_argument(
        "--compare",
        nargs="+",
        metavar="NAME=DIR",
        help="compare results directories of the same configurations trained under different "
        "settings: writes compare.md and compare.png instead of the study's report",
    )
    return parser


@console_main("dlo-report")
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
