"""dlo-train / dlo-evaluate: eval CSV protocol, checkpoints, resume, config errors."""

import csv
import importlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
import yaml
from dlo_interface.task import DEFAULT_TASK_RULES, LEGACY_TASK_RULES
from dlo_policy import config as config_module
from dlo_policy import evaluate, rundir, train
from dlo_policy.config import ConfigError, load_config
from dlo_policy.sac import SAC

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib: helper modules

from sac_reach_env import STEP_DELAY_VARIABLE  # noqa: E402
from tiny_training import TINY, restore_threads  # noqa: E402,F401 (restore_threads: an autouse fixture)


def read_eval(run: Path) -> list[dict[str, str]]:
    with (run / rundir.EVAL_FILE).open(newline="") as f:
        return list(csv.DictReader(f))


def test_eval_csv_has_documented_columns_and_ablation_rows(tmp_path):
    run = tmp_path / "run"
    assert (
        train.main(
            ["--out", str(run), "--steps", "300", "--modalities", "All", "--no-progress", "train.eval_without=[T, V]", *TINY]
        )
        == 0
    )
    with (run / rundir.EVAL_FILE).open(newline="") as f:
        assert next(csv.reader(f)) == list(rundir.EVAL_COLUMNS)
    rows = read_eval(run)
    assert [(int(r["step"]), r["tested_without"]) for r in rows] == [
        (step, without) for step in (0, 100, 200, 300) for without in ("", "T", "V")
    ]
    for row in rows:
        assert sum(float(row[o]) for o in rundir.OUTCOMES) == pytest.approx(1.0)
        assert sum(float(row[o]) for o in rundir.OUTCOMES_AUTHORS) == pytest.approx(1.0)
        assert int(row["episodes"]) == 10
    # fresh episodes at every evaluation, the same ones for every tested input set of an evaluation
    first_seeds = {int(r["step"]): int(r["eval_seed"]) for r in rows}
    assert all(int(r["eval_seed"]) == first_seeds[int(r["step"])] for r in rows)
    seeds = sorted(first_seeds.values())
    assert all(b - a >= 10 for a, b in zip(seeds, seeds[1:]))
    # held-out test of the best policy, once per tested input set, on seeds below every evaluation seed
    for name in (rundir.TEST_FILE, rundir.test_file("T"), rundir.test_file("V")):
        test = json.loads((run / name).read_text())
        assert test["episodes"] == 100 and test["seed"] + 100 <= seeds[0]
        assert sum(test[o] for o in rundir.OUTCOMES) == pytest.approx(1.0)
        assert sum(test["authors_code"][o] for o in rundir.OUTCOMES) == pytest.approx(1.0)
    assert json.loads((run / rundir.TEST_FILE).read_text())["without"] == []
    done = json.loads((run / rundir.DONE_FILE).read_text())
    assert done["env_steps"] == 300 and done["updates"] == 250
    assert done["test"] == json.loads((run / rundir.TEST_FILE).read_text())
    assert (run / rundir.POLICY_FILE).exists() and (run / rundir.CONFIG_FILE).exists()


def test_resume_after_interruption_continues_steps_and_buffer(tmp_path):
    run = tmp_path / "run"
    config = load_config(
        None,
        [*TINY, "env_options.crash_after=250", "train.progress=false", "train.total_steps=300", "train.checkpoint_every=200"],
    )
    with pytest.raises(InterruptedError):
        train.train(config, run)
    assert not (run / rundir.DONE_FILE).exists()
    checkpoint = SAC.load(run / rundir.CHECKPOINT_FILE)
    assert (checkpoint.num_env_steps, len(checkpoint.replay)) == (200, 200)
    assert train.main(["--out", str(run), "--resume", "--steps", "400"]) == 0
    agent = SAC.load(run / rundir.CHECKPOINT_FILE)
    assert (agent.num_env_steps, agent.num_updates, len(agent.replay)) == (400, 350, 400)
    assert [int(r["step"]) for r in read_eval(run)] == [0, 100, 200, 300, 400]
    wall = [float(r["wall_time_s"]) for r in read_eval(run)]
    assert wall == sorted(wall)
    sources = json.loads((run / rundir.DONE_FILE).read_text())["sources"]  # the code of each part of the run
    assert [s["from_step"] for s in sources] == [0, 200]
    assert all(len(s["commit"]) == 40 or s["commit"] == "unknown" for s in sources)


def test_existing_run_needs_resume(tmp_path, capsys):
    run = tmp_path / "run"
    assert train.main(["--out", str(run), "--steps", "100", "--no-progress", *TINY]) == 0
    assert train.main(["--out", str(run), "--steps", "100", "--no-progress", *TINY]) == 2
    assert "--resume" in capsys.readouterr().err


@pytest.mark.parametrize(
    "override, message",
    [
        ("sac.batch_sise=64", "unknown key(s) sac.batch_sise"),
        ("sac.batch_size=many", "sac.batch_size: expected an integer"),
        ("sac.tau=1.5", "sac.tau: must be in (0, 1]"),
        ("modalities=X+K", "modalities: modalities must be a '+'-joined subset"),
        ("sac.hidden_sizes=64", "sac.hidden_sizes: expected a list"),
        ("train.eval_without=[V]", "train.eval_without: must be modalities that the run observes"),
    ],
)
def test_bad_config_is_a_clear_error(override, message, tmp_path, capsys):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)").replace("+", r"\+")):
        load_config(None, ["modalities=T+K", override])
    assert train.main(["--out", str(tmp_path / "run"), *TINY, "modalities=T+K", override]) == 2
    said = {"sac.batch_sise=64": "unknown key 'sac.batch_sise'; did you mean 'sac.batch_size'?"}  # dlo-train's own
    assert said.get(override, message) in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


def test_yaml_file_then_overrides_then_flags(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("seed: 4\nsac: {batch_size: 64, actor_lr: 3e-4}\ntrain: {eval_every: 500}\n")
    config = load_config(path, ["train.eval_every=1000"], {"seed": 7})
    assert (config.seed, config.sac.batch_size, config.sac.actor_lr, config.train.eval_every) == (7, 64, 3e-4, 1000)


def test_held_out_test_seeds_may_end_right_below_the_evaluation_seeds():
    """train.test_seed: in [0, eval_seed - test_episodes] (config.py), both ends included."""
    config = load_config(None, ["train.test_seed=900", "train.test_episodes=100", "train.eval_seed=1000"])
    assert config.train.test_seed + config.train.test_episodes == config.train.eval_seed
    assert load_config(None, ["train.test_seed=0"]).train.test_seed == 0
    with pytest.raises(ConfigError, match="train.test_seed"):
        load_config(None, ["train.test_seed=901", "train.test_episodes=100", "train.eval_seed=1000"])
    with pytest.raises(ConfigError, match="train.test_seed"):
        load_config(None, ["train.test_seed=-1"])


def test_an_override_with_nothing_after_the_equals_sign_is_the_empty_string():
    """load_config: 'label=' sets the label to '' (the modalities name the run), not YAML's null."""
    config = load_config(None, ["label=The label", "label="])
    assert config.label == "" and config.name == config.modalities


def test_evaluate_cli_prints_table_and_writes_json(tmp_path, capsys):
    run = tmp_path / "run"
    assert train.main(["--out", str(run), "--steps", "100", "--no-progress", *TINY]) == 0
    capsys.readouterr()
    out = tmp_path / "eval.json"
    assert (
        evaluate.main(
            [
                "--checkpoint",
                str(run / rundir.POLICY_FILE),
                "--episodes",
                "12",
                "--seed",
                "5",
                "--json",
                str(out),
                "--without",
                "V",
                "--threads",
                "1",
            ]
        )
        == 0
    )
    printed = capsys.readouterr().out
    assert "hold_the_end" in printed and "authors rule" in printed and "without V" in printed
    assert set(json.loads(out.read_text())["authors_code"]) == set(rundir.OUTCOMES)
    result = json.loads(out.read_text())
    assert sum(result[o] for o in rundir.OUTCOMES) == pytest.approx(1.0)
    assert result["episodes"] == 12 and result["without"] == ["V"]
    (run / "config.yaml").unlink()
    assert evaluate.main(["--checkpoint", str(run / rundir.POLICY_FILE)]) == 2
    assert "config.yaml not found" in capsys.readouterr().err


def test_blanked_columns_follow_the_observation_layout():
    assert evaluate.blanked_columns("All", ["T"]) == [3, 4]
    assert evaluate.blanked_columns("All", ["V"]) == [5, 6, 7, 8]
    assert evaluate.blanked_columns("T+V", ["V"]) == [2, 3, 4, 5]
    with pytest.raises(ValueError):
        evaluate.blanked_columns("V+K", ["T"])


def test_cli_help_exits_cleanly():
    for main in (train.main, evaluate.main):
        with pytest.raises(SystemExit) as exit_info:
            main(["--help"])
        assert exit_info.value.code == 0


def test_best_policy_is_the_best_evaluation_so_far(tmp_path):
    run = tmp_path / "run"
    assert train.main(["--out", str(run), "--steps", "300", "--modalities", "All", "--no-progress", *TINY]) == 0
    rows = [r for r in read_eval(run) if r["tested_without"] == ""]
    best_row = max(rows, key=lambda r: (float(r["hold_the_end"]), float(r["episode_reward"])))
    best = json.loads((run / rundir.BEST_FILE).read_text())
    first_best = next(
        r for r in rows if (r["hold_the_end"], r["episode_reward"]) == (best_row["hold_the_end"], best_row["episode_reward"])
    )
    assert best["step"] == int(first_best["step"])
    assert best["episode_reward"] == pytest.approx(float(best_row["episode_reward"]))
    assert SAC.load(run / rundir.BEST_POLICY_FILE).num_env_steps == best["step"]


def test_evaluation_seeds_depend_on_run_seed_and_index_and_never_meet_the_test_seeds():
    seeds = {train.eval_seeds(load_config(None, [f"seed={s}"]), k) for s in range(3) for k in range(300)}
    assert len(seeds) == 900 and min(seeds) >= load_config().train.test_seed + load_config().train.test_episodes
    ranges = sorted(seeds)
    assert all(b - a >= 10 for a, b in zip(ranges, ranges[1:]))  # 10 episodes each: no overlap
    with pytest.raises(ConfigError, match="train.test_seed"):
        load_config(None, ["train.test_seed=999990"])


def eval_rows_without_wall_time(run: Path) -> list[dict[str, str]]:
    return [{k: v for k, v in row.items() if k != "wall_time_s"} for row in read_eval(run)]


# The run that the tests below stop mid-run (a signal, SIGKILL), resume, and compare with the uninterrupted one.
STOPPED_RUN = ["--steps", "450", "--seed", "3", "--modalities", "All", "--no-progress", *TINY, "train.eval_every=50"]


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory) -> Path:
    """STOPPED_RUN never interrupted, trained once for the tests that compare a stopped and resumed run with it:
    with train.checkpoint_every beyond the run, which changes no number (a checkpoint only saves), so that it is
    the uninterrupted run of each of them whatever their train.checkpoint_every."""
    whole = tmp_path_factory.mktemp("uninterrupted") / "whole"
    threads = torch.get_num_threads()  # (restore_threads gives back a test's own, not a module fixture's)
    try:
        assert train.main(["--out", str(whole), *STOPPED_RUN, "train.checkpoint_every=100000"]) == 0
    finally:
        torch.set_num_threads(threads)
    return whole


def stopped_run_env() -> dict[str, str]:
    """The environment of the dlo-train process a test stops: the test helpers importable (sac_reach_env), and
    4 ms of sleep in each of its steps (sac_reach_env.STEP_DELAY_VARIABLE), time to stop it mid-run. Its
    config.yaml holds no delay: its resumed part, in this process, and the uninterrupted run do not sleep."""
    here = str(Path(__file__).resolve().parent)
    return {**os.environ, "PYTHONPATH": os.pathsep.join([here, os.environ.get("PYTHONPATH", "")]), STEP_DELAY_VARIABLE: "0.004"}


def test_resume_after_sigkill_reproduces_the_uninterrupted_run(tmp_path, uninterrupted):
    """A real SIGKILL of dlo-train mid-run, then --resume: the same evaluations, best policy and
    final weights as the run that was never interrupted (same seed, same config but for its
    train.checkpoint_every, which changes no number)."""
    args = [*STOPPED_RUN, "train.checkpoint_every=150"]
    whole, killed = uninterrupted, tmp_path / "killed"
    process = subprocess.Popen(
        [sys.executable, "-m", "dlo_policy.train", "--out", str(killed), *args],
        env=stopped_run_env(),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and process.poll() is None:
        if (killed / rundir.CHECKPOINT_FILE).exists() and len(read_eval(killed)) >= 5:  # past the checkpoint
            break
        time.sleep(0.05)
    assert process.poll() is None, "the run ended before it could be killed"
    os.kill(process.pid, signal.SIGKILL)
    process.wait()
    interrupted_at = SAC.load(killed / rundir.CHECKPOINT_FILE).num_env_steps
    assert 150 <= interrupted_at < 450 and not (killed / rundir.DONE_FILE).exists()
    assert train.main(["--out", str(killed), "--resume"]) == 0
    assert eval_rows_without_wall_time(killed) == eval_rows_without_wall_time(whole)
    assert (killed / rundir.BEST_FILE).read_text() == (whole / rundir.BEST_FILE).read_text()
    for name in (rundir.POLICY_FILE, rundir.BEST_POLICY_FILE):
        a, b = SAC.load(whole / name), SAC.load(killed / name)
        for p, q in zip(a.actor.parameters(), b.actor.parameters()):
            assert torch.equal(p, q), name
    assert json.loads((killed / rundir.TEST_FILE).read_text()) == json.loads((whole / rundir.TEST_FILE).read_text())


def test_checkpoints_fall_on_episode_boundaries(tmp_path):
    run = tmp_path / "run"
    assert train.main(["--out", str(run), "--steps", "230", "--no-progress", *TINY, "train.checkpoint_every=110"]) == 0
    agent = SAC.load(run / rundir.CHECKPOINT_FILE)
    assert agent.num_env_steps == 230  # the final save
    extra = SAC.extra_state(run / rundir.CHECKPOINT_FILE)
    assert extra["best"] == json.loads((run / rundir.BEST_FILE).read_text())


@pytest.mark.parametrize("content", [b"", os.urandom(4096), b"PK\x03\x04 not a zip", b"\x80\x02}q\x00."])
def test_garbage_checkpoint_is_one_line_naming_the_file(content, tmp_path, capsys):
    path = tmp_path / "policy.pt"
    path.write_bytes(content)
    (tmp_path / "config.yaml").write_text("modalities: All\n")
    assert evaluate.main(["--checkpoint", str(path), "--episodes", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"dlo-evaluate: error: not a dlo-vitac policy file: {path} (")
    with pytest.raises(ValueError, match="^not a dlo-vitac policy file: "):
        SAC.load(path)


def test_missing_checkpoint_is_named(tmp_path, capsys):
    assert evaluate.main(["--checkpoint", "/missing.pt"]) == 2
    assert capsys.readouterr().err.strip() == "dlo-evaluate: error: checkpoint /missing.pt not found"


@pytest.mark.parametrize(
    "override, message",
    [
        (
            "env_options.tactile_noise=loud",
            "env_options: tactile_noise: expected none, partial, full or a pair "
            "[sigma_theta, sigma_y] (rad, m; >= 0) such as [0.1,0.001], got 'loud'",
        ),
        ("env_options.tactile_nois=full", "env_options: unknown option(s) tactile_nois"),
        ("env_options.horizon=0", "env_options: horizon: expected an integer >= 1"),
        ("env_options.without=X", "env_options: modalities must be"),
    ],
)
def test_bad_env_options_are_one_line_and_write_nothing(override, message, tmp_path, capsys):
    run = tmp_path / "run"
    assert train.main(["--out", str(run), "--steps", "10", "--no-progress", override]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert not run.exists()


@pytest.mark.skipif(torch.cuda.is_available(), reason="a CUDA device is present")
@pytest.mark.parametrize(
    "override, message",
    [
        ("train.device=cuda", "sees no CUDA device"),
        ("train.sim_arch=cuda", "Taichi found no CUDA device"),
        ("train.device=tpu", "train.device: must be auto, cpu or cuda"),
    ],
)
def test_gpu_settings_without_a_gpu_exit_2_with_one_line(override, message, tmp_path):
    run = tmp_path / "run"
    env = {k: v for k, v in os.environ.items() if k != "DLO_TI_ARCH"}
    result = subprocess.run(
        [sys.executable, "-m", "dlo_policy.train", "--out", str(run), "--steps", "10", "--no-progress", override],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert result.returncode == 2
    errors = [line for line in result.stderr.splitlines() if not line.startswith("[Taichi]")]
    assert len(errors) == 1 and message in errors[0], result.stderr
    assert not run.exists()


def test_tensorboard_event_files_hold_losses_speed_episodes_and_both_rules(tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    run = tmp_path / "run"
    assert (
        train.main(["--out", str(run), "--steps", "300", "--modalities", "All", "--no-progress", "train.eval_without=[T]", *TINY])
        == 0
    )
    events = EventAccumulator(str(run / rundir.TB_DIR))
    events.Reload()
    tags = set(events.Tags()["scalars"])
    for tag in (
        "loss/critic",
        "loss/actor",
        "loss/alpha",
        "speed/steps_per_s",
        "train/episode_return",
        "train/episode_length",
        "eval/hold_the_end",
        "eval/hold_the_end_authors",
        "eval/episode_reward",
        "eval/alpha",
        "eval/entropy",
        "eval/q_value",
        "eval/saturated",
        "eval_without_T/hold_the_end",
    ):
        assert tag in tags, tag
    assert [e.step for e in events.Scalars("eval/hold_the_end")] == [0, 100, 200, 300]
    rows = [r for r in read_eval(run) if r["tested_without"] == ""]
    assert [e.value for e in events.Scalars("eval/episode_reward")] == pytest.approx([float(r["episode_reward"]) for r in rows])
    assert [e.step for e in events.Scalars("loss/critic")] == [100, 200, 300]  # updates start after step 50


class RecordingWriter:
    """Stands in for torch's SummaryWriter: records the calls dlo-train makes on it, writes nothing."""

    made: list["RecordingWriter"] = []

    def __init__(self, log_dir=None, **kwargs):
        self.calls: list[tuple] = []
        RecordingWriter.made.append(self)

    def add_scalar(self, tag, value, global_step=None, *args, **kwargs):
        self.calls.append(("add_scalar", tag, global_step))

    def flush(self):
        self.calls.append(("flush",))

    def close(self):
        self.calls.append(("close",))


def test_every_evaluation_is_flushed_to_tensorboard_at_once(tmp_path, monkeypatch):
    """dlo-train: each evaluation row's scalars are flushed to the event file as soon as they are written
    (TensorBoardLog.evaluation), so a TensorBoard watching a long run shows it then, not at the next
    flush of SummaryWriter's own timer or at close."""
    monkeypatch.setattr(RecordingWriter, "made", [])
    monkeypatch.setattr("torch.utils.tensorboard.SummaryWriter", RecordingWriter)
    run = tmp_path / "run"
    assert (
        train.main(
            ["--out", str(run), "--steps", "100", "--no-progress", *TINY, "train.eval_without=[T]", "train.test_episodes=2"]
        )
        == 0
    )
    (writer,) = RecordingWriter.made
    calls = writer.calls
    blocks = []  # one per evaluation row: (prefix, step, the call right after its scalars)
    i = 0
    while i < len(calls):
        prefix = calls[i][1].split("/")[0] if calls[i][0] == "add_scalar" else ""
        if not prefix.startswith("eval"):
            i += 1
            continue
        step, j = calls[i][2], i
        while j < len(calls) and calls[j][0] == "add_scalar" and calls[j][1].split("/")[0] == prefix and calls[j][2] == step:
            j += 1
        blocks.append((prefix, step, calls[j] if j < len(calls) else None))
        i = j
    rows = read_eval(run)
    assert len(rows) == 4  # evaluations at steps 0 and 100, each with and without T
    assert blocks == [("eval_without_T" if r["tested_without"] else "eval", int(r["step"]), ("flush",)) for r in rows], calls
    assert calls[-1] == ("close",)


def test_the_held_out_test_shows_progress(tmp_path, capsys):
    run = tmp_path / "run"
    assert (
        train.main(
            [
                "--out",
                str(run),
                "--steps",
                "100",
                "--modalities",
                "All",
                *TINY,
                "train.test_episodes=12",
                "train.eval_without=[T]",
                "train.progress=true",
            ]
        )
        == 0
    )
    err = capsys.readouterr().err
    assert "All held-out test" in err and "24/24" in err and "without T" in err


def test_the_protocol_defaults_are_the_documented_ones():
    """README (Training), docs/ARCHITECTURE.md#task (Evaluation), docs/RESULTS.md (How results are
    measured): every 200 steps on 10 fresh episodes, evaluation k of a run with seed s on seeds
    1,000,000 + 100,000 s + 10 k + (0..9); the held-out test on 100 episodes, seeds 5000-5099."""
    config = load_config()
    assert (config.train.eval_every, config.train.eval_episodes) == (200, 10)
    assert (config.train.test_seed, config.train.test_episodes) == (5000, 100)
    for seed in (0, 1, 3, 9):
        config = load_config(None, [f"seed={seed}"])
        for k in (0, 1, 7, 249):  # 249: the last evaluation of a 50,000-step run
            assert train.eval_seeds(config, k) == 1_000_000 + 100_000 * seed + 10 * k


def test_the_episodes_each_evaluation_and_the_held_out_test_run_on(tmp_path, monkeypatch):
    """What dlo-train --help promises, as the evaluation calls see it (not only the seeds it writes down):
    evaluation k on eval_seeds(k) .. + eval_episodes - 1, every tested input set of an evaluation on the
    same episodes, and the held-out test of best_policy.pt on test_seed .. test_seed + test_episodes - 1."""
    calls = []
    real = train.evaluate_agent

    def spy(agent, env, first_seed, episodes, *args, **kwargs):
        calls.append((first_seed, episodes))
        return real(agent, env, first_seed, episodes, *args, **kwargs)

    monkeypatch.setattr(train, "evaluate_agent", spy)
    run = tmp_path / "run"
    assert (
        train.main(
            [
                "--out",
                str(run),
                "--steps",
                "200",
                "--seed",
                "2",
                "--no-progress",
                *TINY,
                "train.eval_without=[T]",
                "train.test_episodes=30",
            ]
        )
        == 0
    )
    seeds = [1_000_000 + 100_000 * 2 + 10 * k for k in range(3)]  # steps 0, 100, 200 (TINY: eval_every 100)
    assert calls == [(s, 10) for s in seeds for _ in ("", "T")] + [(5000, 30), (5000, 30)]
    assert [int(r["eval_seed"]) for r in read_eval(run)] == [s for s in seeds for _ in ("", "T")]
    for name in (rundir.TEST_FILE, rundir.test_file("T")):
        test = json.loads((run / name).read_text())
        assert (test["seed"], test["episodes"]) == (5000, 30)


def test_resume_takes_the_saved_config_and_refuses_anything_but_steps(tmp_path, capsys):
    """dlo-train --help: --resume continues the run in --out from its last checkpoint, with its saved
    config; only --steps may change. Without a checkpoint there is nothing to resume: one line, exit 2."""
    from dlo_policy.config import save_config

    run = tmp_path / "run"
    for extra in (["sac.batch_size=64"], ["--seed", "3"], ["--modalities", "V"], ["--config", "c.yaml"], ["--label", "x"]):
        assert train.main(["--out", str(run), "--resume", *extra]) == 2
        err = capsys.readouterr().err
        assert err.strip() == "dlo-train: error: --resume uses the run's saved config; only --steps may be given"
    assert not run.exists()
    run.mkdir()
    save_config(load_config(None, TINY), run / rundir.CONFIG_FILE)
    assert train.main(["--out", str(run), "--resume", "--steps", "200"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"--resume: no {run / rundir.CHECKPOINT_FILE} to resume from" in err
    assert {p.name for p in run.iterdir()} <= {rundir.CONFIG_FILE, rundir.LOCK_FILE}  # nothing trained, nothing written


RULES_ENV = '''"""A tiny env module that takes the cable env's task_rules option and notes what it was given."""
import sac_reach_env

GIVEN = []


def make_env(modalities="All", seed=0, task_rules=None, **options):
    GIVEN.append(task_rules)
    return sac_reach_env.make_env(modalities, seed, **options)


def make_vec_env(num_envs, modalities="All", seed=0, task_rules=None, **options):
    GIVEN.append(task_rules)
    return sac_reach_env.make_vec_env(num_envs, modalities, seed, **options)
'''


def test_a_run_from_before_task_rules_resumes_on_the_rules_it_was_trained_on(tmp_path, monkeypatch):
    """dlo-train: "the task rules are always recorded: a new run's are the default, an older run resumed
    keeps paper_text" (dlo_interface.task.LEGACY_TASK_RULES), in config.yaml and in the env it trains on."""
    (tmp_path / "audit_rules_env.py").write_text(RULES_ENV)
    monkeypatch.syspath_prepend(str(tmp_path))
    env_module = importlib.import_module("audit_rules_env")
    monkeypatch.setattr(config_module, "CABLE_ENV", "audit_rules_env")  # it takes task_rules like the cable env
    tiny = [o for o in TINY if not o.startswith("env_module")]
    run = tmp_path / "run"
    assert (
        train.main(
            [
                "--out",
                str(run),
                "--steps",
                "60",
                "env_module=audit_rules_env",
                *tiny,
                "train.progress=false",
                "train.eval_episodes=3",
                "train.test_episodes=2",
            ]
        )
        == 0
    )
    saved = yaml.safe_load((run / rundir.CONFIG_FILE).read_text())
    assert saved["env_options"] == {"task_rules": DEFAULT_TASK_RULES}
    assert set(env_module.GIVEN) == {DEFAULT_TASK_RULES}

    del saved["env_options"]["task_rules"]  # a run directory written before the option existed
    (run / rundir.CONFIG_FILE).write_text(yaml.safe_dump(saved, sort_keys=False))
    env_module.GIVEN.clear()
    assert train.main(["--out", str(run), "--resume", "--steps", "120"]) == 0
    assert yaml.safe_load((run / rundir.CONFIG_FILE).read_text())["env_options"] == {"task_rules": LEGACY_TASK_RULES}
    assert env_module.GIVEN and set(env_module.GIVEN) == {LEGACY_TASK_RULES}


def test_the_progress_bars_show_steps_training_returns_and_the_last_evaluation(tmp_path, capsys):
    """dlo-train's progress (stderr; here not a terminal: plain lines, dlo_common.console.Progress): the run's
    name, steps done of the total, and after each evaluation the mean return of the last training episodes, the
    evaluation's reward and hold-the-end fraction under both outcome rules, alpha; the held-out test counts
    episodes over every tested input set; --no-progress shows neither."""
    import re

    run = tmp_path / "run"
    started = time.perf_counter()
    assert (
        train.main(
            [
                "--out",
                str(run),
                "--steps",
                "100",
                "--modalities",
                "All",
                *TINY,
                "train.test_episodes=3",
                "train.eval_without=[T]",
                "train.progress=true",
            ]
        )
        == 0
    )
    elapsed = time.perf_counter() - started
    err = capsys.readouterr().err
    assert re.search(r"^All: 100/100 steps \(100%\), .* steps/s", err, re.MULTILINE), err
    assert re.search(
        r"train_return -?\d+\.\d\d, eval_reward -?\d+\.\d\d, hold_the_end \d+% paper rule / \d+% "
        r"authors' rule, alpha \d\.\d{3}$",
        err,
        re.MULTILINE,
    ), err
    assert re.search(r"^All held-out test: 6/6 episodes \(100%\), .* episodes/s, .*, without T$", err, re.MULTILINE), err
    assert "all inputs" in err
    rows = read_eval(run)
    # what the run records: the last all-inputs evaluation in done.json; wall seconds of this run (2 decimals);
    # the learner's health of evaluation step s drawn with a generator seeded s (reproducible on resume)
    done = json.loads((run / rundir.DONE_FILE).read_text())
    assert {k: str(v) for k, v in done["last_eval"].items()} == {k: v for k, v in rows[-2].items()}
    assert rows[-2]["tested_without"] == "" and int(rows[-2]["step"]) == 100
    for value in [r["wall_time_s"] for r in rows] + [str(done["wall_time_s"])]:
        assert 0 <= float(value) <= elapsed and len(value.partition(".")[2]) <= 2, value
    health = SAC.load(run / rundir.CHECKPOINT_FILE).diagnostics(seed=100)
    for key in ("alpha", "entropy", "q_value", "saturated"):
        assert float(rows[-1][key]) == round(health[key], 6), key
    assert max(len(r[k].partition(".")[2]) for r in rows for k in ("alpha", "entropy", "q_value")) == 6
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(run / rundir.TB_DIR))
    events.Reload()
    lengths = [e.value for e in events.Scalars("train/episode_length")]
    returns = [e.value for e in events.Scalars("train/episode_return")]
    assert len(lengths) >= 5 and all(1 <= n <= 20 for n in lengths) and all(r < 0 for r in returns)  # reward <= 0
    assert train.main(["--out", str(run), "--resume", "--steps", "200"]) == 0  # the count starts where the run stands
    err = capsys.readouterr().err
    steps = [line.split()[1] for line in err.splitlines() if line.startswith("All: ")]
    assert err.startswith("dlo-train: resuming from step 100 (") and steps == [f"{n}/200" for n in range(120, 201, 20)]
    quiet = tmp_path / "quiet"
    assert (
        train.main(
            [
                "--out",
                str(quiet),
                "--steps",
                "100",
                "--modalities",
                "All",
                "--no-progress",
                *TINY,
                "train.test_episodes=3",
                "train.eval_without=[T]",
                "train.progress=true",
            ]
        )
        == 0
    )
    err = capsys.readouterr().err
    assert "100/100" not in err and "held-out test" not in err and "it/s" not in err, err


def test_resume_rewinds_best_json_and_best_policy_to_the_checkpoint(tmp_path):
    """dlo-train --resume: best.json and best_policy.pt go back to the best of the checkpoint's step at once
    (evaluations after the checkpoint are run again), whatever a later evaluation had written there."""
    run = tmp_path / "run"
    assert train.main(["--out", str(run), "--steps", "100", "--no-progress", *TINY, "train.test_episodes=2"]) == 0
    best = json.loads((run / rundir.BEST_FILE).read_text())
    assert best == SAC.extra_state(run / rundir.CHECKPOINT_FILE)["best"]
    (run / rundir.BEST_FILE).write_text(json.dumps({"step": 999, "hold_the_end": 1.0, "episode_reward": 0.0}))
    (run / rundir.BEST_POLICY_FILE).write_bytes(b"a later evaluation's policy")
    trainer = train.Trainer(rundir.read_config(run), run, resume=True)
    try:
        assert json.loads((run / rundir.BEST_FILE).read_text()) == best
        assert SAC.load(run / rundir.BEST_POLICY_FILE).num_env_steps == best["step"]
        assert trainer.best == best
    finally:
        trainer.env.close()
        trainer.eval_env.close()
        trainer.tb.close()


CLOSING_ENV = '''"""The reach env, noting every env dlo-train makes and how often it is closed."""
import sac_reach_env

MADE = []


class Noted:
    def __init__(self, env):
        self.env, self.closed = env, 0

    def __getattr__(self, name):
        return getattr(self.env, name)

    def close(self):
        self.closed += 1
        return self.env.close()


def make_env(modalities="All", seed=0, **options):
    MADE.append(Noted(sac_reach_env.make_env(modalities, seed, **options)))
    return MADE[-1]


def make_vec_env(num_envs, modalities="All", seed=0, **options):
    MADE.append(Noted(sac_reach_env.make_vec_env(num_envs, modalities, seed, **options)))
    return MADE[-1]
'''


def test_a_run_closes_its_training_and_evaluation_envs_also_when_it_fails(tmp_path, monkeypatch):
    (tmp_path / "closing_env.py").write_text(CLOSING_ENV)
    monkeypatch.syspath_prepend(str(tmp_path))
    env_module = importlib.import_module("closing_env")
    tiny = [o for o in TINY if not o.startswith("env_module")]
    assert (
        train.main(
            [
                "--out",
                str(tmp_path / "run"),
                "--steps",
                "60",
                "--no-progress",
                "env_module=closing_env",
                *tiny,
                "train.test_episodes=2",
            ]
        )
        == 0
    )
    assert [env.closed for env in env_module.MADE] == [1, 1]  # the training env, then the evaluation env
    env_module.MADE.clear()
    config = load_config(
        None, ["env_module=closing_env", *tiny, "train.progress=false", "train.total_steps=200", "env_options.crash_after=90"]
    )
    with pytest.raises(InterruptedError):
        train.train(config, tmp_path / "crashed")
    assert [env.closed for env in env_module.MADE] == [1, 1]
    assert not (tmp_path / "crashed" / rundir.CHECKPOINT_FILE).exists()  # the first one is due at step 100


def resumed_equals_whole(resumed: Path, whole: Path) -> None:
    """The resumed run is the uninterrupted one: evaluations, best evaluation, final and best policies, held-out test."""
    assert eval_rows_without_wall_time(resumed) == eval_rows_without_wall_time(whole)
    assert (resumed / rundir.BEST_FILE).read_text() == (whole / rundir.BEST_FILE).read_text()
    for name in (rundir.POLICY_FILE, rundir.BEST_POLICY_FILE):
        a, b = SAC.load(whole / name), SAC.load(resumed / name)
        for p, q in zip(a.actor.parameters(), b.actor.parameters()):
            assert torch.equal(p, q), name
    assert json.loads((resumed / rundir.TEST_FILE).read_text()) == json.loads((whole / rundir.TEST_FILE).read_text())


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_stops_the_run_at_an_episode_end_with_a_checkpoint_there_and_the_resumed_run_is_the_whole_one(
    sig, tmp_path, capsys, uninterrupted
):
    """dlo-train --help: Ctrl-C (or SIGTERM) stops the run at the end of its episode with a checkpoint there (here
    the only one: train.checkpoint_every lies beyond the run), one line on stderr naming that step and the command
    that resumes it, exit 130, no traceback, nothing on stdout; --resume says the step it resumes from, and the
    run it finishes is the run that was never interrupted, number for number."""
    args = [*STOPPED_RUN, "train.checkpoint_every=100000"]
    whole, stopped = uninterrupted, tmp_path / "stopped"
    process = subprocess.Popen(
        [sys.executable, "-m", "dlo_policy.train", "--out", str(stopped), *args],
        env=stopped_run_env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=default_sigint,
    )  # as from a terminal, also in a background suite
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and process.poll() is None:
        if (stopped / rundir.EVAL_FILE).exists() and len(read_eval(stopped)) >= 3:  # evaluated at step 100
            break
        time.sleep(0.05)
    assert process.poll() is None, "the run ended before the signal"
    process.send_signal(sig)
    out, err = process.communicate(timeout=120)
    step = SAC.load(stopped / rundir.CHECKPOINT_FILE).num_env_steps
    assert (process.returncode, out) == (130, ""), err
    assert err == f"dlo-train: interrupted at step {step}; resume with: dlo-train --out {stopped} --resume\n"
    assert 100 <= step < 450 and not (stopped / rundir.DONE_FILE).exists()
    capsys.readouterr()
    assert train.main(["--out", str(stopped), "--resume"]) == 0
    assert capsys.readouterr().err.startswith(f"dlo-train: resuming from step {step} (")
    resumed_equals_whole(stopped, whole)
    assert [s["from_step"] for s in json.loads((stopped / rundir.DONE_FILE).read_text())["sources"]] == [0, step]


def test_a_signal_before_the_first_step_leaves_a_checkpoint_at_step_0_and_the_resumed_run_is_the_whole_one(tmp_path):
    """A signal while the run starts (its environments built, its first evaluation): a checkpoint at step 0, so
    that --resume works (the evaluation at step 0 runs again, not twice in eval.csv)."""
    args = ["--steps", "200", "--seed", "2", "--no-progress", *TINY, "train.test_episodes=20"]
    whole, stopped = tmp_path / "whole", tmp_path / "stopped"
    assert train.main(["--out", str(whole), *args]) == 0
    stop = train.StopSignals()
    stop.signum = signal.SIGINT  # as if it came while the trainer was being built
    config = train.resolve_config(train.build_parser().parse_args(["--out", str(stopped), *args]))
    with pytest.raises(train.TrainingInterrupted) as interrupted:
        train.Trainer(config, stopped, stop=stop).run()
    assert interrupted.value.step == 0 == SAC.load(stopped / rundir.CHECKPOINT_FILE).num_env_steps
    assert train.main(["--out", str(stopped), "--resume"]) == 0
    resumed_equals_whole(stopped, whole)


def default_sigint():
    """preexec_fn: the child starts with SIGINT's default action (a suite run as a background job ignores it)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_the_first_signal_asks_for_a_stop_a_second_one_stops_at_once_and_an_ignored_one_stays_ignored():
    inherited = signal.getsignal(signal.SIGINT)  # ignored when the suite runs as a background job
    signal.signal(signal.SIGINT, signal.default_int_handler)  # as in a terminal
    try:
        _first_signal_second_signal_ignored_signal()
    finally:
        signal.signal(signal.SIGINT, inherited)


def _first_signal_second_signal_ignored_signal():
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    with train.StopSignals() as stop:
        assert signal.getsignal(signal.SIGINT) == stop._handle == signal.getsignal(signal.SIGTERM)
        stop._handle(signal.SIGTERM, None)
        assert stop.requested and stop.signum == signal.SIGTERM
        with pytest.raises(KeyboardInterrupt):  # Ctrl-C again: at once (the last checkpoint stays)
            stop._handle(signal.SIGINT, None)
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before
    with train.StopSignals() as stop:
        stop.immediate = True  # the held-out test: nothing left to save
        with pytest.raises(KeyboardInterrupt):
            stop._handle(signal.SIGINT, None)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # nohup, or a dlo-experiments worker: its driver stops it
    try:
        with train.StopSignals():
            assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, before[0])
