"""Bag analysis: recompute each episode's outcome and metrics from a recorded run, and plot it.

    dlo-analyze BAG [--plots DIR] [--json FILE]

The per-step task inputs (held particle indices, n_c, L_c) recorded on ``/dlo/task/state`` are
fed through the same ``dlo_sim.task.EpisodeTracker`` the sim node and the gym environment use,
so the recomputed outcomes (paper-text rule, and the authors'-code rule from the recorded
``held_indices_authors``) must equal the recorded ones (a mismatch is reported and exits 1).
Plots (PNG, one per episode): the gripper path over the cable at the start and the end seen from
the top, and closure and the distilled tactile/visual poses over time.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from dlo_perception.cloud import unpack_particles
from dlo_perception.sync import stamp_to_ns
from dlo_sim.task import OUTCOME_NAMES, EpisodeTracker
from dlo_tools.bag import BagError, read_messages
from dlo_tools.outcome_table import outcome_table

TOPICS = {"/dlo/task/state": "task", "/dlo/gripper/state": "gripper", "/dlo/gripper/cmd": "command",
          "/dlo/tactile/pose": "tactile", "/dlo/vision/pose": "vision", "/dlo/rope/particles": "particles"}


def read_run(path) -> dict:
    """{episode: {stream: {step or stamp: message}}} from a bag; republished steps count once."""
    episodes = defaultdict(lambda: defaultdict(dict))
    stamp_episode_step = {}
    for item in read_messages(path, topics=list(TOPICS)):
        stream, msg = TOPICS[item.topic], item.msg
        stamp = stamp_to_ns(msg.header.stamp)
        if stream in ("task", "gripper", "command"):
            episodes[msg.episode][stream][msg.step] = msg
            stamp_episode_step[stamp] = (msg.episode, msg.step)
        else:
            episodes.setdefault("_by_stamp", defaultdict(dict))[stream][stamp] = msg
    by_stamp = episodes.pop("_by_stamp", {})
    for stream, messages in by_stamp.items():  # tactile/vision/particles carry no step: match by stamp
        for stamp, msg in messages.items():
            if stamp in stamp_episode_step:
                episode, step = stamp_episode_step[stamp]
                episodes[episode][stream][step] = msg
    return {e: dict(streams) for e, streams in sorted(episodes.items())}


def recompute_episode(task_states: dict) -> dict:
    """Outcome and metrics of one episode from its TaskState messages {step: msg} (step 0 = reset)."""
    steps = sorted(task_states)
    if not steps or steps[0] != 0:
        raise ValueError("the episode's first step (0) is missing from the bag")
    final = next((s for s in steps if task_states[s].done), None)
    # An episode ends by a drop or at its horizon: the step the sim marked done is that horizon.
    tracker = EpisodeTracker(1, horizon=final if final else 10**9)

    def held_inputs(msg):
        """p_i, n_h, largest held index (paper-text held set) and p_i of the authors' held set."""
        held = np.asarray(msg.held_indices, dtype=np.int64)
        held_authors = np.asarray(msg.held_indices_authors, dtype=np.int64)
        return (np.array([held.mean() if len(held) else -1.0]), np.array([len(held)]),
                np.array([held.max() if len(held) else -1]),
                np.array([held_authors.mean() if len(held_authors) else -1.0]))

    first = task_states[0]
    p_i, _, max_index, p_i_authors = held_inputs(first)
    tracker.reset([0], p_i, max_index, np.array([first.num_particles]), p_i_authors)
    for step in steps[1:final + 1 if final else None]:
        msg = task_states[step]
        p_i, n_h, max_index, p_i_authors = held_inputs(msg)
        tracker.step(p_i, n_h, max_index, np.array([msg.num_particles]), np.array([msg.cable_length]), p_i_authors)
    last = task_states[final if final else steps[-1]]
    summary = tracker.summary(0)
    summary.update(seed=int(first.seed), complete=final is not None,
                   recorded_outcome=OUTCOME_NAMES[int(last.outcome)],
                   recorded_outcome_authors=OUTCOME_NAMES[int(last.outcome_authors)],
                   recorded_return=float(last.episode_return))
    return summary


def plot_episode(episode: int, streams: dict, path: Path) -> None:
    """One PNG: top view (cable at start and end, gripper path) and signals over the steps."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (top, signals) = plt.subplots(1, 2, figsize=(11, 4.2))
    particles = streams.get("particles", {})
    for step, style, label in ((min(particles, default=None), "-", "cable at start"),
                               (max(particles, default=None), "--", "cable at end")):
        if step is not None:
            xyz, held = unpack_particles(particles[step])
            top.plot(xyz[:, 0], xyz[:, 1], style, color="tab:orange", lw=2, label=f"{label} (step {step})")
    gripper = streams.get("gripper", {})
    steps = sorted(gripper)
    if steps:
        path_xy = np.array([[gripper[s].x, gripper[s].y] for s in steps])
        top.plot(path_xy[:, 0], path_xy[:, 1], ".-", color="tab:blue", ms=3, label="gripper path")
    top.set(xlabel="x [m]", ylabel="y [m]", title=f"episode {episode}: top view", aspect="equal")
    top.legend(fontsize=8)
    series = {"closure c_G": [gripper[s].closure for s in steps]}
    tactile, vision = streams.get("tactile", {}), streams.get("vision", {})
    series["theta_T [rad]"] = [tactile[s].angle if s in tactile else np.nan for s in steps]
    series["y_T [cm]"] = [100 * tactile[s].y if s in tactile else np.nan for s in steps]
    series["q_V"] = [vision[s].confidence if s in vision else np.nan for s in steps]
    series["theta_V [rad]"] = [vision[s].angle if s in vision else np.nan for s in steps]
    for label, values in series.items():
        signals.plot(steps, values, label=label, lw=1.2)
    signals.set(xlabel="control step", title="closure and distilled poses")
    signals.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def analyse(path, plots: Path | None = None) -> list:
    """Per-episode recomputed summaries of a bag (optionally writing one plot per episode)."""
    run = read_run(path)
    summaries = []
    for episode, streams in run.items():
        if "task" not in streams:
            continue
        summary = {"episode": int(episode), **recompute_episode(streams["task"])}
        summaries.append(summary)
        if plots is not None:
            plots.mkdir(parents=True, exist_ok=True)
            plot_episode(episode, streams, plots / f"episode_{episode:04d}.png")
    return summaries


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="Recompute outcomes and metrics of a recorded dlo-vitac run "
                                                 "with the shared task module, and plot its episodes.")
    parser.add_argument("bag", help="rosbag2 directory (MCAP) written by recorder_node")
    parser.add_argument("--plots", type=Path, help="write one PNG per episode into this directory")
    parser.add_argument("--json", type=Path, help="write the per-episode summaries to this JSON file")
    args = parser.parse_args(argv)
    try:
        summaries = analyse(args.bag, args.plots)
    except (BagError, ValueError, FileNotFoundError) as error:
        print(f"dlo-analyze: {error}", file=sys.stderr)
        return 2
    complete = [s for s in summaries if s["complete"]]
    print(outcome_table(complete))
    if len(complete) < len(summaries):
        print(f"({len(summaries) - len(complete)} episode(s) unfinished in the bag, not counted)")
    mismatched = [s for s in complete if s["outcome"] != s["recorded_outcome"]
                  or s["outcome_authors"] != s["recorded_outcome_authors"]
                  or abs(s["episode_return"] - s["recorded_return"]) > 1e-6]
    for s in mismatched:
        print(f"MISMATCH episode {s['episode']}: recomputed {s['outcome']} / {s['outcome_authors']} "
              f"{s['episode_return']:.6f}, recorded {s['recorded_outcome']} / {s['recorded_outcome_authors']} "
              f"{s['recorded_return']:.6f} (paper rule / authors' rule, return)", file=sys.stderr)
    if args.json:
        args.json.write_text(json.dumps(summaries, indent=1) + "\n")
    if args.plots:
        print(f"plots: {args.plots}/episode_*.png")
    return 1 if mismatched else 0


if __name__ == "__main__":
    raise SystemExit(main())
