"""benchmarks/run.py, the one runner of the benchmarks: --help, --list, one-line usage errors, one
JSON line per benchmark on stdout (its progress on stderr), a failed benchmark reported as such, and
the smallest real benchmark with its quickest settings. No assertion on a measured figure."""

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RUN = ROOT / "benchmarks" / "run.py"
_spec = importlib.util.spec_from_file_location("benchmarks_run", RUN)
runner = importlib.util.module_from_spec(_spec)
sys.modules[_spec.name] = runner  # its dataclasses look their module up there
_spec.loader.exec_module(runner)


def run(*args, env=None, timeout=60):
    return subprocess.run(
        [sys.executable, str(RUN), *args], capture_output=True, text=True, timeout=timeout, env=env or os.environ.copy(), cwd=ROOT
    )


def test_help_and_list_name_every_benchmark_and_its_script():
    help_ = run("--help")
    assert help_.returncode == 0 and "--list" in help_.stdout and "--quick" in help_.stdout
    listed = run("--list")
    assert listed.returncode == 0 and listed.stderr == ""
    names = [line.split()[0] for line in listed.stdout.splitlines() if not line.startswith(" ")]
    assert names == list(runner.BENCHMARKS)
    for bench in runner.BENCHMARKS.values():
        assert (ROOT / "benchmarks" / bench.script).is_file() and f"benchmarks/{bench.script}" in listed.stdout
    assert {"sim", "sac"} <= set(runner.BENCHMARKS)  # the two with a peer: MuJoCo and Stable-Baselines3
    assert "MuJoCo" in runner.BENCHMARKS["sim"].against and "Stable-Baselines3" in runner.BENCHMARKS["sac"].against


@pytest.mark.parametrize(
    "args, message",
    [
        (["nosuch"], "no benchmark 'nosuch'"),
        (["sim", "env", "--", "--seconds", "1"], "options after -- go to one benchmark"),
    ],
)
def test_usage_errors_are_one_line_and_exit_2(args, message):
    result = run(*args)
    assert result.returncode == 2 and result.stdout == "", result.stdout
    assert len(result.stderr.strip().splitlines()) == 1 and message in result.stderr, result.stderr


def test_without_the_environment_it_says_what_to_source():
    env = {k: v for k, v in os.environ.items() if k != "DLO_ROOT"}
    result = run("env", env=env)
    assert result.returncode == 2 and result.stderr.strip() == "benchmarks/run.py: error: source scripts/env.sh first"


def test_names_may_be_given_as_the_script_names():
    assert runner.resolve("bench_sim.py") == runner.resolve("bench_sim") == runner.resolve("sim") == "sim"


def test_one_record_per_benchmark_its_json_last_and_failures_named(tmp_path):
    good = tmp_path / "bench_good.py"
    good.write_text("import sys\nprint('warming up')\nprint('progress', file=sys.stderr)\nprint('{\"rate\": 3}')\n")
    log = tmp_path / "log.txt"
    with log.open("w") as stream:
        record = runner.run_benchmark("good", good, ["--x"], log=stream)
    assert record["result"] == {"rate": 3} and record["returncode"] == 0 and record["args"] == ["--x"]
    assert "error" not in record
    assert set(log.read_text().splitlines()) == {"[good] warming up", "[good] progress"}  # the JSON is not progress

    silent = tmp_path / "bench_silent.py"
    silent.write_text("print('done, but no figures')\n")
    with open(os.devnull, "w") as devnull:
        record = runner.run_benchmark("silent", silent, [], log=devnull)
    assert record["error"] == "no JSON line last: done, but no figures" and "result" not in record

    broken = tmp_path / "bench_broken.py"
    broken.write_text("import sys\nprint('{\"partial\": 1}')\nsys.exit('bench_broken: error: no GPU')\n")
    with open(os.devnull, "w") as devnull:
        record = runner.run_benchmark("broken", broken, [], log=devnull)
    assert record["returncode"] == 1 and record["error"] == "exit 1: bench_broken: error: no GPU"


def test_the_smallest_benchmark_with_its_quickest_settings():
    result = run("--quick", "env", timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    lines = result.stdout.strip().splitlines()
    assert len(lines) == 1  # one JSON line per benchmark, nothing else on stdout
    record = json.loads(lines[0])
    assert record["benchmark"] == "env" and record["args"] == list(runner.BENCHMARKS["env"].quick)
    assert set(record["result"]) >= {"env_steps_per_s", "bare_steps_per_s", "obs_pipeline_overhead"}
    assert "[env] N=  1: full" in result.stderr  # its progress line, on stderr
