"""dlo-train without training (fast): the code a run records, cores and threads, the command line and its
help, the warning when no update will happen, and the TensorBoard log's arithmetic (a recording writer)."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from dlo_policy import rundir, train
from dlo_policy.config import ConfigError, load_config, save_config
from dlo_policy.modalities import names
from dlo_policy.sac import StepResult

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib: sac_reach_env

from tiny_training import TINY, restore_threads  # noqa: E402,F401 (restore_threads: an autouse fixture)


def git(repo, *args):
    return subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True, check=True).stdout.strip()


def test_source_commit_is_the_commit_and_whether_ros_ws_src_has_uncommitted_changes(tmp_path, monkeypatch):
    """done.json "sources": {"commit": the checkout's HEAD, "dirty": tracked files under ros_ws/src changed};
    {"commit": "unknown", "dirty": None} outside a git checkout or before its first commit."""
    repo = tmp_path / "repo"
    package = repo / "ros_ws" / "src" / "dlo_policy" / "dlo_policy"
    package.mkdir(parents=True)
    monkeypatch.setattr(train, "__file__", str(package / "train.py"))  # source_commit looks where train.py lies
    env = {
        "GIT_AUTHOR_NAME": "t",
        "GIT_AUTHOR_EMAIL": "t@t",
        "GIT_COMMITTER_NAME": "t",
        "GIT_COMMITTER_EMAIL": "t@t",
        "GIT_CONFIG_GLOBAL": os.devnull,
        "GIT_CONFIG_NOSYSTEM": "1",
        "GIT_CEILING_DIRECTORIES": str(tmp_path),
    }
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    assert train.source_commit() == {"commit": "unknown", "dirty": None}  # no checkout at all
    git(repo, "init", "-q")
    (package / "train.py").write_text("# the code\n")
    (repo / "README.md").write_text("readme\n")
    assert train.source_commit() == {"commit": "unknown", "dirty": None}  # a checkout without a commit
    git(repo, "add", ".")
    git(repo, "commit", "-q", "-m", "first")
    sha = git(repo, "rev-parse", "HEAD")
    assert len(sha) == 40
    assert train.source_commit() == {"commit": sha, "dirty": False}
    (repo / "README.md").write_text("changed outside ros_ws/src\n")
    (package / "new_module.py").write_text("# untracked\n")
    assert train.source_commit() == {"commit": sha, "dirty": False}
    (package / "train.py").write_text("# the code, edited\n")
    assert train.source_commit() == {"commit": sha, "dirty": True}


def test_available_cores_are_the_ones_this_process_may_use(monkeypatch):
    asked = []
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: asked.append(pid) or {0}, raising=False)
    monkeypatch.setattr(os, "cpu_count", lambda: 8)
    assert train.available_cores() == 1 and asked == [0]  # this process's affinity, not the machine's cores
    monkeypatch.delattr(os, "sched_getaffinity")
    assert train.available_cores() == 8
    monkeypatch.setattr(os, "cpu_count", lambda: None)
    assert train.available_cores() == 1


def test_set_threads_sets_torch_threads_and_zero_means_every_core(monkeypatch):
    monkeypatch.setattr(train, "available_cores", lambda: 3)
    assert train.set_threads(2) == 2 and torch.get_num_threads() == 2
    assert train.set_threads(0) == 3 and torch.get_num_threads() == 3


def test_an_evaluation_index_past_the_seed_stride_is_refused():
    """eval_seeds: evaluation k uses eval_seed + 100,000 seed + k eval_episodes + (0..eval_episodes-1), which
    must stay below the next run seed's block; the last evaluation that fits is allowed."""
    config = load_config(None, ["seed=1", "train.eval_episodes=10"])
    last = train.EVAL_SEED_STRIDE // 10 - 1
    assert train.eval_seeds(config, last) == 1_000_000 + 100_000 + 10 * last
    assert train.eval_seeds(config, last) + 10 == 1_000_000 + 2 * 100_000  # ends right below seed 2's block
    with pytest.raises(ValueError, match=f"evaluation {last + 1}: more than 100000 evaluation episodes"):
        train.eval_seeds(config, last + 1)
    config = load_config(None, ["seed=0", "train.eval_episodes=7"])
    assert [train.eval_seeds(config, k) for k in range(3)] == [1_000_000, 1_000_007, 1_000_014]


def test_help_shows_the_protocol_the_options_and_the_override_examples(capsys):
    with pytest.raises(SystemExit) as exit_info:
        train.main(["--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: dlo-train ")
    # the module docstring as written (RawDescriptionHelpFormatter: the column layout kept)
    assert "\n    step             env steps taken when evaluated\n" in out
    assert "\n    dlo-train --out runs/V+K/seed3 --resume          # continue from the last checkpoint\n" in out
    assert (
        "Overrides are key=value pairs on config keys (see config/sac_default.yaml), e.g.\n"
        "  sac.batch_size=256 train.eval_every=500 env_options.tactile_noise=partial" in out
    )
    flat = " ".join(out.split())
    for text in (
        f"--modalities MODALITIES All, or a '+'-joined subset of {', '.join(names())} (e.g. V+K); default All",
        "--seed SEED run seed (default 0)",
        "--steps STEPS total env steps (default 50000)",
        "--out OUT run directory",
        "--config CONFIG YAML config (default: built-in defaults, see config/sac_default.yaml)",
        "--label LABEL experiment name used to group seeds in dlo-report",
        "--resume continue the run in --out from its last checkpoint (its saved config; only --steps may change)",
        "--no-progress no progress display (a bar on a terminal, else a line every tenth of the run)",
        "key=value config overrides",
    ):
        assert text in flat, text


def test_out_is_required(capsys):
    with pytest.raises(SystemExit) as exit_info:
        train.main(["--steps", "10"])
    assert exit_info.value.code == 2
    assert "the following arguments are required: --out" in capsys.readouterr().err


@pytest.mark.parametrize("left", [(rundir.EVAL_FILE,), (rundir.CHECKPOINT_FILE,)])
def test_a_directory_holding_part_of_a_run_is_not_trained_into_again(left, tmp_path, capsys):
    """An eval.csv alone (a run stopped before its first checkpoint) or a checkpoint: --resume or another --out."""
    run = tmp_path / "run"
    run.mkdir()
    for name in left:
        (run / name).write_bytes(b"")
    assert train.main(["--out", str(run), "--steps", "100", "--no-progress", *TINY]) == 2
    assert capsys.readouterr().err == f"dlo-train: error: {run} already holds a run: pass --resume or choose another --out\n"
    assert sorted(p.name for p in run.iterdir()) == sorted([*left, rundir.LOCK_FILE])


@pytest.mark.parametrize("selected_by", ["hold_the_end", "hold_the_end_authors"])
def test_keep_if_best_keeps_the_first_of_the_highest_hold_the_end_then_reward(selected_by):
    """best_policy.pt / best.json: a later evaluation replaces the best only when it is strictly better under the
    run's own outcome rule (`selected_by`: the authors' rule for authors_code runs, the paper rule for paper_text),
    then by episode reward; a tie keeps the earlier one. The other rule's numbers do not choose."""
    import types

    states = iter(range(100))
    trainer = types.SimpleNamespace(
        best=None,
        best_policy_state=None,
        written=[],
        selected_by=selected_by,
        agent=types.SimpleNamespace(policy_state=lambda: next(states)),
        config=types.SimpleNamespace(train=types.SimpleNamespace(init_from="")),  # a new agent (not fine-tuning)
    )
    trainer.write_best = lambda: trainer.written.append((trainer.best["step"], trainer.best_policy_state))
    other = "hold_the_end" if selected_by == "hold_the_end_authors" else "hold_the_end_authors"
    for step, hold, reward in (
        (0, 0.2, -1.0),
        (100, 0.2, -1.0),
        (200, 0.2, -0.5),
        (300, 0.1, 5.0),
        (400, 0.3, -9.0),
        (500, 0.3, -9.0),
    ):
        row = {"step": step, selected_by: hold, other: 1.0 - hold, "episode_reward": reward, "alpha": 1}
        train.Trainer.keep_if_best(trainer, row)
    assert trainer.written == [(0, 0), (200, 1), (400, 2)]
    assert trainer.best == {"step": 400, selected_by: 0.3, other: 0.7, "episode_reward": -9.0, "selected_by": selected_by}


def test_a_trainer_makes_its_run_directory_records_its_config_and_seeds_its_agent(tmp_path, monkeypatch):
    """Trainer (also what dlo-experiments runs): the run directory made (parents too), config.yaml written,
    one "sources" entry from step 0, the agent's initial weights from the run seed."""
    import yaml

    def actor(seed, out):
        trainer = train.Trainer(load_config(None, [*TINY, f"seed={seed}", "train.progress=false"]), out)
        try:
            assert [s["from_step"] for s in trainer.sources] == [0]
            return [p.detach().clone() for p in trainer.agent.actor.parameters()]
        finally:
            trainer.env.close()
            trainer.eval_env.close()
            trainer.tb.close()

    selected = []
    monkeypatch.setattr(train.taichi_runtime, "select", selected.append)  # the simulator's backend: train.sim_arch
    out = tmp_path / "a" / "b"
    first = actor(3, out)
    assert selected == ["cpu"]
    saved = yaml.safe_load((out / rundir.CONFIG_FILE).read_text())
    assert (saved["seed"], saved["env_module"], saved["sac"]["hidden_sizes"]) == (3, "sac_reach_env", [32, 32])
    same, other = actor(3, tmp_path / "c"), actor(4, tmp_path / "d")
    assert all(torch.equal(p, q) for p, q in zip(first, same))
    assert not all(torch.equal(p, q) for p, q in zip(first, other))
    # sac.observation_scaling=bounds scales by the env's observation bounds: the trainer passes them on
    trainer = train.Trainer(
        load_config(None, [*TINY, "sac.observation_scaling=bounds", "train.progress=false"]), tmp_path / "bounds"
    )
    try:
        assert trainer.agent.normalizer is not None
    finally:
        trainer.env.close()
        trainer.eval_env.close()
        trainer.tb.close()


class NoTraining:
    """Stands in for train.train: what main would train, no training."""

    def __init__(self):
        self.calls = []

    def __call__(self, config, out, resume=False):
        self.calls.append((config, out, resume))
        return {"env_steps": config.train.total_steps}


@pytest.mark.parametrize("steps, warned", [(20, True), (50, True), (51, False)])
def test_a_run_without_any_gradient_update_is_warned_about(steps, warned, tmp_path, capsys, monkeypatch):
    """dlo-train: with train.total_steps <= sac.learning_starts SAC.learn never updates: one warning line
    with a learning_starts that would (a third of the steps), and the run still starts."""
    stub = NoTraining()
    monkeypatch.setattr(train, "train", stub)
    assert train.main(["--out", str(tmp_path / "run"), "--steps", str(steps), "--no-progress", *TINY]) == 0
    captured = capsys.readouterr()
    warning = (
        f"dlo-train: warning: train.total_steps {steps} <= sac.learning_starts 50: no gradient update will "
        f"happen (random actions only); pass e.g. sac.learning_starts={steps // 3} or --steps above 50\n"
    )
    assert captured.err == (warning if warned else "")
    assert captured.out.strip().splitlines()[-1] == f'{{"env_steps": {steps}}}'  # the summary, after Taichi's line
    ((config, out, resume),) = stub.calls
    assert (config.train.total_steps, out, resume) == (steps, tmp_path / "run", False)


def test_flags_reach_the_run_and_resume_takes_only_steps(tmp_path, monkeypatch):
    stub = NoTraining()
    monkeypatch.setattr(train, "train", stub)
    run = tmp_path / "run"
    assert (
        train.main(
            ["--out", str(run), "--steps", "120", "--seed", "4", "--modalities", "T+K", "--label", "x", "--no-progress", *TINY]
        )
        == 0
    )
    config = stub.calls[-1][0]
    assert (config.train.total_steps, config.seed, config.modalities, config.label, config.train.progress) == (
        120,
        4,
        "T+K",
        "x",
        False,
    )
    assert train.main(["--out", str(run), "--steps", "120", *TINY]) == 0
    assert stub.calls[-1][0].train.progress is True  # no --no-progress: the config's (default) setting
    run.mkdir()
    save_config(load_config(None, [*TINY, "seed=5", "train.progress=false"]), run / rundir.CONFIG_FILE)
    assert train.main(["--out", str(run), "--resume", "--steps", "300"]) == 0
    config, out, resume = stub.calls[-1]
    assert (config.seed, config.train.total_steps, config.train.progress, out, resume) == (5, 300, False, run, True)


@pytest.mark.skipif(torch.cuda.is_available(), reason="a CUDA device is present")
def test_check_devices_refuses_a_torch_device_this_machine_lacks(tmp_path, capsys, monkeypatch):
    with pytest.raises(ConfigError, match="sees no CUDA device"):
        train.check_devices(load_config(None, ["train.device=cuda"]))
    stub = NoTraining()
    monkeypatch.setattr(train, "train", stub)
    assert train.main(["--out", str(tmp_path / "run"), "--steps", "10", *TINY, "train.device=cuda"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("dlo-train: error: ") and "sees no CUDA device" in err and err.count("\n") == 1
    assert stub.calls == []  # refused before the run starts


def test_check_devices_refuses_a_simulator_backend_taichi_cannot_give():
    """train.sim_arch=cuda where Taichi already runs on the CPU in this process (as it does on a machine
    without CUDA): one ConfigError, not a silent CPU run (test_train.py checks a fresh process)."""
    from dlo_common import taichi_runtime

    if taichi_runtime.arch() != "cpu":
        pytest.skip("Taichi runs on another backend in this process")
    taichi_runtime.init("cpu")
    with pytest.raises(ConfigError, match="^Taichi is already running on cpu in this process$"):
        train.check_devices(load_config(None, ["train.sim_arch=cuda"]))
    train.check_devices(load_config(None, ["train.sim_arch=cpu", "train.device=cpu"]))


class RecordingWriter:
    def __init__(self, log_dir=None, **kwargs):
        self.log_dir, self.calls = log_dir, []

    def add_scalar(self, tag, value, global_step=None, *args, **kwargs):
        self.calls.append((tag, value, global_step))

    def flush(self):
        self.calls.append(("flush",))

    def close(self):
        self.calls.append(("close",))


class Clock:
    def __init__(self):
        self.now = 10.0

    def perf_counter(self):
        return self.now


@pytest.fixture
def tb(tmp_path, monkeypatch):
    monkeypatch.setattr("torch.utils.tensorboard.SummaryWriter", RecordingWriter)
    clock = Clock()
    monkeypatch.setattr(train, "time", clock)
    log = train.TensorBoardLog(tmp_path / "tb")
    assert log.writer.log_dir == str(tmp_path / "tb")
    return log, clock


def test_tensorboard_losses_are_window_means_and_speed_is_steps_per_second(tb):
    log, clock = tb
    for step in range(1, 201):
        clock.now += 0.02
        losses = {"critic_loss": float(step), "actor_loss": 2.0, "q_extra": -1.0} if step > 50 else {}
        log.step(step, losses)
    calls = log.writer.calls
    assert calls[:4] == [
        ("loss/critic", pytest.approx(np.mean(range(51, 101))), 100),
        ("loss/actor", 2.0, 100),
        ("loss/q_extra", -1.0, 100),
        ("speed/steps_per_s", pytest.approx(100 / 2.0), 100),
    ]
    assert calls[4:] == [
        ("loss/critic", pytest.approx(np.mean(range(101, 201))), 200),
        ("loss/actor", 2.0, 200),
        ("loss/q_extra", -1.0, 200),
        ("speed/steps_per_s", pytest.approx(100 / 2.0), 200),
    ]
    clock.now += 0.0
    log.step(300, {})  # a window of no measurable time: finite (100 steps / 1 ns), no division by zero
    assert log.writer.calls[-1] == ("speed/steps_per_s", pytest.approx(1e11), 300)


def test_tensorboard_episodes_and_evaluations(tb):
    log, _ = tb
    log.episode(57, -1.5, 57)
    assert log.writer.calls == [("train/episode_return", -1.5, 57), ("train/episode_length", 57, 57)]
    log.writer.calls.clear()
    row = {
        "step": 200,
        "tested_without": "",
        "episodes": 10,
        "eval_seed": 1_000_020,
        "wall_time_s": 3.5,
        "hold_the_end": 0.4,
        "episode_reward": -2.0,
        "time_at_end": float("nan"),
        "note": "text",
        "alpha": 1,
    }
    log.evaluation(row)
    log.evaluation({**row, "tested_without": "T", "hold_the_end": 0.1})
    assert log.writer.calls == [
        ("eval/hold_the_end", 0.4, 200),
        ("eval/episode_reward", -2.0, 200),
        ("eval/alpha", 1, 200),
        ("flush",),
        ("eval_without_T/hold_the_end", 0.1, 200),
        ("eval_without_T/episode_reward", -2.0, 200),
        ("eval_without_T/alpha", 1, 200),
        ("flush",),
    ]
    log.close()
    assert log.writer.calls[-1] == ("close",)


def test_without_tensorboard_a_run_logs_nothing_and_says_so_once(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "torch.utils.tensorboard", None)  # import fails: not installed
    log = train.TensorBoardLog(tmp_path / "tb")
    err = capsys.readouterr().err
    assert err.startswith("dlo-train: warning: no TensorBoard event files (") and err.count("\n") == 1
    assert "pip install tensorboard" in err
    assert log.writer is None
    for step in (100, 150):
        log.step(step, {"critic_loss": 1.0})
    log.episode(100, 1.0, 10)
    log.evaluation({"step": 100, "tested_without": "", "hold_the_end": 0.5})
    log.close()
    assert not (tmp_path / "tb").exists()


def test_each_training_episode_logs_its_own_return_and_length(tmp_path, monkeypatch):
    """TensorBoard train/episode_return and train/episode_length (module docstring): per training episode,
    the sum of that episode's rewards and its step count, logged at the step it ends (terminated or
    truncated); each episode starts from zero, the first one too."""
    import types

    monkeypatch.setattr("torch.utils.tensorboard.SummaryWriter", RecordingWriter)
    trainer = train.Trainer(load_config(None, [*TINY, "train.progress=false"]), tmp_path / "run")
    try:
        trainer.bar = types.SimpleNamespace(update=lambda n: None)
        agent = types.SimpleNamespace(num_env_steps=0, alpha=1.0)
        for reward, terminated, truncated in (
            (-0.5, False, False),
            (-0.25, False, False),
            (-1.0, True, False),
            (-0.5, False, False),
            (-0.25, False, True),
        ):
            agent.num_env_steps += 1
            trainer.on_step(agent, StepResult(reward, terminated, truncated, {}, {}))
        logged = [call for call in trainer.tb.writer.calls if call[0].startswith("train/")]
        assert logged == [
            ("train/episode_return", -1.75, 3),
            ("train/episode_length", 3, 3),
            ("train/episode_return", -0.75, 5),
            ("train/episode_length", 2, 5),
        ]
    finally:
        trainer.env.close()
        trainer.eval_env.close()
        trainer.tb.close()


class HeldOutEnv:
    def __init__(self):
        self.closed = 0

    def close(self):
        self.closed += 1


def held_out_trainer(tmp_path, monkeypatch, results):
    """A Trainer's state for test_best (no training): evaluation results replayed, best_policy.pt a stand-in."""
    import types

    from dlo_policy.evaluate import blanked_columns

    config = load_config(None, [*TINY, "train.eval_without=[T]", "train.test_episodes=3", "train.progress=true"])
    monkeypatch.setattr(train.SAC, "load", staticmethod(lambda path, **kwargs: types.SimpleNamespace(num_env_steps=300)))

    def evaluate_agent(agent, env, first_seed, episodes, blank=(), progress=None):
        progress(1)
        result = results.pop(0)
        if isinstance(result, BaseException):
            raise result
        return types.SimpleNamespace(to_json=lambda: dict(result))

    monkeypatch.setattr(train, "evaluate_agent", evaluate_agent)
    return types.SimpleNamespace(
        config=config,
        out_dir=tmp_path,
        eval_env=HeldOutEnv(),
        tested=[("", []), ("T", blanked_columns(config.modalities, ["T"]))],
    )


def test_held_out_test_files_say_which_modality_was_blanked_like_dlo_evaluate(tmp_path, monkeypatch):
    """test.json and test_without_X.json are dlo-evaluate's JSON (module docstring): "without" lists the
    blanked modality as `dlo-evaluate --without X` does ([] for all inputs), with the checkpoint, the first
    test seed, the modalities and the policy's env steps."""
    import json

    trainer = held_out_trainer(tmp_path, monkeypatch, [{"hold_the_end": 0.5}, {"hold_the_end": 0.25}])
    assert train.Trainer.test_best(trainer)["hold_the_end"] == 0.5
    common = {
        "checkpoint": rundir.BEST_POLICY_FILE,
        "seed": trainer.config.train.test_seed,
        "modalities": "All",
        "env_steps": 300,
    }
    assert json.loads((tmp_path / "test.json").read_text()) == {"hold_the_end": 0.5, **common, "without": []}
    assert json.loads((tmp_path / "test_without_T.json").read_text()) == {"hold_the_end": 0.25, **common, "without": ["T"]}
    assert trainer.eval_env.closed == 1


def test_an_interrupted_held_out_test_finishes_its_progress_line_and_closes_the_env(tmp_path, monkeypatch, capsys):
    """Ctrl-C during the held-out test: its progress bar's line is finished (the interruption's message
    starts on a line of its own) and the evaluation env is closed."""
    trainer = held_out_trainer(tmp_path, monkeypatch, [{"hold_the_end": 0.5}, KeyboardInterrupt()])
    with pytest.raises(KeyboardInterrupt):
        train.Trainer.test_best(trainer)
    err = capsys.readouterr().err
    assert "held-out test" in err and err.endswith("\n"), repr(err)
    assert trainer.eval_env.closed == 1 and not (tmp_path / "test_without_T.json").exists()


def test_an_interrupted_training_finishes_its_progress_line_and_closes_its_envs(tmp_path, monkeypatch, capsys):
    """Ctrl-C during training: the progress bar's line is finished (the interruption's message starts on a
    line of its own), the TensorBoard log and both envs are closed, no checkpoint is written."""
    import types

    closed = []

    def learn(env, total, callback):
        trainer.bar.update(7)
        raise KeyboardInterrupt

    agent = types.SimpleNamespace(num_env_steps=10, learn=learn)
    trainer = types.SimpleNamespace(
        config=load_config(None, [*TINY, "train.total_steps=100", "train.progress=true"]),
        agent=agent,
        env=types.SimpleNamespace(close=lambda: closed.append("env")),
        eval_env=types.SimpleNamespace(close=lambda: closed.append("eval_env")),
        tb=types.SimpleNamespace(close=lambda: closed.append("tb")),
        save_checkpoint=lambda: closed.append("checkpoint"),
        on_step=None,
        stop=train.StopSignals(),
    )
    with pytest.raises(KeyboardInterrupt):
        train.Trainer.run(trainer)
    err = capsys.readouterr().err
    assert "17/100" in err and err.endswith("\n"), repr(err)
    assert sorted(closed) == ["env", "eval_env", "tb"]
