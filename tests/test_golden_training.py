"""The golden training run: a short dlo-train run whose eval.csv is committed must stay bit-identical.

A study must not drift with the code under it: a refactor of the env, the task, the simulator, the
observation or SAC must not change one number a run produces. This test trains the same short run
(All, seed 7, 600 env steps, 300 gradient updates, evaluations every 200 steps with and without T)
and compares every column of its eval.csv with tests/golden/All_seed7_600/eval.csv, exactly (only the
wall-clock column differs between runs). It was generated at the commit that added it and checked
equal to a run of the code before the task_rules switch (60560be).

When a change is MEANT to change training (a new default, a physics fix), regenerate it and say so
in the commit message, with the study runs it invalidates:
    dlo-train --modalities All --seed 7 --steps 600 --out /tmp/golden --no-progress $(cat tests/golden/ARGS)
    cp /tmp/golden/eval.csv /tmp/golden/config.yaml tests/golden/All_seed7_600/
"""
import csv
import os
import pathlib
import subprocess
import sys

import yaml

ROOT = pathlib.Path(__file__).resolve().parents[1]
GOLDEN = ROOT / "tests" / "golden" / "All_seed7_600"
ARGS = (ROOT / "tests" / "golden" / "ARGS").read_text().split()
VOLATILE = {"wall_time_s"}


def rows(path):
    with open(path, newline="") as f:
        return [{k: v for k, v in row.items() if k not in VOLATILE} for row in csv.DictReader(f)]


def test_the_golden_training_run_is_reproduced_bit_for_bit(tmp_path):
    out = tmp_path / "run"
    result = subprocess.run([sys.executable, "-m", "dlo_policy.train", "--modalities", "All", "--seed", "7",
                             "--steps", "600", "--out", str(out), "--no-progress", *ARGS],
                            capture_output=True, text=True, timeout=900, env=os.environ.copy())
    assert result.returncode == 0, result.stderr[-3000:]
    config, golden = (yaml.safe_load((d / "config.yaml").read_text()) for d in (out, GOLDEN))
    for section, values in golden.items():  # every setting of the golden run is unchanged (new ones may be added)
        assert config[section] == values if not isinstance(values, dict) else \
            {k: config[section].get(k) for k in values} == values, section
    expected, got = rows(GOLDEN / "eval.csv"), rows(out / "eval.csv")
    assert len(got) == len(expected) == 8
    for want, have in zip(expected, got):
        assert have == want, f"step {want['step']} without '{want['tested_without']}': " + ", ".join(
            f"{k} {want[k]} -> {have[k]}" for k in want if have.get(k) != want[k])
