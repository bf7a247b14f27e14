"""dlo-experiments piece by piece, in-process and fast: no run trains, no process is spawned, no Ray
cluster is started (stand-ins for the trainer, the process pool and Ray record what the driver does)."""

import concurrent.futures
import concurrent.futures.process
import io
import json
import os
import signal
import socket
import sys
from pathlib import Path

import pytest
from dlo_policy import experiments, rundir
from dlo_policy.config import load_config
from dlo_policy.rundir import CHECKPOINT_FILE, DONE_FILE, EVAL_FILE, LOCK_FILE, LOG_FILE

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib: sac_reach_env

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


class Clock:
    """time.monotonic / time.perf_counter reading the given values in turn."""

    def __init__(self, *readings):
        self.readings = list(readings)

    def monotonic(self):
        return self.readings.pop(0)

    perf_counter = monotonic


# ------------------------------------------------------------------ output_to
def test_output_to_flushes_python_buffers_on_both_sides_and_closes_what_it_opened(tmp_path, capfd, monkeypatch):
    """What Python buffered before goes to the old stdout/stderr, what it buffered inside goes to the log,
    both descriptors come back, and no descriptor is left open."""
    out = io.TextIOWrapper(io.BufferedWriter(io.FileIO(1, "w", closefd=False), 1 << 16))
    err = io.TextIOWrapper(io.BufferedWriter(io.FileIO(2, "w", closefd=False), 1 << 16))
    monkeypatch.setattr(sys, "stdout", out)
    monkeypatch.setattr(sys, "stderr", err)
    log = tmp_path / "train.log"
    fds = len(os.listdir("/proc/self/fd"))
    out.write("before out|")
    err.write("before err|")
    with experiments.output_to(log):
        out.write("inside out|")
        err.write("inside err|")
    out.write("after out|")
    err.write("after err|")
    out.flush()
    err.flush()
    assert len(os.listdir("/proc/self/fd")) == fds
    monkeypatch.undo()
    assert log.read_text() == "inside out|inside err|"
    captured = capfd.readouterr()
    assert (captured.out, captured.err) == ("before out|after out|", "before err|after err|")


# ------------------------------------------------------------------ run_one, stamp_done, _run_local_task
class StubTrainer:
    made: list = []

    def __init__(self, config, path, resume=False, stop=None):
        StubTrainer.made.append((config.seed, path, resume, sorted(p.name for p in path.iterdir())))
        self.path = path

    def run(self):
        os.write(1, b"stdout\n")
        os.write(2, b"stderr\n")
        assert (self.path / LOCK_FILE).read_text().strip() == str(os.getpid())  # the run holds its directory
        with pytest.raises(rundir.RunInUse):
            with rundir.lock(self.path):
                pass
        return {"env_steps": 7}


def test_run_one_resumes_only_from_a_checkpoint_and_writes_its_output_to_train_log(tmp_path, monkeypatch):
    monkeypatch.setattr(StubTrainer, "made", [])
    monkeypatch.setattr(experiments, "Trainer", StubTrainer)
    config = load_config(None, [*TINY, "seed=3"]).to_dict()
    fresh = tmp_path / "fresh"  # nothing there yet
    assert experiments.run_one(config, str(fresh)) == {"env_steps": 7}
    stopped = tmp_path / "stopped"  # stopped before its first checkpoint: its evaluations are dropped
    stopped.mkdir()
    (stopped / EVAL_FILE).write_text("step\n0\n")
    experiments.run_one(config, str(stopped))
    partial = tmp_path / "partial"  # a checkpoint: resumed, its evaluations kept
    partial.mkdir()
    (partial / EVAL_FILE).write_text("step\n0\n")
    (partial / CHECKPOINT_FILE).write_bytes(b"")
    experiments.run_one(config, str(partial))
    assert StubTrainer.made == [
        (3, fresh, False, [LOCK_FILE, LOG_FILE]),
        (3, stopped, False, [LOCK_FILE, LOG_FILE]),
        (3, partial, True, [LOCK_FILE, CHECKPOINT_FILE, EVAL_FILE, LOG_FILE]),
    ]
    for run in (fresh, stopped, partial):
        assert (run / LOG_FILE).read_text() == "stdout\nstderr\n"


def write_done(run, summary):
    run.mkdir(parents=True, exist_ok=True)
    rundir.write_done(run, summary)


def test_stamp_done_adds_where_and_how_long_the_run_ran(tmp_path):
    write_done(tmp_path, {"env_steps": 60})
    experiments.stamp_done(tmp_path, "node7", 12.3456, 2)
    assert rundir.read_done(tmp_path) == {
        "env_steps": 60,
        "node": "node7",
        "host": socket.gethostname(),
        "duration_s": 12.35,
        "attempts": 2,
    }


def test_a_local_task_stamps_its_run_and_returns_errors_as_text(tmp_path, monkeypatch):
    def run_one(config, run_dir):
        if config["fail"] == "in use":
            raise rundir.RunInUse(f"{run_dir} is in use by another training (pid 1)")
        if config["fail"] == "boom":
            raise RuntimeError("boom")
        write_done(Path(run_dir), {"env_steps": 5})

    monkeypatch.setattr(experiments, "run_one", run_one)
    monkeypatch.setattr(experiments, "time", Clock(100.0, 103.5, 0.0, 1.0, 0.0, 1.0))
    run = tmp_path / "run"
    run.mkdir()
    assert experiments._run_local_task({"fail": None}, str(run)) == (str(run), None)
    assert rundir.read_done(run) == {
        "env_steps": 5,
        "node": "local",
        "host": socket.gethostname(),
        "duration_s": 3.5,
        "attempts": 1,
    }
    assert experiments._run_local_task({"fail": "in use"}, "x") == ("x", "x is in use by another training (pid 1)")
    path, error = experiments._run_local_task({"fail": "boom"}, "y")
    assert path == "y" and error.startswith("Traceback") and error.rstrip().endswith("RuntimeError: boom")


def test_task_failed_means_it_has_an_error():
    assert not experiments.Task(Path("a"), {}).failed
    assert experiments.Task(Path("a"), {}, error="why").failed


# ------------------------------------------------------------------ _die_with_the_driver
class FakeLibc:
    def __init__(self, calls):
        self.calls = calls

    def prctl(self, *args):
        self.calls.append(("prctl", *args))


def test_a_worker_asks_the_kernel_for_sigterm_when_the_driver_dies(monkeypatch):
    import ctypes

    calls, exits = [], []
    monkeypatch.setattr(ctypes, "CDLL", lambda name, **kwargs: calls.append(("CDLL", name, kwargs)) or FakeLibc(calls))
    monkeypatch.setattr(os, "_exit", lambda code: exits.append(code))
    monkeypatch.setattr(os, "getppid", lambda: 4242)
    experiments._die_with_the_driver()
    assert calls == [("CDLL", None, {"use_errno": True}), ("prctl", 1, int(signal.SIGTERM))]  # PR_SET_PDEATHSIG
    assert exits == []
    monkeypatch.setattr(os, "getppid", lambda: 1)  # the driver died before prctl took effect
    experiments._die_with_the_driver()
    assert exits == [1]

    def no_libc(name, **kwargs):
        raise OSError("no libc")

    monkeypatch.setattr(ctypes, "CDLL", no_libc)
    experiments._die_with_the_driver()  # elsewhere a no-op
    monkeypatch.setattr(ctypes, "CDLL", lambda name, **kwargs: object())  # no prctl
    experiments._die_with_the_driver()
    assert exits == [1]


# ------------------------------------------------------------------ GridProgress
def test_grid_progress_prints_a_line_per_run_and_a_bar_of_the_counts(capsys):
    progress = experiments.GridProgress(3, enabled=True)
    assert "done=0 running=0 failed=0 retried=0" in capsys.readouterr().err  # shown from the start
    progress.refresh(running=2)
    assert "running=2" in capsys.readouterr().err  # a change of the counts is shown at once
    progress.refresh()
    assert progress.running == 2
    progress.done(experiments.Task(Path("a"), {}), " (node n1)")
    progress.done(experiments.Task(Path("b"), {}, error="Traceback\nboom"))
    progress.retried += 1
    progress.refresh(running=1)
    captured = capsys.readouterr()
    assert captured.out == "[1/3] a: ok (node n1)\n[2/3] b: FAILED\nTraceback\nboom\n"
    assert "runs:" in captured.err and "2/3" in captured.err and ("run/s" in captured.err or "s/run" in captured.err)
    assert "done=1 running=1 failed=1 retried=1" in captured.err
    assert (progress.finished, progress.failed) == (2, 1)
    progress.running = 0
    progress.close()
    assert "done=1 running=0 failed=1 retried=1" in capsys.readouterr().err


def test_grid_progress_lines_are_flushed_and_a_disabled_bar_prints_nothing(capsys, monkeypatch):
    raw = io.BytesIO()
    monkeypatch.setattr(sys, "stdout", io.TextIOWrapper(raw, write_through=False))
    progress = experiments.GridProgress(2, enabled=False)
    progress.log("[start] run on node n")
    assert raw.getvalue() == b"[start] run on node n\n"  # in the log file at once, not when a buffer fills
    progress.done(experiments.Task(Path("a"), {}))
    progress.close()
    monkeypatch.undo()
    assert capsys.readouterr().err == ""


# ------------------------------------------------------------------ run_local
class FakePool:
    made: list = []

    def __init__(self, **kwargs):
        self.kwargs, self.shutdowns, self.submitted = kwargs, [], []
        self._processes = {1: FakeWorker(), 2: FakeWorker()}
        FakePool.made.append(self)

    def submit(self, function, config, run_dir):
        self.submitted.append((function, config, run_dir))
        future = concurrent.futures.Future()
        outcome = config["outcome"]
        if outcome == "broken":
            future.set_exception(concurrent.futures.process.BrokenProcessPool("died"))
        elif outcome == "interrupt":
            future.set_exception(KeyboardInterrupt())
        else:
            future.set_result((run_dir, None if outcome == "ok" else outcome))
        return future

    def shutdown(self, **kwargs):
        self.shutdowns.append(kwargs)


class FakeWorker:
    def __init__(self):
        self.calls = []

    def terminate(self):
        self.calls.append("terminate")

    def join(self, timeout=None):
        self.calls.append(("join", timeout))

    def is_alive(self):
        return False


@pytest.fixture
def pool(monkeypatch):
    monkeypatch.setattr(FakePool, "made", [])
    monkeypatch.setattr(concurrent.futures, "ProcessPoolExecutor", FakePool)
    return FakePool


def test_run_local_runs_each_task_in_a_fresh_spawned_process_jobs_at_a_time(pool, monkeypatch):
    tasks = [experiments.Task(Path(f"r{i}"), {"outcome": o}) for i, o in enumerate(["ok", "Traceback: x", "broken"])]
    progress = experiments.GridProgress(3, enabled=False)
    running, refreshed = [], []
    monkeypatch.setattr(progress, "refresh", lambda running=None: refreshed.append(running))
    real_done = progress.done
    monkeypatch.setattr(progress, "done", lambda task, where="": (running.append(progress.running), real_done(task)))
    experiments.run_local(tasks, 2, progress)
    (made,) = pool.made
    assert made.kwargs["max_workers"] == 2 and made.kwargs["max_tasks_per_child"] == 1
    assert made.kwargs["mp_context"].get_start_method() == "spawn"
    assert made.kwargs["initializer"] is experiments._die_with_the_driver
    assert made.submitted == [(experiments._run_local_task, t.config, str(t.run_dir)) for t in tasks]
    assert [(t.attempts, t.node) for t in tasks] == [(1, "local")] * 3
    assert tasks[0].error is None and tasks[1].error == "Traceback: x"
    assert tasks[2].error.startswith("its process died (killed, out of memory?) and took the process pool down")
    assert running == [2, 1, 0] and progress.finished == 3
    assert refreshed == [2]  # shown at the start: as many running as jobs (or tasks, if fewer)
    assert made.shutdowns == [{"wait": True}]


def test_run_local_stops_its_workers_when_interrupted(pool):
    tasks = [experiments.Task(Path("r0"), {"outcome": "interrupt"})]
    with pytest.raises(KeyboardInterrupt):
        experiments.run_local(tasks, 1, experiments.GridProgress(1, enabled=False))
    (made,) = pool.made
    assert made.shutdowns == [{"wait": False, "cancel_futures": True}]
    for worker in made._processes.values():  # SIGTERM: the run stops at its episode's end, checkpointed
        assert worker.calls == ["terminate", ("join", pytest.approx(experiments.STOP_WAIT, abs=5))]


# ------------------------------------------------------------------ Ray pieces
def test_result_files_send_the_end_of_a_long_train_log(tmp_path):
    (tmp_path / DONE_FILE).write_text("{}")
    (tmp_path / LOG_FILE).write_bytes(b"a" * 10 + b"b" * experiments.MAX_LOG_BYTES)
    files = experiments.result_files(tmp_path)
    assert files[LOG_FILE] == b"b" * experiments.MAX_LOG_BYTES and files[DONE_FILE] == b"{}"


class FakeRayModule:
    def __init__(self, nodes=(), init_error=None):
        self._nodes, self.init_error, self.inits, self.shutdowns = list(nodes), init_error, [], 0

    def get_runtime_context(self):
        return type("Context", (), {"get_node_id": staticmethod(lambda: "nodeA" + "0" * 20)})()

    def init(self, **kwargs):
        self.inits.append(kwargs)
        if self.init_error:
            raise self.init_error

    def nodes(self):
        return self._nodes

    def shutdown(self):
        self.shutdowns += 1


def test_a_ray_task_says_where_it_starts_then_sends_back_its_files(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", FakeRayModule())
    seen = []

    def run_one(config, run_dir, stop_signals=True):
        assert stop_signals is False  # a Ray worker's signals keep Ray's handlers
        seen.append(Path(run_dir))
        if config.get("fail"):
            (Path(run_dir) / LOG_FILE).write_text("log")
            raise RuntimeError("diverged")
        for name in ("config.yaml", LOG_FILE, CHECKPOINT_FILE):
            (Path(run_dir) / name).write_text(name)
        write_done(Path(run_dir), {"env_steps": 5})

    monkeypatch.setattr(experiments, "run_one", run_one)
    monkeypatch.setattr(experiments, "time", Clock(10.0, 14.25))
    messages = list(experiments._ray_task({"seed": 0}, 2))
    node = "nodeA" + "0" * 20
    assert messages[0] == {"started": node}
    assert set(messages[1]) == {"node", "error", "files"} and (messages[1]["node"], messages[1]["error"]) == (node, None)
    files = messages[1]["files"]
    assert set(files) == {"config.yaml", LOG_FILE, DONE_FILE}  # never the checkpoint
    assert json.loads(files[DONE_FILE]) == {
        "env_steps": 5,
        "node": node,
        "host": socket.gethostname(),
        "duration_s": 4.25,
        "attempts": 2,
    }
    assert seen[0].name.startswith("dlo-run-") and not seen[0].exists()  # a temporary directory, gone afterwards
    monkeypatch.setattr(experiments, "time", Clock(0.0, 1.0))
    failed = list(experiments._ray_task({"fail": True}, 1))[1]
    assert failed["error"].startswith("Traceback") and "RuntimeError: diverged" in failed["error"]
    assert failed["files"] == {LOG_FILE: b"log"}


def test_connect_ray_checks_the_head_answers_then_connects_quietly(monkeypatch):
    import logging

    fake = FakeRayModule()
    monkeypatch.setattr(experiments, "import_ray", lambda: fake)
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        port = server.getsockname()[1]
        for address in ("auto", "ray://127.0.0.1:1", f"127.0.0.1:{port}"):
            assert experiments.connect_ray(address) is fake
            assert fake.inits[-1] == {"address": address, "log_to_driver": False, "logging_level": logging.WARNING}
    for address in (":6379", "headnode", "headnode:port"):
        with pytest.raises(experiments.GridError, match=f"^--ray-address {address}: expected HOST:PORT"):
            experiments.connect_ray(address)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        closed = s.getsockname()[1]
    with pytest.raises(
        experiments.GridError,
        match=f"^--ray-address 127.0.0.1:{closed}: no Ray head answers there "
        r"\(Connection refused\); start one with ray start --head$",
    ):
        experiments.connect_ray(f"127.0.0.1:{closed}")
    assert len(fake.inits) == 3
    for error, why in (
        (ConnectionError("first line\nsecond line"), "first line"),
        (RuntimeError(""), "RuntimeError"),
        (ValueError("bad"), "bad"),
    ):
        fake.init_error = error
        with pytest.raises(experiments.GridError) as caught:
            experiments.connect_ray("auto")
        assert str(caught.value) == f"--ray-address auto: no Ray cluster to connect to ({why})"


def test_a_ray_head_that_never_answers_is_given_10_s(monkeypatch):
    asked = []

    def never(address, timeout=None):
        asked.append((address, timeout))
        raise TimeoutError("timed out")

    monkeypatch.setattr(experiments, "import_ray", lambda: FakeRayModule())
    monkeypatch.setattr(experiments.socket, "create_connection", never)
    with pytest.raises(experiments.GridError) as caught:
        experiments.connect_ray("[::1]:6379")
    assert str(caught.value) == (
        "--ray-address [::1]:6379: no Ray head answers there (TimeoutError); start one with ray start --head"
    )
    assert asked == [(("::1", 6379), 10)]


def test_import_ray_only_when_asked_with_a_clear_exit_without_it(monkeypatch):
    fake = FakeRayModule()
    monkeypatch.setitem(sys.modules, "ray", fake)
    assert experiments.import_ray() is fake
    monkeypatch.setitem(sys.modules, "ray", None)  # not installed
    with pytest.raises(SystemExit) as caught:
        experiments.import_ray()
    assert str(caught.value) == (
        "dlo-experiments: --ray-address needs Ray, which is not installed: pip install ray "
        "(or leave out --ray-address to run local processes)"
    )


def test_makespan_places_the_longest_runs_first_and_needs_one_worker():
    assert experiments.makespan([1, 1, 2], jobs=2) == 2  # 2 | 1 + 1, not 1 + 2 | 1
    assert experiments.makespan([2, 3], jobs=0) == 5
    assert experiments.makespan([], jobs=3) == 0


def test_check_capacity_wants_one_live_node_with_the_cpus_and_gpus_of_a_run():
    fake = FakeRayModule(
        [
            {"Alive": True, "Resources": {"CPU": 2.0}},
            {"Alive": True, "Resources": {"CPU": 4.0, "GPU": 1.0}},
            {"Alive": False, "Resources": {"CPU": 64.0, "GPU": 8.0}},
        ]
    )
    experiments.check_capacity(fake, 2)
    experiments.check_capacity(fake, 4)
    experiments.check_capacity(fake, 4, 1.0)
    with pytest.raises(experiments.GridError) as caught:
        experiments.check_capacity(fake, 5)
    assert str(caught.value) == (
        "no node of the Ray cluster has 5 CPUs for a run (at most 4 CPUs, 1 GPUs per node): "
        "lower --threads / --gpus-per-run, or add bigger nodes"
    )
    with pytest.raises(experiments.GridError, match=r"has 2 CPUs and 1.5 GPU\(s\) for a run \(at most 4 CPUs, 1 GPUs"):
        experiments.check_capacity(fake, 2, 1.5)
    with pytest.raises(experiments.GridError, match=r"has 1 CPUs for a run \(at most 0 CPUs, 0 GPUs per node\)"):
        experiments.check_capacity(FakeRayModule([]), 1)
    with pytest.raises(experiments.GridError, match=r"has 1 CPUs for a run \(at most 0 CPUs, 0 GPUs per node\)"):
        experiments.check_capacity(FakeRayModule([{"Alive": True, "Resources": {}}]), 1)
    with pytest.raises(experiments.GridError, match=r"and 1 GPU\(s\) for a run \(at most 8 CPUs, 0 GPUs per node\)"):
        experiments.check_capacity(FakeRayModule([{"Alive": True, "Resources": {"CPU": 8.0}}]), 1, 1.0)


class FakeRay:
    """run_ray's view of Ray: `plan[seed]` lists how each attempt ends: ok, lost (node dies after it
    started), lost-early (before it started), vanished (the generator just ends), error (the task raised)."""

    class exceptions:  # noqa: N801
        class RayError(Exception):
            pass

        class RayTaskError(RayError):
            pass

        class NodeDiedError(RayError):
            pass

    def __init__(self, plan):
        self.plan, self.options, self.shutdowns = plan, [], 0

    def remote(self, **options):
        self.options.append(options)
        fake = self

        class Remote:
            @staticmethod
            def remote(config, attempt):
                return fake.generator(config["seed"], fake.plan[config["seed"]][attempt - 1], attempt)

        return lambda function: Remote

    def generator(self, seed, outcome, attempt):
        node = f"node{seed}{attempt}" + "0" * 20
        if outcome == "lost-early":
            raise self.exceptions.NodeDiedError("gone")
        yield {"started": node}
        if outcome == "lost":
            raise self.exceptions.NodeDiedError("the node died")
        if outcome == "error":
            raise self.exceptions.RayTaskError("the task raised")
        if outcome == "vanished":
            return
        if outcome == "failed":  # the run itself failed on the worker: its log and the traceback come back
            yield {"node": node, "error": "Traceback: diverged", "files": {LOG_FILE: b"log"}}
            return
        yield {"node": node, "error": None, "files": {DONE_FILE: b"{}"}}

    def wait(self, pending, num_returns, timeout):
        assert num_returns == 1 and timeout == 1.0
        return pending[:1], pending[1:]

    def get(self, value):
        return value

    def shutdown(self):
        self.shutdowns += 1


def test_run_ray_reports_starts_retries_and_task_errors(tmp_path, capsys):
    fake = FakeRay({0: ["error"], 1: ["lost-early", "vanished", "ok"], 2: ["failed"]})
    tasks = [experiments.Task(tmp_path / f"seed{seed}", {"seed": seed}) for seed in range(3)]
    progress = experiments.GridProgress(3, enabled=False)
    shown, real_refresh = [], progress.refresh

    def refresh(running=None):
        real_refresh(running)
        shown.append(progress.running)

    progress.refresh = refresh
    experiments.run_ray(fake, tasks, threads=2, retries=2, progress=progress, gpus=0.5)
    failed = tasks.pop()
    assert failed.error == "Traceback: diverged" and (tmp_path / "seed2" / LOG_FILE).read_text() == "log\nTraceback: diverged"
    assert not (tmp_path / "seed2" / DONE_FILE).exists()
    assert fake.options == [{"num_cpus": 2, "num_gpus": 0.5, "max_calls": 1, "max_retries": 0}]
    assert fake.shutdowns == 1
    error, retried = tasks
    assert error.error == "the task raised" and error.attempts == 1 and error.lost == []
    assert retried.error is None and retried.attempts == 3
    assert retried.lost == ["NodeDiedError", "StopIteration on node node12000000"]
    assert (progress.finished, progress.failed, progress.retried, progress.running) == (3, 2, 2, 0)
    assert shown == [1, 1, 2, 1, 2, 1, 0, 1, 0]  # the runs that have started on a node, after each message
    out = capsys.readouterr().out
    assert f"[start] {tmp_path / 'seed0'} on node node01000000 (attempt 1)\n" in out
    assert f"[retry] {tmp_path / 'seed1'}: attempt 1 lost (NodeDiedError); starting attempt 2\n" in out
    assert f"[retry] {tmp_path / 'seed1'}: attempt 2 lost (StopIteration on node node12000000); starting attempt 3\n" in out
    assert f"{tmp_path / 'seed1'}: ok (node node13000000)\n" in out
    assert (tmp_path / "seed1" / DONE_FILE).exists() and not (tmp_path / "seed0").exists()


def test_run_ray_shuts_ray_down_even_when_interrupted():
    fake = FakeRay({0: ["ok"]})

    def interrupted(pending, num_returns, timeout):
        raise KeyboardInterrupt

    fake.wait = interrupted
    with pytest.raises(KeyboardInterrupt):
        experiments.run_ray(fake, [experiments.Task(Path("r"), {"seed": 0})], 1, 0, experiments.GridProgress(1, enabled=False))
    assert fake.shutdowns == 1


# ------------------------------------------------------------------ estimate
def test_estimate_calibrates_on_the_most_expensive_configuration_and_skips_finished_runs(tmp_path, monkeypatch):
    probes = []
    monkeypatch.setattr(
        experiments, "calibrate", lambda config: probes.append(config.modalities) or experiments.Calibration(1.0, 3.0)
    )
    specs = [experiments.RunSpec(label, label, 0) for label in ("K", "T+K", "V", "T+V", "All")]
    configs = [
        experiments.run_config(s, None, ["train.eval_every=100", "train.test_episodes=10", "train.eval_episodes=10"], 1000, 1)
        for s in specs
    ]
    partial = specs[1].directory(tmp_path)
    partial.mkdir(parents=True)
    (partial / EVAL_FILE).write_text("step\n0\n600\n")
    (partial / CHECKPOINT_FILE).write_bytes(b"")
    statuses = ["todo", "partial", "todo", "todo", "done"]
    text = experiments.estimate(specs, configs, statuses, tmp_path, jobs=2)
    assert probes == ["T+V"]  # vision renders: the dearest of the runs still to do (All is done)
    whole, rest = 1000 * 1.0 + (11 + 1) * 3.0, 400 * 1.0 + (4 + 1) * 3.0  # 1000 s + 36 s; 400 s + 15 s
    assert text == (
        f"estimate: 4 runs, {(3 * whole + rest) / 3600:.1f} run-hours, wall ~{experiments._duration(2 * whole)}"
        " on 2 job(s) (calibrated now on T+V: 1000 ms per step with its update, 3.0 s per evaluation of 10 "
        "episodes; other load on this machine is included)"
    )
    again = experiments.estimate(specs, configs, statuses, tmp_path, jobs=1, resume_partial=False)
    assert f"~{experiments._duration(4 * whole)} on 1 job(s)" in again and experiments._duration(4 * whole) == "1.2 h"
    assert experiments.estimate(specs, configs, ["done"] * 5, tmp_path, jobs=1) == "estimate: nothing to run"
    assert probes == ["T+V", "T+V"]
    assert experiments._duration(3599) == "60 min" and experiments._duration(3600) == "1.0 h"
    assert experiments._duration(5400) == "1.5 h" and experiments._duration(90) == "2 min"


# ------------------------------------------------------------------ the command line
def test_help_describes_the_grid_and_every_option(capsys):
    with pytest.raises(SystemExit) as exit_info:
        experiments.main(["--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: dlo-experiments ")
    assert "\n    single       T, K, V, All\n" in out  # the module docstring as laid out
    flat = " ".join(out.split())
    for text in (
        "Overrides (key=value) apply to every run, e.g. train.eval_every=500.",
        "--out OUT results directory (one subdirectory per run)",
        "--groups GROUPS comma-separated subset of single,pairs,ablation,sensitivity,robust (default: the paper's, "
        "single,pairs,ablation,sensitivity)",
        "--labels LABELS only these configuration labels (comma-separated), e.g. All,V,T,K; a run directory's name works too",
        "--seeds SEEDS seeds per configuration (default 3)",
        "--first-seed FIRST_SEED seeds are first-seed .. first-seed + seeds - 1",
        "--steps STEPS env steps per run (default: the config's, 50000)",
        "--config CONFIG YAML config for every run",
        "--threads THREADS torch threads (and Ray CPUs) per run (default 1)",
        "--jobs JOBS parallel local runs (default: cores // threads); with --dry-run: the number of workers",
        "--ray-address RAY_ADDRESS run on this Ray cluster instead: HOST:PORT of its head",
        "--gpus-per-run GPUS_PER_RUN Ray: GPUs each run reserves",
        "--retries RETRIES Ray: times a run whose worker or node was lost is started again (default 2)",
        "--resume continue a grid in --out: finished runs (done.json) are skipped",
        "--no-progress no progress bar over the runs",
        "--dry-run list the runs and their status, estimate the wall time",
        "--collect RESULTS train nothing: copy the small files of every finished run",
        "key=value config overrides for every run",
    ):
        assert text in flat, text


def test_the_defaults_are_the_documented_ones(tmp_path):
    args = experiments.build_parser().parse_args(["--out", str(tmp_path)])
    assert (args.out, args.groups, args.labels, args.seeds, args.first_seed, args.steps, args.config) == (
        tmp_path,
        "single,pairs,ablation,sensitivity",
        None,
        3,
        0,
        None,
        None,
    )
    assert (args.threads, args.jobs, args.ray_address, args.gpus_per_run, args.retries) == (1, None, None, 0.0, 2)
    assert (args.resume, args.no_progress, args.dry_run, args.collect, args.overrides) == (False, False, False, None, [])
    args = experiments.build_parser().parse_args(
        [
            "--out",
            "o",
            "--seeds",
            "2",
            "--first-seed",
            "5",
            "--steps",
            "9",
            "--config",
            "c.yaml",
            "--threads",
            "2",
            "--jobs",
            "3",
            "--gpus-per-run",
            "0.25",
            "--retries",
            "4",
            "--resume",
            "--no-progress",
            "--dry-run",
            "--collect",
            "r",
            "a=1",
            "b=2",
        ]
    )
    assert (args.seeds, args.first_seed, args.steps, args.config, args.threads, args.jobs) == (2, 5, 9, Path("c.yaml"), 2, 3)
    assert (args.gpus_per_run, args.retries, args.resume, args.no_progress, args.dry_run, args.collect) == (
        0.25,
        4,
        True,
        True,
        True,
        Path("r"),
    )
    assert args.overrides == ["a=1", "b=2"]
    with pytest.raises(SystemExit):
        experiments.build_parser().parse_args([])  # --out is required


class Driver:
    """main's collaborators, recorded: run_local, Ray (connect, capacity, run_ray), estimate, the cores."""

    def __init__(self, monkeypatch, cores=4, outcomes=None):
        self.local, self.ray_runs, self.estimates, self.connected = [], [], [], []
        self.outcomes = outcomes or {}  # run directory name (label) -> error text or "interrupt"
        self.capacity_error = None
        self.ray = FakeRayModule()
        monkeypatch.setattr(experiments, "available_cores", lambda: cores)
        monkeypatch.setattr(experiments, "run_local", self.run_local)
        monkeypatch.setattr(experiments, "import_ray", lambda: self.ray)
        monkeypatch.setattr(experiments, "connect_ray", lambda address: self.connected.append(address) or self.ray)
        monkeypatch.setattr(experiments, "check_capacity", self.check_capacity)
        monkeypatch.setattr(experiments, "run_ray", self.run_ray)
        monkeypatch.setattr(experiments, "estimate", self.estimate)
        self.handlers = []  # signal handlers main installs (recorded, not installed in the test process)
        monkeypatch.setattr(experiments.signal, "signal", lambda sig, handler: self.handlers.append((sig, handler)))

    def finish(self, tasks, progress):
        for task in tasks:
            outcome = self.outcomes.get(task.run_dir.parent.name)
            if outcome == "interrupt":
                raise KeyboardInterrupt
            if outcome == "grid error":
                raise experiments.GridError("the cluster went away")
            task.error = outcome
            if outcome is None:
                write_done(task.run_dir, {"env_steps": 1})
            progress.done(task)

    def run_local(self, tasks, jobs, progress):
        self.local.append((tasks, jobs))
        self.finish(tasks, progress)

    def run_ray(self, ray, tasks, threads, retries, progress, gpus=0.0):
        self.ray_runs.append((ray, tasks, threads, retries, gpus))
        self.finish(tasks, progress)

    def check_capacity(self, ray, threads, gpus=0.0):
        if self.capacity_error:
            raise experiments.GridError(self.capacity_error)

    def estimate(self, specs, configs, statuses, out, jobs, resume_partial=True):
        self.estimates.append(([s.label for s in specs], statuses, out, jobs, resume_partial))
        return "estimate: stub"


def grid_args(out, *extra, overrides=()):
    return [
        "--out",
        str(out),
        "--groups",
        "single",
        "--labels",
        "T,V",
        "--seeds",
        "1",
        "--no-progress",
        *extra,
        *TINY,
        *overrides,
    ]


def test_main_lists_the_runs_runs_the_rest_and_reports(tmp_path, monkeypatch, capsys):
    driver = Driver(monkeypatch)
    out = tmp_path / "grid"
    write_done(out / "T" / "seed0", {"env_steps": 1})
    assert experiments.main(grid_args(out, "--steps", "70", "--threads", "2", overrides=["sac.batch_size=8"])) == 0
    captured = capsys.readouterr()
    assert captured.out.splitlines() == [
        f"done     {out / 'T' / 'seed0'}  (single)",
        f"todo     {out / 'V' / 'seed0'}  (single)",
        "2 runs, 1 done, 1 to run",
        f"[1/1] {out / 'V' / 'seed0'}: ok",
        "grid: 1 run(s): 1 finished, 0 failed",
    ]
    assert captured.err == ""
    ((tasks, jobs),) = driver.local
    assert jobs == 2  # 4 cores // 2 threads
    (task,) = tasks
    assert task.run_dir == out / "V" / "seed0" and task.attempts == 0
    config = task.config
    assert (
        config["modalities"],
        config["seed"],
        config["train"]["total_steps"],
        config["train"]["num_threads"],
        config["sac"]["batch_size"],
    ) == ("V", 0, 70, 2, 8)
    assert driver.handlers == [(signal.SIGTERM, experiments._interrupt)]  # SIGTERM stops the runs like Ctrl-C
    with pytest.raises(KeyboardInterrupt, match="signal 15"):
        experiments._interrupt(15, None)


def test_main_picks_seeds_labels_and_groups_as_asked(tmp_path, monkeypatch, capsys):
    driver = Driver(monkeypatch)
    out = tmp_path / "grid"
    assert (
        experiments.main(
            [
                "--out",
                str(out),
                "--groups",
                " single , ,",
                "--labels",
                " K , , All ,",
                "--seeds",
                "2",
                "--first-seed",
                "4",
                "--no-progress",
                *TINY,
            ]
        )
        == 0
    )
    ((tasks, jobs),) = driver.local
    assert [(t.run_dir.parent.name, t.run_dir.name) for t in tasks] == [
        ("K", "seed4"),
        ("All", "seed4"),
        ("K", "seed5"),
        ("All", "seed5"),
    ]
    assert jobs == 4
    assert "4 runs, 0 done, 4 to run" in capsys.readouterr().out


def test_a_label_is_also_its_directory_name(tmp_path, monkeypatch, capsys):
    """'All tactile-partial' runs in All_tactile-partial/: either spelling picks it (a user copies the directory)."""
    driver = Driver(monkeypatch)
    for k, spelling in enumerate(("All tactile-partial", "All_tactile-partial")):
        assert (
            experiments.main(
                [
                    "--out",
                    str(tmp_path / f"grid{k}"),
                    "--groups",
                    "sensitivity",
                    "--labels",
                    spelling,
                    "--seeds",
                    "1",
                    "--no-progress",
                    *TINY,
                ]
            )
            == 0
        )
        assert len(driver.local) == k + 1
        assert [t.run_dir.parent.name for t in driver.local[-1][0]] == ["All_tactile-partial"]
    capsys.readouterr()


def test_a_label_not_in_the_groups_is_one_line_naming_the_choices(tmp_path, monkeypatch, capsys):
    driver = Driver(monkeypatch)
    assert (
        experiments.main(
            ["--out", str(tmp_path / "grid"), "--groups", "single", "--labels", "All,T+K", "--seeds", "1", "--no-progress", *TINY]
        )
        == 2
    )
    assert capsys.readouterr().err == (
        "dlo-experiments: error: --labels: 'T+K' is not a configuration of the groups single (their labels: T, K, V, All)\n"
    )
    assert driver.local == [] and not (tmp_path / "grid").exists()


def test_main_never_runs_more_threads_than_cores(tmp_path, monkeypatch, capsys):
    driver = Driver(monkeypatch, cores=4)
    assert experiments.main(grid_args(tmp_path / "a", "--jobs", "3", "--threads", "2")) == 0
    assert driver.local[-1][1] == 2
    assert capsys.readouterr().err == "dlo-experiments: 3 jobs x 2 threads > 4 cores; using 2 jobs\n"
    assert experiments.main(grid_args(tmp_path / "b", "--jobs", "2", "--threads", "2")) == 0
    assert driver.local[-1][1] == 2 and capsys.readouterr().err == ""
    assert experiments.main(grid_args(tmp_path / "c", "--threads", "8")) == 0
    assert driver.local[-1][1] == 1  # one job even with fewer cores than threads
    assert capsys.readouterr().err == "dlo-experiments: 1 jobs x 8 threads > 4 cores; using 1 jobs\n"


def test_main_dry_run_estimates_for_the_asked_workers_and_runs_nothing(tmp_path, monkeypatch, capsys):
    driver = Driver(monkeypatch, cores=4)
    out = tmp_path / "grid"
    (out / "V" / "seed0").mkdir(parents=True)
    (out / "V" / "seed0" / CHECKPOINT_FILE).write_bytes(b"")
    assert experiments.main(grid_args(out, "--dry-run")) == 0
    assert driver.estimates[-1] == (["T", "V"], ["todo", "partial"], out, 4, True)
    lines = capsys.readouterr().out.splitlines()
    assert lines[-1] == "estimate: stub"
    assert lines[1] == f"partial  {out / 'V' / 'seed0'}  (single)"  # resumed here: no note
    assert experiments.main(grid_args(out, "--dry-run", "--jobs", "9", "--threads", "2")) == 0
    assert driver.estimates[-1][3] == 9 and "cores" not in capsys.readouterr().err
    assert experiments.main(grid_args(out, "--dry-run", "--ray-address", "auto")) == 0
    assert driver.estimates[-1][3:] == (1, False)  # Ray: one worker unless asked; a partial run starts over
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == f"todo     {out / 'T' / 'seed0'}  (single)"
    assert lines[1] == f"partial  {out / 'V' / 'seed0'}  (single) (starts over on the cluster: its checkpoint stays here)"
    assert driver.local == [] and driver.ray_runs == [] and driver.connected == []


def test_main_with_nothing_left_to_run_runs_nothing(tmp_path, monkeypatch, capsys):
    driver = Driver(monkeypatch)
    out = tmp_path / "grid"
    for label in ("T", "V"):
        write_done(out / label / "seed0", {})
    assert experiments.main(grid_args(out)) == 0
    assert driver.local == [] and capsys.readouterr().out.splitlines()[-1] == "2 runs, 2 done, 0 to run"


def test_main_exits_1_naming_the_failed_runs(tmp_path, monkeypatch, capsys):
    Driver(monkeypatch, outcomes={"T": "Traceback: diverged"})
    out = tmp_path / "grid"
    assert experiments.main(grid_args(out)) == 1
    captured = capsys.readouterr()
    assert "grid: 2 run(s): 1 finished, 1 failed" in captured.out
    assert captured.err == f"1 run(s) failed: {out / 'T' / 'seed0'} (see their train.log)\n"


def test_main_interrupted_exits_130_counting_the_finished_runs(tmp_path, monkeypatch, capsys):
    Driver(monkeypatch, outcomes={"V": "interrupt"})
    argv = [a for a in grid_args(tmp_path / "grid") if a != "--no-progress"]
    argv[argv.index("T,V")] = "T,V,K"  # T and K finish, V is interrupted
    assert experiments.main(argv) == 130
    err = capsys.readouterr().err
    assert err.split("\n")[-2] == (  # on a line of its own: the progress bar was closed first
        "dlo-experiments: interrupted; 2 of 3 run(s) finished: run the same command again to continue (a stopped "
        "run resumes from its checkpoint)"
    )
    assert "runs:" in err


def test_main_closes_the_progress_bar_before_its_report(tmp_path, monkeypatch, capsys):
    Driver(monkeypatch)
    argv = [a for a in grid_args(tmp_path / "grid") if a != "--no-progress"]
    assert experiments.main(argv) == 0
    err = capsys.readouterr().err
    assert "done=2 running=0 failed=0 retried=0" in err and err.endswith("\n")
    driver = Driver(monkeypatch, outcomes={"T": "grid error"})
    argv = [a for a in grid_args(tmp_path / "other", "--ray-address", "head:1") if a != "--no-progress"]
    assert experiments.main(argv) == 2
    err = capsys.readouterr().err
    assert err.split("\n")[-2] == "dlo-experiments: error: the cluster went away" and "runs:" in err
    assert driver.ray_runs


def test_main_needs_ray_before_anything_when_asked_for_it(tmp_path, monkeypatch, capsys):
    driver = Driver(monkeypatch)

    def no_ray():
        raise SystemExit("dlo-experiments: --ray-address needs Ray, which is not installed")

    monkeypatch.setattr(experiments, "import_ray", no_ray)
    with pytest.raises(SystemExit, match="needs Ray"):
        experiments.main(grid_args(tmp_path / "grid", "--dry-run", "--ray-address", "auto"))
    assert capsys.readouterr().out == "" and driver.estimates == []


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--seeds", "0"], "--seeds must be at least 1"),
        (["--jobs", "0"], "--jobs must be at least 1, --retries and --gpus-per-run at least 0"),
        (["--gpus-per-run", "-0.5", "--ray-address", "auto"], "--jobs must be at least 1, --retries and --gpus-per-run"),
        (["--groups", "singles"], "unknown group"),
        (["sac.batch_size=many"], "sac.batch_size: expected an integer"),
    ],
)
def test_main_usage_mistakes_are_one_line_exit_2(extra, message, tmp_path, monkeypatch, capsys):
    driver = Driver(monkeypatch)
    overrides = [e for e in extra if "=" in e and not e.startswith("-")]
    options = [e for e in extra if e not in overrides]
    assert experiments.main(grid_args(tmp_path / "grid", *options, overrides=overrides)) == 2
    err = capsys.readouterr().err
    assert err.startswith("dlo-experiments: error: ") and message in err and err.count("\n") == 1
    assert driver.local == [] and not (tmp_path / "grid").exists()


def test_main_on_ray_connects_checks_capacity_and_runs_there(tmp_path, monkeypatch, capsys):
    driver = Driver(monkeypatch)
    out = tmp_path / "grid"
    assert (
        experiments.main(
            grid_args(out, "--ray-address", "head:6379", "--threads", "8", "--retries", "5", "--gpus-per-run", "0.5")
        )
        == 0
    )
    assert driver.connected == ["head:6379"] and driver.local == []
    ((ray, tasks, threads, retries, gpus),) = driver.ray_runs
    assert (ray, len(tasks), threads, retries, gpus) == (driver.ray, 2, 8, 5, 0.5)  # no cap by local cores
    assert "cores" not in capsys.readouterr().err
    driver.capacity_error = "no node of the Ray cluster has 8 CPUs"
    assert experiments.main(grid_args(tmp_path / "other", "--ray-address", "head:6379", "--threads", "8")) == 2
    assert capsys.readouterr().err == "dlo-experiments: error: no node of the Ray cluster has 8 CPUs\n"
    assert driver.ray.shutdowns == 1 and len(driver.ray_runs) == 1
    driver.capacity_error = None
    driver.outcomes = {"T": "grid error"}
    assert experiments.main(grid_args(tmp_path / "third", "--ray-address", "head:6379")) == 2
    assert capsys.readouterr().err == "dlo-experiments: error: the cluster went away\n"


def test_main_collect_needs_an_existing_runs_directory(tmp_path, capsys):
    runs = tmp_path / "runs"
    assert experiments.main(["--out", str(runs), "--collect", str(tmp_path / "results")]) == 2
    assert capsys.readouterr().err == f"dlo-experiments: error: --collect: no directory {runs}\n"
    write_done(runs / "All" / "seed0", {})
    assert experiments.main(["--out", str(runs), "--collect", str(tmp_path / "results")]) == 0
    assert capsys.readouterr().out == f"{tmp_path / 'results' / 'All' / 'seed0'}\n"


def test_calibrate_times_its_steps_and_one_evaluation(monkeypatch):
    """Calibration: (seconds of `steps` SAC steps after a warm-up) / steps, and the seconds of one evaluation
    of eval_episodes episodes after a warm-up one (a clock that reads 5, 17, 100, 103 s)."""
    import torch

    monkeypatch.setattr(experiments, "time", Clock(5.0, 17.0, 100.0, 103.0))
    config = load_config(None, [*TINY, "train.num_threads=1"])
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        assert experiments.calibrate(config, steps=30) == experiments.Calibration(12.0 / 30, 3.0)
        assert torch.get_num_threads() == 1  # measured with the run's --threads
    finally:
        torch.set_num_threads(threads)


def test_a_finished_run_has_only_its_held_out_test_left():
    cal = experiments.Calibration(step_s=0.5, eval_s=2.0)
    config = load_config(
        None, ["train.total_steps=1000", "train.eval_every=200", "train.eval_episodes=10", "train.test_episodes=20"]
    )
    assert cal.run_seconds(config, done_steps=1000) == pytest.approx(2 * 2.0)
    assert cal.run_seconds(config, done_steps=1200) == pytest.approx(2 * 2.0)


@pytest.mark.parametrize("tty, quiet, due", [(False, 59.0, 61.0), (True, 0.5, 1.5)])
def test_grid_progress_redraws_a_log_file_every_60_s_and_a_terminal_every_second(tty, quiet, due, capsys, monkeypatch):
    """Unchanged counts: a log file gets a line at most every 60 s, a terminal a redraw every second
    (tqdm's own clock set by hand)."""
    monkeypatch.setattr(sys.stderr, "isatty", lambda: tty, raising=False)
    progress = experiments.GridProgress(2, enabled=True)
    clock = [1000.0]
    progress.bar._time = lambda: clock[0]
    progress.bar.start_t = progress.bar.last_print_t = clock[0]
    capsys.readouterr()
    clock[0] += quiet
    progress.refresh()
    assert capsys.readouterr().err == ""
    clock[0] += due - quiet
    progress.refresh()
    assert "runs:   0%|" in capsys.readouterr().err  # redrawn, still no run done
    progress.close()


def test_grid_progress_eta_comes_from_the_runs_finished_so_far(capsys):
    """The remaining time is the average time per finished run so far, not a recent run's: runs done after
    61 s and 200 s, one to go: 100 s, not the 139 s of the last one (tqdm's own clock set by hand)."""
    progress = experiments.GridProgress(3, enabled=True)
    clock = [1000.0]
    progress.bar._time = lambda: clock[0]
    progress.bar.start_t = progress.bar.last_print_t = clock[0]
    clock[0] += 61.0
    progress.done(experiments.Task(Path("a"), {}))
    clock[0] += 139.0
    progress.done(experiments.Task(Path("b"), {}))
    assert "2/3 [03:20<01:40," in capsys.readouterr().err
    progress.close()


def test_every_drawn_state_of_the_grid_bar_is_consistent(capsys):
    """Each line the bar draws shows as many runs done as its counts say (n = done + failed), a run's end is
    drawn at once, unchanged counts are not drawn again within the minute, and closing ends the line."""
    import re

    progress = experiments.GridProgress(3, enabled=True)
    clock = [1000.0]
    progress.bar._time = lambda: clock[0]
    progress.bar.start_t = progress.bar.last_print_t = clock[0]
    drawn = capsys.readouterr().err
    clock[0] += 5.0
    progress.done(experiments.Task(Path("a"), {}))
    err = capsys.readouterr().err
    assert "1/3 [" in err
    drawn += err
    clock[0] += 5.0
    progress.refresh()
    assert capsys.readouterr().err == ""
    clock[0] += 5.0
    progress.done(experiments.Task(Path("b"), {}, error="boom"))
    clock[0] += 5.0
    progress.refresh(running=0)
    progress.close()
    drawn += capsys.readouterr().err
    states = re.findall(r"(\d+)/3 \[[^\]]*done=(\d+) running=\d+ failed=(\d+)", drawn)
    assert len(states) >= 3 and all(int(n) == int(done) + int(failed) for n, done, failed in states), drawn
    assert states[-1] == ("2", "1", "1") and drawn.endswith("\n")


def test_calibrate_times_steps_with_an_update_each_and_an_evaluation_after_warm_ups(monkeypatch):
    """--dry-run's calibration (module docstring): the clock runs over `steps` SAC steps, each an env step and
    one gradient update (the warm-up before it has already updated), then over one evaluation of
    train.eval_episodes episodes from train.eval_seed on the evaluation env after a warm-up evaluation on it;
    both envs are closed. A configuration scaling observations by the env's bounds calibrates too."""
    from dlo_policy import evaluate, sac

    events, agents = [], []

    class RecordedSAC(sac.SAC):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            agents.append(self)

    class EventClock:
        def __init__(self, *readings):
            self.readings = list(readings)

        def perf_counter(self):
            events.append(("clock", agents[0].num_env_steps, agents[0].num_updates))
            return self.readings.pop(0)

    real_make_env, real_evaluate = experiments.make_env, evaluate.evaluate_agent

    def make_env(config, *args, **kwargs):
        env = real_make_env(config, *args, **kwargs)
        name = "eval env" if args else "training env"
        real_close = env.close
        env.close = lambda: events.append(("close", name)) or real_close()
        env.recorded_name = name
        return env

    def evaluate_agent(agent, vec_env, first_seed, episodes, *args, **kwargs):
        events.append(("evaluate", vec_env.recorded_name, first_seed, episodes))
        return real_evaluate(agent, vec_env, first_seed, episodes, *args, **kwargs)

    monkeypatch.setattr(sac, "SAC", RecordedSAC)
    monkeypatch.setattr(experiments, "make_env", make_env)
    monkeypatch.setattr(evaluate, "evaluate_agent", evaluate_agent)
    monkeypatch.setattr(experiments, "time", EventClock(5.0, 17.0, 100.0, 103.0))
    config = load_config(None, [*TINY, "train.num_threads=1", "sac.observation_scaling=bounds"])
    assert experiments.calibrate(config, steps=30) == experiments.Calibration(12.0 / 30, 3.0)
    (agent,) = agents
    assert agent.normalizer is not None  # scaled by the env's observation bounds
    (_, warm_steps, warm_updates), (_, steps, updates) = events[0], events[1]
    assert warm_updates > 0
    assert (steps - warm_steps, updates - warm_updates) == (30, 30)
    seed = config.train.eval_seed
    assert events[2:] == [
        ("close", "training env"),
        ("evaluate", "eval env", seed, 4),
        ("clock", steps, updates),
        ("evaluate", "eval env", seed, 4),
        ("clock", steps, updates),
        ("close", "eval env"),
    ]


def test_main_accepts_one_job_and_no_retries(tmp_path, monkeypatch, capsys):
    """--jobs must be at least 1, --retries at least 0 (the usage error's words): exactly those are accepted."""
    driver = Driver(monkeypatch)
    assert experiments.main(grid_args(tmp_path / "a", "--jobs", "1", "--retries", "0")) == 0
    assert driver.local[-1][1] == 1
    assert experiments.main(grid_args(tmp_path / "b", "--ray-address", "head:6379", "--retries", "0")) == 0
    assert driver.ray_runs[-1][3] == 0
    assert capsys.readouterr().err == ""


def test_main_prints_its_report_after_the_finished_progress_bar(tmp_path, monkeypatch):
    """On a terminal-less log (stdout and stderr into one file): the progress bar's last line is finished
    and the report comes after it, last."""
    stream = io.StringIO()
    monkeypatch.setattr(sys, "stdout", stream)
    monkeypatch.setattr(sys, "stderr", stream)
    Driver(monkeypatch)
    argv = [a for a in grid_args(tmp_path / "grid") if a != "--no-progress"]
    assert experiments.main(argv) == 0
    monkeypatch.undo()
    log = stream.getvalue()
    report = "grid: 2 run(s): 2 finished, 0 failed\n"
    assert log.endswith(report), repr(log)
    bar = log[: -len(report)]
    # the bar's finished line, then a line break (tqdm pads a status shorter than the one before it, which depends
    # on the measured rate in runs/s, with spaces: rehearsal 95 saw '986.43run/s, ...] ' after '1066.85run/s, ...]')
    assert bar.endswith("\n") and bar[:-1].rstrip(" ").endswith("done=2 running=0 failed=0 retried=0]"), repr(log)


def test_collect_into_a_directory_inside_the_runs_skips_what_it_collected(tmp_path, capsys):
    """--collect RESULTS with RESULTS under --out: the copies in RESULTS are not runs of --out; a second
    collect copies nothing (no RESULTS/RESULTS/...)."""
    runs = tmp_path / "runs"
    write_done(runs / "All" / "seed0", {"env_steps": 1})
    results = runs / "results"
    for _ in range(2):
        assert experiments.main(["--out", str(runs), "--collect", str(results)]) == 0
    assert capsys.readouterr().out == f"{results / 'All' / 'seed0'}\n"
    assert sorted(p.relative_to(results).as_posix() for p in results.rglob("*")) == ["All", "All/seed0", f"All/seed0/{DONE_FILE}"]
    write_done(results, {"env_steps": 1})  # RESULTS itself holding a done.json is not a run of --out either
    assert experiments.main(["--out", str(runs), "--collect", str(results)]) == 0
    assert capsys.readouterr().out == ""
