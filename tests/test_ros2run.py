"""scripts/ros2run, the stand-in for `ros2 run`: a SIGINT that arrives while it still looks the executable up
(its package index walk: pipelines of awk, grep and sed) ends it, whatever the moment.

The launcher stops a graph by sending SIGINT to each node's process, which is ros2run until it execs the
node. Bash, waiting for a pipeline whose commands did not get the signal and end normally, takes the signal
as handled by them and goes on: it used to exec the node anyway, and the launcher killed that node with
SIGKILL 10 s later ("did not stop within 10 s of SIGINT"), a recorder perhaps mid-way through opening its bag.
"""

from __future__ import annotations

import os
import pathlib
import signal
import subprocess
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
ROS2RUN = ROOT / "scripts" / "ros2run"


def fake_prefix(tmp_path: pathlib.Path) -> pathlib.Path:
    """An install prefix with one package whose executable runs until a signal ends it."""
    prefix = tmp_path / "install"
    (prefix / "share" / "ament_index" / "resource_index" / "packages").mkdir(parents=True)
    (prefix / "share" / "ament_index" / "resource_index" / "packages" / "fake_pkg").touch()
    exe = prefix / "lib" / "fake_pkg" / "forever"
    exe.parent.mkdir(parents=True)
    exe.write_text(f"#!/bin/sh\ntouch {tmp_path}/started\nexec sleep 600\n")
    exe.chmod(0o755)
    return prefix


def test_a_sigint_during_the_lookup_ends_ros2run_instead_of_the_node_starting(tmp_path):
    prefix = fake_prefix(tmp_path)
    env = dict(os.environ, AMENT_PREFIX_PATH=f"{prefix}:{os.environ.get('AMENT_PREFIX_PATH', '')}",
               DLO_ROOT=str(ROOT))
    # The lookup lasts ~0.1-0.3 s; signals sent across it and beyond, every ~10 ms, hit each of its steps.
    ended_in_lookup = 0
    for k in range(40):
        (tmp_path / "started").unlink(missing_ok=True)
        proc = subprocess.Popen([str(ROS2RUN), "fake_pkg", "forever"], env=env, stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        time.sleep(0.01 * k)
        proc.send_signal(signal.SIGINT)
        try:
            out, _ = proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
            raise AssertionError(f"SIGINT {10 * k} ms after the start was lost: ros2run went on and started the node") \
                from None
        assert proc.returncode in (130, -signal.SIGINT), (k, proc.returncode, out)
        ended_in_lookup += not (tmp_path / "started").exists()
    assert ended_in_lookup > 0  # some signals did arrive during the lookup (the case this test is about)
