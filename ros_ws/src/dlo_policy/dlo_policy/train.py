"""Train one SAC agent with the paper's protocol: `dlo-train`.

    dlo-train --modalities V+K --seed 3 --steps 50000 --out runs/V+K/seed3 [--config FILE] [key=value ...]
    dlo-train --out runs/V+K/seed3 --resume          # continue from the last checkpoint

Every `train.eval_every` env steps (and at step 0) the agent is evaluated with deterministic
actions on `train.eval_episodes` FRESH episodes: evaluation k (k = step / eval_every) uses seeds
`eval_seeds(config, k)` = eval_seed + 100,000 seed + k eval_episodes + i, so no two evaluations of
a run (nor of runs with other seeds) share an episode, and the same run reproduces them (every
tested input set of one evaluation sees the same episodes). Each evaluation appends a row to
`eval.csv` per tested input set (all inputs, then each of `train.eval_without`):

    step             env steps taken when evaluated
    tested_without   '' (all inputs), or the modality blanked for this row (ablation)
    episodes         evaluation episodes
    eval_seed        seed of the evaluation's first episode (the others follow it)
    hold_the_end, stop_before, reach_end_but_drop, drop_before   outcome fractions (sum to 1),
                     paper-text rule (dlo_interface.task)
    hold_the_end_authors, stop_before_authors, reach_end_but_drop_authors, drop_before_authors
                     the same under the authors'-code rule (dlo_interface.task)
    episode_reward   mean undiscounted episode reward
    time_at_end      mean steps spent at the end of the cable
    how_far          mean how-far-it-goes metric reported by the env
    train_episodes   training episodes finished so far
    wall_time_s      training seconds so far (across resumes)
    alpha, entropy, q_value, saturated   learner health (SAC.diagnostics, on 1,024 replay samples
                     drawn with a generator of their own: logging does not change the run)

After the last step, the best evaluation's policy (best_policy.pt: highest hold-the-end
fraction under the run's own task rules' outcome rule -- `hold_the_end_authors` for `authors_code`,
`hold_the_end` for `paper_text` -- then reward; best.json names it in "selected_by"; a run started from another's
checkpoint chooses among its evaluations after step 0) is tested once
on `train.test_episodes` held-out episodes, seeds `train.test_seed + i` (below every evaluation seed:
never seen during training or selection): test.json (dlo-evaluate's JSON; also test_without_X.json
for each of `train.eval_without`).
The paper reports the best evaluation during training; the held-out test is the unbiased number.

The run directory also holds config.yaml (resolved config), checkpoint.pt (everything, replay
buffer included, at the first episode end after every `train.checkpoint_every` steps; 0, the default: a
tenth of the run's steps, between 100 and 5,000, recorded in config.yaml), policy.pt (actor only, at the end) and
done.json (completion marker with a summary; "sources": the git commit of every part of the run,
{"commit", "dirty", "from_step"}, one per start or resume, "source" the first; dlo-experiments skips
runs that have it).

Ctrl-C (SIGINT) or SIGTERM stops the run at the end of the current episode (at most the env's horizon
of steps: an evaluation under way finishes first) with a checkpoint there, says `interrupted at step N;
resume with: dlo-train --out OUT --resume` on stderr and exits 130; the resumed run is the uninterrupted
one, number for number. A second Ctrl-C stops at once (the last checkpoint stays). `--resume` says
`resuming from step N` on stderr. stdout carries only the JSON summary at the end (done.json's).

Progress (stderr; `--no-progress` or train.progress=false: none): a bar on a terminal; elsewhere (a log
file) a line at every tenth of the run and at least every 5 minutes. Both show the last evaluation:
its reward and hold-the-end fraction under the paper-text rule and under the authors' rule.

TensorBoard (`tensorboard --logdir runs`): tb/ in the run directory holds event files with, against
env steps: train/episode_return and train/episode_length per training episode; loss/critic,
loss/actor, loss/alpha and speed/steps_per_s averaged over every TB_EVERY steps; every evaluation's
columns (eval/..., eval_without_T/... for the ablation): both rules' outcome fractions, reward,
time at end, how far, and the learner health (alpha, entropy, q_value, saturated); with
`env_options.randomise`, randomised/<family> per training episode. Logging changes nothing in the run (no
random draws); a resumed run appends to the same directory.

Domain randomisation (`env_options.randomise`, e.g. `env_options.randomise=observation_delay=0:2,friction=0.02:1.2`;
`dlo_policy.perturbations`): only the training env draws each episode's magnitudes (from the episode's seed:
a resumed run draws the same); evaluations and the held-out test run without it, on the paper's task.
`env_options.randomise_draw=one` draws one of its observation, action and camera families per episode (or none)
instead of all of them (`all`, the default). The ranges and the draw are in config.yaml, and randomised.csv has one
row per training episode: the env step it ended at, its index and seed, and each randomised family's magnitude (a
family a `one` draw did not choose: its off value).

Fine-tuning (`train.init_from=RUN/checkpoint.pt`, a full checkpoint of a run with the same modalities, observation
size, action box, network sizes and observation scaling): the agent starts from that run's networks, target
critics, temperature, optimiser states and observation scaling, at that run's policy; its steps, replay buffer and
random draws are its own (from step 0 and its seed), and it acts with the policy it took from its first step (no
uniform actions before `sac.learning_starts`; updates still start there, on its own transitions). init_from.json
records the file (path, sha256) and its step, seed and modalities. Anything else about it is a one-line error.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib
import json
import math
import os
import shlex
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Optional, Sequence

import numpy as np
from dlo_common import taichi_runtime
from dlo_common.console import EXIT_INTERRUPTED, Progress, console_main
from dlo_interface.task import DEFAULT_TASK_RULES, LEGACY_TASK_RULES, task_rules

from . import rundir
from .cli import check_override_keys
from .config import ConfigError, RunConfig, check_env_options, load_config, make_env, record_task_rules, save_config
from .modalities import ALL_NAME
from .modalities import names as modality_names
from .rundir import BEST_POLICY_FILE, CHECKPOINT_FILE, CONFIG_FILE, EVAL_FILE, POLICY_FILE, TB_DIR, EvalLog

if TYPE_CHECKING:
    from .sac import SAC, StepResult

# torch and the learner are imported when first needed (a wrong key=value is answered before they load);
# train.SAC, train.torch, ... still name them
_LAZY = {
    "torch": ("torch", None),
    "SAC": (".sac", "SAC"),
    "StepResult": (".sac", "StepResult"),
    "resolve_device": (".sac", "resolve_device"),
    "blanked_columns": (".evaluate", "blanked_columns"),
}


def __getattr__(name: str) -> Any:
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    module, attribute = _LAZY[name]
    loaded = importlib.import_module(module, __package__)
    return loaded if attribute is None else getattr(loaded, attribute)


def evaluate_agent(*args: Any, **kwargs: Any) -> Any:
    """dlo_policy.evaluate.evaluate_agent (what the evaluations and the held-out test call, by this name)."""
    from .evaluate import evaluate_agent as evaluate  # noqa: PLC0415 (torch: only when a run starts)

    return evaluate(*args, **kwargs)


EVAL_SEED_STRIDE = 100_000  # eval seeds of run seed s lie in eval_seed + [s, s + 1) * EVAL_SEED_STRIDE
TB_EVERY = 100  # TensorBoard: losses and speed averaged over this many steps
CHECKPOINT_EVERY_MAX = 5000  # train.checkpoint_every 0 (the default): a tenth of the run,
CHECKPOINT_EVERY_MIN = 100  # between these two (default_checkpoint_every)


def source_commit() -> dict[str, Any]:
    """The git commit of the code this process runs ({"commit": sha, "dirty": bool}; "unknown" outside a
    git checkout): what a run records in done.json, so that a study does not drift with the code under it."""
    here = Path(__file__).resolve().parent
    try:
        sha = subprocess.run(
            ["git", "-C", str(here), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10, check=True
        ).stdout.strip()
        top = subprocess.run(
            ["git", "-C", str(here), "rev-parse", "--show-toplevel"], capture_output=True, text=True, timeout=10, check=True
        ).stdout.strip()
        dirty = (
            subprocess.run(
                ["git", "-C", top, "status", "--porcelain", "--untracked-files=no", "--", "ros_ws/src"],
                capture_output=True,
                text=True,
                timeout=10,
                check=True,
            ).stdout.strip()
            != ""
        )
    except (OSError, subprocess.SubprocessError):
        return {"commit": "unknown", "dirty": None}
    return {"commit": sha, "dirty": dirty}


def available_cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def set_threads(num_threads: int) -> int:
    """torch intra-op threads (0: every core this process may use); returns the number set."""
    import torch  # noqa: PLC0415

    threads = num_threads or available_cores()
    torch.set_num_threads(threads)
    return threads


def eval_seeds(config: RunConfig, evaluation: int) -> int:
    """First episode seed of the run's `evaluation`-th evaluation (0 = the one at step 0)."""
    stride = config.train.eval_episodes
    if (evaluation + 1) * stride > EVAL_SEED_STRIDE:
        raise ValueError(f"evaluation {evaluation}: more than {EVAL_SEED_STRIDE} evaluation episodes in one run")
    return config.train.eval_seed + EVAL_SEED_STRIDE * config.seed + evaluation * stride


def default_checkpoint_every(total_steps: int) -> int:
    """train.checkpoint_every of a run that leaves it 0 (the default): a tenth of its steps, at least
    CHECKPOINT_EVERY_MIN, at most CHECKPOINT_EVERY_MAX, so that a short run (1,500 steps: every 150) has
    checkpoints to resume from too; a copy of config/sac_default.yaml keeps that default."""
    return min(CHECKPOINT_EVERY_MAX, max(CHECKPOINT_EVERY_MIN, math.ceil(total_steps / 10)))


def resolve_checkpoint_every(config: RunConfig) -> RunConfig:
    """``config`` with train.checkpoint_every 0 (the default) replaced by default_checkpoint_every of its steps
    (in place): what the run uses and records in config.yaml."""
    if config.train.checkpoint_every == 0:
        config.train.checkpoint_every = default_checkpoint_every(config.train.total_steps)
    return config


class TrainingInterrupted(Exception):
    """The run stopped on SIGINT / SIGTERM; `step`: the step of its checkpoint (None: none was written)."""

    def __init__(self, step: Optional[int]):
        super().__init__(f"interrupted at step {step}" if step is not None else "interrupted before its first step")
        self.step = step


class StopSignals:
    """SIGINT (Ctrl-C) and SIGTERM while a run trains: the first one asks it to stop at the end of the current
    episode, with a checkpoint there (`requested`); a second one, or any while `immediate`, raises
    KeyboardInterrupt at once (the last checkpoint stays). Installed (a context manager) in the main thread
    only, and only for a signal that is not ignored: dlo-experiments' local runs ignore SIGINT (their driver
    stops them with SIGTERM), so do runs started under nohup."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.signum: Optional[int] = None
        self.immediate = False
        self._previous: dict[int, Any] = {}

    @property
    def requested(self) -> bool:
        return self.signum is not None

    def __enter__(self) -> "StopSignals":
        if threading.current_thread() is threading.main_thread():
            for signum in self.SIGNALS:
                if signal.getsignal(signum) is not signal.SIG_IGN:
                    self._previous[signum] = signal.signal(signum, self._handle)
        return self

    def __exit__(self, *exc: Any) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, signal.SIG_DFL if handler is None else handler)
        self._previous.clear()

    def _handle(self, signum: int, frame: Any) -> None:
        if self.immediate or self.signum is not None:
            raise KeyboardInterrupt
        self.signum = signum


class Trainer:
    """Runs `SAC.learn` with periodic evaluation, CSV logging, checkpoints and a progress display.
    `stop`: the signals that stop it at an episode boundary (StopSignals; default: none installed)."""

    def __init__(self, config: RunConfig, out_dir: Path, resume: bool = False, stop: Optional[StopSignals] = None):
        from .evaluate import blanked_columns  # noqa: PLC0415 (torch: only when a run starts)
        from .sac import SAC, resolve_device  # noqa: PLC0415

        self.config, self.out_dir = config, out_dir
        self.stop = stop if stop is not None else StopSignals()
        self.checkpoint_step: Optional[int] = None  # the step of checkpoint.pt as this run last wrote / read it
        checkpoint = out_dir / CHECKPOINT_FILE
        if resume and not checkpoint.exists():
            raise FileNotFoundError(f"--resume: no {checkpoint} to resume from")
        if not resume and (checkpoint.exists() or (out_dir / EVAL_FILE).exists()):
            raise FileExistsError(f"{out_dir} already holds a run: pass --resume or choose another --out")
        out_dir.mkdir(parents=True, exist_ok=True)
        # the task rules are always recorded: a new run's are the default, an older run resumed keeps paper_text
        config = resolve_checkpoint_every(record_task_rules(config, LEGACY_TASK_RULES if resume else DEFAULT_TASK_RULES))
        self.config = config
        # best_policy.pt is chosen by the outcome rule of the run's own task rules (module docstring)
        recorded = config.env_options.get("task_rules")  # recorded for the cable env (other envs: the paper rule)
        self.selected_by = task_rules(recorded).outcome_key if recorded else "hold_the_end"
        save_config(config, out_dir / CONFIG_FILE)
        self.threads = set_threads(config.train.num_threads)
        self.device = resolve_device(config.train.device)
        taichi_runtime.select(config.train.sim_arch)

        self.env = make_env(config, training=True)
        self.eval_env = make_env(config, config.train.eval_episodes, seed=config.train.eval_seed)
        self.best: Optional[dict[str, Any]] = None
        self.best_policy_state: Optional[dict[str, Any]] = None
        if resume:
            self.agent = SAC.load(checkpoint, device=self.device)
            self.checkpoint_step = self.agent.num_env_steps
            print(f"dlo-train: resuming from step {self.checkpoint_step} ({checkpoint})", file=sys.stderr)
            extra = SAC.extra_state(checkpoint)
            self.best, self.best_policy_state = extra.get("best"), extra.get("best_policy")
            self.sources = list(extra.get("sources", []))
            if self.agent.num_env_steps == 0:  # stopped before its first step: the evaluation at step 0 runs again
                self.best = self.best_policy_state = None
            if self.best is not None:
                self.write_best()  # rewind: evaluations after the checkpoint are re-run
        else:
            space = self.env.action_space
            self.agent = SAC(
                self.env.observation_space.shape[0],
                space.low,
                space.high,
                config.sac,
                seed=config.seed,
                observation_low=self.env.observation_space.low,
                observation_high=self.env.observation_space.high,
                device=self.device,
            )
            if config.train.init_from:
                self.start_from(Path(config.train.init_from))
        # an agent started from another acts with its policy from the first step (SAC.initialise_from), resumed too
        self.agent.uniform_warmup = not config.train.init_from
        self.log = EvalLog(out_dir, self.agent.num_env_steps if resume and self.agent.num_env_steps else None)
        self.tested = [("", [])] + [(m, blanked_columns(config.modalities, [m])) for m in config.train.eval_without]
        # the code each part of the run ran on (done.json "sources": one entry per start or resume)
        self.sources = (self.sources if resume else []) + [{**source_commit(), "from_step": self.agent.num_env_steps}]
        self.started = time.perf_counter()
        self.last_eval: dict[str, float] = {}
        self.checkpoint_due = False
        self.episode_return = 0.0
        self.recent_returns: list[float] = []  # the last 10 training episodes' returns, for the progress bar
        self.tb = TensorBoardLog(out_dir / TB_DIR)
        self.episode_length = 0
        ranges = getattr(self.env, "randomise", None) or getattr(getattr(self.env, "vec", None), "randomise", None)
        self.randomised_log = (
            rundir.RandomisedLog(out_dir, list(ranges), self.agent.num_env_steps if resume else None) if ranges else None
        )

    def start_from(self, checkpoint: Path) -> None:
        """train.init_from: the agent takes that checkpoint's networks (SAC.initialise_from); init_from.json records
        which file it was (path, sha256) and its step, seed and modalities. ConfigError (one line) for a file that
        is not a full checkpoint of an agent of this run's shape."""
        self.agent.note_modalities(self.env)
        try:
            taken = self.agent.initialise_from(checkpoint)
        except ValueError as error:
            raise ConfigError(f"train.init_from: {error}") from None
        digest = hashlib.sha256(checkpoint.read_bytes()).hexdigest()
        record = {"path": str(checkpoint.resolve()), "sha256": digest, **taken}
        record["modalities"] = "+".join(taken["modalities"]) if taken["modalities"] else None
        (self.out_dir / rundir.INIT_FILE).write_text(json.dumps(record, indent=1) + "\n")

    def wall_time(self) -> float:
        return self.log.wall_time_offset + time.perf_counter() - self.started

    def evaluate(self) -> None:
        rows = []
        first_seed = eval_seeds(self.config, self.agent.num_env_steps // self.config.train.eval_every)
        health = {key: round(value, 6) for key, value in self.agent.diagnostics(seed=self.agent.num_env_steps).items()}
        for without, columns in self.tested:
            result = evaluate_agent(self.agent, self.eval_env, first_seed, self.config.train.eval_episodes, columns)
            rows.append(
                {
                    "step": self.agent.num_env_steps,
                    "tested_without": without,
                    "eval_seed": first_seed,
                    **result.to_dict(),
                    "train_episodes": self.agent.num_episodes,
                    "wall_time_s": round(self.wall_time(), 2),
                    **health,
                }
            )
        self.log.append(rows)
        for row in rows:
            self.tb.evaluation(row)
        self.last_eval = rows[0]
        self.keep_if_best(rows[0])

    def keep_if_best(self, row: dict[str, Any]) -> None:
        """Save the policy as best_policy.pt when this evaluation beats every earlier one
        (higher hold-the-end fraction, then higher episode reward), like SB3's EvalCallback. A run started from
        another's checkpoint (train.init_from) chooses among its evaluations after step 0, which evaluates the
        policy it took: the first of them replaces step 0's whatever its score."""
        key = self.selected_by
        score = (row[key], row["episode_reward"])
        taken = self.config.train.init_from and self.best is not None and self.best["step"] == 0 < row["step"]
        if (
            self.best is not None
            and not taken
            and score <= (self.best.get(key, self.best["hold_the_end"]), self.best["episode_reward"])
        ):
            return
        self.best = {name: row[name] for name in ("step", "hold_the_end", "hold_the_end_authors", "episode_reward")}
        self.best["selected_by"] = key
        self.best_policy_state = self.agent.policy_state()
        self.write_best()

    def write_best(self) -> None:
        """best_policy.pt and best.json from the best evaluation so far."""
        import torch  # noqa: PLC0415

        torch.save(self.best_policy_state, self.out_dir / (BEST_POLICY_FILE + ".tmp"))
        os.replace(self.out_dir / (BEST_POLICY_FILE + ".tmp"), self.out_dir / BEST_POLICY_FILE)
        rundir.write_best(self.out_dir, self.best)

    def on_step(self, agent: SAC, result: StepResult) -> bool:
        self.episode_return += result.reward
        self.episode_length += 1
        step = agent.num_env_steps
        ended = result.terminated or result.truncated
        self.tb.step(step, result.losses)
        if ended:
            self.recent_returns = (self.recent_returns + [self.episode_return])[-10:]
            self.tb.episode(step, self.episode_return, self.episode_length)
            self.episode_return, self.episode_length = 0.0, 0
            if self.randomised_log is not None and result.info.get("randomised"):
                drawn = result.info["randomised"]
                self.randomised_log.append(step, agent.num_episodes - 1, int(result.info["episode_seed"]), drawn)
                self.tb.randomised(step, drawn)
        if step % self.config.train.eval_every == 0:
            self.evaluate()
            self.bar.set_status(progress_status(self.last_eval, self.recent_returns, agent.alpha))
        self.bar.update(1)  # after an evaluation at this step: its line shows it
        self.checkpoint_due |= step % self.config.train.checkpoint_every == 0
        if self.checkpoint_due and ended:
            self.save_checkpoint()
        if self.stop.requested and ended:  # SIGINT / SIGTERM: stop here, at an episode boundary, checkpointed
            if self.checkpoint_step != step:
                self.save_checkpoint()
            return False
        return True

    def save_checkpoint(self) -> None:
        """checkpoint.pt at an episode boundary (the next episode has not taken a step: a resumed run
        starts it from its seed exactly as the uninterrupted run does), with the best evaluation so
        far and its policy, so a resume rewinds best_policy.pt / best.json to this step too."""
        extra = {"best": self.best, "best_policy": self.best_policy_state, "sources": self.sources}
        self.agent.save(self.out_dir / CHECKPOINT_FILE, extra=extra)
        self.checkpoint_due = False
        self.checkpoint_step = self.agent.num_env_steps

    def test_best(self) -> dict[str, Any]:
        """Held-out test of best_policy.pt on train.test_episodes episodes (seeds train.test_seed + i);
        writes test.json (+ test_without_X.json) and returns the all-inputs result (dlo-evaluate JSON)."""
        from .sac import SAC  # noqa: PLC0415

        cfg = self.config.train
        best = SAC.load(self.out_dir / BEST_POLICY_FILE)
        # The evaluation env, reseeded: its simulator's kernels were compiled at the start of the run, so
        # the test runs the code the run trained on even if the source changed on disk meanwhile (Taichi
        # compiles a new simulator's kernels from the source files as they are then).
        env = self.eval_env
        results = {}
        bar = Progress(cfg.test_episodes * len(self.tested), f"{self.config.name} held-out test", "episode", enabled=cfg.progress)
        try:
            for without, columns in self.tested:
                bar.set_status(f"without {without}" if without else "all inputs")
                result = evaluate_agent(best, env, cfg.test_seed, cfg.test_episodes, columns, progress=bar.update).to_json()
                payload = {
                    **result,
                    "checkpoint": BEST_POLICY_FILE,
                    "seed": cfg.test_seed,
                    "without": [without] if without else [],
                    "modalities": self.config.modalities,
                    "env_steps": best.num_env_steps,
                }
                rundir.write_test(self.out_dir, without, payload)
                results[without] = payload
        finally:
            bar.close()
            env.close()
        return results[""]

    def run(self) -> dict[str, Any]:
        """Train to train.total_steps, test best_policy.pt, write done.json; its summary. TrainingInterrupted
        when `stop` was requested: checkpoint.pt is then at the step it names (an episode boundary)."""
        total = self.config.train.total_steps
        if self.agent.num_env_steps == 0 and not self.stop.requested:
            self.evaluate()
        self.bar = Progress(total, self.config.name, "step", initial=self.agent.num_env_steps, enabled=self.config.train.progress)
        try:
            if not self.stop.requested:
                self.agent.learn(self.env, total, callback=self.on_step)
        except BaseException:
            self.eval_env.close()
            raise
        finally:
            self.bar.close()
            self.tb.close()
            self.env.close()
        if self.stop.requested and self.agent.num_env_steps < total:
            if self.checkpoint_step != self.agent.num_env_steps:  # asked before the first step: a checkpoint there
                self.save_checkpoint()
            self.eval_env.close()
            raise TrainingInterrupted(self.checkpoint_step)
        self.save_checkpoint()
        self.agent.save_policy(self.out_dir / POLICY_FILE)
        if self.stop.requested:
            self.eval_env.close()
            raise TrainingInterrupted(self.checkpoint_step)
        self.stop.immediate = True  # the held-out test: nothing more to save, a signal stops it at once
        test = self.test_best()  # closes the evaluation env
        summary = {
            "env_steps": self.agent.num_env_steps,
            "updates": self.agent.num_updates,
            "episodes": self.agent.num_episodes,
            "wall_time_s": round(self.wall_time(), 2),
            "threads": self.threads,
            "last_eval": self.last_eval,
            "best_eval": self.best,
            "test": test,
            "source": self.sources[0],
            "sources": self.sources,
        }
        rundir.write_done(self.out_dir, summary)
        return summary


def progress_status(row: dict[str, Any], recent_returns: Sequence[float], alpha: float) -> str:
    """What the progress display says of the last evaluation `row`: the mean return of the last training
    episodes, the evaluation's reward and its hold-the-end fraction under both outcome rules, the temperature."""
    mean_return = float(np.mean(recent_returns)) if len(recent_returns) else math.nan
    return (
        f"train_return {mean_return:.2f}, eval_reward {row['episode_reward']:.2f}, hold_the_end "
        f"{row['hold_the_end']:.0%} paper rule / {row['hold_the_end_authors']:.0%} authors' rule, alpha {alpha:.3f}"
    )


class TensorBoardLog:
    """TensorBoard scalars of a run (module docstring); a one-line warning and no event files when the
    tensorboard package is missing."""

    LOSSES = {"critic_loss": "loss/critic", "actor_loss": "loss/actor", "alpha_loss": "loss/alpha"}
    EVAL_SKIP = {"step", "tested_without", "episodes", "eval_seed", "wall_time_s"}

    def __init__(self, directory: Path):
        try:
            from torch.utils.tensorboard import SummaryWriter
        except ImportError as error:  # tensorboard is in scripts/requirements.txt; a bare install may lack it
            print(f"dlo-train: warning: no TensorBoard event files ({error}); pip install tensorboard", file=sys.stderr)
            self.writer = None
        else:
            self.writer = SummaryWriter(str(directory))
        self.sums: dict[str, float] = {}
        self.counts: dict[str, int] = {}
        self.window_start = time.perf_counter()

    def step(self, step: int, losses: dict) -> None:
        for key, value in losses.items():
            self.sums[key] = self.sums.get(key, 0.0) + value
            self.counts[key] = self.counts.get(key, 0) + 1
        if self.writer is None or step % TB_EVERY:
            return
        for key, total in self.sums.items():
            self.writer.add_scalar(self.LOSSES.get(key, "loss/" + key), total / self.counts[key], step)
        now = time.perf_counter()
        self.writer.add_scalar("speed/steps_per_s", TB_EVERY / max(now - self.window_start, 1e-9), step)
        self.sums, self.counts, self.window_start = {}, {}, now

    def episode(self, step: int, episode_return: float, length: int) -> None:
        if self.writer is not None:
            self.writer.add_scalar("train/episode_return", episode_return, step)
            self.writer.add_scalar("train/episode_length", length, step)

    def randomised(self, step: int, magnitudes: dict) -> None:
        if self.writer is not None:
            for name, value in magnitudes.items():
                self.writer.add_scalar(f"randomised/{name}", value, step)

    def evaluation(self, row: dict[str, Any]) -> None:
        if self.writer is None:
            return
        prefix = f"eval_without_{row['tested_without']}" if row["tested_without"] else "eval"
        for key, value in row.items():
            if key not in self.EVAL_SKIP and isinstance(value, (int, float)) and np.isfinite(value):
                self.writer.add_scalar(f"{prefix}/{key}", value, row["step"])
        self.writer.flush()

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()


def check_devices(config: RunConfig) -> None:
    """ConfigError (one line) when train.device or train.sim_arch names hardware this machine lacks;
    starts Taichi on the asked backend (it falls back to the CPU silently otherwise)."""
    from .sac import resolve_device  # noqa: PLC0415

    try:
        resolve_device(config.train.device)
        taichi_runtime.init(config.train.sim_arch)
    except ValueError as error:
        raise ConfigError(str(error)) from None


def train(config: RunConfig, out_dir: str | Path, resume: bool = False) -> dict[str, Any]:
    """Train (or resume) a run in `out_dir`, holding its lock (rundir.lock), stopped by SIGINT / SIGTERM at an
    episode boundary (TrainingInterrupted; StopSignals); returns the done.json summary."""
    with rundir.lock(Path(out_dir)):
        return run_trainer(config, Path(out_dir), resume)


def run_trainer(config: RunConfig, out_dir: Path, resume: bool, make: Optional[type] = None) -> dict[str, Any]:
    """`make`(...).run() (default: Trainer) under StopSignals: TrainingInterrupted when a signal stopped it (a
    second signal too: then at the last checkpoint, or None before the run had one)."""
    with StopSignals() as stop:
        trainer = None
        try:
            trainer = (make or Trainer)(config, out_dir, resume, stop=stop)
            return trainer.run()
        except KeyboardInterrupt:
            raise TrainingInterrupted(
                getattr(trainer, "checkpoint_step", None) if trainer is not None else _checkpoint_step(out_dir)
            ) from None


def _checkpoint_step(out_dir: Path) -> Optional[int]:
    """The step of out_dir's checkpoint.pt, None without one."""
    if not (out_dir / CHECKPOINT_FILE).exists():
        return None
    from .sac import read_checkpoint  # noqa: PLC0415

    return int(read_checkpoint(out_dir / CHECKPOINT_FILE)["counters"]["env_steps"])


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="dlo-train",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="Overrides are key=value pairs on config keys (see config/sac_default.yaml), e.g.\n"
        "  sac.batch_size=256 train.eval_every=500 env_options.tactile_noise=partial",
    )
    parser.add_argument(
        "--modalities", help=f"{ALL_NAME}, or a '+'-joined subset of {', '.join(modality_names())} (e.g. V+K); default {ALL_NAME}"
    )
    parser.add_argument("--seed", type=int, help="run seed (default 0)")
    parser.add_argument("--steps", type=int, help="total env steps (default 50000)")
    parser.add_argument("--out", type=Path, required=True, help="run directory")
    parser.add_argument("--config", type=Path, help="YAML config (default: built-in defaults, see config/sac_default.yaml)")
    parser.add_argument("--label", help="experiment name used to group seeds in dlo-report")
    parser.add_argument(
        "--resume",
        action="store_true",
        help="continue the run in --out from its last checkpoint (its saved config; only --steps may change)",
    )
    parser.add_argument(
        "--no-progress", action="store_true", help="no progress display (a bar on a terminal, else a line every tenth of the run)"
    )
    parser.add_argument("overrides", nargs="*", metavar="key=value", help="config overrides")
    return parser


def resolve_config(args: argparse.Namespace) -> RunConfig:
    """Defaults < --config file (or the run's saved config on --resume) < overrides < flags."""
    if args.resume:
        if args.config or args.overrides or args.modalities or args.seed is not None or args.label:
            raise ConfigError("--resume uses the run's saved config; only --steps may be given")
        source: Optional[Path] = args.out / CONFIG_FILE
    else:
        check_override_keys(args.overrides)  # a typo answered at once, with the key it likely meant
        source = args.config
    flags = {
        "modalities": args.modalities,
        "seed": args.seed,
        "train.total_steps": args.steps,
        "label": args.label,
        "train.progress": False if args.no_progress else None,
    }
    config = load_config(source, args.overrides, {k: v for k, v in flags.items() if v is not None})
    return resolve_checkpoint_every(config)


def interrupted_line(stopped: TrainingInterrupted, out: Path) -> str:
    """The one line dlo-train ends with when a signal stopped it."""
    resume = f"resume with: dlo-train --out {shlex.quote(str(out))} --resume"
    if stopped.step is not None:
        return f"dlo-train: interrupted at step {stopped.step}; {resume}"
    return (
        f"dlo-train: interrupted before its first checkpoint: nothing to resume; remove {shlex.quote(str(out))} to start it again"
    )


@console_main("dlo-train")
def main(argv: Optional[Sequence[str]] = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        config = resolve_config(args)
        check_env_options(config)
        check_devices(config)
        steps, starts = config.train.total_steps, config.sac.learning_starts
        if steps <= starts:  # SAC.learn updates only after env step learning_starts
            print(
                f"dlo-train: warning: train.total_steps {steps} <= sac.learning_starts {starts}: no gradient "
                f"update will happen ({'the started policy' if config.train.init_from else 'random'} actions only); "
                f"pass e.g. sac.learning_starts={steps // 3} "
                f"or --steps above {starts}",
                file=sys.stderr,
            )
        summary = train(config, args.out, resume=args.resume)
    except (ConfigError, FileExistsError, FileNotFoundError, rundir.RunInUse) as error:
        print(f"dlo-train: error: {error}", file=sys.stderr)
        return 2
    except TrainingInterrupted as stopped:
        print(interrupted_line(stopped, args.out), file=sys.stderr)
        return EXIT_INTERRUPTED
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
