"""Outcomes of a graph run from the sim node's per-episode JSON lines: the final table, the one-line
episode report the launcher streams while the graph runs, the header naming what produced them,
and the health notes read from the nodes' logs. Pure text processing (no rclpy). The launcher
(dlo_bringup.launcher) prints them; dlo-analyze prints the table for a bag.

Each JSON line is one finished episode as ``sim_node`` writes it (``summary_file``): episode, seed,
outcome and outcome_authors (dlo_interface.task, both rules), episode_return, episode_length [steps],
time_at_end [steps], how_far [particles].
"""

from __future__ import annotations

import json
import re

from dlo_interface.task import LEGACY_TASK_RULES, OUTCOME_NAMES, OUTCOME_NONE, recorded_task_rules
from dlo_perception.tactile import noise_label

OUTCOMES = [name for code, name in sorted(OUTCOME_NAMES.items()) if code != OUTCOME_NONE]
SHIPPED = "the shipped All policy"


def episode_row(e: dict) -> str:
    """One episode as a fixed-width row of the outcome table."""
    return (
        f"{e['episode']:>7} {e['seed']:>6}  {e['outcome']:<20} {e.get('outcome_authors', '?'):<20} "
        f"{e['episode_return']:>8.3f} {e['time_at_end']:>19} {e['how_far']:>8}"
    )


def episode_line(e: dict, done: int = 0, total: int = 0) -> str:
    """One finished episode as a line to stream while the graph runs (``done`` episodes finished so far of
    ``total``, 0 = unlimited): episode and seed, outcome under both rules, return, steps."""
    count = f"; {done}/{total or 'unlimited'} done" if done else ""
    steps = e.get("episode_length")
    return (
        f"episode {e['episode']} (seed {e['seed']}{count}): {e['outcome']}, authors' rule "
        f"{e.get('outcome_authors', '?')}; return {e['episode_return']:.3f}"
        + (f", {steps} steps" if steps is not None else "")
        + f", {e['how_far']} particles from the end"
    )


def outcome_table(episodes) -> str:
    """Per-episode lines and the fraction of each outcome under both rules (paper text, authors'
    code: dlo_interface.task), as fixed-width text."""
    lines = [
        f"{'episode':>7} {'seed':>6}  {'outcome (paper rule)':<20} {'authors rule':<20} {'return':>8} "
        f"{'time at end [steps]':>19} {'from end':>8}"
    ]
    lines += [episode_row(e) for e in episodes]
    n = len(episodes)
    lines += ["", f"{'outcome':<20} {'paper rule':>16} {'authors rule':>16}"]
    for name in OUTCOMES:
        counts = [sum(e.get(key) == name for e in episodes) for key in ("outcome", "outcome_authors")]
        cells = [f"{c:>4}/{n:<4} {100.0 * c / max(n, 1):5.1f}%" for c in counts]
        lines.append(f"{name:<20} {cells[0]:>16} {cells[1]:>16}")
    return "\n".join(lines)


def seed_ranges(seeds) -> str:
    """``[3, 4, 5, 9]`` -> ``'3..5, 9'``."""
    seeds, parts = sorted(set(int(s) for s in seeds)), []
    for s in seeds:
        if parts and s == parts[-1][1] + 1:
            parts[-1][1] = s
        else:
            parts.append([s, s])
    return ", ".join(f"{a}" if a == b else f"{a}..{b}" for a, b in parts) or "none"


def run_header(
    episodes,
    policy: str = "",
    checkpoint: str = "",
    without: str = "",
    tactile_noise="",
    mode: str = "",
    policy_line: str = "",
    train_out: str = "",
    perturbations: str = "",
) -> str:
    """What produced the outcomes: policy (and the modalities it observes, from the policy node's start-up
    line ``policy_line``, e.g. 'policy sac on T+K+V without T'), checkpoint, ablation, tactile noise (a
    setting as ``dlo_perception.tactile.noise_setting`` reads it, '' = none; named by ``noise_label``: a
    preset with its numbers, a custom pair as numbers), clock mode, the task rules and the grip (finite, or
    single-particle) the episodes ran under (from the episodes themselves), the robustness perturbations
    (``perturbations``: the launcher's setting, named only when one is on) and their seeds."""
    observes = re.search(r" on ([A-Za-z+]+)", policy_line or "")
    described = f"policy {policy or '?'}" + (f" observing {observes.group(1)}" if observes else "")
    if policy == "sac":
        source = f"checkpoint {checkpoint}" if checkpoint else f"checkpoint: {SHIPPED}"
        if train_out:
            source = f"learning online into {train_out}"
    else:
        source = "no checkpoint"
    ablation = f"ablation: without {without} (zeroed)" if without else "ablation: none"
    seeds = seed_ranges(e["seed"] for e in episodes)
    count = f"{len(episodes)} episode{'' if len(episodes) == 1 else 's'}"
    rules = sorted({recorded_task_rules(e.get("task_rules")).name for e in episodes})  # older files: the legacy rules
    grips = sorted({"single-particle" if e.get("single_particle_grip") else "finite" for e in episodes})  # older: finite
    noise = noise_label(tactile_noise) if tactile_noise not in ("", None) else "none"
    return (
        f"run: {described} ({source}); {ablation}; tactile noise: {noise}"
        + (f"; mode {mode}" if mode else "")
        + f"; task rules {', '.join(rules) or LEGACY_TASK_RULES}"
        + f"; grip {', '.join(grips) or 'finite'}"
        + (f"; perturbations {perturbations}" if perturbations else "")
        + f"; seeds {seeds} ({count})"
    )


# ---------------------------------------------------------------- node health from the logs
_MISSING_INPUT = re.compile(r"no ([a-z_, ]+) input after")
_SEVERITY = re.compile(r"^\[(WARN|ERROR|FATAL)\][^:]*\]: (.*)$")
_WAITING = re.compile(r"\]: (waiting for .*)$")


def health_notes(name: str, lines) -> list:
    """Short notes on a node's health from new lines of its log (rclpy's console format
    ``[SEVERITY] [time] [node]: text``): what it waits for (the last "waiting for ..." line), missing inputs
    of the policy (``policy: no tactile input``), and how many other warnings/errors, with the last one (e.g.
    the real_time sim's "no command for N s: is a policy running?")."""
    notes, missing, problems, waiting = [], [], [], None
    for line in lines:
        found = _WAITING.search(line)
        if found:
            waiting = found.group(1).strip()
            continue
        found = _MISSING_INPUT.search(line)
        if found:
            for key in found.group(1).split(","):
                if key.strip() and key.strip() not in missing:
                    missing.append(key.strip())
            continue
        severity = _SEVERITY.match(line.strip())
        if severity:
            problems.append(severity.group(2).strip())
    notes += [f"{name}: {waiting}"] if waiting else []
    notes += [f"{name}: no {' or '.join(missing)} input"] if missing else []
    if problems:
        last = problems[-1] if len(problems[-1]) <= 90 else problems[-1][:87] + "..."
        notes.append(f"{name}: {len(problems)} warning{'s' if len(problems) > 1 else ''} (last: {last})")
    return notes


def status_line(steps_per_s, sim_time_factor, done: int, total: int, alive: dict, notes) -> str:
    """The periodic health line: step rate, episodes done, nodes alive or dead, notes from the logs."""
    rate = "steps/s ?" if steps_per_s is None else f"{steps_per_s:.1f} steps/s"
    if steps_per_s is not None and sim_time_factor is not None:
        rate += f" (sim time x{sim_time_factor:.2f})"
    dead = [name for name, up in alive.items() if not up]
    nodes = f"nodes alive {len(alive) - len(dead)}/{len(alive)}" + (f" (dead: {', '.join(dead)})" if dead else "")
    return f"{rate}, {done}{'/' + str(total) if total else ''} episodes done, {nodes}" + (
        "; " + "; ".join(notes) if notes else "; no warnings"
    )


def read_episodes(path: str) -> list:
    with open(path) as f:
        return [json.loads(line) for line in f if line.strip()]
