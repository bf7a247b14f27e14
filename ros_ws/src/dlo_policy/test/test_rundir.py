"""dlo_policy.rundir: one training process per run directory (the lock)."""
import os
import subprocess
import sys

import pytest

from dlo_policy import rundir


def test_a_second_holder_is_refused_with_the_first_ones_pid_and_the_lock_is_released_after(tmp_path):
    run = tmp_path / "run"
    with rundir.lock(run):
        assert (run / rundir.LOCK_FILE).read_text().strip() == str(os.getpid())
        with pytest.raises(rundir.RunInUse, match=rf"{run} is in use by another training \(pid {os.getpid()}\)"):
            with rundir.lock(run):
                pass
    with rundir.lock(run):  # released: taken again
        pass


def test_a_lock_held_by_a_process_that_was_killed_is_free(tmp_path):
    run = tmp_path / "run"
    holder = subprocess.Popen([sys.executable, "-c",
                               "import sys, time; from pathlib import Path; from dlo_policy import rundir\n"
                               f"with rundir.lock(Path({str(run)!r})):\n    print('held', flush=True); time.sleep(600)"],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(rundir.RunInUse, match=f"pid {holder.pid}"):
            with rundir.lock(run):
                pass
    finally:
        holder.kill()
        holder.wait()
    with rundir.lock(run):  # SIGKILL left a stale file but no lock
        pass
