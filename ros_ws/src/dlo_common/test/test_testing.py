"""The test harness (tests/support/harness.py) and dlo_common.domains.

reserve_domains: a ROS domain a test uses is used by nothing else on the machine
(another test process, a pytest-xdist worker, launch_graph.sh, any DDS participant);
remove_orphaned_dds_shm: what killed participants leave in /dev/shm is removed, nothing in use;
stop_or_explain and Procs: a node that does not stop on SIGINT fails with its stacks."""

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import harness as testing
import pytest

SUPPORT = Path(testing.__file__).resolve().parent  # tests/support: a child Python finds the harness there


def reserve_in_another_process(first: int, last: int, span: int = 1) -> str:
    """What reserve_domains gives a second process ('none' when nothing is free)."""
    code = (
        f"import sys\nsys.path.insert(0, {str(SUPPORT)!r})\nimport harness as testing\n"
        f"try:\n    print(testing.reserve_domains({span}, {first}, {last}))\n"
        "except RuntimeError:\n    print('none')\n"
    )
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True).stdout.strip()


def test_a_reserved_domain_is_refused_to_another_process_until_released():
    domain = testing.reserve_domains()
    try:
        assert testing.TEST_DOMAINS[0] <= domain <= testing.TEST_DOMAINS[1]
        assert reserve_in_another_process(domain, domain) == "none"
        neighbours = reserve_in_another_process(domain - 1, domain + 1)
        assert neighbours in (str(domain - 1), str(domain + 1), "none")  # never the held one
        with pytest.raises(RuntimeError, match="no 1 free ROS domain"):
            testing.reserve_domains(1, domain, domain)  # this process holds it: not given twice either
    finally:
        testing.release_domains(domain)
    assert reserve_in_another_process(domain, domain) == str(domain)  # released: free again


def test_a_span_is_consecutive_free_domains_all_held():
    first = testing.reserve_domains(3)
    try:
        for domain in (first, first + 1, first + 2):
            assert reserve_in_another_process(domain, domain) == "none", domain
    finally:
        testing.release_domains(first, 3)
    assert reserve_in_another_process(first + 1, first + 1) == str(first + 1)


def test_a_domain_with_a_participant_on_its_ports_is_skipped():
    """A DDS participant of another program (not a dlo-vitac lock) on a domain: its ports are bound."""
    with testing.reserved_domain() as free:
        pass  # a domain nothing else held a moment ago
    for offset in (0, 249):  # the first and the last port of the domain's range
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind(("127.0.0.1", 7400 + 250 * free + offset))
            assert testing.domain_busy(free)
            assert reserve_in_another_process(free, free) == "none"
        finally:
            sock.close()
    assert not testing.domain_busy(free)
    assert reserve_in_another_process(free, free) == str(free)


def test_the_context_manager_releases_and_isolated_env_reserves():
    with testing.reserved_domain(2) as domain:
        assert reserve_in_another_process(domain + 1, domain + 1) == "none"
    assert reserve_in_another_process(domain, domain + 1, span=2) == str(domain)
    env = testing.isolated_env({"PATH": "/usr/bin", "ROS_DOMAIN_ID": "0", "ROS_LOCALHOST_ONLY": "1"})
    domain = int(env["ROS_DOMAIN_ID"])
    try:
        assert domain != 0 and reserve_in_another_process(domain, domain) == "none"  # held for this process
        assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST" and "ROS_LOCALHOST_ONLY" not in env
    finally:
        testing.release_domains(domain)


HOLDER = """import mmap, sys, time
held = open(sys.argv[1], "rb")                    # an open file
mapped = open(sys.argv[2], "r+b")
view = mmap.mmap(mapped.fileno(), 0)              # a mapped one (its file object then closed)
mapped.close()
ports = [open(path, "r+b") for path in sys.argv[3:]]  # mapped ports
port_views = [mmap.mmap(f.fileno(), 0) for f in ports]
for f in ports:
    f.close()
print("ready", flush=True)
time.sleep(120)
"""


def test_only_new_dds_files_no_process_uses_are_removed(tmp_path):
    """remove_orphaned_dds_shm: of Fast DDS's files that appeared since the snapshot, those no process maps
    or holds open go; one open or mapped by a live process, one there before, and any other file stay."""
    shm = tmp_path / "shm"
    shm.mkdir()
    (shm / "fastrtps_before").write_bytes(b"x")
    before = testing.dds_shm_entries(shm)
    assert before == {"fastrtps_before"}
    for name in (
        "fastrtps_orphan",
        "fastrtps_orphan_el",
        "sem.fastrtps_port7001_mutex",
        "fastrtps_open",
        "fastrtps_mapped",
        "someone_else",
        "fastrtps_port7002",
        "sem.fastrtps_port7002_mutex",
    ):
        (shm / name).write_bytes(b"x" * 4096)
    # The holder maps fastrtps_port7002 but not its mutex: a running participant's port, whose mutex Fast DDS
    # maps only while it opens the port. The mutex stays with its port.
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLDER, str(shm / "fastrtps_open"), str(shm / "fastrtps_mapped"), str(shm / "fastrtps_port7002")],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "ready"
        removed = testing.remove_orphaned_dds_shm(before, shm)
    finally:
        holder.kill()
        holder.wait()
    assert sorted(removed) == ["fastrtps_orphan", "fastrtps_orphan_el", "sem.fastrtps_port7001_mutex"]
    assert sorted(p.name for p in shm.iterdir()) == [
        "fastrtps_before",
        "fastrtps_mapped",
        "fastrtps_open",
        "fastrtps_port7002",
        "sem.fastrtps_port7002_mutex",
        "someone_else",
    ]
    assert testing.remove_orphaned_dds_shm(before, shm) == [  # holder gone
        "fastrtps_mapped",
        "fastrtps_open",
        "fastrtps_port7002",
        "sem.fastrtps_port7002_mutex",
    ]


NODE = """import time, rclpy
rclpy.init()
node = rclpy.create_node("shm_probe")
node.create_publisher(__import__("std_msgs.msg", fromlist=["String"]).String, "/shm_probe", 10)
print("up", flush=True)
time.sleep(120)
"""


def test_a_killed_participants_shared_memory_is_removed_and_a_live_ones_kept():
    """What the test session does at its end (conftest.py): a ROS node killed with SIGKILL leaves Fast DDS
    files in /dev/shm; they are removed, while those of a node still running stay."""
    pytest.importorskip("rclpy")
    if not testing.SHM.is_dir():
        pytest.skip("no /dev/shm here")
    before = testing.dds_shm_entries()
    env = testing.isolated_env()
    live, killed = (subprocess.Popen([sys.executable, "-c", NODE], env=env, stdout=subprocess.PIPE, text=True) for _ in range(2))
    try:
        for proc in (live, killed):
            assert proc.stdout.readline().strip() == "up"
        killed_files = {
            name
            for name in testing.dds_shm_entries() - before
            if f"{testing.SHM / name}" in (Path(f"/proc/{killed.pid}/maps").read_text())
        }
        live_maps = Path(f"/proc/{live.pid}/maps").read_text()  # its files, its ports' mutexes (dds_shm_owner) too
        live_files = {
            name for name in testing.dds_shm_entries() - before if f"{testing.SHM / testing.dds_shm_owner(name)}" in live_maps
        }
        if not killed_files:
            pytest.skip("this DDS set-up uses no shared memory")
        killed.kill()
        killed.wait()
        removed = set(testing.remove_orphaned_dds_shm(before))
        assert removed  # what only the killed node held (its locks at least) is gone
        # What the killed node mapped stays only where the live node uses it: the live node maps a peer's segment
        # and ports to exchange data with it, at any moment after discovery, and keeps them until it ends.
        # (A port's mutex, which Fast DDS maps only while it opens the port, goes with its port: dds_shm_owner.)
        left = testing.dds_shm_entries()
        used_by_live = testing.files_in_use([live.pid])
        assert all(str(testing.SHM / testing.dds_shm_owner(name)) in used_by_live for name in killed_files & left), (
            killed_files & left
        )
        assert live_files <= left and not live_files & removed, live_files - left  # the live node's stay
    finally:
        for proc in (live, killed):
            proc.kill()
            proc.wait()


def test_stop_or_explain_returns_the_code_of_a_node_that_stops_and_names_where_one_hangs(tmp_path):
    """A node that ends on SIGINT: its code. One that does not: an AssertionError with its Python stacks
    (faulthandler on SIGABRT) and C stacks (gdb), and it is gone."""
    default_sigint = lambda: signal.signal(signal.SIGINT, signal.SIG_DFL)  # (pytest run with SIGINT ignored)
    stops = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import time\ntry:\n    print('up', flush=True)\n    time.sleep(60)\n"
            "except KeyboardInterrupt:\n    raise SystemExit(7)",
        ],
        stdout=subprocess.PIPE,
        preexec_fn=default_sigint,
    )
    assert stops.stdout.readline() == b"up\n"
    assert testing.stop_or_explain(stops, "stops", 30) == 7
    log = tmp_path / "hangs.log"
    hangs = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import signal, time\nsignal.signal(signal.SIGINT, signal.SIG_IGN)\n"
            "print('up', flush=True)\ndef stuck_in_shutdown():\n    time.sleep(600)\nstuck_in_shutdown()",
        ],
        env=dict(os.environ, PYTHONFAULTHANDLER="1"),
        stdout=log.open("w"),
        stderr=subprocess.STDOUT,
        preexec_fn=default_sigint,
    )
    while "up" not in log.read_text():
        time.sleep(0.05)
    with pytest.raises(AssertionError) as failure:
        testing.stop_or_explain(hangs, "the hanging node", 1, log)
    assert testing.exited(hangs.pid)
    message = str(failure.value)
    assert message.startswith("the hanging node did not stop within 1 s of SIGINT")
    assert "in stuck_in_shutdown" in message  # its Python stack
    if shutil.which("gdb"):
        assert "Thread 1" in message or "#0 " in message, message  # its C stack


def test_procs_stop_every_process_on_sigint_and_one_that_ignores_it_fails_with_its_stacks():
    """Procs.stop_all: processes that end on SIGINT end (also when the tests themselves run with SIGINT ignored,
    as a background job); one that ignores SIGINT is an AssertionError naming it, with its Python stack, and
    is gone; every other one still stopped."""
    stops = (
        "import time\ntry:\n    print('up', flush=True)\n    time.sleep(60)\nexcept KeyboardInterrupt:\n"
        "    print('interrupted', flush=True)"
    )
    hangs = (
        "import signal, time\nsignal.signal(signal.SIGINT, signal.SIG_IGN)\nprint('up', flush=True)\n"
        "def ignores_ctrl_c():\n    time.sleep(600)\nignores_ctrl_c()"
    )
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)  # the children inherit an ignored SIGINT
    try:
        with testing.Procs(dict(os.environ), stop_timeout=5) as start:
            first = start("first", [sys.executable, "-c", stops])
            second = start("second", [sys.executable, "-c", stops])
            for proc in (first, second):
                proc.wait_line("up", timeout=60)
        assert first.p.returncode == second.p.returncode == 0 and "interrupted" in first.output()
        procs = testing.Procs(dict(os.environ), stop_timeout=5)
        quiet = procs("quiet", [sys.executable, "-c", stops])
        stuck = procs("stuck", [sys.executable, "-c", hangs])
        for proc in (quiet, stuck):
            proc.wait_line("up", timeout=60)
    finally:
        signal.signal(signal.SIGINT, previous)
    with pytest.raises(AssertionError) as failure:
        procs.stop_all()
    message = str(failure.value)
    assert message.startswith("stuck did not stop within 5 s of SIGINT") and "quiet" not in message
    assert "in ignores_ctrl_c" in message  # its Python stack (PYTHONFAULTHANDLER, set by Procs)
    assert testing.exited(stuck.p.pid) and quiet.p.returncode == 0
