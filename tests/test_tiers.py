"""The root conftest.py. Its test tiers stay true (tests/README.md#running-the-tests): the markers
are registered, every listed file or test still exists, every fixture the graph rule names is still
defined, and the markers are put on tests also when only ``ros_ws/src`` is collected. A pytest
stopped by SIGTERM tears its fixtures down (no process a test started outlives it)."""

from __future__ import annotations

import ast
import configparser
import importlib.util
import os
import pathlib
import signal
import subprocess
import sys
import time

import pytest
from harness import exited

ROOT = pathlib.Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("dlo_test_tiers", ROOT / "conftest.py")
tiers = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(tiers)


def defined(path: pathlib.Path, decorated_with: str | None = None) -> set[str]:
    """Names of the functions a test file defines (at any depth; only fixtures with ``decorated_with``)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            if decorated_with is None or any(decorated_with in ast.unparse(d) for d in node.decorator_list):
                names.add(node.name)
    return names


def test_the_markers_are_registered():
    ini = configparser.ConfigParser()
    ini.read(ROOT / "pytest.ini")
    markers = {line.split(":")[0].strip() for line in ini["pytest"]["markers"].splitlines() if line.strip()}
    assert markers >= {"graph", "slow"}


def test_every_listed_file_and_test_exists():
    for entry in tiers.GRAPH + tiers.SLOW:
        path, _, test = entry.partition("::")
        assert (ROOT / path).is_file(), f"conftest.py lists {entry}: no such file"
        assert not test or test in defined(ROOT / path), f"conftest.py lists {entry}: no such test"


def test_every_graph_fixture_is_defined():
    fixtures = set()
    for path in [*ROOT.glob("tests/**/*.py"), *ROOT.glob("ros_ws/src/*/test/**/*.py")]:
        fixtures |= defined(path, decorated_with="fixture")
    assert tiers.GRAPH_FIXTURES <= fixtures, tiers.GRAPH_FIXTURES - fixtures


def test_listed_matches_files_tests_and_parametrizations():
    entries = ("a/test_x.py", "a/test_y.py::test_one")
    assert tiers.listed("a/test_x.py::test_any[p1]", entries)
    assert tiers.listed("a/test_y.py::test_one", entries)
    assert tiers.listed("a/test_y.py::test_one[p-2]", entries)
    assert not tiers.listed("a/test_y.py::test_one_more", entries)
    assert not tiers.listed("a/test_y.py::test_two", entries)


def test_markers_are_put_on_tests_when_only_ros_ws_is_collected():
    """By fixture (``procs``) and by the list; the unit tests of the same file stay unmarked."""
    module = "ros_ws/src/dlo_bag/test/test_playback.py"
    collected = subprocess.run(
        [sys.executable, "-m", "pytest", "--collect-only", "-q", "-m", "graph", module],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert collected.returncode == 0, collected.stdout + collected.stderr
    graph = {line.split("::")[1].split("[")[0] for line in collected.stdout.splitlines() if "::" in line}
    with_procs = {
        node.name
        for node in ast.walk(ast.parse((ROOT / module).read_text()))
        if isinstance(node, ast.FunctionDef) and node.name.startswith("test_") and "procs" in [a.arg for a in node.args.args]
    }
    assert "test_playback_republishes_the_same_messages" in with_procs and "test_pacer_keeps_relative_timing" not in (with_procs)
    assert graph == with_procs, collected.stdout


def inner_pytest(tmp_path, workers, **env_vars) -> subprocess.Popen:
    """pytest on ``tmp_path/test_inner.py`` with the root conftest (its SIGTERM handling), ``env_vars`` set."""
    path = os.pathsep.join([str(ROOT), str(ROOT / "tests" / "support"), os.environ.get("PYTHONPATH", "")])  # + the harness
    env = dict(os.environ, **env_vars, PYTHONPATH=path)
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "pytest",
            "-q",
            "-p",
            "conftest",
            "-p",
            "no:cacheprovider",
            "--rootdir",
            str(tmp_path),
            "-c",
            os.devnull,
            *workers,
            str(tmp_path / "test_inner.py"),
        ],
        cwd=tmp_path,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def wait_for_file(path, run: subprocess.Popen):
    """Until the inner test writes ``path`` (a starved xdist worker takes minutes to start); fails if it never does."""
    deadline = time.monotonic() + 600
    while not path.exists() and time.monotonic() < deadline and run.poll() is None:
        time.sleep(0.1)
    if not path.exists():
        run.kill()
        pytest.fail(f"the inner test never wrote {path.name}:\n" + run.communicate()[0][-2000:])


@pytest.mark.parametrize("workers", [[], ["-n", "1"]], ids=["serial", "xdist"])  # scripts/test.sh: xdist workers
def test_sigterm_to_pytest_runs_fixture_teardown_so_no_child_outlives_it(workers, tmp_path):
    (tmp_path / "test_inner.py").write_text(
        "import os, pathlib, subprocess, time\n"
        "import pytest\n\n"
        "@pytest.fixture\n"
        "def child():\n"
        "    p = subprocess.Popen(['sleep', '600'])\n"
        "    pathlib.Path(os.environ['CHILD_PID']).write_text(str(p.pid))\n"
        "    yield p\n"
        "    p.terminate()\n"
        "    p.wait()\n\n"
        "def test_waits(child):\n"
        "    time.sleep(600)\n"
    )
    pid_file = tmp_path / "child.pid"
    pytest_run = inner_pytest(tmp_path, workers, CHILD_PID=str(pid_file))
    try:
        wait_for_file(pid_file, pytest_run)
        child = int(pid_file.read_text())
        pytest_run.send_signal(signal.SIGTERM)
        out = pytest_run.communicate(timeout=600)[0]  # no deadline in pytest's shutdown: a starved one takes minutes
        assert pytest_run.returncode == 2, out[-2000:]  # interrupted, as on Ctrl-C
        assert exited(child), f"the fixture's child {child} outlived pytest:\n{out[-2000:]}"
    finally:
        if pytest_run.poll() is None:
            pytest_run.kill()


def test_a_second_sigterm_stops_an_xdist_pytest_whose_worker_ignores_the_first(tmp_path):
    """The controller passes the first SIGTERM on to its workers and waits for them; the second one
    interrupts the controller itself (and execnet then interrupts the worker), so a worker that ignores
    SIGTERM cannot keep pytest running."""
    ready = tmp_path / "ready"
    (tmp_path / "test_inner.py").write_text(
        "import os, pathlib, signal, time\n\n"
        "def test_ignores_sigterm():\n"
        "    signal.signal(signal.SIGTERM, signal.SIG_IGN)\n"
        "    pathlib.Path(os.environ['READY']).write_text('')\n"
        "    time.sleep(600)\n"
    )
    pytest_run = inner_pytest(tmp_path, ["-n", "1"], READY=str(ready))
    try:
        wait_for_file(ready, pytest_run)
        pytest_run.send_signal(signal.SIGTERM)
        with pytest.raises(subprocess.TimeoutExpired):  # passed on to the worker, which ignores it
            pytest_run.wait(timeout=3)
        pytest_run.send_signal(signal.SIGTERM)
        out = pytest_run.communicate(timeout=300)[0]
        assert pytest_run.returncode == 2, out[-2000:]
    finally:
        if pytest_run.poll() is None:
            pytest_run.kill()


@pytest.mark.parametrize("workers", [[], ["-n", "1"]], ids=["serial", "xdist"])
def test_fixtures_are_torn_down_before_the_shared_memory_clean_up_of_the_session(workers, tmp_path):
    """The session's clean-up of Fast DDS files scans every process on the machine (slow on a loaded one):
    it runs after the fixtures' teardown, so that a SIGTERM-ed xdist worker, which execnet kills 5 s
    after the interrupt, has already stopped what its tests started (and their files are then free)."""
    log = tmp_path / "order.log"
    (tmp_path / "test_inner.py").write_text(
        "import os\n"
        "import pytest\n"
        "import harness\n\n"
        "def note(what):\n"
        "    with open(os.environ['ORDER_LOG'], 'a') as f:\n"
        "        f.write(what + '\\n')\n\n"
        "harness.remove_orphaned_dds_shm = lambda before: note('clean-up')\n\n"
        "@pytest.fixture(scope='session')\n"
        "def resource():\n"
        "    yield\n"
        "    note('teardown')\n\n"
        "def test_interrupted(resource):\n"
        "    raise KeyboardInterrupt  # as the SIGINT execnet sends an xdist worker, or Ctrl-C\n"
    )
    run = inner_pytest(tmp_path, workers, ORDER_LOG=str(log))
    try:
        out = run.communicate(timeout=300)[0]
    finally:
        if run.poll() is None:
            run.kill()
    order = log.read_text().split() if log.exists() else []
    assert order[:2] == ["teardown", "clean-up"], (order, out[-2000:])
