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
Ours (only when named in --groups):
    robust       All with domain randomisation ("All robust": env_options.randomise = grid.ROBUST_RANGES,
                 each episode's delays, calibration, actuator, false detections and cable drawn from
                 ranges up to about twice the shipped policy's tolerances; docs/RESULTS.md#robustness-envelope),
                 one of its observation, action and camera families per episode (env_options.randomise_draw
                 = one; env_options.randomise_draw=all on the command line: every family at once, as before)
A run's config: the --config file, then its group's env_options, then the key=value overrides (so an override
changes a group's env option too), then the grid's own modalities, seed and label.
Runs are started seed by seed (all configurations of the first seed, then of the second, ...).
A run whose directory has done.json is skipped, so re-running the command (or adding `--resume`,
which says the same) continues an interrupted grid. Stopping the driver (Ctrl-C, SIGTERM, even SIGKILL)
stops its local runs, each at the end of its current episode with a checkpoint there (dlo-train's
Ctrl-C; the driver waits for them, a second Ctrl-C stops them at once), so the next start resumes
each where it stopped; it exits 130. A run directory is trained by one process at a time: a
second grid on the same --out reports those runs as in use instead of writing into them.

Local (default): each run trains in a fresh process into OUT/<label>/seed<k> (see dlo-train),
`--jobs` at a time (`--jobs` x `--threads` <= cores: oversubscription costs ~4x); a run with a
checkpoint there resumes from it.

Ray (`--ray-address HOST:PORT`, or `auto` on a cluster node): each run is a Ray task reserving
`--threads` CPUs on some node of an existing cluster. It trains in a temporary directory on that
node, sends its result files back (config.yaml, eval.csv, done.json, best.json, test*.json,
randomised.csv, policy.pt, best_policy.pt, train.log; not checkpoint.pt with its replay buffer) and the driver
writes them under OUT: no shared storage. A run whose worker or node is lost is started again from
its first step on another worker, at most `--retries` times; the report at the end names the
retried runs. A partial local run (checkpoint under OUT) also starts from its first step there.
Every node needs this code and its Python environment (`source scripts/env.sh`; README, Cluster).

Each finished run's done.json records where and how long it ran: "node" (the Ray node id, or
"local"), "host", "duration_s" (wall seconds of the execution that finished it: set-up,
training, evaluations, held-out test) and "attempts". A progress bar over runs (done / running /
failed / retried, ETA from the runs finished so far) goes to stderr (`--no-progress`: none).

`dlo-experiments --out RUNS --collect RESULTS` trains nothing: it copies the small files of every
finished run under RUNS (done.json present; config.yaml, eval.csv, done.json, best.json, test*.json,
randomised.csv of a randomised run; never checkpoints, replay buffers, policies or bags) into RESULTS with
the same layout, copying a file only when it differs, and prints the run directories it added or updated:
the run record under results/ that docs/RESULTS.md cites.

`--dry-run` lists the runs and estimates the wall time from a short calibration measured now, on
this machine, under its current load: `CALIBRATION_STEPS` SAC steps (env step + one gradient
update, the run's network, `--threads` threads) and one evaluation of the configuration with the
most expensive observation; per run  t = steps x t_step + evaluations x tested input sets x t_eval
(+ the held-out test), and the runs are packed onto `--jobs` workers longest first.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import concurrent.futures.process
import contextlib
import filecmp
import logging
import math
import multiprocessing
import os
import shutil
import signal
import socket
import sys
import tempfile
import threading
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Optional, Sequence

from dlo_common.console import EXIT_INTERRUPTED, console_main
from tqdm import tqdm

from . import rundir
from .cli import check_override_keys
from .config import ConfigError, RunConfig, check_env_options, make_env
from .grid import EXTRA_GROUPS, GROUPS, RunSpec, experiment_grid, run_config
from .rundir import CHECKPOINT_FILE, DONE_FILE, EVAL_FILE, LOG_FILE, run_status
from .train import (
    Trainer,
    TrainingInterrupted,
    available_cores,
    resolve_checkpoint_every,
    run_trainer,
    set_threads,
)

STOP_WAIT = 300.0  # s an interrupted grid waits for its runs to reach the end of an episode and checkpoint


class GridError(Exception):
    """A user-facing problem that stops the grid before or while dispatching (one line, exit 2)."""


@contextlib.contextmanager
def output_to(path: Path) -> Iterator[None]:
    """This process's stdout and stderr (file descriptors 1 and 2, so native libraries' output too)
    appended to `path` for the duration, then restored."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    try:
        with path.open("a") as log:
            os.dup2(log.fileno(), 1)
            os.dup2(log.fileno(), 2)
            try:
                yield
            finally:
                sys.stdout.flush()
                sys.stderr.flush()
                os.dup2(saved[0], 1)
                os.dup2(saved[1], 2)
    finally:
        os.close(saved[0])
        os.close(saved[1])


def run_one(config_data: dict[str, Any], run_dir: str, stop_signals: bool = True) -> dict[str, Any]:
    """Train one run in this process (resuming it if it has a checkpoint), holding the run directory's
    lock from the first look at it (rundir.lock); output to train.log. `stop_signals`: SIGTERM (and SIGINT
    unless ignored) stops it at the end of an episode with a checkpoint there (train.StopSignals:
    TrainingInterrupted), as dlo-train; off: the signals keep their handlers (a Ray worker's)."""
    path = Path(run_dir)
    with rundir.lock(path):
        resume = (path / CHECKPOINT_FILE).exists()
        if not resume:
            (path / EVAL_FILE).unlink(missing_ok=True)  # evaluations of a run stopped before its first checkpoint
        with output_to(path / LOG_FILE):
            config = RunConfig.from_dict(config_data)
            if stop_signals:
                return run_trainer(config, path, resume, make=Trainer)
            return Trainer(config, path, resume=resume).run()


def stamp_done(run_dir: Path, node: str, duration_s: float, attempts: int) -> None:
    """Add where and how long the run ran to its done.json."""
    summary = rundir.read_done(run_dir)
    summary.update(node=node, host=socket.gethostname(), duration_s=round(duration_s, 2), attempts=attempts)
    rundir.write_done(run_dir, summary)


@dataclass(eq=False)
class Task:
    """One run to execute, and what happened to it."""

    run_dir: Path
    config: dict[str, Any]
    attempts: int = 0
    node: Optional[str] = None  # where the current (or last) attempt runs
    lost: list[str] = field(default_factory=list)  # why earlier attempts were lost (Ray)
    error: Optional[str] = None  # why the run failed (traceback); None: finished or not yet

    @property
    def failed(self) -> bool:
        return self.error is not None


class GridProgress:
    """A progress bar over the grid's runs (stderr) and the per-run lines (stdout)."""

    def __init__(self, total: int, enabled: bool):
        self.total, self.finished, self.failed, self.retried, self.running = total, 0, 0, 0, 0
        # a terminal gets a live bar; a log file a line per change of the counts, else every 60 s
        self.bar = tqdm(
            total=total,
            desc="runs",
            unit="run",
            disable=not enabled,
            file=sys.stderr,
            dynamic_ncols=True,
            mininterval=1.0 if sys.stderr.isatty() else 60.0,
            smoothing=0.0,
            postfix=self.counts(),
        )
        self.shown = self.counts()

    def counts(self) -> str:
        return f"done={self.finished - self.failed} running={self.running} failed={self.failed} retried={self.retried}"

    def refresh(self, running: Optional[int] = None) -> None:
        """Show the counts now if they changed; else only the clock moves (at tqdm's pace)."""
        if running is not None:
            self.running = running
        if self.counts() != self.shown:
            self.shown = self.counts()
            self.bar.set_postfix_str(self.shown, refresh=True)
        else:
            self.bar.update(0)

    def log(self, line: str) -> None:
        self.bar.write(line, file=sys.stdout)
        sys.stdout.flush()

    def done(self, task: Task, where: str = "") -> None:
        self.finished += 1
        self.failed += task.failed
        status = f"FAILED\n{task.error}" if task.failed else "ok"
        self.log(f"[{self.finished}/{self.total}] {task.run_dir}: {status}{where}")
        self.shown = self.counts()
        self.bar.set_postfix_str(self.shown, refresh=False)
        self.bar.update(1)
        self.bar.refresh()

    def close(self) -> None:
        self.bar.set_postfix_str(self.counts(), refresh=True)
        self.bar.close()


LOCAL_NODE = "local"


def _run_local_task(config_data: dict[str, Any], run_dir: str) -> tuple[str, Optional[str]]:
    """In a fresh process: train (or resume) the run in `run_dir`; (run_dir, traceback or None)."""
    start = time.monotonic()
    try:
        run_one(config_data, run_dir)
        stamp_done(Path(run_dir), LOCAL_NODE, time.monotonic() - start, attempts=1)
        return run_dir, None
    except rundir.RunInUse as error:  # a user's mistake (two grids on one --out): one line, not a traceback
        return run_dir, str(error)
    except TrainingInterrupted as stopped:  # the driver stopped it: its checkpoint is where the next start resumes
        return run_dir, f"{stopped} (stopped by the driver; the next start resumes it)"
    except Exception:  # noqa: BLE001 (reported by the parent; the other runs go on)
        return run_dir, traceback.format_exc()


def _die_with_the_driver() -> None:
    """Worker initializer: the kernel sends this worker SIGTERM when the driver dies, however it dies
    (SIGKILL included), so no run goes on training unseen (Linux; elsewhere a no-op). SIGINT is ignored: a
    Ctrl-C reaches the driver, which stops its runs with SIGTERM (each then checkpoints at the end of its
    episode; one signal, not Ctrl-C and then the driver's SIGTERM, which would stop it at once)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGTERM))  # PR_SET_PDEATHSIG
        if os.getppid() == 1:  # the driver died before prctl took effect
            os._exit(1)
    except (OSError, AttributeError):
        pass


def run_local(tasks: list[Task], jobs: int, progress: GridProgress) -> None:
    """Each task in a fresh spawned process, `jobs` at a time; sets each task's error."""
    context = multiprocessing.get_context("spawn")
    pool = concurrent.futures.ProcessPoolExecutor(
        max_workers=jobs, mp_context=context, max_tasks_per_child=1, initializer=_die_with_the_driver
    )
    try:
        futures = {pool.submit(_run_local_task, task.config, str(task.run_dir)): task for task in tasks}
        for task in tasks:
            task.attempts, task.node = 1, LOCAL_NODE
        remaining = len(futures)
        progress.refresh(running=min(jobs, remaining))
        for future in concurrent.futures.as_completed(futures):
            task = futures[future]
            try:
                task.error = future.result()[1]
            except concurrent.futures.process.BrokenProcessPool:
                task.error = (
                    "its process died (killed, out of memory?) and took the process pool down: "
                    "run the command again to continue (finished runs are skipped, partial ones resume)"
                )
            remaining -= 1
            progress.running = min(jobs, remaining)
            progress.done(task)
    except BaseException:  # Ctrl-C, SIGTERM (main turns it into KeyboardInterrupt): stop the runs too
        workers = list((getattr(pool, "_processes", None) or {}).values())
        manager = getattr(pool, "_executor_manager_thread", None)
        with _quiet_thread(manager):
            pool.shutdown(wait=False, cancel_futures=True)
            stop_workers(workers)
            if manager is not None:
                manager.join(timeout=30)
        raise
    pool.shutdown(wait=True)


@contextlib.contextmanager
def _quiet_thread(thread: Optional[threading.Thread]) -> Iterator[None]:
    """No traceback from `thread` meanwhile: the pool's manager thread, which (CPython 3.11) fails with a
    TypeError in _adjust_process_count when a worker of a pool already shut down returns its last task (an
    interrupted run's result) and exits (max_tasks_per_child), after the grid stopped anyway."""
    previous = threading.excepthook

    def hook(args: Any) -> None:
        if thread is None or args.thread is not thread:
            previous(args)

    threading.excepthook = hook
    try:
        yield
    finally:
        threading.excepthook = previous


def stop_workers(workers: Sequence[Any], wait: float = STOP_WAIT) -> None:
    """SIGTERM to each worker process: its run stops at the end of its episode with a checkpoint there
    (train.StopSignals); wait up to `wait` s for them, then kill what is left. A second Ctrl-C (or SIGTERM)
    meanwhile kills them at once (their last checkpoints stay)."""
    for worker in workers:
        worker.terminate()
    try:
        deadline = time.monotonic() + wait
        for worker in workers:
            worker.join(timeout=max(0.0, deadline - time.monotonic()))
    finally:
        for worker in workers:
            if worker.is_alive():
                worker.kill()
                worker.join(timeout=30)


def import_ray() -> Any:
    """Ray, imported only when asked for; a clear exit when it is not installed."""
    try:
        import ray  # noqa: PLC0415 (optional dependency)
    except ImportError:
        raise SystemExit(
            "dlo-experiments: --ray-address needs Ray, which is not installed: pip install ray "
            "(or leave out --ray-address to run local processes)"
        ) from None
    return ray


MAX_LOG_BYTES = 1 << 20  # the end of a longer train.log is sent back


def result_files(run_dir: Path) -> dict[str, bytes]:
    """The run's small result files, name -> content (rundir.result_names: never checkpoint.pt, it holds
    the replay buffer)."""
    files = {name: (run_dir / name).read_bytes() for name in rundir.result_names(run_dir)}
    if LOG_FILE in files:
        files[LOG_FILE] = files[LOG_FILE][-MAX_LOG_BYTES:]
    return files


def write_result(run_dir: Path, files: dict[str, bytes], error: Optional[str]) -> None:
    """A Ray run's files under OUT (done.json last, each file replaced atomically); a failed run
    leaves only its train.log, with the error at the end."""
    run_dir.mkdir(parents=True, exist_ok=True)
    if error is not None:
        log = files.get(LOG_FILE, b"") + f"\n{error}".encode()
        files = {LOG_FILE: log}
    else:
        # a checkpoint of an earlier local attempt: the run started over on the cluster
        (run_dir / CHECKPOINT_FILE).unlink(missing_ok=True)
    for name in sorted(files, key=lambda n: n == DONE_FILE):
        temporary = run_dir / (name + ".part")
        temporary.write_bytes(files[name])
        os.replace(temporary, run_dir / name)


def _ray_task(config_data: dict[str, Any], attempt: int) -> Iterator[dict[str, Any]]:
    """On a Ray worker (a generator: the driver learns when and where the run starts): train the
    run in a temporary directory of this node, then send its result files back."""
    import ray  # noqa: PLC0415

    node = ray.get_runtime_context().get_node_id()
    yield {"started": node}
    start = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="dlo-run-") as directory:
        run_dir = Path(directory)
        error = None
        try:
            run_one(config_data, str(run_dir), stop_signals=False)
            stamp_done(run_dir, node, time.monotonic() - start, attempt)
        except Exception:  # noqa: BLE001 (sent to the driver; the other runs go on)
            error = traceback.format_exc()
        yield {"node": node, "error": error, "files": result_files(run_dir)}


def connect_ray(address: str) -> Any:
    """Ray, connected (quietly) to the existing cluster at `address`; GridError (one line) when
    nothing answers there (checked first: ray.init would wait minutes for an absent head)."""
    ray = import_ray()
    if address != "auto" and "://" not in address:
        host, _, port = address.rpartition(":")
        if not host or not port.isdigit():
            raise GridError(f"--ray-address {address}: expected HOST:PORT of the head node (or auto)")
        try:
            socket.create_connection((host.strip("[]"), int(port)), timeout=10).close()
        except OSError as error:
            raise GridError(
                f"--ray-address {address}: no Ray head answers there "
                f"({error.strerror or type(error).__name__}); start one with ray start --head"
            ) from None
    try:
        ray.init(address=address, log_to_driver=False, logging_level=logging.WARNING)
    except (ConnectionError, RuntimeError, ValueError) as error:
        first_line = (str(error).strip().splitlines() or [type(error).__name__])[0]
        raise GridError(f"--ray-address {address}: no Ray cluster to connect to ({first_line})") from None
    return ray


def check_capacity(ray: Any, threads: int, gpus: float = 0.0) -> None:
    """GridError when no node of the cluster can take a run of `threads` CPUs (and `gpus` GPUs):
    its task would wait forever."""
    nodes = [node["Resources"] for node in ray.nodes() if node["Alive"]]
    if not any(node.get("CPU", 0) >= threads and node.get("GPU", 0) >= gpus for node in nodes):
        most_cpus = max((node.get("CPU", 0) for node in nodes), default=0)
        most_gpus = max((node.get("GPU", 0) for node in nodes), default=0)
        wanted = f"{threads} CPUs" + (f" and {gpus:g} GPU(s)" if gpus else "")
        raise GridError(
            f"no node of the Ray cluster has {wanted} for a run (at most {most_cpus:g} CPUs, "
            f"{most_gpus:g} GPUs per node): lower --threads / --gpus-per-run, or add bigger nodes"
        )


def run_ray(ray: Any, tasks: list[Task], threads: int, retries: int, progress: GridProgress, gpus: float = 0.0) -> None:
    """Each task as a Ray task reserving `threads` CPUs (and `gpus` GPUs) on the connected cluster;
    its files come back to the driver. A task whose worker or node is lost is submitted again, at
    most `retries` times."""
    try:
        # max_calls=1: every run in a fresh worker process (torch threads, Taichi, file descriptors);
        # max_retries=0: lost attempts are resubmitted here, where they are counted and reported
        resources = {"num_cpus": threads, **({"num_gpus": gpus} if gpus else {})}
        remote = ray.remote(**resources, max_calls=1, max_retries=0)(_ray_task)
        pending: dict[Any, Task] = {}

        def submit(task: Task) -> None:
            task.attempts += 1
            task.node = None
            pending[remote.remote(task.config, task.attempts)] = task

        for task in tasks:
            submit(task)
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=1.0)
            for generator in ready:
                task = pending.pop(generator)
                try:
                    message = ray.get(next(generator))
                except ray.exceptions.RayTaskError as error:  # raised by the task itself: not retried
                    task.error = str(error)
                    progress.done(task)
                    continue
                except (ray.exceptions.RayError, StopIteration) as error:  # worker or node lost
                    reason = type(error).__name__ + (f" on node {task.node[:12]}" if task.node else "")
                    task.lost.append(reason)
                    if len(task.lost) > retries:
                        task.error = f"lost {len(task.lost)} times ({'; '.join(task.lost)}); --retries {retries}"
                        progress.done(task)
                    else:
                        progress.retried += 1
                        progress.log(
                            f"[retry] {task.run_dir}: attempt {task.attempts} lost ({reason}); "
                            f"starting attempt {task.attempts + 1}"
                        )
                        submit(task)
                    continue
                if "started" in message:
                    task.node = message["started"]
                    progress.log(f"[start] {task.run_dir} on node {task.node[:12]} (attempt {task.attempts})")
                    pending[generator] = task
                    continue
                task.error = message["error"]
                write_result(task.run_dir, message["files"], task.error)
                progress.done(task, f" (node {task.node[:12]})")
            progress.refresh(running=sum(task.node is not None for task in pending.values()))
    finally:
        ray.shutdown()


def report(tasks: Sequence[Task]) -> list[str]:
    """The end of the grid: what finished, failed and was retried."""
    failed = [task for task in tasks if task.failed]
    lines = [f"grid: {len(tasks)} run(s): {len(tasks) - len(failed)} finished, {len(failed)} failed"]
    retried = [task for task in tasks if task.lost]
    if retried:
        lines.append(f"retried {len(retried)} run(s) after a lost worker or node:")
        for task in retried:
            outcome = "failed" if task.failed else f"finished on node {(task.node or '?')[:12]}"
            lines.append(
                f"  {task.run_dir}: lost {len(task.lost)}x ({'; '.join(task.lost)}), {outcome} at attempt {task.attempts}"
            )
    return lines


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

    from .evaluate import evaluate_agent  # noqa: PLC0415
    from .sac import SAC  # noqa: PLC0415

    set_threads(config.train.num_threads)
    env = make_env(config, training=True)
    sac_config = dataclasses.replace(config.sac, learning_starts=config.sac.batch_size)
    agent = SAC(
        env.observation_space.shape[0],
        env.action_space.low,
        env.action_space.high,
        sac_config,
        seed=config.seed,
        observation_low=env.observation_space.low,
        observation_high=env.observation_space.high,
    )
    agent.learn(env, sac_config.learning_starts + 5)  # fill a batch; first updates warm up
    start = time.perf_counter()
    agent.learn(env, agent.num_env_steps + steps)
    step_s = (time.perf_counter() - start) / steps
    env.close()
    vec_env = make_env(config, config.train.eval_episodes, seed=config.train.eval_seed)
    evaluate_agent(agent, vec_env, config.train.eval_seed, vec_env.num_envs)  # warm-up (kernel compilation)
    start = time.perf_counter()
    evaluate_agent(agent, vec_env, config.train.eval_seed, config.train.eval_episodes)
    eval_s = time.perf_counter() - start
    vec_env.close()
    return Calibration(step_s, eval_s)


def done_steps(run_dir: Path) -> int:
    """Env steps a partial run has already taken (its last evaluation row), 0 if none."""
    try:
        rows = rundir.read_eval_rows(run_dir)
        return int(rows[-1]["step"]) if rows and (run_dir / CHECKPOINT_FILE).exists() else 0
    except (OSError, KeyError, ValueError):
        return 0


def makespan(durations: Sequence[float], jobs: int) -> float:
    """Wall time of running `durations` on `jobs` workers, longest first onto the least loaded."""
    loads = [0.0] * max(jobs, 1)
    for duration in sorted(durations, reverse=True):
        loads[loads.index(min(loads))] += duration
    return max(loads)


def estimate(
    specs: Sequence[RunSpec],
    configs: Sequence[RunConfig],
    statuses: Sequence[str],
    out: Path,
    jobs: int,
    resume_partial: bool = True,
) -> str:
    """One paragraph: calibration and the estimated wall time of the runs still to do."""
    todo = [(spec, config) for spec, config, status in zip(specs, configs, statuses) if status != "done"]
    if not todo:
        return "estimate: nothing to run"
    # the most expensive observation: vision (rendering) if any run uses it, then the most inputs
    probe = max((config for _, config in todo), key=lambda c: ("V" in c.modalities or c.modalities == "All", len(c.modalities)))
    calibration = calibrate(probe)
    durations = [
        calibration.run_seconds(config, done_steps(spec.directory(out)) if resume_partial else 0) for spec, config in todo
    ]
    wall = makespan(durations, jobs)
    return (
        f"estimate: {len(todo)} runs, {sum(durations) / 3600:.1f} run-hours, wall ~{_duration(wall)} on "
        f"{jobs} job(s) (calibrated now on {probe.modalities}: {1000 * calibration.step_s:.0f} ms per step "
        f"with its update, {calibration.eval_s:.1f} s per evaluation of {probe.train.eval_episodes} episodes; "
        f"other load on this machine is included)"
    )


def _duration(seconds: float) -> str:
    return f"{seconds / 3600:.1f} h" if seconds >= 3600 else f"{seconds / 60:.0f} min"


def collect_results(runs: Path, results: Path) -> list[Path]:
    """Copy the small files of every finished run (a done.json) anywhere under `runs` into `results`,
    same layout: its record (rundir.record_names). A file is copied only when it is new or differs.
    Returns the directories under `results` that were added or updated, in path order."""
    runs, results = Path(runs), Path(results)
    changed = []
    for done in sorted(runs.rglob(DONE_FILE)):
        run = done.parent
        if results.resolve() in run.resolve().parents or run.resolve() == results.resolve():
            continue  # RESULTS inside RUNS: not a run of RUNS
        dest = results / run.relative_to(runs)
        updated = False
        for source in [run / name for name in rundir.record_names(run)]:
            target = dest / source.name
            if target.is_file() and filecmp.cmp(source, target, shallow=False):
                continue
            dest.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(source, target)
            updated = True
        if updated:
            changed.append(dest)
    return changed


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="dlo-experiments",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="Overrides (key=value) apply to every run, e.g. train.eval_every=500.",
    )
    parser.add_argument("--out", type=Path, required=True, help="results directory (one subdirectory per run)")
    parser.add_argument(
        "--groups",
        default=",".join(GROUPS),
        help=f"comma-separated subset of {','.join(GROUPS + EXTRA_GROUPS)} (default: the paper's, {','.join(GROUPS)})",
    )
    parser.add_argument(
        "--labels", help="only these configuration labels (comma-separated), e.g. All,V,T,K; a run directory's name works too"
    )
    parser.add_argument("--seeds", type=int, default=3, help="seeds per configuration (default 3)")
    parser.add_argument("--first-seed", type=int, default=0, help="seeds are first-seed .. first-seed + seeds - 1")
    parser.add_argument("--steps", type=int, help="env steps per run (default: the config's, 50000)")
    parser.add_argument("--config", type=Path, help="YAML config for every run")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (and Ray CPUs) per run (default 1)")
    parser.add_argument(
        "--jobs",
        type=int,
        help="parallel local runs (default: cores // threads); with --dry-run: the number of "
        "workers the estimate is for (default: as many local runs, or 1 with --ray-address)",
    )
    parser.add_argument(
        "--ray-address",
        help="run on this Ray cluster instead: HOST:PORT of its head (`ray start --head` prints it), or auto on one of its nodes",
    )
    parser.add_argument(
        "--gpus-per-run",
        type=float,
        default=0.0,
        help="Ray: GPUs each run reserves (e.g. 1, or 0.25 to share one among 4 runs; default 0). "
        "Ray shows a task only the GPUs it reserved, so train.device=auto trains on the CPU "
        "without this",
    )
    parser.add_argument(
        "--retries", type=int, default=2, help="Ray: times a run whose worker or node was lost is started again (default 2)"
    )
    parser.add_argument(
        "--resume",
        action="store_true",
        help="continue a grid in --out: finished runs (done.json) are skipped, partial local ones "
        "resume from their checkpoint (this is also what happens without the flag)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar over the runs")
    parser.add_argument(
        "--dry-run",
        action="store_true",
        help="list the runs and their status, estimate the wall time (short calibration), run nothing",
    )
    parser.add_argument(
        "--collect",
        type=Path,
        metavar="RESULTS",
        help="train nothing: copy the small files of every finished run under --out (config.yaml, "
        "eval.csv, done.json, best.json, test*.json) into RESULTS, same layout, and print the "
        "run directories added or updated",
    )
    parser.add_argument("overrides", nargs="*", metavar="key=value", help="config overrides for every run")
    return parser


def _interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


@console_main("dlo-experiments")
def main(argv: Optional[Sequence[str]] = None) -> int:
    args = build_parser().parse_args(argv)
    if threading.current_thread() is threading.main_thread():  # SIGTERM stops the runs like Ctrl-C does
        signal.signal(signal.SIGTERM, _interrupt)
    if args.collect is not None:
        return _collect(args)
    problem = _argument_problem(args)
    if problem:
        return _usage_error(problem)
    if args.ray_address:
        import_ray()
    jobs = _local_jobs(args)
    try:
        specs, configs = _grid_configs(args)
    except (ConfigError, ValueError) as error:
        return _usage_error(str(error))
    statuses = [run_status(s.directory(args.out)) for s in specs]
    restarts = " (starts over on the cluster: its checkpoint stays here)" if args.ray_address else ""
    for spec, status in zip(specs, statuses):
        note = restarts if status == "partial" else ""
        print(f"{status:8s} {spec.directory(args.out)}  ({', '.join(spec.groups)}){note}")
    tasks = [
        Task(spec.directory(args.out), config.to_dict())
        for spec, config, status in zip(specs, configs, statuses)
        if status != "done"
    ]
    print(f"{len(specs)} runs, {len(specs) - len(tasks)} done, {len(tasks)} to run", flush=True)
    if args.dry_run:
        workers = args.jobs or (1 if args.ray_address else jobs)
        print(estimate(specs, configs, statuses, args.out, workers, resume_partial=not args.ray_address), flush=True)
        return 0
    if not tasks:
        return 0
    return _run_grid(args, tasks, jobs)


def _collect(args) -> int:
    """--collect: copy the small files of the runs under --out into the record (one line per run directory)."""
    if not args.out.is_dir():
        return _usage_error(f"--collect: no directory {args.out}")
    for directory in collect_results(args.out, args.collect):
        print(directory, flush=True)
    return 0


def _argument_problem(args) -> Optional[str]:
    """The usage error of a bad --threads, --seeds, --jobs, --retries or --gpus-per-run, or None."""
    for name in ("threads", "seeds"):
        if getattr(args, name) < 1:
            return f"--{name} must be at least 1"
    if args.jobs is not None and args.jobs < 1 or args.retries < 0 or args.gpus_per_run < 0:
        return "--jobs must be at least 1, --retries and --gpus-per-run at least 0"
    if args.gpus_per_run and not args.ray_address:
        return "--gpus-per-run is for --ray-address (local runs use train.device)"
    return None


def _local_jobs(args) -> int:
    """How many runs at once on this machine: --jobs, else as many as the cores hold at --threads each (a local
    grid asking more than the cores is cut down, with a line saying so)."""
    cores = available_cores()
    jobs = args.jobs or max(1, cores // args.threads)
    if not args.ray_address and not args.dry_run and jobs * args.threads > cores:
        print(
            f"dlo-experiments: {jobs} jobs x {args.threads} threads > {cores} cores; using {max(1, cores // args.threads)} jobs",
            file=sys.stderr,
        )
        jobs = max(1, cores // args.threads)
    return jobs


def _grid_configs(args) -> tuple[list, list]:
    """The grid's run specs (its groups, seeds and --labels) and their checked configurations; ConfigError or
    ValueError for a bad group, label, override or env option."""
    groups = [g.strip() for g in args.groups.split(",") if g.strip()]
    specs = experiment_grid(groups, range(args.first_seed, args.first_seed + args.seeds))
    if args.labels:
        wanted = wanted_labels(args.labels, specs, ",".join(groups))
        specs = [s for s in specs if s.label in wanted]
    check_override_keys(args.overrides)
    configs = [run_config(s, args.config, args.overrides, args.steps, args.threads) for s in specs]
    for config in configs:  # 0, the default: a tenth of the run, so that a short grid's runs can be resumed too
        resolve_checkpoint_every(config)
    for config in configs:
        check_env_options(config)
    return specs, configs


def _run_grid(args, tasks: list, jobs: int) -> int:
    """Run ``tasks`` on the Ray cluster or here with ``jobs`` at once, then the report; the exit status."""
    progress: Optional[GridProgress] = None
    try:
        if args.ray_address:
            ray = connect_ray(args.ray_address)
            try:
                check_capacity(ray, args.threads, args.gpus_per_run)
            except GridError:
                ray.shutdown()
                raise
            progress = GridProgress(len(tasks), enabled=not args.no_progress)
            run_ray(ray, tasks, args.threads, args.retries, progress, gpus=args.gpus_per_run)
        else:
            progress = GridProgress(len(tasks), enabled=not args.no_progress)
            run_local(tasks, jobs, progress)
    except GridError as error:
        if progress is not None:
            progress.close()
        return _usage_error(str(error))
    except KeyboardInterrupt:
        if progress is not None:
            progress.close()
        finished = sum(task.error is None and run_status(task.run_dir) == "done" for task in tasks)
        print(
            f"dlo-experiments: interrupted; {finished} of {len(tasks)} run(s) finished: run the same command "
            "again to continue (a stopped run resumes from its checkpoint)",
            file=sys.stderr,
        )
        return EXIT_INTERRUPTED
    progress.close()
    lines = report(tasks)
    print("\n".join(lines), flush=True)
    failed = [str(task.run_dir) for task in tasks if task.failed]
    if failed:
        print(f"{len(failed)} run(s) failed: {', '.join(failed)} (see their train.log)", file=sys.stderr)
        return 1
    return 0


def wanted_labels(labels: str, specs, groups: str) -> set[str]:
    """The labels `--labels` names, each as written or as its run directory's name ('All_tactile-partial' for
    'All tactile-partial'); ValueError naming the choices for one that is no configuration of the groups."""
    known = list(dict.fromkeys(s.label for s in specs))
    by_name = {**{s.label: s.label for s in specs}, **{s.directory(Path()).parent.name: s.label for s in specs}}
    wanted = set()
    for label in (part.strip() for part in labels.split(",")):
        if not label:
            continue
        if label not in by_name:
            raise ValueError(
                f"--labels: {label!r} is not a configuration of the groups {groups} (their labels: {', '.join(known)})"
            )
        wanted.add(by_name[label])
    return wanted


def _usage_error(message: str) -> int:
    print(f"dlo-experiments: error: {message}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
