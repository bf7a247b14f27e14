"""dlo-train train.init_from (fine-tuning): a run that starts from another run's checkpoint takes its networks,
temperature, optimiser states and observation scaling, keeps its own steps, replay buffer and random draws, acts
with the policy it took from its first step (also after a resume), records the file it started from, and refuses
a file it cannot start from in one line."""

import hashlib
import json
import signal
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from dlo_policy import rundir, train
from dlo_policy.sac import SAC

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib: helper modules

from tiny_training import TINY as TINY_RUN  # noqa: E402
from tiny_training import restore_threads  # noqa: E402,F401 (restore_threads: an autouse fixture)

TINY = [*TINY_RUN, "train.test_episodes=5"]  # the held-out test is not what these tests check

NO_UPDATES = "sac.learning_starts=100000"  # the started run changes nothing of what it took


@pytest.fixture(scope="module")
def parent(tmp_path_factory) -> Path:
    """A tiny run of 200 steps (seed 1): the checkpoint the fine-tuning runs start from."""
    run = tmp_path_factory.mktemp("parent") / "run"
    previous = torch.get_num_threads()
    assert train.main(["--out", str(run), "--steps", "200", "--seed", "1", "--no-progress", *TINY]) == 0
    torch.set_num_threads(previous)
    return run


def same_tensors(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_the_started_run_has_the_checkpoints_agent_and_its_own_steps_buffer_and_record(parent, tmp_path):
    checkpoint = parent / rundir.CHECKPOINT_FILE
    run = tmp_path / "child"
    args = ["--out", str(run), "--steps", "120", "--seed", "2", "--no-progress", *TINY, NO_UPDATES]
    assert train.main([*args, f"train.init_from={checkpoint}"]) == 0
    theirs, mine = SAC.load(checkpoint), SAC.load(run / rundir.CHECKPOINT_FILE)
    for part in ("actor", "critic", "critic_target"):
        assert same_tensors(getattr(theirs, part).state_dict(), getattr(mine, part).state_dict()), part
    assert torch.equal(theirs.log_alpha, mine.log_alpha)
    assert (mine.num_env_steps, mine.num_updates, len(mine.replay)) == (120, 0, 120)  # its own steps and buffer
    assert mine.normalizer.count == theirs.normalizer.count + 120  # the scaling went on from the checkpoint's
    assert [int(r["step"]) for r in rundir.read_eval_rows(run)][0] == 0
    assert yaml.safe_load((run / rundir.CONFIG_FILE).read_text())["train"]["init_from"] == str(checkpoint)
    record = json.loads((run / rundir.INIT_FILE).read_text())
    assert record == {
        "path": str(checkpoint.resolve()),
        "sha256": hashlib.sha256(checkpoint.read_bytes()).hexdigest(),
        "env_steps": 200,
        "seed": 1,
        "modalities": record["modalities"],
    }
    assert rundir.INIT_FILE in rundir.record_names(run)  # dlo-experiments --collect keeps it
    # a new agent of the same seed and steps, started from nothing: another buffer (uniform actions, other networks)
    fresh = tmp_path / "fresh"
    assert train.main(["--out", str(fresh), "--steps", "120", "--seed", "2", "--no-progress", *TINY, NO_UPDATES]) == 0
    assert not np.array_equal(
        SAC.load(fresh / rundir.CHECKPOINT_FILE).replay.state_dict()["actions"][:120].numpy(),
        mine.replay.state_dict()["actions"][:120].numpy(),
    )
    assert not (fresh / rundir.INIT_FILE).exists()


def test_a_started_agent_samples_its_policy_from_the_first_step_and_a_new_one_acts_uniformly(parent):
    agent = SAC.load(parent / rundir.CHECKPOINT_FILE)
    obs = np.linspace(-1, 1, agent.obs_dim).astype(np.float32)
    started = SAC(agent.obs_dim, agent.action_low, agent.action_high, agent.config, seed=5)
    new = SAC(agent.obs_dim, agent.action_low, agent.action_high, agent.config, seed=5)
    started.initialise_from(parent / rundir.CHECKPOINT_FILE)
    assert started.num_env_steps == 0 < started.config.learning_starts and not started.uniform_warmup
    for one, policy_like in ((started, True), (new, False)):
        state = one.generator.get_state()
        acted = one.explore(obs)
        one.generator.set_state(state)
        sampled = one.policy_action(obs, deterministic=False)
        assert np.array_equal(acted, sampled) == policy_like
    assert started.config.actor_lr == started.actor_optimizer.param_groups[0]["lr"]


def test_a_resumed_started_run_is_the_whole_one(parent, tmp_path):
    """Stopped at an episode end and resumed, the run acts with its policy as the whole run did (config.yaml's
    init_from, not the checkpoint, says that it was started from another): the same transitions and evaluations."""
    checkpoint = parent / rundir.CHECKPOINT_FILE
    args = ["--steps", "180", "--seed", "2", "--no-progress", *TINY, NO_UPDATES, f"train.init_from={checkpoint}"]
    whole, part = tmp_path / "whole", tmp_path / "part"
    assert train.main(["--out", str(whole), *args, "train.eval_every=60"]) == 0
    config = train.resolve_config(train.build_parser().parse_args(["--out", str(part), *args, "train.eval_every=60"]))
    stop = train.StopSignals()
    trainer = train.Trainer(config, part, stop=stop)
    on_step = trainer.on_step

    def stopping(agent, result):  # a Ctrl-C after step 70: the run stops at that episode's end
        if agent.num_env_steps == 70:
            stop.signum = signal.SIGINT
        return on_step(agent, result)

    trainer.on_step = stopping
    with pytest.raises(train.TrainingInterrupted) as stopped:
        trainer.run()
    assert 70 <= stopped.value.step < 180
    assert train.main(["--out", str(part), "--resume"]) == 0
    replay = [SAC.load(run / rundir.CHECKPOINT_FILE).replay.state_dict() for run in (whole, part)]
    for key in ("obs", "actions", "rewards"):
        assert torch.equal(replay[0][key], replay[1][key]), key
    strip = [{k: v for k, v in row.items() if k != "wall_time_s"} for row in rundir.read_eval_rows(whole)]
    assert strip == [{k: v for k, v in row.items() if k != "wall_time_s"} for row in rundir.read_eval_rows(part)]


@pytest.mark.parametrize(
    "target, override, message",
    [
        ("policy.pt", "", "a policy file (actor only); fine-tuning needs a run's checkpoint.pt"),
        (
            "checkpoint.pt",
            "sac.hidden_sizes=[16,16]",
            "its networks have hidden sizes [32, 32], this run's sac.hidden_sizes [16, 16]",
        ),
        ("checkpoint.pt", "sac.observation_scaling=none", "its observation scaling is running, this run's none"),
        ("missing.pt", "", "not found"),
    ],
)
def test_a_file_it_cannot_start_from_is_one_line(parent, tmp_path, capsys, target, override, message):
    run = tmp_path / "child"
    args = ["--out", str(run), "--steps", "60", "--no-progress", *TINY, f"train.init_from={parent / target}"]
    assert train.main([*args, *([override] if override else [])]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("dlo-train: error: train.init_from: ") and message in err, err
    assert not (run / rundir.EVAL_FILE).exists() and not (run / rundir.CHECKPOINT_FILE).exists()


def test_a_started_run_chooses_its_best_policy_after_step_0(parent, tmp_path):
    """Step 0 evaluates the policy the run took: a started run's best_policy.pt is chosen among its evaluations
    after it (the first replaces step 0's, then the usual rule); a new run keeps the usual rule from step 0."""
    rows = [(0, 1.0), (60, 0.0), (120, 0.5), (180, 0.2)]
    chosen = {}
    for name, extra in (("started", [f"train.init_from={parent / rundir.CHECKPOINT_FILE}"]), ("new", [])):
        args = ["--out", str(tmp_path / name), "--steps", "60", "--no-progress", *TINY, *extra]
        trainer = train.Trainer(train.resolve_config(train.build_parser().parse_args(args)), tmp_path / name)
        for step, hold in rows:
            trainer.keep_if_best({"step": step, "hold_the_end": hold, "hold_the_end_authors": hold, "episode_reward": 0.0})
        chosen[name] = json.loads((tmp_path / name / rundir.BEST_FILE).read_text())["step"]
        trainer.env.close()
        trainer.eval_env.close()
    assert chosen == {"started": 120, "new": 0}
