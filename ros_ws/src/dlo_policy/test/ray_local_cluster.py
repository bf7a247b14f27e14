"""A multi-node Ray cluster on this machine, on the loopback address only (a test helper).

    python ray_local_cluster.py --workers 2 --temp-dir /tmp/rayNNN [--num-cpus 1]

Starts a head node and `--workers` worker nodes (each its own raylet, object store and worker
processes; `ray.cluster_utils.Cluster`), prints one JSON line
    {"address": "127.0.0.1:PORT", "head": {...}, "workers": [{"node_id", "raylet_pid"}, ...]}
and keeps the cluster up until stdin closes or SIGTERM/SIGINT arrives; then it shuts every node
down. Run it in its own session (start_new_session): Ray's reaper kills the process group if this
process dies, so nothing it started outlives it.

Loopback only: Ray turns 127.0.0.1 into this machine's outward address (and binds its gRPC
servers to every interface) unless RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0, which makes 127.0.0.1
the node address of every node and of every driver that sets it too (then Ray's servers listen
on 127.0.0.1 only). `ray start` refuses worker nodes in that mode, so the nodes are started
through the Python API here.
"""

from __future__ import annotations

import os

os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"  # before Ray is imported: node IP 127.0.0.1
os.environ.setdefault("RAY_DISABLE_USAGE_STATS", "1")

import argparse  # noqa: E402
import inspect  # noqa: E402
import json  # noqa: E402
import signal  # noqa: E402
import socket  # noqa: E402
import sys  # noqa: E402
import threading  # noqa: E402

LOOPBACK = "127.0.0.1"
# a lost node is declared dead after ~2 s instead of ~30 s
SYSTEM_CONFIG = {
    "health_check_initial_delay_ms": 1000,
    "health_check_period_ms": 500,
    "health_check_timeout_ms": 1000,
    "health_check_failure_threshold": 3,
}


def free_port() -> int:
    with socket.socket() as s:
        s.bind((LOOPBACK, 0))
        return s.getsockname()[1]


def node_args(num_cpus: int, temp_dir: str) -> dict:
    return {
        "node_ip_address": LOOPBACK,
        "num_cpus": num_cpus,
        "include_dashboard": False,
        "object_store_memory": 80 * 1024 * 1024,
        "temp_dir": temp_dir,
        "runtime_env_agent_port": free_port(),
    }  # given: the raylet does not wait for the agent to report it


def patch_agent_port_wait() -> None:
    """The raylet waits at most 15 s (fixed), then aborts, for its dashboard agent to report its
    ports; under load (tests at nice 15 beside training jobs) the Python agent starts slower than
    that. With the `ray` package alone the agent runs minimal: it reports "-1" (no metrics, no
    HTTP) for all three ports, so the same "-1" is written before the raylet starts."""
    from ray._private import services  # noqa: PLC0415
    from ray._raylet import DASHBOARD_AGENT_LISTEN_PORT_NAME, METRICS_AGENT_PORT_NAME, METRICS_EXPORT_PORT_NAME, persist_port  # noqa: PLC0415

    start_raylet = services.start_raylet
    signature = inspect.signature(start_raylet)

    def start_raylet_with_ports(*args, **kwargs):
        bound = signature.bind(*args, **kwargs).arguments
        for name in (METRICS_AGENT_PORT_NAME, METRICS_EXPORT_PORT_NAME, DASHBOARD_AGENT_LISTEN_PORT_NAME):
            persist_port(bound["session_dir"], bound["node_id"], name, -1)
        return start_raylet(*args, **kwargs)

    services.start_raylet = start_raylet_with_ports


def describe(node) -> dict:
    return {"node_id": node.node_id, "raylet_pid": node.all_processes["raylet"][0].process.pid}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--num-cpus", type=int, default=1, help="CPUs of every node (head included)")
    parser.add_argument("--head-cpus", type=int, help="CPUs of the head (default --num-cpus)")
    parser.add_argument("--temp-dir", required=True, help="Ray's temp dir (short: it holds sockets)")
    args = parser.parse_args()

    # Ray's Cluster writes the head's address to $RAY_TMPDIR/ray/ray_current_cluster (else $TMPDIR/ray or
    # /tmp/ray), a folder it never creates: on a machine where Ray never ran the start fails with
    # FileNotFoundError. Keep that file in this cluster's own temp dir, never in a shared /tmp/ray.
    os.environ["RAY_TMPDIR"] = args.temp_dir
    os.makedirs(os.path.join(args.temp_dir, "ray"), exist_ok=True)
    from ray.cluster_utils import Cluster  # noqa: PLC0415

    patch_agent_port_wait()

    head_cpus = args.num_cpus if args.head_cpus is None else args.head_cpus
    cluster = Cluster(
        initialize_head=True, head_node_args={**node_args(head_cpus, args.temp_dir), "_system_config": SYSTEM_CONFIG}
    )
    stop = threading.Event()
    try:
        workers = [cluster.add_node(**node_args(args.num_cpus, args.temp_dir)) for _ in range(args.workers)]
        cluster.wait_for_nodes()
        print(
            json.dumps(
                {"address": cluster.address, "head": describe(cluster.head_node), "workers": [describe(w) for w in workers]}
            ),
            flush=True,
        )
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda *_: stop.set())
        threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
        stop.wait()
    finally:
        cluster.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
