"""Print the outcome table of a graph run from the sim node's per-episode JSON lines.

    python -m dlo_tools.outcome_table OUTCOMES.jsonl
"""

from __future__ import annotations

import argparse
import json
import sys

from dlo_sim.task import OUTCOME_NAMES, OUTCOME_NONE

OUTCOMES = [name for code, name in sorted(OUTCOME_NAMES.items()) if code != OUTCOME_NONE]


def outcome_table(episodes) -> str:
    """Per-episode lines and the fraction of each outcome under both rules (paper text, authors'
    code: dlo_sim.task), as fixed-width text."""
    lines = [f"{'episode':>7} {'seed':>6}  {'outcome (paper rule)':<20} {'authors rule':<20} {'return':>8} "
             f"{'time at end':>11} {'from end':>8}"]
    for e in episodes:
        lines.append(f"{e['episode']:>7} {e['seed']:>6}  {e['outcome']:<20} {e.get('outcome_authors', '?'):<20} "
                     f"{e['episode_return']:>8.3f} {e['time_at_end']:>11} {e['how_far']:>8}")
    n = len(episodes)
    lines += ["", f"{'outcome':<20} {'paper rule':>16} {'authors rule':>16}"]
    for name in OUTCOMES:
        counts = [sum(e.get(key) == name for e in episodes) for key in ("outcome", "outcome_authors")]
        cells = [f"{c:>4}/{n:<4} {100.0 * c / max(n, 1):5.1f}%" for c in counts]
        lines.append(f"{name:<20} {cells[0]:>16} {cells[1]:>16}")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("outcomes", help="JSON-lines file written by sim_node's summary_file parameter")
    args = parser.parse_args(argv)
    try:
        with open(args.outcomes) as f:
            episodes = [json.loads(line) for line in f if line.strip()]
    except FileNotFoundError:
        print(f"no finished episodes ({args.outcomes} does not exist)", file=sys.stderr)
        return 1
    print(outcome_table(episodes))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
