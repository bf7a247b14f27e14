"""The shipped policy's robustness envelope, as dlo-driver-check compares a driver with it. No rclpy.

``shipped_envelope.json`` beside this module is an extract of the committed envelope
(``results/robustness/shipped/robustness.json``, made by ``dlo-robustness``; docs/RESULTS.md#robustness-envelope):
for each perturbation family its unit, nominal and tolerance, the first magnitude going away from the nominal at
which the shipped policy holds the end in fewer than 80% of 100 held-out episodes, per outcome rule and side. It
ships inside the package, so an installed checker reads it without the repository; when it is missing the
checker still measures and says that it cannot compare.

    python -m dlo_driver_kit.envelope results/robustness/shipped/robustness.json          # write the extract
    python -m dlo_driver_kit.envelope results/robustness/shipped/robustness.json --check  # exit 1 if stale

(test_driver_check_envelope.py checks that the extract is the committed envelope's.)
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Optional

ENVELOPE_FILE = Path(__file__).resolve().with_name("shipped_envelope.json")
SOURCE = "results/robustness/shipped/robustness.json"  # where the extract comes from (the repository's record)
RULE_NAMES = {"paper": "paper rule", "authors": "authors' rule"}


def extract(summary: dict) -> dict:
    """The part of a robustness.json (dlo_policy.robustness) the checker needs."""
    return {
        "source": SOURCE,
        "policy": summary["policy"],
        "checkpoint_sha256": summary["checkpoint_sha256"],
        "episodes": summary["episodes"],
        "seed": summary["seed"],
        "threshold": summary["threshold"],
        "baseline": {key: summary["baseline"][key] for key in ("hold_the_end", "hold_the_end_authors")},
        "families": {
            name: {key: entry[key] for key in ("unit", "side", "nominal", "training_range", "tolerance")}
            for name, entry in summary["families"].items()
        },
    }


def load(path: Path = ENVELOPE_FILE) -> tuple[Optional[dict], str]:
    """(the envelope, '') or (None, why it cannot be read: one line)."""
    try:
        return json.loads(Path(path).read_text()), ""
    except FileNotFoundError:
        return None, f"the shipped policy's envelope is not installed ({Path(path).name} missing beside dlo_driver_kit)"
    except (OSError, ValueError) as error:
        return None, f"the shipped policy's envelope cannot be read ({Path(path).name}: {error})"


def tolerance(envelope: dict, family: str, side: str = "above") -> tuple[Optional[float], str]:
    """The family's tolerance on one side, the stricter of the two outcome rules, and the rule(s) it is from:
    (magnitude, 'both rules' / "authors' rule" / 'paper rule'); (None, '') where neither rule drops below 80% in
    the envelope's grid on that side."""
    found = {}
    for rule in RULE_NAMES:
        value = envelope["families"][family]["tolerance"][rule].get(side)
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            found[rule] = float(value)
    if not found:
        return None, ""
    stricter = min(found.values()) if side == "above" else max(found.values())
    rules = [rule for rule, value in found.items() if value == stricter]
    return stricter, "both rules" if len(rules) == 2 else RULE_NAMES[rules[0]]


def number(value: float, digits: int = 2) -> str:
    """A magnitude as a line shows it: 1 not 1.0, 0.16 not 0.160."""
    return f"{round(value, digits):g}"


def compare(envelope: Optional[dict], family: str, measured: float, text: str, unit: str, why: str = "") -> str:
    """One line: ``text`` (the measurement in words), then within or beyond the shipped policy's 80% tolerance of
    ``family`` (above its nominal; ``measured`` in the family's unit, ``unit`` its words), or why it cannot say."""
    if envelope is None:
        return f"{text}: not compared ({why})"
    limit, rules = tolerance(envelope, family, "above")
    if limit is None:
        return f"{text}: within the envelope (the shipped policy stays above 80% over its whole {family} grid)"
    verdict = "within" if measured < limit else "beyond"
    unit = unit.replace("steps", "step") if number(limit) == "1" else unit
    return (
        f"{text}: {verdict} the shipped policy's 80% tolerance of {' '.join(filter(None, (number(limit), unit)))} "
        f"({family}; below 80% from there, {rules})"
    )


def compare_gain(envelope: Optional[dict], measured: float, text: str, why: str = "") -> str:
    """The velocity gain against velocity_gain's tolerance on both sides of 1."""
    if envelope is None:
        return f"{text}: not compared ({why})"
    above, rules_above = tolerance(envelope, "velocity_gain", "above")
    below, rules_below = tolerance(envelope, "velocity_gain", "below")
    inside = (above is None or measured < above) and (below is None or measured > below)
    bounds = ", ".join(
        f"{number(limit)}x and {word} ({rules})"
        for word, limit, rules in (("slower", below, rules_below), ("faster", above, rules_above))
        if limit is not None
    )
    return f"{text}: {'within' if inside else 'beyond'} the shipped policy's 80% tolerance (velocity_gain; below 80% at {bounds})"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m dlo_driver_kit.envelope",
        description="Write (or --check) the shipped policy's envelope extract the driver checker reads, from a "
        "dlo-robustness summary.",
    )
    parser.add_argument("summary", type=Path, help=f"robustness.json (the shipped policy's: {SOURCE})")
    parser.add_argument("--check", action="store_true", help="exit 1 when the packaged extract differs, write nothing")
    args = parser.parse_args(argv)
    try:
        wanted = extract(json.loads(args.summary.read_text()))
    except (OSError, ValueError, KeyError) as error:
        print(f"python -m dlo_driver_kit.envelope: {args.summary}: not a robustness summary ({error})", file=sys.stderr)
        return 2
    text = json.dumps(wanted, indent=1, sort_keys=True) + "\n"
    if args.check:
        current = ENVELOPE_FILE.read_text() if ENVELOPE_FILE.exists() else ""
        if current != text:
            print(f"{ENVELOPE_FILE} is stale: rerun without --check", file=sys.stderr)
            return 1
        return 0
    ENVELOPE_FILE.write_text(text)
    print(ENVELOPE_FILE)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
