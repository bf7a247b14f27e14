"""dlo-train's output and its answers (dlo-train --help): stdout carries only the JSON summary (it can be piped
to a JSON parser); progress goes to stderr, a bar on a terminal and plain lines elsewhere, showing the last
evaluation under both outcome rules; a wrong key=value is answered at once with the key it likely meant; a run
that does not set train.checkpoint_every checkpoints every tenth of its steps, so that a short one can be
resumed too."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from dlo_policy import rundir, train
from dlo_policy.sac import SAC

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # --import-mode=importlib: sac_reach_env

from tiny_training import TINY, restore_threads  # noqa: E402,F401 (restore_threads: an autouse fixture)


def environment() -> dict:
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(HERE), os.environ.get("PYTHONPATH", "")])}


def test_stdout_is_only_the_json_summary(tmp_path):
    """`dlo-train ... | python -c 'import json, sys; json.loads(sys.stdin.read())'` works: Taichi's start line
    ("[Taichi] Starting on arch=x64") is not on stdout, nor is the progress."""
    run = tmp_path / "run"
    result = subprocess.run(
        [sys.executable, "-m", "dlo_policy.train", "--out", str(run), "--steps", "100", *TINY, "train.test_episodes=2"],
        capture_output=True,
        text=True,
        timeout=600,
        env=environment(),
    )
    assert result.returncode == 0, result.stderr[-3000:]
    summary = json.loads(result.stdout)
    assert summary["env_steps"] == 100 and summary == json.loads((run / rundir.DONE_FILE).read_text())


def test_off_a_terminal_progress_is_a_plain_line_every_tenth_showing_both_outcome_rules(tmp_path, capsys):
    """A log file (here pytest's capture) gets no bar refreshes (carriage returns): a line at every tenth of the
    run; the last evaluation's hold-the-end fraction under the paper-text rule and under the authors' rule."""
    run = tmp_path / "run"
    assert train.main(["--out", str(run), "--steps", "200", *TINY, "train.test_episodes=4", "train.progress=true"]) == 0
    err = capsys.readouterr().err
    assert "\r" not in err
    lines = [line for line in err.splitlines() if line.startswith("All: ")]
    assert [line.split()[1] for line in lines] == [f"{step}/200" for step in range(20, 201, 20)]
    rows = {int(row["step"]): row for row in rundir.read_eval_rows(run) if row["tested_without"] == ""}
    last = rows[200]
    shown = f"hold_the_end {float(last['hold_the_end']):.0%} paper rule / {float(last['hold_the_end_authors']):.0%} authors' rule"
    assert shown in lines[-1], lines[-1]
    assert re.search(r"^All held-out test: 4/4 episodes \(100%\)", err, re.MULTILINE), err


def test_a_wrong_key_is_answered_with_the_likely_one_before_torch_loads(tmp_path):
    """`dlo-train sac.batch_sise=64`: one line naming the closest key (dlo_common.params.did_you_mean), exit 2,
    answered before torch (and the simulator) is loaded: at once, not after seconds of imports."""
    probe = (
        "import json, sys\n"
        "from dlo_policy import train\n"
        f"code = train.main(['--out', {str(tmp_path / 'run')!r}, 'sac.batch_sise=64', 'train.eval_every=500'])\n"
        "print(json.dumps({'code': code, 'torch': 'torch' in sys.modules}))\n"
    )
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=300, env=environment())
    assert json.loads(result.stdout) == {"code": 2, "torch": False}, result.stdout + result.stderr
    assert result.stderr == "dlo-train: error: unknown key 'sac.batch_sise'; did you mean 'sac.batch_size'?\n"
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    "override, key",
    [
        ("sak.batch_size=64", "sac.batch_size"),
        ("evl_every=3", "train.eval_every"),
        ("train.checkpoint_evry=9", "train.checkpoint_every"),
        ("sac.normalize_observations=true", "sac.observation_scaling"),  # its name before it was released
    ],
)
def test_every_unknown_key_gets_a_suggestion_and_the_known_ones_pass(override, key, tmp_path, capsys):
    assert train.main(["--out", str(tmp_path / "run"), override]) == 2
    assert capsys.readouterr().err.endswith(f"; did you mean {key!r}?\n")
    from dlo_policy.cli import check_override_keys

    check_override_keys(
        ["sac.observation_scaling=none", "env_options.anything=1", "train={eval_every: 5}", "seed=3", "label="]
    )  # a key of a section, a free mapping, a section, top-level keys


def test_a_short_run_that_does_not_set_checkpoint_every_can_be_resumed(tmp_path):
    """train.checkpoint_every unset: a tenth of the run (at least 100, at most 5,000), recorded in config.yaml;
    a 300-step run that dies at step 250 has a checkpoint to resume from (with 5,000 it had none)."""
    tiny = [a for a in TINY if not a.startswith("train.checkpoint_every=")]
    run = tmp_path / "run"
    with pytest.raises(InterruptedError):  # the env dies at its 250th step (a killed run)
        train.main(["--out", str(run), "--steps", "300", "--no-progress", *tiny, "env_options.crash_after=250"])
    assert yaml.safe_load((run / rundir.CONFIG_FILE).read_text())["train"]["checkpoint_every"] == 100
    assert 200 <= SAC.load(run / rundir.CHECKPOINT_FILE).num_env_steps < 250
    assert train.main(["--out", str(run), "--resume"]) == 0
    assert [int(row["step"]) for row in rundir.read_eval_rows(run) if row["tested_without"] == ""] == [0, 100, 200, 300]
    assert [train.default_checkpoint_every(n) for n in (300, 1500, 20_000, 50_000, 200_000)] == [100, 150, 2000, 5000, 5000]


def test_a_checkpoint_interval_that_is_set_is_kept(tmp_path):
    def resolved(*argv):
        return train.resolve_config(train.build_parser().parse_args(["--out", str(tmp_path / "run"), *argv]))

    assert resolved("--steps", "1500").train.checkpoint_every == 150
    assert resolved("--steps", "1500", "train.checkpoint_every=7").train.checkpoint_every == 7
    assert resolved("--steps", "1500", "train={checkpoint_every: 8}").train.checkpoint_every == 8
    config_file = tmp_path / "c.yaml"
    config_file.write_text("train: {checkpoint_every: 9}\n")
    assert resolved("--steps", "1500", "--config", str(config_file)).train.checkpoint_every == 9
    config_file.write_text("train: {eval_every: 300}\n")
    assert resolved("--steps", "1500", "--config", str(config_file)).train.checkpoint_every == 150
    shipped = Path(train.__file__).resolve().parents[1] / "config" / "sac_default.yaml"  # a user's copy of it
    assert resolved("--steps", "1500", "--config", str(shipped)).train.checkpoint_every == 150
    assert resolved("--steps", "1500", "train.checkpoint_every=0").train.checkpoint_every == 150
