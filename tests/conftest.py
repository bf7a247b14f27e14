"""Workspace-level fixtures: an isolated ROS 2 domain per test session, and graph launches that
never outlive their test."""

import os
import signal
import subprocess
import time

import pytest


@pytest.fixture(scope="session", autouse=True)
def isolated_ros_domain():
    """Give this test session (each pytest-xdist worker) a DDS domain of its own, reserved so that no other
    test process, launched graph or participant on this machine uses it (harness.reserve_domains),
    also when the shell sets ROS_DOMAIN_ID (a user's graph runs there)."""
    from harness import reserve_domains

    os.environ["ROS_DOMAIN_ID"] = str(reserve_domains())
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    yield os.environ["ROS_DOMAIN_ID"]


def kill_process_group(pid: int, grace: float = 30.0) -> None:
    """SIGINT the process group ``pid`` leads (a launcher stops its graph and closes its bag), then
    SIGKILL whatever is left of it after ``grace`` seconds. Nothing of the group survives this."""
    try:
        os.killpg(pid, signal.SIGINT)
    except ProcessLookupError:
        return
    deadline = time.monotonic() + grace
    while time.monotonic() < deadline:
        try:  # a leader that is our own unreaped child stays a zombie (still "in" its group) until reaped
            os.waitpid(pid, os.WNOHANG)
        except ChildProcessError:
            pass
        try:
            os.killpg(pid, 0)
        except ProcessLookupError:
            return
        time.sleep(0.2)
    try:
        os.killpg(pid, signal.SIGKILL)
    except ProcessLookupError:
        pass


def run_in_own_group(cmd, *, timeout: float, **popen) -> subprocess.CompletedProcess:
    """``subprocess.run`` for a command that starts other processes (scripts/launch_graph.sh): it
    runs in its own process group; on timeout the whole group is stopped (SIGINT, then SIGKILL), not
    just the script, and the timeout is raised; after it returns, no process of the group is left."""
    popen.setdefault("preexec_fn", lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # SIGINT trappable
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True, **popen)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        kill_process_group(proc.pid)
        out, err = proc.communicate()
        raise subprocess.TimeoutExpired(cmd, timeout, out, err) from None
    finally:
        kill_process_group(proc.pid, grace=10.0)  # nodes the launcher may have left behind
    return subprocess.CompletedProcess(cmd, proc.returncode, out, err)


@pytest.fixture(scope="session")
def launch_in_own_group():
    """The ``run_in_own_group`` function, for tests and module fixtures that launch graphs."""
    return run_in_own_group


@pytest.fixture
def own_groups():
    """Register the pid of a child started with ``start_new_session=True``: at teardown its whole
    process group is stopped (SIGINT, SIGKILL after 30 s), whatever the test did or failed to do."""
    pids = []
    yield pids.append
    for pid in pids:
        kill_process_group(pid)
