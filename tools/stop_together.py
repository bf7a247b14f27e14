#!/usr/bin/env python3
"""Stop a whole graph with one SIGINT, again and again, and catch a node that does not exit.

    tools/stop_together.py [--rounds 100] [--run 20] [--out /tmp/stop_together]

Each round starts sim_node, tactile_node, vision_node and a random policy_node on a ROS domain reserved for it
(tests/support/harness.py), lets them run ``--run`` s, sends SIGINT to all four at once (what a terminal's Ctrl-C to a
launched graph does) and waits 30 s for each. A node still running then gets its C and Python stacks written to
OUT/hang_<round>_<node>.txt (harness.hang_report: gdb, then SIGABRT) and is killed; a node that
exits with another status than its interrupted one (1: its middleware teardown was cut after
dlo_common.node_main.TEARDOWN_LIMIT s) keeps its stderr in OUT/stderr_<round>_<node>.txt. One JSON line per
round on stdout and in OUT/rounds.jsonl.
A diagnostic for the middleware's teardown (docs/appendix/REHEARSALS.md: rehearsals 98 and 99), not a product command.
Needs scripts/env.sh sourced and gdb for the stacks.
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "support"))  # the test harness
from harness import ROS2RUN, hang_report, isolated_env, release_domains, reserve_domains  # noqa: E402

NODES = {
    "sim": ["dlo_sim", "sim_node", "min_subscribers:=3", "publish_markers:=false"],
    "tactile": ["dlo_perception", "tactile_node"],
    "vision": ["dlo_perception", "vision_node"],
    "policy": ["dlo_policy", "policy_node", "policy:=random", "modalities:=All"],
}
INTERRUPTED = {"sim": 130}  # exit status after a SIGINT (0 for the others)
STOP_WAIT = 30.0  # s after the SIGINT


def one_round(index: int, run_s: float, out: Path) -> dict:
    domain = reserve_domains()
    env = {**isolated_env(domain_id=domain), "PYTHONFAULTHANDLER": "1"}  # (Python stacks on hang_report's SIGABRT)
    stderr = {name: out / f"stderr_{index}_{name}.txt" for name in NODES}
    try:
        procs = {}
        for name, (package, executable, *params) in NODES.items():
            args = [str(ROS2RUN), package, executable, "--ros-args"] + [a for p in params for a in ("-p", p)]
            with stderr[name].open("w") as err:  # (the child keeps its own descriptor)
                procs[name] = subprocess.Popen(args, env=env, stdout=subprocess.DEVNULL, stderr=err)
        time.sleep(run_s)
        for proc in procs.values():
            proc.send_signal(signal.SIGINT)
        start, hung, codes = time.monotonic(), [], {}
        for name, proc in procs.items():
            try:
                codes[name] = proc.wait(timeout=max(0.1, STOP_WAIT - (time.monotonic() - start)))
            except subprocess.TimeoutExpired:
                hung.append(name)
                (out / f"hang_{index}_{name}.txt").write_text(
                    hang_report(proc, name, STOP_WAIT, lambda name=name: stderr[name].read_text(errors="replace"))
                )
        unexpected = [name for name, code in codes.items() if code != INTERRUPTED.get(name, 0)]
        for name in procs:
            if name not in hung and name not in unexpected:
                stderr[name].unlink()
        return {
            "round": index,
            "domain": domain,
            "hung": hung,
            "exit_codes": codes,
            "unexpected": unexpected,
            "stop_s": round(time.monotonic() - start, 2),
        }
    finally:
        release_domains(domain)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="tools/stop_together.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--rounds", type=int, default=100, help="graphs started and stopped (default 100)")
    parser.add_argument("--run", type=float, default=20.0, help="seconds each graph runs before the SIGINT")
    parser.add_argument("--out", type=Path, default=Path("/tmp/stop_together"), help="where the lines and stacks go")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    hangs = cut = 0
    with (args.out / "rounds.jsonl").open("a") as log:
        for index in range(args.rounds):
            result = one_round(index, args.run, args.out)
            line = json.dumps(result)
            print(line, flush=True)
            log.write(line + "\n")
            log.flush()  # (a round's line is on disk while the next one runs)
            hangs += bool(result["hung"])
            cut += bool(result["unexpected"])
    print(
        f"{hangs} of {args.rounds} rounds left a node running {STOP_WAIT:g} s after the SIGINT; in {cut} a node "
        "exited with another status than its interrupted one (stderr kept in --out)"
    )
    return 1 if hangs else 0


if __name__ == "__main__":
    raise SystemExit(main())
