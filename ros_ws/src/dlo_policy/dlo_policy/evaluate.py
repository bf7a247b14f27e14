"""Evaluation protocol: deterministic episodes on seeded environments -> outcome fractions + metrics.

`dlo-evaluate --checkpoint PATH --episodes N --seed S [--json FILE] [--without T|V|K]` loads a
checkpoint written by `dlo-train` (or a shipped policy: `--checkpoint shipped`, `shipped:NAME`), runs N
episodes with seeds S .. S+N-1 in a vector env built from the run's saved config, prints the outcome table
and optionally writes JSON.
`--without X` blanks modality X's observation entries (zeros) before the policy sees them: the
paper's ablation of an agent trained with all inputs. A progress bar over the episodes goes to stderr
when it is a terminal (`--progress` also elsewhere, as a plain line every tenth of the episodes; `--quiet`
turns it off); stdout carries only the table (a reader that stops early, `| head -3`, ends it quietly).

`dlo-evaluate --policy oracle|tactile_reactive|random ...` (instead of `--checkpoint`) runs a scripted
baseline of `dlo_policy.scripted` through the same protocol on the All-modalities environment
(`--task-rules` picks the task variant, default the env's; `--stop-before-end N` makes the oracle
stop once it holds particle n_c - 1 - N). Both outcome rules are reported in the table and the JSON.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

import numpy as np
import torch
from dlo_common.console import Progress, console_main
from dlo_interface.task import DEFAULT_TASK_RULES, TASK_RULES

from .cli import CHECKPOINT_HELP, OneLineErrorParser, checkpoint_argument
from .config import RunConfig, make_env
from .modalities import by_name, names, parse_modalities
from .rundir import AUTHORS_SUFFIX, CONFIG_FILE, OUTCOMES, read_trained_config
from .sac import SAC

SCRIPTED_POLICIES = ("oracle", "tactile_reactive", "random")  # dlo_policy.scripted, as the policy node names them
SCRIPTED_MODALITIES = "All"  # the environment of the scripted baselines (tactile_reactive reads K, T and V)


@dataclass
class EvalResult:
    """Means over `episodes` evaluation episodes (NaN where the env reports no such info)."""

    episodes: int
    hold_the_end: float  # outcome fractions, paper-text rule
    stop_before: float
    reach_end_but_drop: float
    drop_before: float
    hold_the_end_authors: float  # outcome fractions, authors'-code rule
    stop_before_authors: float
    reach_end_but_drop_authors: float
    drop_before_authors: float
    episode_reward: float  # undiscounted, unscaled sum of env rewards
    time_at_end: float  # steps spent holding one of the last particles
    how_far: float  # the env's how-far-it-goes metric

    def to_dict(self) -> dict[str, float]:
        return asdict(self)

    def to_json(self) -> dict[str, Any]:
        """dlo-evaluate's JSON: the paper-text rule at the top level, the authors' rule under "authors_code"."""
        values = self.to_dict()
        authors = {name: values.pop(name + AUTHORS_SUFFIX) for name in OUTCOMES}
        return {**values, "authors_code": authors}


def blanked_columns(modalities: str, without: Sequence[str]) -> list[int]:
    """Observation columns of the modalities in `without`, for an agent observing `modalities`."""
    columns, start = [], 0
    for modality in parse_modalities(modalities):
        size = by_name(modality).size
        if modality in without:
            columns += range(start, start + size)
        start += size
    missing = [m for m in without if m not in parse_modalities(modalities)]
    if missing:
        raise ValueError(f"cannot blank {missing}: the agent observes only {modalities}")
    return columns


def evaluate_agent(
    agent: SAC,
    vec_env: Any,
    first_seed: int,
    episodes: int,
    blank: Sequence[int] = (),
    progress: Optional[Callable[[int], Any]] = None,
) -> EvalResult:
    """One deterministic episode per seed first_seed .. first_seed + episodes - 1.

    Runs `vec_env.num_envs` episodes at a time: `reset(seed=s)` starts env i on seed s + i (the
    gymnasium and dlo_policy.env convention). `blank`: observation columns zeroed before acting.
    Outcomes come from the `info` of each env's first episode end (`outcome`, `outcome_authors`,
    `time_at_end`, `how_far`); later episodes of an env (auto-reset) are ignored. `progress(n)` is called
    with the number of counted episodes that just ended (e.g. a progress bar's update).
    """
    if hasattr(agent, "note_modalities"):  # the modalities the agent acts on, saved with its checkpoints
        agent.note_modalities(vec_env)
    n_envs = vec_env.num_envs
    rewards: list[float] = []
    ends: list[dict[str, Any]] = []
    for start in range(0, episodes, n_envs):
        wanted = min(n_envs, episodes - start)  # the other envs of the last batch run, ignored
        obs, _ = vec_env.reset(seed=first_seed + start)
        returns = np.zeros(n_envs)
        finished = np.zeros(n_envs, dtype=bool)
        batch_ends: list[dict[str, Any]] = [{} for _ in range(n_envs)]
        while not finished[:wanted].all():
            obs = np.array(obs, dtype=np.float32)
            obs[:, blank] = 0.0
            obs, reward, terminated, truncated, infos = vec_env.step(agent.predict(obs, deterministic=True))
            returns += np.where(finished, 0.0, reward)
            ended = np.flatnonzero((terminated | truncated) & ~finished)
            for i in ended:
                batch_ends[i] = _episode_end_info(infos, i)
            finished |= terminated | truncated
            if progress is not None and (ended < wanted).any():
                progress(int((ended < wanted).sum()))
        rewards += returns[:wanted].tolist()
        ends += batch_ends[:wanted]
    fractions = {**_fractions(ends, "outcome", ""), **_fractions(ends, "outcome_authors", AUTHORS_SUFFIX)}
    return EvalResult(
        episodes=episodes,
        **fractions,
        episode_reward=float(np.mean(rewards)),
        time_at_end=_mean_of(ends, "time_at_end"),
        how_far=_mean_of(ends, "how_far"),
    )


def _fractions(ends: list[dict[str, Any]], key: str, suffix: str) -> dict[str, float]:
    """Fraction of episodes per outcome name under info `key` (NaN if an episode lacks it)."""
    outcomes = [end.get(key) for end in ends]
    known = all(o is not None for o in outcomes)
    return {name + suffix: (float(np.mean([o == name for o in outcomes])) if known else math.nan) for name in OUTCOMES}


def _episode_end_info(infos: dict[str, Any], i: int) -> dict[str, Any]:
    """Env i's entries of a gymnasium vector-env info dict (keys with a `_key` mask that is set)."""
    end = {}
    for key, values in infos.items():
        mask = infos.get("_" + key)
        if not key.startswith("_") and (mask is None or mask[i]):
            end[key] = _python_value(values[i])
    return end


def _python_value(value: Any) -> Any:
    return value.item() if isinstance(value, np.generic) else value


def _mean_of(ends: list[dict[str, Any]], key: str) -> float:
    values = [end[key] for end in ends if key in end]
    return float(np.mean(values)) if len(values) == len(ends) and values else math.nan


def make_vec_env_for(config: RunConfig, num_envs: int, seed: int) -> Any:
    """The run's vector env (`config.make_env`); dlo-evaluate builds its env through this name."""
    return make_env(config, num_envs, seed=seed)


class ScriptedAgent:
    """A scripted policy of dlo_policy.scripted as `evaluate_agent`'s agent: `predict(obs)` is
    `policy(obs, env)` (the oracle reads the simulator's ground truth through `env`)."""

    num_env_steps = 0

    def __init__(self, policy: Any, vec_env: Any) -> None:
        self.policy, self.vec_env = policy, vec_env

    def predict(self, obs: np.ndarray, deterministic: bool = True) -> np.ndarray:
        return self.policy(obs, self.vec_env)


class _ResetsPolicy:
    """The vector env with one change: `reset` also clears the scripted policy's per-env memory, so
    every batch of episodes starts it afresh."""

    def __init__(self, vec_env: Any, policy: Any) -> None:
        self._env, self._policy = vec_env, policy

    def reset(self, **kwargs: Any) -> Any:
        self._policy.reset()
        return self._env.reset(**kwargs)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._env, name)


def scripted_policy(name: str, seed: int = 0, stop_before_end: Optional[int] = None) -> Any:
    """A fresh scripted policy by its `--policy` name (random is seeded with `seed`)."""
    from .scripted import OracleFollow, RandomPolicy, TactileReactive  # noqa: PLC0415

    if name == "oracle":
        return OracleFollow() if stop_before_end is None else OracleFollow(stop_before_end=stop_before_end)
    if name == "tactile_reactive":
        return TactileReactive()
    if name == "random":
        return RandomPolicy(seed=seed)
    raise ValueError(f"unknown scripted policy {name!r}: expected one of {', '.join(SCRIPTED_POLICIES)}")


def make_scripted_vec_env(num_envs: int, seed: int, task_rules: str) -> Any:
    """The All-modalities vector env the scripted baselines run on."""
    from .env import make_vec_env  # noqa: PLC0415

    return make_vec_env(num_envs, modalities=SCRIPTED_MODALITIES, seed=seed, task_rules=task_rules)


def load_run_config(checkpoint: Path) -> RunConfig:
    """The config.yaml written next to a checkpoint by dlo-train (runs from before task_rules existed
    were trained on the paper-text rules and read so)."""
    path = checkpoint.parent / CONFIG_FILE
    if not path.exists():
        raise FileNotFoundError(f"{path} not found: a checkpoint is read together with its run's {CONFIG_FILE}")
    return read_trained_config(checkpoint.parent)


def format_table(result: EvalResult) -> str:
    """Outcome fractions under both rules, then the metrics, as fixed-width text."""
    lines = [f"{'outcome':<20} {'paper rule':>10} {'authors rule':>12}", "-" * 44]
    lines += [f"{name:<20} {getattr(result, name):>10.1%} {getattr(result, name + AUTHORS_SUFFIX):>12.1%}" for name in OUTCOMES]
    lines += [
        "-" * 44,
        f"{'episodes':<20} {result.episodes:>10d}",
        f"{'episode reward':<20} {result.episode_reward:>10.3f}",
        f"{'time at end':<20} {result.time_at_end:>10.2f}",
        f"{'how far':<20} {result.how_far:>10.2f}",
    ]
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineErrorParser(prog="dlo-evaluate", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    what = parser.add_mutually_exclusive_group(required=True)
    what.add_argument("--checkpoint", type=checkpoint_argument, help=CHECKPOINT_HELP)
    what.add_argument(
        "--policy",
        choices=SCRIPTED_POLICIES,
        help="a scripted baseline instead of a checkpoint: oracle (ground truth), tactile_reactive "
        "(observations only, after She et al. 2021) or random (seeded with --seed)",
    )
    parser.add_argument(
        "--task-rules",
        choices=TASK_RULES,
        help=f"with --policy: the task variant (default {DEFAULT_TASK_RULES}); a checkpoint is "
        "evaluated under the rules of its run's config.yaml",
    )
    parser.add_argument(
        "--stop-before-end",
        type=int,
        metavar="N",
        help="with --policy oracle: stop once the largest held index reaches n_c - 1 - N (default 2; 9 = at particle n_c - 10)",
    )
    parser.add_argument("--episodes", type=int, default=100, help="number of episodes (default 100)")
    parser.add_argument("--seed", type=int, default=0, help="first episode seed (default 0)")
    parser.add_argument("--json", type=Path, help="also write the results to this JSON file")
    parser.add_argument(
        "--without", choices=names(), action="append", default=[], help="blank this modality's observations (repeatable)"
    )
    parser.add_argument("--num-envs", type=int, default=10, help="environments stepped together (default 10)")
    parser.add_argument("--threads", type=int, default=0, help="torch threads (default: all cores)")
    shown = parser.add_mutually_exclusive_group()
    shown.add_argument(
        "--progress",
        action="store_true",
        help="show the progress (stderr) even when stderr is not a terminal: a plain line every tenth of the episodes",
    )
    shown.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


@console_main("dlo-evaluate")
def main(argv: Optional[Sequence[str]] = None) -> int:
    args = build_parser().parse_args(argv)
    if args.episodes < 1 or args.num_envs < 1:
        print("dlo-evaluate: error: --episodes and --num-envs must be >= 1", file=sys.stderr)
        return 2
    problem = _option_problem(args)
    if problem:
        print(f"dlo-evaluate: error: {problem}", file=sys.stderr)
        return 2
    if args.threads:
        torch.set_num_threads(args.threads)
    if args.policy is not None:
        return _evaluate_scripted(args)
    try:
        agent = SAC.load(args.checkpoint)  # first: a missing or foreign file is named as such
        config = load_run_config(args.checkpoint)
        blank = blanked_columns(config.modalities, args.without)
    except (FileNotFoundError, ValueError) as error:
        print(f"dlo-evaluate: error: {error}", file=sys.stderr)
        return 2
    vec_env = make_vec_env_for(config, min(args.num_envs, args.episodes), seed=args.seed)
    result = _run(agent, vec_env, args, blank)
    title = f"{config.name}, seeds {args.seed}..{args.seed + args.episodes - 1}"
    _report(
        result,
        args,
        title,
        {
            "checkpoint": str(args.checkpoint),
            "policy": "sac",
            "seed": args.seed,
            "without": args.without,
            "modalities": config.modalities,
            "env_steps": agent.num_env_steps,
        },
    )
    return 0


def _option_problem(args: argparse.Namespace) -> Optional[str]:
    """Why the options do not fit together (None when they do)."""
    if args.checkpoint is not None and args.task_rules is not None:
        return "--task-rules is for --policy: a checkpoint is evaluated under its run's task rules"
    if args.stop_before_end is not None and args.policy != "oracle":
        return "--stop-before-end is for --policy oracle"
    if args.stop_before_end is not None and args.stop_before_end < 0:
        return f"--stop-before-end must be >= 0, got {args.stop_before_end}"
    return None


def _evaluate_scripted(args: argparse.Namespace) -> int:
    """dlo-evaluate --policy NAME: a scripted baseline through the same protocol, JSON and table."""
    rules = args.task_rules or DEFAULT_TASK_RULES
    try:
        blank = blanked_columns(SCRIPTED_MODALITIES, args.without)
    except ValueError as error:
        print(f"dlo-evaluate: error: {error}", file=sys.stderr)
        return 2
    policy = scripted_policy(args.policy, seed=args.seed, stop_before_end=args.stop_before_end)
    vec_env = make_scripted_vec_env(min(args.num_envs, args.episodes), seed=args.seed, task_rules=rules)
    result = _run(ScriptedAgent(policy, vec_env), _ResetsPolicy(vec_env, policy), args, blank)
    name = args.policy + (f" (stops {args.stop_before_end} before the end)" if args.stop_before_end is not None else "")
    title = f"scripted {name} on {SCRIPTED_MODALITIES}, task rules {rules}, seeds {args.seed}..{args.seed + args.episodes - 1}"
    details = {
        "policy": args.policy,
        "seed": args.seed,
        "without": args.without,
        "modalities": SCRIPTED_MODALITIES,
        "task_rules": rules,
    }
    if args.stop_before_end is not None:
        details["stop_before_end"] = args.stop_before_end
    _report(result, args, title, details)
    return 0


def _run(agent: Any, vec_env: Any, args: argparse.Namespace, blank: Sequence[int]) -> EvalResult:
    """`evaluate_agent` with the progress bar of the command line; the env is closed afterwards."""
    hidden = args.quiet or not (args.progress or sys.stderr.isatty())
    try:
        with Progress(args.episodes, "dlo-evaluate", "episode", enabled=not hidden) as bar:
            return evaluate_agent(agent, vec_env, args.seed, args.episodes, blank, progress=bar.update)
    finally:
        vec_env.close()


def _report(result: EvalResult, args: argparse.Namespace, title: str, details: dict[str, Any]) -> None:
    """The title and the table on stdout; with --json the results (both outcome rules) and `details`."""
    print(title + (f", without {'+'.join(args.without)}" if args.without else ""))
    print(format_table(result))
    if args.json:
        payload = {**result.to_json(), **details}
        args.json.write_text(json.dumps(payload, indent=2) + "\n")


if __name__ == "__main__":
    sys.exit(main())
