"""One recorded episode as arrays over its control steps, for plots and videos (no rclpy).

:func:`episode_series` turns the per-step messages of one episode (``dlo_bag.analysis.read_run``:
{stream: {step: message}}) into numpy arrays indexed like ``steps``: closure, commands, reward, held
particles, where the end was reached under both outcome rules (``dlo_interface.task.at_end`` /
``at_end_authors``, the functions the task itself uses) and every ``plot`` series of the observation topics
(``dlo_common.topics``: theta_T, y_T, q_V, theta_V, y_V, ..., under their names, in their SI units), so a
modality added there is plotted with no change here. A value a step lacks (e.g. no visual pose recorded) is NaN.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from operator import attrgetter

import numpy as np
from dlo_common.topics import select
from dlo_interface.task import at_end, at_end_authors


@dataclass
class EpisodeSeries:
    """Arrays over ``steps`` (control steps present in the bag, ascending)."""

    episode: int
    steps: np.ndarray
    values: dict[str, np.ndarray] = field(default_factory=dict)
    first_at_end: int | None = None  # first step at the end, paper rule (any of the last 10 held)
    first_at_end_authors: int | None = None  # first step at the end, authors' rule
    final_step: int | None = None  # the step the sim marked done

    def __getitem__(self, key: str) -> np.ndarray:
        return self.values[key]


def _get(stream: dict, steps, attr, dtype=float) -> np.ndarray:
    """Field ``attr`` (dotted for a nested one) of each step's message of ``stream``, NaN where a step has none."""
    get = attrgetter(attr)
    return np.array([get(stream[s]) if s in stream else np.nan for s in steps], dtype=dtype)


def episode_series(episode: int, streams: dict) -> EpisodeSeries:
    """The arrays of one episode (see the module docstring)."""
    task = streams.get("task", {})
    gripper = streams.get("gripper", {})
    steps = np.array(sorted(set(task) | set(gripper)), dtype=int)
    command = streams.get("command", {})
    v = {
        "x": _get(gripper, steps, "x"),
        "y": _get(gripper, steps, "y"),
        "z": _get(gripper, steps, "z"),
        "closure": _get(gripper, steps, "closure"),
        # the command answering step s acts between s and s + 1
        "cmd_vx": _get(command, steps, "vx"),
        "cmd_vy": _get(command, steps, "vy"),
        "cmd_closure": _get(command, steps, "closure"),
        **{series.name: _get(streams.get(t.key, {}), steps, series.field) for t in select("observation") for series in t.plot},
        "reward": _get(task, steps, "reward"),
        "return": _get(task, steps, "episode_return"),
        "n_held": _get(task, steps, "n_held"),
        "num_particles": _get(task, steps, "num_particles"),
        "mean_held_index": _get(task, steps, "mean_held_index"),
        "mean_held_index_authors": _get(task, steps, "mean_held_index_authors"),
    }
    v["max_held_index"] = np.array(
        [max(task[s].held_indices) if s in task and len(task[s].held_indices) else -1 for s in steps], dtype=float
    )
    n_c = v["num_particles"]
    known = ~np.isnan(n_c)
    end_paper = np.zeros(len(steps), bool)
    end_authors = np.zeros(len(steps), bool)
    end_paper[known] = at_end(v["max_held_index"][known].astype(int), n_c[known].astype(int))
    end_authors[known] = at_end_authors(v["mean_held_index_authors"][known], n_c[known].astype(int))
    v["at_end"], v["at_end_authors"] = end_paper, end_authors
    final = next((int(s) for s in steps if s in task and task[s].done), None)
    return EpisodeSeries(
        episode=int(episode),
        steps=steps,
        values=v,
        first_at_end=int(steps[end_paper][0]) if end_paper.any() else None,
        first_at_end_authors=int(steps[end_authors][0]) if end_authors.any() else None,
        final_step=final,
    )


def still_spans(
    series: EpisodeSeries, keys=("x", "y", "closure"), min_steps: int = 15, tol: float = 1e-5
) -> list[tuple[int, int]]:
    """Runs of at least ``min_steps`` consecutive steps over which none of ``keys`` changes by more
    than ``tol`` (default: the gripper stands still with a constant closure, so the robot does
    nothing): [(first step, last step)], for shading plots."""
    if len(series.steps) < 2:
        return []
    data = np.stack([np.nan_to_num(series[k], nan=0.0) for k in keys], axis=1)
    still = np.all(np.abs(np.diff(data, axis=0)) <= tol, axis=1)  # step i -> i + 1 unchanged
    spans, start = [], None
    for i, flag in enumerate(np.append(still, False)):
        if flag and start is None:
            start = i
        elif not flag and start is not None:
            if i - start >= min_steps:
                spans.append((int(series.steps[start]), int(series.steps[i])))
            start = None
    return spans
