"""dlo-robustness: a checkpoint's robustness envelope over the perturbation families (dlo_policy.perturbations).

`dlo-robustness [--checkpoint PATH] [--family NAME ...] [--episodes 100] [--seed 7000] [--out results/robustness]`
evaluates the policy (default: the shipped one) with every perturbation off (the baseline), then with each family at
each magnitude of its grid (the registry's, or `--grid NAME=M1,M2,...`), one family at a time, on the same episodes
(seeds S .. S+N-1, held out: 7000 on is what neither training, evaluation nor the shipped policy's selection saw),
through dlo-evaluate's protocol (`dlo_policy.evaluate.evaluate_agent`: deterministic actions, a vector env of the
run's config.yaml with `env_options.perturbations` set to the one family, both outcome rules).

It writes `OUT/<policy>/` (`<policy>`: `--name`, else `shipped` for the shipped policy, else the run directory's
name): `points/` one JSON per evaluated point (baseline.json, FAMILY/MAGNITUDE.json: what dlo-evaluate --json
writes, and the settings it was made with); `robustness.json` (every point with 95% Wilson intervals of hold the end
under both rules, and each family's tolerance); `robustness.png` (hold the end against magnitude, one panel per
family, both rules, 95% bands, the 80% line, the baseline). Resumable: a point whose file exists (made with the same
checkpoint, episodes, seeds and batch) is read, not run again; an interrupted run goes on where it stopped.

Tolerance: for each family and outcome rule, going away from the nominal on each side of it (velocity_gain below
and above 1; a physics family below and above its training range), the first magnitude at which hold the end drops
below 80% (`--threshold`); null where it never does in the grid (it tolerates the whole grid on that side), the
nominal itself where the baseline is already below. `significant`: the same with the interval's upper end.

A progress bar over the episodes goes to stderr on a terminal (a plain line every tenth elsewhere; `--quiet`: none);
stdout carries the tolerance table and, last, one JSON line (out, points run and read, tolerances).

`dlo-robustness compare A B [C ...] --out DIR` puts envelopes side by side, the first the reference: compare.png,
compare.md, compare.json, each policy's tolerances and their ratios to the reference's, and issue 40's test
(`dlo-robustness compare --help`; dlo_policy.robustness_compare).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import sys
from pathlib import Path
from typing import Any, Optional, Sequence

from dlo_common.console import Progress, console_main

from . import perturbations as registry
from .cli import CHECKPOINT_HELP, OneLineErrorParser, checkpoint_argument

THRESHOLD = 0.8  # hold the end below this: the family's tolerance is passed
Z95 = 1.959963984540054  # two-sided 95% normal quantile (Wilson interval)
SUMMARY_FILE = "robustness.json"
FIGURE_FILE = "robustness.png"
POINTS_DIR = "points"
RULES = {"paper": "hold_the_end", "authors": "hold_the_end_authors"}  # rule -> EvalResult field
DEFAULT_SEED = 7000
SETTINGS = ("checkpoint_sha256", "episodes", "seed", "num_envs")  # what a point file must have been made with


def wilson(successes: float, n: int, z: float = Z95) -> tuple:
    """95% Wilson score interval (low, high) of a binomial proportion successes / n."""
    if n <= 0:
        return (math.nan, math.nan)
    p = successes / n
    denominator = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denominator
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denominator
    return (max(0.0, centre - half), min(1.0, centre + half))


def sides(family: registry.Family, magnitudes: Sequence) -> dict:
    """The grid's magnitudes on each side of the nominal, nearest first: {"below": [...], "above": [...]}, only
    sides that have some (a physics family's nominal is its training range; magnitudes inside it are on neither)."""
    low, high = (family.off, family.off) if family.off is not None else family.training
    found = {
        "below": sorted((m for m in magnitudes if m < low), reverse=True),
        "above": sorted(m for m in magnitudes if m > high),
    }
    return {side: ms for side, ms in found.items() if ms}


def tolerance(family: registry.Family, baseline: float, points: dict, threshold: float = THRESHOLD) -> dict:
    """{side: the first magnitude, going away from the nominal, whose value in ``points`` ({magnitude: value}) is
    below ``threshold``; None if none is; the nominal (None for a physics family: its range) if ``baseline`` is}."""
    result = {}
    for side, magnitudes in sides(family, list(points)).items():
        if baseline < threshold:
            result[side] = family.off if family.off is not None else "baseline"
            continue
        result[side] = next((m for m in magnitudes if points[m] < threshold), None)
    return result


def file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def magnitude_text(m) -> str:
    return f"{m:g}"


def point_path(out: Path, family: Optional[str], magnitude=None) -> Path:
    """Where a point's JSON lies: points/baseline.json, points/FAMILY/MAGNITUDE.json."""
    if family is None:
        return out / POINTS_DIR / "baseline.json"
    return out / POINTS_DIR / family / f"{magnitude_text(magnitude)}.json"


def read_point(path: Path, settings: dict) -> Optional[dict]:
    """The point stored at ``path`` if it was made with ``settings``; None if absent; ValueError if it was made
    with others (another checkpoint, episodes, seeds or batch)."""
    if not path.exists():
        return None
    try:
        point = json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise ValueError(f"{path} cannot be read ({error}); remove it to evaluate it again") from None
    other = {key: point.get(key) for key in SETTINGS if point.get(key) != settings[key]}
    if other:
        raise ValueError(
            f"{path} was made with other settings ({', '.join(f'{k} {v}' for k, v in other.items())}); "
            "use another --out or --name, or remove it"
        )
    return point


def write_json(path: Path, payload: Any) -> None:
    """Write ``payload`` atomically (an interrupted run leaves no half-written point)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(path.name + ".part")
    temporary.write_text(json.dumps(payload, indent=2) + "\n")
    os.replace(temporary, path)


def summarise(points: dict, baseline: dict, families: dict, header: dict, threshold: float) -> dict:
    """robustness.json: the header, the baseline, and per family its points with intervals and its tolerance."""

    def with_intervals(point):
        n = point["episodes"]
        entry = {"hold_the_end": point["hold_the_end"], "hold_the_end_authors": point["authors_code"]["hold_the_end"]}
        for key in ("hold_the_end", "hold_the_end_authors"):
            entry[f"{key}_ci95"] = list(wilson(round(entry[key] * n), n))
        entry["outcomes"] = {k: point[k] for k in ("stop_before", "reach_end_but_drop", "drop_before")}
        entry["outcomes_authors"] = {k: point["authors_code"][k] for k in ("stop_before", "reach_end_but_drop", "drop_before")}
        entry.update({k: point[k] for k in ("episode_reward", "time_at_end", "how_far")})
        return entry

    base = with_intervals(baseline)
    result = {**header, "threshold": threshold, "baseline": base, "families": {}}
    for name, magnitudes in families.items():
        f = registry.family(name)
        rows = [{"magnitude": m, **with_intervals(points[(name, m)])} for m in magnitudes if (name, m) in points]
        tolerances, significant = {}, {}
        for rule, key in (("paper", "hold_the_end"), ("authors", "hold_the_end_authors")):
            values = {row["magnitude"]: row[key] for row in rows}
            highs = {row["magnitude"]: row[key + "_ci95"][1] for row in rows}
            tolerances[rule] = tolerance(f, base[key], values, threshold)
            significant[rule] = tolerance(f, base[key + "_ci95"][1], highs, threshold)
        result["families"][name] = {
            "unit": f.unit,
            "side": f.side,
            "perturbs": f.perturbs,
            "nominal": f.off,
            "training_range": list(f.training) if f.training else None,
            "points": rows,
            "tolerance": tolerances,
            "tolerance_significant": significant,
        }
    return result


def tolerance_text(family: registry.Family, tol: dict, grid: Sequence) -> str:
    """A family's tolerance under one rule in words, ``grid`` the magnitudes tried: 'above: 1.5', 'above: none up
    to 3', 'below: below at the nominal', joined by '; '."""
    parts = []
    for side, m in tol.items():
        if m is None:
            edge = max(grid) if side == "above" else min(grid)
            parts.append(f"{side}: none up to {edge:g}" if side == "above" else f"{side}: none down to {edge:g}")
        elif m == "baseline" or (family.off is not None and m == family.off):
            parts.append(f"{side}: below at the nominal")
        else:
            parts.append(f"{side}: {m:g}")
    return "; ".join(parts)


def nominal_span(entry: dict) -> tuple:
    """A family's nominal in robustness.json as (low, high): the off value twice, or a physics family's training range."""
    return (entry["nominal"], entry["nominal"]) if entry["nominal"] is not None else tuple(entry["training_range"])


def curve_parts(entry: dict, baseline: dict, key: str) -> tuple:
    """A family's points under one rule (``key``: hold_the_end or hold_the_end_authors) as the two lines a figure
    draws: the points outside the nominal joined through the unperturbed run at the nominal (a point, or both ends
    of a physics family's training range), and those inside the training range on their own (often none)."""
    low, high = nominal_span(entry)
    points = sorted(entry["points"], key=lambda p: p["magnitude"])
    below = [p for p in points if p["magnitude"] < low]
    above = [p for p in points if p["magnitude"] > high]
    inside = [p for p in points if low <= p["magnitude"] <= high]
    nominal = [{"magnitude": x, key: baseline[key], key + "_ci95": baseline[key + "_ci95"]} for x in sorted({low, high})]
    return below + nominal + above, inside


def figure_panels(count: int):
    """A figure of ``count`` family panels, four to a row: (figure, axes array, rows)."""
    import matplotlib  # noqa: PLC0415 (the figure only)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    columns = 4
    rows = max(1, math.ceil(count / columns))
    fig, axes = plt.subplots(rows, columns, figsize=(4.0 * columns, 2.9 * rows), squeeze=False)
    return fig, axes, rows


def decorate_panel(ax, name: str, entry: dict, magnitudes: Sequence, threshold: float) -> None:
    """A family's panel around its curves: the training range (or value), log x for a grid of factors with the
    grid's ticks, the threshold dashed, the axes' limits, title and labels."""
    import matplotlib.ticker  # noqa: PLC0415

    low, high = nominal_span(entry)
    if entry["training_range"]:
        if high > low:
            ax.axvspan(low, high, color="0.88", zorder=0, label="training range")
        else:
            ax.axvline(low, color="0.7", lw=1.0, zorder=0, label="training value")
    grid = sorted(set(magnitudes))
    every = grid + [low, high]
    if min(every) > 0 and max(every) / min(every) >= 20:  # a grid of factors: log x, its ticks
        ax.set_xscale("log")
        ax.set_xticks(grid, [f"{m:g}" for m in grid])
        ax.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())
    ax.axhline(threshold, color="0.3", lw=0.8, ls="--")
    ax.set_ylim(-0.03, 1.03)
    ax.set_title(name, fontsize=9)
    ax.set_xlabel(entry["unit"], fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(alpha=0.3)


def finish_figure(fig, axes, count: int, rows: int, title: str, path: Path) -> None:
    """The unused panels off, the y labels, one legend and the title above the panels; saved to ``path``."""
    import matplotlib.pyplot as plt  # noqa: PLC0415

    for ax in list(axes.flat)[count:]:
        ax.axis("off")
    for ax in axes[:, 0]:
        ax.set_ylabel("hold the end", fontsize=8)
    handles = {}
    for ax in axes.flat:
        for handle, label in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(label, handle)
    fig.legend(list(handles.values()), list(handles), loc="upper right", fontsize=8, ncol=len(handles))
    fig.suptitle(title, fontsize=10, x=0.01, ha="left")
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.45 / (2.9 * rows)))  # the title and the legend above the panels
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot(summary: dict, path: Path) -> None:
    """hold the end against magnitude, one panel per family, both rules with 95% bands, the threshold, the baseline."""
    names = list(summary["families"])
    fig, axes, rows = figure_panels(len(names))
    base = summary["baseline"]
    colours = {"paper": "tab:blue", "authors": "tab:orange"}
    for ax, name in zip(axes.flat, names):
        entry = summary["families"][name]
        points = sorted(entry["points"], key=lambda p: p["magnitude"])
        # the unperturbed run sits at the nominal: a point (0, 1 for a gain, a physics family's one training value)
        # or, for a physics family drawn from a range, a segment over that range
        low, high = nominal_span(entry)
        for rule, key in (("paper", "hold_the_end"), ("authors", "hold_the_end_authors")):
            outside, inside = curve_parts(entry, base, key)
            for part in (outside, inside):
                if not part:
                    continue
                x = [p["magnitude"] for p in part]
                ax.plot(
                    x,
                    [p[key] for p in part],
                    "-",
                    color=colours[rule],
                    lw=1.2,
                    label=f"{rule} rule" if part is not inside else None,
                )
                ax.fill_between(
                    x,
                    [p[key + "_ci95"][0] for p in part],
                    [p[key + "_ci95"][1] for p in part],
                    color=colours[rule],
                    alpha=0.15,
                    lw=0,
                )
            ax.plot([p["magnitude"] for p in points], [p[key] for p in points], "o", ms=3, color=colours[rule])
            ax.plot([low], [base[key]], "s", ms=4, color=colours[rule], mfc="white")
        decorate_panel(ax, name, entry, [p["magnitude"] for p in points], summary["threshold"])
    title = (
        f"{summary['policy']}: hold the end under perturbation, one family at a time ({summary['episodes']} "
        f"episodes per point, seeds {summary['seed']}..{summary['seed'] + summary['episodes'] - 1}, 95% "
        f"intervals; open square: unperturbed; dashed: {summary['threshold']:.0%})"
    )
    finish_figure(fig, axes, len(names), rows, title, path)


def parse_grid(items: Sequence[str]) -> dict:
    """--grid NAME=M1,M2,... (repeatable) -> {name: (magnitudes, ...)}; ValueError in one line."""
    grids = {}
    for item in items:
        name, sep, values = item.partition("=")
        if not sep or not values.strip():
            raise ValueError(f"--grid: expected NAME=M1,M2,..., got {item!r}")
        f = registry.family(name.strip())
        magnitudes = []
        for value in values.split(","):
            m = f.check(value.strip())
            if isinstance(m, tuple):
                raise ValueError(f"--grid {f.name}: one magnitude per entry, got {value!r}")
            magnitudes.append(m)
        grids[f.name] = tuple(sorted(set(magnitudes)))
    return grids


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineErrorParser(prog="dlo-robustness", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--checkpoint", type=checkpoint_argument, help=CHECKPOINT_HELP + " (default: shipped, the shipped All policy)"
    )
    parser.add_argument(
        "--name",
        help="the policy's directory under --out (default: shipped for the shipped All policy, shipped_NAME for "
        "shipped:NAME, else the run dir's name)",
    )
    parser.add_argument(
        "--family",
        action="append",
        default=[],
        metavar="NAME",
        help="evaluate this family (repeatable; default: every family of the registry, "
        "python -m dlo_policy.perturbations lists them)",
    )
    parser.add_argument(
        "--grid",
        action="append",
        default=[],
        metavar="NAME=M1,M2,...",
        help="the magnitudes of a family instead of its registry grid (repeatable)",
    )
    parser.add_argument("--episodes", type=int, default=100, help="episodes per point (default 100)")
    parser.add_argument(
        "--seed",
        type=int,
        default=DEFAULT_SEED,
        help=f"first episode seed (default {DEFAULT_SEED}: held out from training, evaluation and "
        "the shipped policy's selection)",
    )
    parser.add_argument("--num-envs", type=int, default=10, help="environments stepped together (default 10)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    parser.add_argument(
        "--threshold",
        type=float,
        default=THRESHOLD,
        help=f"hold the end below this is beyond the tolerance (default {THRESHOLD})",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=Path("results/robustness"),
        help="parent of the policy's directory (default results/robustness)",
    )
    parser.add_argument(
        "--quiet",
        action="store_true",
        help="no progress (by default a bar on a terminal, else a plain line every tenth of the episodes, on stderr)",
    )
    return parser


def _shipped_of(checkpoint: Path) -> Optional[str]:
    """The name of the shipped policy ``checkpoint`` is, None if it is none."""
    from .rundir import shipped_names, shipped_policy_path  # noqa: PLC0415

    return next((n for n in shipped_names() if shipped_policy_path(n).resolve() == checkpoint.resolve()), None)


def _policy_name(args, checkpoint: Path, shipped: Optional[str]) -> str:
    from .rundir import SHIPPED_DEFAULT, SHIPPED_SPEC  # noqa: PLC0415

    if args.name:
        return args.name
    if shipped is not None:
        return SHIPPED_SPEC if shipped == SHIPPED_DEFAULT else f"{SHIPPED_SPEC}_{shipped}"
    return checkpoint.resolve().parent.name


@console_main("dlo-robustness")
def main(argv: Optional[Sequence[str]] = None) -> int:
    if (sys.argv[1:] if argv is None else list(argv))[:1] == ["compare"]:
        from .robustness_compare import main as compare  # noqa: PLC0415

        return compare((sys.argv[1:] if argv is None else list(argv))[1:])
    args = build_parser().parse_args(argv)
    prog = "dlo-robustness: error:"
    if args.episodes < 1 or args.num_envs < 1 or args.threads < 1:
        print(f"{prog} --episodes, --num-envs and --threads must be >= 1", file=sys.stderr)
        return 2
    if args.seed < 0 or not 0 < args.threshold <= 1:
        print(f"{prog} --seed must be >= 0 and --threshold in (0, 1]", file=sys.stderr)
        return 2
    if args.name is not None and (not args.name or "/" in args.name or args.name in (".", "..")):
        print(f"{prog} --name must be a plain directory name, got {args.name!r}", file=sys.stderr)
        return 2
    try:
        grids = parse_grid(args.grid)
        chosen = [registry.family(name).name for name in args.family] or list(registry.names())
        chosen += [name for name in grids if name not in chosen]
    except ValueError as error:
        print(f"{prog} {error}", file=sys.stderr)
        return 2
    families = {name: grids.get(name, registry.family(name).grid) for name in registry.names() if name in chosen}

    from .rundir import POLICY_FILE, SHIPPED_DIR, shipped_policy_path  # noqa: PLC0415

    checkpoint = args.checkpoint or shipped_policy_path()
    if not checkpoint.is_file():
        print(f"{prog} checkpoint {checkpoint} does not exist", file=sys.stderr)
        return 2
    import dataclasses  # noqa: PLC0415

    import torch  # noqa: PLC0415

    from .config import make_env  # noqa: PLC0415
    from .evaluate import evaluate_agent, load_run_config  # noqa: PLC0415
    from .sac import SAC, CheckpointError  # noqa: PLC0415

    try:
        agent = SAC.load(checkpoint)
        config = load_run_config(checkpoint)
    except (FileNotFoundError, ValueError, CheckpointError) as error:
        print(f"{prog} {error}", file=sys.stderr)
        return 2
    torch.set_num_threads(args.threads)
    shipped = _shipped_of(checkpoint)
    name = _policy_name(args, checkpoint, shipped)
    # a shipped policy by its place in the package (the installed copy's path is this machine's)
    shown_checkpoint = f"shipped: dlo_policy/{SHIPPED_DIR}/{shipped}/{POLICY_FILE}" if shipped else str(checkpoint)
    out = args.out / name
    settings = {
        "checkpoint_sha256": file_sha256(checkpoint),
        "episodes": args.episodes,
        "seed": args.seed,
        "num_envs": args.num_envs,
    }
    wanted = [(None, None)] + [(family, m) for family, grid in families.items() for m in grid]
    done = {}
    try:
        for family, m in wanted:
            point = read_point(point_path(out, family, m), settings)
            if point is not None:
                done[(family, m)] = point
    except ValueError as error:
        print(f"{prog} {error}", file=sys.stderr)
        return 2
    todo = [key for key in wanted if key not in done]
    with Progress(len(todo) * args.episodes, "dlo-robustness", "episode", enabled=not args.quiet) as bar:
        if done:
            bar.write(f"dlo-robustness: {len(done)} of {len(wanted)} points read from {out / POINTS_DIR}; {len(todo)} to run")
        for family, m in todo:
            label = "baseline" if family is None else f"{family}={magnitude_text(m)}"
            bar.set_status(label)
            options = dict(config.env_options)
            options["perturbations"] = {} if family is None else {family: m}
            run_config = dataclasses.replace(config, env_options=options)
            vec_env = make_env(run_config, min(args.num_envs, args.episodes), seed=args.seed)
            try:
                result = evaluate_agent(agent, vec_env, args.seed, args.episodes, progress=bar.update)
            finally:
                vec_env.close()
            point = {
                **result.to_json(),
                "family": family,
                "magnitude": m,
                **settings,
                "checkpoint": shown_checkpoint,
                "env_options": options,
            }
            write_json(point_path(out, family, m), point)
            done[(family, m)] = point
    header = {
        "policy": name,
        "checkpoint": shown_checkpoint,
        **settings,
        "modalities": config.modalities,
        "env_options": dict(config.env_options),
        "command": "dlo-robustness " + " ".join(sys.argv[1:] if argv is None else list(argv)),
    }
    points = {key: value for key, value in done.items() if key[0] is not None}
    summary = summarise(points, done[(None, None)], families, header, args.threshold)
    write_json(out / SUMMARY_FILE, summary)
    plot(summary, out / FIGURE_FILE)
    print(f"{'family':<24} {'unit':<20} {'tolerance, paper rule':<32} tolerance, authors' rule")
    for family_name, entry in summary["families"].items():
        f = registry.family(family_name)
        print(
            f"{family_name:<24} {f.unit:<20} {tolerance_text(f, entry['tolerance']['paper'], families[family_name]):<32} "
            f"{tolerance_text(f, entry['tolerance']['authors'], families[family_name])}"
        )
    print(
        json.dumps(
            {
                "out": str(out),
                "points": len(wanted),
                "run": len(todo),
                "read": len(wanted) - len(todo),
                "baseline": {
                    "paper": summary["baseline"]["hold_the_end"],
                    "authors": summary["baseline"]["hold_the_end_authors"],
                },
                "tolerance": {n: e["tolerance"] for n, e in summary["families"].items()},
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
