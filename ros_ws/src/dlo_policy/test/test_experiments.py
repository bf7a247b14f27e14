"""dlo-experiments: the paper's grid, local parallel runs, skipping finished runs, Ray without Ray."""

import contextlib
import importlib.util
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from dlo_policy import experiments
from dlo_policy.config import load_config
from dlo_policy.rundir import CHECKPOINT_FILE, DONE_FILE, EVAL_COLUMNS, EVAL_FILE, LOCK_FILE
from harness import exited

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib: helper modules (spawned runs too)

TINY = [
    "env_module=sac_reach_env",
    "sac.hidden_sizes=[16,16]",
    "sac.batch_size=16",
    "sac.learning_starts=20",
    "sac.buffer_size=500",
    "train.eval_every=50",
    "train.checkpoint_every=50",
    "train.eval_episodes=4",
]


def test_grid_covers_the_papers_experiments_once_per_seed():
    specs = experiments.experiment_grid(experiments.GROUPS, seeds=[0, 1])
    labels = sorted({s.label for s in specs})
    assert labels == sorted(
        [
            "T",
            "K",
            "V",
            "All",
            "T+K",
            "V+K",
            "T+V",
            "All tactile-partial",
            "All tactile-full",
            "T+V tactile-partial",
            "T+V tactile-full",
        ]
    )
    assert len(specs) == 2 * len(labels)
    by_label = {s.label: s for s in specs if s.seed == 0}
    assert by_label["All"].eval_without == ("T", "V")
    assert set(by_label["All"].groups) == {"single", "ablation", "sensitivity"}
    assert by_label["T+V tactile-full"].modalities == "T+V"
    assert dict(by_label["T+V tactile-full"].env_options) == {"tactile_noise": "full"}
    assert by_label["V"].eval_without == () and by_label["V"].env_options == ()
    assert experiments.experiment_grid(["single"], seeds=[3])[0].seed == 3
    order = [(s.seed, s.label) for s in experiments.experiment_grid(["single"], seeds=[1, 2])]
    assert order == [(1, "T"), (1, "K"), (1, "V"), (1, "All"), (2, "T"), (2, "K"), (2, "V"), (2, "All")]
    with pytest.raises(ValueError, match="unknown group"):
        experiments.experiment_grid(["singles"], seeds=[0])


def test_runner_skips_finished_runs_and_runs_the_rest_in_processes(tmp_path, capsys):
    out = tmp_path / "grid"
    finished = out / "K" / "seed0"
    finished.mkdir(parents=True)
    (finished / DONE_FILE).write_text("{}")
    argv = ["--out", str(out), "--groups", "single", "--seeds", "1", "--steps", "60", "--jobs", "2", "--threads", "1", *TINY]
    argv += ["train.test_episodes=4"]  # (the held-out test of 100 episodes by default)
    assert experiments.main(argv) == 0
    captured = capsys.readouterr()
    assert "4 runs, 1 done, 3 to run" in captured.out
    assert "grid: 3 run(s): 3 finished, 0 failed" in captured.out and "retried" not in captured.out
    assert "3/3" in captured.err and "done=3 running=0 failed=0" in captured.err  # the progress bar's last state
    assert not (finished / EVAL_FILE).exists()
    for label in ("T", "V", "All"):
        run = out / label / "seed0"
        done = json.loads((run / DONE_FILE).read_text())
        assert done["env_steps"] == 60
        assert (done["node"], done["attempts"]) == ("local", 1) and done["duration_s"] > 0 and done["host"]
        assert (run / "train.log").exists() and (run / CHECKPOINT_FILE).exists()
    assert experiments.main([*argv, "--resume"]) == 0
    assert "4 runs, 4 done, 0 to run" in capsys.readouterr().out


def test_run_status_and_directories(tmp_path):
    spec = experiments.RunSpec("T+V tactile-full", "T+V", 2)
    run = spec.directory(tmp_path)
    assert run == tmp_path / "T+V_tactile-full" / "seed2"
    assert experiments.run_status(run) == "todo"
    run.mkdir(parents=True)
    (run / CHECKPOINT_FILE).write_bytes(b"")
    assert experiments.run_status(run) == "partial"
    (run / DONE_FILE).write_text("{}")
    assert experiments.run_status(run) == "done"


def test_run_config_carries_the_spec_and_overrides(tmp_path):
    spec = experiments.RunSpec("All tactile-partial", "All", 4, (("tactile_noise", "partial"),), ("T", "V"))
    config = experiments.run_config(spec, None, ["sac.batch_size=64"], steps=1000, threads=1)
    assert (config.modalities, config.seed, config.label) == ("All", 4, "All tactile-partial")
    assert config.env_options == {"tactile_noise": "partial"} and config.train.eval_without == ("T", "V")
    assert (config.train.total_steps, config.train.num_threads, config.sac.batch_size) == (1000, 1, 64)
    assert config.train.progress is False


@pytest.mark.skipif(importlib.util.find_spec("ray") is not None, reason="Ray is installed here")
def test_ray_address_without_ray_is_a_clear_error(tmp_path):
    with pytest.raises(SystemExit, match="pip install ray"):
        experiments.main(["--out", str(tmp_path), "--ray-address", "auto"])


def test_makespan_packs_longest_first_and_run_time_counts_evaluations():
    assert experiments.makespan([3, 3, 2, 2, 2], jobs=2) == 7
    assert experiments.makespan([5, 1], jobs=4) == 5
    cal = experiments.Calibration(step_s=0.1, eval_s=2.0)
    config = load_config(
        None, ["train.total_steps=1000", "train.eval_every=200", "train.eval_without=[T]", "train.test_episodes=100"]
    )
    # 1000 steps + (5 evaluations + the one at step 0 + 10 test batches of 10) x 2 tested input sets
    assert cal.run_seconds(config) == pytest.approx(100 + (6 + 10) * 2 * 2.0)
    assert cal.run_seconds(config, done_steps=600) == pytest.approx(40 + (2 + 10) * 2 * 2.0)


def test_the_estimate_counts_a_last_partial_batch_of_held_out_test_episodes():
    """Calibration.run_seconds: the held-out test of 15 episodes in batches of 10 is 2 evaluations, not 1."""
    cal = experiments.Calibration(step_s=0.0, eval_s=1.0)
    config = load_config(
        None, ["train.total_steps=1000", "train.eval_every=500", "train.eval_episodes=10", "train.test_episodes=15"]
    )
    assert cal.run_seconds(config) == pytest.approx(3 + 2)  # evaluations at 0, 500, 1000 + 2 test batches
    config = load_config(
        None,
        [
            "train.total_steps=1000",
            "train.eval_every=500",
            "train.eval_episodes=10",
            "train.test_episodes=5",
            "train.eval_without=[T]",
        ],
    )
    assert cal.run_seconds(config) == pytest.approx((3 + 1) * 2)


def test_a_run_without_a_checkpoint_has_done_no_steps(tmp_path):
    """done_steps: the last evaluation's step of a partial run (checkpoint.pt present); a run without a
    checkpoint starts from step 0 again (dlo-experiments deletes its eval.csv), so it has done none."""
    run = tmp_path / "run"
    run.mkdir()
    header = ",".join(EVAL_COLUMNS)
    (run / EVAL_FILE).write_text(f"{header}\n0,,10\n200,,10\n400,,10\n")
    assert experiments.done_steps(run) == 0
    (run / CHECKPOINT_FILE).write_bytes(b"")
    assert experiments.done_steps(run) == 400
    assert experiments.done_steps(tmp_path / "missing") == 0


def test_dry_run_estimates_from_a_measured_calibration(tmp_path, capsys):
    argv = [
        "--out",
        str(tmp_path / "grid"),
        "--groups",
        "single",
        "--seeds",
        "2",
        "--steps",
        "400",
        "--jobs",
        "2",
        "--dry-run",
        *TINY,
    ]
    assert experiments.main(argv) == 0
    out = capsys.readouterr().out
    assert "8 runs, 0 done, 8 to run" in out and "estimate: 8 runs" in out and "ms per step" in out
    assert not (tmp_path / "grid").exists()


def test_bad_env_option_stops_the_grid_before_any_run(tmp_path, capsys):
    argv = ["--out", str(tmp_path / "grid"), "--groups", "single", "--seeds", "1", "env_options.tactile_noise=loud"]
    assert experiments.main(argv) == 2
    assert "env_options: tactile_noise" in capsys.readouterr().err
    assert not (tmp_path / "grid").exists()


def test_output_to_redirects_the_file_descriptors_and_restores_them(tmp_path, capfd):
    log = tmp_path / "train.log"
    with experiments.output_to(log):
        os.write(1, b"inside out\n")
        os.write(2, b"inside err\n")
    os.write(1, b"after\n")
    assert log.read_text() == "inside out\ninside err\n"
    assert capfd.readouterr().out == "after\n"


def make_run(run_dir: Path) -> None:
    run_dir.mkdir(parents=True)
    for name in ("config.yaml", "eval.csv", "best.json", "test.json", "test_without_T.json", "train.log"):
        (run_dir / name).write_text(name)
    for name in ("policy.pt", "best_policy.pt", CHECKPOINT_FILE):
        (run_dir / name).write_bytes(b"\0" * 10)
    (run_dir / DONE_FILE).write_text(json.dumps({"env_steps": 60}))


def test_a_remote_run_sends_back_its_small_files_and_the_driver_writes_done_json_last(tmp_path, monkeypatch):
    make_run(tmp_path / "worker")
    files = experiments.result_files(tmp_path / "worker")
    assert set(files) == {
        "config.yaml",
        "eval.csv",
        "best.json",
        "test.json",
        "test_without_T.json",
        "train.log",
        "policy.pt",
        "best_policy.pt",
        DONE_FILE,
    }  # never the checkpoint (replay buffer)
    target = tmp_path / "out" / "All" / "seed0"
    target.mkdir(parents=True)
    (target / CHECKPOINT_FILE).write_bytes(b"an earlier local attempt")
    written = []
    real_replace = os.replace
    monkeypatch.setattr(experiments.os, "replace", lambda a, b: (written.append(Path(b).name), real_replace(a, b)))
    experiments.write_result(target, files, error=None)
    assert written[-1] == DONE_FILE and sorted(written) == sorted(files)
    assert {p.name for p in target.iterdir()} == set(files)  # the stale checkpoint is gone, no .part left
    assert (target / "test_without_T.json").read_text() == "test_without_T.json"

    failed = tmp_path / "out" / "V" / "seed0"
    experiments.write_result(failed, files, error="Traceback: boom")
    assert {p.name for p in failed.iterdir()} == {"train.log"}  # not done: the next grid runs it again
    assert (failed / "train.log").read_text().endswith("train.log\nTraceback: boom")
    assert experiments.run_status(failed) == "todo"


class FakeRay:
    """Just what run_ray uses of Ray: remote tasks as generators, wait, get; `plan` says for each
    run (by seed) how its attempts end: "ok", or "lost" (its node dies mid-run)."""

    class exceptions:  # noqa: N801 (mirrors ray.exceptions)
        class RayError(Exception):
            pass

        class RayTaskError(RayError):
            pass

        class NodeDiedError(RayError):
            pass

    def __init__(self, plan: dict[int, list[str]]):
        self.plan, self.submitted = plan, []

    def remote(self, **options):
        fake = self

        class Remote:
            @staticmethod
            def remote(config, attempt):
                fake.submitted.append((config["seed"], attempt))
                return fake.generator(config["seed"], fake.plan[config["seed"]][attempt - 1], attempt)

        assert options == {"num_cpus": 1, "max_calls": 1, "max_retries": 0}
        return lambda function: Remote

    def generator(self, seed, outcome, attempt):
        node = f"node{seed}{attempt}" + "0" * 20
        yield {"started": node}
        if outcome == "lost":
            raise self.exceptions.NodeDiedError("the node died")
        yield {"node": node, "error": None, "files": {DONE_FILE: json.dumps({"node": node}).encode()}}

    def wait(self, pending, num_returns, timeout):
        return pending[:1], pending[1:]

    def get(self, value):
        return value

    def shutdown(self):
        pass


def test_ray_runs_lost_with_their_node_are_retried_a_bounded_number_of_times(tmp_path):
    fake = FakeRay({0: ["ok"], 1: ["lost", "ok"], 2: ["lost", "lost", "lost"]})
    tasks = [experiments.Task(tmp_path / f"seed{seed}", {"seed": seed}) for seed in range(3)]
    progress = experiments.GridProgress(len(tasks), enabled=False)
    experiments.run_ray(fake, tasks, threads=1, retries=2, progress=progress)
    assert sorted(fake.submitted) == [(0, 1), (1, 1), (1, 2), (2, 1), (2, 2), (2, 3)]
    ok, retried, failed = tasks
    assert (ok.error, ok.attempts, ok.lost) == (None, 1, [])
    assert retried.error is None and retried.attempts == 2 and retried.node.startswith("node12")
    assert json.loads((tmp_path / "seed1" / DONE_FILE).read_text())["node"] == retried.node
    assert failed.attempts == 3 and "lost 3 times" in failed.error and "--retries 2" in failed.error
    assert not (tmp_path / "seed2" / DONE_FILE).exists()
    assert (progress.finished, progress.failed, progress.retried) == (3, 1, 3)
    lines = experiments.report(tasks)
    assert lines[0] == "grid: 3 run(s): 2 finished, 1 failed"
    assert lines[1] == "retried 2 run(s) after a lost worker or node:"
    assert lines[2].startswith(f"  {tmp_path / 'seed1'}: lost 1x (NodeDiedError on node node11") and lines[2].endswith(
        "finished on node node12000000 at attempt 2"
    )
    assert lines[3].startswith(f"  {tmp_path / 'seed2'}: lost 3x") and lines[3].endswith("failed at attempt 3")


def test_usage_mistakes_are_one_line_errors(tmp_path, capsys):
    base = ["--out", str(tmp_path / "grid"), "--groups", "single", "--labels", "T", "--seeds", "1", *TINY]
    for extra, message in (
        (["--threads", "0"], "--threads must be at least 1"),
        (["--retries", "-1"], "--retries and --gpus-per-run at least 0"),
        (["--gpus-per-run", "1"], "--gpus-per-run is for --ray-address"),
    ):
        assert experiments.main([*base, *extra]) == 2
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "grid").exists()


@pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="Ray is not installed")
def test_ray_address_where_no_cluster_answers_is_a_one_line_error(tmp_path, capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # closed again: nothing listens there
    base = ["--out", str(tmp_path / "grid"), "--groups", "single", "--labels", "T", "--seeds", "1", *TINY]
    for address, message in ((f"127.0.0.1:{port}", "no Ray head answers there"), ("nonsense", "expected HOST:PORT")):
        assert experiments.main([*base, "--ray-address", address]) == 2
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "grid").exists()


def _start_grid(out, *extra):
    env = dict(os.environ, PYTHONPATH=f"{Path(__file__).resolve().parent}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "dlo_policy.experiments",
            "--out",
            str(out),
            "--groups",
            "single",
            "--labels",
            "T",
            "--seeds",
            "1",
            "--steps",
            "1000000",
            "--jobs",
            "1",
            "--no-progress",
            *extra,
            *TINY,
        ],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def _worker_pid(run_dir, grid, timeout=120):
    """The pid of the process training into run_dir (from its lock file), once it trains."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and grid.poll() is None:
        lock = run_dir / LOCK_FILE
        if lock.exists() and lock.read_text().strip() and (run_dir / EVAL_FILE).exists():
            return int(lock.read_text())
        time.sleep(0.2)
    raise AssertionError(f"no run started: {grid.communicate(timeout=30)[0][-2000:] if grid.poll() is not None else ''}")


def _gone(pid, timeout=60):
    """True once `pid` has exited (a zombie counts), checked at least once, for up to `timeout` s."""
    deadline = time.monotonic() + timeout
    while not exited(pid):
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.2)
    return True


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_stopping_the_driver_stops_its_runs(tmp_path, sig):
    out = tmp_path / "grid"
    grid = _start_grid(out)
    worker = None
    try:
        worker = _worker_pid(out / "T" / "seed0", grid)
        grid.send_signal(sig)
        output = grid.communicate(timeout=90)[0]
        if sig == signal.SIGTERM:
            assert grid.returncode == 130 and "interrupted" in output, output[-2000:]
        assert _gone(worker), f"the run (pid {worker}) trains on after the driver got {sig.name}"
    finally:
        if grid.poll() is None:
            grid.kill()
        if worker and not _gone(worker, timeout=0):
            with contextlib.suppress(ProcessLookupError):
                os.kill(worker, signal.SIGKILL)


def test_a_second_grid_on_the_same_runs_fails_that_run_in_one_line_and_leaves_the_first_alone(tmp_path, capsys):
    out = tmp_path / "grid"
    grid = _start_grid(out)
    try:
        worker = _worker_pid(out / "T" / "seed0", grid)
        argv = [
            "--out",
            str(out),
            "--groups",
            "single",
            "--labels",
            "T",
            "--seeds",
            "1",
            "--steps",
            "1000000",
            "--jobs",
            "1",
            "--no-progress",
            *TINY,
        ]
        assert experiments.main(argv) == 1
        captured = capsys.readouterr()
        assert f"is in use by another training (pid {worker})" in captured.out + captured.err
        assert "Traceback" not in captured.out + captured.err
        assert grid.poll() is None and not _gone(worker, timeout=0)  # the first grid trains on
    finally:
        grid.terminate()
        grid.communicate(timeout=90)


def test_a_partial_local_run_resumes_from_its_checkpoint_and_one_without_starts_afresh(tmp_path):
    """dlo-experiments --help (Local): a run with a checkpoint under OUT resumes from it (the same run,
    continued: done.json names both parts); a run stopped before its first checkpoint starts again
    from step 0 (its evaluations so far are not kept twice)."""
    import csv

    from dlo_policy import train
    from dlo_policy.rundir import read_done

    tiny = [
        "env_module=sac_reach_env",
        "sac.hidden_sizes=[32,32]",
        "sac.batch_size=32",
        "sac.learning_starts=50",
        "sac.buffer_size=2000",
        "train.eval_every=100",
        "train.num_threads=1",
        "train.test_episodes=10",
        "train.progress=false",
        "train.total_steps=300",
        "train.checkpoint_every=200",
    ]
    crashing = load_config(None, [*tiny, "env_options.crash_after=250"])
    partial = tmp_path / "partial"
    with pytest.raises(InterruptedError):
        train.train(crashing, partial)
    assert (partial / CHECKPOINT_FILE).exists() and not (partial / DONE_FILE).exists()
    experiments.run_one(crashing.to_dict(), str(partial))

    def steps(run):
        with (run / EVAL_FILE).open(newline="") as f:
            return [int(row["step"]) for row in csv.DictReader(f)]

    assert [s["from_step"] for s in read_done(partial)["sources"]] == [0, 200]
    assert steps(partial) == [0, 100, 200, 300]

    fresh = tmp_path / "fresh"  # stopped after its first evaluation, before any checkpoint
    early = load_config(None, [*tiny, "env_options.crash_after=120"])
    with pytest.raises(InterruptedError):
        train.train(early, fresh)
    assert not (fresh / CHECKPOINT_FILE).exists() and steps(fresh) == [0, 100]
    experiments.run_one(load_config(None, tiny).to_dict(), str(fresh))
    assert [s["from_step"] for s in read_done(fresh)["sources"]] == [0]
    assert steps(fresh) == [0, 100, 200, 300]


def test_ctrl_c_stops_the_grid_and_its_run_at_an_episode_end_with_a_checkpoint_the_next_start_resumes(tmp_path):
    """dlo-experiments --help: Ctrl-C (SIGINT to the terminal's whole process group: the driver and its workers)
    stops the local runs at the end of their episodes with a checkpoint there (here the only one: checkpoint_every
    lies beyond the run), exit 130, no traceback (the driver's output nor the run's train.log); the same command
    again resumes the run from that step."""
    out = tmp_path / "grid"
    run = out / "T" / "seed0"
    env = dict(os.environ, PYTHONPATH=f"{Path(__file__).resolve().parent}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    grid_args = [
        "--out",
        str(out),
        "--groups",
        "single",
        "--labels",
        "T",
        "--seeds",
        "1",
        "--jobs",
        "1",
        "--no-progress",
        *TINY,
        "train.checkpoint_every=100000000",
        "train.test_episodes=4",
    ]
    grid = subprocess.Popen(
        [sys.executable, "-m", "dlo_policy.experiments", *grid_args, "--steps", "1000000"],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # as from a terminal
    worker = None
    try:
        worker = _worker_pid(run, grid)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and len((run / EVAL_FILE).read_text().splitlines()) < 3:  # step 50 evaluated
            time.sleep(0.1)
        os.killpg(grid.pid, signal.SIGINT)
        output = grid.communicate(timeout=300)[0]
        assert grid.returncode == 130 and "interrupted" in output, output[-3000:]
        assert "Traceback" not in output and "KeyboardInterrupt" not in output, output[-3000:]
        assert _gone(worker)
    finally:
        if grid.poll() is None:
            os.killpg(grid.pid, signal.SIGKILL)
            grid.communicate()
    from dlo_policy.sac import read_checkpoint

    step = read_checkpoint(run / CHECKPOINT_FILE)["counters"]["env_steps"]
    assert step >= 50 and "Traceback" not in (run / "train.log").read_text()
    assert experiments.main([*grid_args, "--steps", str(step + 30)]) == 0
    assert [s["from_step"] for s in json.loads((run / DONE_FILE).read_text())["sources"]] == [0, step]
