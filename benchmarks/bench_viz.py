#!/usr/bin/env python3
"""Benchmark the live view and the videos: bridge latency and CPU, closed-loop rate with and
without the bridge and a client, video rendering speed. Prints a JSON line last.

1. **Videos**: a recorded run of ``--episodes`` episodes (scripts/launch_graph.sh --record), then
   every episode rendered as MP4 (dlo_bag.video): frames/s of wall time and of CPU time.
2. **Live view, paired**: one step-locked graph runs episodes until stopped (launch_graph.sh
   --episodes 0: sim, tactile, vision, policy). In alternating windows of ``--window`` seconds
   (order A B B A, repeated ``--pairs`` times, so slow drifts of a shared machine's load cancel)
   the graph runs **A** alone or **B** with ``dlo_viz foxglove_bridge`` and one protocol
   client (a separate process, subscribed to every topic). This script's ROS node subscribes to
   the gripper state in both (the rate: control steps/s within episodes, resets excluded) and
   answers every state with a probe on ``/dlo/bench/probe`` (std_msgs/Header stamped with the
   wall time of publishing), which the bridge serves like any /dlo topic:

   - ``bridge_latency_ms``: probe publish -> client receive (p50/p99) at the graph's full rate;
   - ``bridge_added_latency_ms``: the same gripper state at the client minus at this node's own
     ROS subscription (what the bridge adds on top of DDS);
   - ``bridge_cpu_percent_of_one_core``: the bridge's CPU time / wall time in the B windows;
   - ``rate``: steps/s in A and in B windows and their ratio (the issue asks >= 0.9).

    python benchmarks/run.py viz -- [--episodes 2] [--window 15] [--pairs 2] [--policy tactile_reactive]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "ros_ws" / "src" / "dlo_viz" / "test"))  # the protocol test client

PROBE = "/dlo/bench/probe"


def client_process(url: str, out: str, stop) -> None:
    """Protocol client in its own process: subscribe to everything, log (topic, stamp, recv)."""
    from foxglove_ws_client import FoxgloveTestClient

    client = FoxgloveTestClient(url).connect()
    subscribed: set[str] = set()
    while not stop.is_set():
        new = {c["topic"] for c in client.channels.values()} - subscribed
        if new:
            subscribed |= set(client.subscribe(sorted(new)))
        time.sleep(0.05)
    client.close()
    rows, counts = [], {}
    for m in client.messages:
        counts[m.topic] = counts.get(m.topic, 0) + 1
        if m.topic in (PROBE, "/dlo/gripper/state"):
            msg = client.decode(m)
            stamp = msg.stamp if m.topic == PROBE else msg.header.stamp  # the probe is a std_msgs/Header
            rows.append((m.topic, stamp.sec * 1_000_000_000 + stamp.nanosec, m.recv_time))
    Path(out).write_text(json.dumps({"rows": rows, "counts": counts}))


class Watcher:
    """This script's ROS node on the graph's domain: gripper-state arrival times, probes."""

    def __init__(self, domain: int) -> None:
        import rclpy
        from dlo_msgs.msg import GripperState
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile
        from std_msgs.msg import Header

        self.rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node("bench_viz", context=self.context)
        self.states: list[tuple[int, int, int, int]] = []  # (episode, step, stamp ns, arrival ns)
        self.probe = self.node.create_publisher(Header, PROBE, QoSProfile(depth=100))

        def on_state(msg) -> None:
            now = time.time_ns()
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            self.states.append((int(msg.episode), int(msg.step), stamp, now))
            probe = Header(frame_id=f"{msg.episode}:{msg.step}")
            t = time.time_ns()
            probe.stamp.sec, probe.stamp.nanosec = t // 1_000_000_000, t % 1_000_000_000
            self.probe.publish(probe)

        self.node.create_subscription(GripperState, "/dlo/gripper/state", on_state, 100)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        while not self._stop.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        self._stop.set()
        self.thread.join(5)
        self.node.destroy_node()
        self.rclpy.shutdown(context=self.context)


def cpu_seconds(pid: int) -> float | None:
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime + stime
    except (OSError, IndexError, ValueError):
        return None


def window_rate(states, t0: int, t1: int) -> dict:
    """Control steps/s from consecutive steps of one episode that both arrived in [t0, t1]."""
    first: dict[tuple[int, int], int] = {}
    for episode, step, _stamp, t in states:
        first.setdefault((episode, step), t)
    periods = [
        first[(e, s + 1)] - t for (e, s), t in first.items() if (e, s + 1) in first and t0 <= t and first[(e, s + 1)] <= t1
    ]
    if not periods:
        return {"steps_per_s": None, "steps_per_s_median": None, "periods": 0}
    return {
        "steps_per_s": len(periods) / (sum(periods) / 1e9),  # mean rate: stalls count
        "steps_per_s_median": 1e9 / float(np.median(periods)),
        "periods": len(periods),
    }


def pct(values, q) -> float | None:
    return round(float(np.percentile(np.asarray(values) / 1e6, q)), 3) if len(values) else None


def launch(args, *extra: str) -> subprocess.Popen:
    cmd = ["bash", str(ROOT / "scripts" / "launch_graph.sh"), "--seed", str(args.seed), "--policy", args.policy, *extra]
    return subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "DLO_USE_ROS2RUN": "1"},
        start_new_session=True,
    )


def video_benchmark(args, work: Path) -> dict:
    from dlo_bag.analysis import read_run, recompute_episode
    from dlo_bag.video import render_episode_video

    bag = work / "bag"
    proc = launch(args, "--episodes", str(args.episodes), "--record", str(bag), "--logs", str(work / "logs_video"))
    out, _ = proc.communicate()
    if proc.returncode != 0:
        raise RuntimeError(f"recorded run failed ({proc.returncode}):\n{out[-2000:]}")
    run = read_run(bag, extra={"/dlo/camera/image": "image"})
    videos = []
    for episode, streams in run.items():
        if "task" not in streams:
            continue
        summary = {"episode": episode, **recompute_episode(streams["task"])}
        cpu0 = time.process_time()
        item = render_episode_video(episode, streams, summary, work / f"video/episode_{episode:04d}.mp4", policy=args.policy)
        item["render_cpu_s"] = round(time.process_time() - cpu0, 3)
        videos.append({k: item[k] for k in ("frames", "render_s", "render_fps", "render_cpu_s", "bytes")})
    frames = sum(v["frames"] for v in videos)
    return {
        "episodes": videos,
        "frames_per_s": round(frames / max(1e-9, sum(v["render_s"] for v in videos)), 2),
        "frames_per_cpu_s": round(frames / max(1e-9, sum(v["render_cpu_s"] for v in videos)), 2),
    }


class Bridge:
    """The bridge process and one protocol client process (B windows)."""

    def __init__(self, domain: int, work: Path, index: int, params: list[str]) -> None:
        env = {**os.environ, "ROS_DOMAIN_ID": str(domain)}
        extra = [x for param in params for x in ("-p", param)]
        self.proc = subprocess.Popen(
            [
                str(ROOT / "scripts" / "ros2run"),
                "dlo_viz",
                "foxglove_bridge",
                "--ros-args",
                "-p",
                "port:=0",
                "-p",
                "stats_period:=0",
                *extra,
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env=env,
            start_new_session=True,
        )
        self.lines: list[str] = []
        url = None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip())
            if m := re.search(r"(ws://127\.0\.0\.1:\d+)", line):
                url = m.group(1)
                break
        if url is None:
            raise RuntimeError("the bridge did not start:\n" + "\n".join(self.lines[-20:]))
        threading.Thread(target=self._drain, daemon=True).start()
        ctx = mp.get_context("spawn")  # no fork of a process that runs ROS threads
        self.stop_event = ctx.Event()
        self.out = work / f"client_{index}.json"
        self.client = ctx.Process(target=client_process, args=(url, str(self.out), self.stop_event))
        self.client.start()

    def _drain(self) -> None:
        for line in self.proc.stdout:
            self.lines.append(line.rstrip())

    def close(self) -> dict:
        self.stop_event.set()
        self.client.join(120)
        self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.wait(30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
        return json.loads(self.out.read_text()) if self.out.exists() else {"rows": [], "counts": {}}


def _wait_for_graph(proc: subprocess.Popen, lines: list[str]) -> tuple[Watcher | None, int | None]:
    """Read the launcher's output until the policy starts; a Watcher on the graph's domain."""
    watcher, domain = None, None
    for line in proc.stdout:
        lines.append(line.rstrip())
        if m := re.search(r"ROS_DOMAIN_ID=(\d+)", line):
            watcher = Watcher(int(m.group(1)))
            domain = int(m.group(1))
        if "[launch] policy" in line:
            break
    return watcher, domain


def _wait_until_running(proc: subprocess.Popen, watcher: Watcher | None, lines: list[str]) -> None:
    end = time.monotonic() + 900
    while watcher is None or len(watcher.states) < 50:  # the graph runs (Taichi kernels built)
        if proc.poll() is not None or time.monotonic() > end:
            raise RuntimeError("the graph did not start:\n" + "\n".join(lines[-20:]))
        time.sleep(0.5)


def _cpu_percent(before: float | None, after: float | None, t0: int, t1: int) -> float | None:
    if before is None or after is None:
        return None
    return 100.0 * (after - before) / ((t1 - t0) / 1e9)


def _bridge_window(window: dict, bridge: Bridge, watcher: Watcher, cpu: tuple, t0: int, t1: int) -> None:
    """Close the B window's bridge and add its CPU shares, probe and added latencies to ``window``."""
    data = bridge.close()
    (cpu0, cpu1), (ccpu0, ccpu1) = cpu
    if (bridge_cpu := _cpu_percent(cpu0, cpu1, t0, t1)) is not None:
        window["bridge_cpu_percent"] = bridge_cpu
    if (client_cpu := _cpu_percent(ccpu0, ccpu1, t0, t1)) is not None:
        window["client_cpu_percent"] = client_cpu
    rows = [r for r in data["rows"] if t0 <= r[2] <= t1]
    window["probe_ns"] = [recv - stamp for topic, stamp, recv in rows if topic == PROBE]
    direct: dict[int, int] = {}
    for _e, _s, stamp, t in watcher.states:
        direct.setdefault(stamp, t)
    seen_states: dict[int, int] = {}
    for topic, stamp, recv in rows:
        if topic == "/dlo/gripper/state":
            seen_states.setdefault(stamp, recv)
    window["added_ns"] = [recv - direct[s] for s, recv in seen_states.items() if s in direct]
    window["client_counts"] = data["counts"]


def _measure_window(args, work: Path, i: int, mode: str, watcher: Watcher, domain: int) -> dict:
    """One A (graph alone) or B (graph + bridge + client) window of ``args.window`` seconds."""
    bridge = None
    if mode == "B":
        bridge = Bridge(domain, work, i, args.bridge_param)
        time.sleep(args.warmup)  # discovery, subscriptions, the client subscribes to every topic
    else:
        time.sleep(1.0)  # settle after the last bridge left
    t0, cpu0 = time.time_ns(), (cpu_seconds(bridge.proc.pid) if bridge else None)
    ccpu0 = cpu_seconds(bridge.client.pid) if bridge else None
    time.sleep(args.window)
    t1, cpu1 = time.time_ns(), (cpu_seconds(bridge.proc.pid) if bridge else None)
    ccpu1 = cpu_seconds(bridge.client.pid) if bridge else None
    window = {"mode": mode, **window_rate(watcher.states, t0, t1)}
    if bridge:
        _bridge_window(window, bridge, watcher, ((cpu0, cpu1), (ccpu0, ccpu1)), t0, t1)
    print(
        f"[bench_viz] window {i} {mode}: {window['steps_per_s'] or 0:.1f} steps/s "
        f"({window['periods']} periods)" + (f", bridge {window.get('bridge_cpu_percent', 0):.1f}% CPU" if bridge else ""),
        file=sys.stderr,
    )
    return window


def _stop_graph(proc: subprocess.Popen, watcher: Watcher | None) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)  # the launcher stops every node it started
        try:
            proc.wait(120)
        except subprocess.TimeoutExpired:
            proc.terminate()
    if watcher is not None:
        watcher.close()


def _summarise(windows: list[dict]) -> dict:
    """The JSON result of the live part: rates per mode, latencies, CPU shares."""

    def rate(mode, key="steps_per_s"):
        values = [w[key] for w in windows if w["mode"] == mode and w[key]]
        return float(np.mean(values)) if values else None

    probe = [x for w in windows for x in w.get("probe_ns", [])]
    added = [x for w in windows for x in w.get("added_ns", [])]
    cpu = [w["bridge_cpu_percent"] for w in windows if "bridge_cpu_percent" in w]
    client_cpu = [w["client_cpu_percent"] for w in windows if "client_cpu_percent" in w]
    a, b = rate("A"), rate("B")
    return {
        "steps_per_s_without_bridge": round(a, 2) if a else None,
        "steps_per_s_with_bridge_and_client": round(b, 2) if b else None,
        "rate_ratio": round(b / a, 3) if a and b else None,
        "rate_ratio_median_periods": (
            round(rate("B", "steps_per_s_median") / rate("A", "steps_per_s_median"), 3)
            if rate("A", "steps_per_s_median") and rate("B", "steps_per_s_median")
            else None
        ),
        "windows": [
            {
                k: (round(v, 2) if isinstance(v, float) else v)
                for k, v in w.items()
                if k not in ("probe_ns", "added_ns", "client_counts")
            }
            for w in windows
        ],
        "bridge_latency_ms": {
            "p50": pct(probe, 50),
            "p99": pct(probe, 99),
            "n": len(probe),
            "what": "probe publish -> protocol client receive",
        },
        "bridge_added_latency_ms": {
            "p50": pct(added, 50),
            "p99": pct(added, 99),
            "n": len(added),
            "what": "client receive - this node's direct ROS receive, same gripper state",
        },
        "bridge_cpu_percent_of_one_core": round(float(np.mean(cpu)), 1) if cpu else None,
        "client_cpu_percent_of_one_core": round(float(np.mean(client_cpu)), 1) if client_cpu else None,
        "client_messages_last_window": next((w["client_counts"] for w in reversed(windows) if "client_counts" in w), None),
    }


def live_benchmark(args, work: Path) -> dict:
    proc = launch(args, "--episodes", "0", "--logs", str(work / "logs_live"))
    watcher = None
    lines: list[str] = []
    windows = []
    try:
        watcher, domain = _wait_for_graph(proc, lines)
        threading.Thread(target=lambda: [lines.append(x.rstrip()) for x in proc.stdout], daemon=True).start()
        _wait_until_running(proc, watcher, lines)
        for i, mode in enumerate("ABBA" * args.pairs):
            windows.append(_measure_window(args, work, i, mode, watcher, domain))
    finally:
        _stop_graph(proc, watcher)
    return _summarise(windows)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=2, help="episodes of the recorded run for the videos")
    parser.add_argument("--seed", type=int, default=500)
    parser.add_argument("--policy", default="tactile_reactive", choices=("sac", "tactile_reactive", "random"))
    parser.add_argument("--window", type=float, default=15.0, help="seconds per A/B window")
    parser.add_argument("--pairs", type=int, default=2, help="repetitions of the A B B A pattern")
    parser.add_argument("--warmup", type=float, default=4.0, help="seconds between starting the bridge and a B window")
    parser.add_argument("--keep", type=Path, default=None, help="keep bags, logs and videos in this directory")
    parser.add_argument(
        "--bridge-param",
        action="append",
        default=[],
        metavar="NAME:=VALUE",
        help="a parameter of the bridge in the B windows, e.g. nice:=0 (repeatable)",
    )
    parser.add_argument("--no-video", action="store_true", help="skip the recorded run and the video part")
    args = parser.parse_args()
    if "DLO_ROOT" not in os.environ:
        print("bench_viz: source scripts/env.sh first", file=sys.stderr)
        return 2
    work = args.keep or Path(tempfile.mkdtemp(prefix="bench_viz_"))
    work.mkdir(parents=True, exist_ok=True)
    video = None
    if not args.no_video:
        video = video_benchmark(args, work)
        print(f"[bench_viz] video: {video['frames_per_s']} frames/s", file=sys.stderr)
    live = live_benchmark(args, work)
    result = {
        **live,
        "video": video,
        "bridge_params": args.bridge_param,
        "episodes": args.episodes,
        "window_s": args.window,
        "pairs": args.pairs,
        "policy": args.policy,
        "cpus": os.cpu_count(),
        "load_average_1min": round(os.getloadavg()[0], 2),
    }
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
