"""Bag analysis: recompute each episode's outcome and metrics from a recorded run, and plot it.

    dlo-analyze BAG [--plots DIR] [--json FILE] [--video DIR [--video-format gif]]

The per-step task inputs (held particle indices, n_c, L_c; the task rules and move spacing the episode ran
under) recorded on ``/dlo/task/state`` are fed through the same ``dlo_interface.task.EpisodeTracker`` the sim
node and the gym environment use, so the recomputed outcomes (paper-text rule, and the authors'-code rule from the recorded
``held_indices_authors``) must equal the recorded ones (a mismatch is reported and exits 1).
Plots (PNG, one per episode): the gripper path over the cable at the start and the end seen from
the top (fixed end and first step at the end marked), and over the control steps one axis per
unit: closure, angles [rad], offsets [mm], commanded velocities [m/s], reward (the observations are the plot
series of the registry's observation topics, ``dlo_common.topics``: a new unit gets an axis of its own); spans
where nothing changes are shaded. Videos (``--video``, :mod:`dlo_bag.video`): one MP4 (or GIF) per episode,
top camera + side view + signal strip, one frame per control step, real time by default; progress on
stderr (one line per finished video with its path and the time it took; on a terminal a bar too).

What drove the run is read from the bag too (:func:`policy_records`: the policy node's ``/dlo/policy/info``,
or its copy in the metadata): the policy, its checkpoint and sha256, the modalities and the task rules, grip and
env_options it was trained under. ``dlo-analyze`` prints it above the table (``policy: ...``), puts it into
every episode of ``--json`` and into the video titles; ``--policy TEXT`` overrides the titles' label (a bag
recorded before the policy node published it has none: its titles say "policy not recorded").

A bag without ``/dlo/task/state`` (recorded from a robot driver, not the sim) has no outcomes: it
says so in one line and exits 3. Exit status (the same table for every bag tool, ``dlo_bag.errors``):
0 analysed, 1 a recomputed outcome differs from the recorded one or the bag is damaged (run
dlo-bag-recover), 2 bad option, no such path or not a bag, 3 no task state.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
from dlo_common.console import console_main
from dlo_common.topics import plot_series_by_unit, select, topic
from dlo_interface.cloud import unpack_particles
from dlo_interface.task import DEFAULT_MOVE_SPACING, OUTCOME_NAMES, EpisodeTracker, recorded_task_rules
from dlo_perception.sync import stamp_to_ns

from dlo_bag.errors import EXIT_BAD_BAG, EXIT_NO_TASK_STATE, EXIT_USAGE, BagError, NotABagError
from dlo_bag.info import bag_info
from dlo_bag.outcome_table import outcome_table
from dlo_bag.reader import read_messages
from dlo_bag.recording import POLICY_KEY, POLICY_TOPIC

# What an episode is read from, {topic: stream} (the registry, dlo_common.topics): the topics of a control step that
# carry its episode and step (state, command, task), the observations (matched to a step by stamp) and the particle
# cloud (the cable in the top-view plots); a stream is named by its topic's key.
STEPPED = frozenset(t.key for t in select("state", "command", "task"))
TOPICS = {t.name: t.key for t in (*select("state", "command", "task", "observation"), topic("particles"))}


def read_run(path, extra: dict[str, str] | None = None) -> dict:
    """{episode: {stream: {step or stamp: message}}} from a bag; republished steps count once.

    ``extra``: more {topic: stream name} to read, matched to steps by stamp (e.g. the camera images
    for videos: ``{"/dlo/camera/image": "image"}``).
    """
    topics = {**TOPICS, **(extra or {})}
    episodes = defaultdict(lambda: defaultdict(dict))
    stamp_episode_step = {}
    for item in read_messages(path, topics=list(topics)):
        stream, msg = topics[item.topic], item.msg
        stamp = stamp_to_ns(msg.header.stamp)
        if stream in STEPPED:
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


def policy_records(path) -> list[dict]:
    """What drove the run: the policy records of a bag (``dlo_policy.policy_node.policy_record``, JSON on
    ``/dlo/policy/info``), distinct, in the order recorded; a bag part without the message (a later part of a split
    recording) has its copy in the metadata (``dlo_bag.recording.POLICY_KEY``). [] for a bag recorded without a
    policy node or before the record existed. A record that is not a JSON object is kept as ``{"policy": text}``."""
    texts = [str(item.msg.data) for item in read_messages(path, [POLICY_TOPIC])]
    if not texts:
        texts = [custom[POLICY_KEY] for custom in bag_info(path).custom_data if custom.get(POLICY_KEY)]
    records = []
    for text in texts:
        try:
            record = json.loads(text)
        except ValueError:
            record = None
        record = record if isinstance(record, dict) else {"policy": text}
        if record not in records:
            records.append(record)
    return records


# env_options a policy may be trained under, in the label's order, with the value that goes without saying (left out)
TRAINED_DEFAULTS = {"carry_law": "paper", "contact_radius": 0.004, "vision_source": "image", "move_spacing": 0.0}


def policy_label(record: dict) -> str:
    """One line naming a policy record, for titles and the ``policy:`` line: kind, checkpoint (run directory and
    file, ``shipped`` for the bundled one) with the start of its sha256, the modalities observed and ablated, and
    what it was trained under (task rules, grip, env_options that differ from the defaults), e.g.
    ``sac shipped all/policy.pt (sha256 e9d241f8) on K+T+V; trained authors_code, single-particle grip``."""
    text = str(record.get("policy") or "unknown policy")
    if record.get("train_out"):
        text += f" learning online into {record['train_out']}"
    elif record.get("checkpoint"):
        path = Path(str(record["checkpoint"]))
        text += f" {'shipped ' if record.get('shipped') else ''}{path.parent.name}/{path.name}"
        if record.get("sha256"):
            text += f" (sha256 {str(record['sha256'])[:8]})"
    if record.get("modalities"):
        text += f" on {record['modalities']}"
    if record.get("without"):
        text += f" without {record['without']}"
    trained = [str(record["task_rules"])] if record.get("task_rules") else []
    if record.get("single_particle_grip") is not None:
        trained.append("single-particle grip" if record["single_particle_grip"] else "finite grip")
    options = record.get("env_options") if isinstance(record.get("env_options"), dict) else {}
    trained += [
        f"{key} {options[key]}" for key, default in TRAINED_DEFAULTS.items() if key in options and options[key] != default
    ]
    return text + (f"; trained {', '.join(trained)}" if trained else "")


def recorded_policy(records: list) -> str | None:
    """The label of a bag's policy records (:func:`policy_label`; several: joined by ', then '), None for none."""
    return ", then ".join(policy_label(r) for r in records) or None


def recompute_episode(task_states: dict) -> dict:
    """Outcome and metrics of one episode from its TaskState messages {step: msg} (step 0 = reset)."""
    steps = sorted(task_states)
    if not steps or steps[0] != 0:
        raise ValueError("the episode's first step (0) is missing from the bag")
    final = next((s for s in steps if task_states[s].done), None)
    # An episode ends by a drop or at its horizon: the step the sim marked done is that horizon.
    rules = recorded_task_rules(getattr(task_states[0], "task_rules", "")).name  # bags from before the field too
    spacing = float(getattr(task_states[0], "move_spacing", DEFAULT_MOVE_SPACING))  # before the field: the cable's own
    tracker = EpisodeTracker(1, horizon=final if final else 10**9, task_rules=rules, move_spacing=spacing)

    def held_inputs(msg):
        """p_i, n_h, largest held index (paper-text held set), p_i and n_h of the authors' held set."""
        held = np.asarray(msg.held_indices, dtype=np.int64)
        held_authors = np.asarray(msg.held_indices_authors, dtype=np.int64)
        return (
            np.array([held.mean() if len(held) else -1.0]),
            np.array([len(held)]),
            np.array([held.max() if len(held) else -1]),
            np.array([held_authors.mean() if len(held_authors) else -1.0]),
            np.array([len(held_authors)]),
        )

    first = task_states[0]
    p_i, _, max_index, p_i_authors, _ = held_inputs(first)
    tracker.reset([0], p_i, max_index, np.array([first.num_particles]), p_i_authors)
    for step in steps[1 : final + 1 if final else None]:
        msg = task_states[step]
        p_i, n_h, max_index, p_i_authors, n_h_authors = held_inputs(msg)
        tracker.step(p_i, n_h, max_index, np.array([msg.num_particles]), np.array([msg.cable_length]), p_i_authors, n_h_authors)
    last = task_states[final if final else steps[-1]]
    summary = tracker.summary(0)
    summary.update(
        seed=int(first.seed),
        complete=final is not None,
        task_rules=rules,
        recorded_outcome=OUTCOME_NAMES[int(last.outcome)],
        recorded_outcome_authors=OUTCOME_NAMES[int(last.outcome_authors)],
        recorded_return=float(last.episode_return),
    )
    return summary


def episode_title(episode: int, summary: dict | None) -> str:
    """'episode E · seed S · return R' / 'outcome: X (paper rule) · Y (authors' rule)'."""
    summary = summary or {}
    head = f"episode {episode}  ·  seed {summary.get('seed', '?')}"
    if "episode_return" in summary:
        head += f"  ·  return {summary['episode_return']:.2f}"
    if summary.get("complete", True) and "outcome" in summary:
        tail = f"outcome: {summary['outcome']} (paper rule)  ·  {summary['outcome_authors']} (authors' rule)"
    else:
        tail = "unfinished in the bag: no outcome"
    return head + "\n" + tail


def plot_episode(episode: int, streams: dict, path: Path, summary: dict | None = None) -> None:
    """One PNG of :func:`episode_figure`."""
    episode_figure(episode, streams, summary).savefig(path, dpi=90, bbox_inches="tight")


def _plot_top_view(top, s, particles: dict) -> None:
    """The episode's top view: the cable at start and end, the gripper path, the fixed end and where the
    gripper first reached the end (both rules); legend outside the axes."""
    steps = s.steps
    fixed = None
    for step, style, label in (
        (min(particles, default=None), "-", "cable at start"),
        (max(particles, default=None), "--", "cable at end"),
    ):
        if step is not None:
            xyz, _held = unpack_particles(particles[step])
            top.plot(xyz[:, 0], xyz[:, 1], style, color="tab:orange", lw=2, label=f"{label} (step {step})")
            fixed = xyz[0] if fixed is None else fixed
    if len(steps):
        top.plot(s["x"], s["y"], ".-", color="tab:blue", ms=3, lw=1, label="gripper path")
        top.plot(s["x"][:1], s["y"][:1], "^", color="tab:blue", ms=8, label=f"gripper at step {steps[0]}")
    if fixed is not None:
        top.plot([fixed[0]], [fixed[1]], "s", color="k", ms=8, label="fixed end (particle 0)")
    for mark, marker, color, rule in (
        (s.first_at_end, "*", "tab:green", "paper rule"),
        (s.first_at_end_authors, "D", "tab:purple", "authors' rule"),
    ):
        if mark is not None:
            i = int(np.searchsorted(steps, mark))
            top.plot(
                [s["x"][i]],
                [s["y"][i]],
                marker,
                color=color,
                ms=11,
                ls="none",
                label=f"gripper when first at the end,\n{rule} (step {mark})",
            )
    top.set(xlabel="x [m]", ylabel="y [m]", title="top view (world frame)", aspect="equal")
    top.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False, borderaxespad=0)


# How the plots and the video strip show a unit of the observation topics' plot series (dlo_common.topics): its axis
# label and the scale from the SI unit; a series of any other unit gets an axis "[unit]" of its own
UNIT_AXES = {"rad": ("angle [rad]", 1.0), "m": ("offset [mm]", 1000.0), "N": ("force [N]", 1.0), "N m": ("torque [N m]", 1.0)}


def series_label(t, series) -> str:
    """The label of an observation topic's plot series wherever it is drawn (these plots, the video strip
    ``dlo_bag.video``, the Foxglove layout ``dlo_viz.foxglove_layout``): its name (theta as θ) and its topic's key,
    "θ_T tactile"."""
    return f"{series.name.replace('theta', 'θ')} {t.key}"


def unit_axis_label(unit: str) -> str:
    """The axis label of a unit of the observation series (:data:`UNIT_AXES`: "angle [rad]", "offset [mm]"; any
    other unit "[unit]")."""
    return UNIT_AXES.get(unit, (f"[{unit}]",))[0]


def observation_axes(s) -> dict:
    """{unit: [(legend, values, line style)]} of the observation topics' plot series (``dlo_common.topics``), in
    registry order, labelled by :func:`series_label` and scaled to the axis' unit (:data:`UNIT_AXES`); a unit none of
    whose series has a value in the bag is left out. The episode plots and the video strip draw these."""
    axes = {
        unit: [(series_label(t, series), UNIT_AXES.get(unit, ("", 1.0))[1] * s[series.name], {}) for t, series in pairs]
        for unit, pairs in plot_series_by_unit("observation").items()
    }
    return {unit: lines for unit, lines in axes.items() if any(np.isfinite(values).any() for _, values, _ in lines)}


def _signal_axes_spec(s) -> list:
    """The signals over the control steps, one axis per unit: [(y label, [(name, values, line style)])]; the
    observations' from the registry (:func:`observation_axes`: unitless ones with the closure)."""
    held_end = s["num_particles"] - 10
    observed = observation_axes(s)
    spec = [
        (
            "closure [-]",
            [("c_G measured", s["closure"], {}), ("c_G commanded", s["cmd_closure"], {"ls": "--"}), *observed.pop("-", [])],
        ),
        (
            "held particle\nindex [-]",
            [
                ("largest held", s["max_held_index"], {}),
                ("mean held (paper)", s["mean_held_index"], {"alpha": 0.8}),
                ("mean held (authors)", s["mean_held_index_authors"], {"ls": ":"}),
                ("end: n_c - 10", held_end, {"color": "k", "lw": 0.8, "ls": "--"}),
            ],
        ),
    ]
    spec += [(unit_axis_label(unit), lines) for unit, lines in observed.items()]
    return spec + [
        ("command\n[m/s]", [("v_x", s["cmd_vx"], {}), ("v_y", s["cmd_vy"], {})]),
        ("reward [-]", [("reward per step", s["reward"], {"drawstyle": "steps-mid"})]),
    ]


def _plot_signal_axis(ax, s, label: str, lines: list, spans: list) -> None:
    """One signal axis: its lines, the first-at-the-end marks, the still spans, its legend outside."""
    for name, values, style in lines:
        if np.isfinite(values).any():
            ax.plot(s.steps, values, label=name, **{"lw": 1.2, **style})
    ax.set_ylabel(label, fontsize=9)
    ax.tick_params(labelsize=8)
    for mark, color in ((s.first_at_end, "tab:green"), (s.first_at_end_authors, "tab:purple")):
        if mark is not None:
            ax.axvline(mark, color=color, ls=":", lw=1.2)
    for a, b in spans:
        ax.axvspan(a, b, color="0.85", zorder=0)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False, borderaxespad=0)


def _annotate_still_spans(ax, spans: list) -> None:
    for a, b in spans:
        ax.annotate(
            f"gripper still (no motion, constant closure): steps {a}-{b}",
            xy=((a + b) / 2, 0.5),
            xycoords=("data", "axes fraction"),
            ha="center",
            va="center",
            fontsize=8,
            color="0.3",
            bbox={"boxstyle": "round", "fc": "white", "ec": "0.7", "alpha": 0.8},
        )


def episode_figure(episode: int, streams: dict, summary: dict | None = None):
    """The episode plot (a matplotlib Figure): top view (cable at start and end, gripper path, fixed end,
    where the end was first reached) and, over the control steps, one axis per unit: closure [-], held
    particle index, angles [rad], offsets [mm] (and an axis for each other unit of the observation topics' plot
    series, dlo_common.topics), commanded velocity [m/s], reward [-]; legends outside the data. Matplotlib's
    constrained layout places the titles, tick labels and legends (no text overlaps another axis' tick labels,
    whatever the data's extent)."""
    from matplotlib.figure import Figure

    from dlo_bag.episode_series import episode_series, still_spans

    s = episode_series(episode, streams)
    steps = s.steps
    axes_spec = _signal_axes_spec(s)  # signals over the control steps: one axis per unit
    fig = Figure(figsize=(12.0, 13.5 * (2.2 + len(axes_spec)) / 8.2), dpi=90, layout="constrained")
    fig.suptitle(episode_title(episode, summary), fontsize=13)
    grid = fig.add_gridspec(1 + len(axes_spec), 1, height_ratios=[2.2] + [1] * len(axes_spec))
    _plot_top_view(fig.add_subplot(grid[0]), s, streams.get("particles", {}))

    spans = still_spans(s)
    axes = []
    for row, (label, lines) in enumerate(axes_spec):
        ax = fig.add_subplot(grid[row + 1], sharex=axes[0] if axes else None)
        _plot_signal_axis(ax, s, label, lines, spans)
        if row < len(axes_spec) - 1:
            ax.tick_params(labelbottom=False)
        axes.append(ax)
    axes[0].set_title(
        "signals over the episode (dotted: first step at the end, green = paper rule, "
        "purple = authors' rule; grey: gripper still)",
        fontsize=9,
    )
    _annotate_still_spans(axes[0], spans)
    axes[-1].set_xlabel("control step (0.08 s each)")
    fig.align_ylabels(axes)
    if len(steps):
        axes[-1].set_xlim(steps[0], max(steps[-1], steps[0] + 1))
    return fig


def write_videos(
    run: dict,
    summaries: dict,
    out: Path,
    *,
    fmt: str = "mp4",
    policy: str | None = None,
    speed: float = 1.0,
    width: int | None = None,
    log=None,
) -> list[dict]:
    """One video per episode of ``run`` into ``out`` (``episode_NNNN.mp4`` / ``.gif``).

    ``log``: a text stream for progress (dlo-analyze: stderr, so that stdout stays the table): a line
    naming the videos to come, then one line per finished video with its path, frames and the seconds
    it took; on a terminal also a progress bar over all the frames (tqdm, removed at the end)."""
    from dlo_bag.video import render_episode_video

    out.mkdir(parents=True, exist_ok=True)
    todo = [(episode, streams) for episode, streams in run.items() if "task" in streams]
    frames = sum(len(set(streams["task"]) | set(streams.get("gripper", {}))) for _, streams in todo)
    bar = None
    if log is not None and todo and getattr(log, "isatty", lambda: False)():
        from tqdm import tqdm

        bar = tqdm(total=frames, desc="videos", unit="frame", file=log, leave=False, dynamic_ncols=True)

    def say(line: str) -> None:
        if bar is not None:
            bar.write(line, file=log)
        elif log is not None:
            print(line, file=log, flush=True)

    say(f"dlo-analyze: rendering {len(todo)} video{'' if len(todo) == 1 else 's'} ({frames} frames) into {out}")
    written = []
    try:
        for k, (episode, streams) in enumerate(todo, 1):
            item = render_episode_video(
                episode,
                streams,
                summaries.get(episode, {}),
                out / f"episode_{episode:04d}.{fmt}",
                fmt=fmt,
                policy=policy,
                speed=speed,
                width=width,
                progress=bar.update if bar is not None else None,
            )
            written.append({"episode": int(episode), **item})
            say(
                f"dlo-analyze: video {k}/{len(todo)}: {item['path']} (episode {episode}, {item['frames']} frames "
                f"in {item['render_s']:.1f} s)"
            )
    finally:
        if bar is not None:
            bar.close()
    return written


class NoTaskState(ValueError):
    """The bag has no ``/dlo/task/state`` (a driver's bag: only the sim publishes the task state)."""

    def __init__(self, path, gripper_states: int = 0) -> None:
        super().__init__(
            f"{path} has no /dlo/task/state: a driver bag ({gripper_states} gripper states); outcomes "
            "need the task state (the sim publishes it)"
        )


def analyse(path, plots: Path | None = None, video: dict | None = None, records: list | None = None) -> list:
    """Per-episode recomputed summaries of a bag (optionally writing one plot and one video per
    episode; ``video``: keyword arguments of :func:`write_videos`, ``out`` included; its ``policy`` label
    defaults to the bag's own record). Each summary carries the bag's policy record (``policy``, the last one
    recorded; None without one; ``records``: :func:`policy_records` of the bag, read here when not given)."""
    run = read_run(path, extra={topic("image").name: "image"} if video else None)
    if not any("task" in streams for streams in run.values()):
        raise NoTaskState(path, sum(len(streams.get("gripper", {})) for streams in run.values()))
    records = policy_records(path) if records is None else records
    if video and not video.get("policy"):
        video = {**video, "policy": recorded_policy(records)}
    summaries = []
    for episode, streams in run.items():
        if "task" not in streams:
            continue
        summary = {"episode": int(episode), **recompute_episode(streams["task"]), "policy": records[-1] if records else None}
        summaries.append(summary)
        if plots is not None:
            plots.mkdir(parents=True, exist_ok=True)
            plot_episode(episode, streams, plots / f"episode_{episode:04d}.png", summary)
    if video:
        by_episode = {s["episode"]: s for s in summaries}
        for item in write_videos(run, by_episode, **video):
            by_episode[item["episode"]]["video"] = item["path"]
    return summaries


@console_main("dlo-analyze")
def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description="Recompute outcomes and metrics of a recorded dlo-vitac run "
        "with the shared task module, and plot its episodes.",
        epilog="Exit status: 0 analysed, 1 a recomputed outcome differs from the "
        "recorded one, 2 unreadable bag or bad option, 3 the bag has no "
        "/dlo/task/state (a driver bag: no outcomes to compute).",
    )
    parser.add_argument("bag", help="rosbag2 directory (MCAP) written by recorder_node")
    parser.add_argument("--plots", type=Path, help="write one PNG per episode into this directory")
    parser.add_argument("--json", type=Path, help="write the per-episode summaries to this JSON file")
    parser.add_argument(
        "--video",
        type=Path,
        metavar="DIR",
        help="write one video per episode into this directory (episode_NNNN.mp4): top camera, "
        "side view, closure/poses/reward strip; one frame per control step",
    )
    parser.add_argument("--video-format", choices=("mp4", "gif"), default="mp4", help="mp4 (H.264, default) or gif")
    parser.add_argument(
        "--video-speed",
        type=float,
        default=1.0,
        help="playback speed: 1.0 = real time (12.5 frames/s, default), 2.0 = twice as fast",
    )
    parser.add_argument(
        "--video-width", type=int, default=None, help="frame width in pixels (height = 3/4); default 960 (mp4), 480 (gif)"
    )
    parser.add_argument(
        "--policy",
        default=None,
        metavar="TEXT",
        help="label the video titles with TEXT instead of the policy the bag records (the policy "
        "node's /dlo/policy/info: checkpoint and sha256, modalities, the task rules and grip it "
        "was trained under); for a bag recorded before that, whose titles otherwise say "
        "'policy not recorded', e.g. 'sac (shipped)'",
    )
    args = parser.parse_args(argv)
    if args.video_speed <= 0:
        parser.error("--video-speed must be > 0")
    if args.video_width is not None and args.video_width < 160:
        parser.error("--video-width must be >= 160 pixels")
    video = None
    if args.video:
        video = {
            "out": args.video,
            "fmt": args.video_format,
            "policy": args.policy,
            "speed": args.video_speed,
            "width": args.video_width,
            "log": sys.stderr,
        }
    try:
        records = policy_records(args.bag)
        summaries = analyse(args.bag, args.plots, video, records)
    except NoTaskState as error:
        print(f"dlo-analyze: {error}", file=sys.stderr)
        return EXIT_NO_TASK_STATE
    except NotABagError as error:
        print(f"dlo-analyze: {error}", file=sys.stderr)
        return EXIT_USAGE
    except (BagError, ValueError, FileNotFoundError) as error:
        print(f"dlo-analyze: {error}", file=sys.stderr)
        return EXIT_BAD_BAG if isinstance(error, BagError) else EXIT_USAGE
    except RuntimeError as error:  # dlo_bag.video.VideoError: the encoder failed
        print(f"dlo-analyze: video: {error}", file=sys.stderr)
        return 2
    complete = [s for s in summaries if s["complete"]]
    if records:
        print(f"policy: {recorded_policy(records)}")
    print(outcome_table(complete))
    if len(complete) < len(summaries):
        print(f"({len(summaries) - len(complete)} episode(s) unfinished in the bag, not counted)")
    mismatched = [
        s
        for s in complete
        if s["outcome"] != s["recorded_outcome"]
        or s["outcome_authors"] != s["recorded_outcome_authors"]
        or abs(s["episode_return"] - s["recorded_return"]) > 1e-6
    ]
    for s in mismatched:
        print(
            f"MISMATCH episode {s['episode']}: recomputed {s['outcome']} / {s['outcome_authors']} "
            f"{s['episode_return']:.6f}, recorded {s['recorded_outcome']} / {s['recorded_outcome_authors']} "
            f"{s['recorded_return']:.6f} (paper rule / authors' rule, return)",
            file=sys.stderr,
        )
    if args.json:
        args.json.write_text(json.dumps(summaries, indent=1) + "\n")
    if args.plots:
        print(f"plots: {args.plots}/episode_*.png")
    if args.video:
        print(f"videos: {args.video}/episode_*.{args.video_format}")
    return EXIT_BAD_BAG if mismatched else 0


if __name__ == "__main__":
    raise SystemExit(main())
