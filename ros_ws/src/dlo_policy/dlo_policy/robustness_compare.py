"""dlo-robustness compare: two or more robustness envelopes side by side (issue 40: the robust policy against the
nominal one).

`dlo-robustness compare A B [C ...] --out DIR` reads the robustness.json of each envelope directory (what
`dlo-robustness` wrote: `results/robustness/<policy>/`), the first being the reference (the nominal, shipped policy),
checks that they were made on the same episodes (episodes, first seed, environments stepped together, threshold:
else one line naming the difference) and writes

- `DIR/compare.png`: hold the end against magnitude, one panel per family, one colour per policy, the authors' rule
  solid with its 95% band, the paper rule dashed, the threshold dotted, each policy's randomised range (where it
  was trained with `env_options.randomise`) shaded in its colour;
- `DIR/compare.md` and `DIR/compare.json`: each policy's unperturbed hold the end with its interval and the
  difference to the reference; per family, side and rule each policy's tolerance and how far it lies from the
  nominal, and the ratio of each policy's distance to the reference's; the issue's test.

Distances: a tolerance (the first magnitude, going away from the nominal, whose hold the end is below the
threshold) is measured from the nominal as robustness.json defines it: from the family's off value (a delay or a
noise from 0, velocity_gain from 1), a physics family from the end of its training range on that side (friction
above 0.3, cable_length below 30). A policy that never drops below the threshold on a side ("whole grid") is
counted as tolerating at least the farthest magnitude tried there: its ratio is a bound (">= 3" or "<= 0.5"), and a
bound that cannot settle ">= 2" leaves the family undetermined (a longer grid would). A tolerance at the nominal
(already below unperturbed) is a distance of 0.

The issue's test, for each policy after the first: "robust vs shipped: unperturbed authors' rule -1 point (within 3);
tolerance >= 2x on N of M families" -- the unperturbed hold the end (authors' rule) at most 3 points below the
reference's, and the tolerance (authors' rule) at least twice the reference's. The M families: `--family` (repeatable),
else those the policy was randomised over (its checkpoint's `env_options.randomise`, which robustness.json records),
else every family both envelopes evaluated. A family's counted sides: those its randomised range reaches the reference's
tolerance on (where it trained at magnitudes the reference fails at: velocity_gain 0.5-2 against 0.25 and 1.5 counts
above only); without a range, or where it reaches none, every side. A family passes when each counted side is >= 2x.

The last stdout line is one JSON line (out, and per policy the test's numbers).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Optional, Sequence

from . import perturbations as registry
from .cli import OneLineErrorParser
from .robustness import (
    SUMMARY_FILE,
    curve_parts,
    decorate_panel,
    figure_panels,
    finish_figure,
    nominal_span,
    write_json,
)

FIGURE_FILE = "compare.png"
TABLE_FILE = "compare.md"
JSON_FILE = "compare.json"
SAME = ("episodes", "seed", "num_envs", "threshold")  # what two envelopes must share to be compared point by point
WITHIN_POINTS = 3  # issue 40: unperturbed, at most this many points below the reference (authors' rule)
TIMES = 2  # issue 40: the tolerance at least this many times the reference's
RULES = (("authors", "hold_the_end_authors"), ("paper", "hold_the_end"))  # the issue's rule first
SIDES = ("below", "above")
RULE_NAMES = {"authors": "authors' rule", "paper": "paper rule"}


def read_envelope(directory: Path) -> dict:
    """DIR/robustness.json; ValueError in one line when the directory, the file or its fields are missing."""
    directory = Path(directory)
    if not directory.is_dir():
        raise ValueError(f"{directory}: no such directory (an envelope is a directory dlo-robustness wrote)")
    path = directory / SUMMARY_FILE
    try:
        summary = json.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"{directory}: no {SUMMARY_FILE} (not an envelope dlo-robustness wrote)") from None
    except (OSError, ValueError) as error:
        raise ValueError(f"{path} cannot be read ({error})") from None
    missing = [key for key in (*SAME, "baseline", "families") if not isinstance(summary, dict) or key not in summary]
    if missing:
        raise ValueError(f"{path}: not a dlo-robustness summary (no {', '.join(missing)})")
    return summary


def check_same_episodes(envelopes: dict) -> None:
    """ValueError naming the first setting in which an envelope differs from the first one ({label: summary})."""
    (first, reference), *others = envelopes.items()
    for label, summary in others:
        for key in SAME:
            if summary[key] != reference[key]:
                raise ValueError(
                    f"not the same episodes: {label} has {key} {summary[key]}, {first} {reference[key]} "
                    f"(envelopes are compared on the same {', '.join(SAME)})"
                )


def randomised_ranges(summary: dict) -> dict:
    """{family: (low, high)} the envelope's policy was trained with (its env_options.randomise); {} when none."""
    value = (summary.get("env_options") or {}).get("randomise")
    return dict(registry.parse_ranges(value)) if value else {}


def distance(entry: dict, side: str, magnitude) -> float:
    """How far ``magnitude`` lies from the family's nominal on ``side`` (module docstring); 0 at the nominal."""
    if magnitude == "baseline":
        return 0.0
    low, high = nominal_span(entry)
    return float(low - magnitude) if side == "below" else float(magnitude - high)


def side_tolerance(entry: dict, rule: str, side: str) -> dict:
    """One policy's tolerance on one side under one rule: {"magnitude", "distance", "whole_grid"}; a whole grid's
    magnitude and distance are the farthest tried (at least that)."""
    tolerance = entry["tolerance"][rule][side]
    if tolerance is not None:
        return {"magnitude": tolerance, "distance": distance(entry, side, tolerance), "whole_grid": False}
    low, high = nominal_span(entry)
    tried = [p["magnitude"] for p in entry["points"] if (p["magnitude"] < low if side == "below" else p["magnitude"] > high)]
    farthest = min(tried) if side == "below" else max(tried)
    return {"magnitude": farthest, "distance": distance(entry, side, farthest), "whole_grid": True}


def ratio(reference: dict, other: dict) -> dict:
    """``other``'s distance over ``reference``'s (side_tolerance records): {"value", "bound", "twice"}. ``bound``
    "=" (both measured), ">=" (other tolerates its whole grid), "<=" (the reference does), None where undefined
    (both tolerate their whole grid, or both are below at the nominal). ``twice``: True/False whether it is at least
    TIMES, None when the grid cannot tell. An infinite value (the reference below at the nominal) is None with
    ``bound`` "inf"."""
    a, b = reference["distance"], other["distance"]
    if reference["whole_grid"] and other["whole_grid"]:
        return {"value": None, "bound": None, "twice": None}
    if a == 0:
        if b == 0:
            return {"value": None, "bound": None, "twice": None}
        return {"value": None, "bound": "inf", "twice": True}
    value = b / a
    meets = round(value, 9) >= TIMES
    if other["whole_grid"]:
        return {"value": value, "bound": ">=", "twice": True if meets else None}
    if reference["whole_grid"]:
        return {"value": value, "bound": "<=", "twice": False if not meets else None}
    return {"value": value, "bound": "=", "twice": meets}


def counted_sides(entry: dict, reference: dict, ranges: dict, name: str) -> list:
    """The sides of a family the issue's test counts (module docstring): those the randomised range reaches the
    reference's tolerance (authors' rule) on; every side without a range or where it reaches none."""
    sides = [side for side in SIDES if side in reference["tolerance"]["authors"] and side in entry["tolerance"]["authors"]]
    if name not in ranges:
        return sides
    low, high = ranges[name]
    reached = []
    for side in sides:
        tolerance = reference["tolerance"]["authors"][side]
        if tolerance is None:
            continue
        at = nominal_span(reference)[0 if side == "below" else 1] if tolerance == "baseline" else tolerance
        if (low <= at) if side == "below" else (high >= at):
            reached.append(side)
    return reached or sides


def points_text(difference: float) -> str:
    """-0.01 -> '-1 point', 0.025 -> '+2.5 points'."""
    value = round(difference * 100, 1)
    value = 0.0 if value == 0 else value
    return f"{value:+g} point{'' if abs(value) == 1 else 's'}" if value else "0 points"


def newcombe(p1: float, ci1: Sequence, p2: float, ci2: Sequence) -> list:
    """95% interval of p2 - p1 from the two Wilson intervals (Newcombe's method 10, independent samples: wider than
    needed for the same episodes, which it does not use)."""
    d = p2 - p1
    return [d - math.hypot(p2 - ci2[0], ci1[1] - p1), d + math.hypot(ci2[1] - p2, p1 - ci1[0])]


def compare(envelopes: dict, families: Optional[Sequence] = None) -> dict:
    """compare.json from {label: robustness.json}, the first the reference; ``families``: the families the issue's
    test counts (None: those each policy was randomised over, else every family both envelopes have)."""
    check_same_episodes(envelopes)
    (first, reference), *others = envelopes.items()
    result = {
        "reference": first,
        "policies": list(envelopes),
        **{key: reference[key] for key in SAME},
        "unperturbed": {},
        "families": {},
        "tests": {},
    }
    for label, summary in envelopes.items():
        base = summary["baseline"]
        row = {}
        for rule, key in RULES:
            row[rule] = {"hold_the_end": base[key], "ci95": base[key + "_ci95"]}
            if label != first:
                ref = reference["baseline"]
                row[rule]["difference"] = base[key] - ref[key]
                row[rule]["difference_ci95"] = newcombe(ref[key], ref[key + "_ci95"], base[key], base[key + "_ci95"])
        result["unperturbed"][label] = row
    names = [n for n in registry.names() if any(n in s["families"] for s in envelopes.values())]
    for name in names:
        entries = {label: s["families"][name] for label, s in envelopes.items() if name in s["families"]}
        family = {"unit": registry.family(name).unit, "nominal": list(nominal_span(next(iter(entries.values()))))}
        family["evaluated_by"] = list(entries)
        family["sides"] = {}
        for side in SIDES:
            present = [label for label, e in entries.items() if side in e["tolerance"]["authors"]]
            if not present:
                continue
            rows = {}
            for rule, _ in RULES:
                rows[rule] = {label: side_tolerance(entries[label], rule, side) for label in present}
                for label in present:
                    if first in present and label != first:
                        rows[rule][label]["ratio"] = ratio(rows[rule][first], rows[rule][label])
            family["sides"][side] = rows
        result["families"][name] = family
    for label, summary in others:
        result["tests"][label] = issue_test(result, label, reference, summary, families)
    return result


def issue_test(result: dict, label: str, reference: dict, summary: dict, families: Optional[Sequence]) -> dict:
    """Issue 40's test of one policy against the reference (module docstring)."""
    first = result["reference"]
    difference = result["unperturbed"][label]["authors"]["difference"]
    ranges = randomised_ranges(summary)
    both = [n for n in result["families"] if n in summary["families"] and n in reference["families"]]
    if families:
        chosen, source = list(families), "those named by --family"
    elif ranges:
        chosen, source = list(ranges), f"those {label} was randomised over (env_options.randomise)"
    else:
        chosen, source = both, "every family both envelopes evaluated"
    verdicts = {}
    for name in chosen:
        if name not in both:
            verdicts[name] = {"counted": False, "why": "not in both envelopes"}
            continue
        sides = counted_sides(summary["families"][name], reference["families"][name], ranges, name)
        ratios = {side: result["families"][name]["sides"][side]["authors"][label]["ratio"] for side in sides}
        twice = [r["twice"] for r in ratios.values()]
        passed = True if twice and all(t is True for t in twice) else (False if False in twice else None)
        verdicts[name] = {"counted": True, "sides": sides, "range": list(ranges[name]) if name in ranges else None}
        verdicts[name]["twice"] = passed
    counted = [n for n, v in verdicts.items() if v["counted"]]
    passed = [n for n in counted if verdicts[n]["twice"] is True]
    undetermined = [n for n in counted if verdicts[n]["twice"] is None]
    within = round(difference * 100, 6) >= -WITHIN_POINTS
    line = (
        f"{label} vs {first}: unperturbed authors' rule {points_text(difference)} "
        f"({'within' if within else 'more than'} {WITHIN_POINTS}); tolerance >= {TIMES}x on {len(passed)} of "
        f"{len(counted)} families" + (f" ({len(undetermined)} undetermined: the grid too short)" if undetermined else "")
    )
    return {
        "line": line,
        "unperturbed_difference_points": round(difference * 100, 1),
        "within": within,
        "twice": len(passed),
        "families": len(counted),
        "undetermined": len(undetermined),
        "families_from": source,
        "per_family": verdicts,
    }


# ----------------------------------------------------------------------------------------------------------- text


def tolerance_cell(record: dict) -> str:
    """'1.5 (0.5)', 'none to 3 (>= 2)', 'at the nominal' (the magnitude, its distance from the nominal)."""
    if record["whole_grid"]:
        return f"none to {record['magnitude']:g} (>= {record['distance']:g})"
    if record["distance"] == 0:
        return "at the nominal"
    return f"{record['magnitude']:g} ({record['distance']:g})"


def ratio_cell(r: dict) -> str:
    if r["bound"] == "inf":
        return "inf (reference at the nominal)"
    if r["bound"] is None:
        return "n/a"
    return f"{'' if r['bound'] == '=' else r['bound'] + ' '}{r['value']:.2g}"


def percent(value: float, ci: Sequence) -> str:
    return f"{value:.0%} [{ci[0]:.0%}, {ci[1]:.0%}]"


def markdown(result: dict, sources: dict, command: str) -> str:
    """compare.md."""
    first = result["reference"]
    labels = result["policies"]
    out = [
        f"# Robustness envelopes: {', '.join(labels)}",
        "",
        f"Made by `{command}`. Every envelope on the same {result['episodes']} episodes (seeds {result['seed']}.."
        f"{result['seed'] + result['episodes'] - 1}, {result['num_envs']} environments stepped together), threshold "
        f"{result['threshold']:.0%}; reference {first}. Envelopes: "
        + "; ".join(f"{label} `{path}`" for label, path in sources.items())
        + ".",
        "",
        "## Unperturbed",
        "",
        "| policy | hold the end, authors' rule [95%] | paper rule [95%] | difference, authors' / paper [95%] |",
        "|---|---|---|---|",
    ]
    for label in labels:
        row = result["unperturbed"][label]
        cells = [percent(row[rule]["hold_the_end"], row[rule]["ci95"]) for rule in ("authors", "paper")]
        if "difference" in row["authors"]:
            diff = " / ".join(
                f"{points_text(row[rule]['difference'])} [{row[rule]['difference_ci95'][0] * 100:+.0f}, "
                f"{row[rule]['difference_ci95'][1] * 100:+.0f}]"
                for rule in ("authors", "paper")
            )
        else:
            diff = "(reference)"
        out.append(f"| {label} | {cells[0]} | {cells[1]} | {diff} |")
    out += [
        "",
        "(The difference's interval: Newcombe's, for independent samples; the same episodes make the true one narrower.)",
        "",
        f"## Tolerance: where hold the end drops below {result['threshold']:.0%}",
        "",
        "Each cell: the first magnitude below the threshold going away from the nominal (its distance from the nominal "
        "in brackets: from the off value, a physics family from the end of its training range); 'none to M (>= D)': "
        "never below in the grid, counted as at least the farthest magnitude tried. Ratio: the policy's distance over "
        f"{first}'s.",
        "",
        "| family (unit) | side | rule | " + " | ".join(labels) + " | " + " | ".join(f"ratio {x}" for x in labels[1:]) + " |",
        "|---" * (3 + 2 * len(labels) - 1) + "|",
    ]
    for name, family in result["families"].items():
        for side, rules in family["sides"].items():
            for rule, _ in RULES:
                records = rules[rule]
                cells = [tolerance_cell(records[x]) if x in records else "-" for x in labels]
                ratios = [ratio_cell(records[x]["ratio"]) if "ratio" in records.get(x, {}) else "-" for x in labels[1:]]
                out.append(f"| `{name}` ({family['unit']}) | {side} | {rule} | " + " | ".join(cells + ratios) + " |")
    out += ["", "## Issue 40's test", ""]
    for test in result["tests"].values():
        out += [f"**{test['line']}**", ""]
        out.append(
            f"Families: {test['families_from']}; counted sides: those its randomised range reaches "
            f"{first}'s tolerance (authors' rule) on, every side without one. Per family (authors' rule):"
        )
        out.append("")
        for name, verdict in test["per_family"].items():
            if not verdict["counted"]:
                out.append(f"- `{name}`: not counted ({verdict['why']})")
                continue
            sides = ", ".join(verdict["sides"])
            state = {True: f">= {TIMES}x", False: f"below {TIMES}x", None: "undetermined"}[verdict["twice"]]
            ranged = f", trained {verdict['range'][0]:g}-{verdict['range'][1]:g}" if verdict["range"] else ""
            out.append(f"- `{name}` ({sides}{ranged}): {state}")
        out.append("")
    return "\n".join(out)


# --------------------------------------------------------------------------------------------------------- figure


def plot(result: dict, envelopes: dict, path: Path) -> None:
    """compare.png: one panel per family, one colour per policy; authors' rule solid with its 95% band, paper dashed."""
    import matplotlib.pyplot as plt  # noqa: PLC0415 (the figure only)

    names = list(result["families"])
    fig, axes, rows = figure_panels(len(names))
    cycle = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    colours = {label: cycle[k % len(cycle)] for k, label in enumerate(envelopes)}
    for ax, name in zip(axes.flat, names):
        magnitudes = []
        entry = None
        for label, summary in envelopes.items():
            if name not in summary["families"]:
                continue
            entry = summary["families"][name]
            base = summary["baseline"]
            colour = colours[label]
            ranges = randomised_ranges(summary)
            if name in ranges:
                ax.axvspan(*ranges[name], color=colour, alpha=0.08, zorder=0, label=f"{label} trained on")
            for rule, key in RULES:
                solid = rule == "authors"
                outside, inside = curve_parts(entry, base, key)
                for part in (outside, inside):
                    if not part:
                        continue
                    x = [p["magnitude"] for p in part]
                    shown = f"{label}, {RULE_NAMES[rule]}"
                    ax.plot(
                        x,
                        [p[key] for p in part],
                        "-" if solid else "--",
                        color=colour,
                        lw=1.3 if solid else 0.9,
                        label=shown if part is outside else None,
                    )
                    if solid:
                        ax.fill_between(
                            x,
                            [p[key + "_ci95"][0] for p in part],
                            [p[key + "_ci95"][1] for p in part],
                            color=colour,
                            alpha=0.15,
                            lw=0,
                        )
            magnitudes += [p["magnitude"] for p in entry["points"]]
        decorate_panel(ax, name, entry, magnitudes, result["threshold"])
    first = result["reference"]
    title = (
        f"{' vs '.join(result['policies'][1:])} against {first}: hold the end under perturbation ({result['episodes']} "
        f"episodes per point, seeds {result['seed']}..{result['seed'] + result['episodes'] - 1}; solid: authors' rule "
        f"with its 95% band, dashed: paper rule; dashed grey: {result['threshold']:.0%})"
    )
    finish_figure(fig, axes, len(names), rows, title, path)


# ------------------------------------------------------------------------------------------------------------ CLI


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineErrorParser(
        prog="dlo-robustness compare", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("envelopes", nargs="+", type=Path, metavar="DIR", help="envelope directories, the reference first")
    parser.add_argument("--out", type=Path, required=True, help="where compare.png, compare.md and compare.json go")
    parser.add_argument(
        "--family",
        action="append",
        default=[],
        metavar="NAME",
        help="a family the issue's test counts (repeatable; default: those the policy was randomised over, "
        "else every family both envelopes evaluated)",
    )
    return parser


def labels(directories: Sequence[Path], summaries: Sequence[dict]) -> list:
    """Each envelope's name: its policy (robustness.json), else its directory's; the directory where two agree."""
    names = [str(s.get("policy") or d.resolve().name) for d, s in zip(directories, summaries)]
    return [str(d) if names.count(n) > 1 else n for d, n in zip(directories, names)]


def main(argv: Optional[Sequence[str]] = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    prog = "dlo-robustness compare: error:"
    if len(args.envelopes) < 2:
        print(f"{prog} give two or more envelope directories, the reference first", file=sys.stderr)
        return 2
    try:
        families = [registry.family(name).name for name in args.family]
        summaries = [read_envelope(d) for d in args.envelopes]
        names = labels(args.envelopes, summaries)
        envelopes = dict(zip(names, summaries))
        result = compare(envelopes, families or None)
    except ValueError as error:
        print(f"{prog} {error}", file=sys.stderr)
        return 2
    command = "dlo-robustness compare " + " ".join(argv)
    result["command"] = command
    result["envelopes"] = {label: str(d) for label, d in zip(names, args.envelopes)}
    args.out.mkdir(parents=True, exist_ok=True)
    write_json(args.out / JSON_FILE, result)
    (args.out / TABLE_FILE).write_text(markdown(result, result["envelopes"], command) + "\n")
    plot(result, envelopes, args.out / FIGURE_FILE)
    for test in result["tests"].values():
        print(test["line"])
    print(
        json.dumps(
            {
                "out": str(args.out),
                "reference": result["reference"],
                "tests": {
                    label: {k: test[k] for k in ("unperturbed_difference_points", "within", "twice", "families", "undetermined")}
                    for label, test in result["tests"].items()
                },
            }
        )
    )
    return 0
