"""dlo-normalizer-drift (was scripts/normalizer_drift.py): --help, one-line errors on a run
directory it cannot read, and a tiny run on a synthetic run directory whose drift is known."""

import json
import os
import subprocess
from pathlib import Path

import pytest
import torch
from dlo_policy import normalizer_drift

INSTALL_BIN = Path(__file__).resolve().parents[3] / "ros_ws" / "install" / "dlo_policy" / "lib" / "dlo_policy"


def executable(*args, timeout=300):
    env = {**os.environ, "PATH": f"{INSTALL_BIN}:{os.environ['PATH']}"}
    return subprocess.run(["dlo-normalizer-drift", *args], capture_output=True, text=True, timeout=timeout, env=env)


def make_run(path: Path, steps=40) -> Path:
    """A K-only run: x_G constant 0 for the first half, 1 after; y_G and c_G constant: the largest shift
    is in x_G, in the window where the jump happens."""
    path.mkdir(parents=True)
    obs = torch.zeros(100, 3)
    obs[steps // 2 : steps, 0] = 1.0
    torch.save({"counters": {"env_steps": steps, "updates": 0, "episodes": 0}, "replay": {"obs": obs}}, path / "checkpoint.pt")
    (path / "config.yaml").write_text("modalities: K\n")
    (path / "eval.csv").write_text("step,tested_without,hold_the_end\n10,,0.0\n20,,0.5\n20,T,0.0\n30,,1.0\n40,,1.0\n")
    return path


def test_help():
    result = executable("--help", timeout=120)
    assert result.returncode == 0 and "RUN_DIR" in result.stdout and "--every" in result.stdout


def test_a_tiny_run_finds_the_jump_and_prints_json_last(tmp_path):
    run = make_run(tmp_path / "run")
    result = executable(str(run), "--every", "10")
    assert result.returncode == 0, result.stderr
    payload = json.loads(result.stdout.strip().splitlines()[-1])
    assert payload["steps"] == 40 and [w["step"] for w in payload["windows"]] == [20, 30, 40]
    shifts = {w["step"]: w for w in payload["windows"]}
    assert shifts[30]["dimension"] == "x_G" and shifts[30]["shift"] > shifts[40]["shift"] > 0.0
    assert shifts[20]["shift"] == 0.0 and shifts[20]["hold_the_end"] == 0.5  # the T-ablated row is not counted


def test_a_run_with_the_previous_action_names_its_columns(tmp_path):
    """env_options.previous_action: the observation's last 3 columns are the previous action (a_x, a_y, a_c)."""
    run = tmp_path / "run"
    run.mkdir()
    obs = torch.zeros(100, 6)
    obs[20:40, 4] = 1.0  # a_y jumps
    torch.save({"counters": {"env_steps": 40, "updates": 0, "episodes": 0}, "replay": {"obs": obs}}, run / "checkpoint.pt")
    (run / "config.yaml").write_text("modalities: K\nenv_options:\n  previous_action: true\n")
    (run / "eval.csv").write_text("step,tested_without,hold_the_end\n10,,0.0\n20,,0.5\n30,,1.0\n40,,1.0\n")
    windows = {w["step"]: w for w in normalizer_drift.drift(run, 10)["windows"]}
    assert windows[30]["dimension"] == "a_y"


@pytest.mark.parametrize(
    "case, message",
    [
        ("missing", "checkpoint.pt not found"),
        ("text", "not a full dlo-train checkpoint with its replay buffer"),
        ("policy", "not a full dlo-train checkpoint with its replay buffer (KeyError"),
        ("every", "--every must be >= 1, got 0"),
        ("none", "the following arguments are required: RUN_DIR"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, case, message):
    run = make_run(tmp_path / "run")
    argv = [str(run)]
    if case == "missing":
        argv = [str(tmp_path / "elsewhere")]
    elif case == "text":
        (run / "checkpoint.pt").write_text("not a checkpoint\n")
    elif case == "policy":  # a policy file has no replay buffer
        torch.save({"actor": {}}, run / "checkpoint.pt")
    elif case == "every":
        argv += ["--every", "0"]
    else:
        argv = []
    with pytest.raises(SystemExit) as exit_:
        raise SystemExit(normalizer_drift.main(argv))
    err = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and len(err.splitlines()) == 1 and message in err, err
    assert err.startswith("dlo-normalizer-drift: error: ") and capsys.readouterr().out == ""
