"""dlo-experiments on a real multi-node Ray cluster on this machine, loopback only.

Three nodes (head + 2 workers, each its own raylet, object store and worker processes, 1 CPU each;
ray_local_cluster.py) bound to 127.0.0.1, a driver (`dlo-experiments --ray-address`) in its own
process with node address 127.0.0.1 too. The tiny grid (sac_reach_env, 16x16 networks, 200 steps,
T, K, V, All: 4 runs on 3 one-CPU nodes, so the first three start on three different nodes)
spreads over the nodes; one worker node is killed (SIGKILL: its raylet and every process it
started) while it runs a run; the grid still finishes every run, on the driver's disk, and
reports the retry. Every Ray process started here is stopped at the end, also when a test fails.
"""

import importlib.util
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="Ray is not installed")

HERE = Path(__file__).resolve().parent
TINY = [
    "env_module=sac_reach_env",
    "sac.hidden_sizes=[16,16]",
    "sac.batch_size=16",
    "sac.learning_starts=20",
    "sac.buffer_size=500",
    "train.eval_every=50",
    "train.checkpoint_every=50",
    "train.eval_episodes=4",
    "train.test_episodes=4",
    "env_options.step_delay=0.01",
]  # ~7 s of stepping per run: time to kill a node
STEPS = 200
RESULT_FILES = {"config.yaml", "eval.csv", "done.json", "best.json", "best_policy.pt", "policy.pt", "test.json", "train.log"}
START_TIMEOUT_S = 300  # a node's start is ~10 s on an idle machine; far slower beside training jobs
GRID_TIMEOUT_S = 1200
RUNS = 4


def ray_env(temp_dir: str) -> dict:
    """Environment of the cluster and the driver: node address 127.0.0.1 for every node and the
    driver (Ray otherwise turns 127.0.0.1 into the machine's outward address), no usage reports,
    Ray's own files (the current-cluster address file) in the cluster's temp dir, nothing assumed
    under /tmp/ray, temporary files in it too (the run directory of the run on the node killed, which
    that run cannot remove, goes with it), the test helpers importable by Ray's workers (sac_reach_env)."""
    env = dict(os.environ)
    env.update(
        RAY_TMPDIR=temp_dir,
        TMPDIR=temp_dir,
        RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER="0",
        RAY_DISABLE_USAGE_STATS="1",
        RAY_worker_register_timeout_seconds="600",  # workers start slowly on a loaded machine
        RAY_worker_niceness="0",  # Ray's workers keep the test's priority (Ray's default: +15)
        PYTHONPATH=os.pathsep.join([str(HERE), env.get("PYTHONPATH", "")]),
    )
    return env


def processes_mentioning(text: str) -> list[int]:
    """Ids of the processes whose command line contains `text` (here: the cluster's own temp dir)."""
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and int(entry.name) != os.getpid():
            try:
                if text.encode() in (entry / "cmdline").read_bytes():
                    pids.append(int(entry.name))
            except OSError:
                pass
    return pids


def children(pid: int) -> list[int]:
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                found.append(int(entry.name))
    return found


def kill(pids) -> None:
    for pid in pids:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


def listening_addresses(pids: list[int]) -> set[str]:
    """Local addresses of the TCP sockets in LISTEN state that these processes hold."""
    inodes = set()
    for pid in pids:
        try:
            for fd in Path(f"/proc/{pid}/fd").iterdir():
                try:
                    target = os.readlink(fd)
                except OSError:
                    continue
                if target.startswith("socket:["):
                    inodes.add(target[8:-1])
        except OSError:
            continue
    addresses = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            lines = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            if fields[3] == "0A" and fields[9] in inodes:  # 0A: LISTEN
                addresses.add(decode_address(fields[1].split(":")[0]))
    return addresses


def decode_address(raw: str) -> str:
    """/proc/net/tcp{,6} hex address (32-bit words, each little-endian) -> dotted IPv4 / IPv6 text."""
    data = b"".join(bytes.fromhex(raw[i : i + 8])[::-1] for i in range(0, len(raw), 8))
    if len(data) == 16 and data[:12] == bytes(10) + b"\xff\xff":  # IPv4-mapped IPv6 (::ffff:a.b.c.d)
        data = data[12:]
    if len(data) == 4:
        return ".".join(str(b) for b in data)
    import ipaddress  # noqa: PLC0415

    return str(ipaddress.IPv6Address(data))


@pytest.fixture(scope="module")
def cluster():
    """Head + 2 worker nodes on 127.0.0.1; stopped (and anything left of it killed) afterwards."""
    temp_dir = tempfile.mkdtemp(prefix="dlo-ray-", dir="/tmp")  # short: Ray puts sockets in it
    holder = subprocess.Popen(
        [sys.executable, str(HERE / "ray_local_cluster.py"), "--workers", "2", "--num-cpus", "1", "--temp-dir", temp_dir],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=open(Path(temp_dir) / "holder.log", "w"),
        text=True,
        env=ray_env(temp_dir),
        start_new_session=True,
    )
    try:
        line: list[str] = []
        reader = threading.Thread(target=lambda: line.append(holder.stdout.readline()), daemon=True)
        reader.start()
        reader.join(START_TIMEOUT_S)
        if not line or not line[0].strip():
            log = (Path(temp_dir) / "holder.log").read_text()[-3000:]
            pytest.fail(f"the Ray cluster did not start within {START_TIMEOUT_S} s:\n{log}")
        info = json.loads(line[0])
        yield {**info, "temp_dir": temp_dir, "holder_pid": holder.pid}
    finally:
        try:
            holder.stdin.close()  # the helper shuts every node down
            holder.wait(timeout=120)
        except (subprocess.TimeoutExpired, OSError):
            pass
        try:
            os.killpg(holder.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        holder.wait()
        kill(processes_mentioning(temp_dir))  # raylets' workers live in process groups of their own
        shutil.rmtree(temp_dir, ignore_errors=True)


def grid_command(out: Path, address: str) -> list[str]:
    return [
        sys.executable,
        "-m",
        "dlo_policy.experiments",
        "--out",
        str(out),
        "--ray-address",
        address,
        "--groups",
        "single",
        "--seeds",
        "1",
        "--steps",
        str(STEPS),
        "--threads",
        "1",
        "--retries",
        "2",
        *TINY,
    ]


def test_ray_servers_listen_on_the_loopback_address_only(cluster):
    pids = [cluster["holder_pid"], *processes_mentioning(cluster["temp_dir"])]
    addresses = listening_addresses(pids)
    host, port = cluster["address"].rsplit(":", 1)
    assert host == "127.0.0.1"
    assert addresses, "no listening socket found for the cluster's processes"
    assert addresses <= {"127.0.0.1", "::1"}, addresses  # nothing on 0.0.0.0, :: or an outward address


def test_grid_spreads_over_nodes_survives_a_lost_node_and_returns_every_result(cluster, tmp_path):
    out = tmp_path / "grid"
    victim = cluster["workers"][0]
    node_ids = {cluster["head"]["node_id"], *(w["node_id"] for w in cluster["workers"])}
    stderr_path = tmp_path / "driver.err"
    driver = subprocess.Popen(
        grid_command(out, cluster["address"]),
        stdout=subprocess.PIPE,
        stderr=open(stderr_path, "w"),
        text=True,
        env=ray_env(cluster["temp_dir"]),
        cwd=tmp_path,
    )
    lines, killed_run = [], None
    deadline = time.monotonic() + GRID_TIMEOUT_S
    timer = threading.Timer(GRID_TIMEOUT_S, driver.kill)
    timer.start()
    try:
        for line in driver.stdout:
            lines.append(line.rstrip("\n"))
            # "[start] OUT/K/seed0 on node <id[:12]> (attempt 1)": kill that node while the run is on it
            if killed_run is None and line.startswith("[start]") and f"on node {victim['node_id'][:12]}" in line:
                killed_run = line.split()[1]
                time.sleep(1.0)  # into its training steps
                kill([victim["raylet_pid"], *children(victim["raylet_pid"])])
        driver.wait(timeout=max(1.0, deadline - time.monotonic()))
    finally:
        timer.cancel()
        if driver.poll() is None:
            driver.kill()
            driver.wait()
    output, errors = "\n".join(lines), stderr_path.read_text()
    assert driver.returncode == 0, output + errors[-3000:]
    assert killed_run is not None, "no run started on the worker node to be killed:\n" + output

    runs = sorted(out.glob("*/seed*"))
    assert len(runs) == RUNS
    nodes_used = set()
    for run in runs:
        names = {p.name for p in run.iterdir()}
        assert names == RESULT_FILES, (run, names)  # no checkpoint.pt (the replay buffer stays on the worker)
        done = json.loads((run / "done.json").read_text())
        assert done["env_steps"] == STEPS and done["node"] in node_ids and done["duration_s"] > 0
        assert done["host"] and done["attempts"] >= 1
        assert (run / "eval.csv").read_text().splitlines()[-1].split(",")[0] == str(STEPS)
        nodes_used.add(done["node"])
    assert len(nodes_used) >= 2, nodes_used  # the grid spread over the cluster

    lost = json.loads((Path(killed_run) / "done.json").read_text())
    assert lost["attempts"] == 2 and lost["node"] != victim["node_id"]
    assert f"[retry] {killed_run}: attempt 1 lost" in output
    assert f"grid: {RUNS} run(s): {RUNS} finished, 0 failed" in output
    assert "retried 1 run(s) after a lost worker or node:" in output
    assert f"  {killed_run}: lost 1x (" in output and "finished on node" in output
    assert f"{RUNS}/{RUNS}" in errors and "failed=0 retried=1" in errors  # the progress bar's last state

    # the same command again: every run is finished, nothing is dispatched
    again = subprocess.run(
        grid_command(out, cluster["address"]),
        capture_output=True,
        text=True,
        env=ray_env(cluster["temp_dir"]),
        cwd=tmp_path,
        timeout=600,
    )
    assert again.returncode == 0, again.stderr[-3000:]
    assert f"{RUNS} runs, {RUNS} done, 0 to run" in again.stdout and "[start]" not in again.stdout
