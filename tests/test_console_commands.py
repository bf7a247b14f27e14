"""Every console command of the project (the ``dlo-*`` console_scripts of each package's setup.py; the nodes
aside): stdout carries what the command promises, so it is piped, and a reader that stops early (``| head``)
ends it quietly (dlo_common.console.console_main: exit 141 like coreutils' commands, nothing on stderr), not
with a BrokenPipeError traceback or Python's "Exception ignored ... BrokenPipeError" and exit 120."""

import importlib
import os
import pathlib
import re
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
ENTRY = re.compile(r'"(dlo-[\w-]+)\s*=\s*([\w.]+):(\w+)"')
# commands whose main is not wrapped yet, each with why (another change owns its file)
NOT_YET: dict[str, str] = {}


def console_commands() -> list[tuple[str, str, str]]:
    found = []
    for setup in sorted(ROOT.glob("ros_ws/src/*/setup.py")):
        found += ENTRY.findall(setup.read_text())
    return sorted(found)


def test_the_commands_are_found():
    names = [name for name, _, _ in console_commands()]
    assert {"dlo-train", "dlo-evaluate", "dlo-experiments", "dlo-report", "dlo-bag-info", "dlo-analyze"} <= set(names)


@pytest.mark.parametrize(
    "name, module, function",
    [
        pytest.param(*entry, marks=pytest.mark.xfail(reason=NOT_YET[entry[0]], strict=False) if entry[0] in NOT_YET else ())
        for entry in console_commands()
    ],
)
def test_every_command_ends_quietly_when_its_reader_goes_away(name, module, function):
    """Its main is dlo_common.console.console_main's wrapper (what that does: dlo_common/test/test_console.py;
    real commands into a closed pipe: test_bag_info.py, test_train_output.py)."""
    main = getattr(importlib.import_module(module), function)
    assert main.__code__.co_filename.endswith(os.path.join("dlo_common", "console.py")), f"{name}: {module}.{function}"
    assert main.__wrapped__.__module__ == module


@pytest.mark.parametrize("variables", [{"PYTHONUNBUFFERED": "1"}, {}])
def test_a_printed_summary_into_a_pipe_whose_reader_has_gone_ends_quietly(variables, tmp_path):
    """`dlo-report RESULTS | head -0`: at its print (unbuffered) or at the end (buffered), exit 141, nothing on
    stderr (before: a BrokenPipeError traceback, or "Exception ignored ... BrokenPipeError" and exit 120)."""
    read, write = os.pipe()
    os.close(read)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"} | variables
    code = "import sys\nfrom dlo_policy.report import main\nsys.exit(main())"
    try:
        result = subprocess.run(
            [
                sys.executable,
                "-c",
                code,
                "--compare",
                f"a={ROOT / 'results' / 'sag' / 'running'}",
                "--out",
                str(tmp_path / "report"),
            ],
            stdout=write,
            stderr=subprocess.PIPE,
            text=True,
            timeout=300,
            env=env,
        )
    finally:
        os.close(write)
    assert (result.returncode, result.stderr) == (141, ""), result.stderr[-2000:]
