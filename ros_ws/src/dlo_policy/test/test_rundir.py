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


def test_the_lock_file_names_the_holder_even_over_a_longer_stale_pid(tmp_path):
    """rundir.lock: the file holds the holder's pid and nothing of an earlier holder's longer pid."""
    run = tmp_path / "run"
    run.mkdir()
    (run / rundir.LOCK_FILE).write_text("123456789012345\n")  # left by an earlier holder (a lock file stays)
    with rundir.lock(run):
        assert (run / rundir.LOCK_FILE).read_text() == f"{os.getpid()}\n"
        with pytest.raises(rundir.RunInUse, match=rf"\(pid {os.getpid()}\)"):
            with rundir.lock(run):
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


def test_a_run_directory_from_before_task_rules_reads_as_paper_text(tmp_path):
    """docs/ARCHITECTURE.md#task (Task variants), dlo-evaluate --help: a checkpoint is evaluated under the
    task rules of its run's config.yaml; run directories from before the switch (no task_rules there)
    read as paper_text, the rules they were trained on."""
    from dlo_policy.config import load_config, save_config
    from dlo_policy.evaluate import load_run_config

    old, new = tmp_path / "old", tmp_path / "new"
    old.mkdir()
    new.mkdir()
    save_config(load_config(), old / rundir.CONFIG_FILE)  # the cable env, no task_rules named
    save_config(load_config(None, ["env_options.task_rules=authors_code"]), new / rundir.CONFIG_FILE)
    assert "task_rules" not in (old / rundir.CONFIG_FILE).read_text()
    assert rundir.read_trained_config(old).env_options["task_rules"] == "paper_text"
    assert rundir.read_trained_config(new).env_options["task_rules"] == "authors_code"
    assert load_run_config(old / "policy.pt").env_options["task_rules"] == "paper_text"
    assert load_run_config(new / "best_policy.pt").env_options["task_rules"] == "authors_code"
