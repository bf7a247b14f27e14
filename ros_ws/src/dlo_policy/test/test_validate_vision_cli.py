"""dlo-validate-vision (was scripts/validate_vision.py): --help, one-line errors on bad
input, a tiny real run whose JSON line comes last, and the statistics where no state shows the cable
to both (None, not a crash)."""

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
from dlo_policy import validate_vision

INSTALL_BIN = Path(__file__).resolve().parents[3] / "ros_ws" / "install" / "dlo_policy" / "lib" / "dlo_policy"


def executable(*args, timeout=600):
    env = {**os.environ, "PATH": f"{INSTALL_BIN}:{os.environ['PATH']}"}
    return subprocess.run(["dlo-validate-vision", *args], capture_output=True, text=True, timeout=timeout, env=env)


def test_help():
    result = executable("--help", timeout=120)
    assert result.returncode == 0 and "ground truth" in result.stdout
    for option in ("--num-envs", "--rounds", "--steps", "--seed"):
        assert option in result.stdout


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--steps", "0"], "--num-envs, --rounds and --steps must be >= 1"),
        (["--num-envs", "-2"], "--num-envs, --rounds and --steps must be >= 1"),
        (["--rounds", "two"], "argument --rounds: invalid int value: 'two'"),
        (["--episodes", "64"], "unrecognized arguments: --episodes 64"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(capsys, argv, message):
    with pytest.raises(SystemExit) as exit_:
        raise SystemExit(validate_vision.main(argv))
    err = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and len(err.splitlines()) == 1 and message in err, err
    assert err.startswith("dlo-validate-vision: error: ")


def test_a_tiny_real_run():
    result = executable("--num-envs", "2", "--rounds", "1", "--steps", "2", "--seed", "7")
    assert result.returncode == 0, result.stderr[-3000:]
    lines = result.stdout.strip().splitlines()
    payload = json.loads(lines[-1])
    assert payload["states"] == 4 and 0.0 <= payload["visible_agreement"] <= 1.0
    assert lines[-2].startswith("| y m |") and "v_V agreement" in result.stdout


def test_no_state_seen_by_both_gives_no_error_statistics():
    image = {"visible": np.array([True, False]), "confidence": np.zeros(2), "angle": np.zeros(2), "y": np.zeros(2)}
    truth = {**image, "visible": np.array([False, False])}
    result = validate_vision.compare(image, truth)
    assert result["both_visible"] == 0 and result["visible_false_positive"] == 0.5
    assert result["confidence"] is None and result["angle"] is None and result["y"] is None
