"""The test harness: node processes on an isolated ROS domain, for the tests of every package and of tests/.

Test code only (no package ships it): pytest finds it through ``pythonpath`` in pytest.ini (``import harness``);
a script outside pytest puts ``tests/support`` on ``sys.path`` first. The tests of dlo_bag, dlo_viz and
dlo_driver_kit define their fixtures over these in a few lines:

- :class:`Proc`: a child process whose merged stdout/stderr is collected line by line (``wait_line``).
- :data:`REPO`, :data:`ROS2RUN`: the repository (``DLO_ROOT``, set by ``scripts/env.sh``) and its
  ``scripts/ros2run``.
- :func:`reserve_domains`: ROS domains no other test process, launched graph or participant on this
  machine uses (``dlo_common.domains``: busy ports, the locks shared with the launcher), held until this
  process ends (or :func:`release_domains`): tests in parallel (pytest-xdist workers, two suites, a user's
  graph) never share a domain.
- :func:`isolated_env`: a copy of the environment on a reserved ROS domain with localhost discovery;
  :func:`package_test_env` the same, skipping the test when the package's executable is not built.
- :class:`Procs`: starts processes and stops every one still running at the end (SIGINT, wait; one that does
  not stop fails with its stacks).
- :func:`stop_or_explain`: SIGINT a node and wait for it; one that hangs fails with its C and Python stacks
  (:func:`hang_report`); :func:`stop_all_or_explain` the same for several at once (Procs uses it).
- :func:`remove_orphaned_dds_shm`: the Fast DDS shared-memory files that killed participants left in
  /dev/shm since a snapshot, removed (the root conftest.py does it at the end of every test session).
- :func:`made_up_force_topic`: an observation topic the registry does not have, for the tests that add a
  modality to ``dlo_common.topics.TOPICS`` (plots, videos, the Foxglove layout).
- :class:`LogLines`: a node's logger stand-in for in-process tests (``monkeypatch.setattr(node, "get_logger",
  lambda: log)``): every line with its level, in order.

Standard library and dlo_common only: no rclpy; pytest is imported inside :func:`package_test_env` only.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import queue
import random
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Iterable
from pathlib import Path

from dlo_common.domains import DOMAIN_LOCK_DIR, domain_busy

# DLO_ROOT is set by scripts/env.sh; without it, the source tree this file lies in (tests/support/).
REPO = Path(os.environ.get("DLO_ROOT") or Path(__file__).resolve().parents[2])
ROS2RUN = REPO / "scripts" / "ros2run"


class LogLines:
    """A node's logger stand-in: ``lines`` holds every ``(level, text)`` logged, in order (throttling and the other
    keyword arguments are the real logger's business); ``of(level)`` the texts of one level."""

    def __init__(self) -> None:
        self.lines: list[tuple[str, str]] = []

    def __getattr__(self, level: str):
        if level.startswith("_"):
            raise AttributeError(level)
        return lambda text, **_: self.lines.append((level, text))

    def of(self, level: str) -> list[str]:
        return [text for lvl, text in self.lines if lvl == level]


class Proc:
    """A child process whose merged stdout/stderr is collected line by line. It starts with SIGINT's default
    action even when the tests run with SIGINT ignored (as a background job), so that SIGINT stops it."""

    def __init__(self, cmd: list[str], env: dict[str, str], name: str, **popen) -> None:
        self.name = name
        self.cmd = cmd
        given = popen.pop("preexec_fn", None)

        def preexec() -> None:
            signal.signal(signal.SIGINT, signal.SIG_DFL)
            if given is not None:
                given()

        self.p = subprocess.Popen(
            cmd,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            bufsize=1,
            start_new_session=True,
            preexec_fn=preexec,
            **popen,
        )
        self.lines: list[str] = []
        self._q: queue.Queue[str | None] = queue.Queue()
        self._t = threading.Thread(target=self._pump, daemon=True)
        self._t.start()

    def _pump(self) -> None:
        assert self.p.stdout is not None
        for line in self.p.stdout:
            self.lines.append(line.rstrip("\n"))
            self._q.put(line.rstrip("\n"))
        self._q.put(None)

    def output(self) -> str:
        return "\n".join(self.lines)

    def output_when_ended(self) -> str:
        """:meth:`output` once the process has ended and its last lines are read."""
        self.p.wait()
        self._t.join(timeout=10)
        return self.output()

    def wait_line(self, prefix: str, timeout: float = 60.0) -> str:
        """The first new line containing ``prefix``; fails if the process ends first."""
        end = time.monotonic() + timeout
        while True:
            left = end - time.monotonic()
            if left <= 0:
                raise AssertionError(f"{self.name}: no '{prefix}' within {timeout} s:\n" + self.output())
            try:
                line = self._q.get(timeout=left)
            except queue.Empty:
                continue
            if line is None:
                raise AssertionError(f"{self.name} exited ({self.p.wait()}) before '{prefix}':\n" + self.output())
            if prefix in line:
                return line

    def signal(self, sig: int) -> None:
        self.p.send_signal(sig)

    def wait(self, timeout: float = 30.0) -> int:
        rc = self.p.wait(timeout=timeout)
        self._t.join(timeout=5)
        return rc

    def kill(self) -> None:
        if self.p.poll() is None:
            self.p.kill()
            self.p.wait(timeout=10)


def exited(pid: int) -> bool:
    """True when process ``pid`` has ended: gone, or a zombie its parent has not reaped yet."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[-1].split()[0] == "Z"  # after "pid (comm)": comm may hold spaces
    except (FileNotFoundError, ProcessLookupError):
        return True


def stop_or_explain(proc: subprocess.Popen, name: str, timeout: float = 30.0, log: Path | None = None) -> int:
    """SIGINT ``proc`` (a node) and wait up to ``timeout`` s for it to end; its return code. A node that does not
    end is a failure that must say where it hangs (:func:`hang_report`, its output read from ``log``): an
    AssertionError with its C and Python stacks; the node is killed."""
    stop_all_or_explain(
        [(proc, name, lambda: log.read_text(errors="replace") if log is not None and log.exists() else "(no log)")], timeout
    )
    return proc.returncode


def stop_all_or_explain(procs: Iterable[tuple[subprocess.Popen, str, Callable[[], str]]], timeout: float) -> None:
    """SIGINT every process of ``procs`` (process, name, its output) still running and wait up to ``timeout`` s
    for each; those that did not end fail together in one AssertionError with their stacks (:func:`hang_report`)."""
    running = [entry for entry in procs if entry[0].poll() is None]
    for proc, _, _ in running:
        proc.send_signal(signal.SIGINT)
    hung = []
    for entry in running:
        try:
            entry[0].wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            hung.append(entry)
    reports = [hang_report(proc, name, timeout, output) for proc, name, output in hung]
    if reports:
        raise AssertionError("\n\n".join(reports))


def hang_report(proc: subprocess.Popen, name: str, timeout: float, output) -> str:
    """Where a node that did not end within ``timeout`` s of SIGINT hangs: the C stacks of its threads (gdb, when
    installed), then a SIGABRT, which makes a node started with ``PYTHONFAULTHANDLER=1`` write its threads' Python
    stacks to its output (``output()``, read after it ended); the node is killed if SIGABRT does not end it."""
    try:
        gdb = subprocess.run(
            ["gdb", "-p", str(proc.pid), "-batch", "-ex", "thread apply all bt"], capture_output=True, text=True, timeout=60
        ).stdout
    except (OSError, subprocess.TimeoutExpired) as error:
        gdb = f"(no C stacks: {error})"
    proc.send_signal(signal.SIGABRT)
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    return (
        f"{name} did not stop within {timeout:g} s of SIGINT\n--- its output, Python stacks at the end ---\n"
        f"{output()[-20000:]}\n--- its C stacks ---\n{gdb[-20000:]}"
    )


# The domains of tests: 100..232 (232: the highest id Fast DDS maps to ports on Linux); scripts/launch_graph.sh
# picks its own in 10..99. Both lock a domain in DOMAIN_LOCK_DIR (flock on N.lock, dlo_common.domains) while they use it.
TEST_DOMAINS = (100, 232)
_held_domains: dict[int, int] = {}  # domain -> the fd of its lock file (this process holds the flock)


def _lock_domain(domain: int) -> bool:
    DOMAIN_LOCK_DIR.mkdir(parents=True, exist_ok=True)
    fd = os.open(DOMAIN_LOCK_DIR / f"{domain}.lock", os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        return False
    _held_domains[domain] = fd
    return True


def release_domains(first: int, span: int = 1) -> None:
    """Give back domains ``first .. first + span - 1`` that :func:`reserve_domains` gave this process."""
    for domain in range(first, first + span):
        fd = _held_domains.pop(domain, None)
        if fd is not None:
            os.close(fd)  # closing the file releases its flock


def reserve_domains(span: int = 1, first: int = TEST_DOMAINS[0], last: int = TEST_DOMAINS[1]) -> int:
    """The first of ``span`` consecutive ROS domains in ``first .. last`` that nothing else uses: locked by no
    other process (tests, launch_graph.sh) and with no participant on their ports. They stay locked by this
    process until it ends or :func:`release_domains`. The search starts at a random place (per process),
    so that processes started together rarely race for the same lock. RuntimeError when none is free."""
    count = last - first - span + 2
    start = random.Random(os.getpid() ^ int(time.monotonic_ns())).randrange(count)
    for i in range(count):
        base = first + (start + i) % count
        taken: list[int] = []
        for domain in range(base, base + span):
            if domain in _held_domains or domain_busy(domain) or not _lock_domain(domain):
                break
            taken.append(domain)
        if len(taken) == span:
            return base
        for domain in taken:
            release_domains(domain)
    raise RuntimeError(f"no {span} free ROS domain(s) in {first}..{last} on this machine")


@contextlib.contextmanager
def reserved_domain(span: int = 1):
    """``with reserved_domain() as domain:`` :func:`reserve_domains` for the block only."""
    domain = reserve_domains(span)
    try:
        yield domain
    finally:
        release_domains(domain, span)


SHM = Path("/dev/shm")
DDS_SHM_PREFIXES = ("fastrtps_", "sem.fastrtps_")  # Fast DDS's shared-memory segments, port files, semaphores


def dds_shm_entries(shm: Path = SHM) -> set[str]:
    """The names of Fast DDS's shared-memory files in ``shm`` now."""
    try:
        return {p.name for p in shm.iterdir() if p.name.startswith(DDS_SHM_PREFIXES)}
    except OSError:
        return set()


def files_in_use(pids: Iterable[int] | None = None) -> set[str]:
    """Every file the processes ``pids`` (default: every process on this machine) have mapped or open
    (/proc/PID/maps, /proc/PID/fd)."""
    used: set[str] = set()
    procs = Path("/proc").iterdir() if pids is None else (Path(f"/proc/{pid}") for pid in pids)
    for proc in procs:
        if not proc.name.isdigit():
            continue
        with contextlib.suppress(OSError):
            for line in (proc / "maps").read_text().splitlines():
                fields = line.split(None, 5)  # address perms offset device inode [path]
                if len(fields) == 6:
                    used.add(fields[5].removesuffix(" (deleted)").strip())
        with contextlib.suppress(OSError):
            for fd in (proc / "fd").iterdir():
                with contextlib.suppress(OSError):
                    used.add(os.readlink(fd))
    return used


def dds_shm_owner(name: str) -> str:
    """The Fast DDS file whose use keeps ``name`` alive: a port's named mutex (``sem.fastrtps_portN_mutex``)
    belongs to its port (``fastrtps_portN``): Fast DDS maps the mutex only while it opens the port, so a
    running participant's port mutex is mostly mapped by no one. Every other file stands for itself."""
    if name.startswith("sem.fastrtps_port") and name.endswith("_mutex"):
        return name.removeprefix("sem.").removesuffix("_mutex")
    return name


def remove_orphaned_dds_shm(before: set[str], shm: Path = SHM) -> list[str]:
    """Remove the Fast DDS shared-memory files that appeared in ``shm`` since ``before`` (a
    :func:`dds_shm_entries` snapshot) and that no process maps or holds open (a port's mutex: while no
    process uses its port, :func:`dds_shm_owner`): what participants killed with SIGKILL (crash tests)
    leave behind. Files of running participants, and every file that was there before, stay. Returns
    the removed names."""
    new = sorted(dds_shm_entries(shm) - before)
    if not new:
        return []
    used = files_in_use()
    removed = []
    for name in new:
        path = shm / name
        if str(path) not in used and str(shm / dds_shm_owner(name)) not in used:
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
                removed.append(name)
    return removed


def isolated_env(base: dict[str, str] | None = None, domain_id: int | None = None) -> dict[str, str]:
    """A copy of ``base`` (default: ``os.environ``) on ROS domain ``domain_id`` (default: one reserved for
    this process, :func:`reserve_domains`) with localhost-only discovery and unbuffered Python output."""
    env = dict(os.environ if base is None else base)
    env["ROS_DOMAIN_ID"] = str(reserve_domains() if domain_id is None else domain_id)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["PYTHONUNBUFFERED"] = "1"
    env.pop("ROS_LOCALHOST_ONLY", None)
    return env


def package_test_env(package: str, executable: str) -> dict[str, str]:
    """:func:`isolated_env` on a reserved domain for the tests of ``package``; skips the test (pytest.skip)
    when scripts/env.sh is not sourced, scripts/ros2run is missing or ``ros2run <package>`` does not list
    ``executable``."""
    import pytest

    if "DLO_ROOT" not in os.environ:
        pytest.skip("source scripts/env.sh first")
    if not ROS2RUN.exists():
        pytest.skip(f"{ROS2RUN} missing")
    env = isolated_env(domain_id=reserve_domains())
    check = subprocess.run([str(ROS2RUN), package], env=env, capture_output=True, text=True, timeout=60)
    if f"{package} {executable}" not in check.stdout.splitlines():
        pytest.skip(f"{package} is not built (run scripts/setup.sh): " + check.stderr)
    return env


class Procs:
    """Processes started with ``procs(name, cmd, env=None, **popen)`` (a :class:`Proc` in ``env``, default
    the one given here, with ``PYTHONFAULTHANDLER=1``); :meth:`stop_all` (also on leaving a ``with`` block)
    sends SIGINT to every one still running and waits up to ``stop_timeout`` s for each: one that does not
    stop (a node that ignores Ctrl-C) fails the test with its stacks (:func:`hang_report`) and is killed."""

    def __init__(self, env: dict[str, str], stop_timeout: float = 30.0) -> None:
        self.env = env
        self.stop_timeout = stop_timeout
        self.started: list[Proc] = []

    def __call__(self, name: str, cmd: list[str], env: dict[str, str] | None = None, **popen) -> Proc:
        proc = Proc(cmd, {"PYTHONFAULTHANDLER": "1", **(self.env if env is None else env)}, name, **popen)
        self.started.append(proc)
        return proc

    def stop_all(self) -> None:
        stop_all_or_explain([(proc.p, proc.name, proc.output_when_ended) for proc in self.started], self.stop_timeout)
        for proc in self.started:
            proc.wait()  # its last lines read

    def __enter__(self) -> Procs:
        return self

    def __exit__(self, *exc) -> None:
        self.stop_all()


def made_up_force_topic(*series):
    """A made-up observation topic (a wrench on the sim node, ``/dlo/test/force``, key ``test_force``) with these
    plot series (``dlo_common.topics.Series``): a modality added to the registry."""
    from dlo_common import topics

    return topics.Topic(
        "/dlo/test/force",
        "geometry_msgs/msg/WrenchStamped",
        "sim_node",
        "observation",
        "made up for the test",
        key="test_force",
        plot=tuple(series),
    )
