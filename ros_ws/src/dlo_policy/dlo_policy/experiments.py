"""The paper's experiment grid over N seeds: `dlo-experiments`.

    dlo-experiments --out results --seeds 3 --groups single,ablation [--steps 50000] [--jobs 2]
    dlo-experiments --out results --seeds 10 --ray-address auto     # same grid on a Ray cluster

Groups (paper, Results):
    single       T, K, V, All
    pairs        T+K, V+K, T+V
    ablation     All, evaluated every time also without T and without V, compared with the agents
                 trained without them (V+K, T+K)
    sensitivity  tactile noise none / partial / full with K (All) and without K (T+V), against no
                 tactile input (V+K, V); "none" is the env's default, so it reuses All and T+V
Runs are started seed by seed (all configurations of the first seed, then of the second, ...).
Each run trains into OUT/<label>/seed<k> (see dlo-train). A run whose directory has done.json is
skipped; one with a checkpoint resumes from it; so an interrupted grid continues where it stopped.
Runs go to local processes (`--jobs` x `--threads` <= cores: oversubscription costs ~4x) or, with
`--ray-address`, to an existing Ray cluster (`pip install ray`; OUT must be shared storage).

`--dry-run` lists the runs and estimates the wall time from a short calibration measured now, on
this machine, under its current load: `CALIBRATION_STEPS` SAC steps (env step + one gradient
update, the run's network, `--threads` threads) and one evaluation of the configuration with the
most expensive observation; per run  t = steps x t_step + evaluations x tested input sets x t_eval
(+ the held-out test), and the runs are packed onto `--jobs` workers longest first.
"""
from __future__ import annotations

import argparse
import concurrent.futures
import csv
import importlib
import math
import multiprocessing
import os
import re
import sys
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Sequence

from .config import ConfigError, RunConfig, check_env_options, load_config
from .train import CHECKPOINT_FILE, DONE_FILE, EVAL_FILE, available_cores, set_threads, train

GROUPS = ("single", "pairs", "ablation", "sensitivity")
TACTILE_NOISE_LEVELS = ("partial", "full")
SENSITIVITY_PAIRS = (("All", "V+K"), ("T+V", "V"))  # (with tactile, same without tactile): with K, without K


@dataclass(frozen=True)
class RunSpec:
    """One training run of the grid."""

    label: str
    modalities: str
    seed: int
    env_options: tuple[tuple[str, Any], ...] = ()
    eval_without: tuple[str, ...] = ()
    groups: tuple[str, ...] = field(default=(), compare=False)

    def directory(self, out_dir: Path) -> Path:
        return out_dir / re.sub(r"[^A-Za-z0-9+\-]+", "_", self.label) / f"seed{self.seed}"


def sensitivity_label(modalities: str, noise: str) -> str:
    return f"{modalities} tactile-{noise}"


def experiment_grid(groups: Sequence[str], seeds: Sequence[int]) -> list[RunSpec]:
    """The runs of `groups`, each configuration once (shared between groups) for every seed."""
    unknown = set(groups) - set(GROUPS)
    if unknown:
        raise ValueError(f"unknown group(s) {sorted(unknown)}; choose from {', '.join(GROUPS)}")
    configs: dict[str, dict[str, Any]] = {}

    def add(group: str, label: str, modalities: str, env_options=(), eval_without=()) -> None:
        entry = configs.setdefault(label, {"modalities": modalities, "env_options": tuple(env_options),
                                           "eval_without": (), "groups": ()})
        entry["eval_without"] = tuple(sorted(set(entry["eval_without"]) | set(eval_without)))
        entry["groups"] += (group,)

    if "single" in groups:
        for modalities in ("T", "K", "V", "All"):
            add("single", modalities, modalities)
    if "pairs" in groups:
        for modalities in ("T+K", "V+K", "T+V"):
            add("pairs", modalities, modalities)
    if "ablation" in groups:
        add("ablation", "All", "All", eval_without=("T", "V"))
        add("ablation", "V+K", "V+K")  # trained without T
        add("ablation", "T+K", "T+K")  # trained without V
    if "sensitivity" in groups:
        for modalities, no_tactile in SENSITIVITY_PAIRS:
            add("sensitivity", modalities, modalities)  # tactile noise "none" (the env's default)
            for noise in TACTILE_NOISE_LEVELS:
                add("sensitivity", sensitivity_label(modalities, noise), modalities,
                    env_options=(("tactile_noise", noise),))
            add("sensitivity", no_tactile, no_tactile)
    # seed-major: every configuration's first seed before any second one, so a grid that is
    # stopped part-way leaves the same number of finished seeds per configuration (+- 1)
    return [RunSpec(label, c["modalities"], seed, c["env_options"], c["eval_without"], c["groups"])
            for seed in seeds for label, c in configs.items()]


def run_config(spec: RunSpec, config_path: Optional[Path], overrides: Sequence[str], steps: Optional[int],
               threads: int) -> RunConfig:
    values: dict[str, Any] = {"modalities": spec.modalities, "seed": spec.seed, "label": spec.label,
                              "train.eval_without": list(spec.eval_without), "train.num_threads": threads,
                              "train.progress": False}
    values.update({f"env_options.{key}": value for key, value in spec.env_options})
    if steps is not None:
        values["train.total_steps"] = steps
    return load_config(config_path, overrides, values)


def run_status(run_dir: Path) -> str:
    if (run_dir / DONE_FILE).exists():
        return "done"
    return "partial" if (run_dir / CHECKPOINT_FILE).exists() else "todo"


def run_one(config_data: dict[str, Any], run_dir: str) -> dict[str, Any]:
    """Train one run in this process (resuming it if it has a checkpoint); output to train.log."""
    path = Path(run_dir)
    path.mkdir(parents=True, exist_ok=True)
    resume = (path / CHECKPOINT_FILE).exists()
    if not resume:
        (path / EVAL_FILE).unlink(missing_ok=True)  # evaluations of a run stopped before its first checkpoint
    with (path / "train.log").open("a") as log:
        os.dup2(log.fileno(), sys.stdout.fileno())
        os.dup2(log.fileno(), sys.stderr.fileno())
        return train(RunConfig.from_dict(config_data), path, resume=resume)


def _run_one_reporting(config_data: dict[str, Any], run_dir: str) -> tuple[str, Optional[str]]:
    try:
        run_one(config_data, run_dir)
        return run_dir, None
    except Exception:  # noqa: BLE001 (reported by the parent; the other runs go on)
        return run_dir, traceback.format_exc()


def run_local(tasks: list[tuple[dict[str, Any], str]], jobs: int) -> list[tuple[str, Optional[str]]]:
    """Each task in a fresh spawned process, `jobs` at a time."""
    context = multiprocessing.get_context("spawn")
    results = []
    with concurrent.futures.ProcessPoolExecutor(max_workers=jobs, mp_context=context,
                                                max_tasks_per_child=1) as pool:
        futures = [pool.submit(_run_one_reporting, config, run_dir) for config, run_dir in tasks]
        for future in concurrent.futures.as_completed(futures):
            results.append(future.result())
            _print_result(*results[-1], done=len(results), total=len(tasks))
    return results


def import_ray() -> Any:
    """Ray, imported only when asked for; a clear exit when it is not installed."""
    try:
        import ray  # noqa: PLC0415 (optional dependency)
    except ImportError:
        raise SystemExit("dlo-experiments: --ray-address needs Ray, which is not installed: pip install ray "
                         "(or leave out --ray-address to run local processes)") from None
    return ray


def run_ray(tasks: list[tuple[dict[str, Any], str]], address: str, threads: int) -> list[tuple[str, Optional[str]]]:
    """Each task as a Ray task reserving `threads` CPUs on an existing cluster."""
    ray = import_ray()
    ray.init(address=address)
    remote = ray.remote(num_cpus=threads)(_run_one_reporting)
    pending = [remote.remote(config, run_dir) for config, run_dir in tasks]
    results = []
    while pending:
        finished, pending = ray.wait(pending)
        results += ray.get(finished)
        _print_result(*results[-1], done=len(results), total=len(tasks))
    return results


CALIBRATION_STEPS = 120


@dataclass(frozen=True)
class Calibration:
    """Seconds per training step (env step + update) and per evaluation, measured here."""

    step_s: float
    eval_s: float

    def run_seconds(self, config: RunConfig, done_steps: int = 0) -> float:
        """Estimated seconds for the rest of a run (from `done_steps` on) incl. evaluations and the test."""
        cfg = config.train
        steps = max(cfg.total_steps - done_steps, 0)
        tested = 1 + len(cfg.eval_without)
        evaluations = steps // cfg.eval_every + (done_steps == 0)
        test_evaluations = math.ceil(cfg.test_episodes / cfg.eval_episodes)
        return steps * self.step_s + (evaluations + test_evaluations) * tested * self.eval_s


def calibrate(config: RunConfig, steps: int = CALIBRATION_STEPS) -> Calibration:
    """Time `steps` SAC steps (each with one update) and one evaluation of `config` in this process."""
    import dataclasses  # noqa: PLC0415
    import time  # noqa: PLC0415

    from .evaluate import evaluate_agent, make_vec_env_for  # noqa: PLC0415
    from .sac import SAC  # noqa: PLC0415

    set_threads(config.train.num_threads)
    env_module = importlib.import_module(config.env_module)
    env = env_module.make_env(modalities=config.modalities, seed=config.seed, **config.env_options)
    sac_config = dataclasses.replace(config.sac, learning_starts=config.sac.batch_size)
    agent = SAC(env.observation_space.shape[0], env.action_space.low, env.action_space.high, sac_config,
                seed=config.seed, observation_low=env.observation_space.low,
                observation_high=env.observation_space.high)
    agent.learn(env, sac_config.learning_starts + 5)  # fill a batch; first updates warm up
    start = time.perf_counter()
    agent.learn(env, agent.num_env_steps + steps)
    step_s = (time.perf_counter() - start) / steps
    env.close()
    vec_env = make_vec_env_for(config, config.train.eval_episodes, seed=config.train.eval_seed)
    evaluate_agent(agent, vec_env, config.train.eval_seed, vec_env.num_envs)  # warm-up (kernel compilation)
    start = time.perf_counter()
    evaluate_agent(agent, vec_env, config.train.eval_seed, config.train.eval_episodes)
    eval_s = time.perf_counter() - start
    vec_env.close()
    return Calibration(step_s, eval_s)


def done_steps(run_dir: Path) -> int:
    """Env steps a partial run has already taken (its last evaluation row), 0 if none."""
    try:
        with (run_dir / EVAL_FILE).open(newline="") as f:
            rows = list(csv.DictReader(f))
        return int(rows[-1]["step"]) if rows and (run_dir / CHECKPOINT_FILE).exists() else 0
    except (OSError, KeyError, ValueError):
        return 0


def makespan(durations: Sequence[float], jobs: int) -> float:
    """Wall time of running `durations` on `jobs` workers, longest first onto the least loaded."""
    loads = [0.0] * max(jobs, 1)
    for duration in sorted(durations, reverse=True):
        loads[loads.index(min(loads))] += duration
    return max(loads)


def estimate(specs: Sequence[RunSpec], configs: Sequence[RunConfig], statuses: Sequence[str], out: Path,
             jobs: int) -> str:
    """One paragraph: calibration and the estimated wall time of the runs still to do."""
    todo = [(spec, config) for spec, config, status in zip(specs, configs, statuses) if status != "done"]
    if not todo:
        return "estimate: nothing to run"
    # the most expensive observation: vision (rendering) if any run uses it, then the most inputs
    probe = max((config for _, config in todo),
                key=lambda c: ("V" in c.modalities or c.modalities == "All", len(c.modalities)))
    calibration = calibrate(probe)
    durations = [calibration.run_seconds(config, done_steps(spec.directory(out))) for spec, config in todo]
    wall = makespan(durations, jobs)
    return (f"estimate: {len(todo)} runs, {sum(durations) / 3600:.1f} run-hours, wall ~{_duration(wall)} on "
            f"{jobs} job(s) (calibrated now on {probe.modalities}: {1000 * calibration.step_s:.0f} ms per step "
            f"with its update, {calibration.eval_s:.1f} s per evaluation of {probe.train.eval_episodes} episodes; "
            f"other load on this machine is included)")


def _duration(seconds: float) -> str:
    return f"{seconds / 3600:.1f} h" if seconds >= 3600 else f"{seconds / 60:.0f} min"


def _print_result(run_dir: str, error: Optional[str], done: int, total: int) -> None:
    status = "ok" if error is None else f"FAILED\n{error}"
    print(f"[{done}/{total}] {run_dir}: {status}", flush=True)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="dlo-experiments", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="Overrides (key=value) apply to every run, e.g. train.eval_every=500.")
    parser.add_argument("--out", type=Path, required=True, help="results directory (one subdirectory per run)")
    parser.add_argument("--groups", default="single,pairs,ablation,sensitivity",
                        help=f"comma-separated subset of {','.join(GROUPS)} (default: all)")
    parser.add_argument("--labels", help="only these configuration labels (comma-separated), e.g. All,V,T,K")
    parser.add_argument("--seeds", type=int, default=3, help="seeds per configuration (default 3)")
    parser.add_argument("--first-seed", type=int, default=0, help="seeds are first-seed .. first-seed + seeds - 1")
    parser.add_argument("--steps", type=int, help="env steps per run (default: the config's, 50000)")
    parser.add_argument("--config", type=Path, help="YAML config for every run")
    parser.add_argument("--threads", type=int, default=1, help="torch threads per run (default 1)")
    parser.add_argument("--jobs", type=int, help="parallel local runs (default: cores // threads)")
    parser.add_argument("--ray-address", help="dispatch to this Ray cluster instead (e.g. auto, ray://host:10001)")
    parser.add_argument("--dry-run", action="store_true",
                        help="list the runs and their status, estimate the wall time (short calibration), run nothing")
    parser.add_argument("overrides", nargs="*", metavar="key=value", help="config overrides for every run")
    return parser


def main(argv: Optional[Sequence[str]] = None) -> int:
    args = build_parser().parse_args(argv)
    if args.ray_address:
        import_ray()
    cores = available_cores()
    jobs = args.jobs or max(1, cores // args.threads)
    if not args.ray_address and jobs * args.threads > cores:
        print(f"dlo-experiments: {jobs} jobs x {args.threads} threads > {cores} cores; "
              f"using {max(1, cores // args.threads)} jobs", file=sys.stderr)
        jobs = max(1, cores // args.threads)
    try:
        specs = experiment_grid([g.strip() for g in args.groups.split(",") if g.strip()],
                                range(args.first_seed, args.first_seed + args.seeds))
        if args.labels:
            wanted = {label.strip() for label in args.labels.split(",")}
            specs = [s for s in specs if s.label in wanted]
        configs = [run_config(s, args.config, args.overrides, args.steps, args.threads) for s in specs]
        for config in configs:
            check_env_options(config)
    except (ConfigError, ValueError) as error:
        print(f"dlo-experiments: error: {error}", file=sys.stderr)
        return 2
    statuses = [run_status(s.directory(args.out)) for s in specs]
    for spec, status in zip(specs, statuses):
        print(f"{status:8s} {spec.directory(args.out)}  ({', '.join(spec.groups)})")
    tasks = [(config.to_dict(), str(spec.directory(args.out)))
             for spec, config, status in zip(specs, configs, statuses) if status != "done"]
    print(f"{len(specs)} runs, {len(specs) - len(tasks)} done, {len(tasks)} to run", flush=True)
    if args.dry_run:
        print(estimate(specs, configs, statuses, args.out, 1 if args.ray_address else jobs), flush=True)
        return 0
    if not tasks:
        return 0
    if args.ray_address:
        results = run_ray(tasks, args.ray_address, args.threads)
    else:
        results = run_local(tasks, jobs)
    failed = [run_dir for run_dir, error in results if error is not None]
    if failed:
        print(f"{len(failed)} run(s) failed: {', '.join(failed)} (see their train.log)", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
