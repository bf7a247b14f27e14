"""dlo_policy.rundir: one training process per run directory (the lock); where the shipped policy is found."""

import os
import subprocess
import sys
from pathlib import Path

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
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time; from pathlib import Path; from dlo_policy import rundir\n"
            f"with rundir.lock(Path({str(run)!r})):\n    print('held', flush=True); time.sleep(600)",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
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


def test_the_lock_makes_the_directory_and_a_0644_lock_file(tmp_path):
    run = tmp_path / "grid" / "K" / "seed_1"  # dlo-experiments' layout: parents that do not exist yet
    with rundir.lock(run):
        mode = (run / rundir.LOCK_FILE).stat().st_mode & 0o777
    umask = os.umask(0)
    os.umask(umask)
    assert mode == 0o644 & ~umask


def test_a_holder_that_has_not_written_its_pid_is_named_as_it_reads(tmp_path):
    """The refusal names what the lock file holds: '?' for nothing yet, undecodable bytes replaced, at most 32
    bytes of it (one line); a refused process writes nothing into the file."""
    import fcntl

    run = tmp_path / "run"
    run.mkdir()
    path = run / rundir.LOCK_FILE
    for content, named in ((b"", "?"), (b"\xff\xfe\n", "\ufffd\ufffd"), (b"x" * 100, "x" * 32)):
        path.write_bytes(content)
        fd = os.open(path, os.O_RDWR)  # another holder: locked, its pid not (yet) written
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            with pytest.raises(rundir.RunInUse) as refused:
                with rundir.lock(run):
                    pass
            assert f"(pid {named})" in str(refused.value)
            assert path.read_bytes() == content
        finally:
            os.close(fd)


def make_files(run, names):
    run.mkdir(parents=True, exist_ok=True)
    for name in names:
        (run / name).write_text("x")


def test_result_and_record_names_are_the_files_present_done_json_last(tmp_path):
    run = tmp_path / "run"
    make_files(
        run,
        [
            "done.json",
            "test_without_T.json",
            "test.json",
            "train.log",
            "policy.pt",
            "best_policy.pt",
            "best.json",
            "eval.csv",
            "config.yaml",
            "checkpoint.pt",
            "other.txt",
        ],
    )
    (run / rundir.TB_DIR).mkdir()
    assert rundir.result_names(run) == [
        "config.yaml",
        "eval.csv",
        "best.json",
        "best_policy.pt",
        "policy.pt",
        "train.log",
        "test.json",
        "test_without_T.json",
        "done.json",
    ]
    assert rundir.record_names(run) == ["config.yaml", "eval.csv", "done.json", "best.json", "test.json", "test_without_T.json"]
    for name in ("policy.pt", "done.json", "eval.csv"):
        (run / name).unlink()
    assert rundir.result_names(run) == [
        "config.yaml",
        "best.json",
        "best_policy.pt",
        "train.log",
        "test.json",
        "test_without_T.json",
    ]
    assert rundir.record_names(run) == ["config.yaml", "best.json", "test.json", "test_without_T.json"]


def test_run_status_is_done_partial_or_todo(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    assert rundir.run_status(run) == "todo" and not rundir.is_done(run)
    make_files(run, ["checkpoint.pt"])
    assert rundir.run_status(run) == "partial"
    make_files(run, ["done.json"])
    assert rundir.run_status(run) == "done" and rundir.is_done(run)
    (run / "checkpoint.pt").unlink()
    assert rundir.run_status(run) == "done"


def test_done_best_and_test_json_are_written_as_documented(tmp_path):
    """done.json and test*.json indented by 2, best.json one line; each ends with a newline."""
    run = tmp_path / "run"
    run.mkdir()
    summary = {"steps": 300, "outcomes": [0.5, 0.25]}
    rundir.write_done(run, summary)
    assert (run / "done.json").read_text() == '{\n  "steps": 300,\n  "outcomes": [\n    0.5,\n    0.25\n  ]\n}\n'
    assert rundir.read_done(run) == summary
    rundir.write_best(run, {"step": 200, "hold_the_end": 0.5, "episode_reward": 1.25})
    assert (run / "best.json").read_text() == '{"step": 200, "hold_the_end": 0.5, "episode_reward": 1.25}\n'
    rundir.write_best(run, None)
    assert (run / "best.json").read_text() == "null\n"
    rundir.write_test(run, "", {"episodes": 2})
    rundir.write_test(run, "T", {"episodes": 3})
    assert (run / "test.json").read_text() == '{\n  "episodes": 2\n}\n'
    assert (run / "test_without_T.json").read_text() == '{\n  "episodes": 3\n}\n'
    assert rundir.test_names(run) == ["test.json", "test_without_T.json"]


def eval_row(step, wall_time):
    return {"step": step, "tested_without": "", "episodes": 10, "wall_time_s": wall_time}


def test_eval_log_keeps_the_rows_up_to_the_resume_step_and_their_wall_time(tmp_path):
    """EvalLog: a fresh run starts eval.csv afresh (header only); a resumed run keeps the rows up to and including
    its checkpoint step, and its wall time goes on from the last kept row's."""
    run = tmp_path / "run"
    run.mkdir()
    log = rundir.EvalLog(run, None)
    assert log.wall_time_offset == 0.0
    log.append([eval_row(step, 1.5 * step) for step in (10, 20, 30, 40)])
    rows = rundir.read_eval_rows(run)
    assert [row["step"] for row in rows] == ["10", "20", "30", "40"] and list(rows[0]) == list(rundir.EVAL_COLUMNS)
    assert rows[1]["wall_time_s"] == "30.0" and rows[1]["alpha"] == ""

    resumed = rundir.EvalLog(run, 30)
    assert [row["step"] for row in rundir.read_eval_rows(run)] == ["10", "20", "30"]
    assert resumed.wall_time_offset == 45.0
    resumed.append([eval_row(40, 70.0)])
    assert [(row["step"], row["wall_time_s"]) for row in rundir.read_eval_rows(run)] == [
        ("10", "15.0"),
        ("20", "30.0"),
        ("30", "45.0"),
        ("40", "70.0"),
    ]

    assert rundir.EvalLog(run, 5).wall_time_offset == 0.0  # resumed before the first evaluation: nothing kept
    assert rundir.read_eval_rows(run) == []
    rundir.EvalLog(run, None).append([eval_row(10, 15.0)])
    fresh = rundir.EvalLog(run, None)  # a new run in a directory with an old eval.csv
    assert fresh.wall_time_offset == 0.0 and rundir.read_eval_rows(run) == []
    assert (run / "eval.csv").read_bytes() == (",".join(rundir.EVAL_COLUMNS) + "\r\n").encode()
    other = tmp_path / "other"
    other.mkdir()
    assert rundir.EvalLog(other, 30).wall_time_offset == 0.0 and rundir.read_eval_rows(other) == []


def test_sim_settings_are_what_the_policy_file_was_trained_on(tmp_path):
    """scripts/launch_graph.sh --help: with --policy sac the sim runs the task rules and grip of the
    checkpoint's run (its config.yaml); trained_sim_settings says which, None without a config.yaml."""
    from dlo_policy.config import load_config, save_config

    runs = {
        "old": [],
        "spg": ["env_options.task_rules=authors_code", "env_options.single_particle_grip=true"],
        "text": ["env_options.task_rules=paper_text", "env_options.single_particle_grip=false"],
        "levers": [
            "env_options.task_rules=authors_code",
            "env_options.carry_law=authors",
            "env_options.contact_radius=0.005",
            "env_options.vision_source=particles",
            "env_options.move_spacing=0.004",
        ],
    }
    for name, overrides in runs.items():
        (tmp_path / name).mkdir()
        save_config(load_config(None, overrides), tmp_path / name / rundir.CONFIG_FILE)
        (tmp_path / name / "policy.pt").write_bytes(b"")
    defaults = {
        "carry_law": "paper",
        "contact_radius": 0.004,
        "vision_source": "image",
        "start_pose": "ours",
        "move_spacing": 0.0,
    }
    assert rundir.trained_sim_settings(tmp_path / "old" / "policy.pt") == {
        "task_rules": "paper_text",
        "single_particle_grip": False,
        **defaults,
    }  # from before the options
    assert rundir.trained_sim_settings(tmp_path / "spg" / "checkpoint.pt") == {
        "task_rules": "authors_code",
        "single_particle_grip": True,
        **defaults,
    }
    assert rundir.trained_sim_settings(tmp_path / "levers" / "policy.pt") == {
        "task_rules": "authors_code",
        "single_particle_grip": False,
        "carry_law": "authors",
        "contact_radius": 0.005,
        "vision_source": "particles",
        "start_pose": "ours",
        "move_spacing": 0.004,
    }
    (tmp_path / "bare").mkdir()
    (tmp_path / "bare" / "policy.pt").write_bytes(b"")
    assert rundir.trained_sim_settings(tmp_path / "bare" / "policy.pt") is None
    # the shipped policy: the study's authors_code, one-particle grip
    assert rundir.trained_sim_settings(rundir.shipped_policy_path()) == {
        "task_rules": "authors_code",
        "single_particle_grip": True,
        **defaults,
    }


def test_sim_settings_of_a_bad_config_is_a_config_error(tmp_path):
    """(The launcher says it in one line: tests/test_launch_graph_exit_codes.py.)"""
    from dlo_policy.config import ConfigError

    (tmp_path / "policy.pt").write_bytes(b"")
    (tmp_path / rundir.CONFIG_FILE).write_text("env_options: [not, a, mapping\n")
    with pytest.raises(ConfigError):
        rundir.trained_sim_settings(tmp_path / "policy.pt")


def test_the_shipped_policy_is_the_installed_one_when_the_package_is_installed(monkeypatch, tmp_path):
    import ament_index_python.packages as index

    (tmp_path / rundir.SHIPPED_POLICY).parent.mkdir(parents=True, exist_ok=True)
    (tmp_path / rundir.SHIPPED_POLICY).write_bytes(b"installed")
    monkeypatch.setattr(index, "get_package_share_directory", lambda package: str(tmp_path))
    assert rundir.shipped_policy_path() == tmp_path / rundir.SHIPPED_POLICY


@pytest.mark.parametrize("share", ["not installed", "installed without the policy"])
def test_the_shipped_policy_falls_back_to_the_source_tree(monkeypatch, tmp_path, share):
    import ament_index_python.packages as index

    def not_installed(package):
        raise index.PackageNotFoundError(package)

    monkeypatch.setattr(
        index, "get_package_share_directory", not_installed if share == "not installed" else lambda package: str(tmp_path)
    )
    source_tree = Path(rundir.__file__).resolve().parents[1] / rundir.SHIPPED_POLICY
    assert rundir.shipped_policy_path() == source_tree and source_tree.is_file()
