"""A file that is no policy, given as a checkpoint, and a training run too short to learn (issue 20).

- policy_node ``-p checkpoint:=FILE`` and ``dlo-evaluate --checkpoint FILE`` with a text file: one
  line ``not a dlo-vitac policy file: FILE (why)``, exit 2, no traceback (the real executables);
- the short reason for each kind of foreign file (``dlo_policy.sac.read_checkpoint``);
- ``dlo-train`` with ``train.total_steps <= sac.learning_starts`` warns in one line at the start that
  no gradient update will happen, and says what to pass; a run that does update gets no warning.
"""

import functools
import json
import os
import subprocess
from pathlib import Path

import pytest
import torch
from dlo_policy.sac import CHECKPOINT_FORMAT, CheckpointError, read_checkpoint
from harness import reserve_domains

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[3]
ROS2RUN = str(ROOT / "scripts" / "ros2run")
INSTALL_BIN = ROOT / "ros_ws" / "install" / "dlo_policy" / "lib" / "dlo_policy"


@functools.lru_cache(maxsize=None)
def module_domain() -> int:
    """A ROS domain reserved for this module's node processes (tests/support/harness.py), held until pytest ends."""
    return reserve_domains()


def environment(**extra) -> dict:
    """The console scripts on PATH, a ROS domain of this test run's own, the test helpers importable."""
    return {
        **os.environ,
        "PATH": f"{INSTALL_BIN}:{os.environ['PATH']}",
        "ROS_DOMAIN_ID": str(module_domain()),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
        "PYTHONPATH": f"{HERE}:{os.environ.get('PYTHONPATH', '')}",
        **extra,
    }


def one_line(result: subprocess.CompletedProcess) -> str:
    assert "Traceback" not in result.stdout + result.stderr, result.stderr
    assert result.returncode == 2, result.stdout + result.stderr
    assert result.stdout == "" and len(result.stderr.strip().splitlines()) == 1, result.stderr
    return result.stderr.strip()


@pytest.fixture
def text_file(tmp_path):
    path = tmp_path / "hostname"
    path.write_text("build-machine-7\n")
    (tmp_path / "config.yaml").write_text("modalities: All\n")  # a run's config next to it: only the file is wrong
    return path


def test_policy_node_refuses_a_text_file_as_checkpoint(text_file, tmp_path):
    result = subprocess.run(
        [ROS2RUN, "dlo_policy", "policy_node", "--ros-args", "-p", f"checkpoint:={text_file}"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
        env=environment(),
    )
    assert one_line(result) == (
        f"[policy_node] bad parameter: parameter 'checkpoint': not a dlo-vitac policy file: "
        f"{text_file} (a text file, not a torch checkpoint)"
    )


def test_dlo_evaluate_refuses_a_text_file_as_checkpoint(text_file, tmp_path):
    result = subprocess.run(
        ["dlo-evaluate", "--checkpoint", str(text_file)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
        env=environment(),
    )
    assert one_line(result) == (
        f"dlo-evaluate: error: not a dlo-vitac policy file: {text_file} (a text file, not a torch checkpoint)"
    )


@pytest.mark.parametrize(
    "content,reason",
    [
        (b"", "empty file"),
        ("cable: 0.2 m\n\u00e9t\u00e9\n".encode(), "a text file, not a torch checkpoint"),
        (b"PK\x03\x04 not a zip", "a zip archive torch cannot read: damaged or not a torch file"),
        (b"\x00\x01\x02\xff" * 64, "binary data torch cannot load (UnpicklingError)"),
        ({"weights": torch.zeros(2)}, f"a torch file without the {CHECKPOINT_FORMAT} format tag"),
        ([1, 2, 3], f"a torch file without the {CHECKPOINT_FORMAT} format tag"),
        ({"format": "dlo_policy.sac/0"}, f"format 'dlo_policy.sac/0', expected '{CHECKPOINT_FORMAT}'"),
    ],
    ids=["empty", "text", "zip", "binary", "no-tag", "a-list", "other-format"],
)
def test_the_short_reason_of_each_foreign_file(content, reason, tmp_path):
    path = tmp_path / "policy.pt"
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        torch.save(content, path)
    with pytest.raises(CheckpointError) as raised:
        read_checkpoint(path)
    assert str(raised.value) == f"not a dlo-vitac policy file: {path} ({reason})"


TINY = [
    "env_module=sac_reach_env",
    "sac.hidden_sizes=[16,16]",
    "sac.batch_size=8",
    "sac.buffer_size=500",
    "train.eval_every=1000",
    "train.eval_episodes=1",
    "train.test_episodes=1",
    "train.checkpoint_every=1000",
    "train.num_threads=1",
]


@pytest.mark.parametrize(
    "learning_starts,warned", [(None, True), (60, True), (20, False)], ids=["default-1000", "equal", "below"]
)
def test_dlo_train_warns_when_no_update_will_happen(learning_starts, warned, tmp_path):
    overrides = TINY + ([f"sac.learning_starts={learning_starts}"] if learning_starts is not None else [])
    result = subprocess.run(
        ["dlo-train", "--out", str(tmp_path / "run"), "--steps", "60", "--no-progress", *overrides],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
        env=environment(),
    )
    assert result.returncode == 0 and "Traceback" not in result.stderr, result.stderr
    summary = json.loads(result.stdout.strip().splitlines()[-1])
    warnings = [line for line in result.stderr.splitlines() if "warning" in line]
    starts = 1000 if learning_starts is None else learning_starts
    if warned:
        assert summary["updates"] == 0
        assert warnings == [
            f"dlo-train: warning: train.total_steps 60 <= sac.learning_starts {starts}: no gradient "
            "update will happen (random actions only); pass e.g. sac.learning_starts=20 or --steps "
            f"above {starts}"
        ]
        assert result.stderr.splitlines()[0] == warnings[0]  # at the start, before the run
    else:
        assert summary["updates"] == 60 - starts and warnings == []


@pytest.mark.parametrize("how", ["config file", "override", "control character"])
def test_dlo_train_with_broken_yaml_is_one_line_naming_where(how, tmp_path):
    """A config file or a key=value override that is not valid YAML: one line naming it and where it
    breaks (line, column), exit 2, no traceback and no run directory (it was a yaml.ParserError trace).
    Also a character YAML does not allow (a stray control character: PyYAML's reader error has no line,
    and its message ran over two lines)."""
    bad = tmp_path / "mine.yaml"
    bad.write_text("seed: 3\nsac: {batch_size: \x07}\n" if how == "control character" else "seed: 3\nsac: {batch_size: 64\n")
    given = ["sac.hidden_sizes=[256, 256"] if how == "override" else ["--config", str(bad)]
    result = subprocess.run(
        ["dlo-train", "--out", str(tmp_path / "run"), *given],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
        env=environment(),
    )
    said = one_line(result)
    expected = {
        "config file": f"dlo-train: error: {bad}: not valid YAML (line 3, column 1): ",
        "override": "dlo-train: error: override 'sac.hidden_sizes=[256, 256': not valid YAML (line 1, ",
        "control character": f"dlo-train: error: {bad}: not valid YAML (line 2, column 19): unacceptable "
        "character #x0007: special characters are not allowed",
    }[how]
    assert said.startswith(expected), said
    assert not (tmp_path / "run").exists()
