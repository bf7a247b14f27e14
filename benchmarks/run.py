#!/usr/bin/env python3
"""Run the benchmarks of dlo-vitac (ours against a peer) and print one JSON line per benchmark.

    python benchmarks/run.py --list                # the benchmarks: what each measures, against what
    python benchmarks/run.py [NAME ...]            # run these with their default settings (none: all)
    python benchmarks/run.py --quick [NAME ...]    # each with its quickest settings (a smoke run, no figure)
    python benchmarks/run.py NAME -- ARGS ...      # one benchmark with its own options
    python benchmarks/run.py NAME -- --help        # that benchmark's options

Each benchmark is a script here, benchmarks/bench_NAME.py, with its own measurement code; it
prints progress and then its figures as a JSON line, last. The runner starts each in a fresh
interpreter (this one), one after the other, passes its progress lines to stderr (prefixed with
[NAME]) and prints on stdout exactly one JSON line per benchmark:
{"benchmark": NAME, "script": ..., "args": [...], "returncode": 0, "seconds": wall time, "result": {its JSON}},
with "error" instead of "result" when it failed or printed no JSON. `> results.jsonl` keeps the figures.
Run it after `source scripts/env.sh`, on a machine as idle as you can get (the figures are wall
times). Exit: 0 every benchmark gave its JSON, 1 one did not, 2 usage error, 130 interrupted.
Figures and their targets: docs/RESULTS.md#speed; what each compares: docs/ARCHITECTURE.md#benchmarks.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent


@dataclass(frozen=True)
class Benchmark:
    script: str  # in benchmarks/
    measures: str
    against: str  # the peer or reference it is compared with in the same run
    quick: tuple[str, ...]  # its quickest settings (--quick)


BENCHMARKS = {  # in the order "all" runs them: cheapest first
    "env": Benchmark(
        "bench_env.py",
        "env-steps/s of the full observation pipeline (N = 1, 10, 64)",
        "the bare simulator with the same actions and resets",
        ("--steps", "5", "--repeats", "1", "--sizes", "1"),
    ),
    "sim": Benchmark(
        "bench_sim.py",
        "Taichi rope env-steps/s, batched and single, rendering off and on",
        "MuJoCo's 50-segment cable (dense Jacobian, CG)",
        ("--seconds", "0.2", "--repeats", "1", "--batches", "1"),
    ),
    "sac": Benchmark(
        "bench_sac.py",
        "SAC gradient updates/s (2 x 1024 MLPs, batch 128)",
        "Stable-Baselines3 SAC, same network, batch and threads; the matmul roofline",
        ("--updates", "5", "--rounds", "1"),
    ),
    "graph": Benchmark(
        "bench_graph.py",
        "the step-locked ROS 2 graph: closed-loop steps/s, hop latency, recorder drops",
        "each hop of one control step (state, poses, command)",
        ("--episodes", "1"),
    ),
    "composed": Benchmark(
        "bench_composed.py",
        "the step-locked graph in one process (--composed): closed-loop steps/s, same episodes",
        "the same graph with a process per node (rounds A B, B A)",
        ("--episodes", "2", "--rounds", "1"),
    ),
    "viz": Benchmark(
        "bench_viz.py",
        "live view: Foxglove bridge latency and CPU; video frames/s",
        "the same graph without the bridge (A B B A windows)",
        ("--episodes", "1", "--window", "3", "--pairs", "1", "--warmup", "2", "--no-video"),
    ),
}


class UsageError(Exception):
    pass


def resolve(name: str) -> str:
    """A benchmark's name from NAME, bench_NAME or bench_NAME.py."""
    key = name.removesuffix(".py").removeprefix("bench_")
    if key not in BENCHMARKS:
        raise UsageError(f"no benchmark {name!r}; the benchmarks: {', '.join(BENCHMARKS)} (--list)")
    return key


def listing() -> str:
    lines = []
    for name, bench in BENCHMARKS.items():
        lines.append(f"{name:6s} benchmarks/{bench.script:15s} {bench.measures}; against: {bench.against}")
        lines.append(f"{'':6s} quick: {' '.join(bench.quick)}")
    return "\n".join(lines)


def last_json(lines: list[str]) -> dict | None:
    """The benchmark's result: its last non-empty stdout line, if that is a JSON object."""
    for line in reversed(lines):
        if line.strip():
            try:
                value = json.loads(line)
            except ValueError:
                return None
            return value if isinstance(value, dict) else None
    return None


def run_benchmark(name: str, script: Path, args: list[str], log=sys.stderr) -> dict:
    """Run one benchmark script; its progress goes to `log` as it comes; -> the record the runner prints."""
    record = {
        "benchmark": name,
        "script": str(script.relative_to(HERE.parent)) if script.is_relative_to(HERE.parent) else str(script),
        "args": args,
    }
    start = time.monotonic()
    proc = subprocess.Popen(
        [sys.executable, "-u", str(script), *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, bufsize=1
    )
    errors: list[str] = []

    def forward_stderr() -> None:
        for line in proc.stderr:
            errors.append(line.rstrip("\n"))
            print(f"[{name}] {line.rstrip()}", file=log, flush=True)

    thread = threading.Thread(target=forward_stderr, daemon=True)
    thread.start()
    lines: list[str] = []
    for line in proc.stdout:  # every line but the last is progress: shown one line late
        if lines:
            print(f"[{name}] {lines[-1]}", file=log, flush=True)
        lines.append(line.rstrip("\n"))
    returncode = proc.wait()
    thread.join(10)
    record.update(returncode=returncode, seconds=round(time.monotonic() - start, 1))
    result = last_json(lines)
    if returncode == 0 and result is not None:
        record["result"] = result
        return record
    if lines:
        print(f"[{name}] {lines[-1]}", file=log, flush=True)
    last = next((line for line in reversed(lines + errors) if line.strip()), "")  # stderr first
    record["error"] = (f"exit {returncode}" if returncode else "no JSON line last") + (f": {last.strip()}" if last else "")
    return record


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="benchmarks/run.py",
        description=__doc__.split("\n\n")[0],
        epilog=__doc__.split("\n\n", 1)[1],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "names", nargs="*", metavar="NAME", help=f"benchmarks to run: {', '.join(BENCHMARKS)} (default: all, in that order)"
    )
    parser.add_argument("--list", action="store_true", help="list the benchmarks and run nothing")
    parser.add_argument("--quick", action="store_true", help="each benchmark with its quickest settings (a smoke run)")
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    extra: list[str] = []
    if "--" in argv:
        cut = argv.index("--")
        argv, extra = argv[:cut], argv[cut + 1 :]
    args = build_parser().parse_args(argv)
    try:
        names = [resolve(name) for name in args.names] or list(BENCHMARKS)
        if args.list:
            print(listing())
            return 0
        if extra and len(names) != 1:
            raise UsageError("options after -- go to one benchmark: name exactly one")
        if "DLO_ROOT" not in os.environ:
            raise UsageError("source scripts/env.sh first")
    except UsageError as error:
        print(f"benchmarks/run.py: error: {error}", file=sys.stderr)
        return 2
    if {"-h", "--help"} & set(extra):  # the benchmark's own help, as it prints it
        return subprocess.call([sys.executable, str(HERE / BENCHMARKS[names[0]].script), *extra])
    failed = 0
    try:
        for name in names:
            bench = BENCHMARKS[name]
            record = run_benchmark(name, HERE / bench.script, [*(bench.quick if args.quick else ()), *extra])
            failed += "error" in record
            print(json.dumps(record), flush=True)
    except KeyboardInterrupt:
        print("benchmarks/run.py: interrupted", file=sys.stderr)
        return 130
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
